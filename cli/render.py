"""``warpscatter render``: render one or more configs (still or animated) and report what was written."""

from __future__ import annotations

import importlib
import json
import sys
import traceback
from pathlib import Path

import click

from warpscatter import methods
from warpscatter.config import Config
from warpscatter.errors import ConfigError, WarpscatterError
from warpscatter.io.resources import in_package

from .common import (
    EXIT_FAILURE,
    EXIT_INVALID,
    TIMING_ROWS,
    ProgressDisplay,
    common_options,
    error_text,
    executor_options,
    fail,
    fail_error,
    find_config,
    interrupted,
    load_or_exit,
    make_executor,
    resolve_out_dir,
    set_option,
    setup,
    stats_lines,
    timing_table,
)


def _own_method_and_name(path: Path, overrides) -> tuple[str | None, str | None]:
    """The method and output name a config file (with its --set overrides) asks for itself, or (None, None) when it
    cannot be read (loading it then reports why)."""
    from warpscatter.config import OutputConfig, apply_overrides, read_config_data
    from warpscatter.scattering.settings import ScatteringSettings

    try:
        data, _ = read_config_data(path)
        apply_overrides(data, list(overrides))
    except ConfigError:
        return None, None
    render = data.get("render") if isinstance(data.get("render"), dict) else {}
    section = {k: (v if isinstance(v, dict) else {}) for k, v in render.items()}
    method = (section.get("lighting", {}).get("method") or section.get("scattering", {}).get("method")
              or ScatteringSettings.model_fields["method"].default)
    output = data.get("output") if isinstance(data.get("output"), dict) else {}
    return str(method), str(output.get("name") or OutputConfig.model_fields["name"].default)


def _render_config(path: Path, overrides, method: str | None, name: str | None, seed: int | None,
                   debug: bool) -> Config:
    """One config of ``render``, loaded with its overrides, --method, --name and --seed applied before validation
    (exit 2 when invalid), as --set would apply them.

    Where --method changes the method, the name is the config's own (neither --name nor --set output.name) and it
    does not hold ``{method}``, ``_{method}`` is appended to it: the render does not overwrite the config's own
    outputs."""
    path = find_config(path)
    own_method, own_name = _own_method_and_name(path, overrides)
    extra = []
    if method:
        extra.append(f"render.{'lighting' if method in methods.LIGHTING else 'scattering'}.method={method}")
    named = name is not None or any(o.partition("=")[0].strip() == "output.name" for o in overrides)
    if name is not None:
        extra.append(f"output.name={json.dumps(name)}")
    elif method and own_name and method != own_method and not named and "{method}" not in own_name:
        extra.append(f"output.name={json.dumps(own_name + '_{method}')}")
    if seed is not None:
        lighting = method in methods.LIGHTING if method else own_method in methods.LIGHTING
        extra.append(f"render.{'lighting' if lighting else 'scattering'}.seed={seed}")
    return load_or_exit(path, [*overrides, *extra], debug)


@click.command()
@click.argument("config_paths", metavar="CONFIG...", nargs=-1, required=True,
                type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output-dir", "output_dir", type=click.Path(path_type=Path),
              help="Write outputs here (relative to the current folder) instead of output.dir (relative to the "
                   "config file).")
@set_option
@click.option("--method", metavar="NAME", help="Scattering method (same as --set render.scattering.method=NAME), or "
              "a lighting method csm / raytrace (same as --set render.lighting.method=NAME); appends _NAME to the "
              "config's output name unless its method is NAME, the name holds {method} or --name is given.")
@click.option("--name", "name", metavar="TEMPLATE", help="Output file stem (output.name), a template: {config} the "
              "config file's stem, {method} the method, e.g. --name '{config}_{method}'.")
@click.option("--seed", type=int, default=None, help="Seed of the jitter / Monte-Carlo patterns (render.scattering."
              "seed, or render.lighting.seed for csm / raytrace); the same seed gives the same image.")
@click.option("--frames", metavar="A:B", default=None, help="Animated configs: the frames to render (A:B inclusive, "
              "A:B:STEP or A,B,C) [default: all].")
@click.option("--force", is_flag=True, help="Animated configs: render frames again even where their files exist "
              "from the same config (by default a run resumes).")
