"""Property-based fuzzing of whole renders (issue 17): random configs around the bundled ones through the Python API.

Each example takes a bundled config and overrides its camera (position, look-at, field of view, clip planes, size
16-64), its light (direction and irradiance, or a spot's position, axis, cone and intensity, or an environment / area
/ linear light of the Monte-Carlo methods), its medium (extinction, grey or RGB, albedo, phase), a mesh's opacity,
albedo and transform, the method, the surface shadows, steps (4-16), the shadow-map resolution (64-256) and some of
the techniques' own keys, with in-range, boundary, degenerate (the camera looking along ``up``, ``look_at ==
position``, the light straight behind or into the camera, a spot light at the camera, no medium, no light, no caster)
and, in a quarter of the examples, out-of-range values (1e39, NaN, negative), and renders it with or without
``out_dir``. The only allowed outcomes:

* a result whose images are all finite and non-negative; with ``out_dir``, its files, and only they, exist;
* :class:`~warpscatter.errors.ConfigError` or :class:`~warpscatter.errors.InputFileError` (the CLI's exit 2), with
  nothing written.

Anything else (another exception, a NaN, a negative pixel, a missing output, a stray temporary) fails the test.

The default run is deterministic (``derandomize``) and bounded (:data:`DEFAULT_EXAMPLES`: 250 configs, ~20 s on two
cores once the kernels are compiled); for releases run the long profile (registered in ``tests/conftest.py``)::

    pytest --hypothesis-profile=long tests/test_fuzz.py -s     # 1000 configs (~65 s); -s prints the outcome counts

Set ``WARPSCATTER_FUZZ_STATS=counts.json`` to write the counts (examples run, renders, config / input errors,
crashes, non-finite or negative pixels, lost outputs) to a file.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
import traceback
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import warpscatter
from warpscatter import methods
from warpscatter.config import DEBUG_AOVS, load_config
from warpscatter.errors import ConfigError, InputFileError
from warpscatter.shadows.settings import SHADOW_METHODS

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = ROOT / "configs"

#: Examples of the suite's run. A profile that sets its own max_examples (``--hypothesis-profile=long``) wins.
DEFAULT_EXAMPLES = 250
FUZZ_EXAMPLES = (settings.default.max_examples
                 if settings.default.max_examples != settings.get_profile("default").max_examples
                 else DEFAULT_EXAMPLES)

#: Bundled configs fuzzed: the classic pipeline (directional and spot lights) and the Monte-Carlo lighting methods.
CLASSIC = ["quickstart", "colonnade", "canopy", "gate", "gate_soft_shadows", "terrain", "window", "spot",
           "spot_epipolar", "spot_moments", "canopy_moments", "colonnade_fourier"]
LIGHTING = ["csm_gate", "csm_area", "csm_objects"]
BASES = {name: load_config(CONFIGS / f"{name}.yaml") for name in CLASSIC + LIGHTING}

#: Outcome counts of this process's examples (printed at the end of the module, written to WARPSCATTER_FUZZ_STATS).
STATS: Counter = Counter()

#: The keys the refused configs were refused at (how often), printed with the counts.
REFUSED: Counter = Counter()

#: Values no config key accepts.
WILD = [1e39, -1e39, 1e200, math.inf, -math.inf, math.nan, 1e30]


# ---- strategies ----------------------------------------------------------------------------------


def number(lo: float, hi: float, hostile: bool, *, log: bool = False, wild=()):
    """A value in [lo, hi] (log-uniform with ``log``) or a bound; when ``hostile``, sometimes out of range too."""
    if log:
        inside = st.floats(math.log10(lo), math.log10(hi)).map(lambda e: 10.0 ** e)
    else:
        inside = st.floats(lo, hi, allow_nan=False, allow_infinity=False)
    bounds = st.sampled_from([lo, hi])
    if not hostile:
        return st.one_of(inside, inside, inside, bounds)
    outside = [v for v in (lo - abs(lo) - 1.0, hi * 10.0 + 1.0, *wild, *WILD) if not lo <= v <= hi]
    return st.one_of(inside, bounds, st.sampled_from(outside))


def vector(scale: float = 10.0):
    return st.tuples(*[st.floats(-scale, scale, allow_nan=False, allow_infinity=False)] * 3).map(list)


def rgb(hi: float, hostile: bool):
    grey = number(0.0, hi, hostile, wild=(-0.5,))
    return st.one_of(grey.map(lambda v: [v, v, v]), st.tuples(*[number(0.0, hi, hostile)] * 3).map(list),
                     st.just([0.0, 0.0, 0.0]))


def _unit(v):
    n = math.sqrt(sum(x * x for x in v))
    return [x / n for x in v]


def _forward(cam):
    return _unit([b - a for a, b in zip(cam.position, cam.look_at, strict=True)])


@st.composite
def camera(draw, base, hostile: bool) -> dict:
    cam = base.camera
    pos, at = list(cam.position), list(cam.look_at)
    dist = math.dist(pos, at)
    modes = ["base", "jitter", "jitter", "random", "far_away"]
    if hostile:
        modes += ["along_up", "same_point", "tiny_offset", "wild"]
    mode = draw(st.sampled_from(modes))
    out: dict = {}
    if mode == "jitter":
        pos = [p + d for p, d in zip(pos, draw(vector(0.3 * dist)), strict=True)]
        at = [p + d for p, d in zip(at, draw(vector(0.3 * dist)), strict=True)]
    elif mode == "random":
        pos, at = draw(vector(50.0)), draw(vector(50.0))
        if not hostile and math.dist(pos, at) < 1e-3:
            at = [at[0] + 1.0, at[1], at[2] + 1.0]
    elif mode == "along_up":  # looking straight up or down: up is parallel to the view
        at = [pos[0], pos[1] + draw(st.sampled_from([-5.0, -1e-3, 2.0, 1e4])), pos[2]]
    elif mode == "same_point":
        at = list(pos)
    elif mode == "tiny_offset":
        at = [pos[0] + draw(st.sampled_from([1e-9, 1e-6, 1e-3])), pos[1], pos[2]]
    elif mode == "far_away":
        k = draw(st.sampled_from([1e2, 1e4] + ([1e5, 1e6, 1e7] if hostile else [])))
        pos, at = [p * k for p in pos], [a * k for a in at]
    elif mode == "wild":
        pos = [draw(st.sampled_from(WILD)), pos[1], pos[2]]
    if mode != "base":
        out["camera.position"], out["camera.look_at"] = pos, at
    if draw(st.booleans()):
        out["camera.fov_y"] = draw(number(0.01, 170.0, hostile, wild=(0.0, 179.9999, 180.0, 1e-9)))
    if draw(st.integers(0, 3)) == 0:  # far / near: 1e-6 .. 1e7
        near = draw(number(1e-6, 10.0, hostile, log=True, wild=(0.0, -1.0, 1e-9)))
        out["camera.near"] = near
        if math.isfinite(near) and near > 0.0:
            far = near * draw(number(1.001, 1e7, hostile, log=True, wild=(1e9, 0.5)))
            out["camera.far"] = far if hostile else min(far, 1e6)
    if draw(st.integers(0, 7)) == 0:
        ups = [[1e-300, 1.0, 0.0], [0.0, 1e-300, 0.0], [0.0, -1.0, 0.0], [0.3, 0.9, 0.1]]
        out["camera.up"] = draw(st.sampled_from(ups + ([[0.0, 0.0, 0.0], [1e200, 0.0, 0.0]] if hostile else [])))
    out["camera.width"] = draw(st.integers(16, 64))
    out["camera.height"] = draw(st.integers(16, 64))
    return out


def _direction(draw, hostile, special: dict):
    """A light direction: the config's (None), random, one of ``special`` (degenerate against the camera), or, when
    hostile, zero or out of range."""
    kinds = ["keep", "random", "random", *special]
    if hostile:
        kinds += ["zero", "huge", "wild"]
    kind = draw(st.sampled_from(kinds))
    if kind == "keep":
        return None
    if kind == "random":
        v = draw(vector(1.0))
        return v if any(v) else [0.0, -1.0, 0.0]
    return {**special, "zero": [0.0, 0.0, 0.0], "huge": [1e200, -1.0, 0.0], "wild": [math.nan, -1.0, 0.0]}[kind]


@st.composite
def light(draw, name, base, hostile: bool) -> dict:
    out: dict = {}
    kind = base.light.type
    fwd = _forward(base.camera)
    if kind == "directional":
        right = _unit([fwd[2], 0.0, -fwd[0]])
        d = _direction(draw, hostile, {"behind_camera": fwd, "into_camera": [-x for x in fwd], "image_plane": right,
                                       "tiny": [1e-300, -1e-300, 1e-310], "straight_down": [0.0, -1.0, 0.0]})
        if d is not None:
            out["light.direction"] = d
        if draw(st.booleans()):
            out["light.irradiance"] = draw(rgb(1e6, hostile))
    elif kind == "spot":
        pos = list(base.light.position)
        where = draw(st.sampled_from(["keep", "jitter", "at_camera", "behind_camera", "random"]))
        cam = list(base.camera.position)
        if where == "jitter":
            pos = [p + d for p, d in zip(pos, draw(vector(2.0)), strict=True)]
        elif where == "at_camera":
            pos = cam
        elif where == "behind_camera":
            pos = [c - 3.0 * f for c, f in zip(cam, fwd, strict=True)]
        elif where == "random":
            pos = draw(vector(30.0))
        if where != "keep":
            out["light.position"] = pos
        if draw(st.integers(0, 3)) == 0:  # the same place as a point light (six cube-face spots)
            return {"light": {"type": "point", "position": pos, "intensity": draw(rgb(1e6, hostile))}}

        to_cam = [c - p for c, p in zip(cam, pos, strict=True)]
        d = _direction(draw, hostile, {"into_camera": to_cam if any(to_cam) else [0.0, 0.0, 1.0],
                                       "along_view": fwd, "tiny": [0.0, -1e-300, 1e-300]})
        if d is not None:
            out["light.direction"] = d
        if draw(st.booleans()):
            out["light.cone_deg"] = draw(number(0.01, 89.0, hostile, wild=(0.0, 90.0, 1e-9)))
        if draw(st.booleans()):
            out["light.intensity"] = draw(rgb(1e6, hostile))
    elif kind == "environment":
        if draw(st.booleans()):
            out["light.scale"] = draw(number(0.0, 1e6, hostile, wild=(-1.0,)))
    else:  # area (csm_area): itself, resized, degenerate, textured, or a linear or volume light
        shape = draw(st.sampled_from(["keep", "resize", "tiny", "linear", "volume", "textured"]
                                     + (["parallel"] if hostile else [])))
        if shape == "resize":
            out["light.u"] = draw(vector(10.0))
            out["light.v"] = draw(vector(10.0))
        elif shape == "parallel":
            out["light.v"] = [2.0 * x for x in base.light.u]
        elif shape == "tiny":
            out["light.u"], out["light.v"] = [1e-3, 0.0, 0.0], [0.0, 0.0, 1e-3]
        elif shape == "linear":
            start = list(base.light.position)
            out["light"] = {"type": "linear", "start": start,
                            "end": [start[0] + draw(st.sampled_from([1e-6, 1.0, 6.0] + ([0.0, 1e-9] if hostile
                                                                                       else []))), start[1], start[2]],
                            "intensity": draw(rgb(1e6, hostile))}
        elif shape == "volume":
            out["light"] = {"type": "volume", "position": list(base.light.position), "u": [2.0, 0.0, 0.0],
                            "v": [0.0, 1.0, 0.0],
                            "w": [0.0, 0.0, draw(st.sampled_from([1e-6, 1.0] + ([0.0, 1e-12] if hostile else [])))],
                            "intensity": draw(rgb(1e6, hostile))}
        elif shape == "textured":
            out["light.texture"] = "../assets/light_cookie.png"
        if shape not in ("linear", "volume") and draw(st.booleans()):
            out["light.power"] = draw(rgb(1e6, hostile))
    return out


@st.composite
def medium(draw, hostile: bool) -> dict:
    out: dict = {}
    choice = draw(st.integers(0, 5))
    if choice == 0:
        out["medium.sigma_t"] = 0.0
    elif choice <= 3:
        out["medium.sigma_t"] = draw(number(1e-4, 1e4, hostile, log=True, wild=(-1.0, 1e5)))
    elif choice == 4:
        out["medium.sigma_t"] = draw(st.tuples(*[number(1e-3, 100.0, hostile, log=True)] * 3).map(list))
    if draw(st.booleans()):
        out["medium.albedo"] = draw(st.one_of(number(0.0, 1.0, hostile, wild=(1.5,)), rgb(1.0, hostile)))
    if draw(st.booleans()):
        out["medium.phase"] = draw(st.one_of(
            st.just({"type": "isotropic"}),
            number(-0.99, 0.99, hostile, wild=(0.9999, 1.0, -1.0)).map(
                lambda g: {"type": "henyey_greenstein", "g": g})))
    return out


@st.composite
def render_settings(draw, name, base, hostile: bool) -> dict:
    out: dict = {}
    if name in LIGHTING:
        lt = "render.lighting"
        out[f"{lt}.method"] = draw(st.sampled_from(list(methods.LIGHTING)))
        out[f"{lt}.samples"] = draw(st.sampled_from([1, 4]))
        out[f"{lt}.passes"] = draw(st.integers(1, 2))
        out[f"{lt}.csm.maps"] = draw(st.sampled_from([[8, 4], [16, 8]]))
        out[f"{lt}.csm.resolution"] = draw(st.sampled_from([16, 32]))
        out[f"{lt}.csm.light_samples"] = [2, 2]
        out[f"{lt}.seed"] = draw(st.integers(0, 2**31 - 1))
        if name == "csm_objects":
            out["animation"] = None  # render() renders one config; sequences have their own API
        return out
    sc = "render.scattering"
    valid = [m for m, spec in methods.SCATTERING.items() if base.light.type in spec.lights]
    out[f"{sc}.method"] = draw(st.sampled_from(list(methods.SCATTERING) if hostile else valid))
    out[f"{sc}.steps"] = draw(st.integers(4, 16))
    out[f"{sc}.visibility"] = draw(st.sampled_from(["exact", "shadow_map"]))
    out[f"{sc}.jitter"] = draw(st.sampled_from(["per_pixel", "fixed"]))
    out[f"{sc}.shadow_map.resolution"] = draw(st.one_of(st.integers(64, 256),
                                                        st.tuples(st.integers(64, 256), st.integers(64, 256))
                                                        .map(list)))
    if draw(st.booleans()):
        out[f"{sc}.prefiltered.rectification"] = draw(st.sampled_from(["auto", "projective", "nonlinear"]))
    out[f"{sc}.prefiltered.epipole_steps"] = draw(st.integers(4, 16))
    if draw(st.integers(0, 3)) == 0:
        out[f"{sc}.seed"] = draw(st.integers(-1, 2**31) if hostile else st.integers(0, 2**31 - 1))
    out["render.shadows.method"] = draw(st.sampled_from(SHADOW_METHODS))
    return out


@st.composite
def scene(draw, base, hostile: bool) -> dict:
    """One mesh's material (translucent occluders) and placement changed, or nothing."""
    out: dict = {}
    if draw(st.booleans()):
        return out
    k = draw(st.integers(0, len(base.scene.meshes) - 1))
    mesh = f"scene.meshes.{k}"
    if draw(st.booleans()):
        out[f"{mesh}.material.opacity"] = draw(number(0.001, 1.0, hostile, wild=(0.0, 1.5)))
    if draw(st.booleans()):
        out[f"{mesh}.material.albedo"] = draw(rgb(1.0, hostile))
    if draw(st.booleans()):
        out[f"{mesh}.transform.scale"] = draw(st.one_of(number(0.01, 10.0, hostile, log=True, wild=(0.0, 1e9)),
                                                        st.tuples(*[number(0.01, 10.0, hostile, log=True)] * 3)
                                                        .map(list)))
        out[f"{mesh}.transform.rotate_deg"] = draw(vector(360.0))
        out[f"{mesh}.transform.translate"] = draw(vector(5.0))
    return out


