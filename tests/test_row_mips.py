"""Row mip-maps of the prefiltered textures (Peters 2017 D.5; warpscatter.scattering.prefiltered.row_mips): the levels
hold the row-pair means of the level before in every storage, the per-row look-up data follows, a pixel's level follows
its row footprint, the look-ups read the level's rows, caster culling keeps what the levels read, and renders with mips
stay within the measured bounds of the exact marcher, changing only pixels whose footprint spans more than a row."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

import warpscatter as ws
from warpscatter.errors import ConfigError
from warpscatter.scattering.prefiltered import filtered_lookups as fl
from warpscatter.scattering.prefiltered import prefix_sums as pf
from warpscatter.scattering.prefiltered import row_mips as rm
from warpscatter.scattering.prefiltered.textures import FOURIER_UNORM_LEVELS

ROWS, COLS = 16, 24


def _depth(rows=ROWS, cols=COLS, seed=0):
    return np.random.default_rng(seed).random((rows, cols)).astype(np.float32)


def _chain(texture, levels=8, tau=None, bounds=None):
    rows = texture.basis.shape[0] if isinstance(texture, pf.FilteredBasis) else texture.texels.shape[0]
    b = bounds if bounds is not None else wp.zeros((1, 1), dtype=wp.vec2)
    return rm.row_mip_chain(texture, tau if tau is not None else np.zeros(rows, np.float32), b, levels)


def _levels(values: np.ndarray, counts: list[int]) -> list[np.ndarray]:
    out, first = [], 0
    for n in counts:
        out.append(values[first:first + n])
        first += n
    return out


def test_level_rows_halve_while_even():
    assert rm.level_rows(1024, 8) == [1024, 512, 256, 128, 64, 32, 16, 8]
    assert rm.level_rows(1000, 8) == [1000, 500, 250, 125]  # a pair must be two adjacent slices
    assert rm.level_rows(16, 8) == [16, 8, 4, 2, 1]
    assert rm.level_rows(7, 8) == [7]
    assert rm.level_rows(1024, 1) == [1024]


@pytest.mark.parametrize("kind, bits, tol", [("fourier", 0, 1e-6), ("fourier", 8, None), ("moments4", 64, None),
                                             ("moments4", 128, 1e-6), ("moments6", 64, None), ("moments6", 96, None),
                                             ("moments6", 192, 1e-6)])
def test_levels_are_row_pair_means_in_the_texture_storage(kind, bits, tol):
    """Level L + 1 row k holds the mean of level L rows 2k, 2k + 1 (decoded), stored in level 0's format: float32
    exactly (to rounding), a fixed-point format to half a code of its own (re-rounded per level, as a GPU's mipmap
    generation of that format)."""
    depth = _depth()
    tau = np.linspace(0.0, 0.2, ROWS, dtype=np.float32)
    if kind == "fourier":
        tex = pf.prefilter_weighted(depth, 8, tau, bits=bits)
        half_code = 1.0 / float(FOURIER_UNORM_LEVELS)  # codes step 2 / 255 in [-1, 1]
    else:
        tex = pf.prefilter_moments(depth, 4 if kind == "moments4" else 6, tau, storage_bits=bits)
        half_code = {64: 0.5 / 1023.0 if kind == "moments6" else 0.5 / 65535.0, 96: 0.5 / 65535.0}.get(bits, 0.0)
    level0 = tex.values().numpy()
    chain = _chain(tex, tau=tau)
    counts = chain.level_rows
    assert counts == [16, 8, 4, 2, 1] and chain.levels == 5
    values = _levels(chain.texture.values().numpy(), counts)
    np.testing.assert_array_equal(values[0], level0)  # level 0 unchanged
    for lo, hi in zip(values[:-1], values[1:], strict=True):
        expected = 0.5 * (lo[0::2] + lo[1::2])
        err = np.abs(hi - expected).max()
        assert err <= (tol if tol is not None else half_code * 1.0001 + 1e-7), err
    taus = _levels(chain.optical_step, counts)
    np.testing.assert_allclose(taus[1], 0.5 * (tau[0::2] + tau[1::2]), rtol=1e-6)
    assert chain.texture.nbytes == pytest.approx(tex.nbytes * sum(counts) / ROWS)


def test_depth_bounds_of_a_merged_row_cover_its_pair():
    depth = _depth()
    bounds = pf.depth_bounds(depth)
    chain = _chain(pf.prefilter_moments(depth, 6, None), bounds=bounds)
    b = _levels(chain.bounds.numpy(), chain.level_rows)
    np.testing.assert_array_equal(b[0], bounds.numpy())
    np.testing.assert_array_equal(b[1][..., 0], np.minimum(b[0][0::2, :, 0], b[0][1::2, :, 0]))
    np.testing.assert_array_equal(b[1][..., 1], np.maximum(b[0][0::2, :, 1], b[0][1::2, :, 1]))


def test_one_level_and_split_textures():
    depth = _depth()
    tex = pf.prefilter_weighted(depth, 8, None)
    chain = _chain(tex, levels=1)
    assert chain.levels == 1 and chain.texture is tex  # no copy, no mips
    with pytest.raises(ValueError, match="splits 1"):
        _chain(pf.prefilter_weighted(depth, 8, None, splits=2), levels=2)
    with pytest.raises(ValueError, match="mip levels"):
        _chain(tex, levels=0)


@wp.kernel
def _levels_kernel(mips: rm.RowMips, coords: wp.array2d(dtype=wp.vec3), out: wp.array2d(dtype=wp.vec2)):
    j, i = wp.tid()
    out[j, i] = rm.pixel_mip_level(mips, coords, j, i)


def _pixel_levels(v: np.ndarray, rows: int, levels: int, wrap: int = 0) -> np.ndarray:
    coords = np.zeros((*v.shape, 3), np.float32)
    coords[..., 1] = v
    mips = rm.RowMips()
    mips.rows, mips.levels, mips.wrap = rows, levels, wrap
    out = wp.empty(v.shape, dtype=wp.vec2)
    wp.launch(_levels_kernel, v.shape, [mips, wp.array(coords, dtype=wp.vec3), out])
    return out.numpy()


def test_pixel_level_is_log2_of_the_row_footprint():
    """lambda = log2(rows spanned) + MIP_LEVEL_BIAS (-0.5), clamped to [0, levels - 1]: level and blend."""
    rows = 1024
    for spanned, level, blend in ((0.5, 0, 0.0), (1.4, 0, 0.0), (2.0, 0, 0.5), (3.0, 1, np.log2(1.5) - 0.5),
                                  (16.0, 3, 0.5), (1000.0, 7, 0.0)):
        v = 0.3 + np.arange(6, dtype=np.float64)[None, :] * spanned / rows + np.zeros((4, 1))
        lv = _pixel_levels(v.astype(np.float32), rows, 8)
        np.testing.assert_allclose(lv[1:-1, 1:-1, 0], level)
        np.testing.assert_allclose(lv[1:-1, 1:-1, 1], blend, atol=2e-3)
    # the larger image axis counts; a depth edge's jump on one side does not
    v = np.zeros((5, 5), np.float32) + 0.5
    v[:, 3:] += 0.25  # a jump between columns 2 and 3
    v += (np.arange(5, dtype=np.float32) * 4.0 / rows)[:, None]  # 4 rows per image row
    lv = _pixel_levels(v, rows, 8)
    np.testing.assert_allclose(lv[1:-1, 1:-1].sum(axis=-1), 1.5, atol=1e-4)
    # rows wrapping around the circle: v = 0.999 and 0.001 are 2 / 1000 apart
    v = np.array([[0.997, 0.999, 0.001, 0.003]], np.float32)
    np.testing.assert_allclose(_pixel_levels(v, 1000, 8, wrap=1)[0, 1:3].sum(axis=-1), 0.5, atol=1e-4)
    assert _pixel_levels(v, 1000, 1, wrap=1).max() == 0.0  # one level: always level 0


def test_lookup_of_a_level_reads_the_mean_of_its_rows():
    """Alternating lit (depth 1) and shadowed (depth 0) rows: level 0 reads one row's visibility, level 1 their
    mean, level 2 the same mean (a coarser average of the same stripes)."""
    depth = np.zeros((ROWS, COLS), np.float32)
    depth[0::2] = 1.0
    chain = _chain(pf.prefilter_weighted(depth, 16, None))
    mips = chain.params(wrap=False)

    @wp.kernel
    def lookup(tex: fl.FilteredBasisArrays, mips: rm.RowMips, v: float, out: wp.array(dtype=wp.float32)):
        k = wp.tid()
        out[k] = fl.prefiltered_visibility_split(tex, 0.999, v, 0.6, rm.level_window(mips, k))

    out = wp.zeros(3, dtype=wp.float32)
    wp.launch(lookup, 3, [chain.texture.arrays(), mips, (4 + 0.5) / ROWS, out])  # row 4: lit, rows 4, 5 average
    vis = out.numpy()
    assert vis[0] == pytest.approx(1.0, abs=0.05)
    assert vis[1] == pytest.approx(0.5, abs=0.05)
    assert vis[2] == pytest.approx(0.5, abs=0.05)


# ---- renders -------------------------------------------------------------------------------------------------

#: The sun low behind a slatted fence, in view: thin shafts converge on it, where a pixel spans several slices.
FENCE_SUN = {
    "scene": {"meshes": [
        {"procedural": "ground_plane", "params": {"size": 40}, "material": {"albedo": [0.4, 0.38, 0.35]}},
        {"procedural": "fence", "params": {"posts": 8, "slats": 4, "gap": 0.15, "height": 1.8},
         "material": {"albedo": [0.55, 0.42, 0.3]}}]},
    "camera": {"position": [0.6, 1.0, -6.0], "look_at": [0.0, 1.3, 0.0], "up": [0, 1, 0], "fov_y": 50,
               "width": 160, "height": 90, "near": 0.1, "far": 60},
    "light": {"type": "directional", "direction": [0.05, -0.12, -1.0], "irradiance": [3.0, 3.0, 3.0]},
    "medium": {"sigma_t": 0.1, "albedo": 1.0, "phase": {"type": "henyey_greenstein", "g": 0.5}},
    "render": {"scattering": {"method": "raymarch", "visibility": "exact", "steps": 256},
               "surfaces": {"enabled": False}},
    "output": {"aovs": ["scattering"]},
}


@pytest.fixture(scope="module")
def fence_exact():
    return ws.render(FENCE_SUN).images["scattering"]


def _rel_l1(a, b) -> float:
    return float(np.abs(a - b).sum() / np.abs(b).sum())


@pytest.mark.parametrize("method, bound", [("fourier", 0.030), ("moments6", 0.044)])
def test_render_with_mips_near_the_exact_marcher(fence_exact, method, bound):
    """Mips change only the pixels spanning more than 2^0.5 rows (the mip_level debug output says which: 14 % of
    them here), and the render stays within the measured bound of the exact marcher (160x90, 256^2 map: fourier 2.52
    -> 2.52 %, moments6 3.70 -> 3.70 % with 8 levels, caster culling off; bounds with margin). The center-sampled
    reference aliases like level 0, so mips do not lower this error; against a supersampled one they did not either
    (README)."""
    over = {"render.scattering.method": method, "output.aovs": ["scattering", "mip_level"],
            "render.scattering.shadow_map.resolution": 256,
            "render.scattering.prefiltered.caster_culling": False}  # culling keeps more texels for the levels
    plain = ws.render(FENCE_SUN, {**over, "render.scattering.prefiltered.mip_levels": 1})
    mipped = ws.render(FENCE_SUN, {**over, "render.scattering.prefiltered.mip_levels": 8})
    assert mipped.stats["mip_levels"] == 8 and plain.stats["mip_levels"] == 1
    level = mipped.images["mip_level"]
    assert level.max() > 2.0 and level.min() == 0.0 and np.all(plain.images["mip_level"] == 0.0)
    a, b = plain.images["scattering"], mipped.images["scattering"]
    same = level == 0.0
    np.testing.assert_array_equal(a[same], b[same])
    assert np.abs(a[~same] - b[~same]).max() > 0.0
    assert np.all(np.isfinite(b))
    err = _rel_l1(b, fence_exact)
    assert err < bound, err


def test_caster_culling_keeps_what_the_levels_read():
    """With mips a pixel reads its footprint's merged rows: caster culling keeps every texel those average
    (it empties fewer texels than for level 0 alone), and culling still changes no hard look-up much (culled vs not
    with 8 levels: the render moves as little as with one level)."""
    # the ground in the map (skip_unseen_planes off): its own texels are most of what culling empties
    over = {"render.scattering.method": "moments6", "render.scattering.shadow_map.resolution": 256,
            "render.scattering.shadow_map.skip_unseen_planes": False}
    frac = {}
    for lv in (1, 8):
        r = ws.render(FENCE_SUN, {**over, "render.scattering.prefiltered.mip_levels": lv,
                                  "render.scattering.prefiltered.caster_culling": True})
        frac[lv] = r.stats["culled_texel_fraction"]
    assert 0.0 < frac[8] < frac[1]


def test_config_errors_name_the_key():
    with pytest.raises(ConfigError, match="mip_levels"):
        ws.load_config(FENCE_SUN, {"render.scattering.prefiltered.mip_levels": 9})
    with pytest.raises(ConfigError, match="mip_levels"):
        ws.load_config(FENCE_SUN, {"render.scattering.method": "fourier",
                                   "render.scattering.prefiltered.mip_levels": 4,
                                   "render.scattering.prefiltered.splits": 2})


def test_cli_validate_names_the_mip_levels_and_the_key_out_of_range():
    from click.testing import CliRunner

    from warpscatter.cli.main import main

    ok = CliRunner().invoke(main, ["validate", "configs/spot_moments.yaml", "--set",
                                   "render.scattering.prefiltered.mip_levels=4"])
    assert ok.exit_code == 0 and "4 row mip levels" in ok.output
    bad = CliRunner().invoke(main, ["validate", "configs/colonnade_fourier.yaml", "--set",
                                    "render.scattering.prefiltered.mip_levels=12"])
    assert bad.exit_code != 0 and "render.scattering.prefiltered.mip_levels" in bad.output


SPOT = "configs/spot.yaml"
SPOT_SMALL = {"camera.width": 160, "camera.height": 90, "render.surfaces.enabled": False, "camera.supersample": 1,
              "render.scattering.method": "raymarch",  # the references; the fast method is set per case
              "render.scattering.shadow_map.resolution": 512}


def test_spot_mips_antialias_the_textured_light():
    """Under the stained-glass spot in view the rows converge on the light and the texture's detail is finer than
    the pixels: against a 3x3-supersampled exact render (the pixels' mean) fourier's error falls with 8 levels
    (measured 6.40 -> 5.47 %, ratio 0.85; at 320x180 with 1024^2 maps 4.28 -> 2.71 %, moments6 4.24 -> 2.68 %, where
    the exact render at the pixel centres is itself 3.86 % off), while against the pixel centres it grows (1.25 ->
    3.46 %). Only pixels at a level above 0 change (caster culling off)."""
    w, h, ss = 160, 90, 3
    big = ws.render(SPOT, {**SPOT_SMALL, "camera.width": w * ss, "camera.height": h * ss,
                           "render.scattering.steps": 256}).images["scattering"]
    mean = big.reshape(h, ss, w, ss, 3).mean(axis=(1, 3))
    over = {**SPOT_SMALL, "render.scattering.method": "fourier", "output.aovs": ["scattering", "mip_level"]}
    plain = ws.render(SPOT, over)
    mipped = ws.render(SPOT, {**over, "render.scattering.prefiltered.mip_levels": 8})
    assert mipped.stats["mip_levels"] == 8
    a, b, level = plain.images["scattering"], mipped.images["scattering"], mipped.images["mip_level"]
    assert np.all(np.isfinite(b)) and np.all(b >= 0.0)
    np.testing.assert_array_equal(a[level == 0.0], b[level == 0.0])
    assert _rel_l1(b, mean) < 0.92 * _rel_l1(a, mean)


@pytest.mark.parametrize("over", [
    {"render.scattering.method": "fourier", "render.scattering.prefiltered.rectification": "projective",
     "light.direction": [0.05, -0.5, 1.0]},
    {"render.scattering.method": "fourier", "render.scattering.fourier.storage_bits": 8},
    {"render.scattering.method": "moments4", "medium.sigma_t": [0.05, 0.1, 0.2]},
    {"render.scattering.method": "moments6", "render.scattering.moments.storage_bits": 64,
     "render.scattering.prefiltered.segments": 1},
])
def test_mips_in_every_pipeline_variant(over):
    """The projective map (rows without wrap), RGBA8 storage, a coloured medium (per-channel weights) and one segment
    read the levels too: finite, and within 5 % rel. L1 of the same render without mips (measured <= 0.5 %)."""
    base = {**over, "render.scattering.shadow_map.resolution": 256}
    a = ws.render(FENCE_SUN, {**base, "render.scattering.prefiltered.mip_levels": 1}).images["scattering"]
    res = ws.render(FENCE_SUN, {**base, "render.scattering.prefiltered.mip_levels": 6})
    b = res.images["scattering"]
    assert res.stats["mip_levels"] == 6 and np.all(np.isfinite(b)) and np.all(b >= 0.0)
    assert _rel_l1(b, a) < 0.05
