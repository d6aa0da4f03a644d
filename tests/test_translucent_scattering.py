"""Issue #13: translucent occluders in every scattering method (Peters 2017 Sec. 3.2's transmittance model).

Under one infinite horizontal slab of opacity alpha, every medium point below it sees (1 - alpha) E, so L_scat is
(1 - alpha) times the unshadowed closed form E sigma_s f(cos) (1 - exp(-sigma_t s)) / sigma_t, whatever the light
direction: the shadow map's translucent layer, each prefiltered method's two-depth rectified map and the marchers
that read the map must all reproduce it. Before the translucent layer, every method but exact visibility treated the
slab as opaque (L_scat 0 under it: a relative error of 1).
"""

import numpy as np
import pytest
import warp as wp
from conftest import quad, render_method

from warpscatter.raster.gbuffer import gbuffer_raycast
from warpscatter.runtime.device import module_options
from warpscatter.scene import DeviceGeometry, Scene
from warpscatter.scene.camera import Camera
from warpscatter.scene.lights import DirectionalLight
from warpscatter.scene.medium import Medium
from warpscatter.shadows.shadow_map import render_shadow_map
from warpscatter.shadows.surface import SurfaceShadows, surface_visibility

module_options()

SIZE = 400.0


def _slab_scene(opacity: float, two_sided: bool = False) -> Scene:
    """Ground at y = 0, a translucent slab at y = 3 (one surface, or two faces 0.2 apart), the camera at y = 1
    looking down so that every ray ends on the ground, a slanted sun."""
    cam = Camera(position=[0, 1, 0], look_at=[0, 0.3, -1], up=[0, 1, 0], fov_y=50, width=48, height=32, near=0.1,
                 far=60)
    light = DirectionalLight(direction=[0.3, -1.0, 0.2], irradiance=[1.0, 0.8, 0.6])
    medium = Medium(sigma_t=0.1, albedo=0.9, phase="henyey_greenstein", g=0.3)
    verts, tris, mats = [], [], []
    for k, y in enumerate([0.0, 3.0] + ([3.2] if two_sided else [])):
        v, t = quad([-SIZE, y, SIZE], [SIZE, y, SIZE], [SIZE, y, -SIZE], [-SIZE, y, -SIZE])
        verts.append(v)
        tris.append(t + 4 * k)
        mats.append(np.full(2, min(k, 1), np.int32))
    return Scene(vertices=np.concatenate(verts), triangles=np.concatenate(tris), tri_material=np.concatenate(mats),
                 albedo=np.array([[0.5, 0.5, 0.5]] * 2, np.float32),
                 opacity=np.array([1.0, opacity], np.float32), camera=cam, light=light, medium=medium)


def _closed_form(scene: Scene, distance: np.ndarray) -> np.ndarray:
    cam, light, medium = scene.camera, scene.light, scene.medium
    f = medium.phase_value(-(cam.ray_directions() @ light.direction))
    return (np.asarray(light.irradiance)[None, None, :]
            * (medium.sigma_s * f * (1.0 - np.exp(-medium.sigma_t * distance)) / medium.sigma_t)[..., None])


def test_shadow_map_keeps_the_translucent_layer():
    scene = _slab_scene(0.4, two_sided=True)
    sm = render_shadow_map(scene, 64)
    assert sm.translucent
    covered = np.isfinite(sm.opaque_depth)
    assert covered.mean() > 0.99
    # nearest caster: the upper face, 3.2 - 0.0 = 3.2 units (along the light's slant) before the ground
    gap = (sm.opaque_depth - sm.depth)[covered]
    np.testing.assert_allclose(gap, 3.2 * np.linalg.norm([0.3, -1.0, 0.2]), rtol=1e-4)
    np.testing.assert_allclose(sm.transmittance[covered], 0.6 * 0.6, rtol=1e-6)  # both faces pass 0.6 each
    opaque = render_shadow_map(_slab_scene(1.0), 64)
    assert not opaque.translucent and opaque.opaque_depth is None


