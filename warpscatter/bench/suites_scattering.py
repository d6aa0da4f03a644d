"""Bench suites of the single-scattering methods (:data:`warpscatter.bench.SUITES` describes them): ``prefiltered``,
``moments`` and ``epipolar``. Prefiltered rows also report ``filtered_map_MB``, ``prefilter_GBps`` and
``evaluate_ns_per_px``."""

from __future__ import annotations

import numpy as np
import warp as wp

from ..config import Config
from ..runtime.parallel import chunks, run_parallel, thread_count
from ..runtime.stages import ProgressFn
from .report import BenchReport, errors, measure
from .scenes import bench_scene_config, render_timed, scattering_rows

#: The prefilter's storage modes: (method, storage bits: fourier.storage_bits or moments.storage_bits).
PREFIX_SUM_MODES = (("fourier", 0), ("fourier", 8), ("moments4", 64), ("moments4", 128), ("moments6", 64),
                    ("moments6", 96), ("moments6", 192))
#: Coefficients of the fourier textures of the prefix-sum rows (the method's default).
PREFIX_SUM_COEFFICIENTS = 32


def storage_extras(row: dict, stats: dict, pixels: int) -> dict:
    """Add a prefiltered render row's texture size, prefilter throughput and evaluate time per pixel; returns it."""
    stages = row.get("stages_ms") or {}
    if "filtered_map_bytes" not in stats or "prefilter" not in stages:
        return row
    nbytes = stats["filtered_map_bytes"]
    row["extra"].update(filtered_map_MB=round(nbytes / 2**20, 2),
                        prefilter_GBps=round(nbytes / (1e-3 * stages["prefilter"]) / 1e9, 3),
                        evaluate_ns_per_px=round(1e6 * stages["evaluate"] / pixels, 1))
    return row