@st.composite
def technique(draw, name, base, hostile: bool) -> dict:
    """The methods' own keys: shadows, prefiltered, epipolar, the debug outputs."""
    out: dict = {}
    if name in LIGHTING:
        if draw(st.booleans()):
            out["render.lighting.filter"] = draw(st.sampled_from(["nearest", "pcf", "roulette"]))
        return out
    sh, pf, ep = "render.shadows", "render.scattering.prefiltered", "render.scattering.epipolar"
    if draw(st.booleans()):
        out[f"{sh}.filter_px"] = draw(st.integers(1, 9))
        if base.light.type == "directional":
            out[f"{sh}.light_angle_deg"] = draw(number(1e-3, 30.0, hostile, log=True, wild=(0.0, 180.0)))
        else:
            out[f"{sh}.light_size"] = draw(number(1e-3, 5.0, hostile, log=True, wild=(0.0,)))
    if draw(st.booleans()):
        out[f"{pf}.segments"] = draw(st.sampled_from([None, 1, 3, 8]))
        out[f"{pf}.reference_ray"] = draw(st.sampled_from(["auto", "pixels", "least", "optimal", "bisectrix",
                                                           "mean"]))
        out[f"{pf}.weighting"] = draw(st.sampled_from(["transmittance", "average"]))
        out[f"{pf}.map_radius"] = draw(st.sampled_from(["view", "casters"]))
        out[f"{pf}.resample_filter"] = draw(st.sampled_from(["none", "supersample", "moments"]))
        out[f"{pf}.mip_levels"] = draw(st.sampled_from([1, 2, 8]))
    if draw(st.integers(0, 3)) == 0:
        out[f"{pf}.splits"] = draw(st.integers(1, 4))
        out[f"{pf}.segments"] = 1
        out[f"{pf}.mip_levels"] = 1
    if draw(st.booleans()):
        out[f"{sh}.coloured"] = draw(st.booleans())
        out[f"{sh}.supersampling"] = draw(st.integers(1, 3))
        out[f"{sh}.sampling"] = draw(st.sampled_from(["bilinear", "mipmap"]))
        out[f"{sh}.max_translucent_layers"] = draw(st.integers(1, 4))
        out["render.scattering.shadow_map.bias"] = draw(number(0.0, 10.0, hostile, wild=(-1.0, 1e4)))
    if draw(st.booleans()):
        out["render.scattering.fourier.coefficients"] = draw(st.sampled_from([4, 8, 16, 32]))
        out["render.scattering.fourier.storage_bits"] = draw(st.sampled_from([0, 8]))
        out["render.scattering.moments.overestimation"] = draw(st.one_of(st.just("adaptive"),
                                                                         number(0.0, 1.0, hostile)))
    if draw(st.booleans()):
        out[f"{ep}.lines"] = draw(st.sampled_from([8, 32, 64]))
        out[f"{ep}.kernel"] = draw(st.sampled_from(["gaussian", "shepard", "threshold"]))
        out[f"{ep}.initial_samples"] = draw(st.sampled_from([2, 4, 16]))
    if draw(st.integers(0, 3)) == 0:
        out["output.aovs"] = ["color", "scattering", "surface", "depth", "rectified", "epipole_mask", "rectified_map",
                              "mip_level"]
    return out


