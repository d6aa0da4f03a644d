"""What a user sees first: camera anti-aliasing (``camera.supersample``), the sky fill on surfaces
(``render.surfaces.ambient``), the ways of giving a sun, the warning of a dark render, and bundled configs that render
with the method they showcase."""

from pathlib import Path

import numpy as np
import pytest

import warpscatter
from warpscatter.config import sun_direction
from warpscatter.errors import ConfigError
from warpscatter.io.metrics import errors
from warpscatter.io.resources import bundled_configs
from warpscatter.pipeline.supersample import box_filter

ROOT = Path(__file__).resolve().parent.parent
QUICKSTART = ROOT / "configs" / "quickstart.yaml"
SMALL = {"camera.width": 48, "camera.height": 27}


# ---- anti-aliasing ---------------------------------------------------------------------------------------------


def test_box_filter_averages_blocks_and_keeps_other_sizes():
    frame = np.arange(6 * 4 * 3, dtype=np.float32).reshape(6, 4, 3)
    other = np.ones((8, 8), np.float32)  # a light-space debug image: not the frame's size
    out = box_filter({"color": frame, "depth": frame[..., 0], "map": other}, 2, (6, 4))
    assert out["color"].shape == (3, 2, 3) and out["depth"].shape == (3, 2)
    np.testing.assert_allclose(out["color"][1, 0], frame[2:4, 0:2].mean(axis=(0, 1)))
    assert out["map"] is other


@pytest.mark.parametrize("method", ["raymarch", "fourier"])
def test_supersampled_render_is_the_block_mean_of_the_larger_frame(method):
    # supersample 2 at 48x27 is exactly the 96x54 render box-filtered: every method renders the larger frame as it is
    over = {**SMALL, "render.scattering.method": method, "render.scattering.jitter": "fixed"}
    aa = warpscatter.render(QUICKSTART, {**over, "camera.supersample": 2})
    big = warpscatter.render(QUICKSTART, {**over, "camera.supersample": 1, "camera.width": 96, "camera.height": 54})
    assert aa.images["color"].shape == (27, 48, 3) and aa.stats["supersample"] == 2
    assert aa.stats["resolution"] == [48, 27]
    for name in ("color", "scattering", "surface", "depth"):
        want = box_filter({name: big.images[name]}, 2, (54, 96))[name]
        np.testing.assert_allclose(aa.images[name], want, rtol=1e-6, atol=1e-7)


def test_supersample_limits_the_rendered_size():
    with pytest.raises(ConfigError, match="supersample"):
        warpscatter.load_config(QUICKSTART, {"camera.width": 4000, "camera.supersample": 8})


# ---- the sky fill --------------------------------------------------------------------------------------------


def test_ambient_adds_albedo_times_sky_seen_through_the_medium():
    over = {**SMALL, "camera.supersample": 1}
    plain = warpscatter.render(QUICKSTART, {**over, "render.surfaces.ambient": [0, 0, 0]})
    sky = (0.1, 0.2, 0.3)
    lit = warpscatter.render(QUICKSTART, {**over, "render.surfaces.ambient": list(sky)})
    config = lit.config
    # the ground (mesh 0) where the G-buffer hits it: albedo * sky * exp(-sigma_t s) more, nothing else changes
    depth = plain.images["depth"]
    added = lit.images["surface"] - plain.images["surface"]
    np.testing.assert_array_equal(lit.images["scattering"], plain.images["scattering"])
    np.testing.assert_allclose(lit.images["color"] - plain.images["color"], added, atol=1e-6)
    albedos = np.array([m.material.albedo for m in config.scene.meshes])
    expected = albedos[:, None, None, :] * np.array(sky) * np.exp(-config.medium.sigma_t * depth)[None, ..., None]
    # every surface pixel got one material's fill; the sky (no hit) got none
    hit = plain.images["depth"] < 0.99 * config.camera.far / 1.0
    match = np.isclose(added[None], expected, rtol=1e-4, atol=1e-6).all(axis=-1).any(axis=0)
    assert match[hit].mean() > 0.99
    assert (lit.images["surface"][hit] > 0).all(axis=-1).mean() > 0.99  # no pure-black wall left


def test_ambient_is_refused_by_the_lighting_methods():
    with pytest.raises(ConfigError, match="render.surfaces.ambient"):
        warpscatter.load_config(ROOT / "configs" / "csm_gate.yaml", {"render.surfaces.ambient": [0.1, 0.1, 0.1]})


# ---- the sun, three ways ------------------------------------------------------------------------------------------


