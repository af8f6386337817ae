"""One writer per output directory: an exclusive lock file beside the output.

Every command that writes an output (directories: ``render``, ``detect``,
``recon``, ``study``, ``demo``, ``fit``; files: ``export``, ``video``,
``mannequin``, ``scene-mesh``) holds :func:`output_lock` on it while it
works (``dataset`` holds its own ``flock`` on ``OUT/.dataset.lock``). The lock is the file ``.<name>.lock`` next to ``<name>`` (beside, not
inside: outputs are swapped into place by renaming a temporary sibling). It
is created with ``O_CREAT | O_EXCL`` and holds one JSON object naming its
owner::

    {"pid": 1234, "host": "node7", "start_ticks": 5512345, "boot_id": "...",
     "started": "2026-12-01T19:20:00Z", "command": "transient-mi render ..."}

A second process asking for the same lock is refused with one line naming the
owner. A lock whose owner is dead is *stale* and taken over: same host (and
boot) and either no process with that pid, or a process with that pid that
started at another time (the pid was reused). A lock written on another host
cannot be checked from here and is never taken over; the message says which
file to remove once that run is known to be gone.

While the lock is held nobody else writes that output, so temporary siblings
left by a killed run (``.<name>.XXXXXXXX.tmp`` / ``.old``, from
:func:`transient_core.atomic.temp_dir_beside` and :func:`transient_core.atomic.replace_dir`)
are removed on acquisition.

The lock is re-entrant within one process (``render`` of a ``spad_film``
scene runs ``detect`` into the same directory).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import socket
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from .errors import UserInputError
from .fault import point as _fault

LOCK_SUFFIX = ".lock"
#: A lock file that cannot be parsed is treated as being written for this long, then as stale.
UNREADABLE_GRACE_S = 10.0

_held: dict[str, int] = {}  # lock path -> nesting depth in this process


def lock_path(out: str | os.PathLike) -> Path:
    """The lock file of output ``out``: ``.<name>.lock`` in the same directory."""
    o = Path(out)
    parent = o.parent if str(o.parent) else Path(".")
    return parent / f".{o.name}{LOCK_SUFFIX}"


def _boot_id() -> str | None:
    try:
        return Path("/proc/sys/kernel/random/boot_id").read_text().strip()
    except OSError:
        return None


def process_start_ticks(pid: int) -> int | None:
    """Start time of process ``pid`` in clock ticks since boot (Linux ``/proc``), or None if unknown."""
    try:
        stat = Path(f"/proc/{int(pid)}/stat").read_text()
    except OSError:
        return None
    # the command name (field 2) is in parentheses and may contain spaces: split after the last ')'
    fields = stat[stat.rfind(")") + 2:].split()
    try:
        return int(fields[19])  # field 22 of stat(5)
    except (IndexError, ValueError):
        return None


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # exists, owned by someone else
    except (OverflowError, ValueError):
        return False
    return True


def owner_record(command: str | None = None) -> dict:
    """The JSON object this process writes into a lock file."""
    pid = os.getpid()
    return {"pid": pid, "host": socket.gethostname(), "start_ticks": process_start_ticks(pid),
            "boot_id": _boot_id(), "started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "command": command if command is not None else " ".join(sys.argv)}


def owner_is_dead(rec: dict) -> bool:
    """True when the lock's owner is certainly gone (same host and boot; pid absent or reused)."""
    if rec.get("host") != socket.gethostname():
        return False
    boot = _boot_id()
    if rec.get("boot_id") and boot and rec["boot_id"] != boot:
        return True  # written before this machine's last reboot
    pid = rec.get("pid")
    if not isinstance(pid, int) or pid <= 0:
        return True
    if not _pid_alive(pid):
        return True
    then, now = rec.get("start_ticks"), process_start_ticks(pid)
    return then is not None and now is not None and then != now


def _read(path: Path) -> dict | None:
    try:
        rec = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return rec if isinstance(rec, dict) else None


def _describe(rec: dict) -> str:
    return (f"pid {rec.get('pid')} on {rec.get('host')}, started {rec.get('started')}"
            + (f": {rec['command']}" if rec.get("command") else ""))


def _create(path: Path, rec: dict) -> bool:
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    except FileExistsError:
        return False
    with os.fdopen(fd, "w") as f:
        f.write(json.dumps(rec) + "\n")
    return True


def _take_over(path: Path, stale_text: str) -> None:
    """Move a stale lock aside, unless it changed since it was judged stale (then put it back)."""
    aside = path.with_name(f"{path.name}.{os.getpid()}.stale")
    try:
        os.rename(path, aside)
    except FileNotFoundError:
        return  # someone else removed it first
    try:
        same = aside.read_text() == stale_text
    except OSError:
        same = False
    if not same:  # another process took it over and wrote its own lock in between: restore that one
        try:
            os.link(aside, path)
        except OSError:
            pass
    aside.unlink(missing_ok=True)


