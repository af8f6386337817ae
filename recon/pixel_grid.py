"""Checks of the relay-wall sampling that wave-based methods (LCT, f-k, phasor RSD) rely on."""

from __future__ import annotations

import numpy as np

from transient_core.errors import UserInputError

__all__ = ["regular_pixel_grid", "RegularGrid", "SAME_SPOT_TOLERANCE_M"]

#: A confocal laser spot within this distance of its pixel's patch centre counts as on it (metres):
#: rendered captures store positions in float32 (~1e-7 m), far below any bin's path width.
SAME_SPOT_TOLERANCE_M = 1e-6


class RegularGrid:
    """Pixels on an axis-aligned regular grid in the plane z = 0.

    Attributes
    ----------
    x_m : ndarray (W,)
        Column x coordinates, increasing.
    y_m : ndarray (H,)
        Row y coordinates, increasing.
    dx_m, dy_m : float
        Spacings (NaN for a single column/row).
    """

    def __init__(self, x_m: np.ndarray, y_m: np.ndarray):
        self.x_m = x_m
        self.y_m = y_m
        self.dx_m = float(x_m[1] - x_m[0]) if len(x_m) > 1 else float("nan")
        self.dy_m = float(y_m[1] - y_m[0]) if len(y_m) > 1 else float("nan")


def regular_pixel_grid(capture, method: str, rtol: float = 1e-4) -> RegularGrid | None:
    """Return the capture's pixel grid if it is regular, axis-aligned and in the plane z = 0, else None.

    Positions may deviate from the regular grid by ``rtol`` times the pixel
    pitch (rendered captures store float32 positions, ~1e-7 m off); the
    returned axes are the column / row means. ``method`` only names the caller
    in messages. Raises nothing; the callers decide whether to fall back or to
    raise.
    """
    P = capture.pixel_centers
    if not capture.wall_is_z0(atol=1e-6):
        return None
    x = P[..., 0].mean(axis=0)
    y = P[..., 1].mean(axis=1)
    steps = [np.diff(a) for a in (x, y) if len(a) > 1]
    if not steps:
        return RegularGrid(x, y)
    pitch = float(np.mean(np.concatenate(steps)))
    if not pitch > 0:
        return None
    tol = rtol * pitch
    if np.max(np.abs(P[..., 0] - x[None, :])) > tol or np.max(np.abs(P[..., 1] - y[:, None])) > tol:
        return None
    for a in (x, y):
        if len(a) > 1:
            d = np.diff(a)
            if not (d[0] > 0 and np.max(np.abs(d - d.mean())) <= tol):
                return None
            a[:] = a[0] + d.mean() * np.arange(len(a))   # the regular grid the positions approximate
    return RegularGrid(x, y)


def require_regular_confocal(capture, method: str) -> RegularGrid:
    """The pixel grid of a confocal capture suitable for LCT / f-k, or a clear error.

    Needs: a confocal capture, laser spot k on pixel k's patch, pixels on a
    regular axis-aligned grid in the plane z = 0 with equal x and y spacing.
    """
    where = capture.source or "capture"
    if capture.mode != "confocal":
        raise UserInputError(
            f"--method {method} needs a confocal capture (laser on each pixel's wall patch); {where} is an "
            f"{capture.describe()}: use bp, fbp or phasor for it")
    S = capture.spots.reshape(capture.height, capture.width, 3)
    dev = float(np.max(np.linalg.norm(S - capture.pixel_centers, axis=-1)))
    if dev > SAME_SPOT_TOLERANCE_M:
        raise UserInputError(f"--method {method}: laser spot k must be pixel k's patch centre, but they differ by "
                             f"up to {dev:.3g} m in {where}; use bp, fbp or phasor")
    g = regular_pixel_grid(capture, method)
    if g is None:
        raise UserInputError(
            f"--method {method} needs the pixels on a regular, axis-aligned grid in the relay-wall plane z = 0 "
            f"with normal +z; {where} is not (resample it onto such a grid, or use bp, fbp or phasor)")
    if capture.height < 2 or capture.width < 2:
        raise UserInputError(f"--method {method} needs at least 2x2 pixels, {where} has "
                             f"{capture.height}x{capture.width}")
    if not np.isclose(g.dx_m, g.dy_m, rtol=1e-4):
        raise UserInputError(
            f"--method {method} needs equal pixel spacing along x and y; {where} has dx={g.dx_m:.6g} m, "
            f"dy={g.dy_m:.6g} m (resample it onto a square grid, or use bp, fbp or phasor)")
    return g
