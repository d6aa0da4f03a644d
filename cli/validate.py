"""``warpscatter validate`` (check a config, print its summary or every problem) and ``warpscatter schema`` (the JSON
schema of a config)."""

from __future__ import annotations

import json
from pathlib import Path

import click

from warpscatter import methods
from warpscatter.config import AOV_NAMES, Config

from .common import (
    EXIT_FAILURE,
    EXIT_INVALID,
    common_options,
    fail,
    find_config,
    format_value,
    load_or_exit,
    set_option,
    setup,
)


def _scattering_summary(sc) -> str:
    """What the scattering method of a ``render.scattering`` section marches with or stores."""
    method = methods.get("scattering", sc.method)
    if method.visibility == methods.VISIBILITY_CONFIGURABLE:
        return f"visibility {sc.visibility}, {sc.march_steps} steps, {sc.march_jitter} jitter"
    options = f", {sc.prefiltered.mip_levels} row mip levels" if sc.prefiltered.mip_levels > 1 else ""
    warp = sc.prefiltered.depth_warp_for(sc.method, sc.shadow_map.size[0])
    options += f", depth warp {warp:g}" if warp != 0.0 else ""
    if sc.method == "fourier":
        return f"{sc.fourier.coefficients} coefficients, {sc.shadow_map.resolution}^2 maps{options}"
    return (f"{sc.num_moments} moments, {sc.filtered_bits_per_texel} bits per texel, {sc.shadow_map.resolution}^2 "
            f"maps{options}")


def summary(config: Config) -> list[str]:
    """The lines ``validate`` prints: one per section (scene, camera, light, medium, sky fill, method, output)."""
    meshes = config.scene.meshes
    procedural = [m.procedural for m in meshes if m.procedural]
    kinds = f"{len(meshes) - len(procedural)} file(s)"
    if procedural:
        kinds += f", procedural: {', '.join(procedural)}"
    cam = config.camera
    med = config.medium
    phase = med.phase.type + (f" (g {med.phase.g:g})" if med.phase.type == "henyey_greenstein" else "")
    sc = config.render.scattering
    lt = config.render.lighting
    out = config.output
    extra = [a for a in AOV_NAMES if a in out.aovs and a != "color"]
    return [
        f"  scene:   {len(meshes)} mesh(es) ({kinds})",
        f"  camera:  {cam.width}x{cam.height}"
        f"{f' ({cam.supersample}x{cam.supersample} rays a pixel)' if cam.supersample > 1 else ''}, fov_y "
        f"{cam.fov_y:g} deg, {format_value(cam.position)} -> {format_value(cam.look_at)}, near {cam.near:g}, "
        f"far {cam.far:g}",
        f"  light:   {config.light.describe()}",
        f"  medium:  sigma_t {format_value(med.sigma_t)}, albedo {format_value(med.albedo)}, phase {phase}",
        *([f"  surfaces: sky fill {format_value(config.render.surfaces.ambient)}"]
          if any(config.render.surfaces.ambient) else []),
        f"  method:  {sc.method} ({_scattering_summary(sc)})" if lt.method is None else
        f"  method:  lighting {lt.method} ({lt.samples} strata x {lt.passes} passes, filter {lt.filter}"
        f"{', CSM file ' + str(lt.csm.file) if lt.csm.file else ''})",
        f"  output:  {out.dir / config.output_name}.exr/.png/.json" + (f" + {', '.join(extra)}" if extra else ""),
    ]


@click.command()
@click.argument("config_path", metavar="CONFIG", type=click.Path(dir_okay=False, path_type=Path))
@set_option
@click.option("--dump", is_flag=True, help="Print the whole resolved config (defaults, absolute paths) as YAML.")
@common_options(kernels=False)
@click.pass_context
def validate(ctx, config_path: Path, overrides, dump: bool, verbose, quiet, debug: bool) -> None:
    """Check CONFIG (and --set overrides) without rendering; print a summary or every problem."""
    setup(verbose, quiet)
    config = load_or_exit(find_config(config_path), overrides, debug or ctx.obj.get("debug", False))
    if dump:
        click.echo(config.model_dump_yaml(), nl=False)
        return
    memory = _memory_line(config)
    click.echo(f"ok: {config.source or config_path}")
    if not quiet:
        for line in summary(config):
            click.echo(line)
        if memory:
            click.echo(memory)


def _memory_line(config: Config) -> str | None:
    """The render's estimated peak memory against the budget (``warpscatter.pipeline.memory``) as a summary line;
    exits 2 when it does not fit, as ``render`` would refuse it. None for an animated config (its frames are checked
    by ``render``) or where the pipeline is a stand-in."""
    import importlib

    from warpscatter.errors import ConfigError

    pipeline = importlib.import_module("warpscatter.pipeline")
    memory = getattr(pipeline, "memory", None)
    if memory is None or config.animation is not None:
        return None
    try:
        budget = memory.memory_budget()
        estimate = memory.check_memory(config, budget)
    except ConfigError as exc:
        fail(str(exc), EXIT_INVALID)
    room = f" of {budget[0] / memory.GIB:.1f} GiB available ({budget[1]})" if budget else ""
    return f"  memory:  estimated peak {estimate / memory.GIB:.2f} GiB{room}"


@click.command()
@click.option("-o", "--output", "output", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Write the schema to this file instead of stdout.")
@common_options(kernels=False)
def schema(output, verbose, quiet, debug) -> None:
    """Print the JSON schema of a config (every key with its type, range, default and description).

    Point an editor's YAML language server at it for completion and checks, e.g. a first line
    `# yaml-language-server: $schema=warpscatter.schema.json`.
    """
    setup(verbose, quiet)
    text = json.dumps(Config.model_json_schema(), indent=2) + "\n"
    if output is None:
        click.echo(text, nl=False)
        return
    from warpscatter.io.output_sets import write_file_atomic

    try:
        output.parent.mkdir(parents=True, exist_ok=True)
        write_file_atomic(output, lambda tmp: tmp.write_text(text, encoding="utf-8"))
    except OSError as exc:
        fail(f"-o {output}: {exc}", EXIT_FAILURE, debug)
    if not quiet:
        click.echo(f"wrote:\n  {output}")


__all__ = ["schema", "summary", "validate"]
