"""Loading Mitsuba XML scenes with ``-D name=value`` parameters and readable errors."""

from __future__ import annotations

import hashlib
import re
from contextlib import contextmanager
from pathlib import Path

import mitsuba as mi

from transient_core.errors import UserInputError

_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def parse_defines(items: list[str] | None) -> dict[str, str]:
    """Parse ``["name=value", ...]`` into a dict (Mitsuba's ``$name`` substitution).

    Raises
    ------
    UserInputError
        For an item without ``=``, an empty or non-identifier name, or a
        name given twice.
    """
    out: dict[str, str] = {}
    for item in items or []:
        if "=" not in item:
            raise UserInputError(f"-D {item!r}: expected name=value (e.g. -D spp=64)")
        name, value = item.split("=", 1)
        name = name.strip()
        if not _NAME.match(name):
            raise UserInputError(f"-D {item!r}: {name!r} is not a valid parameter name (letters, digits, _)")
        if name in out:
            raise UserInputError(f"-D {name}= given twice ({out[name]!r} and {value!r})")
        out[name] = value
    return out


def mitsuba_error_message(err: BaseException) -> str:
    """Condense a Mitsuba loader error (which may wrap a Python traceback) to one line."""
    text = str(err)
    for line in reversed(text.splitlines()):
        m = re.search(r"(?:PluginParameterError|UserInputError|StackError): (.*)$", line)
        if m:
            return m.group(1).strip()
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    lines = [ln for ln in lines if not ln.startswith(("Traceback", "File \""))]
    lines = [re.sub(r"^\[[\w.]+:\d+\]\s*", "", ln) for ln in lines]
    lines = [re.sub(r"^(RuntimeError|ValueError|TypeError|Exception): (\[[\w.]+:\d+\]\s*)?", "", ln) for ln in lines]
    if not lines:
        return type(err).__name__
    # "Found unused parameters:" + "- $foo=3" style lists become one line.
    if len(lines) > 1 and lines[-1].startswith("-"):
        head = [ln for ln in lines if not ln.startswith("-")]
        items = [ln.lstrip("- ") for ln in lines if ln.startswith("-")]
        return (head[-1] if head else "") + " " + ", ".join(items)
    return lines[-1] if len(lines[-1]) > 20 or len(lines) == 1 else " ".join(lines[-2:])


def file_sha256(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


@contextmanager
def single_threaded():
    """Run the ``with`` block with one drjit thread, then restore the thread count.

    Scenes are loaded this way: Mitsuba computes the vertex normals of a
    mesh file that has none (e.g. the generated mannequin PLY) with parallel
    floating-point scatter-adds, whose order, and so the last bits of the
    normals and of every render, varies between runs when more than one
    thread does it. Loaded on one thread, the same scene gives the same bytes.
    """
    import drjit as dr

    n = dr.thread_count()
    dr.set_thread_count(1)
    try:
        yield
    finally:
        dr.set_thread_count(n)


def load_scene(path: str | Path, defines: dict[str, str] | None = None):
    """Load a Mitsuba XML scene, turning loader failures into :class:`UserInputError`.

    The scene is loaded on one drjit thread (see :func:`single_threaded`) so
    that renders are byte-reproducible; rendering then uses every thread.

    Parameters
    ----------
    path : path
        The XML scene file.
    defines : dict, optional
        Values for the scene's ``$name`` parameters (strings).
    """
    p = Path(path)
    if not p.exists():
        raise UserInputError(f"scene file {str(p)!r} does not exist")
    if not p.is_file():
        raise UserInputError(f"scene file {str(p)!r} is not a file")
    # Mitsuba's scene optimisation merges meshes that share an (equivalent)
    # BSDF; for NLOS scenes that could fuse the relay wall with hidden
    # geometry, so it is switched off for them.
    nlos = "spad_array" in p.read_text(errors="replace")
    try:
        with single_threaded():
            return mi.load_file(str(p), optimize=not nlos, **(defines or {}))
    except RuntimeError as e:
        raise UserInputError(f"{p}: {mitsuba_error_message(e)}") from None
