r"""The free-mesh fit's first stage: the start mesh's global affine map and reflectance by Levenberg-Marquardt
(what ``transient-mi fit --model mesh`` runs before it moves single vertices).

Why a global stage
------------------
In three-bounce data a surface's depth, its tilt and its reflectance are coupled: tilting a plane about its
centre brings one edge nearer and the light's onset earlier, which a shift away from the wall undoes, and a
larger or nearer surface looks like a brighter one. The objective over (tilt, depth) is a long, narrow,
curved valley (docs/fit.md, measured on the tilted plane: from a flat start the steepest way down is to move
the whole plane nearer and dim it, not to tilt it), which first-order per-vertex steps (Adam) crawl along
for hundreds of iterations. A Gauss-Newton step on a few global parameters takes the valley's coupling from
the data's Jacobian, and a start that covers part of a surface (a backprojection's front surface keeps its
brightest part only) is stretched to its extent by the same map.

Parameters and objective
------------------------
``p = [A (3 x 3, row-major), t (3, m), log rho]``: the vertices ``x' = c + A (x - c) + t`` (``c`` the start's
centroid; ``A = I``, ``t = 0`` at the start) and the reflectance ``rho = exp(log rho)`` (within 0.01 to 1).
The objective is the fit's data term (:mod:`~transient_mi.fit.capture_model`) written as a sum of squares,
``0.5 |r|^2`` with ``r = sqrt(w) (blur(mu) - k)``; the regularisers are not part of it (an affine map keeps a
flat mesh flat and a smooth one smooth). The Jacobian is held in memory, ``13`` numbers per (spot, pixel, bin):
about 170 MB for 16 x 16 pixels, 16 spots and 400 bins. The Jacobian ``dr/dp`` is taken by forward differences of the
deterministic forward model (13 renders, no derivative pass: a quadrature render costs a fraction of its
reverse pass), the step is Levenberg-Marquardt's ``(J^T J + lambda diag(J^T J)) dp = -J^T r``, accepted when
the objective falls (else ``lambda`` grows four times, the trust radius halves, and the step is tried again, at
most 6 times); ``lambda`` falls after a step whose decrease is at least 3/4 of the Gauss-Newton model's and
grows after one below 1/4 (Nielsen's gain ratio). The
temporal blur goes from the fit's start blur to its end blur over the iterations (geometric), as in the
vertex stages. A trial mesh that would hide a wall patch from the detector or cannot be rendered counts as a
rise of the objective.
"""

from __future__ import annotations

import math

import numpy as np

from transient_core.errors import UserInputError

__all__ = ["affine_vertices", "align_affine", "realign_carved", "realign_iterations"]

#: Forward-difference steps: the linear part's entries (dimensionless: about 0.2 mm at 20 cm from the
#: centroid), the translation (m), the log reflectance.
FD_STEPS = (1e-3, 5e-4, 1e-2)
#: Trust region: a step moves no vertex by more than this (m), doubled after a step whose decrease is at least
#: 3/4 of the Gauss-Newton model's (up to ``MAX_TRUST_M``), halved after a rejected one; the reflectance changes
#: by at most a factor ``e^0.5`` a step.
START_TRUST_M = 0.05
MAX_TRUST_M = 0.15
MAX_LOG_ALBEDO_STEP = 0.5


