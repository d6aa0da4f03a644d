"""``warpscatter`` command line: render, validate and bench, thin over the library.

Exit codes: 0 success, 1 a failure while rendering or benchmarking, 2 an invalid config, override,
suite name or command line (nothing is written then), 130 interrupted.

Progress goes to stderr (one updating line on a terminal, one line per stage otherwise); results
(the per-stage timing table, statistics and the written files) go to stdout.
"""

from __future__ import annotations

import importlib
import inspect
import math
import sys
import time
import traceback
from pathlib import Path

import click
from pydantic import ValidationError

from warpscatter import __version__, methods
from warpscatter.config import AOV_NAMES, Config, load_config
from warpscatter.csm import settings as csm_settings
from warpscatter.errors import ConfigError, WarpscatterError
from warpscatter.schema import format_validation_errors

EXIT_FAILURE = 1
EXIT_INVALID = 2
EXIT_INTERRUPTED = 130

_set_option = click.option(
    "--set",
    "overrides",
    multiple=True,
    metavar="KEY=VALUE",
    help="Override a config value, e.g. --set camera.fov_y=40 --set scene.meshes.0.material.opacity=0.5 "
    "(VALUE is parsed as YAML; repeatable).",
)
_debug_option = click.option("--debug", is_flag=True, help="Show the full traceback of an error.")


# ---- output helpers --------------------------------------------------------------------------------


class ProgressDisplay:
    """``progress(stage, fraction)`` callback drawing on stderr.

    On a terminal: one line redrawn in place (at most ~10 times a second) with the stage, a bar and
    the elapsed time. Otherwise: one plain line when a stage starts. Disabled: does nothing.
    """

    BAR = 24

    def __init__(self, enabled: bool = True, stream=None):
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled
        self.tty = enabled and _isatty(self.stream)
        self.stage: str | None = None
        self.start = time.perf_counter()
        self.last_draw = 0.0
        self.drawn = False

    def __call__(self, stage: str, fraction: float) -> None:
        if not self.enabled:
            return
        try:
            self._update(str(stage), float(fraction))
        except Exception:  # a display problem must never break a render
            self.enabled = False

    def _update(self, stage: str, fraction: float) -> None:
        now = time.perf_counter()
        new_stage = stage != self.stage
        self.stage = stage
        if not self.tty:
            if new_stage:
                self.stream.write(f"[{now - self.start:7.2f}s] {stage}\n")
                self.stream.flush()
            return
        if not (new_stage or fraction >= 1.0 or now - self.last_draw >= 0.1):
            return
        f = min(max(fraction, 0.0), 1.0) if math.isfinite(fraction) else 0.0
        filled = int(round(f * self.BAR))
        bar = "#" * filled + "-" * (self.BAR - filled)
        self.stream.write(f"\r\x1b[K{stage:<28.28} [{bar}] {100 * f:5.1f}%  {now - self.start:7.2f}s")
        self.stream.flush()
        self.last_draw = now
        self.drawn = True

    def close(self) -> None:
        """Clear the updating line (terminal only)."""
        if self.tty and self.drawn:
            self.stream.write("\r\x1b[K")
            self.stream.flush()
            self.drawn = False


def _isatty(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


def _format_seconds(s: float) -> str:
    if s < 1e-3:
        return f"{s * 1e6:8.1f} us"
    if s < 1.0:
        return f"{s * 1e3:8.1f} ms"
    return f"{s:8.3f} s "


def timing_table(timings) -> str:
    """Per-stage timing table: stage, time, share of the total, and a total row."""
    rows = [(str(k), float(v)) for k, v in dict(timings or {}).items()]
    if not rows:
        return "(no timings)"
    total = sum(v for _, v in rows)
    width = max(len("stage"), len("total"), *(len(k) for k, _ in rows))
    lines = [f"{'stage':<{width}}  {'time':>11}  {'share':>6}", "-" * (width + 21)]
    for k, v in rows:
        share = 100.0 * v / total if total > 0 else 0.0
        lines.append(f"{k:<{width}}  {_format_seconds(v)}  {share:5.1f}%")
    lines.append("-" * (width + 21))
    lines.append(f"{'total':<{width}}  {_format_seconds(total)}  {100.0 if total > 0 else 0.0:5.1f}%")
    return "\n".join(lines)


def _format_value(v) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_format_value(x) for x in v) + "]"
    return str(v)


