"""The gallery: every picture the docs show, rendered again by one call (``warpscatter gallery -o docs/images``;
the pictures and ``gallery.json``: docs/gallery.md). Renders go through :func:`warpscatter.render` at each config's own
settings; wide images are box-filtered down in linear light, never up. Errors are relative L1 against the reference;
times exclude the kernel compile.
"""

from __future__ import annotations

import importlib
import json
import logging
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from ..api import load_config, render
from ..errors import ConfigError
from ..io.images import json_ready, srgb_encode, write_png
from ..io.metrics import errors
from ..io.output_sets import write_file_atomic
from ..io.provenance import machine, source_commit, timestamp
from ..io.resources import ROOT

log = logging.getLogger("warpscatter.runs.gallery")

#: The layout of ``gallery.json`` (``format`` key).
FORMAT = "warpscatter-gallery/1"
#: The config of the README's hero picture and of the methods' comparison.
HERO_CONFIG = "quickstart"
COMPARE_CONFIG = "quickstart"
#: The sections of a gallery (the ``section`` of each image in ``gallery.json``).
SECTIONS = ("hero", "configs", "methods", "compare", "bench")


@dataclass(frozen=True)
class Sizes:
    """The gallery's image sizes (widths in pixels; heights follow each config's aspect) and reference quality.

    Attributes:
        hero: the widest hero picture (``quickstart.png``).
        config: the widest per-config picture (``configs/<config>.png``).
        compare: the width the methods' comparison renders at.
        reference_steps: ray-march steps per ray of the comparison's exact reference.
        render_width: render every config this wide (None: at its own size); one ray a pixel then.
        map_resolution: the scattering methods' shadow maps (None: each config's own).
        csm_maps: the coherent shadow maps' grid of depth maps (None: each config's own).
    """

    hero: int = 960
    config: int = 480
    compare: int = 480
    reference_steps: int = 256
    render_width: int | None = None
    map_resolution: int | None = None
    csm_maps: tuple[int, int] | None = None


#: The gallery of the docs.
FULL = Sizes()
#: A few dozen pixels a picture: the tests' gallery (seconds per image, compile aside).
QUICK = Sizes(hero=64, config=48, compare=48, reference_steps=32, render_width=48, map_resolution=256,
              csm_maps=(16, 8))

#: The comparison's methods (name -> overrides of the quickstart): each fast method at its defaults.
COMPARED: dict[str, dict[str, Any]] = {
    "fourier": {"render.scattering.method": "fourier"},
    "moments4": {"render.scattering.method": "moments4"},
    "moments6": {"render.scattering.method": "moments6"},
    "epipolar": {"render.scattering.method": "epipolar", "render.scattering.visibility": "shadow_map"},
    "raymarch_shadow_map": {"render.scattering.method": "raymarch", "render.scattering.visibility": "shadow_map"},
}
#: The comparison's reference: the marcher with exact visibility (its steps: :attr:`Sizes.reference_steps`).
REFERENCE_NAME = "raymarch"
REFERENCE = {"render.scattering.method": "raymarch", "render.scattering.visibility": "exact"}
#: Lighting and shadow methods the quickstart cannot show: (kind, method) -> the bundled config that shows it
#: (checked at run time; another config using the method stands in).
SHOWCASES: dict[tuple[str, str], str] = {
    ("lighting", "csm"): "csm_gate",
    ("shadows", "msm"): "canopy_moments",
    ("shadows", "msm_soft"): "gate_soft_shadows",
}
#: Signed error at which the error images saturate, as a fraction of the reference's mean (as the bench's).
ERROR_RANGE = 0.25


@dataclass
class Entry:
    """One written image and what made it (a row of ``gallery.json``; paths relative to the gallery folder)."""

    path: str
    section: str
    config: str | None = None  # the bundled config's name
    method: str | None = None
    overrides: dict[str, Any] = field(default_factory=dict)
    frame: int | None = None  # the frame of an animated config
    render_size: list[int] | None = None  # [width, height] rendered (before supersampling)
    size: list[int] | None = None  # [width, height] of the image file
    bytes: int = 0
    seconds: float | None = None  # render stages less the compile; a chart: the time to draw it
    rel_l1: float | None = None  # against the comparison's exact reference
    note: str = ""
    version: str = __version__
    commit: str | None = None
    created: str = ""


