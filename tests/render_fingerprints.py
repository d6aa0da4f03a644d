"""Bit-identity check for refactors: render every bundled config (and variants of every method and option) at a
reduced size, and run every bench suite in quick mode; record the images' hashes, the render stats and the bench
rows' error figures, or compare them with a recorded set.

Not a pytest module (it takes minutes): run it by hand around a change that must not change any image::

    python tests/render_fingerprints.py record /tmp/before     # on the old code
    python tests/render_fingerprints.py compare /tmp/before    # on the new code: exit 1 on any difference

``--only SUBSTRING`` restricts the render cases, ``--no-bench`` skips the bench suites.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = ROOT / "configs"
SMALL = ["camera.width=160", "camera.height=90"]


def _cases() -> dict[str, tuple[str, list[str]]]:
    """name -> (config file, overrides)."""
    cases: dict[str, tuple[str, list[str]]] = {}
    for path in sorted(CONFIGS.glob("*.yaml")):
        extra = ["render.lighting.passes=2"] if path.stem.startswith("csm") else []
        cases[path.stem] = (path.name, SMALL + extra)

    def add(name, config, *overrides):
        cases[name] = (config, SMALL + list(overrides))

    sc = "render.scattering"
    RM = f"{sc}.method=raymarch"  # the bundled configs show their fast method; these cases are the marcher's
    # ---- reference marcher ----
    add("colonnade/raymarch-sm", "colonnade.yaml", RM, f"{sc}.visibility=shadow_map", f"{sc}.steps=32")
    add("colonnade/raymarch-sm-fixed", "colonnade.yaml", RM, f"{sc}.visibility=shadow_map", f"{sc}.jitter=fixed",
        f"{sc}.seed=3", f"{sc}.shadow_map.bias=2.5", f"{sc}.shadow_map.resolution=[512,256]")
    add("spot/raymarch-sm", "spot.yaml", RM, f"{sc}.visibility=shadow_map", f"{sc}.steps=32")
    add("spot/raymarch-fixed", "spot.yaml", RM, f"{sc}.jitter=fixed", f"{sc}.steps=16")
    add("window/nosurf", "window.yaml", RM, "render.surfaces.enabled=false", f"{sc}.steps=16")
    add("gate/isotropic", "gate.yaml", RM, "medium.phase={type: isotropic}", f"{sc}.steps=16", "medium.sigma_t=0")
    # ---- translucent casters and coloured media in every scattering method ----
    coloured = ["medium.sigma_t=[0.03,0.06,0.12]", "medium.albedo=[0.95,0.8,0.6]"]
    for method in ("raymarch", "fourier", "moments6", "epipolar"):
        add(f"gate_translucent/{method}", "gate_soft_shadows.yaml", f"{sc}.method={method}", f"{sc}.steps=16",
            f"{sc}.shadow_map.resolution=256")
        add(f"quickstart/coloured-{method}", "quickstart.yaml", f"{sc}.method={method}", f"{sc}.steps=16",
            f"{sc}.shadow_map.resolution=256", *coloured)
    add("quickstart/coloured-projective", "quickstart.yaml", f"{sc}.method=fourier", *coloured,
        f"{sc}.shadow_map.resolution=256", f"{sc}.prefiltered.rectification=projective")
    # ---- prefiltered methods on three scenes, every rectification ----
    for scene in ("colonnade", "window", "canopy", "gate"):
        for method in ("fourier", "moments4", "moments6"):
            for rect in ("auto", "projective", "nonlinear"):
                add(f"{scene}/{method}-{rect}", f"{scene}.yaml", f"{sc}.method={method}", f"{sc}.steps=32",
                    f"{sc}.shadow_map.resolution=256", f"{sc}.prefiltered.rectification={rect}")
    pf = f"{sc}.prefiltered"
    base = ["colonnade.yaml", f"{sc}.steps=32", f"{sc}.shadow_map.resolution=256"]
    for label, extra in (
        ("fourier-splits", [f"{sc}.method=fourier", f"{pf}.splits=3"]),
        ("fourier-8bit-m16", [f"{sc}.method=fourier", f"{sc}.fourier.storage_bits=8", f"{sc}.fourier.coefficients=16"]),
        ("fourier-average", [f"{sc}.method=fourier", f"{pf}.weighting=average"]),
        ("fourier-optimal", [f"{sc}.method=fourier", f"{pf}.reference_ray=optimal"]),
        ("fourier-bisectrix", [f"{sc}.method=fourier", f"{pf}.reference_ray=bisectrix"]),
        ("fourier-mean", [f"{sc}.method=fourier", f"{pf}.reference_ray=mean"]),
        ("fourier-resample", [f"{sc}.method=fourier", f"{pf}.resample_filter=moments"]),
        ("fourier-resample-px", [f"{sc}.method=fourier", f"{pf}.resample_filter=moments",
                                 f"{pf}.resample_filter_px=3"]),
        ("fourier-culled", [f"{sc}.method=fourier", f"{pf}.caster_culling=true", f"{pf}.caster_culling_bias=0.03"]),
        ("fourier-noepipole", [f"{sc}.method=fourier", f"{pf}.epipole_angle_deg=0", f"{pf}.epipole_block=0"]),
        ("fourier-guard", [f"{sc}.method=fourier", f"{pf}.guard_band=0.3", f"{pf}.epipole_angle_deg=12"]),
        ("moments4-128", [f"{sc}.method=moments4", f"{sc}.moments.storage_bits=128"]),
        ("moments4-beta", [f"{sc}.method=moments4", f"{sc}.moments.overestimation=0.3"]),
        ("moments6-96", [f"{sc}.method=moments6", f"{sc}.moments.storage_bits=96"]),
        ("moments6-192-unculled", [f"{sc}.method=moments6", f"{sc}.moments.storage_bits=192",
                                   f"{pf}.caster_culling=false"]),
        ("moments6-resample", [f"{sc}.method=moments6", f"{pf}.resample_filter=moments"]),
    ):
        add(f"colonnade/{label}", base[0], *base[1:], *extra)
    wbase = ["window.yaml", f"{sc}.steps=32", f"{sc}.shadow_map.resolution=256", f"{pf}.rectification=projective"]
    for label, extra in (
        ("fourier-cross-ratio", [f"{sc}.method=fourier", f"{pf}.projective_weights=cross_ratio"]),
        ("fourier-regions1", [f"{sc}.method=fourier", f"{pf}.regions=1", f"{pf}.splits=2"]),
        ("fourier-pixels-average", [f"{sc}.method=fourier", f"{pf}.weighting=average"]),
        ("moments4-optimal", [f"{sc}.method=moments4", f"{pf}.reference_ray=optimal"]),
    ):
        add(f"window/{label}", wbase[0], *wbase[1:], *extra)
    side = "light.direction=[-0.6,-0.5,0.8]"  # both epipoles far outside the view: auto picks projective
    for method in ("fourier", "moments4", "moments6"):
        add(f"colonnade/side-{method}", "colonnade.yaml", side, f"{sc}.method={method}", f"{sc}.steps=32",
            f"{sc}.shadow_map.resolution=256")
    add("colonnade/side-fourier-cross-ratio-splits", "colonnade.yaml", side, f"{sc}.method=fourier",
        f"{sc}.shadow_map.resolution=256", f"{pf}.projective_weights=cross_ratio", f"{pf}.splits=2",
        f"{pf}.regions=3", f"{pf}.reference_ray=mean")
    add("colonnade/side-moments6-culled-bias", "colonnade.yaml", side, f"{sc}.method=moments6",
        f"{sc}.shadow_map.resolution=256", f"{pf}.caster_culling_bias=0", f"{pf}.epipole_margin=0.2")
    # ---- epipolar ----
    ep = f"{sc}.epipolar"
    for scene in ("colonnade", "spot", "window"):
        for vis in ("exact", "shadow_map"):
            add(f"{scene}/epipolar-{vis}", f"{scene}.yaml", f"{sc}.method=epipolar", f"{sc}.visibility={vis}",
                f"{sc}.steps=32", f"{sc}.shadow_map.resolution=256", f"{ep}.lines=128")
    add("quickstart/epipolar-fallback", "quickstart.yaml", f"{sc}.method=epipolar", "light.direction=[13,0,4]",
        f"{sc}.steps=16", f"{ep}.fallback_stride=3")
    add("colonnade/epipolar-anti", "colonnade.yaml", f"{sc}.method=epipolar", "light.direction=[0.5,0.35,1.0]",
        f"{sc}.visibility=shadow_map", f"{sc}.steps=16", f"{ep}.lines=64")
    add("colonnade/fourier-anti", "colonnade.yaml", f"{sc}.method=fourier", "light.direction=[0.5,-0.35,1.0]",
        f"{sc}.steps=16", f"{sc}.shadow_map.resolution=256")
    for label, extra in (
        ("shepard", [f"{ep}.kernel=shepard", f"{ep}.taps=5"]),
        ("threshold", [f"{ep}.kernel=threshold", f"{ep}.depth_threshold=0.2", f"{ep}.initial_samples=8"]),
        ("fixed", [f"{sc}.jitter=fixed", f"{ep}.samples_per_line=64", f"{ep}.outer_lines=0"]),
        ("prefilter-tex", [f"{ep}.prefilter_light_texture=true", f"{ep}.fallback_stride=2"]),
        ("falloff", [f"{ep}.distance_falloff=0", f"{ep}.depth_sigma=0.5", f"{ep}.min_weight=0.5",
                     f"{ep}.max_epipole_distance=2"]),
    ):
        add(f"spot/epipolar-{label}", "spot_epipolar.yaml", f"{sc}.steps=32", f"{sc}.shadow_map.resolution=256",
            f"{ep}.lines=128", *extra)
    # ---- prefiltered methods under a spot light (rectify_local, prefiltered_spot) ----
    for label, extra in (
        ("fourier", [f"{sc}.method=fourier"]),
        ("moments4", [f"{sc}.method=moments4", f"{sc}.prefiltered.caster_culling=false"]),
        ("moments6-grey", [f"{sc}.method=moments6", "light.texture=null", "medium.sigma_t=[0.05, 0.12, 0.3]"]),
        ("fourier-8bit", [f"{sc}.method=fourier", f"{sc}.fourier.storage_bits=8", f"{sc}.prefiltered.segments=2"]),
    ):
        add(f"spot/prefiltered-{label}", "spot_moments.yaml", f"{sc}.shadow_map.resolution=256", *extra)
    point = "light={type: point, position: [-0.5, 2.2, 4.0], intensity: [30, 30, 30]}"
    for label, extra in (("marcher", [f"{sc}.method=raymarch", f"{sc}.visibility=shadow_map", f"{sc}.steps=32"]),
                         ("exact", [f"{sc}.method=raymarch", f"{sc}.steps=32"]),
                         ("moments6", [f"{sc}.method=moments6"])):
        add(f"point/{label}", "spot_moments.yaml", f"{sc}.shadow_map.resolution=256", point, *extra)
    # ---- surface shadows ----
    sh = "render.shadows"
    gbase = ["gate_soft_shadows.yaml", f"{sc}.steps=8", f"{sc}.shadow_map.resolution=256"]
    for label, extra in (
        ("pcf", [f"{sh}.method=pcf", f"{sh}.filter_px=5"]),
        ("none", [f"{sh}.method=none"]),
        ("msm64", [f"{sh}.method=msm"]),
        ("msm128-mip", [f"{sh}.method=msm", f"{sh}.storage=128", f"{sh}.sampling=mipmap"]),
        ("msm-coloured", [f"{sh}.method=msm", f"{sh}.coloured=true", f"{sh}.supersampling=1",
                          "scene.meshes.0.material.albedo=[0.9,0.2,0.1]"]),
        ("msm-layers", [f"{sh}.method=msm", f"{sh}.max_translucent_layers=2", f"{sh}.filter_px=7"]),
        ("msm_soft", [f"{sh}.method=msm_soft", f"{sh}.max_kernel_px=12"]),
        ("msm_soft-coloured", [f"{sh}.method=msm_soft", f"{sh}.coloured=true"]),
        ("pcss", [f"{sh}.method=pcss", f"{sh}.light_angle_deg=4"]),
    ):
        add(f"gate_soft/{label}", gbase[0], *gbase[1:], *extra)
    for method in ("msm", "msm_soft", "pcss"):
        add(f"spot/shadows-{method}", "spot.yaml", RM, f"{sc}.visibility=shadow_map", f"{sc}.steps=8",
            f"{sh}.method={method}", f"{sh}.light_size=0.8")
    # ---- Monte-Carlo lighting ----
    lt = "render.lighting"
    for label, extra in (
        ("raytrace", [f"{lt}.method=raytrace"]),
        ("nearest", [f"{lt}.filter=nearest"]),
        ("pcf", [f"{lt}.filter=pcf", f"{lt}.csm.maps=[16,8]", f"{lt}.csm.resolution=64"]),
        ("zigzag-bias", [f"{lt}.csm.enumeration=zigzag", f"{lt}.bias=0.05", f"{lt}.normal_offset=0.01",
                         f"{lt}.csm.maps=[16,8]", f"{lt}.csm.layers=z1z3", f"{lt}.csm.far=infinite"]),
        ("nobackground", [f"{lt}.background=false", f"{lt}.samples=4", f"{lt}.seed=5", "medium.sigma_t=0.05"]),
    ):
        add(f"csm_gate/{label}", "csm_gate.yaml", f"{lt}.passes=2", *extra)
    for label, extra in (
        ("raytrace", [f"{lt}.method=raytrace"]),
        ("semi_local", [f"{lt}.csm.local_lights=semi_local", f"{lt}.csm.maps=[16,8]"]),
        ("linear", ["light={type: linear, start: [-3, 6, -1], end: [3, 6, 1], intensity: [30, 30, 30]}"]),
        ("linear-raytrace", ["light={type: linear, start: [-3, 6, -1], end: [3, 6, 1], intensity: [30, 30, 30]}",
                             f"{lt}.method=raytrace"]),
        ("two-sided", ["light.two_sided=true", f"{lt}.filter=roulette"]),
    ):
        add(f"csm_area/{label}", "csm_area.yaml", f"{lt}.passes=2", f"{lt}.csm.light_samples=[4,2]", *extra)
    return cases


def _hash(a: np.ndarray) -> str:
    a = np.ascontiguousarray(a)
    return hashlib.sha256(str(a.dtype).encode() + str(a.shape).encode() + a.tobytes()).hexdigest()[:24]


def _jsonable(v):
    if isinstance(v, dict):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, (np.floating, float)):
        return float(v) if math.isfinite(v) else str(v)
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (str, int, bool)) or v is None:
        return v
    return str(v)


def render_cases(only: str | None, images_dir: Path | None) -> dict:
    from warpscatter.config import load_config
    from warpscatter.pipeline import render

    out = {}
    cases = _cases()
    for k, (name, (config, overrides)) in enumerate(cases.items()):
        if only and only not in name:
            continue
        t0 = time.perf_counter()
        try:
            cfg = load_config(CONFIGS / config, overrides)
            if cfg.animation is not None:  # an animated config: its first frame
                cfg = cfg.at_frame(cfg.animation.frame_numbers[0])
            result = render(cfg, write=False)
            entry = {"images": {n: _hash(a) for n, a in sorted(result.images.items())},
                     "stats": _jsonable(result.stats)}
            if images_dir is not None:
                np.savez_compressed(images_dir / (name.replace("/", "__") + ".npz"), **result.images)
        except Exception as exc:  # an error is a fingerprint too (the same config must fail the same way)
            entry = {"error": f"{type(exc).__name__}: {exc}"}
        out[name] = entry
        print(f"[{k + 1}/{len(cases)}] {name}: {time.perf_counter() - t0:.1f}s"
              + (f"  ERROR {entry['error']}" if "error" in entry else ""), flush=True)
    return out


#: Fields of bench rows and render stats that are times (or derived from times): left out of the fingerprint.
_TIME_KEYS = ("median_ms", "stages_ms", "speedup", "min_s", "times_s")


def _is_time_key(k: str) -> bool:
    return k in _TIME_KEYS or k.endswith(("_ms", "_s", "per_s")) or "speedup" in k or "vs_embree" in k \
        or "seconds" in k


def _timeless(fields: dict) -> dict:
    """A row's or a stats dict's fields without the times (nested dicts: the same one level down)."""
    return {k: (_timeless(v) if isinstance(v, dict) else v) for k, v in fields.items() if not _is_time_key(k)}


def _without_times(doc: dict) -> dict:
    """The fingerprint document with the time fields of every render's stats and every bench row removed."""
    out = {"renders": {name: {**e, **({"stats": _timeless(e["stats"])} if "stats" in e else {})}
                       for name, e in doc.get("renders", {}).items()}}
    if "bench" in doc:
        out["bench"] = {suite: {key: _timeless(row) for key, row in rows.items()}
                        for suite, rows in doc["bench"].items()}
    return out


