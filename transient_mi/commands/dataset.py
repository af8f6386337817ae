"""``transient-mi dataset``: render a spec's items in parallel on Dask."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ._options import whole_number


def dataset(
    spec: Path = typer.Argument(..., help="Dataset spec, YAML or JSON (see docs/dataset.md)."),
    out: Path = typer.Option(..., "-o", "--out", help="Dataset directory (created; rerun to resume)."),
    scheduler: Optional[str] = typer.Option(None, "--scheduler",
                                            help="Address of a running Dask scheduler, e.g. tcp://127.0.0.1:8786 "
                                                 "(default: a local cluster)."),
    workers: Optional[int] = typer.Option(None, "--workers", parser=whole_number("--workers"), metavar="<int>",
                                          help="Worker processes of the local cluster (default: one per core up "
                                               "to 4 cores, about sqrt(cores) above)."),
    threads_per_worker: Optional[int] = typer.Option(None, "--threads-per-worker", parser=whole_number("--threads-per-worker"), metavar="<int>",
                                                     help="drjit threads in each worker process (default: cores / "
                                                          "worker processes on each host)."),
    dry_run: bool = typer.Option(False, "--dry-run", help="Validate the spec and scene, list the plan, write nothing."),
) -> None:
    """Build every item of SPEC into OUT: items/item_NNNNNN/ (capture, mesh, params.json) and index.csv.

    Idempotent: finished items are skipped, interrupted ones are redone.
    """
    from transient_mi.dataset.runner import DatasetError, run_dataset

    try:
        report = run_dataset(spec, out, scheduler=scheduler, workers=workers, threads_per_worker=threads_per_worker,
                             dry_run=dry_run, echo=lambda m: typer.echo(m, err=True))
    except DatasetError as e:
        typer.echo(f"error: {e}", err=True)
        raise typer.Exit(1)
    if dry_run:
        _print_plan(report)
    typer.echo(report.summary())


def _print_plan(report) -> None:
    items = report.items
    varied = items[0].record["varied"] if items else []
    typer.echo(f"{len(items)} items; varied: {', '.join(varied) or 'nothing (repeats only)'}")
    for it in items[:10]:
        p = it.record["parameters"]
        vals = ", ".join(f"{k}={p[k]!r}" for k in varied)
        typer.echo(f"  {it.name}: render_seed={it.record['render_seed']}" + (f", {vals}" if vals else ""))
    if len(items) > 10:
        typer.echo(f"  ... ({len(items) - 10} more)")


def register(app: typer.Typer) -> None:
    app.command("dataset")(dataset)
