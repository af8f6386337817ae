"""Deterministic fault injection for the reliability tests (docs/reliability.md).

The atomic-write helpers (:mod:`transient_core.atomic`), the output lock
(:mod:`transient_core.lock`) and the few places that move finished files into
place call :func:`point` at named moments. Normally that is a dictionary lookup
and nothing else. When the environment variable ``TRANSIENT_MI_FAULT`` is set
to ``POINT[@NAME]:N`` the process kills itself (``SIGKILL``, as ``kill -9``
would; no clean-up, no ``finally`` blocks) the ``N``-th time it reaches
``POINT`` (for a file whose name matches ``NAME``, a shell-style pattern, when given; a pattern with
``/`` is matched against as many trailing path components, e.g. ``variance/spot_*.exr``)::

    TRANSIENT_MI_FAULT=after_rename@spot_*.exr:1   # right after the first spot file is in place
    TRANSIENT_MI_FAULT=before_rename:3             # a temporary written, not yet renamed (3rd file)
    TRANSIENT_MI_FAULT=before_rename@manifest.json:2

Points:

``before_rename``
    a temporary file or directory is complete and about to be renamed onto its final name;
``after_rename``
    it has just been renamed (the file exists under its final name);
``replace_dir``
    :func:`transient_core.atomic.replace_dir` has moved the old output aside and not yet put
    the new one in place;
``lock_acquired``
    the output lock has just been taken.

Several faults may be given, separated by commas; the first whose count is reached fires.
"""

from __future__ import annotations

import fnmatch
import os
import signal

ENV = "TRANSIENT_MI_FAULT"
POINTS = ("before_rename", "after_rename", "replace_dir", "lock_acquired")

_counts: dict[tuple[str, str | None, int], int] = {}


def _parse(spec: str) -> list[tuple[str, str | None, int]]:
    out = []
    for item in filter(None, (s.strip() for s in spec.split(","))):
        where, _, n = item.rpartition(":")
        name, _, pattern = where.partition("@")
        if name not in POINTS or not n.isdigit() or int(n) < 1:
            raise ValueError(f"{ENV}={spec!r}: expected POINT[@NAME]:N with POINT one of {', '.join(POINTS)} "
                             "and N >= 1")
        out.append((name, pattern or None, int(n)))
    return out


def point(name: str, path: str | os.PathLike | None = None) -> None:
    """Reach fault point ``name`` (for the file ``path``); kill this process if ``TRANSIENT_MI_FAULT`` says so."""
    spec = os.environ.get(ENV)
    if not spec:
        return
    parts = os.path.normpath(os.fspath(path)).split(os.sep) if path is not None else [""]
    for key in _parse(spec):
        p, pattern, n = key
        if p != name:
            continue
        if pattern is not None and not fnmatch.fnmatchcase("/".join(parts[-(pattern.count("/") + 1):]), pattern):
            continue
        _counts[key] = _counts.get(key, 0) + 1
        if _counts[key] == n:
            os.kill(os.getpid(), signal.SIGKILL)
