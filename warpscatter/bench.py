"""Benchmark suites: ``warpscatter bench [SUITE]``.

Every suite times library stages the way a render runs them: a warm-up run first (kernel compile
is measured apart, as the ``compile`` figure of the first load in the process), then the median of
``repeats`` runs per stage. Rows carry the error against the exact reference where one applies
(relative L1 = sum|a - b| / sum|b| and RMSE over all pixels and channels) and the speed-up over the
brute-force ray marcher measured in the SAME run.

Output: a terminal table (:meth:`BenchReport.table`), ``bench-<suite>.json`` and, when matplotlib
is installed (the ``plot`` extra), ``bench-<suite>.png``.

Suites (:data:`SUITES`):

* ``raster``    — depth map of a >= 1M-triangle mesh: the Warp rasterizer against BVH ray casting
  (``wp.Mesh``) and Embree (embreex, the ``peers`` extra) when installed.
* ``reference`` — the ray marcher at 1920x1080, 128 steps, with shadow-map and exact visibility.
* ``parallel``  — speed-up of split CPU launches (1 thread against all) for the rasterizer and the marcher.

``quick=True`` shrinks every size (for smoke tests and CI); figures for notes come from full runs.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import warp as wp

from .wpinit import default_device, init

SUITES: dict[str, str] = {
    "raster": "1024^2 depth map of a >=1M-triangle mesh: Warp rasterizer vs wp.Mesh ray casting vs Embree",
    "reference": "ray marching at 1920x1080, 128 steps: shadow-map vs exact (ray-cast) visibility",
    "parallel": "speed-up of split CPU launches (1 thread vs all cores): rasterizer and ray marcher",
    "prefiltered": "fourier method (Klehm 2014): stage times vs map size, output size, basis count; error vs exact; "
                   "scene-complexity sweep",
    "moments": "fourier, moments4, moments6 (Peters 2017) and the marcher on colonnade, canopy, window (colonnade "
               "and canopy also with a receiver-only ground): time, bits per texel, error vs exact; moment soft "
               "shadows vs PCSS",
    "epipolar": "epipolar sampling (Engelhardt 2010) on the colonnade under a textured spot: fraction ray-marched, "
                "stage times, errors (vs per-pixel marching, exact, converged) for 256-1024 lines and 8-32 initial "
                "samples; per_pixel and fixed step patterns",
    "csm": "coherent shadow maps (Ritschel 2007): compression ratio, precompute time and memory vs N and "
           "enumeration; visibility queries/s (random, coherent) against BVH shadow rays; the csm render method's "
           "time per pass and error against raytrace",
}

ProgressFn = Callable[[str, float], None]


# ---- measurement helpers ---------------------------------------------------------------------------


def measure(fn: Callable[[], object], repeats: int, warmup: int) -> dict:
    """Run ``fn`` warmup times untimed, then ``repeats`` times; return median/min/all times (seconds)."""
    for _ in range(warmup):
        fn()
        wp.synchronize()
    times = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        fn()
        wp.synchronize()
        times.append(time.perf_counter() - t0)
    return {"median_s": statistics.median(times), "min_s": min(times), "times_s": times}


def errors(image: np.ndarray, reference: np.ndarray) -> dict:
    """Relative L1 and RMSE of ``image`` against ``reference`` (same shape)."""
    a = np.asarray(image, np.float64)
    b = np.asarray(reference, np.float64)
    denom = np.abs(b).sum()
    return {"rel_l1": float(np.abs(a - b).sum() / denom) if denom > 0 else float("nan"),
            "rmse": float(np.sqrt(np.mean((a - b) ** 2)))}


@contextmanager
def thread_limit(n: int | None):
    """Temporarily set WARPSCATTER_THREADS (None: leave as is)."""
    old = os.environ.get("WARPSCATTER_THREADS")
    if n is not None:
        os.environ["WARPSCATTER_THREADS"] = str(n)
    try:
        yield
    finally:
        if n is not None:
            if old is None:
                os.environ.pop("WARPSCATTER_THREADS", None)
            else:
                os.environ["WARPSCATTER_THREADS"] = old


@dataclass
class BenchReport:
    """Rows of one suite run plus the machine description."""

    suite: str
    rows: list[dict] = field(default_factory=list)
    meta: dict = field(default_factory=dict)
    files: list[Path] = field(default_factory=list)

    def add(self, **row) -> dict:
        self.rows.append(row)
        return row

    def table(self) -> str:
        """Fixed-width text table: one line per row, stage medians in ms."""
        cols = ["name", "params", "median_ms", "stages_ms", "speedup", "rel_l1", "rmse", "extra"]
        lines = []
        for r in self.rows:
            stages = r.get("stages_ms") or {}
            lines.append([
                r.get("name", ""),
                " ".join(f"{k}={v}" for k, v in (r.get("params") or {}).items()),
                f"{r['median_ms']:.1f}" if r.get("median_ms") is not None else "",
                " ".join(f"{k}={v:.1f}" for k, v in stages.items()),
                f"{r['speedup']:.2f}x" if r.get("speedup") is not None else "",
                f"{r['rel_l1']:.4f}" if r.get("rel_l1") is not None else "",
                f"{r['rmse']:.3g}" if r.get("rmse") is not None else "",
                " ".join(f"{k}={v}" for k, v in (r.get("extra") or {}).items()),
            ])
        widths = [max(len(c), *(len(x[i]) for x in lines)) if lines else len(c) for i, c in enumerate(cols)]
        out = [f"suite {self.suite}: " + ", ".join(f"{k}={v}" for k, v in self.meta.items() if k != "suite")]
        out.append("  ".join(c.ljust(w) for c, w in zip(cols, widths, strict=True)))
        out.append("  ".join("-" * w for w in widths))
        out += ["  ".join(x.ljust(w) for x, w in zip(line, widths, strict=True)) for line in lines]
        return "\n".join(out)

    def write(self, out_dir: Path) -> list[Path]:
        """Write JSON (and a PNG chart when matplotlib is available) into ``out_dir``."""
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        path = out_dir / f"bench-{self.suite}.json"
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(json.dumps({"suite": self.suite, "meta": self.meta, "rows": self.rows}, indent=2))
        os.replace(tmp, path)
        self.files = [path]
        chart = self._chart(out_dir / f"bench-{self.suite}.png")
        if chart is not None:
            self.files.append(chart)
        return self.files

    def _chart(self, path: Path) -> Path | None:
        try:
            import matplotlib

            matplotlib.use("Agg")
            import matplotlib.pyplot as plt
        except ImportError:
            return None
        rows = [r for r in self.rows if r.get("median_ms") is not None]
        if not rows:
            return None
        labels = [f"{r['name']}\n" + " ".join(f"{k}={v}" for k, v in (r.get("params") or {}).items()) for r in rows]
        fig, ax = plt.subplots(figsize=(max(6, 1.2 * len(rows)), 4))
        ax.bar(range(len(rows)), [r["median_ms"] for r in rows], color="#4477aa")
        ax.set_xticks(range(len(rows)), labels, fontsize=7)
        ax.set_ylabel("median time (ms)")
        ax.set_yscale("log")
        ax.set_title(f"warpscatter bench {self.suite} ({self.meta.get('threads')} threads)")
        fig.tight_layout()
        tmp = path.with_name(".tmp-" + path.name)
        fig.savefig(tmp, dpi=110)
        plt.close(fig)
        os.replace(tmp, path)
        return path


def machine_meta() -> dict:
    from .parallel import thread_count

    return {"warp": wp.__version__, "python": platform.python_version(), "cpu": platform.processor() or
            platform.machine(), "threads": thread_count(), "device": default_device()}


# ---- scenes ----------------------------------------------------------------------------------------


def bench_light_texture() -> Path:
    """The bundled light cookie (source checkout), else a generated 128^2 window-pane texture in a temp folder."""
    bundled = Path(__file__).resolve().parent.parent / "assets" / "light_cookie.png"
    if bundled.is_file():
        return bundled
    import tempfile

    from .imageio import write_png

    path = Path(tempfile.gettempdir()) / "warpscatter-bench-cookie.png"
    if not path.is_file():
        y, x = np.mgrid[0:128, 0:128] / 128.0
        panes = ((np.abs((x * 4) % 1 - 0.5) < 0.42) & (np.abs((y * 4) % 1 - 0.5) < 0.42)).astype(np.float32)
        tint = np.stack([0.6 + 0.4 * x, 0.7 + 0.3 * y, 1.0 - 0.5 * x], -1).astype(np.float32)
        write_png(path, panes[..., None] * tint)
    return path


def bench_scene_config(name: str, width: int, height: int, leaves: int = 4000, receiver_only_ground: bool = False,
                       **render):
    """A validated config for a bench scene (procedural only, so the bench runs from any install).

    Args:
        name: ``colonnade``, ``canopy`` or ``window`` (the scenes of ``configs/``), or ``colonnade_spot`` (the
            colonnade under a textured spot light).
        width, height: image size in pixels.
        leaves: leaf quads of the canopy scene (its complexity knob).
        receiver_only_ground: mark the scene's ground plane ``receiver_only`` (it shadows nothing visible, so the
            exact image is unchanged; the shadow-map methods no longer see its depths).
        **render: the config's ``render`` section.
    """
    from .config import Config

    scenes = {  # mirror configs/colonnade.yaml, canopy.yaml, window.yaml
        "colonnade": {
            "scene": {"meshes": [
                {"procedural": "ground_plane", "params": {"size": 80.0}},
                {"procedural": "colonnade", "params": {"pillars": 12, "spacing": 2.0, "radius": 0.3, "height": 5.0,
                                                       "segments": 24, "row_gap": 5.0}},
            ]},
            "camera": {"position": [-12.0, 1.7, -7.0], "look_at": [0.0, 2.5, 2.0], "fov_y": 55, "near": 0.1,
                       "far": 120.0},
            "light": {"type": "directional", "direction": [-0.5, -0.35, -1.0], "irradiance": [3.2, 2.9, 2.4]},
            "medium": {"sigma_t": 0.08, "albedo": 1.0, "phase": {"type": "henyey_greenstein", "g": 0.6}},
        },
        "canopy": {
            "scene": {"meshes": [
                {"procedural": "ground_plane", "params": {"size": 80.0}},
                {"procedural": "canopy", "params": {"leaves": leaves, "radius": 3.0, "trunk_height": 3.0, "seed": 0,
                                                    "leaf_size": 0.25}},
            ]},
            "camera": {"position": [2.0, 1.6, -10.0], "look_at": [0.0, 3.8, 0.0], "fov_y": 50, "near": 0.1,
                       "far": 100.0},
            "light": {"type": "directional", "direction": [0.3, -0.6, -1.0], "irradiance": [3.0, 2.8, 2.3]},
            "medium": {"sigma_t": 0.1, "albedo": 1.0, "phase": {"type": "henyey_greenstein", "g": 0.6}},
        },
        "window": {
            "scene": {"meshes": [
                {"procedural": "room_window", "params": {"size": [8.0, 4.0, 8.0], "window": [2.0, 1.8],
                                                         "window_center": [0.0, 2.3], "panes": [2, 2],
                                                         "mullion": 0.1}},
            ]},
            "camera": {"position": [2.8, 1.6, 3.4], "look_at": [-0.4, 1.4, -1.5], "fov_y": 60, "near": 0.05,
                       "far": 30.0},
            "light": {"type": "directional", "direction": [0.35, -0.6, 1.0], "irradiance": [4.0, 3.7, 3.1]},
            "medium": {"sigma_t": 0.15, "albedo": 1.0, "phase": {"type": "henyey_greenstein", "g": 0.5}},
        },
    }
    scenes["colonnade_spot"] = {**scenes["colonnade"], "light": {
        "type": "spot", "position": [10.0, 25.0, 14.0], "direction": [-10.0, -22.5, -14.0], "cone_deg": 25.0,
        "intensity": [2400.0, 2250.0, 2100.0], "texture": str(bench_light_texture())}}
    data = dict(scenes[name])
    if receiver_only_ground:
        data["scene"] = {"meshes": [{**m, "receiver_only": m.get("procedural") == "ground_plane"}
                                    for m in data["scene"]["meshes"]]}
    data["camera"] = {**data["camera"], "width": width, "height": height}
    data["render"] = render
    return Config.from_dict(data)


# ---- suites ----------------------------------------------------------------------------------------


def _dense_mesh(min_triangles: int):
    """A height-field terrain with at least ``min_triangles`` triangles (from the procedural generators)."""
    from .scene.procedural import terrain

    res = int(np.ceil(np.sqrt(min_triangles / 2.0))) + 1
    mesh = terrain(size=40.0, resolution=res, amplitude=3.0, seed=1)
    return mesh.vertices, mesh.triangles


def suite_raster(report: BenchReport, repeats: int, warmup: int, quick: bool, progress: ProgressFn | None):
    from . import raster, raycast
    from .scene.camera import Camera

    size = 256 if quick else 1024
    verts, tris = _dense_mesh(100_000 if quick else 1_000_000)
    cam = Camera(position=[0.0, 25.0, 30.0], look_at=[0.0, 0.0, 0.0], up=[0, 1, 0], fov_y=55, width=size,
                 height=size, near=0.5, far=200.0)
    vp = cam.view_projection()
    t0 = time.perf_counter()
    wp.load_module(raster, device=default_device())
    wp.load_module(raycast, device=default_device())
    compile_s = time.perf_counter() - t0
    params = {"size": f"{size}x{size}", "triangles": len(tris)}
    if progress:
        progress("raster", 0.0)
    m = measure(lambda: raster.rasterize(verts, tris, vp, size, size), repeats, warmup)
    r_raster = report.add(name="raster", params=params, median_ms=1e3 * m["median_s"],
                          extra={"compile_s": round(compile_s, 2)})
    if progress:
        progress("raycast (wp.Mesh)", 0.3)
    t0 = time.perf_counter()
    mesh = raycast.build_mesh(verts, tris)
    build_s = time.perf_counter() - t0
    m2 = measure(lambda: raycast.raycast_depth(mesh, vp, size, size), repeats, warmup)
    report.add(name="raycast wp.Mesh", params=params, median_ms=1e3 * m2["median_s"],
               extra={"bvh_build_ms": round(1e3 * build_s, 1)})
    r_raster["speedup"] = m2["median_s"] / m["median_s"]  # raster vs BVH ray casting
    try:
        import embreex  # noqa: F401
    except ImportError:
        report.meta["embree"] = "not installed (pip install warpscatter[peers])"
    else:
        if progress:
            progress("raycast (Embree)", 0.7)
        t_embree, build_e = _embree_primary(verts, tris, cam, repeats, warmup)
        report.add(name="raycast Embree", params=params, median_ms=1e3 * t_embree,
                   extra={"bvh_build_ms": round(1e3 * build_e, 1), "threads": 1})
        r_raster["extra"]["vs_embree"] = f"{t_embree / m['median_s']:.2f}x"
    if progress:
        progress("raster", 1.0)


def _embree_primary(verts, tris, cam, repeats, warmup) -> tuple[float, float]:
    """Median time of one primary ray per pixel with Embree (embreex), and its BVH build time."""
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    t0 = time.perf_counter()
    scene = rtcore_scene.EmbreeScene()
    TriangleMesh(scene, verts.astype(np.float32)[tris])
    dirs = cam.ray_directions().reshape(-1, 3).astype(np.float32)
    origins = np.broadcast_to(cam.position.astype(np.float32), dirs.shape).copy()
    scene.run(origins[:1], dirs[:1])  # forces the BVH build
    build = time.perf_counter() - t0
    m = measure(lambda: scene.run(origins, dirs, output=1), repeats, warmup)
    return m["median_s"], build


def _render_timed(cfg, repeats, warmup, device=None, with_stats: bool = False):
    """Render a config's stages ``warmup + repeats`` times; per-stage medians (ms), images, compile time, the
    scene (and the render's stats with ``with_stats``)."""
    from .pipeline import StageTimer, compile_kernels, render_images
    from .scene import build_scene

    t0 = time.perf_counter()
    compile_kernels(device)
    compile_s = time.perf_counter() - t0
    scene = build_scene(cfg)
    runs, images = [], None
    for k in range(warmup + max(1, repeats)):
        timer = StageTimer()
        images, stats = render_images(scene, cfg.render, timer=timer, device=device)
        if k >= warmup:
            runs.append(timer.timings)
    stages = {name: 1e3 * statistics.median(r[name] for r in runs) for name in runs[0] if name != "compile"}
    return (stages, images, compile_s, scene, stats) if with_stats else (stages, images, compile_s, scene)


def suite_reference(report: BenchReport, repeats: int, warmup: int, quick: bool, progress: ProgressFn | None):
    w, h, steps = (480, 270, 32) if quick else (1920, 1080, 128)
    rows = {}
    for k, vis in enumerate(("exact", "shadow_map")):
        if progress:
            progress(f"raymarch {vis}", k / 2)
        cfg = bench_scene_config("colonnade", w, h, scattering={"method": "raymarch", "visibility": vis,
                                                                "steps": steps, "shadow_map": {"resolution": 1024}},
                                 surfaces={"enabled": False})
        # exact visibility casts w*h*steps shadow rays: one timed run, no warm-up beyond the compile
        reps, warm = (1, 0) if vis == "exact" else (repeats, warmup)
        stages, images, compile_s, scene = _render_timed(cfg, reps, warm)
        total = sum(stages.values())
        rows[vis] = (report.add(name=f"raymarch {vis}", params={"size": f"{w}x{h}", "steps": steps,
                                                                "scene": "colonnade"},
                                median_ms=total, stages_ms=stages,
                                extra={"compile_s": round(compile_s, 2), "repeats": reps,
                                       "Mrays_per_s": round(w * h * steps / total / 1e3, 1)}), images)
    ref = rows["exact"][1]["scattering"]
    for vis, (row, images) in rows.items():
        row["speedup"] = rows["exact"][0]["median_ms"] / row["median_ms"]
        if vis != "exact":
            row.update(errors(images["scattering"], ref))
    if progress:
        progress("reference", 1.0)


def suite_parallel(report: BenchReport, repeats: int, warmup: int, quick: bool, progress: ProgressFn | None):
    from . import raster
    from .parallel import thread_count
    from .scene.camera import Camera

    n = thread_count()
    size = 256 if quick else 1024
    verts, tris = _dense_mesh(50_000 if quick else 500_000)
    cam = Camera(position=[0.0, 25.0, 30.0], look_at=[0.0, 0.0, 0.0], up=[0, 1, 0], fov_y=55, width=size,
                 height=size, near=0.5, far=200.0)
    w, h, steps = (240, 135, 32) if quick else (960, 540, 64)
    cfg = bench_scene_config("colonnade", w, h, scattering={"method": "raymarch", "visibility": "shadow_map",
                                                            "steps": steps}, surfaces={"enabled": False})
    for k, threads in enumerate((1, n)):
        if progress:
            progress(f"{threads} thread(s)", k / 2)
        with thread_limit(threads):
            m = measure(lambda: raster.rasterize(verts, tris, cam.view_projection(), size, size), repeats, warmup)
            report.add(name="raster", params={"threads": threads, "triangles": len(tris), "size": size},
                       median_ms=1e3 * m["median_s"])
            stages, _, _, _ = _render_timed(cfg, repeats, warmup)
            report.add(name="raymarch shadow_map", params={"threads": threads, "size": f"{w}x{h}", "steps": steps},
                       median_ms=stages["scattering"])
    by = {(r["name"], r["params"]["threads"]): r for r in report.rows}
    for name in ("raster", "raymarch shadow_map"):
        by[(name, n)]["speedup"] = by[(name, 1)]["median_ms"] / by[(name, n)]["median_ms"]
        by[(name, 1)]["speedup"] = 1.0
    if progress:
        progress("parallel", 1.0)


def _scattering_rows(report, name, cfg_kw, params, repeats, warmup, reference=None, extra=None):
    """Time one render configuration's scattering stages; add a row with errors against ``reference``."""
    cfg = bench_scene_config(**cfg_kw)
    stages, images, compile_s, scene, stats = _render_timed(cfg, repeats, warmup, with_stats=True)
    technique = {k: v for k, v in stages.items() if k not in ("upload", "bvh", "gbuffer", "shadow_map", "shading")}
    marched = stats.get("epipole_raymarched_fraction")
    row = report.add(name=name, params=params, median_ms=sum(technique.values()), stages_ms=technique,
                     extra={"compile_s": round(compile_s, 2), **(extra or {}),
                            **({"epipole_pct": round(100 * marched, 2)} if marched is not None else {})})
    if reference is not None:
        row.update(errors(images["scattering"], reference))
    return row, images


def suite_prefiltered(report: BenchReport, repeats: int, warmup: int, quick: bool, progress: ProgressFn | None):
    """Klehm 2014 Table 2 style sweeps for the ``fourier`` method, plus the speed/error bar of issue #3."""
    full = (480, 270) if quick else (1920, 1080)
    smap = 256 if quick else 1024
    no_surf = {"enabled": False}

    def fourier(m=32, res=smap, **f):
        return {"method": "fourier", "shadow_map": {"resolution": res}, "fourier": {"coefficients": m, **f}}

    def march(steps, vis="shadow_map", res=smap):
        return {"method": "raymarch", "visibility": vis, "steps": steps, "shadow_map": {"resolution": res}}

    # ---- the bar: colonnade at full HD, 1024^2 map ----
    if progress:
        progress("exact reference", 0.0)
    w, h = full
    ref_row, ref_img = _scattering_rows(report, "raymarch exact (reference)", {
        "name": "colonnade", "width": w, "height": h, "scattering": march(128, "exact"), "surfaces": no_surf},
        {"scene": "colonnade", "size": f"{w}x{h}", "steps": 128}, 1, 0)
    reference = ref_img["scattering"]
    rows = {}
    # the brute-force marcher (exact visibility) at 32 steps with another seed: its error against the reference is
    # its own noise, the bar's error threshold; the shadow-map marcher shows the same at the cheaper visibility
    for label, sc, reps in (("raymarch exact 32", {**march(32, "exact"), "seed": 1}, 1),
                            ("raymarch shadow_map 128", march(128), repeats), ("raymarch shadow_map 32", march(32),
                                                                               repeats),
                            ("fourier M=32", fourier(), repeats),
                            ("fourier M=32 filtered resampling",  # Peters 2017 Sec. 5.2
                             {**fourier(), "prefiltered": {"resample_filter": "moments"}}, repeats)):
        if progress:
            progress(label, 0.1)
        rows[label], _ = _scattering_rows(report, label, {"name": "colonnade", "width": w, "height": h,
                                                          "scattering": sc, "surfaces": no_surf},
                                          {"scene": "colonnade", "size": f"{w}x{h}", "map": smap}, reps,
                                          warmup if reps > 1 else 0, reference)
    base = ref_row["median_ms"]
    for r in (*rows.values(), ref_row):
        r["speedup"] = base / r["median_ms"]  # against the brute-force (exact) 128-step marcher of this run
    f = rows["fourier M=32"]
    report.meta["bar"] = {
        "fourier_speedup_vs_exact_raymarch128": round(f["speedup"], 2),
        "fourier_speedup_vs_shadow_map_raymarch128": round(rows["raymarch shadow_map 128"]["median_ms"]
                                                           / f["median_ms"], 2),
        "fourier_rel_l1": round(f["rel_l1"], 4),
        "exact_raymarch32_rel_l1": round(rows["raymarch exact 32"]["rel_l1"], 4),
        "shadow_map_raymarch32_rel_l1": round(rows["raymarch shadow_map 32"]["rel_l1"], 4),
        "fourier_epipole_pct": f["extra"].get("epipole_pct"),
    }

    # ---- sweeps (Klehm 2014 Table 2): map size, output size, basis count ----
    maps = [(256, 256), (512, 512)] if quick else [(512, 512), (1024, 1024), (2048, 2048), (4096, 1024)]
    outs = [(240, 135), (480, 270)] if quick else [(480, 270), (960, 540), (1920, 1080), (3840, 2160)]
    counts = [4, 32] if quick else [4, 8, 16, 32, 64, 128]
    for k, (mw, mh) in enumerate(maps):
        if progress:
            progress(f"map {mw}x{mh}", 0.3 + 0.1 * k / len(maps))
        _scattering_rows(report, "fourier map sweep", {"name": "colonnade", "width": w, "height": h,
                                                           "scattering": fourier(res=[mw, mh]), "surfaces": no_surf},
                         {"map": f"{mw}x{mh}", "size": f"{w}x{h}", "M": 32}, repeats, warmup,
                         extra={"filtered_basis_MB": round(mw * mh * 32 * 4 / 2**20, 1)})
    for k, (ow, oh) in enumerate(outs):
        if progress:
            progress(f"output {ow}x{oh}", 0.4 + 0.1 * k / len(outs))
        _scattering_rows(report, "fourier output sweep", {"name": "colonnade", "width": ow, "height": oh,
                                                              "scattering": fourier(), "surfaces": no_surf},
                         {"size": f"{ow}x{oh}", "map": smap, "M": 32}, repeats, warmup)
    for k, m in enumerate(counts):
        if progress:
            progress(f"M={m}", 0.5 + 0.1 * k / len(counts))
        _scattering_rows(report, "fourier basis sweep", {"name": "colonnade", "width": w, "height": h,
                                                             "scattering": fourier(m), "surfaces": no_surf},
                         {"M": m, "size": f"{w}x{h}", "map": smap}, repeats, warmup,
                         extra={"bytes_per_texel": 4 * m, "bytes_per_texel_8bit": m})

    # ---- scene complexity: canopy leaves x1 .. x100; the fourier evaluation stays flat ----
    cw, ch = (240, 135) if quick else (480, 270)
    steps = 16 if quick else 32
    leaf_counts = [1000, 10000] if quick else [1000, 10000, 100000]
    for k, leaves in enumerate(leaf_counts):
        if progress:
            progress(f"canopy {leaves} leaves", 0.7 + 0.3 * k / len(leaf_counts))
        common = {"name": "canopy", "width": cw, "height": ch, "leaves": leaves, "surfaces": no_surf}
        params = {"leaves": leaves, "triangles": 2 * leaves, "size": f"{cw}x{ch}"}
        _scattering_rows(report, "complexity fourier", dict(common, scattering=fourier()), params, repeats, warmup)
        _scattering_rows(report, f"complexity raymarch exact {steps}", dict(common, scattering=march(steps, "exact")),
                         params, 1, 0)


def suite_moments(report: BenchReport, repeats: int, warmup: int, quick: bool, progress: ProgressFn | None):
    """Peters 2017 Fig. 15-16/19 style: the prefiltered methods and the marcher on three scenes (colonnade and canopy
    also with a receiver-only ground); soft shadows."""
    w, h = (240, 135) if quick else (960, 540)
    smap = 256 if quick else 1024
    no_surf = {"enabled": False}
    methods = [("raymarch shadow_map 128", {"method": "raymarch", "visibility": "shadow_map", "steps": 128}),
               ("fourier M=32", {"method": "fourier"}), ("fourier M=32 8-bit", {"method": "fourier",
                                                                             "fourier": {"storage_bits": 8}})]
    methods += [(f"{m} {b}-bit", {"method": m, "moments": {"storage_bits": b}})
                for m, bits in (("moments4", (64, 128)), ("moments6", (64, 96, 192))) for b in bits]
    # caster culling (warpscatter's, on by default for the moment methods only): each side of the default
    methods += [("fourier M=32 culled", {"method": "fourier", "prefiltered": {"caster_culling": True}}),
                ("moments6 192-bit unculled", {"method": "moments6", "moments": {"storage_bits": 192},
                                               "prefiltered": {"caster_culling": False}})]
    # filtering during resampling (Peters 2017 Sec. 5.2, Fig. 17): a filtered 4-moment map and Algorithm 2
    methods += [(f"{label} filtered", {**sc, "prefiltered": {"resample_filter": "moments"}}) for label, sc in methods
                if label in ("fourier M=32", "moments4 64-bit", "moments6 64-bit", "moments6 192-bit")]
    # each scene as configured, and colonnade / canopy once more with the ground plane receiver_only: the ground
    # shadows nothing visible (the exact image is the same), but the shadow map is fitted to the casters and no
    # ray that ends on the ground sees the ground's own depths just behind its fragment depth in the rectified map
    # (where moment bounds are loosest; caster culling removes most of those too)
    variants = [("colonnade", False), ("colonnade", True), ("canopy", False), ("canopy", True), ("window", False)]
    casting_refs = {}
    for k, (scene, ro_ground) in enumerate(variants):
        title = f"{scene} (receiver-only ground)" if ro_ground else scene
        if progress:
            progress(f"{title}: exact reference", 0.8 * k / len(variants))
        _, ref = _scattering_rows(report, f"{title}: raymarch exact (reference)", {
            "name": scene, "width": w, "height": h, "receiver_only_ground": ro_ground,
            "scattering": {"method": "raymarch", "visibility": "exact", "steps": 128}, "surfaces": no_surf},
            {"size": f"{w}x{h}", "steps": 128}, 1, 0)
        if ro_ground:  # the flag must not change the exact image (same seed): the difference is reported
            report.rows[-1]["extra"]["vs_casting_ground_rel_l1"] = errors(ref["scattering"],
                                                                          casting_refs[scene])["rel_l1"]
        else:
            casting_refs[scene] = ref["scattering"]
        rows = {}
        for label, sc in methods:
            if progress:
                progress(f"{title}: {label}", 0.8 * k / len(variants))
            sc = {**sc, "shadow_map": {"resolution": smap}}
            rows[label], img = _scattering_rows(report, f"{title}: {label}", {
                "name": scene, "width": w, "height": h, "receiver_only_ground": ro_ground, "scattering": sc,
                "surfaces": no_surf}, {"size": f"{w}x{h}", "map": smap}, repeats, warmup, ref["scattering"])
            bits = 32 * (8 if "8-bit" in label else 32) if label.startswith("fourier") else (
                int(label.split()[1].split("-")[0]) if label.startswith("moments") else None)
            if bits:
                rows[label]["extra"]["bits_per_texel"] = bits
        base = rows["raymarch shadow_map 128"]["median_ms"]
        for r in rows.values():
            r["speedup"] = base / r["median_ms"]
    # ---- soft shadows on surfaces: moment soft shadows against the PCSS brute force ----
    if progress:
        progress("soft shadows", 0.8)
    from .config import Config
    from .pipeline import StageTimer, render_images
    from .scene import build_scene

    images = {}
    for method in ("pcss", "msm_soft"):
        cfg = bench_scene_config("colonnade", w, h, scattering={"method": "raymarch", "visibility": "shadow_map",
                                                                "steps": 1, "shadow_map": {"resolution": smap}},
                                 shadows={"method": method, "light_angle_deg": 2.0})
        cfg = Config.from_dict({**cfg.model_dump(mode="json"), "medium": {"sigma_t": 0.0}})
        scene = build_scene(cfg)
        runs = []
        for k in range(warmup + repeats):
            timer = StageTimer()
            img, stats = render_images(scene, cfg.render, timer=timer)
            if k >= warmup:
                runs.append(timer.timings)
        stages = {n: 1e3 * statistics.median(r[n] for r in runs) for n in runs[0]
                  if n in ("msm_generate", "msm_sat", "shading")}
        images[method] = img["surface"]
        report.add(name=f"soft shadows {method}", params={"size": f"{w}x{h}", "map": smap, "light_angle_deg": 2.0},
                   median_ms=sum(stages.values()), stages_ms=stages,
                   extra={k: v for k, v in stats.items() if k in ("sat_bytes",)})
    report.rows[-1].update(errors(images["msm_soft"], images["pcss"]))
    report.rows[-1]["speedup"] = report.rows[-2]["median_ms"] / report.rows[-1]["median_ms"]


def suite_epipolar(report: BenchReport, repeats: int, warmup: int, quick: bool, progress: ProgressFn | None):
    """Engelhardt & Dachsbacher 2010: fraction ray-marched, stage times and errors for line / sample counts.

    Every epipolar row is compared with the per-pixel marcher at the same steps AND the same step pattern
    (``jitter``; the sweep uses the default ``per_pixel``, the bar case 1024 lines / 16 samples is repeated with
    ``fixed``), with the exact-visibility reference (per-pixel jitter, same steps) and with a converged marcher
    (8x steps, another seed: its own noise is about 1/8 of the others').
    """
    w, h = (320, 180) if quick else (1920, 1080)
    steps = 32 if quick else 128
    smap = 256 if quick else 1024
    no_surf = {"enabled": False}
    scene = "colonnade_spot"
    size = f"{w}x{h}"
    common = {"name": scene, "width": w, "height": h, "surfaces": no_surf}
    march = {"method": "raymarch", "visibility": "shadow_map", "steps": steps, "shadow_map": {"resolution": smap}}
    if progress:
        progress("exact reference", 0.0)
    _, exact = _scattering_rows(report, "raymarch exact (reference)",
                                dict(common, scattering={**march, "visibility": "exact"}),
                                {"scene": scene, "size": size, "steps": steps, "jitter": "per_pixel"}, 1, 0)
    # the same marcher with 8x the steps: a converged reference that still includes the light texture, against
    # which the per-pixel marcher's own noise (textured lights) shows too
    if progress:
        progress("converged marcher", 0.05)
    _, converged = _scattering_rows(report, "raymarch shadow_map (8x steps, converged)",
                                    dict(common, scattering={**march, "steps": 8 * steps, "seed": 11}),
                                    {"scene": scene, "size": size, "steps": 8 * steps, "jitter": "per_pixel"}, 1, 0,
                                    exact["scattering"])
    per_pixel = {}
    for k, jitter in enumerate(("per_pixel", "fixed")):
        if progress:
            progress(f"per-pixel ray marching ({jitter})", 0.1 + 0.05 * k)
        row, images = _scattering_rows(report, f"raymarch shadow_map (per pixel, {jitter})",
                                       dict(common, scattering={**march, "jitter": jitter}),
                                       {"scene": scene, "size": size, "steps": steps, "jitter": jitter}, repeats,
                                       warmup, exact["scattering"])
        row["speedup"] = 1.0
        row["extra"]["rel_l1_vs_converged"] = round(errors(images["scattering"], converged["scattering"])["rel_l1"],
                                                    4)
        per_pixel[jitter] = (row, images["scattering"])
    line_counts = [256, 1024] if quick else [256, 512, 1024]
    sample_counts = [8, 16] if quick else [8, 16, 32]
    cases = [(n, s, "per_pixel") for n in line_counts for s in sample_counts] + [(1024, 16, "fixed")]
    from .pipeline import render_images as _ri

    for k, (n_lines, n_init, jitter) in enumerate(cases):
        if progress:
            progress(f"{n_lines} lines, {n_init} samples, {jitter}", 0.2 + 0.8 * k / len(cases))
        sc = {**march, "method": "epipolar", "jitter": jitter,
              "epipolar": {"lines": n_lines, "initial_samples": n_init}}
        cfg = bench_scene_config(**dict(common, scattering=sc))
        stages, images, compile_s, scene_obj = _render_timed(cfg, repeats, warmup)
        _, stats = _ri(scene_obj, cfg.render)
        technique = {k2: v for k2, v in stages.items() if k2 in ("lines", "discontinuities", "raymarch", "interpolate")}
        pp_row, pp_img = per_pixel[jitter]
        row = report.add(name="epipolar", params={"lines": n_lines, "initial": n_init, "size": size, "steps": steps,
                                                   "jitter": jitter},
                         median_ms=sum(technique.values()), stages_ms=technique,
                         extra={"raymarched_pct": round(100 * stats["epipolar_raymarched_fraction"], 2),
                                "rel_l1_vs_per_pixel": round(errors(images["scattering"], pp_img)["rel_l1"], 4),
                                "rel_l1_vs_converged": round(errors(images["scattering"],
                                                                    converged["scattering"])["rel_l1"], 4)})
        row.update(errors(images["scattering"], exact["scattering"]))
        row["speedup"] = pp_row["median_ms"] / row["median_ms"]
    bar = {}
    for jitter in ("per_pixel", "fixed"):
        best = [r for r in report.rows if r["name"] == "epipolar" and r["params"]["lines"] == 1024
                and r["params"]["initial"] == 16 and r["params"]["jitter"] == jitter]
        if best:
            bar[jitter] = {"speedup_vs_per_pixel": round(best[0]["speedup"], 2),
                           "rel_l1_vs_per_pixel": best[0]["extra"]["rel_l1_vs_per_pixel"],
                           "rel_l1_vs_converged": best[0]["extra"]["rel_l1_vs_converged"],
                           "per_pixel_rel_l1_vs_converged": per_pixel[jitter][0]["extra"]["rel_l1_vs_converged"]}
    if bar:
        report.meta["bar"] = bar  # the bar figure is the default step pattern, bar["per_pixel"]


def _bumpy_sphere(count: int) -> tuple[np.ndarray, np.ndarray]:
    """A closed, bumpy UV sphere (2 count^2 - ... triangles; count 246: about 240k) for the CSM suite."""
    import trimesh

    m = trimesh.creation.uv_sphere(radius=1.0, count=[count, count])
    n = np.asarray(m.vertices, np.float64)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    rng = np.random.default_rng(0)
    k, ph = rng.normal(size=(24, 3)) * 3.0, rng.uniform(0.0, 2.0 * np.pi, 24)
    r = 1.0 + 0.5 * np.mean(np.sin(n @ k.T + ph), axis=1)
    return (n * r[:, None]).astype(np.float32), np.asarray(m.faces, np.int32)


def suite_csm(report: BenchReport, repeats: int, warmup: int, quick: bool, progress: ProgressFn | None):
    """Ritschel 2007 Tables 1-2: compression vs N and enumeration; queries/s against BVH shadow rays."""
    from .csm import build_csm, csm_device_data
    from .csm.query import visibility_kernel
    from .parallel import launch_rows
    from .raycast import build_mesh, shadow_ray_visibility

    verts, tris = _bumpy_sphere(60 if quick else 246)
    res = 64 if quick else 128
    sides = [8, 16] if quick else [32, 64, 128]
    cases = [(n, "hilbert") for n in sides] + [(sides[1], e) for e in ("zigzag", "scanline")]
    csms = {}
    for k, (n, enum) in enumerate(cases):
        if progress:
            progress(f"CSM N={n}^2 {enum}", 0.7 * k / len(cases))
        t0 = time.perf_counter()
        csm = build_csm(verts, tris, n1=n, n2=n, resolution=res, enumeration=enum)
        st = csm.stats
        csms[(n, enum)] = csm
        report.add(name="csm precompute", params={"N": f"{n}x{n}", "M": res, "enumeration": enum,
                                                  "triangles": len(tris)},
                   median_ms=1e3 * (time.perf_counter() - t0),
                   stages_ms={"render": 1e3 * st.seconds_render, "compress": 1e3 * st.seconds_compress},
                   extra={"ratio": round(st.ratio, 1), "segments_per_texel": round(st.segments_per_texel, 1),
                          "MB": round(st.compressed_bytes / 2**20, 1),
                          "peak_working_MB": round(st.peak_working_bytes / 2**20, 1)})
    # ---- queries: surface points, random (upper hemisphere) and coherent directions ----
    csm = csms[(sides[-1], "hilbert")]
    rng = np.random.default_rng(0)
    count = 200_000 if quick else 2_000_000
    tri = verts[tris]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    idx = rng.choice(len(tris), size=count, p=area / area.sum())
    a, b = rng.random((2, count))
    sa = np.sqrt(a)
    bary = np.stack([1 - sa, sa * (1 - b), sa * b], 1)
    points = np.einsum("kj,kjc->kc", bary, tri[idx]).astype(np.float32)
    normal = np.cross(tri[idx, 1] - tri[idx, 0], tri[idx, 2] - tri[idx, 0])
    random_dirs = rng.normal(size=(count, 3))
    random_dirs[np.sum(random_dirs * normal, axis=1) < 0] *= -1
    coherent = np.tile(np.array([0.3, 0.8, 0.52]) / np.linalg.norm([0.3, 0.8, 0.52]), (count, 1))
    mesh = build_mesh(verts, tris)
    data = csm_device_data(csm)
    pts = wp.array(points, dtype=wp.vec3)
    out = wp.empty(count, dtype=wp.float32)
    eps = 1e-4 * float(csm.radius)
    for k, (label, dirs) in enumerate((("random", random_dirs), ("coherent", coherent))):
        if progress:
            progress(f"queries {label}", 0.7 + 0.15 * k)
        d = wp.array(dirs.astype(np.float32), dtype=wp.vec3)
        rows = {}
        for method in ("csm nearest", "csm pcf", "bvh shadow rays"):
            if method == "bvh shadow rays":
                def fn(d=d):
                    return shadow_ray_visibility(mesh, pts, d, eps=eps)
            else:
                mode = 1 if method == "csm pcf" else 0

                def fn(mode=mode, d=d):
                    launch_rows(visibility_kernel, count, [data, pts, d, 0.0, mode, 0, out], min_chunk=1024)
                    return out
            m = measure(fn, repeats, warmup)
            vis = fn().numpy().copy()
            rows[method] = (report.add(name=f"queries {label}: {method}",
                                       params={"queries": count, "N": f"{sides[-1]}x{sides[-1]}", "M": res},
                                       median_ms=1e3 * m["median_s"],
                                       extra={"Mqueries_per_s": round(count / m["median_s"] / 1e6, 2),
                                              "mean_visibility": round(float(vis.mean()), 4)}), vis)
        ref_ms = rows["bvh shadow rays"][0]["median_ms"]
        for method, (row, vis) in rows.items():
            row["speedup"] = ref_ms / row["median_ms"]
            if method == "csm nearest":
                row["extra"]["agreement_with_bvh"] = round(float(np.mean((vis > 0.5) == (rows["bvh shadow rays"][1]
                                                                                            > 0.5))), 4)
    _csm_render_rows(report, repeats, warmup, quick, progress, verts, tris)


def _csm_render_rows(report, repeats, warmup, quick, progress, verts, tris):
    """The ``csm`` render method against ``raytrace`` (wp.Mesh shadow rays) in the same run: time per progressive
    pass (median over warmup + repeats passes), CSM build time, and the image error against the reference."""
    import tempfile

    import trimesh
    import yaml

    from .config import load_config
    from .pipeline import render

    root = Path(__file__).resolve().parent.parent
    w, h = (160, 90) if quick else (320, 180)
    common = [f"camera.width={w}", f"camera.height={h}", "render.lighting.samples=16", "render.lighting.write_every=0",
              f"render.lighting.passes={warmup + repeats}"]
    with tempfile.TemporaryDirectory() as tmp:
        obj = Path(tmp) / "bumpy.obj"
        trimesh.Trimesh(verts, tris, process=False).export(obj)
        sphere = {"scene": {"meshes": [
            {"path": str(obj), "transform": {"translate": [0, 1.6, 0]}, "material": {"albedo": [0.7, 0.7, 0.7]}},
            {"procedural": "ground_plane", "params": {"size": 12}, "receiver_only": True}]},
            "camera": {"position": [0, 3.5, -6], "look_at": [0, 1, 0], "fov_y": 45},
            "light": {"type": "environment", "map": str(root / "assets" / "sky_small.exr")},
            "medium": {"sigma_t": 0.0}, "render": {"lighting": {"method": "csm"}}}  # fmt: skip
        (Path(tmp) / "bumpy.yaml").write_text(yaml.safe_dump(sphere))
        files = {"gate": root / "configs" / "csm_gate.yaml", f"bumpy sphere {len(tris)} tris": Path(tmp) / "bumpy.yaml"}
        scenes = {k: (lambda extra, f=f: load_config(f, common + extra)) for k, f in files.items()}
        for k, (label, make) in enumerate(scenes.items()):
            if progress:
                progress(f"render csm vs raytrace: {label}", 0.85 + 0.075 * k)
            ref = render(make(["render.lighting.method=raytrace"]), write=False)
            got = render(make([]), write=False)
            ref_ms = 1e3 * ref.stats["seconds_per_pass"]
            params = {"scene": label, "size": f"{w}x{h}", "samples": 16, "passes": warmup + repeats}
            report.add(name="render raytrace (per pass)", params=params, median_ms=ref_ms,
                       stages_ms={"bvh": 1e3 * ref.timings.get("bvh", 0.0)}, speedup=1.0)
            report.add(name="render csm (per pass)", params={**params, "N": "x".join(map(str, got.stats["csm_maps"])),
                                                             "M": got.stats["csm_resolution"]},
                       median_ms=1e3 * got.stats["seconds_per_pass"], stages_ms={"csm": 1e3 * got.timings["csm"]},
                       speedup=ref_ms / (1e3 * got.stats["seconds_per_pass"]),
                       **errors(got.images["surface"], ref.images["surface"]))


_SUITE_FNS = {"raster": suite_raster, "reference": suite_reference, "parallel": suite_parallel,
              "prefiltered": suite_prefiltered, "moments": suite_moments, "epipolar": suite_epipolar,
              "csm": suite_csm}


def run(suite: str = "reference", *, repeats: int = 5, warmup: int = 1, out_dir: Path | None = None,
        quick: bool = False, progress: ProgressFn | None = None) -> BenchReport:
    """Run one suite (or ``"all"``) and write its JSON/PNG into ``out_dir`` (default ``bench-out``).

    Raises:
        ValueError: unknown suite name, or repeats < 1 / warmup < 0.
    """
    names = list(SUITES) if suite == "all" else [suite]
    for s in names:
        if s not in SUITES:
            raise ValueError(f"unknown bench suite {s!r} (choose from {', '.join(SUITES)}, all)")
    if repeats < 1 or warmup < 0:
        raise ValueError("repeats must be >= 1 and warmup >= 0")
    init()
    out_dir = Path(out_dir) if out_dir is not None else Path("bench-out")
    reports = []
    for s in names:
        report = BenchReport(suite=s, meta={**machine_meta(), "repeats": repeats, "warmup": warmup, "quick": quick})
        _SUITE_FNS[s](report, repeats, warmup, quick, progress)
        report.write(out_dir)
        reports.append(report)
    if len(reports) == 1:
        return reports[0]
    merged = BenchReport(suite="all", meta=reports[0].meta)
    for r in reports:
        merged.rows += [{**row, "name": f"{r.suite}: {row['name']}"} for row in r.rows]
        merged.files += r.files
    return merged
