"""``warpscatter sweep``: every case of a sweep file (configs x a grid of overrides) rendered, timed and compared with
the sweep's reference."""

from __future__ import annotations

from pathlib import Path

import click

from warpscatter.errors import ConfigError

from .common import (
    EXIT_FAILURE,
    EXIT_INVALID,
    ProgressDisplay,
    common_options,
    executor_options,
    fail,
    fail_error,
    interrupted,
    make_executor,
    resolve_out_dir,
    setup,
)


@click.command()
@click.argument("sweep_path", metavar="SWEEP", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output-dir", "output_dir", type=click.Path(path_type=Path), default=Path("sweep-out"),
              show_default=True, help="Folder for NAME.json, NAME.csv, the chart and (images: true) the images.")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE",
              help="Override a config value in every case and reference (added to the sweep's set; repeatable).")
@executor_options("inline")
@common_options(kernels=True)
@click.pass_context
def sweep(ctx, sweep_path, output_dir, overrides, executor, workers, address, verbose, quiet, debug, device,
          threads):
    """Render every case of a SWEEP file (configs x a grid of overrides), time each, compare it with the sweep's
    reference, and write one table (NAME.json, NAME.csv) and the error-vs-time chart.

    A failed case is reported with its error; the others go on (exit 1 when any failed).
    """
    from warpscatter.config import parse_override
    from warpscatter.runs.sweep import load_sweep, rows_table, run_sweep, sweep_cases

    debug = debug or ctx.obj.get("debug", False)
    setup(verbose, quiet)
    extra = {}
    for text in overrides:
        try:
            key, value = parse_override(text)
        except ValueError as exc:
            fail(f"--set {text}: {exc}", EXIT_INVALID)
        extra[".".join(map(str, key))] = value
    try:
        settings = load_sweep(sweep_path, extra)
        cases, _ = sweep_cases(settings)
    except ConfigError as exc:
        fail(str(ConfigError(exc.problems, sweep_path)), EXIT_INVALID)
    out_dir = resolve_out_dir(output_dir)
    setup(verbose, quiet, device, threads, kernels=True)
    pool = make_executor(executor, workers, address, len(cases), debug)
    progress = ProgressDisplay(enabled=not quiet, every_stage=verbose > 0)
    try:
        with pool:
            result = run_sweep(settings, out_dir, executor=pool, progress=progress)
    except KeyboardInterrupt:
        interrupted(progress)
    except Exception as exc:
        progress.close()
        fail_error(exc, debug)
    progress.close()
    if not quiet:
        click.echo(f"{len(result.rows)} case(s) on {pool.describe()}")
        click.echo(rows_table(result.rows))
        click.echo("wrote:")
    for f in result.files:
        click.echo(f"  {f}" if not quiet else str(f))
    if result.failed:
        fail(f"{len(result.failed)} of {len(result.rows)} cases failed", EXIT_FAILURE)


__all__ = ["sweep"]
