"""Argument checks of the studies: every mistake is a one-line :class:`~transient_core.errors.UserInputError`
naming the parameter, the value and what is allowed, raised before any work starts."""

from __future__ import annotations

import math
import numbers

from transient_core.errors import UserInputError


def _is_real(v) -> bool:
    return isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(float(v))


def _is_int(v) -> bool:
    return isinstance(v, numbers.Integral) and not isinstance(v, bool)


def _as_sequence(values, name: str) -> list:
    """A list from a sequence (or one number); strings and other objects are refused."""
    if isinstance(values, numbers.Real) and not isinstance(values, bool):
        return [values]
    if values is None or isinstance(values, (str, bytes, dict)):
        raise UserInputError(f"{name}={values!r}: expected a list of numbers")
    try:
        values = list(values)
    except TypeError:
        raise UserInputError(f"{name}={values!r}: expected a list of numbers") from None
    if not values:
        raise UserInputError(f"{name}=[]: give at least one value")
    return values


def numbers_list(values, name: str, *, lo: float = 0.0, lo_open: bool = True, hi: float | None = None,
                 unique: bool = True) -> tuple[float, ...]:
    """A non-empty tuple of finite numbers in ``(lo, hi]`` (``[lo, hi]`` with ``lo_open=False``), no repeats."""
    vals = _as_sequence(values, name)
    out = []
    for v in vals:
        ok = _is_real(v) and (float(v) > lo if lo_open else float(v) >= lo) and (hi is None or float(v) <= hi)
        if not ok:
            rng = f"{'>' if lo_open else '>='} {lo:g}" + (f" and <= {hi:g}" if hi is not None else "")
            raise UserInputError(f"{name}: {v!r} is not allowed; expected finite numbers {rng}")
        out.append(float(v))
    if unique and len(set(out)) != len(out):
        dup = sorted({v for v in out if out.count(v) > 1})
        raise UserInputError(f"{name}: {', '.join(f'{v:g}' for v in dup)} given more than once")
    return tuple(out)


def integer(value, name: str, lo: int, hi: int | None = None) -> int:
    """An integer in ``[lo, hi)``."""
    if not _is_int(value) or value < lo or (hi is not None and value >= hi):
        rng = f">= {lo}" if hi is None else f"in [{lo}, {hi})"
        raise UserInputError(f"{name}={value!r}: expected an integer {rng}")
    return int(value)


def integers_list(values, name: str, lo: int, hi: int | None = None, *, min_count: int = 1) -> tuple[int, ...]:
    """A tuple of at least ``min_count`` distinct integers in ``[lo, hi)``."""
    vals = _as_sequence(values, name)
    out = tuple(integer(v, name, lo, hi) for v in vals)
    if len(set(out)) != len(out):
        raise UserInputError(f"{name}={list(out)!r}: values must be distinct")
    if len(out) < min_count:
        raise UserInputError(f"{name}={list(out)!r}: give at least {min_count} distinct values")
    return out


def voxels(value, name: str = "voxels") -> tuple[int, int, int]:
    """``(nx, ny, nz)`` from an int or three ints, each in [2, 1024]."""
    vals = [value] * 3 if _is_int(value) else _as_sequence(value, name)
    if len(vals) != 3 or not all(_is_int(v) and 2 <= v <= 1024 for v in vals):
        shown = str(value) if _is_int(value) else ",".join(map(str, vals))
        raise UserInputError(f"{name} {shown}: expected an integer or three integers (nx, ny, nz), each in "
                             "[2, 1024]")
    return tuple(int(v) for v in vals)


def flag(value, name: str) -> bool:
    if not isinstance(value, bool):
        raise UserInputError(f"{name}={value!r}: expected True or False")
    return value


def progress(value) -> bool | None:
    if value is not None and not isinstance(value, bool):
        raise UserInputError(f"progress={value!r}: expected None (bars on a terminal), True or False")
    return value


def method(value) -> str:
    """A reconstruction method of :mod:`recon` (``lct``/``fk`` are checked against the capture later)."""
    from recon.pipeline import CONFOCAL_ONLY, METHODS

    if value not in METHODS:
        raise UserInputError(f"method={value!r}: allowed {', '.join(METHODS)} ({', '.join(CONFOCAL_ONLY)} need "
                             "confocal captures)")
    return value
