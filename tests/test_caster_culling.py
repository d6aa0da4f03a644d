"""Caster culling of the prefiltered methods' rectified maps (``render.scattering.prefiltered.caster_culling``)."""

from pathlib import Path

import numpy as np
import pytest
import warp as wp
from scipy import ndimage

from warpscatter.bench import bench_scene_config, errors
from warpscatter.config import ConfigError, load_config
from warpscatter.pipeline import render_images
from warpscatter.raster.gbuffer import gbuffer_raster
from warpscatter.scattering import prefiltered as pre
from warpscatter.scattering.rectify import caster_culling as cc
from warpscatter.scattering.rectify.bounds import NonlinearRectification
from warpscatter.scattering.rectify.nonlinear import resample_shadow_map
from warpscatter.scattering.rectify.params import build_rectification
from warpscatter.scattering.rectify.projective import rasterize_rectified
from warpscatter.scattering.rectify.taps import SparseRectifiedDepth
from warpscatter.scattering.settings import PrefilteredSettings, ScatteringSettings
from warpscatter.scene import DeviceGeometry, build_scene
from warpscatter.scene.lights import light_params
from warpscatter.shadows.shadow_map import render_shadow_map

ROOT = Path(__file__).resolve().parent.parent
ROWS = COLS = 128


def _rectified(kind: str):
    """(scene, camera distances, rect, rectified depth) of the canopy (sun in view) or the colonnade under a side
    light with the projective rectification."""
    if kind == "nonlinear":
        cfg = bench_scene_config("canopy", 96, 54, leaves=600)
    else:
        cfg = bench_scene_config("colonnade", 96, 54)
        cfg.light.direction = [0.6, -0.5, 0.2]
    scene = build_scene(cfg)
    rect, choice = build_rectification(scene, PrefilteredSettings(rectification=kind), ROWS, COLS)
    assert choice.kind == kind
    distance = gbuffer_raster(scene, DeviceGeometry(scene)).distance
    if kind == "nonlinear":
        sm = render_shadow_map(scene, 256)
        depth = resample_shadow_map(rect, sm.depth, sm.view_projection, depth="linear", world_to_view=sm.view)
    else:
        casters = scene.casters()
        depth = rasterize_rectified(rect, casters.vertices, casters.triangles)
    return scene, distance, rect, depth


def _readers(scene, distance, rect):
    """numpy float64 look-up footprint of every pixel (prefilter.texel_footprint): rows j0, j1, last column i1, z_r."""
    cam = scene.camera
    points = cam.position + cam.ray_directions() * distance.numpy()[..., None].astype(np.float64)
    u, v, z = np.moveaxis(rect.world_to_rectified(points.reshape(-1, 3)), -1, 0)
    x = np.clip(u * COLS - 1.0, 0.0, COLS - 1)
    i1 = np.minimum(np.minimum(np.floor(x).astype(int), COLS - 1) + 1, COLS - 1)
    y = v * ROWS - 0.5
    if isinstance(rect, NonlinearRectification) and rect.full_circle:
        j0 = np.floor(y).astype(int) % ROWS
        j1 = (j0 + 1) % ROWS
    else:
        y = np.clip(y, 0.0, ROWS - 1)
        j0 = np.minimum(np.floor(y).astype(int), ROWS - 1)
        j1 = np.minimum(j0 + 1, ROWS - 1)
    return j0, j1, i1, z


def _needed(depth, readers, bias=0.0):
    """Texels some pixel reads (row j0 or j1, column <= i1) with z_r > the texel's depth + bias (brute force)."""
    j0, j1, i1, z = readers
    need = np.zeros(depth.shape, bool)
    cols = np.arange(depth.shape[1])
    for j in range(depth.shape[0]):
        sel = (j0 == j) | (j1 == j)
        if not sel.any():
            continue
        order = np.argsort(z[sel])
        zs, last = z[sel][order], i1[sel][order]
        deepest_col = np.maximum.accumulate(last[::-1])[::-1]  # last column read by a reader at or above index k
        k = np.searchsorted(zs, depth[j] + bias, side="right")  # first reader strictly deeper than depth + bias
        reach = np.where(k < len(zs), deepest_col[np.minimum(k, len(zs) - 1)], -1)
        need[j] = (depth[j] < 1.0) & (cols <= reach)
    return need


