r"""The optimiser of ``transient-mi fit --model mesh``: Adam on the regularised objective, coarse to fine in
time and in mesh resolution.

Per iteration (global index ``i`` of ``n``): the capture's objective at this iteration's temporal blur
(:func:`~transient_mi.fit.optimize.sigma_schedule`, as the other models) and its vertex and reflectance
gradient (:meth:`~transient_mi.fit.capture_model.CaptureModel.backward`), plus the regularisers
(:meth:`~transient_mi.fit.mesh_model.MeshModel.regularization`), pulled back to ``u`` through the large-steps
parametrisation. Adam with a *uniform* second moment for the vertex block (``moments="uniform"``, the default;
Nicolet et al. 2021: the largest of the coordinates' second moments, one scalar): per-coordinate Adam would give
a vertex whose elements receive almost no light (a tiny gradient) a full step; the uniform moment keeps the
vertices' steps proportional to their gradients. ``moments="vertex"``: one moment per vertex (the mean of its
three coordinates'), floored at a thousandth of the largest: every vertex with a real gradient moves by about
the step. The reflectance has its own moment (per face with ``reflectance="face"``, floored at a thousandth of
the largest). Step sizes decay on a cosine
(:func:`~transient_mi.fit.optimize.step_scale`); the result is the mean of the last quarter's iterates (within
the last stage).

Stages: the mesh is subdivided (every triangle in four, :func:`~transient_mi.fit.mesh_start.subdivide`) at the
iterations ``stage_starts`` (default: at 50 % of the iterations, once): the first stage fits the coarse shape
while the blur is wide, the second adds detail. Adam's moments restart at a new stage.

Visibility: the quadrature's vertex derivative is the *interior* one (visibility held fixed,
:mod:`transient_mi.integrators._nlos_quadrature_geom`). An open mesh's own boundary is not a visibility event:
moving a boundary vertex grows or shrinks the surface, and the area change is in the derivative, so the
silhouette of an open surface seen from the wall is fitted. What is not differentiated is one part of the
mesh starting or stopping to hide another from the wall or a laser spot (self-occlusion): the fit starts
from the front surface (a height field facing the wall, no self-occlusion), the large-steps smoothing moves
hidden vertices with their visible neighbours, and the regularisers keep the rest in place.

The device's view: the detector must see every wall patch (the scene refuses a mesh that hides one,
:class:`~transient_mi.sensors._nlos_setup.NLOSSetup`), and the true shape does. An Adam step that would move
the mesh into a line of sight from the detector to the wall is halved until it does not (at most
``MAX_STEP_HALVINGS`` times, then the iterate stays where it was), as the alignment counts such a trial mesh as
a rise of the objective; found on the generated chair and holed plate (``transient_mi.scenes.topology``), whose
fits stretched the mesh sideways towards the detector.
"""

from __future__ import annotations

import time

import numpy as np

from .optimize import FitState, resolve_spp, sigma_schedule, step_scale

__all__ = ["run_mesh_adam", "regularized_objective"]

#: An Adam step whose mesh hides a wall patch from the detector is halved at most this many times.
MAX_STEP_HALVINGS = 6


def hides_a_wall_patch(capture, vertices: np.ndarray, albedo: float) -> bool:
    """Whether the mesh ``vertices [V, 3]`` (m) hides a wall patch from the detector (the scene's own check, a
    few ray tests; the mesh is left set)."""
    from transient_core.errors import UserInputError

    capture.set_mesh(vertices, albedo)
    capture.sensor.forget_nlos_setup()
    try:
        capture.sensor.nlos_setup(capture.scene)
    except UserInputError:
        return True
    return False


def _keep_the_view(model, capture, theta: np.ndarray, new: np.ndarray) -> np.ndarray:
    """``new``, or the step from ``theta`` towards it halved until its mesh hides no wall patch (module
    docstring)."""
    step = new - theta
    for _ in range(MAX_STEP_HALVINGS + 1):
        cand = theta + step
        if not hides_a_wall_patch(capture, model.vertices(cand), model.albedo(cand)):
            return cand
        step = 0.5 * step
    return theta


def fit_parameters(model, capture, state) -> np.ndarray:
    """The fit's parameters: the mean of the tail's iterates (:meth:`FitState.result`), or the last iterate where
    that mean's mesh hides a wall patch (every iterate was kept clear of the view, their mean need not be)."""
    theta = state.result()
    if state.tail_count and hides_a_wall_patch(capture, model.vertices(theta), model.albedo(theta)):
        return np.asarray(state.theta, dtype=np.float64)
    return theta


def regularized_objective(model, capture, theta, sigma_ps: float, *, end_ps: float | None = None, seed: int = 0,
                          spp: int = 0, gradient: bool = True):
    """``(data + S R, data, S R, dtheta or None)`` of ``theta`` at the temporal blur ``sigma_ps``, rendered at
    ``end_ps`` (default: the detector's jitter; ``sigma_ps >= end_ps``) as :func:`run_mesh_adam` does."""
    end = capture.jitter_sigma_ps if end_ps is None else float(end_ps)
    capture.set_mesh(model.vertices(theta), model.albedo(theta))
    spp_d, spp_r = resolve_spp_for(capture, spp)
    ideal = capture.ideal(seed, spp_r, end)
    factor = capture.dead_time_factor(ideal)
    mu = capture.expected_counts(ideal, factor)
    data, resid = capture.objective(capture.blur(mu, end, sigma_ps), sigma_ps)
    reg, _ = model.total_regularization(theta)
    g = None
    if gradient:
        gv, ga = capture.backward(capture.blur(resid, end, sigma_ps), ideal, seed + 1, spp_d, end, factor)
        g = model.gradient(theta, gv, ga)
    return data + reg, data, reg, g