def test_sun_forms_give_the_same_direction():
    base = warpscatter.load_config(QUICKSTART)
    d = np.array(base.light.direction)
    toward = warpscatter.load_config(QUICKSTART, {"light.toward_sun": (-d).tolist()})
    np.testing.assert_allclose(toward.light.direction, d, atol=1e-12)
    elevation = np.degrees(np.arcsin(-d[1]))
    azimuth = np.degrees(np.arctan2(-d[0], -d[2]))
    sky = warpscatter.load_config(QUICKSTART, {"light.azimuth_deg": azimuth, "light.elevation_deg": elevation})
    np.testing.assert_allclose(sky.light.direction, d, atol=1e-12)
    # the resolved config holds the direction only, and validates again as it is
    assert sky.light.toward_sun is None and sky.light.azimuth_deg is None and sky.revalidated().light == sky.light


def test_sun_direction_convention():
    np.testing.assert_allclose(sun_direction(0.0, 0.0), [0, 0, 1], atol=1e-15)
    np.testing.assert_allclose(sun_direction(90.0, 0.0), [1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(sun_direction(0.0, 90.0), [0, 1, 0], atol=1e-15)


@pytest.mark.parametrize(("data", "message"), [
    ({"direction": [0, -1, 0], "toward_sun": [0, 1, 0]}, "got direction and toward_sun"),
    ({}, "got none"),
    ({"azimuth_deg": 10}, "elevation_deg is missing"),
])
def test_sun_forms_are_exclusive(data, message):
    config = {"scene": {"meshes": [{"procedural": "ground_plane"}]},
              "camera": {"position": [0, 1, 5], "look_at": [0, 0, 0]},
              "light": {"type": "directional", **data}}
    with pytest.raises(ConfigError, match=message) as err:
        warpscatter.load_config(config)
    assert "light" in str(err.value)


def test_an_override_replaces_the_configs_own_sun_form():
    # --set light.azimuth_deg/elevation_deg on a config that gives light.direction: the new form wins
    config = warpscatter.load_config(QUICKSTART, ["light.azimuth_deg=180", "light.elevation_deg=30"])
    np.testing.assert_allclose(config.light.direction, -np.array(sun_direction(180.0, 30.0)), atol=1e-12)


# ---- a dark render says why ------------------------------------------------------------------------------------


def test_sun_below_the_horizon_warns_and_names_toward_sun():
    d = warpscatter.load_config(QUICKSTART).light.direction
    result = warpscatter.render(QUICKSTART, {**SMALL, "light.direction": [-c for c in d]})  # the mistake of #50
    assert len(result.warnings) == 1 and "light.toward_sun" in result.warnings[0]
    assert result.stats["warnings"] == result.warnings


def test_a_lit_render_has_no_warning():
    assert warpscatter.render(QUICKSTART, SMALL).warnings == []


def test_surfaces_off_and_no_scattering_warns():
    result = warpscatter.render(QUICKSTART, {**SMALL, "render.surfaces.enabled": False, "medium.sigma_t": 0.0})
    assert result.warnings and "render.surfaces.enabled is false" in result.warnings[0]


# ---- bundled configs show their technique -------------------------------------------------------------------------


def test_bundled_configs_render_their_showcased_method_anti_aliased():
    for path in bundled_configs():
        config = warpscatter.load_config(path)
        method = config.render.lighting.method or config.render.scattering.method
        assert method != "raymarch", f"{path.name} defaults to the reference marcher, not the technique it shows"
        assert config.camera.supersample >= 2, f"{path.name} renders stair-steps"
        if config.render.lighting.method is None:
            assert any(config.render.surfaces.ambient), f"{path.name}: surfaces in shadow are pure black"


def test_quickstart_against_the_anti_aliased_exact_reference():
    # Issue #50's bar at a sixth of the size: the quickstart (fourier, 2x2 supersampling) against the exact
    # reference (ray-cast visibility) with 4x4 rays a pixel, colour rel. L1: measured 1.64 % at 160x90 (1.46 % at
    # 240x135, 1.05 % at the bundled 960x540: docs/benchmarks.md); bound 2 %, the issue's.
    over = {"camera.width": 160, "camera.height": 90}
    fast = warpscatter.render(QUICKSTART, over)
    reference = warpscatter.render(QUICKSTART, {**over, "render.scattering.method": "raymarch",
                                                "camera.supersample": 4})
    assert errors(fast.images["color"], reference.images["color"])["rel_l1"] < 0.02
