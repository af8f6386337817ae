"""Helpers of the reliability suites (docs/reliability.md): run the ``transient-mi`` command in this process
(fast: Mitsuba is imported once) or in a child process killed at a named fault point (``TRANSIENT_MI_FAULT``,
:mod:`transient_core.fault`), and compare outputs file by file and manifest fact by fact."""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import signal
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: Manifest / JSON keys that may differ between an interrupted-and-resumed run and an uninterrupted one.
VOLATILE = re.compile(r"(_time_s|_s_wall|^time_s$|^elapsed.*|^command$|^started$|^finished$|^created$|^timings?(_s)?$|"
                      r"^wall_s$|^seconds$|^host$|^pid$|^worker$|^hostname$|^date$|^timestamp$|_utc$|"
                      r"manifest\.json$)")  # (a dataset item's file sizes: the manifest's size follows its command line)


@dataclass
class Result:
    code: int
    out: str
    err: str


def run_cli(*args) -> Result:
    """``transient-mi ARGS`` in this process (the console script's front door), its exit status and output."""
    from transient_cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main([str(a) for a in args])
        except SystemExit as e:
            code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
        except Exception:  # what the console script would show as a traceback, exit status 1
            import traceback

            traceback.print_exc(file=err)
            code = 1
    return Result(int(code or 0), out.getvalue(), err.getvalue())


def killed_cli(*args, fault: str, timeout: float = 600) -> subprocess.CompletedProcess:
    """``transient-mi ARGS`` in a child process that kills itself (SIGKILL) at ``fault`` (``POINT[@NAME]:N``)."""
    env = dict(os.environ, TRANSIENT_MI_PROGRESS="0", TRANSIENT_MI_FAULT=fault)
    r = subprocess.run([sys.executable, "-m", "transient_mi", *map(str, args)], cwd=ROOT, env=env,
                       capture_output=True, text=True, timeout=timeout)
    assert r.returncode == -signal.SIGKILL, (f"expected the run to be killed at {fault}", r.returncode, r.stderr)
    return r


def killed_python(code: str, *args, fault: str, timeout: float = 600) -> subprocess.CompletedProcess:
    """``python -c CODE ARGS`` killed at ``fault`` (for library entry points the command line does not reach)."""
    env = dict(os.environ, TRANSIENT_MI_PROGRESS="0", TRANSIENT_MI_FAULT=fault)
    r = subprocess.run([sys.executable, "-c", code, *map(str, args)], cwd=ROOT, env=env, capture_output=True,
                       text=True, timeout=timeout)
    assert r.returncode == -signal.SIGKILL, (f"expected the run to be killed at {fault}", r.returncode, r.stderr)
    return r


def strip_volatile(obj):
    """``obj`` without the keys of :data:`VOLATILE` (at any depth)."""
    if isinstance(obj, dict):
        return {k: strip_volatile(v) for k, v in obj.items() if not VOLATILE.search(k)}
    if isinstance(obj, list):
        return [strip_volatile(v) for v in obj]
    return obj


def tree(d: Path) -> dict[str, bytes]:
    """Every file under ``d`` (relative path -> bytes), hidden ones included."""
    return {str(p.relative_to(d)): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


def _json_facts(name: str, data: bytes):
    if name.endswith(".jsonl"):
        return [strip_volatile(json.loads(line)) for line in data.decode().splitlines() if line.strip()]
    return strip_volatile(json.loads(data))


def assert_same_output(a: Path, b: Path, *, text_skip=(), csv_volatile=()) -> int:
    """Outputs ``a`` and ``b`` hold the same files; data files byte for byte, JSON files fact for fact (except
    :data:`VOLATILE`), files in ``text_skip`` only by name; CSV columns in ``csv_volatile`` are ignored.
    Returns the number of files compared."""
    ta, tb = tree(a), tree(b)
    assert sorted(ta) == sorted(tb), (sorted(set(ta) ^ set(tb)))
    for name in ta:
        if any(re.fullmatch(pat, name) for pat in text_skip):
            continue
        if name.endswith((".json", ".jsonl")):
            assert _json_facts(name, ta[name]) == _json_facts(name, tb[name]), name
        elif name.endswith(".csv") and csv_volatile:
            assert _csv_facts(ta[name], csv_volatile) == _csv_facts(tb[name], csv_volatile), name
        else:
            assert ta[name] == tb[name], f"{name} differs"
    return len(ta)


def _csv_facts(data: bytes, volatile):
    import csv

    rows = list(csv.DictReader(io.StringIO(data.decode())))
    return [{k: v for k, v in r.items() if k not in volatile and not VOLATILE.search(k)} for r in rows]


def assert_no_leftovers(parent: Path, allow=()) -> None:
    """No temporary, lock, moved-aside or partial file anywhere under ``parent`` (hidden names are ours), but
    the names in ``allow``."""
    left = [str(p.relative_to(parent)) for p in parent.rglob(".*") if p.name not in allow]
    assert left == [], left