def resolve_spp_for(capture, spp: int) -> tuple[int, int]:
    from .optimize import FitSettings

    return resolve_spp(FitSettings(spp=spp), capture.width * capture.height)


def _set_element_size(capture, i: int, n: int, end_m: float) -> None:
    if hasattr(capture, "set_element_size"):  # (the quadrature's coarse to fine, where the forward model has it)
        from .optimize import element_size

        capture.set_element_size(element_size(i, n, end_m))


def run_mesh_adam(model, capture, state: FitState, settings, *, stage_start: int = 0, stop: int | None = None,
                  progress=None, checkpoint=None) -> FitState:
    """Optimise ``state.theta`` in place from ``state.iteration`` to ``stop`` (default ``settings.iterations``,
    the global count the schedules run over) for a stage that began at ``stage_start`` (Adam's bias correction
    counts from there). ``state.v`` holds ``[v_vertices, v_albedo]`` (the vertices' uniform or per-vertex moments,
    then one per reflectance value: one, or one per face).
    ``progress(i, n, objective)`` after each iteration; ``checkpoint(state)`` every
    ``settings.checkpoint_every`` iterations and at ``stop``."""
    n = settings.iterations
    stop = n if stop is None else int(stop)
    theta = np.asarray(state.theta, dtype=np.float64)
    m = np.asarray(state.m, dtype=np.float64) if state.m else np.zeros_like(theta)
    v2 = np.asarray(state.v, dtype=np.float64) if state.v else np.zeros(2)
    b1, b2 = settings.beta1, settings.beta2
    end = max(settings.sigma_end_ps, capture.jitter_sigma_ps)
    capture.keep_blur(end)
    spp, spp_residual = resolve_spp(settings, capture.width * capture.height)
    tail_from = n - int(round(settings.tail_fraction * n))
    for i in range(state.iteration, stop):
        t0 = time.perf_counter()
        sigma = sigma_schedule(i, n, settings.sigma_start_ps, end)
        _set_element_size(capture, i, n, settings.element_size_m)
        x = model.vertices(theta)
        capture.set_mesh(x, model.albedo(theta))
        seed = 2 * (settings.seed * 1_000_003 + i)
        ideal_end = capture.ideal(seed, spp_residual, end)
        factor = capture.dead_time_factor(ideal_end)
        mu_end = capture.expected_counts(ideal_end, factor)
        obj_end, _ = capture.objective(mu_end, end)
        obj, resid = capture.objective(capture.blur(mu_end, end, sigma), sigma)
        reg, _ = model.total_regularization(theta, x)
        gv, ga = capture.backward(capture.blur(resid, end, sigma), ideal_end, seed + 1, spp, end, factor)
        g = model.gradient(theta, gv, ga)
        g = np.where(np.isfinite(g), g, 0.0)
        m = b1 * m + (1 - b1) * g
        nu = getattr(model, "n_u", len(g) - 1)
        gu, ga2 = g[:nu], g[nu:]  # (the vertex block, then the reflectance: one value or one per face)
        per_vertex = getattr(model, "moments", "uniform") == "vertex"
        sq = np.mean((gu * gu).reshape(-1, 3), axis=1) if per_vertex else np.array([float(np.max(gu * gu))])
        na = len(ga2)
        if len(v2) != len(sq) + na:
            v2 = np.zeros(len(sq) + na)
        # (the reflectance: one moment per value, as Adam's own; per face, floored as the vertices' per-vertex ones:
        # a face's reflectance moves at the step where its data agree, however faint its light)
        v2 = b2 * v2 + (1 - b2) * np.concatenate([sq, ga2 * ga2])
        k = i - stage_start + 1
        mh = m / (1 - b1 ** k)
        vh = v2 / (1 - b2 ** k)
        nv = len(vh) - na
        dv = np.repeat(np.sqrt(vh[:nv]), 3) if per_vertex else np.full(len(gu), np.sqrt(vh[0]))
        if per_vertex:  # (a floor: vertices whose gradient is a millionth of the largest stay put)
            dv = np.maximum(dv, 1e-3 * float(np.max(dv)))
        da = np.sqrt(vh[nv:])
        if na > 1:
            da = np.maximum(da, 1e-3 * float(np.max(da)))
        denom = np.concatenate([dv, da]) + 1e-30
        theta = _keep_the_view(model, capture, theta,
                               np.clip(theta - step_scale(i, n) * model.step * mh / denom, model.lower, model.upper))
        if i >= tail_from:
            state.tail_sum = (np.asarray(state.tail_sum) + theta).tolist() if state.tail_count else theta.tolist()
            state.tail_count += 1
        state.theta, state.m, state.v, state.iteration = theta.tolist(), m.tolist(), v2.tolist(), i + 1
        dt = time.perf_counter() - t0
        state.elapsed_s += dt
        state.history.append([float(obj + reg), float(sigma), float(dt), float(obj_end + reg)])
        if progress is not None:
            progress(i + 1, n, obj + reg)
        if checkpoint is not None and ((i + 1) % settings.checkpoint_every == 0 or i + 1 == stop):
            checkpoint(state)
    return state
