"""The fit's optimiser: Adam on the capture's objective, coarse to fine in time, with checkpoints.

With the Monte Carlo estimator each iteration renders the model twice with independent seeds
(:mod:`transient_mi.fit.capture_model`): one render gives the residual, the other the derivative, so the step is
an unbiased estimate of the objective's gradient; Adam (Kingma and Ba 2015) averages the Monte Carlo noise out.
With the quadrature (``estimator="quadrature"``, deterministic) the residual and the derivative are exact for
the quadrature's primal, the same inputs give the same bytes, and the elements are coarse (twice
``element_size_m``) for the first half of the iterations. Adam is kept for both (same schedule): the objective
changes with the temporal blur every iteration, which a quasi-Newton method's curvature pairs (L-BFGS) would
mix up, and the per-parameter step sizes in degrees and millimetres keep joints and placement balanced. Step sizes are per
parameter, in the parameter's units (``model.step``: about 1.5 degrees and 4 mm at the start), and decay
on a cosine to a tenth; parameters are clipped to their bounds. The fit is the mean of the iterates of
the last quarter (Polyak-Ruppert averaging: the iterates wander by the gradient's Monte Carlo noise
around the optimum; their mean wanders less).

Coarse to fine: the temporal blur of model and counts starts at ``sigma_start_ps`` (a basin of
attraction several centimetres wide: limbs far from their place still overlap the data in time) and
shrinks to ``sigma_end_ps`` (30 ps, 9 mm of path; not below the detector's jitter) by 60 % of the
iterations. Model and counts are always blurred alike, so the blur costs resolution, not accuracy; a
blur as narrow as the jitter (10.6 ps) makes each iteration's gradient much noisier at the same spp.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from transient_core.atomic import atomic_file

__all__ = ["FitSettings", "FitState", "run_adam", "ADAM_ITERATIONS", "OPTIMIZERS"]

#: Adam's iterations when none are given.
ADAM_ITERATIONS = 300
#: ``FitSettings.optimizer``'s values.
OPTIMIZERS = ("auto", "adam", "gauss_newton")


@dataclass(frozen=True)
class FitSettings:
    """Optimiser settings (defaults: the paper's capture in about a minute on 2 cores: the quadrature and
    Gauss-Newton; with Monte Carlo and Adam about 10 minutes)."""

    iterations: int | None = None  # None: 300 with Adam, GN_ITERATIONS (16) with Gauss-Newton
    spp: int = 0  # the derivative render's samples per pixel (0: 8192 per spot spread over the pixels, 4 to 64)
    spp_residual: int = 0  # the residual render's (0: 4 x spp; cheaper, no derivative)
    sigma_start_ps: float = 250.0
    sigma_end_ps: float = 30.0  # (at least the detector's jitter)
    seed: int = 0
    checkpoint_every: int = 25
    tail_fraction: float = 0.25  # the fit is the mean of the last quarter's iterates (Polyak averaging)
    beta1: float = 0.9
    beta2: float = 0.99
    estimator: str = "auto"  # the quadrature where the scene allows it, else monte_carlo; or either by name
    element_size_m: float = 0.03  # the quadrature's elements at the end (twice as large for the first half)
    optimizer: str = "auto"  # gauss_newton with the quadrature, adam with Monte Carlo; or either by name

    def n_iterations(self, optimizer: str) -> int:
        """``iterations``, or the default of ``optimizer`` (``adam`` or ``gauss_newton``) when None."""
        if self.iterations is not None:
            return int(self.iterations)
        from .gauss_newton import GN_ITERATIONS

        return GN_ITERATIONS if optimizer == "gauss_newton" else ADAM_ITERATIONS


@dataclass
class FitState:
    """Where an optimisation stands (what a checkpoint holds)."""

    theta: list
    iteration: int = 0
    m: list = field(default_factory=list)
    v: list = field(default_factory=list)
    history: list = field(default_factory=list)  # per iteration: objective, sigma_ps, seconds, objective at the end blur
    elapsed_s: float = 0.0
    tail_sum: list = field(default_factory=list)  # sum of the iterates of the averaged tail
    tail_count: int = 0
    lam: float = 1e-2  # Gauss-Newton's damping (Levenberg-Marquardt)
    converged_stage: int | None = None  # Gauss-Newton: the last blur stage at which no step lowered the objective

    def result(self) -> "np.ndarray":
        """The fit: the mean of the tail's iterates (the last iterate when no tail was averaged)."""
        if self.tail_count:
            return np.asarray(self.tail_sum, dtype=np.float64) / self.tail_count
        return np.asarray(self.theta, dtype=np.float64)

    def save(self, path: Path) -> None:
        with atomic_file(path) as tmp:
            Path(tmp).write_text(json.dumps(asdict(self)) + "\n")

    @classmethod
    def load(cls, path: Path) -> "FitState":
        return cls(**json.loads(Path(path).read_text()))