@click.option("--preview", type=click.Choice(("auto", "mp4", "gif", "none")), default=None,
              help="Animated configs: the preview movie [default: animation.preview].")
@executor_options("local")
@common_options(kernels=True)
@click.pass_context
def render(ctx, config_paths, output_dir, overrides, method, name, seed, frames, force, preview, executor, workers,
           address, verbose, quiet, debug, device, threads):
    """Render the pipelines described by one or more CONFIG files (YAML; or the name of a bundled config, e.g.
    quickstart).

    Writes, per config, NAME.exr, NAME.png, the AOVs of output.aovs (NAME.scattering.exr, NAME.surface.exr,
    NAME.depth.exr) and NAME.json (what made them: the resolved config, versions, timings, statistics) into
    output.dir or -o DIR, then prints a summary, the timings of the longest stages and the written files (-v: every
    stage and the statistics). A render's warnings, e.g. a light that reaches no pixel, go to stderr as
    "warning: ..." unless -q. Every config is checked before the first render.

    A config with an animation section renders its frames (NAME.0001.exr ...) through --executor, skipping the
    frames already rendered from the same config, then writes a preview (NAME.mp4 or NAME.gif).
    """
    debug = debug or ctx.obj.get("debug", False)
    setup(verbose, quiet)
    out_dir = resolve_out_dir(output_dir)
    configs = [_render_config(p, overrides, method, name, seed, debug) for p in config_paths]
    for path, config in zip(config_paths, configs, strict=True):
        if out_dir is None and in_package(config.output.dir):  # a bundled config of a wheel install
            config.output.dir = Path.cwd() / "out"
            if not quiet:
                click.echo(f"note: {path} is bundled inside the installed package: writing to {config.output.dir} "
                           f"(give -o DIR to choose)", err=True)
        elif out_dir is not None:  # the sidecar then records where the files went
            config.output.dir = out_dir
    targets: dict[Path, Path] = {}
    for path, config in zip(config_paths, configs, strict=True):
        target = (out_dir or config.output.dir) / config.output_name
        if target in targets:
            fail(f"{targets[target]} and {path} would both write {target}.*: give them different output.name "
                  f"values (e.g. --name '{{config}}_{{method}}')", EXIT_INVALID)
        targets[target] = path

    frame_lists = {}
    for path, config in zip(config_paths, configs, strict=True):
        if config.animation is not None:
            from warpscatter.runs.animation import parse_frames

            try:
                frame_lists[path] = parse_frames(frames, *config.animation.frame_range)
            except ValueError as exc:
                fail(f"{path}: {exc}", EXIT_INVALID)
    if frames and not frame_lists:
        fail("--frames: none of the configs has an animation section", EXIT_INVALID)

    pipeline = importlib.import_module("warpscatter.pipeline")
    check_memory = getattr(pipeline, "check_memory", None)  # pipeline/memory.py (absent from a stand-in pipeline)
    try:
        budget = pipeline.memory.memory_budget() if check_memory is not None else None
    except ConfigError as exc:
        fail(str(exc), EXIT_INVALID)
    for path, config in zip(config_paths, configs, strict=True):
        try:  # every config (every frame's) is checked before the first render, its memory included
            for frame_config in ((config.at_frame(f) for f in frame_lists[path]) if path in frame_lists
                                 else [config]):
                if budget is not None:
                    check_memory(frame_config, budget)
        except ConfigError as exc:
            fail(str(ConfigError(exc.problems, path)), EXIT_INVALID)
    device = setup(verbose, quiet, device, threads, kernels=True)

    failures = []
    for k, (path, config) in enumerate(zip(config_paths, configs, strict=True)):
        prefix = f"[{k + 1}/{len(configs)}] " if len(configs) > 1 else ""
        expected = None if quiet or path in frame_lists else previous_timings(out_dir or config.output.dir,
                                                                               config.output_name)
        progress = ProgressDisplay(enabled=not quiet, prefix=prefix, expected=expected, every_stage=verbose > 0)
        if path in frame_lists:
            code = _render_animation(config, frame_lists[path], out_dir, progress, quiet, debug, force, preview,
                                     (executor, workers, address))
            if code:
                failures.append(code)
            continue
        try:
            result = pipeline.render(config, out_dir=out_dir, progress=progress, device=device)
        except KeyboardInterrupt:
            interrupted(progress)
        except Exception as exc:
            progress.close()
            if len(configs) == 1:
                fail_error(exc, debug)
            if debug:
                traceback.print_exc(file=sys.stderr)
            click.echo(f"error: {path}: {error_text(exc)}", err=True)
            failures.append(exc.exit_code if isinstance(exc, WarpscatterError) else EXIT_FAILURE)
            continue
        progress.close()
        files = [Path(f) for f in getattr(result, "files", [])]
        lines = stats_lines(getattr(result, "stats", {}))
        if not quiet:
            if len(configs) > 1:
                click.echo(f"{prefix}{path}")
            click.echo(_render_summary(config, device, files, len(lines) if not verbose else 0))
            click.echo(timing_table(getattr(result, "timings", {}), max_rows=None if verbose else TIMING_ROWS))
            if lines and verbose:
                click.echo("stats:")
                for line in lines:
                    click.echo(f"  {line}")
            if files:
                click.echo("wrote:")
        for f in files:
            click.echo(f"  {f}" if not quiet else str(f))
        if not quiet:
            for text in getattr(result, "warnings", None) or []:
                click.echo(f"warning: {text}", err=True)
    if failures:
        fail(f"{len(failures)} of {len(configs)} configs failed", failures[0])


