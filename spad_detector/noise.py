"""Noise sources that are not the signal: dark counts, ambient light, afterpulsing, crosstalk.

Dark counts and ambient background
----------------------------------
Both are Poisson processes, uniform in time, with rates ``dark_count_rate_cps``
and ``ambient_rate_cps`` (avalanches per second of a fully armed SPAD; for
ambient light the PDE is already included). The gate thins them like the
signal, so slot ``j`` of the cycle receives

    lam_bg[j] = (dark_count_rate_cps + ambient_rate_cps) * width_j * 1e-12 * g_j

triggering events per cycle (``width_j`` in ps, ``g_j`` the slot's mean gate
efficiency). Dark counts and ambient light also fall outside the histogram
window (the rest of the period), where they are not recorded but cost dead
time.

Afterpulsing
------------
After an avalanche, trapped carriers may trigger a second one. With
probability ``afterpulse_prob`` an avalanche releases one afterpulse at a delay
``dead_time + D`` with ``D ~ Exponential(mean = afterpulse_delay_ns)``, i.e.
measured from the moment the SPAD re-arms (releases during the hold-off are
harmless, which is why SPADs use hold-off). It triggers an avalanche with
probability ``g(t)`` (the SPAD must be armed by the gate) if the SPAD is ready
then, and is then an ordinary detection (dead time, TCSPC, jitter, its own
afterpulse). ``afterpulse_prob`` is therefore the afterpulsing probability a
datasheet quotes for the given hold-off, at full gate efficiency.

Optical crosstalk
-----------------
Hot carriers in an avalanche emit photons that can trigger a neighbour: each
of the (up to) 4 nearest neighbours on the pixel grid avalanches at the same
instant with probability ``crosstalk_prob * g(t)``, if it is ready. Crosstalk
avalanches can trigger crosstalk in turn (each pixel at most once per instant).
Neighbours are pixels of the same spot file recorded at the same time, so
crosstalk is refused for confocal captures, whose pixels were recorded under
different laser positions.
"""

from __future__ import annotations

import math

import numpy as np

from .cycle import CycleGrid
from .pileup import ready_shift


def background_per_slot(params, grid: CycleGrid, gate_slots: np.ndarray) -> np.ndarray:
    """Mean dark + ambient triggering events per cycle in each slot, shape (n_slots,)."""
    rate = params.dark_count_rate_cps + params.ambient_rate_cps
    return rate * grid.widths * 1e-12 * gate_slots


def neighbour_csr(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """4-neighbour lists of an ``height x width`` pixel grid (row-major pixel index), CSR form.

    Returns ``(ptr[n+1], idx[...])``: neighbours of pixel ``k`` are
    ``idx[ptr[k]:ptr[k+1]]``.
    """
    k = np.arange(height * width).reshape(height, width)
    lists = []
    for y in range(height):
        for x in range(width):
            nb = [k[y + dy, x + dx] for dy, dx in ((-1, 0), (1, 0), (0, -1), (0, 1))
                  if 0 <= y + dy < height and 0 <= x + dx < width]
            lists.append(nb)
    ptr = np.zeros(height * width + 1, dtype=np.int64)
    ptr[1:] = np.cumsum([len(v) for v in lists])
    idx = np.array([i for v in lists for i in v], dtype=np.int64)
    return ptr, idx


def neighbour_sum(x: np.ndarray, height: int, width: int) -> np.ndarray:
    """Sum over the 4 neighbours of each pixel; ``x`` has shape (height * width, n)."""
    g = x.reshape(height, width, -1)
    out = np.zeros_like(g)
    out[1:] += g[:-1]
    out[:-1] += g[1:]
    out[:, 1:] += g[:, :-1]
    out[:, :-1] += g[:, 1:]
    return out.reshape(x.shape)


def afterpulse_release(avalanches: np.ndarray, grid: CycleGrid, dead_time_ps: float,
                       delay_ps: float) -> np.ndarray:
    """Expected afterpulse releases per cycle per slot for unit afterpulse probability.

    Parameters
    ----------
    avalanches : ndarray, shape (n_pix, n_slots)
        Expected avalanches per cycle in each slot (stationary).

    Returns
    -------
    ndarray, shape (n_pix, n_slots)
        Releases per cycle; multiply by ``afterpulse_prob`` and the gate.

    Notes
    -----
    Each avalanche's re-arm time (slot centre + dead time, rounded to a slot
    boundary, modulo the period) receives its mass, which then decays
    exponentially with time constant ``delay_ps``; the periodic steady state
    of that first-order filter is solved exactly (one pass for the carried
    amount, one to release it).
    """
    x = np.asarray(avalanches, dtype=np.float64)
    n_pix, n = x.shape
    target, _ = ready_shift(grid, dead_time_ps)
    dep = np.zeros_like(x)
    np.add.at(dep.T, target, x.T)
    decay = np.exp(-grid.widths / delay_ps)
    total_decay = math.exp(-grid.period_ps / delay_ps)

    def sweep(carry, collect):
        rel = np.zeros_like(x) if collect else None
        for j in range(n):
            carry = carry + dep[:, j]
            if collect:
                rel[:, j] = carry * (1.0 - decay[j])
            carry = carry * decay[j]
        return carry, rel

    end, _ = sweep(np.zeros(n_pix), False)
    start = end / (1.0 - total_decay) if total_decay < 1 else end
    _, rel = sweep(start, True)
    return rel