@pytest.mark.parametrize("kind,threads", [("nonlinear", "1"), ("nonlinear", "3"), ("projective", "2")])
def test_culling_keeps_every_texel_a_pixel_reads_deeper(kind, threads, monkeypatch):
    """Against the brute force; the readers of each band of image rows (one per worker thread) are merged."""
    monkeypatch.setenv("WARPSCATTER_THREADS", threads)
    scene, distance, rect, depth = _rectified(kind)
    before = depth.numpy().copy()
    readers = _readers(scene, distance, rect)
    fraction = cc.cull_unseen_casters(depth, rect, pre.pixel_coords(rect, scene.camera, distance), bias=0.0)
    after = depth.numpy()
    culled = (before < 1.0) & (after == 1.0)
    assert np.array_equal(after[~culled], before[~culled])  # nothing else moves
    assert fraction == pytest.approx(culled.mean())
    need = _needed(before, readers)
    # exact for hard visibility: no texel that shadows some pixel's look-up is emptied
    assert not (culled & need).any()
    # and culling is not idle: the depth binning keeps at most a few texels more than the brute force
    # (measured: culled 622 of 643 cullable of 1555 occupied texels (non-linear), 5232 of 5330 of 6977 (projective))
    cullable = (before < 1.0) & ~need
    assert culled.sum() >= 0.9 * cullable.sum() and cullable.sum() > 0.05 * (before < 1.0).sum()


def test_culling_bias_and_two_depth_maps():
    scene, distance, rect, depth = _rectified("nonlinear")
    before = depth.numpy().copy()
    readers = _readers(scene, distance, rect)
    bias = 1.0 / 64.0
    z2 = wp.array(np.where(before < 1.0, np.minimum(before + 0.3, 0.999), 1.0).astype(np.float32))
    sparse = SparseRectifiedDepth(z1=depth, z2=z2, w2=wp.full(depth.shape, 0.5, dtype=wp.float32))
    z2_before = z2.numpy().copy()
    coords = pre.pixel_coords(rect, scene.camera, distance)
    cc.cull_unseen_casters(sparse, rect, coords, bias=bias)
    for got, was in ((sparse.z1.numpy(), before), (sparse.z2.numpy(), z2_before)):
        culled = (was < 1.0) & (got == 1.0)
        # with a bias, a texel is kept only for readers deeper than depth + bias (bins round towards keeping)
        assert not (culled & _needed(was, readers, bias + 1.0 / cc.CULL_DEPTH_BINS)).any()
        assert culled.any()
    # the bias only ever culls more
    plain = wp.array(before)
    cc.cull_unseen_casters(plain, rect, coords, bias=0.0)
    assert ((plain.numpy() == 1.0) <= (sparse.z1.numpy() == 1.0)).all()
    with pytest.raises(ValueError, match="bias"):
        cc.cull_unseen_casters(plain, rect, coords, bias=-1.0)


def test_rays_ending_on_surfaces_facing_away_keep_their_texels_without_the_bias():
    # the tolerance is for a lit surface's own acne; a ray ending on a surface facing away from the light is shadowed
    # by that surface's depths just in front of its last texels, so its reads keep texels at any depth below its own
    scene, distance, rect, depth = _rectified("nonlinear")
    before = depth.numpy().copy()
    j0, j1, i1, z = _readers(scene, distance, rect)
    coords = pre.pixel_coords(rect, scene.camera, distance)
    away = np.random.default_rng(3).random(distance.shape) < 0.3
    bias = 1.0 / 16.0
    cc.cull_unseen_casters(depth, rect, coords, bias=bias, faces_away=wp.array(away.astype(np.int32)))
    culled = (before < 1.0) & (depth.numpy() == 1.0)
    a = away.ravel()
    need_away = _needed(before, (j0[a], j1[a], i1[a], z[a]))
    need_lit = _needed(before, (j0[~a], j1[~a], i1[~a], z[~a]), bias + 1.0 / cc.CULL_DEPTH_BINS)
    assert not (culled & (need_away | need_lit)).any()
    # the flag matters: with every reader facing the light the same bias culls texels the facing-away ones keep
    plain = wp.array(before)
    cc.cull_unseen_casters(plain, rect, coords, bias=bias)
    plain_culled = (before < 1.0) & (plain.numpy() == 1.0)
    assert (culled <= plain_culled).all() and (plain_culled & need_away).sum() > 100  # measured: 508 texels


def test_end_faces_away_from_the_light():
    # the window room under its sun (travelling +Z and down): the floor faces the light, the window wall (-Z) and
    # the ceiling face away; no surface: 0
    cfg = load_config(ROOT / "configs" / "window.yaml", ["camera.width=64", "camera.height=36"])
    scene = build_scene(cfg)
    g = gbuffer_raster(scene, DeviceGeometry(scene))
    away = cc.end_faces_away(scene.camera, g, light_params(scene.light)).numpy()
    n = g.normal.numpy().astype(np.float64)
    omega = np.asarray(scene.light.direction, np.float64)
    omega /= np.linalg.norm(omega)
    expected = (np.einsum("hwk,k->hw", n, omega) > 0.0) & (np.linalg.norm(n, axis=-1) > 0.5)
    assert np.array_equal(away.astype(bool), expected)
    assert 0.2 < expected.mean() < 0.8
    sky = cc.end_faces_away(scene.camera, g, light_params(scene.light)).numpy()[np.linalg.norm(n, axis=-1) < 0.5]
    assert not sky.any()