def previous_timings(folder: Path, name: str) -> dict | None:
    """The stage timings of the previous render of the same output (``timings_s`` of its ``NAME.json``), or None:
    what the progress display expects of the stages still to come."""
    try:
        timings = json.loads((Path(folder) / f"{name}.json").read_text(encoding="utf-8")).get("timings_s")
    except (OSError, ValueError, AttributeError):
        return None
    return timings if isinstance(timings, dict) and timings else None


def _render_summary(config: Config, device: str | None, files: list[Path], hidden_stats: int) -> str:
    """The first line of a render's report: output name, method, size, device, and where the statistics are when
    they are not shown (``hidden_stats`` of them)."""
    lt, sc = config.render.lighting, config.render.scattering
    text = f"{config.output_name}: {lt.method or sc.method}, {config.camera.width} x {config.camera.height}"
    text += f" on {device}" if device else ""
    if hidden_stats:
        sidecar = next((f.name for f in files if f.suffix == ".json"), None)
        text += f" ({hidden_stats} statistic{'s' if hidden_stats != 1 else ''}: -v" + (f" or {sidecar})" if sidecar
                                                                                    else ")")
    return text


def _render_animation(config, frames, out_dir, progress, quiet, debug, force, preview, executor_args) -> int:
    """Render one animated config's frames; print what was rendered, skipped and failed; return an exit code."""
    from warpscatter.runs.animation import render_animation

    kind, workers, address = executor_args
    executor = make_executor(kind, workers, address, len(frames), debug)
    try:
        with executor:
            result = render_animation(config, out_dir, frames=frames, executor=executor, resume=not force,
                                      preview=preview, progress=progress)
    except KeyboardInterrupt:
        interrupted(progress)
    finally:
        progress.close()
    rendered = result.rendered
    if not quiet:
        fps = len(rendered) / result.seconds if rendered and result.seconds > 0 else 0.0
        click.echo(f"{config.output_name}: {len(rendered)} frame(s) rendered, {len(result.skipped)} already done, "
                   f"{len(result.failed)} failed; {result.seconds:.1f} s ({fps:.2f} frames/s) on {result.executor}")
        if rendered:
            per_frame = sorted(sum(r.timings.values()) for r in rendered)
            click.echo(f"  render time per frame: median {per_frame[len(per_frame) // 2] * 1e3:.1f} ms")
        for note in result.notes:
            click.echo(f"  note: {note}")
    for r in result.failed:
        click.echo(f"error: frame {r.label}: {r.error}", err=True)
        if debug and r.details:
            click.echo(r.details, err=True)
    files = [f for r in rendered for f in r.files] + ([str(result.preview)] if result.preview else [])
    if not quiet and files:
        click.echo("wrote:")
    for f in files:
        click.echo(f"  {f}" if not quiet else str(f))
    return EXIT_FAILURE if result.failed else 0


__all__ = ["previous_timings", "render"]