@st.composite
def cases(draw):
    """(bundled config, overrides, write the outputs?): a quarter of them hostile (out-of-range and invalid values
    possible in every part), the others valid as far as each key goes (bounds and degenerate geometry included)."""
    name = draw(st.sampled_from(list(BASES)))
    base = BASES[name]
    hostile = draw(st.integers(0, 3)) == 0
    overrides = {**draw(camera(base, hostile)), **draw(light(name, base, hostile)),
                 **draw(render_settings(name, base, hostile)), **draw(scene(base, hostile)),
                 **draw(technique(name, base, hostile))}
    if name in CLASSIC:
        overrides.update(draw(medium(hostile)))
        method = overrides["render.scattering.method"]
        if not hostile and method not in ("fourier", "moments4", "moments6"):  # keys of the prefiltered methods
            overrides.pop("output.aovs", None)
        if not hostile and method != "fourier":
            overrides.pop("render.scattering.prefiltered.splits", None)
    return name, overrides, draw(st.booleans())


# ---- the property --------------------------------------------------------------------------------


def _expected_files(result) -> set[str]:
    return {p.name for p in result.files}


def check_case(name: str, overrides: dict, out_dir: Path | None) -> str:
    """Render one case; return its outcome, or raise AssertionError naming what went wrong."""
    STATS["examples"] += 1
    try:
        result = warpscatter.render(CONFIGS / f"{name}.yaml", overrides, out_dir=out_dir)
    except (ConfigError, InputFileError) as exc:
        STATS["config errors" if isinstance(exc, ConfigError) else "input errors"] += 1
        for problem in getattr(exc, "problems", [str(exc)]):
            REFUSED[problem.split(":")[0].split(" ")[0]] += 1
        if out_dir is not None and out_dir.exists() and any(out_dir.iterdir()):
            STATS["lost outputs"] += 1
            raise AssertionError(f"{type(exc).__name__} but files were written: {sorted(os.listdir(out_dir))}") \
                from exc
        return "refused"
    except Exception as exc:
        STATS["crashes"] += 1
        raise AssertionError(f"{name} {overrides}: {type(exc).__name__}: {exc}\n{traceback.format_exc()}") from exc
    for key, image in result.images.items():
        if not np.all(np.isfinite(image)):
            STATS["non-finite images"] += 1
            raise AssertionError(f"{name} {overrides}: image {key!r} has {np.sum(~np.isfinite(image))} non-finite "
                                 f"pixels")
        if key not in DEBUG_AOVS and image.size and np.min(image) < 0.0:
            STATS["negative images"] += 1
            raise AssertionError(f"{name} {overrides}: image {key!r} has negative pixels (min {np.min(image)})")
    if out_dir is not None:
        written = set(os.listdir(out_dir)) if out_dir.exists() else set()
        stem = result.config.output_name
        wanted = {f"{stem}.exr", f"{stem}.png", f"{stem}.json"}
        if not result.files or not wanted <= written or written != _expected_files(result):
            STATS["lost outputs"] += 1
            raise AssertionError(f"{name} {overrides}: wrote {sorted(written)}, reported "
                                 f"{sorted(_expected_files(result))}")
    STATS["renders"] += 1
    return "rendered"


