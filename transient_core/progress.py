"""Progress reports shared by transient_mi and recon.

Three modes, chosen per report:

* ``bar``: a rich progress bar on stderr, when stderr is a terminal (or
  ``TRANSIENT_MI_PROGRESS=1`` forces it);
* ``lines``: when stderr is not a terminal (CI logs, pipes, ``nohup``), one
  plain line every :data:`LINE_INTERVAL_S` seconds (``TRANSIENT_MI_PROGRESS_INTERVAL_S``
  overrides it) with the fraction done, the elapsed time and an ETA, and a
  last line when the work ends if any line was printed; work shorter than the
  interval prints nothing;
* ``off``: ``TRANSIENT_MI_PROGRESS=0``, or a caller that disables it.
"""

from __future__ import annotations

import os
import sys
import time
from contextlib import contextmanager
from typing import Iterable, Iterator, TypeVar

T = TypeVar("T")

#: Seconds between two progress lines when stderr is not a terminal.
LINE_INTERVAL_S = 30.0


def progress_mode(disable: bool | None) -> str:
    """``"bar"``, ``"lines"`` or ``"off"`` (see the module docstring); ``disable=False`` forces the bar."""
    if disable is not None:
        return "off" if disable else "bar"
    env = os.environ.get("TRANSIENT_MI_PROGRESS")
    if env is not None:
        return "off" if env in ("0", "", "false", "no") else "bar"
    return "bar" if sys.stderr.isatty() else "lines"


def _enabled(disable: bool | None) -> bool:
    """Whether a progress bar is drawn (the ``bar`` mode)."""
    return progress_mode(disable) == "bar"


def _interval() -> float:
    try:
        return max(0.0, float(os.environ.get("TRANSIENT_MI_PROGRESS_INTERVAL_S", LINE_INTERVAL_S)))
    except ValueError:
        return LINE_INTERVAL_S


def _duration(s: float) -> str:
    s = int(round(s))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


class LineProgress:
    """Periodic plain progress lines: ``description: 40 % (400/1000), elapsed 0:00:30, eta 0:00:45``."""

    def __init__(self, description: str, total: float | None, interval_s: float | None = None, stream=None,
                 clock=time.monotonic):
        self.description, self.total = description, total
        self.interval_s = _interval() if interval_s is None else interval_s
        self.stream = stream if stream is not None else sys.stderr
        self.clock = clock
        self.t0 = self.last = clock()
        self.done = 0.0
        self.printed = 0

    def line(self) -> str:
        elapsed = self.clock() - self.t0
        if self.total:
            frac = min(1.0, self.done / self.total)
            eta = _duration(elapsed * (1 - frac) / frac) if frac > 0 else "unknown"
            return (f"{self.description}: {100 * frac:.0f} % ({self.done:g}/{self.total:g}), "
                    f"elapsed {_duration(elapsed)}, eta {eta}")
        return f"{self.description}: {self.done:g} done, elapsed {_duration(elapsed)}"

    def _emit(self) -> None:
        print(self.line(), file=self.stream, flush=True)
        self.printed += 1

    def advance(self, n: float = 1) -> None:
        self.done += n
        now = self.clock()
        if now - self.last >= self.interval_s:
            self.last = now
            self._emit()

    def finish(self) -> None:
        if self.printed:
            self._emit()


@contextmanager
def progress_bar(description: str, total: float | None, disable: bool | None = None, mode: str | None = None):
    """Context manager yielding ``advance(n=1)``; reports progress in the mode of :func:`progress_mode`
    (``mode`` overrides it)."""
    mode = mode or progress_mode(disable)
    if mode == "off":
        yield lambda n=1: None
        return
    if mode == "lines":
        lines = LineProgress(description, total)
        yield lines.advance
        lines.finish()
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
    """Iterate with a progress report."""
    if total is None and hasattr(iterable, "__len__"):
        total = len(iterable)  # type: ignore[arg-type]
    with progress_bar(description, total, disable) as advance:
        for item in iterable:
            yield item
            advance(1)
