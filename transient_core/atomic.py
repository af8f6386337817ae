"""Helpers for writing files and directories atomically (temporary name, then rename).

``tempfile.mkstemp``/``mkdtemp`` create 0600 files and 0700 directories; once
renamed into place, outputs should have the permissions an ordinary
``open``/``mkdir`` would give (0666/0777 minus the umask).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from .fault import point as _fault


def umask() -> int:
    """The process umask (read without changing it for longer than a call)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def file_mode() -> int:
    """Mode of a normally created file: 0o666 minus the umask."""
    return 0o666 & ~umask()


def dir_mode() -> int:
    """Mode of a normally created directory: 0o777 minus the umask."""
    return 0o777 & ~umask()


def temp_dir_beside(target: str | os.PathLike, suffix: str = ".tmp") -> Path:
    """A new hidden directory next to ``target`` (same filesystem, so it can be renamed onto it),
    with ordinary directory permissions."""
    t = Path(target)
    parent = t.parent if str(t.parent) else Path(".")
    d = Path(tempfile.mkdtemp(dir=parent, prefix=f".{t.name}.", suffix=suffix))
    os.chmod(d, dir_mode())
    return d


def temp_file_beside(target: str | os.PathLike, suffix: str = ".tmp") -> Path:
    """A new hidden empty file next to ``target`` with ordinary file permissions (closed)."""
    t = Path(target)
    parent = t.parent if str(t.parent) else Path(".")
    fd, tmp = tempfile.mkstemp(dir=parent, prefix=f".{t.name}.", suffix=suffix)
    os.close(fd)
    os.chmod(tmp, file_mode())
    return Path(tmp)


@contextmanager
def atomic_file(target: str | os.PathLike, suffix: str = ".tmp", fsync: bool = False) -> Iterator[Path]:
    """Yield a temporary file beside ``target`` to write; when the block succeeds it is renamed onto
    ``target`` (after ``fsync`` when asked), and when anything fails it is removed.

    A reader therefore sees the old file or the complete new one, never a partial one.
    """
    tmp = temp_file_beside(target, suffix)
    try:
        yield tmp
        if fsync:
            with open(tmp, "rb") as f:
                os.fsync(f.fileno())
        _fault("before_rename", target)
        os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _fault("after_rename", target)


def rename_into_place(tmp: str | os.PathLike, target: str | os.PathLike) -> None:
    """``os.replace(tmp, target)`` for a finished temporary, with the fault points of :mod:`transient_core.fault`."""
    _fault("before_rename", target)
    os.replace(tmp, target)
    _fault("after_rename", target)


def replace_dir(tmp: str | os.PathLike, out: str | os.PathLike) -> None:
    """Rename the finished directory ``tmp`` to ``out`` (same filesystem).

    An existing ``out`` is first moved into a hidden directory beside it, then
    removed once ``tmp`` is in place, so ``out`` is always either the old
    result or the new one, never a mixture.
    """
    tmp, out = Path(tmp), Path(out)
    _fault("before_rename", out)
    if not out.exists():
        os.replace(tmp, out)
        _fault("after_rename", out)
        return
    parent = out.parent if str(out.parent) else Path(".")
    trash = Path(tempfile.mkdtemp(dir=parent, prefix=f".{out.name}.", suffix=".old"))
    os.replace(out, trash / out.name)
    _fault("replace_dir", out)
    os.replace(tmp, out)
    _fault("after_rename", out)
    shutil.rmtree(trash, ignore_errors=True)


def check_output_location(out: str | os.PathLike, option: str = "-o") -> Path:
    """Check that ``out`` can be created, without creating anything; return its parent.

    Missing parent directories are fine (they are created when the output is
    written) as long as the nearest existing ancestor is a directory in which
    this process can create entries (probed for real: permission bits say
    little for root or read-only mounts).

    Raises
    ------
    transient_core.errors.UserInputError
        Naming the option, the path and the problem.
    """
    from .errors import UserInputError

    o = Path(out)
    parent = o.parent if str(o.parent) else Path(".")
    anc = parent
    while not anc.exists():
        if anc.parent == anc:
            break
        anc = anc.parent
    if not anc.is_dir():
        raise UserInputError(f"{option} {o}: {anc} is not a directory")
    try:
        os.rmdir(tempfile.mkdtemp(dir=anc, prefix=".transient-mi-probe-"))
    except OSError as e:
        raise UserInputError(f"{option} {o}: cannot create a directory in {anc} ({e.strerror})") from None
    return parent