def _fail(message: str, code: int, debug: bool = False) -> None:
    if debug:
        traceback.print_exc(file=sys.stderr)
    click.echo(f"error: {message}", err=True)
    sys.exit(code)


def _load(config_path: Path, overrides, debug: bool) -> Config:
    try:
        return load_config(config_path, list(overrides))
    except ConfigError as exc:
        _fail(str(exc), EXIT_INVALID)
    except Exception as exc:  # a bug, not a user error: keep the traceback reachable
        _fail(f"{type(exc).__name__}: {exc}", EXIT_FAILURE, debug)


def _fail_error(exc: BaseException, debug: bool) -> None:
    """Exit for an exception of a command: a :class:`WarpscatterError` with its exit code, anything else 1."""
    if isinstance(exc, WarpscatterError):
        _fail(str(exc), exc.exit_code, debug)
    _fail(_error_text(exc), EXIT_FAILURE, debug)


def _error_text(exc: BaseException) -> str:
    text = str(exc)
    if isinstance(exc, (ValueError, OSError)) and text:
        return text
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _out_dir(path: Path | None) -> Path | None:
    if path is None:
        return None
    out = Path(path).expanduser().resolve()
    if out.exists() and not out.is_dir():
        _fail(f"-o {path}: not a directory", EXIT_INVALID)
    return out


def _summary(config: Config) -> list[str]:
    meshes = config.scene.meshes
    procedural = [m.procedural for m in meshes if m.procedural]
    kinds = f"{len(meshes) - len(procedural)} file(s)"
    if procedural:
        kinds += f", procedural: {', '.join(procedural)}"
    cam = config.camera
    light = config.light
    if light.type == "directional":
        light_text = (
            f"directional, direction {_format_value(light.direction)}, irradiance {_format_value(light.irradiance)}"
        )
    elif light.type == "environment":
        light_text = f"environment map {light.map}, scale {light.scale:g}"
    elif light.type == "area":
        emit = f"power {_format_value(light.power)}" if light.power is not None else \
            f"radiance {_format_value(light.radiance or (1.0, 1.0, 1.0))}"
        light_text = (f"area at {_format_value(light.position)}, edges {_format_value(light.u)} x "
                      f"{_format_value(light.v)}, {emit}" + (", two-sided" if light.two_sided else ""))
    elif light.type == "linear":
        light_text = (f"linear {_format_value(light.start)} -> {_format_value(light.end)}, intensity "
                      f"{_format_value(light.intensity)} per unit length")
    else:
        light_text = (
            f"spot at {_format_value(light.position)}, direction {_format_value(light.direction)}, "
            f"cone {light.cone_deg:g} deg, intensity {_format_value(light.intensity)}"
            + (f", texture {light.texture}" if light.texture else "")
        )
    med = config.medium
    phase = med.phase.type + (f" (g {med.phase.g:g})" if med.phase.type == "henyey_greenstein" else "")
    sc = config.render.scattering
    lt = config.render.lighting
    out = config.output
    extra = [a for a in AOV_NAMES if a in out.aovs and a != "color"]
    return [
        f"  scene:   {len(meshes)} mesh(es) ({kinds})",
        f"  camera:  {cam.width}x{cam.height}, fov_y {cam.fov_y:g} deg, {_format_value(cam.position)} -> "
        f"{_format_value(cam.look_at)}, near {cam.near:g}, far {cam.far:g}",
        f"  light:   {light_text}",
        f"  medium:  sigma_t {med.sigma_t:g}, albedo {med.albedo:g}, phase {phase}",
        f"  method:  {sc.method} (visibility {sc.visibility}, {sc.steps} steps)" if lt.method is None else
        f"  method:  lighting {lt.method} ({lt.samples} strata x {lt.passes} passes, filter {lt.filter}"
        f"{', CSM file ' + str(lt.csm.file) if lt.csm.file else ''})",
        f"  output:  {out.dir / out.name}.exr/.png" + (f" + {', '.join(extra)}" if extra else ""),
    ]


