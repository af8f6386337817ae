"""Carving the aligned start (``--carve``): which of its faces the counts want.

The free mesh keeps its start's topology (:mod:`~transient_mi.fit.mesh_fit`), and a start made from a
reconstruction over-covers: the letter's start is a blob over its strokes, the holed plate's a sheet over its hole.
With the geometry held, three-bounce light is linear in every face's reflectance, so which faces hold the object
is a non-negative linear inverse problem (through the detector layer, which is not linear): this module fits one
reflectance per face to the counts, then drops the dark faces.

**The fit.** The objective is the fit's own (``CaptureModel.objective`` at the end blur: weighted least squares of
the expected counts, pile-up and dead time included), minimised over the reflectances with each held in
``[0, RHO_MAX]`` by L-BFGS-B (Byrd, Lu, Nocedal and Zhu 1995; scipy's): one forward and one reverse pass of the
quadrature per evaluation (the reflectances' gradient alone, ``g = J^T W (mu - k)``). The upper bound is physical: a
diffuse surface reflects at most the light it receives (:data:`RHO_MAX` = 1). It matters where the start
under-covers the object: without it the faces at the start's edge took the missing surface's light with
reflectances up to 2.6 (the tilted plane's 8 x 8 capture), and the grown faces beyond them stayed dark; with it the
light has to go where the surface is. The majorise-minimise step of non-negative least squares (ISRA) that carved
until 2026-12-06 had no such bound, and after 20 of its steps the objective still fell a few per cent a step.

**The prior.** Many reflectance patterns explain the counts about equally well (faces a few centimetres apart send
their light to the same bins), and without a prior the fit left the letter's strokes blotchy: bright faces beside
dark ones inside the object, which the cut then dropped. The objective therefore adds :data:`TV_WEIGHT` times the
signal energy ``S`` (:attr:`~transient_mi.fit.mesh_model.MeshModel.reg_scale`) times the reflectances' total
variation across interior edges, each weighted by its length over the square root of the mesh's area
(:func:`~transient_mi.fit.mesh_regularizers.reflectance_total_variation`, rounded within :data:`TV_DELTA`): a prior
of piecewise-constant reflectance, the object's and zero, whose edge may stay sharp, and whose weight does not
depend on the faces' size. Scratch studies, the carving alone (40 iterations, the same aligned start): on the
letter's 16 x 16 capture the kept faces' silhouette IoU rose from 0.76 to 0.82 (the faces centred on the letter:
0.84); on its 8 x 8 capture the weights 0, 1.2e-5, 3.6e-5, 1.2e-4, 3.6e-4, 1.2e-3 and 3.6e-3 gave 0.68, 0.71,
0.72, 0.72, 0.76, 0.72 and 0.70.

**The cut.** A face is kept when its reflectance is at least :data:`KEEP_FRACTION` of the bright faces' (the
:data:`REFERENCE_PERCENTILE`-th percentile): for a hidden object of one material the faces are near its
reflectance or near zero, and half of it is the decision threshold between the two. The reference assumes the
object covers more than a tenth of the start's faces.
"""

from __future__ import annotations

import math
import time

import numpy as np

#: The largest reflectance a face may take (a diffuse surface reflects at most the light it receives).
RHO_MAX = 1.0
#: Objective evaluations L-BFGS-B may take per iteration asked for, on average (its line search may take more than
#: one in an iteration).
EVALUATIONS_PER_ITERATION = 1.5
#: L-BFGS-B's memory (corrections kept).
LBFGS_MEMORY = 20
#: A face is kept when its reflectance is at least this share of the reference.
KEEP_FRACTION = 0.5
#: The reference reflectance: this percentile of the faces' (the bright ones).
REFERENCE_PERCENTILE = 90.0
#: Weight of the reflectances' total variation (the prior; a share of the signal energy).
TV_WEIGHT = 4e-4
#: Within this difference of reflectance the total variation is rounded (it has a gradient at zero).
TV_DELTA = 0.05


def _state(cap, vertices: np.ndarray, rho: np.ndarray, sigma_ps: float) -> tuple:
    """``(ideal, dead-time factor, mu, objective, its gradient in mu)`` of the per-face reflectances ``rho``."""
    cap.set_mesh(vertices, rho)
    ideal = cap.ideal(0, 0, sigma_ps)
    factor = cap.dead_time_factor(ideal)
    mu = cap.expected_counts(ideal, factor)
    obj, resid = cap.objective(mu, sigma_ps)
    return ideal, factor, mu, obj, resid


