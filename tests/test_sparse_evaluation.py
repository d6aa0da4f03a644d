"""The prefiltered look-up on a grid plus the pixels the grid cannot interpolate (scattering/sparse_evaluation.py)."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from warpscatter.bench import bench_scene_config
from warpscatter.pipeline import render_images
from warpscatter.scattering.sparse_evaluation import (
    COARSER_TOLERANCE,
    PIXELS_ALL,
    PIXELS_GRID,
    PIXELS_LISTED,
    PixelSet,
    evaluate_sparse,
    grid_size,
    pixel_set,
    set_pixel,
)
from warpscatter.scene import build_scene


@wp.kernel
def field_kernel(values: wp.array2d(dtype=wp.vec3), out: wp.array2d(dtype=wp.vec3),
                 visits: wp.array2d(dtype=wp.int32), pixels: PixelSet, offset: int):
    # a stand-in look-up: copies a known field at the pixels of the set and counts the visits
    a, b = wp.tid()
    j, i, listed = set_pixel(pixels, out.shape[0], out.shape[1], a + offset, b)
    if not listed:
        return
    out[j, i] = values[j, i]
    visits[j, i] = visits[j, i] + 1


def run_field(values: np.ndarray, distance: np.ndarray, stride: int, tolerance: float = 0.05,
              depth_tolerance: float = 0.04, end_zone: np.ndarray | None = None, levels: int = 1,
              scale: np.ndarray | None = None):
    h, w = distance.shape
    vals = wp.array(values.astype(np.float32), dtype=wp.vec3)
    out = wp.array(np.full((h, w, 3), np.nan, np.float32), dtype=wp.vec3)
    visits = wp.zeros((h, w), dtype=wp.int32)
    from warpscatter.runtime.parallel import launch_rows

    def launch(pixels, dim):
        launch_rows(field_kernel, dim, [vals, out, visits, pixels])

    zone = wp.array(end_zone.astype(np.int32)) if end_zone is not None else None
    sparse = evaluate_sparse(launch, wp.array(distance.astype(np.float32)), out, stride, tolerance, depth_tolerance,
                             end_zone=zone, levels=levels,
                             scale=wp.array(scale.astype(np.float32)) if scale is not None else None)
    return out.numpy(), visits.numpy(), sparse


def smooth_field(h, w):
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    base = 1.0 + 0.002 * x + 0.003 * y  # linear: bilinear interpolation is exact
    return np.stack([base, 0.5 * base, 0.25 * base], -1)


@pytest.mark.parametrize("h,w,stride", [(37, 53, 2), (36, 52, 2), (40, 41, 3), (17, 9, 4)])
def test_grid_nodes_and_listed_pixels_are_evaluated_once_and_the_rest_interpolated(h, w, stride):
    values = smooth_field(h, w)
    distance = np.full((h, w), 10.0)
    # a step in the field (a shaft's edge) and a nearer object (a silhouette): both need direct evaluation
    values[:, 2 * w // 3:] *= 1.5
    distance[h // 3:h // 2, w // 4:w // 3] = 5.0
    out, visits, sparse = run_field(values, distance, stride)
    assert visits.max() == 1  # nothing is evaluated twice
    ys = np.minimum(np.arange(grid_size(h, stride)) * stride, h - 1)
    xs = np.minimum(np.arange(grid_size(w, stride)) * stride, w - 1)
    assert (visits[np.ix_(ys, xs)] == 1).all()  # every grid node, the last row and column included
    evaluated = visits == 1
    np.testing.assert_array_equal(sparse.mask() == 1, evaluated)
    assert sparse.evaluated == evaluated.sum()
    np.testing.assert_array_equal(out[evaluated], values.astype(np.float32)[evaluated])
    # interpolated pixels: the bilinear interpolation of a linear field (float32 rounding only)
    np.testing.assert_allclose(out[~evaluated], values[~evaluated], rtol=1e-5)
    # which pixels: exactly the grid nodes and the pixels the rule lists (numpy's version of it)
    np.testing.assert_array_equal(evaluated, reference_mask(values, distance, stride, 0.05, 0.04))
    assert evaluated[:, 2 * w // 3 - 1:2 * w // 3 + 1].any(axis=1).all()  # the step: evaluated in every row
    smooth = (slice(h // 2 + stride, h), slice(0, 2 * w // 3 - stride - 1))  # away from the step and the object
    nodes = np.zeros((h, w), bool)
    nodes[np.ix_(ys, xs)] = True
    np.testing.assert_array_equal(evaluated[smooth], nodes[smooth])


def reference_mask(values, distance, stride, tolerance, depth_tolerance):
    """The pixels evaluate_sparse evaluates, in numpy: grid nodes, and pixels whose cell's four corners differ in
    distance by more than depth_tolerance (relative) or in radiance (largest channel) by more than tolerance times the
    largest corner."""
    h, w = distance.shape

    def span(x, size):
        x0 = (x // stride) * stride
        return x0, np.minimum(x0 + stride, size - 1), (x == x0) | (x == size - 1)

    y0, y1, ny = span(np.arange(h), h)
    x0, x1, nx = span(np.arange(w), w)
    lum = values.astype(np.float32).max(-1)
    far = np.zeros((h, w), bool)
    hi = np.full((h, w), -np.inf)
    lo = np.full((h, w), np.inf)
    for yy in (y0, y1):
        for xx in (x0, x1):
            far |= np.abs(distance[yy][:, xx] - distance) > depth_tolerance * distance
            hi = np.maximum(hi, lum[yy][:, xx])
            lo = np.minimum(lo, lum[yy][:, xx])
    node = ny[:, None] & nx[None, :]
    return node | far | (hi - lo > tolerance * hi)


def emulate_levels(values, distance, stride, levels, tolerance, depth_tolerance):
    """evaluate_sparse with levels, in numpy: the look-up (a copy of ``values``) on the coarsest grid's nodes, then
    per level the finer grid's new nodes (the last level: every other pixel) interpolated in their coarse cell or, where
    the cell does not agree, evaluated. Returns (image, evaluated mask)."""
    h, w = distance.shape
    v = values.astype(np.float32)
    strides = [stride * 2 ** k for k in reversed(range(levels))]

    def nodes(size, step):
        return np.minimum(np.arange(grid_size(size, step)) * step, size - 1)

    def on_grid(step):
        m = np.zeros((h, w), bool)
        m[np.ix_(nodes(h, step), nodes(w, step))] = True
        return m

    out = np.full_like(v, np.nan)
    evaluated = on_grid(strides[0])
    out[evaluated] = v[evaluated]
    for n, (coarse, fine) in enumerate(zip(strides, [*strides[1:], 1], strict=True)):
        level_tolerance = tolerance * COARSER_TOLERANCE ** (levels - 1 - n)  # halved per coarser level
        jj, ii = np.nonzero(on_grid(fine) & ~on_grid(coarse))
        y0, x0 = (jj // coarse) * coarse, (ii // coarse) * coarse
        y1, x1 = np.minimum(y0 + coarse, h - 1), np.minimum(x0 + coarse, w - 1)
        fy = np.where(y1 > y0, (jj - y0) / np.maximum(y1 - y0, 1), 0.0)[:, None]
        fx = np.where(x1 > x0, (ii - x0) / np.maximum(x1 - x0, 1), 0.0)[:, None]
        corners = [(y0, x0), (y0, x1), (y1, x0), (y1, x1)]
        lum = np.stack([out[y, x].max(-1) for y, x in corners])
        depth = distance[jj, ii]
        agree = lum.max(0) - lum.min(0) <= level_tolerance * lum.max(0)
        for y, x in corners:
            agree &= np.abs(distance[y, x] - depth) <= depth_tolerance * depth
        blend = ((out[y0, x0] * (1 - fx) + out[y0, x1] * fx) * (1 - fy)
                 + (out[y1, x0] * (1 - fx) + out[y1, x1] * fx) * fy)
        out[jj, ii] = np.where(agree[:, None], blend, v[jj, ii])
        evaluated[jj[~agree], ii[~agree]] = True
    return out, evaluated


@pytest.mark.parametrize("h,w,stride,levels", [(37, 53, 2, 2), (36, 52, 2, 2), (41, 45, 1, 3), (45, 61, 2, 3),
                                               (17, 9, 3, 2), (33, 33, 2, 1)])
def test_levels_fill_the_grid_coarse_to_fine(h, w, stride, levels):
    """Every pixel is evaluated at most once, the pixels evaluated are exactly the emulation's (the coarsest grid and
    what each level's cells cannot interpolate) and the rest take its interpolation; a smooth field costs fewer
    look-ups than with one grid, and levels 1 is the one-grid rule."""
    values = smooth_field(h, w)
    distance = np.full((h, w), 10.0)
    values[:, 2 * w // 3:] *= 1.5  # a shaft's edge
    distance[h // 3:h // 2, w // 4:w // 3] = 5.0  # a silhouette
    out, visits, sparse = run_field(values, distance, stride, levels=levels)
    if stride == 1:  # every pixel, whatever the levels
        assert (visits == 1).all() and sparse.passes == []
        return
    assert visits.max() == 1
    want, want_evaluated = emulate_levels(values, distance, stride, levels, 0.05, 0.04)
    evaluated = visits == 1
    np.testing.assert_array_equal(evaluated, want_evaluated)
    np.testing.assert_array_equal(sparse.mask() == 1, evaluated)
    assert sparse.evaluated == evaluated.sum()
    assert sum(ps.listed.sum() for ps in sparse.passes) == evaluated.sum() - sparse.grid_nodes
    np.testing.assert_array_equal(out[evaluated], values.astype(np.float32)[evaluated])
    np.testing.assert_allclose(out, want, rtol=1e-5)
    np.testing.assert_allclose(out, values, rtol=1e-5)  # a linear field between the edges: exact
    assert sparse.coarse_stride == stride * 2 ** (levels - 1)
    if levels == 1:
        np.testing.assert_array_equal(evaluated, reference_mask(values, distance, stride, 0.05, 0.04))
    else:
        _, one_grid, _ = run_field(values, distance, stride)
        assert evaluated.sum() < (one_grid == 1).sum()


def test_a_shaft_the_coarse_grid_misses_is_found_by_no_level():
    """What levels cost: a feature between the coarsest grid's nodes that no node sees is interpolated over (the
    one-grid rule at that spacing finds it; documented with evaluate_levels)."""
    h, w = 33, 33
    values = smooth_field(h, w)
    values[:, 9:11] *= 2.0  # a 2-pixel shaft between the stride-8 nodes 8 and 16, on stride-2 nodes 10
    _, visits, _ = run_field(values, np.full((h, w), 10.0), 2, levels=3)
    assert visits[:, 9:11].sum() == 0
    _, visits_one, _ = run_field(values, np.full((h, w), 10.0), 2)
    assert visits_one[:, 10].all()


@pytest.mark.parametrize("levels", [1, 2, 3])
def test_a_known_factor_is_interpolated_apart_on_the_coarser_levels(levels):
    """A radiance that is a smooth field times a known peaked factor (a phase function's forward peak): given as
    ``scale``, the coarser levels test and interpolate the smooth field, so fewer pixels are looked up and the image
    is closer to the field than without it; the last level (2-pixel cells) and one level read the radiance as it is."""
    h, w = 41, 57
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    peak = 1.0 + 3.0 / (1.0 + ((x - 30.0) ** 2 + (y - 20.0) ** 2) / 40.0)
    values = smooth_field(h, w) * peak[..., None]
    distance = np.full((h, w), 10.0)
    out_raw, visits_raw, _ = run_field(values, distance, 2, tolerance=0.1, levels=levels)
    out, visits, _ = run_field(values, distance, 2, tolerance=0.1, levels=levels, scale=peak)
    assert visits.max() == 1
    if levels == 1:
        np.testing.assert_array_equal(out, out_raw)
        np.testing.assert_array_equal(visits, visits_raw)
        return
    assert visits.sum() < visits_raw.sum()
    nodes = np.ix_(np.minimum(np.arange(grid_size(h, 2)) * 2, h - 1), np.minimum(np.arange(grid_size(w, 2)) * 2, w - 1))
    np.testing.assert_allclose(out[nodes], values[nodes], rtol=2e-5)  # the coarser levels' nodes: exact
    assert np.abs(out_raw[nodes] / values[nodes] - 1.0).max() > 1e-3  # without the factor the peak is flattened
    assert np.abs(out / values - 1.0).mean() < np.abs(out_raw / values - 1.0).mean()


def test_stride_one_evaluates_every_pixel_in_one_launch():
    values = smooth_field(20, 30)
    out, visits, sparse = run_field(values, np.full((20, 30), 3.0), 1)
    assert (visits == 1).all() and sparse.evaluated_fraction == 1.0 and sparse.passes == []
    np.testing.assert_array_equal(out, values.astype(np.float32))


def test_tolerances_decide_what_is_interpolated():
    h, w = 21, 21
    values = smooth_field(h, w)
    values[10, 10] *= 1.04  # a grid node 4 % above its neighbours
    distance = np.full((h, w), 10.0)
    distance[11, 11] = 10.3  # a pixel 3 % farther than its cell's corners
    _, loose, _ = run_field(values, distance, 2, tolerance=0.05, depth_tolerance=0.04)
    _, tight, _ = run_field(values, distance, 2, tolerance=0.03, depth_tolerance=0.02)
    around = (slice(9, 12), slice(9, 12))
    assert loose[9, 9] == 0 and loose[11, 11] == 0  # within both tolerances: interpolated
    assert tight[around].sum() == 9  # the node's cells and the far pixel: all evaluated
    _, none, _ = run_field(values, distance, 2, tolerance=0.0, depth_tolerance=1.0)
    assert none[around].all()  # tolerance 0 interpolates only cells of equal corners


def test_corners_left_to_the_marcher_are_not_interpolated():
    h, w = 15, 15
    zone = np.zeros((h, w), np.int32)
    zone[6, 6] = 1  # a grid node the look-up left to the marcher
    _, visits, _ = run_field(smooth_field(h, w), np.full((h, w), 10.0), 2, end_zone=zone)
    assert visits[5:8, 5:8].all()  # every pixel of its four cells
    assert visits[1, 1] == 0


def test_pixel_set_modes_map_launch_indices():
    @wp.kernel
    def where_kernel(ps: PixelSet, h: int, w: int, out: wp.array2d(dtype=wp.vec3i)):
        a, b = wp.tid()
        j, i, listed = set_pixel(ps, h, w, a, b)
        out[a, b] = wp.vec3i(j, i, wp.where(listed, 1, 0))

    listed = wp.array(np.array([[0, 4], [0, 7], [5, 1], [8, 9]], np.int32), dtype=wp.vec2i)
    got = {}
    for mode, dim, ps in ((PIXELS_ALL, (2, 3), pixel_set(PIXELS_ALL)), (PIXELS_GRID, (3, 3), pixel_set(PIXELS_GRID, 4)),
                          (PIXELS_LISTED, (2, 3), pixel_set(PIXELS_LISTED, 3, listed, 4))):
        out = wp.zeros(dim, dtype=wp.vec3i)
        wp.launch(where_kernel, dim, [ps, 9, 10, out])
        got[mode] = out.numpy()
    assert got[PIXELS_ALL][1, 2].tolist() == [1, 2, 1]
    assert got[PIXELS_GRID][:, :, 0].T.tolist()[0] == [0, 4, 8] and got[PIXELS_GRID][0, :, 1].tolist() == [0, 4, 8]
    assert got[PIXELS_GRID][2, 2].tolist() == [8, 8, 1]  # 9 rows: the third node is the last row (clamped)
    # 3 listed pixels per launch row: the first row holds the first three, the second the fourth and two idle threads
    assert got[PIXELS_LISTED][0].tolist() == [[0, 4, 1], [0, 7, 1], [5, 1, 1]]
    assert got[PIXELS_LISTED][1].tolist() == [[8, 9, 1], [0, 0, 0], [0, 0, 0]]


# ---- in a render ---------------------------------------------------------------------------------

# (scene, method, levels, largest rel. L1 between stride 2 and every pixel, largest evaluated share): measured at
# 320x180 / 1024^2 with stride 2 and the default tolerances: one level, the window room moments6 0.00049 (evaluated
# 0.397), colonnade fourier 0.00004 (0.790), the spot fence fourier 0.00007 (0.666); two levels 0.00052 (0.278) and
# 0.00005 (0.754); bounds about 1.5x those (at 320x180 most grid cells hold an edge; at 1920x1080 the share is
# 0.28-0.35 with one level, 0.16-0.25 with two).
RENDER_CASES = [("window", "moments6", 1, 0.00075, 0.45), ("colonnade", "fourier", 1, 0.0001, 0.85),
                ("spot_fence", "fourier", 1, 0.0001, 0.72), ("window", "moments6", 2, 0.0008, 0.32),
                ("colonnade", "fourier", 2, 0.0001, 0.8)]


@pytest.mark.parametrize("scene,method,levels,bound,share", RENDER_CASES)
def test_a_render_evaluates_fewer_pixels_and_keeps_them_exact(scene, method, levels, bound, share):
    images = {}
    for stride in (1, 2):
        cfg = bench_scene_config(scene, 320, 180, surfaces={"enabled": False},
                                 scattering={"method": method, "shadow_map": {"resolution": 1024},
                                             "prefiltered": {"evaluate_stride": stride, "evaluate_levels": levels}})
        cfg.output.aovs = [*cfg.output.aovs, "evaluated_pixels"]
        imgs, stats = render_images(build_scene(cfg), cfg.render, aovs=cfg.output.aovs)
        images[stride] = (np.asarray(imgs["scattering"], np.float64), imgs.get("evaluated_pixels"), stats)
    full, _, stats1 = images[1]
    sparse, mask, stats2 = images[2]
    assert stats1["evaluated_fraction"] == 1.0 and stats2["evaluate_stride"] == 2
    assert stats2["evaluate_levels"] == levels and stats2["evaluated_fraction"] < share
    assert np.isfinite(sparse).all()
    evaluated = np.asarray(mask) == 1
    assert abs(evaluated.mean() - stats2["evaluated_fraction"]) < 1e-3
    np.testing.assert_array_equal(sparse[evaluated], full[evaluated])  # the look-up itself is unchanged
    rel = np.abs(sparse - full).sum() / np.abs(full).sum()
    assert 0.0 < rel < bound


def test_evaluate_levels_auto_follows_the_image_height_and_the_light():
    from warpscatter.scattering.settings import EVALUATE_LEVELS_AUTO_ROWS, PrefilteredSettings

    auto = PrefilteredSettings()
    assert auto.evaluate_levels == "auto"
    assert auto.evaluate_levels_for(EVALUATE_LEVELS_AUTO_ROWS) == 2
    assert auto.evaluate_levels_for(EVALUATE_LEVELS_AUTO_ROWS - 1) == 1
    assert auto.evaluate_levels_for(2160, spot=True) == 1
    assert PrefilteredSettings(evaluate_levels=3).evaluate_levels_for(90, spot=True) == 3


def test_the_cli_writes_the_evaluated_pixels_and_other_methods_refuse_them(tmp_path):
    """``output.aovs: [evaluated_pixels]`` writes NAME.evaluated_pixels.exr (1: looked up, 0: interpolated) for the
    prefiltered methods; epipolar refuses it by name; an evaluate_stride out of range is refused by key."""
    from click.testing import CliRunner

    from warpscatter.cli.main import main
    from warpscatter.config import load_config
    from warpscatter.errors import ConfigError
    from warpscatter.io.resources import bundled_config

    config = bundled_config("canopy_moments")
    over = ["camera.width=160", "camera.height=90", "render.scattering.shadow_map.resolution=256",
            "output.aovs=[color,evaluated_pixels]"]
    out = tmp_path / "out"
    result = CliRunner().invoke(main, ["render", str(config), "-o", str(out), *[a for o in over for a in ("--set", o)]])
    assert result.exit_code == 0, result.output
    assert (out / "canopy_moments.evaluated_pixels.exr").is_file()
    with pytest.raises(ConfigError, match="evaluated_pixels is made by"):
        load_config(config, ["render.scattering.method=epipolar", "output.aovs=[color, evaluated_pixels]"])
    with pytest.raises(ConfigError, match="render.scattering.prefiltered.evaluate_stride"):
        load_config(config, ["render.scattering.prefiltered.evaluate_stride=0"])
    with pytest.raises(ConfigError, match="render.scattering.prefiltered.evaluate_levels"):
        load_config(config, ["render.scattering.prefiltered.evaluate_levels=5"])


@pytest.mark.parametrize("scene", ["colonnade", "spot_fence"])
def test_coordinates_at_the_evaluated_pixels_only_give_the_same_image(scene):
    """Without caster culling (fourier), row mip levels or a debug output that shows them, the rectified coordinates
    are computed by the look-up's own launches at the pixels they evaluate: the image is the one computed with every
    pixel's coordinates (asked for by the ``rectified`` debug output)."""
    cfg = bench_scene_config(scene, 160, 90, surfaces={"enabled": False},
                             scattering={"method": "fourier", "shadow_map": {"resolution": 256}})
    built = build_scene(cfg)
    lazy, _ = render_images(built, cfg.render)
    full, _ = render_images(built, cfg.render, aovs=["rectified"])
    np.testing.assert_array_equal(lazy["scattering"], full["scattering"])
    assert full["rectified"].shape == (90, 160, 3) and np.isfinite(full["rectified"]).all()