def acquire(out: str | os.PathLike, option: str = "-o", command: str | None = None) -> Path:
    """Take the lock of output ``out`` (see the module docstring); return the lock path.

    Raises
    ------
    transient_core.errors.UserInputError
        When another live process holds it, or the lock cannot be created.
    """
    path = lock_path(out)
    key = str(path.absolute())
    if key in _held:
        _held[key] += 1
        return path
    rec = owner_record(command)
    for _ in range(5):
        try:
            if _create(path, rec):
                _held[key] = 1
                _fault("lock_acquired", out)
                return path
        except OSError as e:
            raise UserInputError(f"{option} {out}: cannot create the lock file {path} ({e.strerror})") from None
        try:
            text = path.read_text()
        except FileNotFoundError:
            continue  # released meanwhile: try again
        except OSError as e:
            raise UserInputError(f"{option} {out}: cannot read the lock file {path} ({e.strerror})") from None
        other = _read(path) if text else None
        if other is None:
            try:
                age = time.time() - path.stat().st_mtime
            except FileNotFoundError:
                continue
            if age < UNREADABLE_GRACE_S:
                raise UserInputError(f"{option} {out}: another run is starting to write this output (lock file "
                                     f"{path} is being written); wait for it or choose another output")
            _take_over(path, text)
            continue
        if owner_is_dead(other):
            _take_over(path, text)
            continue
        where = "" if other.get("host") == socket.gethostname() else \
            f"; it was taken on another host, so remove {path} yourself once that run is gone"
        raise UserInputError(f"{option} {out}: another run is writing this output ({_describe(other)}){where}")
    raise UserInputError(f"{option} {out}: could not take the lock file {path} (it keeps changing)")


def release(out: str | os.PathLike) -> None:
    """Release a lock taken with :func:`acquire` (the file is removed when the outermost holder releases)."""
    path = lock_path(out)
    key = str(path.absolute())
    depth = _held.get(key, 0)
    if depth > 1:
        _held[key] = depth - 1
        return
    _held.pop(key, None)
    rec = _read(path)
    if rec is not None and rec.get("pid") == os.getpid() and rec.get("host") == socket.gethostname():
        path.unlink(missing_ok=True)


def remove_stale_temporaries(out: str | os.PathLike) -> list[Path]:
    """Remove ``.<name>.XXXXXXXX.tmp`` / ``.old`` siblings of ``out`` (call only while holding its lock).

    They are the temporary and moved-aside directories (or files) of
    :mod:`transient_core.atomic` that a killed run of the same output left behind. When ``out`` itself is
    missing and a moved-aside ``.old`` holds it (a run killed inside :func:`~transient_core.atomic.replace_dir`),
    the old output is first put back: nothing is lost. Returns the removed paths.
    """
    o = Path(out)
    parent = o.parent if str(o.parent) else Path(".")
    # (a file's temporary may keep its suffix after .tmp, e.g. a video's .x.gif.XXXXXXXX.tmp.gif)
    pattern = re.compile(rf"^\.{re.escape(o.name)}\.[A-Za-z0-9_]{{8}}\.(tmp|old)(\.[A-Za-z0-9]{{1,8}})?$")
    removed = []
    try:
        entries = list(parent.iterdir())
    except OSError:
        return removed
    if not os.path.lexists(o):  # killed inside replace_dir after moving the old output aside: put it back
        for p in entries:
            if pattern.match(p.name) and p.name.endswith(".old") and (p / o.name).exists():  # (a directory)
                try:
                    os.rename(p / o.name, o)
                except OSError:
                    pass
                break
    for p in entries:
        if not pattern.match(p.name):
            continue
        try:
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p)
            else:
                p.unlink()
            removed.append(p)
        except OSError:
            pass
    return removed


@contextmanager
def output_lock(out: str | os.PathLike, option: str = "-o", command: str | None = None) -> Iterator[Path]:
    """Hold the exclusive lock of output ``out`` for the block (see the module docstring).

    Missing parent directories are created for the lock file; the ones created
    here are removed again on exit if they are still empty (a refused or failed
    run leaves nothing behind). Stale temporaries of ``out`` are removed once
    the lock is held.
    """
    o = Path(out)
    parent = (o.parent if str(o.parent) else Path(".")).absolute()
    created: list[Path] = []
    p = parent
    while not p.exists() and p.parent != p:
        created.append(p)
        p = p.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        _remove_empty(created)
        raise UserInputError(f"{option} {out}: cannot create the directory {parent} ({e.strerror})") from None
    try:
        acquire(o, option, command)
    except BaseException:
        _remove_empty(created)
        raise
    try:
        if _held.get(str(lock_path(o).absolute())) == 1:
            remove_stale_temporaries(o)
        yield lock_path(o)
    finally:
        release(o)
        _remove_empty(created)


def _remove_empty(dirs: list[Path]) -> None:
    for d in dirs:  # deepest first
        try:
            d.rmdir()
        except OSError:
            break