def _default_suite(run) -> str | None:
    try:
        default = inspect.signature(run).parameters["suite"].default
    except (KeyError, TypeError, ValueError):
        return None
    return default if isinstance(default, str) else None


# ---- commands --------------------------------------------------------------------------------------


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, "--version", prog_name="warpscatter", message="%(prog)s %(version)s")
@click.option("--debug", "debug", is_flag=True, help="Show full tracebacks of errors (any command).")
@click.pass_context
def main(ctx: click.Context, debug: bool) -> None:
    """Shadows and single scattering in participating media, as NVIDIA Warp kernels."""
    ctx.obj = {"debug": debug}


@main.command()
@click.argument("config_path", metavar="CONFIG", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "-o",
    "--output-dir",
    "output_dir",
    type=click.Path(path_type=Path),
    help="Write outputs here (relative to the current folder) instead of output.dir.",
)
@_set_option
@click.option("--method", metavar="NAME", help="Scattering method (same as --set render.scattering.method=NAME), or "
              "a lighting method csm / raytrace (same as --set render.lighting.method=NAME).")
@click.option("-q", "--quiet", is_flag=True, help="No progress or tables; print only the written files.")
@_debug_option
@click.pass_context
def render(ctx, config_path: Path, output_dir, overrides, method, quiet: bool, debug: bool) -> None:
    """Render the pipeline described by CONFIG (a YAML file).

    Writes NAME.exr, NAME.png and the AOVs of output.aovs (NAME.scattering.exr, NAME.surface.exr,
    NAME.depth.exr) into output.dir or -o DIR, then prints the per-stage timings.
    """
    debug = debug or ctx.obj.get("debug", False)
    section = "lighting" if method in methods.LIGHTING else "scattering"
    overrides = list(overrides) + ([f"render.{section}.method={method}"] if method else [])
    config = _load(config_path, overrides, debug)
    out_dir = _out_dir(output_dir)
    if out_dir is not None:
        config.output.dir = out_dir

    progress = ProgressDisplay(enabled=not quiet)
    try:
        pipeline = importlib.import_module("warpscatter.pipeline")
        result = pipeline.render(config, out_dir=out_dir, progress=progress)
    except KeyboardInterrupt:
        progress.close()
        _fail("interrupted", EXIT_INTERRUPTED)
    except Exception as exc:
        progress.close()
        _fail_error(exc, debug)
    progress.close()

    files = [Path(f) for f in getattr(result, "files", [])]
    if not quiet:
        click.echo(timing_table(getattr(result, "timings", {})))
        stats = dict(getattr(result, "stats", {}) or {})
        if stats:
            click.echo("stats:")
            for k, v in stats.items():
                click.echo(f"  {k}: {_format_value(v)}")
        click.echo("wrote:")
    for f in files:
        click.echo(f"  {f}" if not quiet else str(f))


@main.command()
@click.argument("config_path", metavar="CONFIG", type=click.Path(dir_okay=False, path_type=Path))
@_set_option
@click.option("--dump", is_flag=True, help="Print the whole resolved config (defaults, absolute paths) as YAML.")
@_debug_option
@click.pass_context
def validate(ctx, config_path: Path, overrides, dump: bool, debug: bool) -> None:
    """Check CONFIG (and --set overrides) without rendering; print a summary or every problem."""
    config = _load(config_path, overrides, debug or ctx.obj.get("debug", False))
    if dump:
        click.echo(config.model_dump_yaml(), nl=False)
        return
    click.echo(f"ok: {config.source or config_path}")
    for line in _summary(config):
        click.echo(line)


