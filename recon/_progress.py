"""Progress bars (rich) shared by transient_mi and recon.

Bars are drawn on stderr when it is a terminal and are silent otherwise (CI
logs, pipes), unless ``TRANSIENT_MI_PROGRESS=1`` forces them on or ``=0``
off.
"""

from __future__ import annotations

import os
import sys
from contextlib import contextmanager
from typing import Iterable, Iterator, TypeVar

T = TypeVar("T")


def _enabled(disable: bool | None) -> bool:
    if disable is not None:
        return not disable
    env = os.environ.get("TRANSIENT_MI_PROGRESS")
    if env is not None:
        return env not in ("0", "", "false", "no")
    return sys.stderr.isatty()


@contextmanager
def progress_bar(description: str, total: float | None, disable: bool | None = None):
    """Context manager yielding ``advance(n=1)``; draws a rich progress bar."""
    if not _enabled(disable):
        yield lambda n=1: None
        return
    from rich.console import Console
    from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn,
                               TimeElapsedColumn, TimeRemainingColumn)

    cols = [TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
            TimeElapsedColumn(), TextColumn("eta"), TimeRemainingColumn()]
    with Progress(*cols, console=Console(stderr=True), transient=False) as prog:
        task = prog.add_task(description, total=total)
        yield lambda n=1: prog.advance(task, n)


def track(iterable: Iterable[T], description: str, total: int | None = None,
          disable: bool | None = None) -> Iterator[T]:
    """Iterate with a progress bar."""
    if total is None and hasattr(iterable, "__len__"):
        total = len(iterable)  # type: ignore[arg-type]
    with progress_bar(description, total, disable) as advance:
        for item in iterable:
            yield item
            advance(1)