def bench_rectified_depth(size: int, seed: int = 0) -> np.ndarray:
    """A (size, size) rectified blocker-depth map like a real one: smooth depths per row, steps, empty columns."""
    rng = np.random.default_rng(seed)
    x = np.linspace(0.0, 1.0, size)
    d = 0.5 + 0.3 * np.sin(6.0 * x[None, :] + rng.uniform(0.0, 6.0, (size, 1)))
    d += 0.2 * (rng.uniform(0.0, 1.0, (size, size)) < 0.05)
    d[:, rng.integers(0, size, size // 10)] = 1.0
    return np.clip(d, 0.0, 1.0).astype(np.float32)


def memcpy_seconds(nbytes: int, repeats: int) -> tuple[float, int]:
    """The faster memcpy of ``nbytes``: median seconds on one thread or all pool threads, and that thread count."""
    src = np.random.default_rng(1).integers(0, 256, nbytes, dtype=np.uint8)
    dst = np.empty_like(src)
    best = (float("inf"), 1)
    for threads in sorted({1, thread_count()}):
        pieces = chunks(nbytes, threads)

        def copy(pieces=pieces, threads=threads):
            run_parallel(lambda p: np.copyto(dst[p[0]:p[1]], src[p[0]:p[1]]), pieces, threads)

        best = min(best, (measure(copy, repeats, 1)["median_s"], threads))
    return best


def prefix_sum_rows(report: BenchReport, modes, size: int, repeats: int, warmup: int) -> list[dict]:
    """Prefix-sum throughput (Peters 2017 App. C) of each storage mode on a (size, size) rectified map, in texture
    bytes written per second, against the faster memcpy (``x_memcpy``; the paper's GPU: 1.3x for 64-bit four moments,
    2.1x for six). Returns the rows added.
    """
    from ..runtime.device import default_device
    from ..scattering.prefiltered.prefix_sums import prefilter_moments, prefilter_weighted

    depth = wp.array(bench_rectified_depth(size), dtype=wp.float32, device=default_device())
    tau = np.full(size, 4.0 / size, np.float32)  # optical depth 4 over a row
    threads = thread_count()
    rows = []
    for method, bits in modes:
        if method == "fourier":
            def prefilter(b=bits):
                return prefilter_weighted(depth, PREFIX_SUM_COEFFICIENTS, tau, bits=b)
            label = f"fourier M={PREFIX_SUM_COEFFICIENTS} {'8-bit' if bits else 'float32'}"
        else:
            def prefilter(n=int(method[-1]), b=bits):
                return prefilter_moments(depth, n, tau, storage_bits=b)
            label = f"{method} {bits}-bit"
        texture = prefilter()
        nbytes = texture.nbytes
        seconds = measure(prefilter, repeats, warmup)["median_s"]
        copy_s, copy_threads = memcpy_seconds(nbytes, max(5, repeats))
        rows.append(report.add(
            name="prefix sums", params={"mode": label, "map": f"{size}x{size}"}, median_ms=1e3 * seconds,
            stages_ms={"prefilter": 1e3 * seconds},
            extra={"bits_per_texel": 8 * nbytes // (size * size), "texture_MB": round(nbytes / 2**20, 2),
                   "GBps": round(nbytes / seconds / 1e9, 3), "memcpy_GBps": round(nbytes / copy_s / 1e9, 3),
                   "memcpy_threads": copy_threads, "x_memcpy": round(seconds / copy_s, 2), "threads": threads}))
    report.meta["prefix_sums"] = {r["params"]["mode"]: {k: r["extra"][k] for k in ("GBps", "memcpy_GBps", "x_memcpy")}
                                  for r in rows}
    return rows


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
    ref_row, ref_img, _ = scattering_rows(report, "raymarch exact (reference)", {
        "name": "colonnade", "width": w, "height": h, "scattering": march(128, "exact"), "surfaces": no_surf},
        {"scene": "colonnade", "size": f"{w}x{h}", "steps": 128}, 1, 0)
    reference = ref_img["scattering"]
    rows = {}
    # the exact marcher at 32 steps with another seed: its error against the reference is the bar's threshold
    for label, sc, reps in (("raymarch exact 32", {**march(32, "exact"), "seed": 1}, 1),
                            ("raymarch shadow_map 128", march(128), repeats), ("raymarch shadow_map 32", march(32),
                                                                               repeats),
                            ("fourier M=32", fourier(), repeats),
                            ("fourier M=32 filtered resampling",  # Peters 2017 Sec. 5.2
                             {**fourier(), "prefiltered": {"resample_filter": "moments"}}, repeats)):
        if progress:
            progress(label, 0.1)
        rows[label], _, stats = scattering_rows(report, label, {"name": "colonnade", "width": w, "height": h,
                                                              "scattering": sc, "surfaces": no_surf},
                                              {"scene": "colonnade", "size": f"{w}x{h}", "map": smap}, reps,
                                              warmup if reps > 1 else 0, reference)
        storage_extras(rows[label], stats, w * h)
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
        storage_extras(*scattering_rows(report, "fourier map sweep", {
            "name": "colonnade", "width": w, "height": h, "scattering": fourier(res=[mw, mh]), "surfaces": no_surf},
            {"map": f"{mw}x{mh}", "size": f"{w}x{h}", "M": 32}, repeats, warmup)[::2], w * h)
    for k, (ow, oh) in enumerate(outs):
        if progress:
            progress(f"output {ow}x{oh}", 0.4 + 0.1 * k / len(outs))
        storage_extras(*scattering_rows(report, "fourier output sweep", {
            "name": "colonnade", "width": ow, "height": oh, "scattering": fourier(), "surfaces": no_surf},
            {"size": f"{ow}x{oh}", "map": smap, "M": 32}, repeats, warmup)[::2], ow * oh)
    for k, m in enumerate(counts):
        if progress:
            progress(f"M={m}", 0.5 + 0.1 * k / len(counts))
        for bits in (0, 8):
            storage_extras(*scattering_rows(report, "fourier basis sweep", {
                "name": "colonnade", "width": w, "height": h, "scattering": fourier(m, storage_bits=bits),
                "surfaces": no_surf}, {"M": m, "bits": bits or 32, "size": f"{w}x{h}", "map": smap}, repeats,
                warmup, extra={"bytes_per_texel": m * (1 if bits else 4)})[::2], w * h)

    # ---- prefix-sum throughput of the float32 and RGBA8 textures against a memcpy (Peters 2017 App. C) ----
    if progress:
        progress("prefix sums", 0.65)
    prefix_sum_rows(report, PREFIX_SUM_MODES[:2], 512 if quick else 1024, repeats, warmup)

    # ---- scene complexity: canopy leaves x1 .. x100; the fourier evaluation stays flat ----
    cw, ch = (240, 135) if quick else (480, 270)
    steps = 16 if quick else 32
    leaf_counts = [1000, 10000] if quick else [1000, 10000, 100000]
    for k, leaves in enumerate(leaf_counts):
        if progress:
            progress(f"canopy {leaves} leaves", 0.7 + 0.3 * k / len(leaf_counts))
        common = {"name": "canopy", "width": cw, "height": ch, "leaves": leaves, "surfaces": no_surf}
        params = {"leaves": leaves, "triangles": 2 * leaves, "size": f"{cw}x{ch}"}
        storage_extras(*scattering_rows(report, "complexity fourier", dict(common, scattering=fourier()), params,
                                        repeats, warmup)[::2], cw * ch)
        scattering_rows(report, f"complexity raymarch exact {steps}", dict(common, scattering=march(steps, "exact")),
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
    # caster culling (on by default for the moment methods only): each side of the default
    methods += [("fourier M=32 culled", {"method": "fourier", "prefiltered": {"caster_culling": True}}),
                ("moments6 192-bit unculled", {"method": "moments6", "moments": {"storage_bits": 192},
                                               "prefiltered": {"caster_culling": False}})]
    # filtering during resampling (Peters 2017 Sec. 5.2, Fig. 17): a filtered 4-moment map and Algorithm 2
    methods += [(f"{label} filtered", {**sc, "prefiltered": {"resample_filter": "moments"}}) for label, sc in methods
                if label in ("fourier M=32", "moments4 64-bit", "moments6 64-bit", "moments6 192-bit")]
    # colonnade / canopy again with the ground receiver_only: the same exact image, but no ground depths just behind
    # a ray's end in the rectified map (where moment bounds are loosest)
    variants = [("colonnade", False), ("colonnade", True), ("canopy", False), ("canopy", True), ("window", False)]
    casting_refs = {}
    for k, (scene, ro_ground) in enumerate(variants):
        title = f"{scene} (receiver-only ground)" if ro_ground else scene
        if progress:
            progress(f"{title}: exact reference", 0.8 * k / len(variants))
        _, ref, _ = scattering_rows(report, f"{title}: raymarch exact (reference)", {
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
            rows[label], img, stats = scattering_rows(report, f"{title}: {label}", {
                "name": scene, "width": w, "height": h, "receiver_only_ground": ro_ground, "scattering": sc,
                "surfaces": no_surf}, {"size": f"{w}x{h}", "map": smap}, repeats, warmup, ref["scattering"])
            if "bits_per_texel" in stats:
                rows[label]["extra"]["bits_per_texel"] = stats["bits_per_texel"]
            storage_extras(rows[label], stats, w * h)
        base = rows["raymarch shadow_map 128"]["median_ms"]
        for r in rows.values():
            r["speedup"] = base / r["median_ms"]
    # ---- prefix-sum throughput of every storage mode against a memcpy (Peters 2017 App. C) ----
    if progress:
        progress("prefix sums", 0.8)
    prefix_sum_rows(report, PREFIX_SUM_MODES, 512 if quick else 1024, repeats, warmup)
    # ---- soft shadows on surfaces: moment soft shadows against the PCSS brute force ----
    if progress:
        progress("soft shadows", 0.85)
    images = {}
    for method in ("pcss", "msm_soft"):
        cfg = bench_scene_config("colonnade", w, h, scattering={"method": "raymarch", "visibility": "shadow_map",
                                                                "steps": 1, "shadow_map": {"resolution": smap}},
                                 shadows={"method": method, "light_angle_deg": 2.0})
        cfg = Config.from_dict({**cfg.model_dump(mode="json"), "medium": {"sigma_t": 0.0}})
        all_stages, img, _, _, stats = render_timed(cfg, repeats, warmup)
        stages = {k: v for k, v in all_stages.items() if k in ("msm_generate", "msm_sat", "shading")}
        images[method] = img["surface"]
        report.add(name=f"soft shadows {method}", params={"size": f"{w}x{h}", "map": smap, "light_angle_deg": 2.0},
                   median_ms=sum(stages.values()), stages_ms=stages,
                   extra={k: v for k, v in stats.items() if k in ("sat_bytes",)})
    report.rows[-1].update(errors(images["msm_soft"], images["pcss"]))
    report.rows[-1]["speedup"] = report.rows[-2]["median_ms"] / report.rows[-1]["median_ms"]


def suite_epipolar(report: BenchReport, repeats: int, warmup: int, quick: bool, progress: ProgressFn | None):
    """Engelhardt & Dachsbacher 2010: fraction ray-marched, stage times and errors for line / sample counts, against
    the per-pixel marcher (same steps and step pattern), the exact reference and a converged marcher (8x steps).
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
    _, exact, _ = scattering_rows(report, "raymarch exact (reference)",
                                dict(common, scattering={**march, "visibility": "exact"}),
                                {"scene": scene, "size": size, "steps": steps, "jitter": "per_pixel"}, 1, 0)
    # the marcher with 8x the steps: a converged reference including the light texture
    if progress:
        progress("converged marcher", 0.05)
    _, converged, _ = scattering_rows(report, "raymarch shadow_map (8x steps, converged)",
                                    dict(common, scattering={**march, "steps": 8 * steps, "seed": 11}),
                                    {"scene": scene, "size": size, "steps": 8 * steps, "jitter": "per_pixel"}, 1, 0,
                                    exact["scattering"])
    per_pixel = {}
    for k, jitter in enumerate(("per_pixel", "fixed")):
        if progress:
            progress(f"per-pixel ray marching ({jitter})", 0.1 + 0.05 * k)
        row, images, _ = scattering_rows(report, f"raymarch shadow_map (per pixel, {jitter})",
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
    for k, (n_lines, n_init, jitter) in enumerate(cases):
        if progress:
            progress(f"{n_lines} lines, {n_init} samples, {jitter}", 0.2 + 0.8 * k / len(cases))
        sc = {**march, "method": "epipolar", "jitter": jitter,
              "epipolar": {"lines": n_lines, "initial_samples": n_init}}
        cfg = bench_scene_config(**dict(common, scattering=sc))
        stages, images, compile_s, _, stats = render_timed(cfg, repeats, warmup)
        technique = {k2: v for k2, v in stages.items() if k2 in ("lines", "discontinuities", "raymarch", "interpolate")}
        pp_row, pp_img = per_pixel[jitter]
        row = report.add(name="epipolar", params={"lines": n_lines, "initial": n_init, "size": size, "steps": steps,
                                                   "jitter": jitter},
                         median_ms=sum(technique.values()), stages_ms=technique,
                         extra={"raymarched_pct": round(100 * stats["epipolar_raymarched_fraction"], 2),
                                "mean_sample_steps": round(stats["epipolar_mean_sample_steps"], 1),
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
