"""The fit's deterministic optimiser: Levenberg-Marquardt on the capture's objective through the quadrature.

With the deterministic three-bounce estimator (``estimator="quadrature"``) the objective of
:mod:`transient_mi.fit.capture_model`, ``0.5 sum w (mu(theta) - k)^2``, is a smooth, noise-free function of a
few parameters (16 for the mannequin), so a second-order method needs far fewer evaluations than Adam's 300
(Adam averages Monte Carlo noise; here there is none). Each iteration:

1. the residual ``r = sqrt(w) (mu - k)`` at ``theta`` (one render; kept from the last accepted step);
2. the Jacobian ``J = dr/dtheta`` by forward differences, one render per parameter, steps ``model.fd_step``
   (1 degree, 3 mm, 0.01 of reflectance: large enough that the elements' discrete visibility changes little
   between the two renders, small against the basin);
3. the damped Gauss-Newton step ``(J^T J + lam diag(J^T J)) delta = -J^T r`` (Marquardt's scaling), limited to
   ``TRUST * model.step`` per parameter (30 degrees, 8 cm) and clipped to the bounds; accepted when the
   objective falls (``lam`` divided by 3), else ``lam`` multiplied by 4 and the step solved again (one render per
   try, at most :data:`MAX_TRIES`). A stage has converged when its tries all fail or a step lowers the objective by
   less than :data:`REL_TOL` of it; its remaining iterations are skipped (they cost nothing).

Coarse to fine, as Adam's schedule: the stages' temporal blurs fall geometrically from ``sigma_start_ps`` to
``sigma_end_ps`` (:func:`stages`), and the model and the counts are always blurred alike. The elements are
4 x ``element_size_m`` at the widest blur and 2 x after (:func:`element_size_m`).

Pixels: the fit renders every ``pixel_step``-th pixel of the capture along each axis
(:class:`~transient_mi.fit.capture_model.CaptureModel` with ``pixel_step``; the step chosen by
:func:`pixel_step` so that at least :data:`MIN_PIXELS` x :data:`MIN_PIXELS` pixels remain: 4 on the paper's 32 x
32 array). Those pixels are rendered and compared exactly; the others are not used. The time axis carries the
depth; the pixels' count only needs to pin a few parameters, and the fit's cost is proportional to it.

The same inputs give the same parameters bit for bit, and a run resumed from any checkpoint ends where an
uninterrupted one does (each iteration starts from the checkpointed ``theta`` and ``lam`` only).
"""

from __future__ import annotations

import math
import time

import numpy as np

__all__ = ["GN_ITERATIONS", "GN_DETAIL", "pixel_step", "stages", "run_gauss_newton"]

#: Iterations of a Gauss-Newton fit when none are given (the demo's capture: converged by then).
GN_ITERATIONS = 16
#: The mannequin twin's tessellation in a Gauss-Newton fit (as ``transient-mi mannequin --detail``: 12 segments
#: around each primitive). Each face is at least one element of the quadrature, and the fit renders 17 times an
#: iteration; at 8 segments the polygons' faces lie 5 % of a limb's radius inside its surface on average, and the
#: demo's fit came out 2.6 mm too close to the wall (voxel IoU 0.85); at 12 (2.3 %) 1 mm (0.92).
GN_DETAIL = 12
#: The fit keeps at least this many pixels along each axis of the capture (:func:`pixel_step`).
MIN_PIXELS = 8
#: A step moves no parameter by more than this many of its ``model.step`` (Adam's step sizes).
TRUST = 20.0
#: Tries (damping increases) per iteration before a stage counts as converged.
MAX_TRIES = 6
#: A stage has converged when an iteration lowers its objective by less than this share.
REL_TOL = 0.01
#: Stages of the blur schedule, and the share of the iterations each gets (most where the blur is wide: the basin).
STAGE_SHARES = (0.5, 0.375, 0.125)


def pixel_step(width: int, height: int) -> int:
    """The largest step that divides both sides and keeps at least :data:`MIN_PIXELS` pixels along each (1 for
    arrays of fewer)."""
    best = 1
    for s in range(2, 17):
        if width % s == 0 and height % s == 0 and min(width, height) // s >= MIN_PIXELS:
            best = s
    return best


def stages(n: int, sigma_start_ps: float, sigma_end_ps: float) -> list[tuple[int, float]]:
    """``[(first iteration, blur sigma in ps), ...]``: :data:`STAGE_SHARES` of ``n`` iterations, the blurs geometric
    from ``sigma_start_ps`` to ``sigma_end_ps`` (one stage at ``sigma_end_ps`` when ``n`` is under 3)."""
    k = len(STAGE_SHARES) if n >= len(STAGE_SHARES) else 1
    lo, hi = float(sigma_end_ps), max(float(sigma_start_ps), float(sigma_end_ps))
    sig = [hi * (lo / hi) ** (j / (k - 1)) for j in range(k)] if k > 1 else [lo]
    shares = np.asarray(STAGE_SHARES[:k]) / sum(STAGE_SHARES[:k])
    starts = [0]
    for j in range(1, k):
        starts.append(max(starts[-1] + 1, min(n - (k - j), int(round(n * float(shares[:j].sum()))))))
    return list(zip(starts, sig))