@dataclass
class GalleryResult:
    """What :func:`build` did: the images written, the configs that failed, the sections skipped and why."""

    out_dir: Path
    entries: list[Entry] = field(default_factory=list)
    failures: dict[str, str] = field(default_factory=dict)  # job label -> error message
    skipped: dict[str, str] = field(default_factory=dict)  # section -> reason
    seconds: float = 0.0
    manifest: Path | None = None

    @property
    def total_bytes(self) -> int:
        """Bytes of the images written in this run."""
        return sum(e.bytes for e in self.entries)




def bundled_configs() -> list[Path]:
    """The bundled configs (``configs/*.yaml`` of the source tree or the installed package), sorted by name."""
    return sorted((ROOT / "configs").glob("*.yaml"))


def bench_files(bench_dir: str | Path) -> list[Path]:
    """The ``bench-<suite>.json`` results of a bench run's folder, sorted; ValueError if none or one is not one."""
    from ..bench.compare import load_bench_json

    folder = Path(bench_dir)
    if not folder.is_dir():
        raise ValueError(f"--bench-dir {bench_dir}: not a folder (give the -o folder of a `warpscatter bench` run)")
    files = sorted(folder.glob("bench-*.json"))
    if not files:
        raise ValueError(f"--bench-dir {bench_dir}: no bench-*.json in it (`warpscatter bench SUITE -o {bench_dir}` "
                         "writes them)")
    for f in files:
        load_bench_json(f)
    return files




def _area_weights(n_in: int, n_out: int) -> np.ndarray:
    """(n_out, n_in) box-filter weights from n_in to n_out samples (partial samples weighted by overlap)."""
    edges = np.linspace(0.0, n_in, n_out + 1)
    lo, hi = edges[:-1, None], edges[1:, None]
    k = np.arange(n_in)[None, :]
    overlap = np.clip(np.minimum(hi, k + 1) - np.maximum(lo, k), 0.0, None)
    return overlap / overlap.sum(axis=1, keepdims=True)


def downscale(image: np.ndarray, width: int) -> np.ndarray:
    """``image`` (H, W, C) box-filtered down to ``width`` pixels wide (aspect kept), float32; never scaled up."""
    h, w = image.shape[:2]
    if w <= width:
        return image
    height = max(1, round(h * width / w))
    a = np.asarray(image, np.float64)
    out = np.einsum("yi,ijc,xj->yxc", _area_weights(h, height), a, _area_weights(w, width), optimize=True)
    return out.astype(np.float32)


def _aspect_size(width: int, cfg) -> tuple[int, int]:
    return width, max(1, round(width * cfg.camera.height / cfg.camera.width))


def _render_seconds(timings: Mapping[str, float]) -> float:
    """A render's time less its kernel compile (which a warm cache does not pay)."""
    return float(sum(v for k, v in timings.items() if k != "compile"))




@dataclass
class _Job:
    label: str  # e.g. "configs/canopy.png"
    run: Callable[[], list[Entry]]