@main.command()
@click.argument("suite", required=False)
@click.option("--repeats", type=click.IntRange(min=1), default=5, show_default=True, help="Timed runs per case.")
@click.option("--warmup", type=click.IntRange(min=0), default=1, show_default=True, help="Untimed runs first.")
@click.option(
    "-o",
    "--output-dir",
    "output_dir",
    type=click.Path(path_type=Path),
    help="Folder for the JSON report (and PNG chart); default: the bench module's (bench-out).",
)
@click.option("--quick", is_flag=True, help="Smaller sizes and fewer cases (a smoke run).")
@click.option("--list", "list_suites", is_flag=True, help="List the suites and exit.")
@_debug_option
@click.pass_context
def bench(ctx, suite, repeats: int, warmup: int, output_dir: Path, quick: bool, list_suites: bool, debug: bool):
    """Run benchmark SUITE (or "all"): per-stage median times, memory and error against the ray marcher.

    Without SUITE, runs the bench module's default suite. --list shows the suites.
    """
    debug = debug or ctx.obj.get("debug", False)
    try:
        bench_module = importlib.import_module("warpscatter.bench")
        suites = dict(bench_module.SUITES)
    except Exception as exc:
        _fail(_error_text(exc), EXIT_FAILURE, debug)
    if list_suites:
        width = max((len(n) for n in suites), default=0)
        for name, suite_record in suites.items():
            click.echo(f"{name:<{width}}  {suite_record.description}")
        return
    if suite is None:
        suite = _default_suite(bench_module.run) or next(iter(suites), None)
    if suite not in suites and suite != "all":
        _fail(f"unknown suite {suite!r} (choose from: {', '.join([*suites, 'all'])})", EXIT_INVALID)
    out_dir = _out_dir(output_dir)

    progress = ProgressDisplay(enabled=True)
    try:
        report = bench_module.run(
            suite, repeats=repeats, warmup=warmup, out_dir=out_dir, quick=quick, progress=progress
        )
    except KeyboardInterrupt:
        progress.close()
        _fail("interrupted", EXIT_INTERRUPTED)
    except Exception as exc:
        progress.close()
        _fail(_error_text(exc), EXIT_FAILURE, debug)
    progress.close()
    click.echo(report.table())
    files = list(getattr(report, "files", []))
    if files:
        click.echo("wrote:")
        for f in files:
            click.echo(f"  {f}")



def _grid(text: str | None, option: str) -> tuple[int, int] | None:
    """``N1xN2`` as two positive integers (None stays None)."""
    if text is None:
        return None
    try:
        n1, n2 = (int(x) for x in text.lower().split("x"))
        if n1 < 1 or n2 < 1:
            raise ValueError
    except ValueError:
        _fail(f"{option}: expected N1xN2 with positive integers, got {text!r}", EXIT_INVALID)
    return n1, n2


_CSM = csm_settings.CSMBuildSettings.model_fields


def _default(name: str) -> str:
    d = _CSM[name].default
    return "x".join(map(str, d)) if isinstance(d, tuple) else str(d)


@main.command()
@click.argument("source", type=click.Path(path_type=Path))
@click.option("-o", "--output", "output", type=click.Path(path_type=Path), required=True,
              help="The .npz file to write (written to a temporary name, then renamed).")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE", help="Config overrides (SOURCE = config).")
@click.option("--maps", default=None, metavar="N1xN2",
              help=f"Lat-long grid of map directions (azimuth x polar cells) [default: the config's "
                   f"render.lighting.csm.maps, else {_default('maps')}].")
@click.option("--resolution", type=click.IntRange(min=csm_settings.MIN_RESOLUTION, max=csm_settings.MAX_RESOLUTION),
              default=None, help=f"Depth-map resolution M [default: the config's, else {_default('resolution')}].")
@click.option("--enumeration", type=click.Choice(csm_settings.ENUMERATIONS), default=None,
              help=f"Order of the maps along the compressed sequence [default: the config's, else "
                   f"{_default('enumeration')}].")
@click.option("--layers", type=click.Choice(csm_settings.DEPTH_LAYERS), default=None,
              help=f"Depths kept per texel: first and second surface, or first and third (closed meshes) [default: "
                   f"the config's, else {_default('layers')}].")
@click.option("--far", type=click.Choice(csm_settings.FAR_MODES), default=None,
              help=f"Far depth of texels without a second surface: the bounding sphere, or infinity [default: the "
                   f"config's, else {_default('far')}].")
@click.option("--batch", type=click.IntRange(min=1, max=csm_settings.MAX_BATCH), default=None,
              help=f"Maps rendered and compressed per batch (memory ~ M^2 x batch) [default: the config's, else "
                   f"{_default('batch')}].")
