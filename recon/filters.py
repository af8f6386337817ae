"""The paper's volume filter (Gaussian then Laplacian, then a threshold), projections and depth maps.

PAPER.md, Section 4: ``C_f = Laplacian(G_sigma * C)``, then a threshold keeps
the likely object voxels. A reflector is a bright blob in ``C``, where the
Laplacian is negative, so we keep ``max(0, -Laplacian(G_sigma * C))`` (object
voxels positive) before thresholding. The Laplacian is taken in physical
units (``d^2/dx^2 + d^2/dy^2 + d^2/dz^2`` with the voxel sizes), so
anisotropic voxels are handled.

Thresholds (``spec`` strings, also the CLI's ``--threshold``):

``none``
    keep everything;
``otsu``
    Otsu's threshold on the positive voxels (maximises the between-class
    variance of a 256-bin histogram);
``rel:F`` / ``relative:F``
    keep voxels >= F * max (0 < F <= 1);
``abs:V`` / ``absolute:V``
    keep voxels >= V.
"""

from __future__ import annotations

import math

import numpy as np

from transient_core.errors import UserInputError
from .grid import VoxelGrid
from .result import Reconstruction

__all__ = ["paper_filter", "no_filter", "negative_laplacian_of_gaussian", "parse_threshold", "threshold_value",
           "apply_threshold", "otsu_threshold", "projections", "depth_map", "DEFAULT_THRESHOLD"]

DEFAULT_THRESHOLD = "rel:0.3"
_THRESHOLD_HELP = "allowed: none, otsu, rel:F (0 < F <= 1), abs:V (V >= 0)"


def negative_laplacian_of_gaussian(raw: np.ndarray, grid: VoxelGrid, sigma_m: float | None = None) -> np.ndarray:
    """``-Laplacian(G_sigma * raw)`` in units of ``raw`` per m^2, float32.

    The Gaussian (standard deviation ``sigma_m`` metres; default one voxel
    along each axis) is applied first, then the Laplacian as the sum over
    axes of the central second difference ``(f[i-1] - 2 f[i] + f[i+1]) / d^2``
    with the voxel size ``d`` of that axis (exact for quadratics). Borders
    repeat the edge voxel. Axes with fewer than 3 voxels contribute nothing.
    """
    from scipy.ndimage import correlate1d, gaussian_filter

    vs = np.array([grid.voxel_size_m[2], grid.voxel_size_m[1], grid.voxel_size_m[0]])  # z, y, x
    vs = np.where(np.isfinite(vs), vs, 1.0)
    if sigma_m is None:
        sig = np.ones(3)
    else:
        if not (isinstance(sigma_m, (int, float)) and math.isfinite(sigma_m) and sigma_m > 0):
            raise UserInputError(f"sigma_m={sigma_m!r} must be a positive number (metres)")
        sig = sigma_m / vs
    a = np.asarray(raw, dtype=np.float64)
    widest = 4.0 * float(np.max(np.array(a.shape) * vs))  # beyond this the filter flattens the whole volume
    if sigma_m is not None and sigma_m > widest:
        raise UserInputError(f"sigma_m={sigma_m!r} (--sigma-m): wider than 4 x the volume's largest side; allowed "
                             f"0 < sigma_m <= {widest:.4g} m here")
    sig = np.where(np.array(a.shape) >= 3, sig, 0.0)
    smooth = gaussian_filter(a, sig, mode="nearest", truncate=4.0)
    out = np.zeros(a.shape, dtype=np.float64)
    for axis in range(3):
        if a.shape[axis] < 3:
            continue
        out -= correlate1d(smooth, [1.0, -2.0, 1.0], axis=axis, mode="nearest") / vs[axis] ** 2
    return out.astype(np.float32)


def parse_threshold(spec) -> tuple[str, float | None]:
    """Parse a threshold spec into ``(mode, value)``; see the module docstring."""
    if spec is None:
        return ("none", None)
    if isinstance(spec, (int, float)) and not isinstance(spec, bool):
        return _rel(float(spec), spec)
    s = str(spec).strip().lower()
    if s in ("none", "off", ""):
        return ("none", None)
    if s == "otsu":
        return ("otsu", None)
    if ":" in s:
        mode, _, val = s.partition(":")
        try:
            v = float(val)
        except ValueError:
            raise UserInputError(f"threshold {spec!r}: {val!r} is not a number; {_THRESHOLD_HELP}") from None
        if mode in ("rel", "relative"):
            return _rel(v, spec)
        if mode in ("abs", "absolute"):
            if not (math.isfinite(v) and v >= 0):
                raise UserInputError(f"threshold {spec!r}: absolute value must be >= 0; {_THRESHOLD_HELP}")
            return ("abs", v)
    raise UserInputError(f"threshold {spec!r} not understood; {_THRESHOLD_HELP}")