def test_window_room_creases_stay_dark():
    """Issue #13: moments4 / moments6 drew dotted lit lines along the window room's floor-wall creases (and a glow in
    its top-left corner). A ray ending at a crease reads the wall's depths just in front of its last texels; caster
    culling's tolerance (for a lit floor's own acne) emptied them. Rays ending on surfaces facing away from the light
    now read without it. Measured at 320x180 against the shadow-map marcher, pixels of the dark room more than 2
    pixels from the shafts brighter than 2 % of the lit pixels' mean: 306 before, 5 after (both methods); the dark
    room's mean (moments6 / moments4) 8.4e-4 / 1.2e-3 -> 1.4e-5 / 2.0e-5 of the lit pixels'."""
    def room(method, *overrides):
        cfg = load_config(ROOT / "configs" / "window.yaml", ["camera.width=320", "camera.height=180",
                                                             "render.surfaces.enabled=false",
                                                             f"render.scattering.method={method}", *overrides])
        return render_images(build_scene(cfg), cfg.render)[0]["scattering"].astype(np.float64)

    reference = room("raymarch", "render.scattering.visibility=shadow_map")
    dark = reference[..., 1] < 1e-3 * reference[..., 1].max()
    far = ~ndimage.binary_dilation(~dark, iterations=2)  # the prefiltered shafts' edges are a pixel softer
    lit_mean = reference[~dark].mean()
    assert far.sum() > 40000
    for method in ("moments6", "moments4"):
        v = room(method)[far].mean(-1) / lit_mean
        assert (v > 0.02).sum() <= 20
        assert v.mean() < 1e-4


def test_culling_removes_the_ground_error_of_moments6():
    # the canopy with its meadow casting (kept in the maps: skip_unseen_planes off): without culling the meadow's own
    # depths sit just behind the fragment depth of every ray that ends on it and six moments under-estimate the lower
    # image
    w, h, no_surf = 160, 90, {"enabled": False}
    res = {}
    for label, sc in (("exact", {"method": "raymarch", "visibility": "exact", "steps": 128}),
                      ("fourier", {"method": "fourier"}), ("moments6", {"method": "moments6"})):
        for cull in (False, True):
            cfg = bench_scene_config("canopy", w, h, surfaces=no_surf, scattering={
                **sc, "moments": {"storage_bits": 192}, "shadow_map": {"resolution": 256, "skip_unseen_planes": False},
                "prefiltered": {"caster_culling": cull}})
            images, stats = render_images(build_scene(cfg), cfg.render)
            res[label, cull] = images["scattering"]
            if label != "exact":
                assert stats["caster_culling"] == cull and ("culled_texel_fraction" in stats) == cull
                assert np.isfinite(images["scattering"]).all()
    err = {k: errors(v, res["exact", False])["rel_l1"] for k, v in res.items() if k[0] != "exact"}
    # measured: moments6 0.0590 -> 0.0346, fourier 0.0356 -> 0.0354
    assert err["moments6", True] < 0.7 * err["moments6", False]
    assert err["moments6", True] < 0.04
    assert err["fourier", True] < 1.05 * err["fourier", False]


def test_caster_culling_settings_errors():
    with pytest.raises(ValueError, match="caster_culling_bias"):
        PrefilteredSettings(caster_culling_bias=0.5)
    with pytest.raises(ConfigError, match=r"render\.scattering\.prefiltered\.caster_culling_bias"):
        bench_scene_config("canopy", 16, 9, scattering={"method": "moments6",
                                                        "prefiltered": {"caster_culling_bias": -0.1}})


def test_auto_culls_for_the_moment_methods_only():
    assert ScatteringSettings(method="moments6").culls_casters
    assert ScatteringSettings(method="moments4").culls_casters
    assert not ScatteringSettings(method="fourier").culls_casters
    assert ScatteringSettings(method="fourier", prefiltered={"caster_culling": True}).culls_casters
    assert not ScatteringSettings(method="moments6", prefiltered={"caster_culling": False}).culls_casters
    with pytest.raises(ValueError, match="caster_culling"):
        PrefilteredSettings(caster_culling="sometimes")
    for method, culls in (("fourier", False), ("moments6", True)):
        cfg = bench_scene_config("canopy", 32, 18, leaves=200, scattering={"method": method})
        stats = render_images(build_scene(cfg), cfg.render)[1]
        assert stats["caster_culling"] == culls and ("culled_texel_fraction" in stats) == culls
