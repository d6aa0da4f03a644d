"""Bench suite of coherent shadow maps (Ritschel 2007): ``csm``.

Compression ratio, precompute time and memory against the map count N and the enumeration (Tables 1-2);
visibility queries per second (random and coherent directions) against BVH shadow rays; the ``csm`` render
method's time per progressive pass and error against ``raytrace`` in the same run.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import warp as wp

from ..resources import bundled_asset, bundled_config
from ..stages import ProgressFn
from .report import BenchReport, errors, measure
from .scenes import _bumpy_sphere


def suite_csm(report: BenchReport, repeats: int, warmup: int, quick: bool, progress: ProgressFn | None):
    """Ritschel 2007 Tables 1-2: compression vs N and enumeration; queries/s against BVH shadow rays."""
    from ..csm import build_csm, csm_device_data
    from ..csm.query import visibility_kernel
    from ..parallel import launch_rows
    from ..raycast import build_mesh, shadow_ray_visibility

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

    from ..config import load_config
    from ..pipeline import render

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
            "light": {"type": "environment", "map": str(bundled_asset("sky_small.exr"))},
            "medium": {"sigma_t": 0.0}, "render": {"lighting": {"method": "csm"}}}
        (Path(tmp) / "bumpy.yaml").write_text(yaml.safe_dump(sphere))
        files = {"gate": bundled_config("csm_gate"), f"bumpy sphere {len(tris)} tris": Path(tmp) / "bumpy.yaml"}
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