class _Gallery:
    """One gallery run: plans the jobs, runs them, keeps the entries."""

    def __init__(self, out_dir: Path, sizes: Sizes, device, progress):
        self.out = out_dir
        self.sizes = sizes
        self.device = device
        self.progress = progress
        self.commit = source_commit()[0]
        self.configs: dict[str, tuple[np.ndarray, Any, Entry]] = {}  # config -> (its picture, config, entry)
        self.compared: dict[str, tuple[np.ndarray, Entry]] = {}  # name -> (colour image, exposure applied; entry)

    def entry(self, path: Path, section: str, **kw) -> Entry:
        from ..io.images import read_image

        rel = path.relative_to(self.out).as_posix()
        e = Entry(path=rel, section=section, bytes=path.stat().st_size, commit=self.commit, created=timestamp(), **kw)
        if e.size is None:
            img = read_image(path)
            e.size = [int(img.shape[1]), int(img.shape[0])]
        return e


    def render(self, source: Path, overrides: dict[str, Any]):
        """(colour image, config, frame, seconds, overrides applied) of one config with ``overrides``."""
        cfg = load_config(source, overrides)
        overrides = {**self.shrunk(cfg), **overrides}
        if overrides:
            cfg = load_config(source, overrides)
        frame = None
        if cfg.animation is not None:
            start, end = cfg.animation.frame_range
            frame = (start + end) // 2
            cfg = cfg.at_frame(frame)
        result = render(cfg, device=self.device, progress=self.progress)
        return result.images["color"], cfg, frame, _render_seconds(result.timings), overrides

    def shrunk(self, cfg) -> dict[str, Any]:
        """The overrides that shrink a config to :attr:`sizes` (none for the full sizes)."""
        out: dict[str, Any] = {}
        s = self.sizes
        if s.render_width is not None:
            w, h = _aspect_size(s.render_width, cfg)
            out.update({"camera.width": w, "camera.height": h, "camera.supersample": 1})
        lighting = cfg.render.lighting
        if lighting.method is None and s.map_resolution is not None:
            out["render.scattering.shadow_map.resolution"] = min(s.map_resolution,
                                                                 cfg.render.scattering.shadow_map.resolution)
        if lighting.method == "csm" and lighting.csm.file is None and s.csm_maps is not None:
            out["render.lighting.csm.maps"] = [min(a, b) for a, b in zip(s.csm_maps, lighting.csm.maps, strict=True)]
        return out

    def config_image(self, source: Path, path: Path, width: int, section: str) -> list[Entry]:
        image, cfg, frame, seconds, overrides = self.render(source, {})
        small = downscale(image, width)
        write_png(path, small, exposure=cfg.output.exposure)
        e = self.entry(path, section, config=source.stem, method=cfg.method, overrides=overrides, frame=frame,
                       render_size=[cfg.camera.width, cfg.camera.height], seconds=round(seconds, 3))
        self.configs[source.stem] = (small, cfg, e)
        return [e]

    def showcase_image(self, kind: str, method: str, configs: list[Path]) -> list[Entry]:
        """``methods/<method>.png``: the picture of the bundled config that shows a lighting or shadow method."""
        preferred = SHOWCASES[kind, method]
        names = [preferred] + [p.stem for p in configs if p.stem != preferred]
        for name in names:
            if name not in self.configs:  # not rendered (it failed): try the next
                continue
            small, cfg, e = self.configs[name]
            if _uses(cfg, kind, method):
                path = self.out / "methods" / f"{method}.png"
                write_png(path, downscale(small, self.sizes.compare), exposure=cfg.output.exposure)
                return [self.entry(path, "methods", config=name, method=method, overrides=e.overrides, frame=e.frame,
                                   render_size=e.render_size, seconds=e.seconds,
                                   note=f"the picture of configs/{name}.png")]
        raise ValueError(f"methods/{method}.png: no bundled config renders with render.{kind}.method {method} "
                         f"(SHOWCASES names {preferred})")

    def method_image(self, source: Path, name: str, overrides: dict[str, Any]) -> list[Entry]:
        w, h = _aspect_size(self.sizes.compare, load_config(source))
        overrides = {"camera.width": w, "camera.height": h, **overrides}
        image, cfg, frame, seconds, overrides = self.render(source, overrides)
        path = self.out / "methods" / f"{name}.png"
        write_png(path, image, exposure=cfg.output.exposure)
        e = self.entry(path, "methods", config=source.stem, method=cfg.method, overrides=overrides, frame=frame,
                       render_size=[cfg.camera.width, cfg.camera.height], seconds=round(seconds, 3))
        reference = self.compared.get(REFERENCE_NAME)
        shown = image * np.float32(cfg.output.exposure)
        if reference is not None:
            e.rel_l1 = errors(shown, reference[0])["rel_l1"]
        else:
            e.note = f"the comparison's exact reference ({cfg.render.scattering.march_steps} steps)"
        self.compared[name] = (shown, e)
        return [e]

    def compare_figure(self) -> list[Entry]:
        path = self.out / f"compare_{COMPARE_CONFIG}.png"
        t0 = time.perf_counter()
        written = comparison_figure(self.compared, path, COMPARE_CONFIG)
        if written is None:
            return []
        ref = self.compared[REFERENCE_NAME][1]
        return [self.entry(path, "compare", config=COMPARE_CONFIG, method=", ".join(self.compared),
                           overrides={"reference": ref.overrides}, seconds=round(time.perf_counter() - t0, 3),
                           note="each method's colour image and its signed error against the exact reference")]

    def bench_charts(self, json_path: Path) -> list[Entry]:
        return [self.entry(p, "bench", method=suite, seconds=round(s, 3), note=f"from {json_path.name}")
                for p, suite, s in chart_bench_json(json_path, self.out / "bench")]