def fit_face_reflectance(cap, vertices: np.ndarray, rho0, iterations: int, sigma_ps: float,
                         progress=None, *, faces: np.ndarray | None = None,
                         tv_weight: float = 0.0) -> tuple[np.ndarray, list]:
    """Fit one reflectance per face with the geometry held (module docstring).

    Parameters
    ----------
    cap : transient_mi.fit.capture_model.CaptureModel
        The capture model of the mesh, with ``reflectance="face"``.
    vertices : ndarray, float, shape (V, 3)
        The mesh's vertices (m).
    rho0 : float or ndarray, shape (F,)
        The starting reflectance(s) (clipped to ``[0, RHO_MAX]``).
    iterations : int
        L-BFGS-B iterations (fewer when it converges; at most ``EVALUATIONS_PER_ITERATION`` times as many
        evaluations of the objective).
    sigma_ps : float
        The temporal blur the objective is taken at (ps; the fit's end blur).
    progress : callable, optional
        Called as ``progress(i, objective)`` after each iteration.
    faces : ndarray, int, shape (F, 3), optional
        The mesh's faces (needed for the prior).
    tv_weight : float
        Weight of the reflectances' total variation (module docstring; :data:`TV_WEIGHT` in the fit), a share of the
        signal energy; 0: no prior.

    Returns
    -------
    rho : ndarray, float64, shape (F,)
        The reflectances of the lowest objective evaluated (the model is left at them).
    history : list of [objective, evaluations, seconds]
        The starting objective (the prior's term included) first, then the lowest so far after each iteration, with
        the evaluations made.
    """
    from scipy.optimize import minimize

    from .mesh_regularizers import MeshTopology, outline_weights, reflectance_total_variation

    v = np.asarray(vertices, dtype=np.float64)
    F = int(cap.mesh.face_count())
    if tv_weight > 0:
        if faces is None or len(faces) != F:
            raise ValueError("fit_face_reflectance: the prior needs the mesh's faces")
        topo = MeshTopology(np.asarray(faces, dtype=np.int64), len(v))
        pairs, weights = topo.face_pairs, outline_weights(v, topo)
        prior = float(tv_weight) * cap.objective(np.zeros_like(cap.counts), sigma_ps)[0]  # (times the signal energy)
    rho = np.clip(np.broadcast_to(np.asarray(rho0, dtype=np.float64), (F,)), 0.0, RHO_MAX).copy()
    t0 = time.perf_counter()
    history: list = []
    best = {"objective": math.inf, "rho": rho.copy(), "evaluations": 0, "scale": None}

    def evaluate(x: np.ndarray) -> tuple[float, np.ndarray]:
        ideal, factor, mu, obj, resid = _state(cap, v, x, sigma_ps)
        _, g = cap.backward(resid, ideal, 0, 0, sigma_ps, factor, vertices=False)
        g = np.asarray(g, dtype=np.float64)
        if tv_weight > 0:
            e, ge = reflectance_total_variation(x, pairs, weights, TV_DELTA)
            obj, g = obj + prior * e, g + prior * ge
        best["evaluations"] += 1
        if best["scale"] is None:  # (the objective in units of the start's: L-BFGS-B's tolerances are relative)
            best["scale"] = 1.0 / max(obj, 1e-300)
            history.append([obj, 1, time.perf_counter() - t0])
        if obj < best["objective"]:
            best.update(objective=obj, rho=np.array(x, dtype=np.float64))
        return obj * best["scale"], g * best["scale"]

    def step(_x) -> None:
        history.append([best["objective"], best["evaluations"], time.perf_counter() - t0])
        if progress is not None:
            progress(len(history) - 2, best["objective"])

    n = int(iterations)
    if n > 0:
        minimize(evaluate, rho, jac=True, method="L-BFGS-B", bounds=[(0.0, RHO_MAX)] * F, callback=step,
                 options={"maxiter": n, "maxfun": int(math.ceil(EVALUATIONS_PER_ITERATION * n)) + 1, "ftol": 1e-12,
                          "gtol": 0.0, "maxcor": LBFGS_MEMORY})
    else:
        evaluate(rho)
    cap.set_mesh(v, best["rho"])
    return best["rho"], history


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
