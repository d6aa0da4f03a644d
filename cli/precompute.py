"""``warpscatter precompute``: build and save a coherent shadow map (Ritschel 2007) of a mesh file or a config's
scene."""

from __future__ import annotations

import os
import time
from pathlib import Path

import click
from pydantic import ValidationError

from warpscatter.config import load_config
from warpscatter.csm import settings as csm_settings
from warpscatter.errors import ConfigError
from warpscatter.schema import format_validation_errors

from .common import (
    EXIT_INTERRUPTED,
    EXIT_INVALID,
    ProgressDisplay,
    common_options,
    error_text,
    fail,
    fail_error,
    format_bytes,
    setup,
)


def _grid(text: str | None, option: str) -> tuple[int, int] | None:
    """``N1xN2`` as two positive integers (None stays None)."""
    if text is None:
        return None
    try:
        n1, n2 = (int(x) for x in text.lower().split("x"))
        if n1 < 1 or n2 < 1:
            raise ValueError
    except ValueError:
        fail(f"{option}: expected N1xN2 with positive integers, got {text!r}", EXIT_INVALID)
    return n1, n2


_CSM = csm_settings.CSMBuildSettings.model_fields


def _default(name: str) -> str:
    d = _CSM[name].default
    return "x".join(map(str, d)) if isinstance(d, tuple) else str(d)


@click.command()
@click.argument("source", type=click.Path(path_type=Path))
@click.option("-o", "--output", "output", type=click.Path(path_type=Path), required=True,
              help="The .npz file to write, or a folder to write SOURCE_STEM.csm.npz into (written to a unique "
                   "temporary name, then renamed, holding the file's lock: another writer of it waits).")
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
@common_options(kernels=True)
@click.pass_context
def precompute(ctx, source: Path, output: Path, overrides, maps, resolution, enumeration, layers, far, batch,
               light_samples, verbose, quiet, debug: bool, device, threads):
    """Build and save a coherent shadow map (Ritschel 2007) for SOURCE: a mesh file, or a config's scene.

    From a config, the CSM holds the scene's occluders (meshes not marked receiver_only) in world space, ready
    for render.lighting.csm.file: depth cube maps at the light's sample points for an area or linear light
    (unless render.lighting.csm.local_lights is semi_local), else lat-long maps. Options not given take the
    config's render.lighting.csm values (a mesh file: their defaults).
    """
    debug = debug or ctx.obj.get("debug", False)
    given = {"maps": _grid(maps, "--maps"), "light_samples": _grid(light_samples, "--light-samples"),
             "resolution": resolution, "enumeration": enumeration, "layers": layers, "far": far, "batch": batch}
    setup(verbose, quiet, device, threads, kernels=True)
    if output.is_dir() or str(output).endswith(("/", os.sep)):
        output = output / f"{source.stem}.csm.npz"
    if output.suffix != ".npz":
        fail(f"-o: the CSM file must end in .npz (or be a folder), got {output}", EXIT_INVALID)
    if not source.is_file():
        fail(f"{source}: file not found", EXIT_INVALID)
    from warpscatter.io.output_sets import OutputFolderError, OutputNameError, check_output_target

    try:  # before any work: a folder that can hold the file, a name that fits and is not one of the writer's own
        check_output_target(output.parent, output.name, suffixes=[""], dir_key="-o", name_key="-o")
    except OutputNameError as exc:
        fail(exc.problems[0], EXIT_INVALID)
    except OutputFolderError as exc:
        fail(str(exc), EXIT_INVALID)
    light, base = None, csm_settings.CSMBuildSettings()
    try:
        if source.suffix in (".yaml", ".yml"):
            from warpscatter.csm.occluders import scene_occluders
            from warpscatter.scene import build_scene

            config = load_config(source, list(overrides))
            scene = build_scene(config)
            vertices, triangles = scene_occluders(scene)
            if len(triangles) == 0:
                fail(f"{source}: every mesh is receiver_only: no occluder to build a CSM of", EXIT_INVALID)
            light, base = scene.light, config.render.lighting.csm
        else:
            from warpscatter.scene.meshes import load_mesh

            mesh = load_mesh(source)
            vertices, triangles = mesh.vertices, mesh.triangles
    except ConfigError as exc:
        fail(str(exc), EXIT_INVALID)
    except Exception as exc:
        fail(f"{source}: {error_text(exc)}", EXIT_INVALID, debug)
    try:
        settings = csm_settings.CSMBuildSettings.model_validate(
            {**base.model_dump(), "file": None, **{k: v for k, v in given.items() if v is not None}})
    except ValidationError as exc:
        problems = format_validation_errors(exc, csm_settings.CSMBuildSettings)
        fail("\n".join(f"--{p.replace('_', '-')}" for p in problems), EXIT_INVALID)
    from warpscatter.csm import save_csm
    from warpscatter.csm.compress import KIND_CUBE
    from warpscatter.csm.occluders import prepare_csm
    from warpscatter.io.output_sets import remove_stale_temporaries

    progress = ProgressDisplay(enabled=not quiet, every_stage=verbose > 0)
    try:
        t0 = time.perf_counter()
        csm = prepare_csm(light, settings, vertices, triangles,
                          progress=lambda f: progress("depth maps + compression", f))
        output.parent.mkdir(parents=True, exist_ok=True)
        remove_stale_temporaries(output.parent)  # a killed precompute's temporary, say
        save_csm(csm, output)  # a unique temporary, renamed in under the file's lock (another writer waits)
    except KeyboardInterrupt:
        progress.close()
        fail("interrupted", EXIT_INTERRUPTED)
    except Exception as exc:
        progress.close()
        fail_error(exc, debug)
    progress.close()
    st = csm.stats
    what = (f"6 x {csm.n1}x{csm.n2} cube maps of the {light.kind} light" if csm.kind == KIND_CUBE
            else f"{csm.n1}x{csm.n2} maps")
    if not quiet:
        click.echo(f"coherent shadow map: {len(triangles)} triangles, N = {what} of {csm.resolution}^2, "
                   f"{settings.enumeration}")
        click.echo(f"  segments {st.num_segments} ({st.segments_per_texel:.1f} per texel), "
                   f"{st.compressed_bytes / 2**20:.1f} MiB, ratio {st.ratio:.1f}:1 against float32 maps")
        click.echo(f"  render {st.seconds_render:.1f} s, compress {st.seconds_compress:.1f} s, "
                   f"total {time.perf_counter() - t0:.1f} s, peak working memory "
                   f"{format_bytes(st.peak_working_bytes)}")
    click.echo(str(output) if quiet else f"wrote:\n  {output}")


__all__ = ["precompute"]
