"""``warpscatter gallery``: render the pictures the docs show (:func:`warpscatter.runs.gallery.build`).

Registered on the application in :mod:`.main`; the options, logging set-up and exit codes are the other commands'
(:mod:`.common`).
"""

from __future__ import annotations

import time
from pathlib import Path

import click

from .common import (
    EXIT_FAILURE,
    EXIT_INVALID,
    ProgressDisplay,
    common_options,
    error_text,
    fail,
    format_bytes,
    interrupted,
    resolve_out_dir,
    setup,
)


@click.command("gallery")
@click.option("-o", "--output-dir", "output_dir", type=click.Path(path_type=Path), default=Path("docs/images"),
              show_default=True, help="The gallery folder (relative to the current folder).")
@click.option("--bench-dir", "bench_dir", type=click.Path(path_type=Path), default=None,
              help="Chart the bench JSON results (bench-SUITE.json) of a `warpscatter bench ... -o DIR` run into "
                   "OUTPUT/bench/ (without it the charts are skipped and those already there kept).")
@click.option("--quick", is_flag=True, help="Tiny sizes and a short reference (a smoke run: the tests).")
@common_options(kernels=True)
@click.pass_context
def gallery(ctx, output_dir: Path, bench_dir: Path | None, quick: bool, verbose, quiet, debug: bool, device,
            threads):
    """Render the docs' pictures into OUTPUT (docs/images): the README's hero picture (quickstart.png), every
    bundled config with its own method (configs/), the methods side by side on the quickstart with their signed
    error images (compare_quickstart.png, methods/), the bench charts of --bench-dir (bench/), and gallery.json,
    what made each image. About 3 minutes on two shared cores (--quick: seconds, compile aside).
    """
    from warpscatter.runs.gallery import bench_files, build

    debug = debug or (ctx.obj or {}).get("debug", False)
    device = setup(verbose, quiet, device, threads, kernels=True)
    out_dir = resolve_out_dir(output_dir)
    if bench_dir is not None:
        try:
            bench_files(bench_dir)
        except ValueError as exc:
            fail(str(exc), EXIT_INVALID)
    progress = ProgressDisplay(enabled=not quiet)

    start = time.perf_counter()

    def on_job(k: int, n: int, label: str) -> None:  # a terminal: a bar per render stage; else a line per image
        if progress.tty:
            progress.prefix = f"[{k + 1}/{n}] {label}: "
        elif not quiet:
            click.echo(f"[{time.perf_counter() - start:7.2f}s] [{k + 1}/{n}] {label}", err=True)

    try:
        result = build(out_dir, quick=quick, bench_dir=bench_dir, device=device,
                       progress=progress if progress.tty else None, on_job=on_job)
    except KeyboardInterrupt:
        interrupted(progress)
    except ValueError as exc:
        progress.close()
        fail(str(exc), EXIT_INVALID, debug)
    except Exception as exc:
        progress.close()
        fail(error_text(exc), EXIT_FAILURE, debug)
    progress.close()
    for section, reason in result.skipped.items():
        click.echo(f"note: {section}: {reason}", err=True)
    if not quiet:
        click.echo(f"wrote {len(result.entries)} images ({format_bytes(result.total_bytes)}) in "
                   f"{result.seconds:.1f} s:")
    for e in result.entries:
        size = "x".join(map(str, e.size or []))
        click.echo(str(result.out_dir / e.path) if quiet else f"  {e.path}  {size}  {format_bytes(e.bytes)}")
    if result.manifest is not None:
        click.echo(str(result.manifest) if quiet else f"  {result.manifest.name}")
    if result.failures:
        fail(f"{len(result.failures)} gallery image(s) failed (see above): {', '.join(result.failures)}",
              EXIT_FAILURE)