def _uses(cfg, kind: str, method: str) -> bool:
    """Whether a config renders with ``render.<kind>.method`` = ``method``."""
    return getattr(getattr(cfg.render, kind), "method", None) == method


def _suite_chart(suite: str):
    """The chart a suite draws of its rows (``chart_<suite>``), else the bench's default bar chart."""
    from ..bench import SUITES
    from ..bench.report import chart_bars

    record = SUITES.get(suite)
    if record is None:
        return chart_bars
    return getattr(importlib.import_module(record.run.__module__), f"chart_{suite}", chart_bars)


def chart_bench_json(json_path: str | Path, out_dir: Path) -> list[tuple[Path, str, float]]:
    """Draw the charts of a bench run's ``bench-<suite>.json`` files into ``out_dir`` with the bench's chart code;
    returns (path, suite, seconds) of each chart written (none without matplotlib)."""
    from ..bench.compare import load_bench_json
    from ..bench.report import BenchReport, chart_error_time

    data = load_bench_json(json_path)
    suite = data["suite"]
    report = BenchReport(suite=suite, rows=list(data["rows"]), meta=dict(data["meta"]))
    out_dir.mkdir(parents=True, exist_ok=True)
    out = []
    for draw, path in ((_suite_chart(suite), out_dir / f"bench-{suite}.png"),
                       (chart_error_time, out_dir / f"bench-{suite}-error-time.png")):
        t0 = time.perf_counter()
        if draw(report, path) is not None:
            palette_png(path)
            out.append((path, suite, time.perf_counter() - t0))
    return out


def palette_png(path: Path) -> Path:
    """Rewrite a chart's PNG with a 256-colour palette, atomically (a third to a quarter of the bytes); needs Pillow."""
    try:
        from PIL import Image
    except ImportError:
        return path
    with Image.open(path) as img:
        rgb = img.convert("RGB")
    small = rgb.quantize(colors=256, dither=Image.Dither.NONE)
    return write_file_atomic(path, lambda tmp: small.save(tmp, format="PNG", optimize=True))


