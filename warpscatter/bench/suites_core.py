"""Bench suites of the building blocks (:data:`warpscatter.bench.SUITES` describes them): ``raster`` (with Embree,
through embreex of the ``peers`` extra, when installed), ``reference`` and ``parallel``."""

from __future__ import annotations

import time

import numpy as np
import warp as wp

from ..runtime.device import default_device
from ..runtime.stages import ProgressFn
from .report import BenchReport, errors, measure, thread_limit
from .scenes import _dense_mesh, bench_scene_config, render_timed


def suite_raster(report: BenchReport, repeats: int, warmup: int, quick: bool, progress: ProgressFn | None):
    from ..raster import rasterizer as raster
    from ..raster import raycast
    from ..scene.camera import Camera

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
        stages, images, compile_s, _, _ = render_timed(cfg, reps, warm)
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


#: The renders whose every stage the ``parallel`` suite times with 1 thread and with all (colonnade, no surfaces).
SCALING_RENDERS = {
    "raymarch shadow_map": {"method": "raymarch", "visibility": "shadow_map", "steps": 32},
    "fourier": {"method": "fourier"},
    "moments6": {"method": "moments6"},
    "epipolar": {"method": "epipolar", "visibility": "shadow_map"},
}


def suite_parallel(report: BenchReport, repeats: int, warmup: int, quick: bool, progress: ProgressFn | None):
    """Speed-up of all threads over one: the rasterizer, and every stage of each render in :data:`SCALING_RENDERS`
    at 1920x1080 with 1024^2 maps (``--quick``: 320x180, 256^2). Each render row carries the per-stage times with
    all threads (``stages_ms``), with one (``extra.stages_ms_1_thread``) and their ratio (``extra.scaling``)."""
    from ..raster import rasterizer as raster
    from ..runtime.parallel import thread_count
    from ..scene.camera import Camera

    n = thread_count()
    size = 256 if quick else 1024
    verts, tris = _dense_mesh(50_000 if quick else 500_000)
    cam = Camera(position=[0.0, 25.0, 30.0], look_at=[0.0, 0.0, 0.0], up=[0, 1, 0], fov_y=55, width=size,
                 height=size, near=0.5, far=200.0)
    ms = {}
    for threads in (1, n):
        with thread_limit(threads):
            m = measure(lambda: raster.rasterize(verts, tris, cam.view_projection(), size, size), repeats, warmup)
        ms[threads] = 1e3 * m["median_s"]
    report.add(name="raster", params={"threads": n, "triangles": len(tris), "size": size}, median_ms=ms[n],
               speedup=ms[1] / ms[n], extra={"ms_1_thread": round(ms[1], 1)})
    w, h, smap = (320, 180, 256) if quick else (1920, 1080, 1024)
    for k, (label, scattering) in enumerate(SCALING_RENDERS.items()):
        if progress:
            progress(label, k / len(SCALING_RENDERS))
        cfg = bench_scene_config("colonnade", w, h, surfaces={"enabled": False},
                                 scattering={**scattering, "shadow_map": {"resolution": smap}})
        stages = {}
        for threads in (1, n):
            with thread_limit(threads):
                stages[threads] = render_timed(cfg, repeats, warmup)[0]
        total = {t: sum(st.values()) for t, st in stages.items()}
        report.add(name=label, params={"threads": n, "size": f"{w}x{h}", "map": smap}, median_ms=total[n],
                   stages_ms=stages[n], speedup=total[1] / total[n],
                   extra={"stages_ms_1_thread": {s: round(v, 1) for s, v in stages[1].items()},
                          "scaling": {s: round(stages[1][s] / v, 2) for s, v in stages[n].items() if v > 0.0}})
    if progress:
        progress("parallel", 1.0)
