"""Caster culling of the prefiltered methods' rectified maps (``render.scattering.prefiltered.caster_culling``)."""

import numpy as np
import pytest
import warp as wp

from warpscatter.bench import bench_scene_config, errors
from warpscatter.config import ConfigError
from warpscatter.gbuffer import gbuffer_raster
from warpscatter.pipeline import render_images
from warpscatter.scattering import caster_culling as cc
from warpscatter.scattering import prefiltered as pre
from warpscatter.scattering.rectification import build_rectification
from warpscatter.scattering.rectify_nonlinear import NonlinearRectification, SparseRectifiedDepth, resample_shadow_map
from warpscatter.scattering.rectify_projective import rasterize_rectified
from warpscatter.scattering.settings import PrefilteredSettings, ScatteringSettings
from warpscatter.scene import DeviceGeometry, build_scene
from warpscatter.shadows.shadow_map import render_shadow_map

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


@pytest.mark.parametrize("kind", ["nonlinear", "projective"])
def test_culling_keeps_every_texel_a_pixel_reads_deeper(kind):
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


def test_culling_removes_the_ground_error_of_moments6():
    # the canopy with its meadow casting (as configured): without culling the meadow's own depths sit just behind
    # the fragment depth of every ray that ends on it and six moments under-estimate the lower image
    w, h, no_surf = 160, 90, {"enabled": False}
    res = {}
    for label, sc in (("exact", {"method": "raymarch", "visibility": "exact", "steps": 128}),
                      ("fourier", {"method": "fourier"}), ("moments6", {"method": "moments6"})):
        for cull in (False, True):
            cfg = bench_scene_config("canopy", w, h, surfaces=no_surf, scattering={
                **sc, "moments": {"storage_bits": 192}, "shadow_map": {"resolution": 256},
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
