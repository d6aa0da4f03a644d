"""Bench suites of the building blocks: ``raster``, ``reference`` and ``parallel``.

* ``raster``    — depth map of a >= 1M-triangle mesh: the Warp rasterizer against BVH ray casting (``wp.Mesh``)
  and Embree (embreex, the ``peers`` extra) when installed.
* ``reference`` — the ray marcher at 1920x1080, 128 steps, with shadow-map and exact visibility.
* ``parallel``  — speed-up of split CPU launches (1 thread against all) for the rasterizer and the marcher.
"""

from __future__ import annotations

import time

import numpy as np
import warp as wp

from ..stages import ProgressFn
from ..wpinit import default_device
from .report import BenchReport, errors, measure, thread_limit
from .scenes import _dense_mesh, bench_scene_config, render_timed


def suite_raster(report: BenchReport, repeats: int, warmup: int, quick: bool, progress: ProgressFn | None):
    from .. import raster, raycast
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


def suite_parallel(report: BenchReport, repeats: int, warmup: int, quick: bool, progress: ProgressFn | None):
    from .. import raster
    from ..parallel import thread_count
    from ..scene.camera import Camera

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
            stages = render_timed(cfg, repeats, warmup)[0]
            report.add(name="raymarch shadow_map", params={"threads": threads, "size": f"{w}x{h}", "steps": steps},
                       median_ms=stages["scattering"])
    by = {(r["name"], r["params"]["threads"]): r for r in report.rows}
    for name in ("raster", "raymarch shadow_map"):
        by[(name, n)]["speedup"] = by[(name, 1)]["median_ms"] / by[(name, n)]["median_ms"]
        by[(name, 1)]["speedup"] = 1.0
    if progress:
        progress("parallel", 1.0)
