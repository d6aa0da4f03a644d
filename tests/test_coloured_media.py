"""Issue #13: coloured media (RGB sigma_t and albedo) in every method.

Without occluders every method's L_scat is the closed form E_c sigma_s,c f (1 - exp(-sigma_t,c s)) / sigma_t,c per
channel (the prefiltered methods' visibility is 1 whatever its weights). With occluders the marchers are exact per
channel: a coloured render's channel c equals the grey render with channel c's sigma_t and albedo. The prefiltered
methods weight visibility with the channels' mean extinction (their one approximation): tested against the exact
marcher with a bound measured on a scene whose channels' extinctions differ 4x.
"""

import numpy as np
import pytest
from conftest import quad, render_method

from warpscatter.raster.gbuffer import gbuffer_raycast
from warpscatter.scene import DeviceGeometry, Scene
from warpscatter.scene.camera import Camera
from warpscatter.scene.lights import DirectionalLight
from warpscatter.scene.medium import Medium
from warpscatter.shadows.shadow_map import render_shadow_map

SIGMA_T = (0.04, 0.08, 0.16)
ALBEDO = (0.9, 0.7, 0.5)


def _scene(medium: Medium, occluder: bool = True) -> Scene:
    """A ground, and (``occluder``) a 6 x 6 roof at y = 4 casting a shadow into the middle of the view."""
    cam = Camera(position=[0, 2, 6], look_at=[0, 0.5, -4], up=[0, 1, 0], fov_y=55, width=48, height=32, near=0.1,
                 far=60)
    light = DirectionalLight(direction=[0.3, -1.0, 0.25], irradiance=[1.0, 0.9, 0.8])
    parts = [quad([-200, 0, 200], [200, 0, 200], [200, 0, -200], [-200, 0, -200])]
    if occluder:
        parts.append(quad([-3, 4, 3], [3, 4, 3], [3, 4, -3], [-3, 4, -3]))
    verts = np.concatenate([v for v, _ in parts])
    tris = np.concatenate([t + 4 * k for k, (_, t) in enumerate(parts)])
    return Scene(vertices=verts, triangles=tris, tri_material=np.zeros(len(tris), np.int32),
                 albedo=np.array([[0.5, 0.5, 0.5]], np.float32), opacity=np.ones(1, np.float32), camera=cam,
                 light=light, medium=medium)


def _render(scene: Scene, method: str, **keys) -> np.ndarray:
    geo = DeviceGeometry(scene)
    gb = gbuffer_raycast(scene, geo)
    sm = render_shadow_map(scene, 512)
    return render_method(scene, gb, method, geometry=geo, shadow_map=sm, **keys)[0], gb


# unshadowed bounds: measured rel. L1 per channel (max) about 2x; epipolar interpolates between its samples and the
# Fourier series rings at the ground, as in a grey medium
METHODS = [("raymarch", {"visibility": "exact", "steps": 16}, 1e-5),  # measured 1.2e-7
           ("raymarch", {"visibility": "shadow_map", "steps": 16}, 1e-5),  # 1.2e-7
           ("epipolar", {"steps": 16}, 0.015),  # 7.5e-3
           ("fourier", {}, 0.012),  # 5.6e-3
           ("moments6", {}, 1e-4),  # 3.5e-5
           ("moments4", {}, 1e-4)]  # 3.1e-5


@pytest.mark.parametrize("method,keys,bound", METHODS, ids=[f"{m}-{i}" for i, (m, _, _) in enumerate(METHODS)])
def test_unshadowed_coloured_medium_matches_the_closed_form(method, keys, bound):
    scene = _scene(Medium(sigma_t=SIGMA_T, albedo=ALBEDO, phase="henyey_greenstein", g=0.4), occluder=False)
    got, gb = _render(scene, method, **keys)
    cam, light, medium = scene.camera, scene.light, scene.medium
    f = medium.phase_value(-(cam.ray_directions() @ light.direction))
    s = gb.distance.numpy()[..., None]
    sig = np.asarray(SIGMA_T)
    want = np.asarray(light.irradiance) * np.asarray(medium.sigma_s_rgb) * f[..., None] * (1 - np.exp(-sig * s)) / sig
    rel = np.abs(got - want).sum(axis=(0, 1)) / want.sum(axis=(0, 1))
    assert rel.max() < bound, rel
    assert got[..., 2].sum() < 0.7 * got[..., 0].sum()  # the fog is really coloured (blue scatters less here)


@pytest.mark.parametrize("method,keys", [m[:2] for m in METHODS[:2]], ids=["exact", "shadow_map"])
def test_marched_channels_are_grey_renders(method, keys):
    """The marcher is exact per channel: channel c of the coloured render is the grey render with channel c's
    sigma_t and albedo (the same samples; float rounding apart)."""
    coloured, _ = _render(_scene(Medium(sigma_t=SIGMA_T, albedo=ALBEDO)), method, **keys)
    for c in range(3):
        grey, _ = _render(_scene(Medium(sigma_t=SIGMA_T[c], albedo=ALBEDO[c])), method, **keys)
        np.testing.assert_allclose(coloured[..., c], grey[..., c], rtol=2e-5, atol=1e-7)


@pytest.mark.parametrize("method", ["fourier", "moments6", "moments4", "epipolar"])
def test_fast_methods_err_per_channel_as_in_grey_media(method):
    """Against the exact marcher, each channel of a coloured render errs about as much as the grey render with that
    channel's sigma_t and albedo (the prefiltered methods: each channel's own ray weights, COLOURED_SEGMENTS).
    Measured coloured / grey rel. L1 (R, G, B): fourier 1.24/1.51, 1.22/1.40, 1.24/1.40 %; moments6 0.64/0.71,
    0.98/0.96, 1.29/1.00 %; moments4 0.77/0.86, 1.19/1.14, 1.50/1.06 % with its depth warp (without: 1.07/1.51,
    1.65/2.06, 1.96/2.10 %: the warp helps the grey blue channel most); epipolar equal to 1e-7 (it marches)."""
    medium = Medium(sigma_t=SIGMA_T, albedo=ALBEDO)
    ref, _ = _render(_scene(medium), "raymarch", visibility="exact", steps=512)
    assert (ref < 0.5 * ref.max()).mean() > 0.05  # the roof's shadow is in the view
    got, _ = _render(_scene(medium), method)
    rel = np.abs(got - ref).sum(axis=(0, 1)) / ref.sum(axis=(0, 1))
    for c in range(3):
        grey = Medium(sigma_t=SIGMA_T[c], albedo=ALBEDO[c])
        grey_ref, _ = _render(_scene(grey), "raymarch", visibility="exact", steps=512)
        grey_got, _ = _render(_scene(grey), method)
        grey_rel = np.abs(grey_got - grey_ref)[..., c].sum() / grey_ref[..., c].sum()
        assert rel[c] < (1.6 if method == "moments4" else 1.3) * grey_rel + 1e-3, (c, rel[c], grey_rel)