def comparison_figure(compared: Mapping[str, tuple[np.ndarray, Entry]], path: Path, scene: str) -> Path | None:
    """The methods side by side: colour image over signed error image (relative to the reference's mean, saturating
    at +-:data:`ERROR_RANGE`), titled with time and rel. L1. None without matplotlib.
    """
    from ..bench.report import pyplot, save_figure

    plt = pyplot()
    if plt is None or REFERENCE_NAME not in compared:
        return None
    ref_image, ref_entry = compared[REFERENCE_NAME]
    ref = np.asarray(ref_image, np.float64)
    mean = max(float(ref.mean()), 1e-30)
    h, w = ref.shape[:2]
    names = list(compared)
    legend = im = None
    cols = 3
    rows = -(-len(names) // cols)
    panel_w = 3.2
    panel_h = panel_w * h / w
    fig, axes = plt.subplots(2 * rows, cols, figsize=(cols * panel_w + 0.2, rows * (2 * panel_h + 0.75) + 0.5),
                             squeeze=False)
    fig.subplots_adjust(left=0.01, right=0.99, top=1.0 - 0.5 / fig.get_figheight(), bottom=0.01, wspace=0.03,
                        hspace=0.22)
    for k, name in enumerate(names):
        image, e = compared[name]
        top, bottom = axes[2 * (k // cols), k % cols], axes[2 * (k // cols) + 1, k % cols]
        shown = srgb_encode(np.clip(np.asarray(image, np.float64), 0.0, 1.0))
        top.imshow(shown)
        time_text = f"{e.seconds:.2f} s" if e.seconds is not None else ""
        if name == REFERENCE_NAME:
            top.set_title(f"{name} (exact visibility): the reference, {time_text}", fontsize=8)
            bottom.axis("off")
            legend = bottom
            bottom.text(0.02, 0.62, f"below each method: its signed error\n(method - reference) / reference mean,\n"
                                   f"red: too bright, blue: too dark,\nsymmetric scale, saturating at "
                                   f"+-{100 * ERROR_RANGE:.0f} %", fontsize=8, va="center", transform=bottom.transAxes)
            continue
        top.set_title(f"{name}: {time_text}", fontsize=8)
        err = (np.asarray(image, np.float64) - ref).mean(axis=-1) / mean
        im = bottom.imshow(err, cmap="RdBu_r", vmin=-ERROR_RANGE, vmax=ERROR_RANGE)
        bottom.set_title(f"{name}: rel. L1 {100 * (e.rel_l1 or 0.0):.2f} %", fontsize=8)
    for ax in axes.flat:
        ax.set_xticks([])
        ax.set_yticks([])
    for k in range(len(names), rows * cols):
        axes[2 * (k // cols), k % cols].axis("off")
        axes[2 * (k // cols) + 1, k % cols].axis("off")
    if legend is not None and im is not None:
        bar = fig.colorbar(im, cax=legend.inset_axes((0.08, 0.12, 0.84, 0.09)), orientation="horizontal")
        bar.ax.tick_params(labelsize=7)
        bar.set_ticks([-ERROR_RANGE, 0.0, ERROR_RANGE], labels=[f"-{100 * ERROR_RANGE:.0f} %", "0",
                                                               f"+{100 * ERROR_RANGE:.0f} %"])
    steps = ref_entry.overrides.get("render.scattering.steps")
    fig.suptitle(f"warpscatter {__version__}: the methods on the {scene} config, {w}x{h}, against the exact "
                 f"reference ({steps} steps); times: render stages less the compile", fontsize=9)
    path.parent.mkdir(parents=True, exist_ok=True)
    return save_figure(fig, path, layout=False)


def build(out_dir: str | Path, *, quick: bool = False, sizes: Sizes | None = None, bench_dir: str | Path | None = None,
          device=None, progress: Callable[[str, float], None] | None = None,
          on_job: Callable[[int, int, str], None] | None = None) -> GalleryResult:
    """Render the gallery into ``out_dir``: hero picture, bundled configs, methods' comparison, bench charts, JSON.

    Args:
        out_dir: the gallery folder (created).
        quick: tiny sizes (:data:`QUICK`) for the tests; else :data:`FULL`.
        sizes: the sizes, instead of :data:`FULL` / :data:`QUICK`.
        bench_dir: the ``-o`` folder of a ``warpscatter bench`` run whose ``bench-*.json`` are charted.
        device: the Warp device (None: as :func:`warpscatter.render`).
        progress: ``progress(stage, fraction)`` of each render.
        on_job: ``on_job(k, n, label)`` before job k of n.

    Returns:
        :class:`GalleryResult`; a failing config is listed in ``failures`` and the others go on.

    Raises:
        ValueError: ``bench_dir`` holds no bench results, or ``out_dir`` is a file.
    """
    t_start = time.perf_counter()
    out = Path(out_dir).expanduser().resolve()
    if out.exists() and not out.is_dir():
        raise ValueError(f"{out_dir}: not a folder")
    jsons = bench_files(bench_dir) if bench_dir is not None else []
    sizes = sizes or (QUICK if quick else FULL)
    configs = bundled_configs()
    if not configs:
        raise ValueError(f"no bundled configs in {ROOT / 'configs'}")
    for sub in ("configs", "methods"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    g = _Gallery(out, sizes, device, progress)
    result = GalleryResult(out_dir=out)
    by_name = {p.stem: p for p in configs}

    jobs: list[_Job] = []
    if HERO_CONFIG in by_name:
        jobs.append(_Job(f"{HERO_CONFIG}.png", lambda: g.config_image(by_name[HERO_CONFIG], out / f"{HERO_CONFIG}.png",
                                                                      sizes.hero, "hero")))
    for p in configs:
        jobs.append(_Job(f"configs/{p.stem}.png",
                         lambda p=p: g.config_image(p, out / "configs" / f"{p.stem}.png", sizes.config, "configs")))
    if COMPARE_CONFIG in by_name:
        source = by_name[COMPARE_CONFIG]
        reference = {**REFERENCE, "render.scattering.steps": sizes.reference_steps}
        jobs.append(_Job(f"methods/{REFERENCE_NAME}.png", lambda: g.method_image(source, REFERENCE_NAME, reference)))
        for name, overrides in COMPARED.items():
            jobs.append(_Job(f"methods/{name}.png", lambda n=name, o=overrides: g.method_image(source, n, o)))
        jobs.append(_Job(f"compare_{COMPARE_CONFIG}.png", g.compare_figure))
    for kind, method in SHOWCASES:
        jobs.append(_Job(f"methods/{method}.png", lambda k=kind, m=method: g.showcase_image(k, m, configs)))
    for j in jsons:
        jobs.append(_Job(f"bench/{j.stem}.png", lambda j=j: g.bench_charts(j)))
    if not jsons:
        result.skipped["bench"] = ("no --bench-dir: the bench charts were not drawn (those already in "
                                   f"{out / 'bench'} are kept)")

    from ..bench.report import pyplot

    if pyplot() is None:
        result.skipped["compare"] = "matplotlib (the plot extra) is not installed: no comparison figure"
        if jsons:
            result.skipped["bench"] = "matplotlib (the plot extra) is not installed: no bench charts"

    for k, job in enumerate(jobs):
        if on_job is not None:
            on_job(k, len(jobs), job.label)
        t0 = time.perf_counter()
        try:
            written = job.run()
        except KeyboardInterrupt:
            raise
        except Exception as exc:  # one failing config must not stop the others
            known = isinstance(exc, (ConfigError, ValueError, OSError))
            message = str(exc) if known else f"{type(exc).__name__}: {exc}"
            result.failures[job.label] = message
            log.error("%s failed: %s", job.label, message)
            continue
        result.entries += written
        for e in written:
            log.info("%s: %s, %.1f KiB, %.2f s", e.path, "x".join(map(str, e.size or [])), e.bytes / 1024,
                     time.perf_counter() - t0)
    result.seconds = time.perf_counter() - t_start
    result.manifest = write_manifest(result, sizes)
    return result


def write_manifest(result: GalleryResult, sizes: Sizes) -> Path:
    """Write ``gallery.json``: this run's images plus earlier bench charts still present; stale images of the
    sections rendered again are deleted."""
    out = result.out_dir
    path = out / "gallery.json"
    written = {e.path for e in result.entries}
    kept: list[dict] = []
    try:
        old = json.loads(path.read_text(encoding="utf-8")).get("images", [])
    except (OSError, ValueError, AttributeError):
        old = []
    redone = {e.section for e in result.entries}
    for item in old if isinstance(old, list) else []:
        if not isinstance(item, dict) or not isinstance(item.get("path"), str) or item["path"] in written:
            continue
        file = out / item["path"]
        if item.get("section") in redone:
            failed = any(item["path"] == label or item["path"].startswith(label.removesuffix(".png"))
                         for label in result.failures)
            if failed and file.is_file():
                kept.append({**item, "note": "stale: this run failed to render it again"})
            elif not failed and file.is_file() and file.resolve().is_relative_to(out):
                file.unlink()
            continue
        if file.is_file():
            kept.append(item)
    commit, dirty = source_commit()
    doc = {"format": FORMAT, "created": timestamp(), "version": __version__, "commit": commit, "git_dirty": dirty,
           "machine": machine(), "seconds": round(result.seconds, 1), "sizes": asdict(sizes),
           "failures": result.failures, "skipped": result.skipped,
           "images": [asdict(e) for e in result.entries] + kept}

    def write(tmp: Path) -> None:
        tmp.write_text(json.dumps(json_ready(doc), indent=2) + "\n", encoding="utf-8")

    return write_file_atomic(path, write)


def images_named(markdown: str) -> list[str]:
    """The image paths a Markdown page names (``![caption](path)`` and ``<img src="path">``), in order."""
    import re

    return re.findall(r"!\[[^\]]*\]\(([^)\s]+)", markdown) + re.findall(r"<img[^>]*\bsrc=\"([^\"]+)\"", markdown)


__all__ = ["COMPARED", "FORMAT", "FULL", "QUICK", "REFERENCE", "SHOWCASES", "Entry", "GalleryResult", "Sizes",
           "bench_files", "build", "bundled_configs", "chart_bench_json", "comparison_figure", "downscale",
           "images_named", "palette_png", "write_manifest"]
