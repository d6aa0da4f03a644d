"""Ranges of every numeric config key (issue 17, defect 3): out-of-range numbers are refused before any work (exit
2 in the CLI with the key path, ConfigError in the API), every numeric field of every settings model states both
bounds in its JSON schema, and renders at the bounds stay finite."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import warpscatter
from warpscatter.cli.main import main
from warpscatter.config import Config, load_config
from warpscatter.errors import ConfigError
from warpscatter.schema import (
    MAX_COORD,
    MAX_DEPTH_RATIO,
    MAX_EMISSION,
    MAX_FOV_Y_DEG,
    MAX_HG_G,
    MAX_SEED,
    MAX_SIGMA_T,
    MIN_LENGTH,
)

ROOT = Path(__file__).resolve().parent.parent
QUICKSTART = ROOT / "configs" / "quickstart.yaml"
SPOT = ROOT / "configs" / "spot.yaml"
SMALL = {"camera.width": 16, "camera.height": 9, "render.scattering.steps": 8,
         "render.scattering.shadow_map.resolution": 64}


# ---- the issue's cases: exit 2, the key path, nothing written ------------------------------------


@pytest.mark.parametrize(("override", "key"), [
    ("medium.sigma_t=1e39", "medium.sigma_t: must be <= 10000"),
    ("camera.far=1e39", "camera.far: must be <= 1e+06"),
    ("light.irradiance=[1e39, 1e39, 1e39]", "light.irradiance: every component must be <= 1e+06"),
    ("light.direction=[1e200, 0, 0]", "light.direction: every component must lie in [-1e+06, 1e+06]"),
    ("camera.far=1e30", "camera.far: must be <= 1e+06"),
    ("camera.fov_y=179.9999", "camera.fov_y: must be <= 170"),
    ("light.irradiance=[1e30, 1e30, 1e30]", "light.irradiance: every component must be <= 1e+06"),
    ("light.irradiance=1e30", "light.irradiance: expected a list of 3 numbers"),
    ("camera.near=1e-6", "camera: far / near = 1e+08 must be <= 1e+07"),
    ("medium.phase.g=0.9999", "medium.phase.g: must be <= 0.99"),
    ("scene.meshes.0.params.size=1e39", "scene.meshes.0.params: parameter 'size': each value must be finite"),
    ("scene.meshes.1.transform.scale=1e9", "scene.meshes.1.transform.scale: must lie in [1e-06, 1e+06]"),
    ("scene.meshes.1.transform.rotate_deg=[0, 1e30, 0]", "scene.meshes.1.transform.rotate_deg: every component"),
    ("render.scattering.steps=100000000", "render.scattering.steps: must be <= 65536"),
    ("render.scattering.seed=-1", "render.scattering.seed: must be >= 0"),
    ("render.scattering.seed=4294967296", "render.scattering.seed: must be <= 2147483647"),
    ("output.exposure=1e300", "output.exposure: must be <= 1e+06"),
])
def test_out_of_range_number_exits_2_with_its_key_and_writes_nothing(tmp_path, override, key):
    out = tmp_path / "o"
    args = ["render", str(QUICKSTART), "-o", str(out), "--set", "camera.width=32", "--set", "camera.height=18",
            "--set", override]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 2, result.output
    assert key in result.stderr
    assert not out.exists()


def test_out_of_range_number_is_a_config_error_in_the_api(tmp_path):
    with pytest.raises(ConfigError, match=r"medium.sigma_t: must be <= 10000 \(got 1e\+39\)"):
        warpscatter.render(QUICKSTART, {"medium.sigma_t": 1e39}, out_dir=tmp_path / "o")
    assert not (tmp_path / "o").exists()


# ---- every numeric key has both bounds -----------------------------------------------------------

#: Numeric keys allowed without a bound on one side (none: seeds, frame numbers and counts are bounded too).
UNBOUNDED_ALLOWED: set[str] = set()


def _numeric_leaves() -> dict[str, dict]:
    """Every number / integer in Config's JSON schema: key path (``[]``: a list item, ``.0``: a tuple slot) -> its
    schema node."""
    schema = Config.model_json_schema()
    defs = schema.get("$defs", {})
    out: dict[str, dict] = {}

    def walk(node, path, seen):
        if "$ref" in node:
            name = node["$ref"].split("/")[-1]
            if name in seen:
                return
            node, seen = defs[name], seen | {name}
        if node.get("type") in ("number", "integer"):
            out.setdefault(path, node)
        for alt in node.get("anyOf", []) + node.get("oneOf", []) + node.get("allOf", []):
            walk(alt, path, seen)
        for i, item in enumerate(node.get("prefixItems", [])):
            walk(item, f"{path}.{i}", seen)
        if isinstance(node.get("items"), dict):
            walk(node["items"], f"{path}.[]", seen)
        if isinstance(node.get("additionalProperties"), dict):
            walk(node["additionalProperties"], f"{path}.{{}}", seen)
        for name, sub in node.get("properties", {}).items():
            walk(sub, f"{path}.{name}" if path else name, seen)

    walk(schema, "", frozenset())
    return out


NUMERIC = _numeric_leaves()


def test_the_walk_finds_the_numeric_keys():
    for key in ("camera.fov_y", "camera.far", "camera.position.0", "light.irradiance.2", "medium.sigma_t",
                "medium.sigma_t.1", "medium.phase.g", "render.scattering.steps", "render.scattering.seed",
                "render.lighting.seed", "scene.meshes.[].transform.scale", "animation.fps", "animation.frames.1",
                "render.scattering.shadow_map.resolution.0", "render.shadows.evsm_exponents.1"):
        assert key in NUMERIC, key
    assert len(NUMERIC) > 80


@pytest.mark.parametrize("key", sorted(NUMERIC))
def test_every_numeric_key_has_lower_and_upper_bounds(key):
    node = NUMERIC[key]
    if "enum" in node or "const" in node or key in UNBOUNDED_ALLOWED:
        return
    assert "minimum" in node or "exclusiveMinimum" in node, f"{key}: no lower bound ({node})"
    assert "maximum" in node or "exclusiveMaximum" in node, f"{key}: no upper bound ({node})"


def test_bundled_configs_are_within_the_ranges():
    for path in sorted((ROOT / "configs").glob("*.yaml")):
        load_config(path)


# ---- the checks that are not single bounds -------------------------------------------------------


def _problems(overrides, source=QUICKSTART) -> str:
    with pytest.raises(ConfigError) as info:
        load_config(source, overrides)
    return str(info.value)


def test_directions_normalise_without_overflow():
    c = load_config(QUICKSTART, {"light.direction": [1e-300, -1e-300, 0.0], "camera.up": [0.0, 1e-300, 0.0]})
    assert c.light.direction == pytest.approx((2 ** -0.5, -(2 ** -0.5), 0.0))
    assert c.camera.up == (0.0, 1.0, 0.0)
    c = load_config(QUICKSTART, {"light.direction": [MAX_COORD, 0.0, -MAX_COORD]})
    assert c.light.direction == pytest.approx((2 ** -0.5, 0.0, -(2 ** -0.5)))
    assert "light.direction: must be non-zero" in _problems({"light.direction": [0.0, 0.0, 0.0]})


def test_camera_distances():
    assert "position and look_at must be at least 1e-06 apart" in _problems(
        {"camera.position": [0.0, 1.0, 0.0], "camera.look_at": [0.0, 1.0, 1e-7]})
    c = load_config(QUICKSTART, {"camera.near": MAX_COORD / MAX_DEPTH_RATIO, "camera.far": MAX_COORD})
    assert c.camera.far == MAX_COORD  # exactly at both bounds
    load_config(QUICKSTART, {"camera.near": 1e-5})  # far 100: far / near = 1e7
    assert "camera.far: must be >= 1e-06" in _problems({"camera.near": 1e-8, "camera.far": 1e-7})


def test_light_ranges():
    assert "light.cone_deg: must be >= 0.01" in _problems({"light.cone_deg": 1e-9}, SPOT)
    assert "light.intensity: every component must be <= 1e+06" in _problems({"light.intensity": [1e7, 0, 0]}, SPOT)
    assert "light.position: every component must lie in [-1e+06, 1e+06]" in _problems(
        {"light.position": [0, 2e6, 0]}, SPOT)


def _lit(light: dict, **lighting) -> dict:
    return {"scene": {"meshes": [{"procedural": "ground_plane"}]},
            "camera": {"position": [0, 1, 5], "look_at": [0, 0, 0]}, "light": light,
            "render": {"lighting": {"method": "raytrace", **lighting}}}


def test_area_light_power_gives_a_bounded_radiance():
    area = {"type": "area", "position": [0, 2, 0], "u": [1, 0, 0], "v": [0, 0, 1]}
    Config.from_dict(_lit({**area, "power": [1e6, 1e6, 1e6]}))  # radiance 3.2e5
    with pytest.raises(ConfigError, match=r"light: power: gives the radiance .* more than 1e\+06"):
        Config.from_dict(_lit({**area, "u": [1e-3, 0, 0], "v": [0, 0, 1e-3], "power": [100, 100, 100]}))
    with pytest.raises(ConfigError, match=r"light.u: must be at least 1e-06 long"):
        Config.from_dict(_lit({**area, "u": [1e-9, 0, 0]}))
    with pytest.raises(ConfigError, match=r"are parallel"):  # a sliver the scene's AreaLight would refuse
        Config.from_dict(_lit({**area, "u": [1e6, 0, 0], "v": [0, 0, 1e-6]}))
    with pytest.raises(ConfigError, match=r"light: start and end must be at least 1e-06 apart"):
        Config.from_dict(_lit({"type": "linear", "start": [0, 2, 0], "end": [0, 2, 1e-9]}))


def test_lafortune_peak_is_bounded():
    mesh = {"procedural": "ground_plane", "material": {"brdf": {"type": "lafortune", "lobes": [
        {"coefficients": [-1.5, -1.5, 1.5], "exponent": 20}]}}}
    data = _lit({"type": "area", "position": [0, 2, 0], "u": [1, 0, 0], "v": [0, 0, 1]})
    Config.from_dict({**data, "scene": {"meshes": [mesh]}})
    mesh["material"]["brdf"]["lobes"][0]["exponent"] = 200  # 1.5^200 = 1.6e35
    with pytest.raises(ConfigError, match=r"lobes.0: the lobe's peak .* exceeds 1e\+06"):
        Config.from_dict({**data, "scene": {"meshes": [mesh]}})


def test_seeds_and_frames():
    c = load_config(QUICKSTART, {"render.scattering.seed": MAX_SEED})
    assert c.render.scattering.seed == MAX_SEED
    assert "animation.frames: each frame number must lie in [0, 1000000], got [1, 1000000000]" in _problems(
        {"animation.frames": [1, 10**9]})
    assert "animation.frames: must lie in [1, 100000], got 0" in _problems({"animation.frames": 0})
    assert "at most 100000 frames" in _problems({"animation.frames": [0, 200000]})
    assert "animation.fps: must be >= 0.01" in _problems({"animation.frames": 2, "animation.fps": 1e-9})


# ---- renders at the bounds are finite ------------------------------------------------------------

AT_BOUNDS = {
    "sigma_t": {"medium.sigma_t": MAX_SIGMA_T},
    "sigma_t rgb": {"medium.sigma_t": [MAX_SIGMA_T, 0.0, 1.0]},
    "far": {"camera.far": MAX_COORD, "camera.near": MAX_COORD / MAX_DEPTH_RATIO},
    "near": {"camera.near": MIN_LENGTH, "camera.far": 10.0},
    "fov_y": {"camera.fov_y": MAX_FOV_Y_DEG},
    "irradiance": {"light.irradiance": [MAX_EMISSION] * 3},
    "g": {"medium.phase.g": MAX_HG_G},
    "all": {"medium.sigma_t": MAX_SIGMA_T, "camera.far": MAX_COORD, "camera.fov_y": MAX_FOV_Y_DEG,
            "light.irradiance": [MAX_EMISSION] * 3, "medium.phase.g": MAX_HG_G},
    "thin, all": {"medium.sigma_t": 1e-3, "camera.far": MAX_COORD, "camera.fov_y": MAX_FOV_Y_DEG,
                  "light.irradiance": [MAX_EMISSION] * 3, "medium.phase.g": -MAX_HG_G},
    "far away": {"camera.position": [MAX_COORD, 1.7, -13.0], "camera.look_at": [MAX_COORD - 1.0, 2.6, 0.0],
                 "camera.far": MAX_COORD, "scene.meshes.0.params.size": MAX_COORD},
}


def _assert_finite(result):
    for name, image in result.images.items():
        assert np.all(np.isfinite(image)), f"{name} has non-finite pixels"
        assert np.min(image) >= 0.0, f"{name} has negative pixels"


@pytest.mark.parametrize("case", list(AT_BOUNDS))
def test_render_at_the_bounds_is_finite(case):
    _assert_finite(warpscatter.render(QUICKSTART, {**SMALL, "render.scattering.visibility": "shadow_map",
                                                   **AT_BOUNDS[case]}))


@pytest.mark.parametrize("method", ["fourier", "moments6", "epipolar"])
def test_every_method_at_the_bounds_is_finite(method):
    _assert_finite(warpscatter.render(QUICKSTART, {**SMALL, "render.scattering.method": method, **AT_BOUNDS["all"]}))


def test_spot_light_at_the_bounds_is_finite():
    _assert_finite(warpscatter.render(SPOT, {**SMALL, "light.intensity": [MAX_EMISSION] * 3, "light.cone_deg": 89.0,
                                             "medium.sigma_t": MAX_SIGMA_T, "medium.phase.g": MAX_HG_G}))
    _assert_finite(warpscatter.render(SPOT, {**SMALL, "light.cone_deg": 0.01, "camera.fov_y": 0.01}))


def test_union_alternatives_are_one_problem_at_their_key():
    # a key that takes a word or a bounded number names itself, not pydantic's union members
    # ("overestimation.literal['adaptive']: ...", "overestimation.constrained-float: ...")
    assert _problems({"render.scattering.moments.overestimation": 1.5}).splitlines()[1:] == [
        "  render.scattering.moments.overestimation: must be one of 'adaptive' or must be <= 1 (got 1.5) (from --set)"]