def _rel(v: float, spec) -> tuple[str, float]:
    if not (math.isfinite(v) and 0 < v <= 1):
        raise UserInputError(f"threshold {spec!r}: relative fraction must lie in (0, 1]; {_THRESHOLD_HELP}")
    return ("rel", v)


def otsu_threshold(values: np.ndarray, nbins: int = 256) -> float:
    """Otsu's threshold of ``values`` (maximum between-class variance over ``nbins`` bins)."""
    v = np.asarray(values, dtype=np.float64).ravel()
    v = v[np.isfinite(v)]
    if v.size == 0:
        raise UserInputError("Otsu threshold of an empty set of values")
    lo, hi = float(v.min()), float(v.max())
    if hi <= lo:
        return lo
    counts, edges = np.histogram(v, bins=nbins, range=(lo, hi))
    centres = (edges[:-1] + edges[1:]) / 2
    w0 = np.cumsum(counts)
    w1 = w0[-1] - w0
    m = np.cumsum(counts * centres)
    with np.errstate(divide="ignore", invalid="ignore"):
        mu0 = m / w0
        mu1 = (m[-1] - m) / w1
        between = w0 * w1 * (mu0 - mu1) ** 2
    between = np.nan_to_num(between[:-1], nan=-1.0)
    i = int(np.argmax(between))
    return float(edges[i + 1])


def threshold_value(volume: np.ndarray, spec) -> float | None:
    """The absolute threshold ``spec`` means for ``volume`` (None for ``none``)."""
    mode, v = parse_threshold(spec)
    if mode == "none":
        return None
    if mode == "abs":
        return float(v)
    vmax = float(np.max(volume)) if volume.size else 0.0
    if mode == "rel":
        return float(v) * vmax
    pos = volume[volume > 0]
    if pos.size == 0:
        return math.inf
    return otsu_threshold(pos)


def apply_threshold(volume: np.ndarray, spec) -> tuple[np.ndarray, float | None]:
    """Zero the voxels below the threshold; return ``(thresholded, threshold)``.

    Raises
    ------
    UserInputError
        If no voxel survives (the message gives the volume's maximum).
    """
    thr = threshold_value(volume, spec)
    if thr is None:
        return volume, None
    vmax = float(np.max(volume)) if volume.size else 0.0
    keep = volume >= thr
    if vmax <= 0 or not np.any(keep & (volume > 0)):
        raise UserInputError(
            f"threshold {spec!r} (= {thr:.4g}) keeps no voxel: the filtered volume's maximum is {vmax:.4g}; "
            "lower the threshold, use --threshold none, or check that the capture has signal inside the bounds")
    out = np.where(keep, volume, 0).astype(np.float32)
    return out, thr


def paper_filter(rec: Reconstruction, sigma_m: float | None = None, threshold=DEFAULT_THRESHOLD) -> Reconstruction:
    """Apply the paper's filter to a reconstruction: ``max(0, -Laplacian(G_sigma * raw))``, then a threshold.

    Parameters
    ----------
    rec : Reconstruction
    sigma_m : float, optional
        Gaussian standard deviation, metres (default one voxel per axis).
    threshold : str or float
        See the module docstring (default ``rel:0.3``).

    Returns
    -------
    Reconstruction
        Same ``raw``; ``volume`` is the filtered, thresholded volume and
        ``filter`` records the parameters and the absolute threshold used.
    """
    f = np.maximum(negative_laplacian_of_gaussian(rec.raw, rec.grid, sigma_m), 0)
    vol, thr = apply_threshold(f, threshold)
    return Reconstruction(raw=rec.raw, grid=rec.grid, method=rec.method, params=rec.params, volume=vol,
                          filter={"name": "paper", "sigma_m": sigma_m, "threshold": str(threshold),
                                  "threshold_value": thr})


def no_filter(rec: Reconstruction, threshold="none") -> Reconstruction:
    """``volume = raw`` (negative values kept), optionally thresholded."""
    vol, thr = apply_threshold(rec.raw, threshold)
    return Reconstruction(raw=rec.raw, grid=rec.grid, method=rec.method, params=rec.params, volume=vol,
                          filter={"name": "none", "threshold": str(threshold), "threshold_value": thr})


def projections(volume: np.ndarray) -> dict[str, np.ndarray]:
    """Maximum-intensity projections of a ``[z, y, x]`` volume.

    Returns ``{"z": [y, x] (front view, seen from the wall), "y": [z, x] (top view), "x": [z, y] (side view)}``.
    """
    v = np.asarray(volume)
    return {"z": v.max(axis=0), "y": v.max(axis=1), "x": v.max(axis=2)}


def depth_map(volume: np.ndarray, grid: VoxelGrid) -> np.ndarray:
    """Depth (z, metres) of each column's maximum, shape ``[y, x]``; NaN where the column has no positive voxel."""
    v = np.asarray(volume)
    iz = np.argmax(v, axis=0)
    d = grid.z_m[iz].astype(np.float64)
    d[~(v.max(axis=0) > 0)] = np.nan
    return d