@click.option("--light-samples", "light_samples", default=None, metavar="N1xN2",
              help=f"Config with an area / linear light: depth cube maps at N1xN2 points of the light (N1 for "
                   f"linear) [default: the config's, else {_default('light_samples')}].")
@_debug_option
@click.pass_context
def precompute(ctx, source: Path, output: Path, overrides, maps, resolution, enumeration, layers, far, batch,
               light_samples, debug: bool):
    """Build and save a coherent shadow map (Ritschel 2007) for SOURCE: a mesh file, or a config's scene.

    From a config, the CSM holds the scene's occluders (meshes not marked receiver_only) in world space, ready
    for render.lighting.csm.file: depth cube maps at the light's sample points for an area or linear light
    (unless render.lighting.csm.local_lights is semi_local), else lat-long maps. Options not given take the
    config's render.lighting.csm values (a mesh file: their defaults).
    """
    debug = debug or ctx.obj.get("debug", False)
    given = {"maps": _grid(maps, "--maps"), "light_samples": _grid(light_samples, "--light-samples"),
             "resolution": resolution, "enumeration": enumeration, "layers": layers, "far": far, "batch": batch}
    if output.suffix != ".npz":
        _fail(f"-o: the CSM file must end in .npz, got {output}", EXIT_INVALID)
    if not source.is_file():
        _fail(f"{source}: file not found", EXIT_INVALID)
    light, base = None, csm_settings.CSMBuildSettings()
    try:
        if source.suffix in (".yaml", ".yml"):
            from warpscatter.csm.occluders import scene_occluders
            from warpscatter.scene import build_scene

            config = load_config(source, list(overrides))
            scene = build_scene(config)
            vertices, triangles = scene_occluders(scene)
            if len(triangles) == 0:
                _fail(f"{source}: every mesh is receiver_only: no occluder to build a CSM of", EXIT_INVALID)
            light, base = scene.light, config.render.lighting.csm
        else:
            from warpscatter.scene.meshes import load_mesh

            mesh = load_mesh(source)
            vertices, triangles = mesh.vertices, mesh.triangles
    except ConfigError as exc:
        _fail(str(exc), EXIT_INVALID)
    except Exception as exc:
        _fail(f"{source}: {_error_text(exc)}", EXIT_INVALID, debug)
    try:
        settings = csm_settings.CSMBuildSettings.model_validate(
            {**base.model_dump(), "file": None, **{k: v for k, v in given.items() if v is not None}})
    except ValidationError as exc:
        problems = format_validation_errors(exc, csm_settings.CSMBuildSettings)
        _fail("\n".join(f"--{p.replace('_', '-')}" for p in problems), EXIT_INVALID)
    from warpscatter.csm import save_csm
    from warpscatter.csm.compress import KIND_CUBE
    from warpscatter.csm.occluders import prepare_csm

    progress = ProgressDisplay(enabled=True)
    try:
        t0 = time.perf_counter()
        csm = prepare_csm(light, settings, vertices, triangles,
                          progress=lambda f: progress("depth maps + compression", f))
        output.parent.mkdir(parents=True, exist_ok=True)
        save_csm(csm, output)
    except KeyboardInterrupt:
        progress.close()
        _fail("interrupted", EXIT_INTERRUPTED)
    except Exception as exc:
        progress.close()
        _fail_error(exc, debug)
    progress.close()
    st = csm.stats
    what = (f"6 x {csm.n1}x{csm.n2} cube maps of the {light.kind} light" if csm.kind == KIND_CUBE
            else f"{csm.n1}x{csm.n2} maps")
    click.echo(f"coherent shadow map: {len(triangles)} triangles, N = {what} of {csm.resolution}^2, "
               f"{settings.enumeration}")
    click.echo(f"  segments {st.num_segments} ({st.segments_per_texel:.1f} per texel), "
               f"{st.compressed_bytes / 2**20:.1f} MiB, ratio {st.ratio:.1f}:1 against float32 maps")
    click.echo(f"  render {st.seconds_render:.1f} s, compress {st.seconds_compress:.1f} s, "
               f"total {time.perf_counter() - t0:.1f} s, peak working memory {st.peak_working_bytes / 2**20:.1f} MiB")
    click.echo(f"wrote:\n  {output}")


if __name__ == "__main__":
    main()