def affine_vertices(x: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``[V, 3]`` vertices of the start vertices ``x`` under the parameters ``p`` (module docstring)."""
    c = x.mean(axis=0)
    A = np.asarray(p[:9], dtype=np.float64).reshape(3, 3)
    return c + (x - c) @ A.T + np.asarray(p[9:12], dtype=np.float64)


def _residual(cap, x, p, sigma_ps: float, end_ps: float):
    """``r`` of the module docstring (flattened), or None where the mesh cannot be rendered."""
    rho = float(np.clip(math.exp(p[12]), 0.01, 1.0))
    try:
        cap.set_mesh(affine_vertices(x, p), rho)
        ideal = cap.ideal(0, 0, end_ps)
    except UserInputError:  # (e.g. the trial mesh hides a wall patch from the detector)
        return None
    mu = cap.expected_counts(ideal, cap.dead_time_factor(ideal))
    k = cap.counts_blurred(sigma_ps)
    w = cap.weights(sigma_ps)
    r = (np.sqrt(w) * (cap.blur(mu, end_ps, sigma_ps) - k)).ravel()
    return r if np.all(np.isfinite(r)) else None


def align_affine(cap, vertices: np.ndarray, albedo: float, *, iterations: int, sigma_start_ps: float,
                 sigma_end_ps: float, log=None) -> tuple[np.ndarray, float, list]:
    """Fit the start mesh's affine map and reflectance (module docstring).

    Parameters
    ----------
    cap : CaptureModel
        The capture's forward model, its mesh topology the start's.
    vertices : numpy.ndarray
        ``[V, 3]`` start vertices, m.
    albedo : float
        Start reflectance.
    iterations : int
        Levenberg-Marquardt iterations (each: one Jacobian of 13 renders and one or more trial renders).
    sigma_start_ps, sigma_end_ps : float
        Temporal blur of the first and the last iteration (total spread, ps; geometric in between).

    Returns
    -------
    (vertices [V, 3], albedo, history)
        ``history``: per iteration ``[objective at the iteration's blur after the step, sigma_ps, lambda]``.
    """
    x = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    p = np.concatenate([np.eye(3).ravel(), np.zeros(3), [math.log(max(float(albedo), 0.01))]])
    end = float(sigma_end_ps)
    steps = np.array([FD_STEPS[0]] * 9 + [FD_STEPS[1]] * 3 + [FD_STEPS[2]])
    lam = 1e-2
    trust = START_TRUST_M
    history = []
    for i in range(int(iterations)):
        u = i / max(1, iterations - 1)
        sigma = float(math.exp((1 - u) * math.log(max(sigma_start_ps, end)) + u * math.log(end)))
        r0 = _residual(cap, x, p, sigma, end)
        if r0 is None:
            break
        f0 = 0.5 * float(r0 @ r0)
        J = np.empty((len(r0), len(p)))
        for j in range(len(p)):
            q = p.copy()
            q[j] += steps[j]
            rj = _residual(cap, x, q, sigma, end)
            if rj is None:
                q[j] -= 2 * steps[j]
                rj = _residual(cap, x, q, sigma, end)
                J[:, j] = (r0 - rj) / steps[j] if rj is not None else 0.0
            else:
                J[:, j] = (rj - r0) / steps[j]
        H = J.T @ J
        g = J.T @ r0
        d = np.maximum(np.diag(H), 1e-12 * max(float(np.max(np.diag(H))), 1e-300))
        f_new = f0
        for _ in range(6):
            for _ in range(40):  # (lambda raised until the step's largest vertex displacement is within the trust
                dp = np.linalg.solve(H + lam * np.diag(d), -g)  # radius: the trust-region step, bent to the gradient)
                move = float(np.max(np.linalg.norm(affine_vertices(x, p + dp) - affine_vertices(x, p), axis=1)))
                if move <= trust:
                    break
                lam *= 2
            dp[12] = float(np.clip(dp[12], -MAX_LOG_ALBEDO_STEP, MAX_LOG_ALBEDO_STEP))
            r1 = _residual(cap, x, p + dp, sigma, end)
            f1 = 0.5 * float(r1 @ r1) if r1 is not None else math.inf
            if f1 < f0:
                gain = (f0 - f1) / max(-(g @ dp + 0.5 * dp @ H @ dp), 1e-300)  # actual over predicted decrease
                p = p + dp
                p[12] = math.log(float(np.clip(math.exp(p[12]), 0.01, 1.0)))
                f_new = f1
                if gain > 0.75:  # (the Gauss-Newton model holds: trust it more)
                    lam = max(lam / 3, 1e-7)
                    trust = min(2 * trust, MAX_TRUST_M)
                elif gain < 0.25:  # (it does not: a step closer to the gradient's next time)
                    lam *= 2
                break
            lam *= 4
            trust /= 2
        history.append([f_new, sigma, lam])
        if log is not None:
            log(f"align {i + 1}/{iterations}: sigma {sigma:.0f} ps, objective {f0:.4g} -> {f_new:.4g}, lambda {lam:.2g}")
    return affine_vertices(x, p), float(np.clip(math.exp(p[12]), 0.01, 1.0)), history


#: The realignment's first blur, in end blurs (:func:`realign_carved`: the carved mesh is near; no wide blur needed).
REALIGN_BLUR_FACTOR = 2.0


def realign_iterations(align: int) -> int:
    """Levenberg-Marquardt iterations of the alignment run again on the carved mesh: half the first's ``align``,
    rounded up (none without an alignment)."""
    return (int(align) + 1) // 2


def realign_carved(cap, vertices: np.ndarray, albedo: float, align: int, settings,
                   end_ps: float) -> tuple[np.ndarray, float, dict]:
    """The affine alignment again, on the carved mesh of a free-mesh fit (:func:`realign_iterations` of ``align``,
    the blur from :data:`REALIGN_BLUR_FACTOR` times the end blur ``end_ps`` to it): the first alignment fits an
    under- or over-covering start, whose missing or extra surface it partly explains by a tilt or a shift; on the
    carved mesh, which covers what the counts see, that compensation is undone (docs/fit.md). Returns
    ``(vertices [V, 3] (m), reflectance, record)``, the record holding ``iterations``, ``albedo``, ``history`` (as
    :func:`align_affine`'s) and ``seconds``."""
    import time

    from .optimize import element_size

    cap.set_element_size(element_size(0, settings.iterations, settings.element_size_m))
    cap.keep_blur(end_ps)
    t = time.perf_counter()
    n = realign_iterations(align)
    v1, a1, history = align_affine(cap, vertices, float(albedo), iterations=n,
                                   sigma_start_ps=REALIGN_BLUR_FACTOR * end_ps, sigma_end_ps=end_ps)
    return v1, float(a1), {"iterations": n, "albedo": float(a1), "history": history,
                           "seconds": time.perf_counter() - t}
