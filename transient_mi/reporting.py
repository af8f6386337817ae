"""Output helpers shared by ``transient-mi demo`` and the studies.

=============================  ==============================================
:func:`check_output_dir`       refuse an unusable ``-o`` before any work
:func:`atomic_output_dir`      build a result directory under a temporary
                               sibling name, rename it into place at the end
:func:`subplots`               a figure and its axes, without pyplot
:func:`save_figure`            write a figure atomically (temporary name, rename)
:func:`write_csv`              rows (dicts) as CSV
:func:`write_json`             an object as indented JSON
:func:`markdown_table`         rows as a Markdown table
:data:`METRIC_KEYS`            the reconstruction metrics reported per row
=============================  ==============================================
"""

from __future__ import annotations

import csv
import json
import math
import shutil
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterable, Iterator, Sequence

from transient_core.atomic import atomic_file, check_output_location, replace_dir, temp_dir_beside
from transient_core._json import to_json
from transient_core.lock import output_lock
from transient_core.errors import UserInputError

#: Metrics of :func:`recon.metrics.compute_metrics` reported in the demo and study tables.
METRIC_KEYS = ("chamfer_m", "accuracy_m", "completeness_m", "depth_mae_m", "depth_coverage", "iou")


def check_output_dir(out, overwrite: bool = False, option: str = "-o") -> Path:
    """Check that ``out`` can become a result directory; create nothing.

    Raises
    ------
    UserInputError
        ``out`` is a file, a non-empty directory (without ``overwrite``), or
        lies below a file or an unwritable directory.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise UserInputError(f"{option} {out}: exists and is not a directory")
    if out.is_dir() and any(out.iterdir()) and not overwrite:
        raise UserInputError(f"{option} {out}: directory exists and is not empty (pass --overwrite to replace it)")
    check_output_location(out, option)
    return out


@contextmanager
def atomic_output_dir(out, overwrite: bool = False, option: str = "-o") -> Iterator[Path]:
    """Yield a temporary sibling of ``out`` to fill; rename it to ``out`` when the block succeeds.

    Missing parent directories are created; if the block raises, the
    temporary directory and any parent directories created here are removed,
    so a failed run leaves nothing behind. With ``overwrite`` an existing
    ``out`` is replaced (only once the new result is complete).
    """
    out = check_output_dir(out, overwrite, option)
    with output_lock(out, option):
        check_output_dir(out, overwrite, option)  # again under the lock: another run may have written it
        with _atomic_output_dir_locked(out, option) as tmp:
            yield tmp


@contextmanager
def _atomic_output_dir_locked(out: Path, option: str) -> Iterator[Path]:
    parent = out.parent if str(out.parent) else Path(".")
    created: list[Path] = []
    p = parent.absolute()
    while not p.exists():
        created.append(p)
        p = p.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        tmp = temp_dir_beside(out)
    except OSError as e:
        _remove_empty(created)
        raise UserInputError(f"{option} {out}: cannot create a directory in {parent} ({e.strerror})") from None
    try:
        yield tmp
        replace_dir(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        _remove_empty(created)
        raise


def _remove_empty(dirs: list[Path]) -> None:
    for d in dirs:  # deepest first
        try:
            d.rmdir()
        except OSError:
            break


def subplots(nrows: int = 1, ncols: int = 1, *, figsize=None, **kwargs):
    """``(figure, axes)`` like ``pyplot.subplots``, built without pyplot.

    Saving needs no backend, and the session's backend is left alone: selecting
    Agg from library code would switch a Jupyter session away from its inline
    backend, after which ``plt.show()`` draws nothing.
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize)
    return fig, fig.subplots(nrows, ncols, **kwargs)


def save_figure(fig, path, dpi: int = 80) -> Path:
    """Save ``fig`` to ``path`` (PNG) under a temporary name, then rename it."""
    path = Path(path)
    with atomic_file(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=dpi)
    return path


def _plain(v):
    """JSON/CSV-friendly scalar: numpy scalars to Python, NaN to None."""
    if hasattr(v, "item") and not isinstance(v, (list, dict, str)):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def write_csv(path, rows: Sequence[dict], fieldnames: Sequence[str] | None = None) -> Path:
    """Write ``rows`` (dicts with the same keys) as CSV; ``None``/NaN become empty cells."""
    path = Path(path)
    fields = list(fieldnames) if fieldnames is not None else (list(rows[0]) if rows else [])
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: _plain(r.get(k)) for k in fields})
    return path


def write_json(path, obj) -> Path:
    """Write ``obj`` as indented JSON (numpy scalars converted, NaN as null)."""
    path = Path(path)
    path.write_text(json.dumps(to_json(obj), indent=1, allow_nan=False) + "\n")
    return path


def markdown_table(headers: Sequence[str], rows: Iterable[Sequence], formats: Sequence[Callable] | None = None) -> str:
    """A Markdown table; ``formats[i](value)`` formats column ``i`` (default ``str``; ``None`` prints n/a)."""
    lines = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
    for r in rows:
        cells = []
        for i, v in enumerate(r):
            if v is None or (isinstance(v, float) and not math.isfinite(v)):
                cells.append("n/a")
            elif formats is not None and formats[i] is not None:
                cells.append(formats[i](v))
            else:
                cells.append(str(v))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
