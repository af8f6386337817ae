"""Typed, validated reading of Mitsuba plug-in properties.

Every plug-in reads its parameters through these helpers so that a bad value
fails in ``__init__`` with one message naming the plug-in, the parameter, the
value and what is allowed, e.g. ``transient_film: n_bins=-3 must be an
integer >= 1``. Mitsuba wraps exceptions raised while a scene loads; the
render pipeline unwraps :class:`PluginParameterError` back into that one line.

Nothing here binds variant-specific Mitsuba types at import time.
"""

from __future__ import annotations

import math
from typing import Sequence

from transient_core.errors import UserInputError


class PluginParameterError(UserInputError):
    """A plug-in parameter has a value that is not allowed."""


def _has(props, name: str) -> bool:
    return name in props


def get_int(props, plugin: str, name: str, default: int | None, *, min_value: int | None = None,
            max_value: int | None = None) -> int:
    """Read an integer property (``<integer>``), checking its range."""
    if not _has(props, name):
        if default is None:
            raise PluginParameterError(f"{plugin}: parameter {name!r} is required (an integer)")
        return default
    v = props.get(name)
    if isinstance(v, bool) or not isinstance(v, int):
        raise PluginParameterError(f"{plugin}: {name}={v!r} must be an integer (use <integer name=\"{name}\" .../>)")
    if min_value is not None and v < min_value:
        raise PluginParameterError(f"{plugin}: {name}={v} must be an integer >= {min_value}")
    if max_value is not None and v > max_value:
        raise PluginParameterError(f"{plugin}: {name}={v} must be an integer <= {max_value}")
    return v


def get_float(props, plugin: str, name: str, default: float | None, *, min_value: float | None = None,
              max_value: float | None = None, min_exclusive: bool = False) -> float:
    """Read a real property (``<float>`` or ``<integer>``), finite and in range."""
    if not _has(props, name):
        if default is None:
            raise PluginParameterError(f"{plugin}: parameter {name!r} is required (a number)")
        return float(default)
    v = props.get(name)
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise PluginParameterError(f"{plugin}: {name}={v!r} must be a number")
    v = float(v)
    if not math.isfinite(v):
        raise PluginParameterError(f"{plugin}: {name}={v} must be finite")
    if min_value is not None:
        if min_exclusive and not v > min_value:
            raise PluginParameterError(f"{plugin}: {name}={v:g} must be > {min_value:g}")
        if not min_exclusive and v < min_value:
            raise PluginParameterError(f"{plugin}: {name}={v:g} must be >= {min_value:g}")
    if max_value is not None and v > max_value:
        raise PluginParameterError(f"{plugin}: {name}={v:g} must be <= {max_value:g}")
    return v


def get_bool(props, plugin: str, name: str, default: bool) -> bool:
    """Read a ``<boolean>`` property."""
    if not _has(props, name):
        return default
    v = props.get(name)
    if not isinstance(v, bool):
        raise PluginParameterError(f"{plugin}: {name}={v!r} must be true or false (use <boolean .../>)")
    return v


def get_choice(props, plugin: str, name: str, default: str, choices: Sequence[str]) -> str:
    """Read a ``<string>`` property restricted to ``choices``."""
    if not _has(props, name):
        return default
    v = props.get(name)
    if not isinstance(v, str) or v not in choices:
        raise PluginParameterError(f"{plugin}: {name}={v!r}; allowed: {', '.join(choices)}")
    return v


def get_vector3(props, plugin: str, name: str, default: Sequence[float] | None) -> tuple[float, float, float]:
    """Read a ``<point>``/``<vector>`` property (or a 3-element list) as 3 floats."""
    if not _has(props, name):
        if default is None:
            raise PluginParameterError(f"{plugin}: parameter {name!r} is required (a point x, y, z in metres)")
        return tuple(float(c) for c in default)  # type: ignore[return-value]
    v = props.get(name)
    try:
        xyz = tuple(float(v[i]) for i in range(3))
    except (TypeError, IndexError, ValueError):
        raise PluginParameterError(f"{plugin}: {name}={v!r} must be a point/vector with x, y, z") from None
    if not all(math.isfinite(c) for c in xyz):
        raise PluginParameterError(f"{plugin}: {name}={xyz} must be finite")
    return xyz  # type: ignore[return-value]