def element_size_m(stage: int, n_stages: int, size_m: float) -> float:
    """The quadrature's element size in ``stage``: 4 x ``size_m`` at the widest blur (of several stages), then 2 x.

    The twin's faces, not the elements, carry its shape (each face is at least one element; at
    :data:`GN_DETAIL` most faces of the limbs are smaller than 6 cm), so elements this coarse only split its large
    faces less finely. On the demo's capture 12 and 6 cm fitted the joints within 1.6 degrees in 41 s
    (``bench/results/fit.json``); 6 and 3 cm within 1.6 degrees in 60 s (a scratch run of the same code)."""
    return (4.0 if stage == 0 and n_stages > 1 else 2.0) * float(size_m)


def _stage(i: int, plan: list) -> tuple[int, float]:
    j = max(k for k, (start, _) in enumerate(plan) if start <= i)
    return j, plan[j][1]


def run_gauss_newton(model, capture, state, settings, n: int, *, progress=None, checkpoint=None):
    """Optimise ``state.theta`` from ``state.iteration`` to ``n`` iterations (see the module docstring).

    ``capture``: a :class:`~transient_mi.fit.capture_model.CaptureModel` with the quadrature (its ``pixel_step``
    already chosen). ``state``: a :class:`~transient_mi.fit.optimize.FitState`, whose ``lam`` holds the damping;
    its ``history`` gets one row per iteration: the objective at the stage's blur, the blur (ps), the seconds,
    the objective at the final blur (both over the pixels rendered). ``progress(i, n, objective)`` after each
    iteration; ``checkpoint(state)`` every ``settings.checkpoint_every`` iterations and at the end.
    """
    end = max(settings.sigma_end_ps, capture.jitter_sigma_ps)
    capture.keep_blur(end)
    plan = stages(n, settings.sigma_start_ps, end)
    h = np.asarray(model.fd_step, dtype=np.float64)
    limit = TRUST * np.asarray(model.step, dtype=np.float64)
    theta = np.asarray(state.theta, dtype=np.float64)

    def residual(th, sigma):
        capture.set_mesh(model.vertices(th), model.albedo(th))
        mu_end = capture.expected_counts(capture.ideal(0, 1, end))
        k, sw = capture.counts_blurred(sigma), np.sqrt(capture.weights(sigma))
        r = ((capture.blur(mu_end, end, sigma) - k) * sw).ravel()
        return r, mu_end

    cached = None  # (theta, sigma, r, mu_end) of the current iterate
    for i in range(state.iteration, n):
        t0 = time.perf_counter()
        stage, sigma = _stage(i, plan)
        capture.set_element_size(element_size_m(stage, len(plan), settings.element_size_m))
        done = state.converged_stage is not None and state.converged_stage >= stage
        if cached is None or cached[1] != sigma:  # (a new stage: its blur and elements)
            cached = (theta, sigma, *residual(theta, sigma))
        r = cached[2]
        f = 0.5 * float(r @ r)
        lam = float(state.lam)
        if not done:
            J = np.empty((r.size, theta.size))
            for p in range(theta.size):
                th = theta.copy()
                th[p] += h[p] if th[p] + h[p] <= model.upper[p] else -h[p]
                J[:, p] = (residual(th, sigma)[0] - r) / (th[p] - theta[p])
            A, g = J.T @ J, J.T @ r
            del J
            d = np.diag(A).copy()
            d[~(d > 0)] = 1.0
            accepted = small = False
            for _ in range(MAX_TRIES):
                delta = -np.linalg.solve(A + lam * np.diag(d), g)
                scale = float(np.max(np.abs(delta) / limit))
                if scale > 1.0:
                    delta /= scale
                trial = np.clip(theta + delta, model.lower, model.upper)
                rt, mut = residual(trial, sigma)
                ft = 0.5 * float(rt @ rt)
                if math.isfinite(ft) and ft < f:
                    small = f - ft < REL_TOL * f
                    theta, f, cached, accepted = trial, ft, (trial, sigma, rt, mut), True
                    lam = max(lam / 3.0, 1e-7)
                    break
                lam = min(lam * 4.0, 1e7)
            if not accepted or small:  # (at this blur no step lowers the objective by much: on to the next)
                state.converged_stage = stage
        obj_end, _ = capture.objective(cached[3], end)
        state.theta, state.lam, state.iteration = theta.tolist(), lam, i + 1
        dt = time.perf_counter() - t0
        state.elapsed_s += dt
        state.history.append([f, float(sigma), float(dt), float(obj_end)])
        if progress is not None:
            progress(i + 1, n, f)
        if checkpoint is not None and ((i + 1) % settings.checkpoint_every == 0 or i + 1 == n):
            checkpoint(state)
    return state
