"""Meshes the free-mesh fit's tests share (``tests/test_fit_mesh*.py``)."""

from __future__ import annotations

import math

import numpy as np


def tilted_grid(n: int, side: float, tilt_deg: float = 30.0, z: float = 0.5):
    """An ``n x n``-vertex grid of the tilted plane's square (side ``side``, m; turned ``tilt_deg`` about the
    vertical, centred at depth ``z``), faces wound towards the wall (-z): ``(vertices [n^2, 3], faces
    [2 (n-1)^2, 3])``; vertex ``j n + i`` lies at row ``j`` (the vertical coordinate) and column ``i``."""
    s = np.linspace(-side / 2, side / 2, n)
    u, v = np.meshgrid(s, s)
    a = math.radians(tilt_deg)
    x = np.stack([u.ravel() * math.cos(a), v.ravel(), z - u.ravel() * math.sin(a)], axis=1)
    f = []
    for j in range(n - 1):
        for i in range(n - 1):
            q = j * n + i
            f += [[q, q + n + 1, q + 1], [q, q + n, q + n + 1]]
    return x, np.array(f)
