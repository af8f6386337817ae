"""The JSON record every benchmark writes: ``bench/results/<name>.json``.

A record holds the benchmark's own result plus what is needed to judge it:

* ``date_utc``: when the run finished (ISO 8601, UTC);
* ``command``: the exact command line (``python bench/<script>.py ...``);
* ``machine``: CPU model, logical cores, memory (GiB), platform, Python, the
  1-minute load average at the start and at the end of the run;
* ``versions``: transient-mi, mitsuba, drjit, numpy, scipy, numba and the
  peers' versions where a peer ran (installed-distribution metadata; nothing
  is imported to read them);
* ``note``: free text (e.g. "machine shared with 3 other engineers").

The file is written atomically (``transient_core.atomic.atomic_file``): a reader sees
the old record or the new one, never half of one. Peak memory in every
benchmark is ``VmHWM`` from ``/proc/self/status`` (the process's own peak
resident set since it started or since :func:`reset_peak_rss`; unlike
``ru_maxrss`` it does not carry a parent's peak over fork + exec).
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import platform
import shlex
import sys
from importlib import metadata
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _rss import peak_rss_mb, reset_peak_rss, rss_mb  # noqa: E402,F401  (the one copy, re-exported)

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results"
#: Distributions whose versions every record carries (missing ones are recorded as ``None``).
PACKAGES = ("transient-mi", "mitsuba", "drjit", "numpy", "scipy", "numba")


def cpu_model() -> str:
    """The CPU's model name from ``/proc/cpuinfo`` (``platform.processor()`` as a fallback)."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def memory_gib() -> float | None:
    """Total memory of the machine in GiB (``MemTotal``)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemTotal:"):
                    return round(int(line.split()[1]) / 2 ** 20, 1)
    except OSError:
        pass
    return None


def machine(load_start: list[float] | None = None) -> dict:
    """Description of this machine; ``load_start`` is :func:`os.getloadavg` taken when the run began."""
    return {"cpu_model": cpu_model(), "cores": os.cpu_count(), "memory_gib": memory_gib(),
            "platform": platform.platform(), "python": platform.python_version(),
            "load_average_1min_start": None if load_start is None else round(load_start[0], 2),
            "load_average_1min_end": round(os.getloadavg()[0], 2)}


def versions(peers: dict | None = None) -> dict:
    """Installed versions of :data:`PACKAGES`, plus ``peers`` (name -> version string or None)."""
    out = {}
    for name in PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    out.update(peers or {})
    return out


def command_line(argv: list[str] | None = None) -> str:
    """The command that ran this benchmark, as it would be typed from the repository root."""
    argv = sys.argv if argv is None else argv
    script = Path(argv[0]).resolve()
    try:
        script = script.relative_to(ROOT)
    except ValueError:
        pass
    return shlex.join(["python", str(script), *argv[1:]])


def record(name: str, result: dict, *, load_start: list[float] | None = None, note: str | None = None,
           peers: dict | None = None, argv: list[str] | None = None) -> dict:
    """The full record of one run (not written; see :func:`save`)."""
    return {"name": name,
            "date_utc": _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat(),
            "command": command_line(argv), "machine": machine(load_start), "versions": versions(peers),
            "note": note or "", "result": result}


def save(rec: dict, path: str | os.PathLike | None = None) -> Path:
    """Write ``rec`` atomically to ``path`` (default ``bench/results/<name>.json``); returns the path."""
    sys.path.insert(0, str(ROOT))
    from transient_core.atomic import atomic_file

    target = Path(path) if path is not None else RESULTS / f"{rec['name']}.json"
    target.parent.mkdir(parents=True, exist_ok=True)
    with atomic_file(target) as tmp:
        tmp.write_text(json.dumps(rec, indent=1) + "\n")
    return target


def load(name: str) -> dict:
    """The record ``bench/results/<name>.json``."""
    return json.loads((RESULTS / f"{name}.json").read_text())


def add_arguments(ap) -> None:
    """``--save`` / ``--save-as`` / ``--note``: the options every benchmark script shares."""
    ap.add_argument("--save", action="store_true",
                    help="also write the record to bench/results/<name>.json (machine, date, command, versions)")
    ap.add_argument("--save-as", type=Path, default=None, metavar="FILE",
                    help="write the record to FILE instead of bench/results/<name>.json")
    ap.add_argument("--note", default="", help="free-text note stored in the record (e.g. 'machine shared')")


def maybe_save(args, name: str, result: dict, *, load_start, peers: dict | None = None) -> Path | None:
    """Write the record if ``--save`` or ``--save-as`` was given; prints where to stderr."""
    if not (args.save or args.save_as):
        return None
    if args.save_as:  # a record's name is its file's stem (tests/test_quoted_numbers.py)
        name = Path(args.save_as).stem
    path = save(record(name, result, load_start=load_start, note=args.note, peers=peers), args.save_as)
    print(f"[bench] wrote {path}", file=sys.stderr)
    return path


def run_measured(argv: list[str], *, cwd=None, env=None, log=None) -> dict:
    """Run ``python -m MODULE ARGS`` (``argv = [MODULE, *ARGS]``) in a fresh process; wall time and VmHWM.

    The child is this file run as a script: it registers an exit hook that
    writes its own ``VmHWM`` (the peak resident set of that process alone,
    not inherited over fork + exec) and then runs the module as ``__main__``.
    Returns ``{"returncode", "wall_s", "peak_rss_mb"}`` (``peak_rss_mb`` is
    None if the child died before its exit hook ran). ``log``: a path for the
    child's stdout and stderr.
    """
    import subprocess
    import tempfile
    import time

    with tempfile.TemporaryDirectory(prefix="bench-peak-") as td:
        peak_file = Path(td) / "peak.json"
        cmd = [sys.executable, str(Path(__file__).resolve()), str(peak_file), *argv]
        out = open(log, "w") if log else subprocess.DEVNULL
        try:
            t0 = time.perf_counter()
            rc = subprocess.run(cmd, cwd=cwd, env=env, stdout=out, stderr=subprocess.STDOUT).returncode
            wall = time.perf_counter() - t0
        finally:
            if log:
                out.close()
        peak = json.loads(peak_file.read_text())["peak_rss_mb"] if peak_file.exists() else None
    return {"returncode": rc, "wall_s": wall, "peak_rss_mb": peak}


def _child_main(argv: list[str]) -> None:
    """``python _record.py PEAK.json MODULE ARGS...``: run MODULE as __main__, write VmHWM at exit."""
    import atexit
    import runpy

    peak_file, module, *args = argv

    def _write():
        Path(peak_file).write_text(json.dumps({"peak_rss_mb": peak_rss_mb()}))

    atexit.register(_write)
    sys.argv = [module, *args]
    sys.path[0] = os.getcwd()  # as ``python -m`` would have it (not this script's folder)
    runpy.run_module(module, run_name="__main__", alter_sys=True)


if __name__ == "__main__":
    _child_main(sys.argv[1:])


#: Keys of a script's own JSON that describe provenance rather than results (moved out of ``result``).
_PROVENANCE_KEYS = ("name", "benchmark", "command", "date", "date_utc", "machine", "versions", "note")


def as_record(name: str, doc: dict, *, note: str = "") -> dict:
    """``doc`` (a benchmark script's own JSON) in the record layout of :func:`record`.

    Its ``command``, ``date``/``date_utc``, ``machine`` and ``note`` are kept (the machine fields completed
    with :func:`machine`'s ``cpu_model``, ``cores`` and ``memory_gib`` where missing); every other key goes
    under ``result``.
    """
    m = dict(machine())
    m.update({k: v for k, v in (doc.get("machine") or {}).items() if v is not None})
    m.setdefault("cpu_model", cpu_model())
    if not m.get("cores"):
        m["cores"] = os.cpu_count()
    date = doc.get("date_utc") or doc.get("date") or \
        _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat()
    vers = versions()
    vers.update({k: v for k, v in (doc.get("versions") or {}).items() if v})
    return {"name": name, "date_utc": date, "command": doc.get("command") or command_line(),
            "machine": m, "versions": vers, "note": note or doc.get("note") or "",
            "result": {k: v for k, v in doc.items() if k not in _PROVENANCE_KEYS}}


def payload(doc: dict) -> dict:
    """The results of a record (or of an older script's JSON, which has them at the top level)."""
    return doc["result"] if isinstance(doc.get("result"), dict) and "date_utc" in doc else doc