@pytest.fixture(scope="module", autouse=True)
def _report():
    yield
    line = ", ".join(f"{k}: {v}" for k, v in sorted(STATS.items()))
    print(f"\nfuzz outcomes ({FUZZ_EXAMPLES} examples asked): {line}")
    print("refused at: " + ", ".join(f"{k} {v}" for k, v in REFUSED.most_common()))
    target = os.environ.get("WARPSCATTER_FUZZ_STATS")
    if target:
        Path(target).write_text(json.dumps({"max_examples": FUZZ_EXAMPLES, **STATS, "refused at": REFUSED},
                                           indent=2) + "\n")


@settings(max_examples=FUZZ_EXAMPLES, deadline=None, derandomize=True, database=None, print_blob=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(case=cases())
def test_random_configs_render_finitely_or_are_refused(case):
    name, overrides, write = case
    if not write:
        check_case(name, overrides, None)
        return
    root = Path(tempfile.mkdtemp(prefix="fuzz-"))
    try:
        check_case(name, overrides, root / "out")
    finally:
        shutil.rmtree(root, ignore_errors=True)


# ---- the degenerate cases, each once ---------------------------------------------------------------


@pytest.mark.parametrize(("name", "overrides"), [
    ("quickstart", {"camera.look_at": [4.0, 9.0, -13.0]}),  # looking straight up: up is parallel to the view
    ("quickstart", {"camera.look_at": [4.0, 1.7, -13.0]}),  # look_at == position
    ("quickstart", {"light.direction": [-0.2965, 0.0667, 0.9527]}),  # light straight behind the camera
    ("quickstart", {"light.direction": [0.2965, -0.0667, -0.9527]}),  # light straight into the camera
    ("quickstart", {"medium.sigma_t": 0.0}),
    ("quickstart", {"light.irradiance": [0.0, 0.0, 0.0]}),
    ("spot", {"light.position": [5.0, 1.2, -5.0]}),  # the spot light at the camera
    ("spot", {"light.direction": [5.5, -1.0, -9.0]}),  # the spot light shining into the camera
    ("window", {"render.scattering.method": "fourier", "medium.sigma_t": 1e4}),
    ("csm_area", {"light.power": [1e6, 1e6, 1e6], "render.lighting.samples": 1, "render.lighting.passes": 1,
                  "render.lighting.csm.resolution": 16, "render.lighting.csm.light_samples": [2, 2]}),
])
def test_degenerate_configs(tmp_path, name, overrides):
    small = {"camera.width": 24, "camera.height": 16}
    if name in CLASSIC:
        small.update({"render.scattering.steps": 8, "render.scattering.shadow_map.resolution": 64})
    for method in (["raymarch", "epipolar"] if name == "spot" else [None]):
        extra = {} if method is None else {"render.scattering.method": method}
        check_case(name, {**small, **extra, **overrides}, tmp_path / f"out-{method}")


# ---- what the fuzzer found -------------------------------------------------------------------------


@pytest.mark.parametrize(("name", "overrides"), [
    # the only caster below the alpha test (opacity < 0.01 casts nothing): exact visibility had no BVH to build
    # ("ValueError: scene: every mesh is receiver_only ...", exit 1) ...
    ("window", {"scene.meshes.0.material.opacity": 0.001, "render.scattering.visibility": "exact"}),
    # ... and the CSM no occluder ("ValueError: vertices must have shape (V, 3) with V >= 1, got (0, 3)")
    ("csm_gate", {"scene.meshes.0.material.opacity": 0.001}),
])
def test_a_scene_without_casters_is_refused(name, overrides):
    with pytest.raises(ConfigError, match=r"opacity below 0.01 \(the alpha test: it casts nothing\)"):
        warpscatter.render(CONFIGS / f"{name}.yaml", {"camera.width": 16, "camera.height": 16, **overrides})