# bounds: measured rel. L1 against the closed form (alpha = 0.5, 48x32, 256^2 map), about 2x margin; the fast methods
# own error on this scene (epipolar's interpolation, the Fourier basis' ringing) is the most of it. While the
# supersampled resampling's taps ramped over half a texel they followed the slanted slab's depths a little less
# closely than the bilinear weights they take again (moments4 7.0e-3, moments6 3.0e-5 with these)
CASES = [
    ("raymarch", {"visibility": "shadow_map", "steps": 16}, 1e-5),  # measured 8.8e-7
    ("epipolar", {"steps": 16}, 0.02),  # measured 9.0e-3
    ("fourier", {"prefiltered": {"rectification": "nonlinear"}}, 0.015),  # measured 7.1e-3
    ("fourier", {"prefiltered": {"rectification": "nonlinear", "resample_filter": "none"}}, 0.015),  # 8.2e-3
    ("fourier", {"prefiltered": {"rectification": "projective"}}, 0.02),  # measured 1.1e-2
    ("moments6", {"prefiltered": {"rectification": "nonlinear"}}, 1e-3),  # measured 1.3e-4
    ("moments6", {"prefiltered": {"rectification": "nonlinear", "resample_filter": "moments"}}, 1e-3),  # 1.5e-5
    ("moments6", {"prefiltered": {"rectification": "projective"}}, 1e-3),  # measured 4.1e-5
    # moments4's default depth warp (c = 3) spends its resolution away from the light, on the slab's far side
    ("moments4", {"prefiltered": {"rectification": "nonlinear"}}, 0.025),  # measured 1.2e-2
    ("moments4", {"prefiltered": {"rectification": "nonlinear", "depth_warp": 0.0}}, 3e-3),  # measured 1.6e-3
    # the depth warp (Klehm Sec. 5) moves the representations' resolution, not the hard visibility
    ("moments6", {"prefiltered": {"rectification": "nonlinear", "depth_warp": -3.0}}, 1e-3),  # measured 2.7e-4
    ("fourier", {"prefiltered": {"rectification": "nonlinear", "depth_warp": -1.0}}, 0.015),  # measured 6.3e-3
]


@pytest.mark.parametrize("method,keys,bound", CASES, ids=[f"{m}-{i}" for i, (m, _, _) in enumerate(CASES)])
def test_every_method_passes_the_translucent_slabs_light(method, keys, bound):
    opacity = 0.5
    scene = _slab_scene(opacity)
    geo = DeviceGeometry(scene)
    gb = gbuffer_raycast(scene, geo)
    sm = render_shadow_map(scene, 256)
    got, info = render_method(scene, gb, method, geometry=geo, shadow_map=sm, **keys)
    if "rectification" in keys.get("prefiltered", {}):
        assert info["rectification"] == keys["prefiltered"]["rectification"]
    want = (1.0 - opacity) * _closed_form(scene, gb.distance.numpy())
    rel = np.abs(got - want).sum() / want.sum()
    assert rel < bound, rel


@wp.kernel
def _surface_visibility_kernel(sh: SurfaceShadows, points: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.vec3)):
    k = wp.tid()
    zero = wp.vec3(0.0, 0.0, 0.0)
    out[k] = surface_visibility(sh, points[k], wp.vec3(0.0, 1.0, 0.0), zero, zero)


@pytest.mark.parametrize("opacity, two_sided, want", [(0.5, False, 0.5), (0.4, True, 0.36), (1.0, False, 0.0)])
def test_pcf_surface_shadows_pass_the_translucent_casters_light(opacity, two_sided, want):
    """``pcf`` surface shadows read the same translucent layer: the ground under a slab gets 1 - opacity per face
    the light crosses (before, every translucent caster shadowed surfaces like an opaque one)."""
    from warpscatter.shadows.settings import ShadowsSettings
    from warpscatter.shadows.surface import prepare_shadows

    scene = _slab_scene(opacity, two_sided)
    sh, _ = prepare_shadows(scene, render_shadow_map(scene, 128), ShadowsSettings(method="pcf"))
    rng = np.random.default_rng(0)
    # ground points in the view (the map covers the view frustum)
    pts = np.stack([rng.uniform(-0.5, 0.5, 64), np.zeros(64), rng.uniform(-3, -2, 64)], axis=1).astype(np.float32)
    out = wp.empty(64, dtype=wp.vec3)
    wp.launch(_surface_visibility_kernel, 64, [sh, wp.array(pts, dtype=wp.vec3), out])
    np.testing.assert_allclose(out.numpy(), want, atol=1e-6)


def test_warped_depth_is_a_monotone_map_of_the_unit_interval():
    from warpscatter.scattering.prefiltered.textures import check_depth_warp, warped_depth

    @wp.kernel
    def warp_kernel(z: wp.array(dtype=float), c: float, out: wp.array(dtype=float)):
        i = wp.tid()
        out[i] = warped_depth(z[i], c)

    z = np.linspace(0.0, 1.0, 101, dtype=np.float32)
    for c in (-6.0, -1.0, 0.5, 4.0):
        out = wp.empty(101, dtype=float)
        wp.launch(warp_kernel, 101, [wp.array(z), c, out])
        w = out.numpy()
        assert abs(w[0]) < 1e-6 and abs(w[-1] - 1.0) < 1e-5 and np.all(np.diff(w) > 0.0)
        np.testing.assert_allclose(w, np.expm1(c * z) / np.expm1(c), rtol=2e-4, atol=1e-6)
    with pytest.raises(ValueError, match="depth_warp"):
        check_depth_warp(float("nan"))