def bench_suites() -> dict:
    from warpscatter import bench

    out = {}
    for suite in bench.SUITES:
        if suite in ("raster", "parallel"):  # timings only (no image)
            continue
        t0 = time.perf_counter()
        import tempfile

        with tempfile.TemporaryDirectory() as tmp:
            report = bench.run(suite, repeats=1, warmup=0, quick=True, out_dir=Path(tmp))
        rows = {}
        for row in report.rows:
            key = f"{row.get('name')} {json.dumps(row.get('params'), sort_keys=True)}"
            rows[key] = _jsonable({k: v for k, v in row.items() if k not in ("name", "params")})
        out[suite] = rows
        print(f"bench {suite}: {len(rows)} rows, {time.perf_counter() - t0:.1f}s", flush=True)
    return out


def _diff(a, b, path="") -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b)):
            if k not in b:
                out.append(f"{path}{k}: missing now (was {str(a[k])[:80]})")
            elif k not in a:
                out.append(f"{path}{k}: new (now {str(b[k])[:80]})")
            else:
                out += _diff(a[k], b[k], f"{path}{k}.")
        return out
    return [] if a == b else [f"{path[:-1]}: {str(a)[:100]} -> {str(b)[:100]}"]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mode", choices=["record", "compare"])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--only", default=None)
    ap.add_argument("--no-bench", action="store_true")
    args = ap.parse_args()
    args.folder.mkdir(parents=True, exist_ok=True)
    images_dir = None
    if args.mode == "record":
        images_dir = args.folder / "images"
        images_dir.mkdir(exist_ok=True)
    got = {"renders": render_cases(args.only, images_dir)}
    if not args.no_bench:
        got["bench"] = bench_suites()
    if args.mode == "record":
        (args.folder / "fingerprints.json").write_text(json.dumps(got, indent=1, sort_keys=True))
        print(f"recorded {len(got['renders'])} renders into {args.folder}")
        return 0
    want = json.loads((args.folder / "fingerprints.json").read_text())
    if args.only:
        want["renders"] = {k: v for k, v in want["renders"].items() if args.only in k}
    if args.no_bench:
        want.pop("bench", None)
    problems = _diff(_without_times(want), _without_times(json.loads(json.dumps(got))))
    (args.folder / "compare.txt").write_text("\n".join(problems) + "\n")
    n_img = sum(len(v.get("images", {})) for v in got["renders"].values())
    n_rows = sum(len(v) for v in got.get("bench", {}).values())
    if problems:
        print(f"{len(problems)} difference(s):")
        print("\n".join(problems[:200]))
        return 1
    print(f"identical: {len(got['renders'])} renders ({n_img} images, stats included), {n_rows} bench rows")
    return 0


if __name__ == "__main__":
    sys.exit(main())
