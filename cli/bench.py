"""``warpscatter bench``: run a benchmark suite (:func:`warpscatter.bench.run`), list the suites, or compare two
reports."""

from __future__ import annotations

import importlib
import inspect
from pathlib import Path

import click

from .common import (
    EXIT_FAILURE,
    EXIT_INVALID,
    ProgressDisplay,
    common_options,
    error_text,
    fail,
    interrupted,
    resolve_out_dir,
    setup,
)

#: The suite ``warpscatter bench`` runs without a SUITE argument (the default of ``warpscatter.bench.run``; a test
#: checks that they agree) and its duration on two cores.
DEFAULT_SUITE = "reference"
DEFAULT_SUITE_DURATION = "about 2 minutes on two cores"


def _default_suite(run) -> str | None:
    try:
        default = inspect.signature(run).parameters["suite"].default
    except (KeyError, TypeError, ValueError):
        return None
    return default if isinstance(default, str) else None


@click.command()
@click.argument("suite", required=False)
@click.argument("reports", nargs=-1, type=click.Path(dir_okay=False, exists=True, path_type=Path))
@click.option("--repeats", type=click.IntRange(min=1), default=5, show_default=True,
              help="Timed runs per case (pareto: interleaved rounds over all of a scene's cases).")
@click.option("--warmup", type=click.IntRange(min=0), default=1, show_default=True, help="Untimed runs first.")
@click.option(
    "-o",
    "--output-dir",
    "output_dir",
    type=click.Path(path_type=Path),
    help="Folder for the reports (JSON, CSV, PNG charts); default: bench-out in the current folder.",
)
@click.option("--quick", is_flag=True, help="Smaller sizes and fewer cases (a smoke run).")
@click.option("--list", "list_suites", is_flag=True, help="List the suites and exit.")
@common_options(kernels=True)
@click.pass_context
def bench(ctx, suite, reports, repeats: int, warmup: int, output_dir: Path, quick: bool, list_suites: bool,
          verbose, quiet, debug: bool, device, threads):
    """Run benchmark SUITE (or "all"): per-stage times (median and spread of the repeats), memory, and the error
    against the exact reference; writes JSON, CSV and charts.

    Without SUITE: the reference suite (ray marching at 1920x1080, about 2 minutes on two cores). --list shows
    every suite with what it measures. "bench compare A.json B.json" compares two reports case by case.
    """
    debug = debug or ctx.obj.get("debug", False)
    setup(verbose, quiet)
    if suite == "compare":
        if len(reports) != 2:
            fail("bench compare: give two report files (bench compare A.json B.json)", EXIT_INVALID)
        from warpscatter.bench.compare import compare_reports

        try:
            click.echo(compare_reports(*reports))
        except ValueError as exc:
            fail(str(exc), EXIT_INVALID, debug)
        return
    if reports:
        fail(f"unexpected arguments {' '.join(map(str, reports))} (report files go with: bench compare A B)",
              EXIT_INVALID)
    device = setup(verbose, quiet, device, threads, kernels=True)
    try:
        bench_module = importlib.import_module("warpscatter.bench")
        suites = dict(bench_module.SUITES)
    except Exception as exc:
        fail(error_text(exc), EXIT_FAILURE, debug)
    if list_suites:
        width = max((len(n) for n in suites), default=0)
        for suite_name, suite_record in suites.items():
            click.echo(f"{suite_name:<{width}}  {suite_record.description}")
        return
    if suite is None:
        suite = _default_suite(bench_module.run) or next(iter(suites), None)
        if not quiet:
            click.echo(f"running the default suite {suite!r} ({DEFAULT_SUITE_DURATION}; warpscatter bench --list "
                       f"shows the others)", err=True)
    if suite not in suites and suite != "all":
        fail(f"unknown suite {suite!r} (choose from: {', '.join([*suites, 'all', 'compare'])})", EXIT_INVALID)
    out_dir = resolve_out_dir(output_dir)

    progress = ProgressDisplay(enabled=not quiet, every_stage=verbose > 0)
    try:
        report = bench_module.run(
            suite, repeats=repeats, warmup=warmup, out_dir=out_dir, quick=quick, progress=progress
        )
    except KeyboardInterrupt:
        interrupted(progress)
    except Exception as exc:
        progress.close()
        fail(error_text(exc), EXIT_FAILURE, debug)
    progress.close()
    if not quiet:
        click.echo(report.table())
        click.echo("wrote:")
    for f in list(getattr(report, "files", [])):
        click.echo(f"  {f}" if not quiet else str(f))


__all__ = ["DEFAULT_SUITE", "DEFAULT_SUITE_DURATION", "bench"]