def resolve_spp(settings: FitSettings, n_pixels: int) -> tuple[int, int]:
    """``(spp, spp_residual)`` for a capture of ``n_pixels`` pixels (the settings' zeros chosen)."""
    spp = settings.spp or max(4, min(64, 8192 // max(1, n_pixels)))
    return spp, settings.spp_residual or 4 * spp


def sigma_schedule(i: int, n: int, start_ps: float, end_ps: float) -> float:
    """Temporal blur at iteration ``i`` of ``n``: ``start`` shrinking quadratically to ``end`` at 60 %."""
    u = min(1.0, i / max(1.0, 0.6 * n))
    return end_ps + (max(start_ps, end_ps) - end_ps) * (1.0 - u) ** 2


def element_size(i: int, n: int, end_m: float) -> float:
    """The quadrature's element size at iteration ``i`` of ``n``: twice ``end_m`` for the first half, then
    ``end_m`` (coarse to fine: while the blur is wide a coarse mesh of elements resolves the light)."""
    return 2.0 * end_m if i < n // 2 else end_m


def step_scale(i: int, n: int) -> float:
    """Step size factor: a cosine from 1 to 0.1."""
    return 0.1 + 0.45 * (1.0 + math.cos(math.pi * min(i, n) / max(n, 1)))


def run_adam(model, capture, state: FitState, settings: FitSettings, *, progress=None, checkpoint=None,
             log=None) -> FitState:
    """Optimise ``state.theta`` in place from ``state.iteration`` to ``settings.n_iterations("adam")``.

    ``progress(i, n, objective)`` is called after each iteration; ``checkpoint(state)`` every
    ``settings.checkpoint_every`` iterations and at the end.
    """
    n = settings.n_iterations("adam")
    theta = np.asarray(state.theta, dtype=np.float64)
    m = np.asarray(state.m, dtype=np.float64) if state.m else np.zeros_like(theta)
    v = np.asarray(state.v, dtype=np.float64) if state.v else np.zeros_like(theta)
    b1, b2 = settings.beta1, settings.beta2
    end = max(settings.sigma_end_ps, capture.jitter_sigma_ps)
    capture.keep_blur(end)
    spp, spp_residual = resolve_spp(settings, capture.width * capture.height)
    for i in range(state.iteration, n):
        t0 = time.perf_counter()
        sigma = sigma_schedule(i, n, settings.sigma_start_ps, end)
        capture.set_mesh(model.vertices(theta), model.albedo(theta))
        capture.set_element_size(element_size(i, n, settings.element_size_m))
        seed = 2 * (settings.seed * 1_000_003 + i)
        # The renders always use the final blur (the film's kernel; changing it would recompile the kernels);
        # the coarser blur of this iteration is a Gaussian convolution of the expected counts (and, for the
        # derivative, of the residual: the blur is its own adjoint). One residual render gives the objective
        # at the final blur (comparable across iterations: loss.png) and the residual at this iteration's.
        ideal_end = capture.ideal(seed, spp_residual, end)
        factor = capture.dead_time_factor(ideal_end)
        mu_end = capture.expected_counts(ideal_end, factor)
        obj_end, _ = capture.objective(mu_end, end)
        obj, resid = capture.objective(capture.blur(mu_end, end, sigma), sigma)
        gv, ga = capture.backward(capture.blur(resid, end, sigma), ideal_end, seed + 1, spp, end, factor)
        g = model.gradient(theta, gv, ga, area_term=capture.estimator != "quadrature")
        g = np.where(np.isfinite(g), g, 0.0)
        m = b1 * m + (1 - b1) * g
        v = b2 * v + (1 - b2) * g * g
        mh = m / (1 - b1 ** (i + 1))
        vh = v / (1 - b2 ** (i + 1))
        theta = theta - step_scale(i, n) * model.step * mh / (np.sqrt(vh) + 1e-30)
        theta = np.clip(theta, model.lower, model.upper)
        if i >= n - int(round(settings.tail_fraction * n)):
            state.tail_sum = (np.asarray(state.tail_sum) + theta).tolist() if state.tail_count else theta.tolist()
            state.tail_count += 1
        state.theta, state.m, state.v, state.iteration = theta.tolist(), m.tolist(), v.tolist(), i + 1
        dt = time.perf_counter() - t0
        state.elapsed_s += dt
        state.history.append([float(obj), float(sigma), float(dt), float(obj_end)])
        if progress is not None:
            progress(i + 1, n, obj)
        if checkpoint is not None and ((i + 1) % settings.checkpoint_every == 0 or i + 1 == n):
            checkpoint(state)
    return state
