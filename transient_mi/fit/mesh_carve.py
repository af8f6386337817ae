"""Carving the aligned start (``--carve``): which of its faces the counts want.

The free mesh keeps its start's topology (:mod:`~transient_mi.fit.mesh_fit`), and a start made from a
reconstruction over-covers: the letter's start is a blob over its strokes, the holed plate's a sheet over its hole.
With the geometry held, three-bounce light is linear in every face's reflectance, so which faces hold the object
is a non-negative linear inverse problem (through the detector layer, which is not linear): this module fits one
reflectance per face to the counts, then drops the dark faces.

**The fit.** The objective is the fit's own (``CaptureModel.objective`` at the end blur: weighted least squares of
the expected counts, pile-up and dead time included). Each iteration takes a scaled gradient step, the
majorise-minimise step of non-negative least squares (ISRA; Daube-Witherspoon and Muehllehner 1986; for a linear
model it is ``rho <- rho * (J^T W k) / (J^T W J rho)``):

.. math::

    \\rho_f \\leftarrow \\rho_f - \\tau\\, \\rho_f\\, \\frac{g_f}{d_f}, \\qquad g = J^T W (\\mu - k), \\qquad
    d = J^T W (J \\rho),

``J`` the derivative of the expected counts ``mu`` with respect to the reflectances (one reverse pass of the
quadrature each for ``g`` and ``d``; ``J rho``, the change of ``mu`` when every reflectance grows alike, by a
difference through the detector layer alone: the ideal capture is linear in them). A face's step is proportional
to its reflectance, so a face the data do not want falls geometrically and one they want grows, whatever its
light; no step size to tune. The detector's pile-up makes some entries of ``J`` negative (more light early, fewer
counts later), so ``d`` is not a strict majoriser: it is floored at :data:`CURVATURE_FLOOR` of its median, a step
lowers a reflectance by at most :data:`MAX_FALL` of it, and ``tau`` is halved from 1 until the objective falls (up
to :data:`HALVINGS` times; no fall ends the fit).

**The cut.** A face is kept when its reflectance is at least :data:`KEEP_FRACTION` of the bright faces' (the
:data:`REFERENCE_PERCENTILE`-th percentile): for a hidden object of one material the faces are near its
reflectance or near zero, and half of it is the decision threshold between the two. The reference assumes the
object covers more than a tenth of the start's faces.
"""

from __future__ import annotations

import time

import numpy as np

#: A step lowers a face's reflectance by at most this share of it.
MAX_FALL = 0.9
#: The step's curvature ``d`` is floored at this share of its median positive value.
CURVATURE_FLOOR = 0.1
#: Halvings of the step before a fit gives up on an iteration that does not lower the objective.
HALVINGS = 6
#: The smallest reflectance, as a share of the largest (a face may come back).
RHO_FLOOR = 1e-3
#: A face is kept when its reflectance is at least this share of the reference.
KEEP_FRACTION = 0.5
#: The reference reflectance: this percentile of the faces' (the bright ones).
REFERENCE_PERCENTILE = 90.0
#: The relative change of ``mu`` used for ``J rho``.
SCALE_STEP = 1e-3


def _state(cap, vertices: np.ndarray, rho: np.ndarray, sigma_ps: float) -> tuple:
    """``(ideal, dead-time factor, mu, objective, its gradient in mu)`` of the per-face reflectances ``rho``."""
    cap.set_mesh(vertices, rho)
    ideal = cap.ideal(0, 0, sigma_ps)
    factor = cap.dead_time_factor(ideal)
    mu = cap.expected_counts(ideal, factor)
    obj, resid = cap.objective(mu, sigma_ps)
    return ideal, factor, mu, obj, resid


def fit_face_reflectance(cap, vertices: np.ndarray, rho0, iterations: int, sigma_ps: float,
                         progress=None) -> tuple[np.ndarray, list]:
    """Fit one reflectance per face with the geometry held (module docstring).

    Parameters
    ----------
    cap : transient_mi.fit.capture_model.CaptureModel
        The capture model of the mesh, with ``reflectance="face"``.
    vertices : ndarray, float, shape (V, 3)
        The mesh's vertices (m).
    rho0 : float or ndarray, shape (F,)
        The starting reflectance(s).
    iterations : int
        Steps to take (fewer when one no longer lowers the objective).
    sigma_ps : float
        The temporal blur the objective is taken at (ps; the fit's end blur).
    progress : callable, optional
        Called as ``progress(i, objective)`` after each step.

    Returns
    -------
    rho : ndarray, float64, shape (F,)
    history : list of [objective, tau, seconds]
        The starting objective first (``tau`` 0).
    """
    v = np.asarray(vertices, dtype=np.float64)
    F = int(cap.mesh.face_count())
    rho = np.broadcast_to(np.asarray(rho0, dtype=np.float64), (F,)).copy()
    t0 = time.perf_counter()
    cap.set_mesh(v, np.zeros(F))
    ideal_zero = cap.ideal(0, 0, sigma_ps)  # (what no face reflects: the wall's own return)
    ideal, factor, mu, obj, resid = _state(cap, v, rho, sigma_ps)
    history = [[obj, 0.0, time.perf_counter() - t0]]
    for i in range(int(iterations)):
        along = (cap.expected_counts(ideal + SCALE_STEP * (ideal - ideal_zero)) - mu) / SCALE_STEP  # J rho
        _, g = cap.backward(resid, ideal, 0, 0, sigma_ps, factor, vertices=False)
        _, d = cap.backward(cap.weights(sigma_ps) * along, ideal, 0, 0, sigma_ps, factor, vertices=False)
        pos = d[d > 0]
        if not len(pos):
            break
        d = np.maximum(d, CURVATURE_FLOOR * float(np.median(pos)))
        step = np.minimum(rho * g / d, MAX_FALL * rho)
        tau, new = 1.0, None
        for _ in range(HALVINGS + 1):
            trial = np.maximum(rho - tau * step, RHO_FLOOR * float(rho.max()))
            st = _state(cap, v, trial, sigma_ps)
            if st[3] < obj:
                new = (trial, st)
                break
            tau /= 2
        if new is None:
            cap.set_mesh(v, rho)  # (the model left at the last accepted reflectances; no render needed)
            break
        rho, (ideal, factor, mu, obj, resid) = new
        history.append([obj, tau, time.perf_counter() - t0])
        if progress is not None:
            progress(i, obj)
    return rho, history


def keep_faces(rho: np.ndarray) -> np.ndarray:
    """Which faces to keep (bool ``[F]``): reflectance at least :data:`KEEP_FRACTION` of the
    :data:`REFERENCE_PERCENTILE`-th percentile."""
    rho = np.asarray(rho, dtype=np.float64)
    return rho >= KEEP_FRACTION * float(np.percentile(rho, REFERENCE_PERCENTILE))


def drop_faces(vertices: np.ndarray, faces: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mesh of the kept faces, its vertices that no kept face uses removed (the others in their order)."""
    f = np.asarray(faces, dtype=np.int64)[np.asarray(keep, dtype=bool)]
    used = np.unique(f)
    index = np.full(len(vertices), -1, dtype=np.int64)
    index[used] = np.arange(len(used))
    return np.asarray(vertices, dtype=np.float64)[used], index[f]
