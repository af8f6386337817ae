"""Plain JSON values from what the pipelines hold (numpy scalars and arrays, tuples, paths)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Callable

import numpy as np


def to_json(obj: Any, nonfinite: Callable[[float], Any] | None = None) -> Any:
    """``obj`` with numpy arrays and scalars, tuples and paths turned into JSON types, recursively.

    Dict keys become strings. A NaN or infinity becomes ``null`` (``nonfinite=None``) or whatever
    ``nonfinite(value)`` returns; it may raise, for files where such a value is an error.
    """
    if isinstance(obj, dict):
        return {str(k): to_json(v, nonfinite) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_json(v, nonfinite) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_json(obj.tolist(), nonfinite)
    if isinstance(obj, np.generic):
        return to_json(obj.item(), nonfinite)
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, float) and not math.isfinite(obj):
        return None if nonfinite is None else nonfinite(obj)
    return obj
