"""Render to a noise target: ``transient-mi render --noise-target R``.

An ideal capture feeds a photon budget; its Monte Carlo noise should be a
small part of the photon noise that budget gives (see
:mod:`spad_detector.render_noise` for the ratio and its definition).
Rendering with a noise target works group of spots by group of spots:

1. render the base ``spp`` as ``R0`` independent replicates of ``n = spp / R0``
   samples (``R0 = gcd(spp, variance_replicates)``, at least 2);
2. compute the noise ratio of every spot of the group for the intended
   budget and detector (the scene's ``spad_film``, or the given parameters;
   ``auto_gate`` resolved per spot as ``detect`` does);
3. choose the samples per pixel the ``1/spp`` law says bring the largest
   ratio to :data:`PLAN_MARGIN` x the target (capped at ``max_spp``), discard the pilot and render
   the capture afresh with that many samples (``R0`` replicates with their own
   seeds), one replicate at a time; measure the ratio reached on it.

Discarding the pilot keeps the capture unbiased (see :func:`render_group`).
Every decision depends only on rendered data, so the same seed gives the same
bytes. After the pilot and after each replicate the group's state is written
to ``OUT/.partial/group_NNNNN.npz`` (atomically); ``--resume`` continues from
there replicate by replicate, with the same bytes as an uninterrupted run. The
manifest records, per spot, the pilot's ratio, the samples used and the ratio
reached (``render.noise_target``).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from transient_core.atomic import atomic_file
from transient_core.errors import UserInputError

#: Default cap on samples per pixel per spot.
DEFAULT_MAX_SPP = 1 << 20
#: Hidden directory of a capture being rendered (render_capture: per-spot facts; here: group checkpoints).
PARTIAL_DIR = ".partial"
#: The capture's spp is planned for ``PLAN_MARGIN * target``: the pilot's ratio is itself an estimate, and a
#: plan aimed exactly at the target misses it about half the time by a hair.
PLAN_MARGIN = 0.8


@dataclass
class NoiseTargetSpec:
    """What ``--noise-target`` asks for.

    Attributes
    ----------
    target : float
        Largest acceptable ratio of rendering to photon variance (> 0).
    params : DetectorParams
        Detector model the capture is meant for.
    pulses, exposure_s : optional
        Photon budget per laser spot (one of them, or neither for the laser's default).
    max_spp : int
        Cap on samples per pixel per spot.
    quadrature_target : float, optional
        The target instead of ``target`` where the scene renders with the deterministic quadrature (set by
        :func:`~transient_mi.render_capture.prepare_render` once it knows the estimator): a study's ``"auto"``
        asks 0.1 of Monte Carlo and 0.01 of the quadrature, which refines its elements to it in seconds.
    """

    target: float
    params: object
    pulses: int | None = None
    exposure_s: float | None = None
    max_spp: int = DEFAULT_MAX_SPP
    quadrature_target: float | None = None

    def validate(self, base_spp: int, replicates: int) -> "NoiseTargetSpec":
        t = self.target
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t) or t <= 0:
            raise UserInputError(f"--noise-target {t!r}: must be a finite number > 0 (e.g. 0.1)")
        if replicates < 2:
            raise UserInputError(f"--noise-target needs >= 2 independent replicates, but spp={base_spp} gives "
                                 f"{replicates}: use an spp that is a multiple of the integrator's "
                                 "variance_replicates (default 8)")
        if isinstance(self.max_spp, bool) or not isinstance(self.max_spp, int) or self.max_spp < base_spp:
            raise UserInputError(f"--max-spp {self.max_spp!r}: must be a whole number >= spp ({base_spp})")
        return self

    def to_dict(self) -> dict:
        return {"target": float(self.target), "pulses": self.pulses, "exposure_s": self.exposure_s,
                "max_spp": int(self.max_spp), "detector": self.params.to_dict()}


@dataclass
class GroupState:
    """Merged replicates of one group of spots (one entry per spot)."""

    reps: int
    stats: list
    steady: list
    dropped: list
    frac: list
    invalid: int = 0  # contributions with a NaN/-inf path length (a bug), see TransientResult
    negative: float = 0.0

    @classmethod
    def from_results(cls, results) -> "GroupState":
        from transient_mi.integrators._replicates import ReplicateStats

        return cls(int(results[0].replicates), [ReplicateStats.from_result(r) for r in results],
                   [np.asarray(r.steady, dtype=np.float64).reshape(-1) for r in results],
                   [int(r.dropped_contributions) for r in results], [float(r.dropped_fraction) for r in results],
                   sum(int(r.invalid_contributions) for r in results),
                   min(float(r.negative_fraction) for r in results))

    def merge(self, other: "GroupState") -> None:
        n = self.reps + other.reps
        for g in range(len(self.stats)):
            self.stats[g] = self.stats[g].merge(other.stats[g])
            self.steady[g] = (self.steady[g] * self.reps + other.steady[g] * other.reps) / n
            self.dropped[g] += other.dropped[g]
            self.frac[g] = (self.frac[g] * self.reps + other.frac[g] * other.reps) / n
        self.invalid += other.invalid
        self.negative = min(self.negative, other.negative)
        self.reps = n

    def results(self, shape, samples_per_rep_pixel: int):
        from transient_mi.films.transient_film import TransientResult

        H, W, T = shape
        out = []
        for g, s in enumerate(self.stats):
            var, tvar = s.variance(), s.total_variance()
            out.append(TransientResult(
                histogram=s.mean.reshape(H, W, T), steady=self.steady[g].astype(np.float32).reshape(H, W),
                dropped_contributions=self.dropped[g], dropped_fraction=self.frac[g],
                samples=H * W * samples_per_rep_pixel * self.reps,
                variance=None if var is None else var.reshape(H, W, T),
                total_variance=None if tvar is None else tvar.reshape(H, W), replicates=self.reps,
                invalid_contributions=self.invalid if g == 0 else 0, negative_fraction=self.negative))
        return out

    # ------------------------------------------------------------ checkpoint

    def save(self, path: Path, digest: str) -> None:
        arrays = {"reps": np.int64(self.reps), "digest": np.array(digest), "invalid": np.int64(self.invalid),
                  "negative": np.float64(self.negative)}
        for g, s in enumerate(self.stats):
            m2 = s.m2 if s.m2 is not None else np.zeros_like(s.mean)
            arrays.update({f"mean{g}": s.mean, f"m2{g}": m2, f"tmean{g}": s.total_mean, f"tm2{g}": s.total_m2,
                           f"steady{g}": self.steady[g], f"dropped{g}": np.int64(self.dropped[g]),
                           f"frac{g}": np.float64(self.frac[g]), f"n{g}": np.int64(s.n)})
        path.parent.mkdir(exist_ok=True)
        with atomic_file(path, fsync=True) as tmp:
            with open(tmp, "wb") as f:
                np.savez(f, **arrays)

    @classmethod
    def load(cls, path: Path, digest: str, n_spots: int) -> "GroupState | None":
        from transient_mi.integrators._replicates import ReplicateStats

        if not path.is_file():
            return None
        try:
            z = np.load(path)
            if str(z["digest"]) != digest:
                return None
            stats = [ReplicateStats(int(z[f"n{g}"]), z[f"mean{g}"], z[f"m2{g}"], z[f"tmean{g}"], z[f"tm2{g}"])
                     for g in range(n_spots)]
            return cls(int(z["reps"]), stats, [z[f"steady{g}"] for g in range(n_spots)],
                       [int(z[f"dropped{g}"]) for g in range(n_spots)],
                       [float(z[f"frac{g}"]) for g in range(n_spots)], int(z["invalid"]), float(z["negative"]))
        except Exception:  # a damaged checkpoint is rendered again
            return None


@dataclass
class TargetRun:
    """Per-capture helper: models, budget, the ratio of a spot."""

    spec: NoiseTargetSpec
    manifest: dict
    models: dict = field(default_factory=dict)
    budget: object = None

    def __post_init__(self):
        from spad_detector.budget import resolve_budget
        from spad_detector.stream import resolve_gates

        m = self.manifest
        self.budget = resolve_budget(self.spec.params, m.get("laser"), pulses=self.spec.pulses,
                                     exposure_s=self.spec.exposure_s)
        self._run_params, _, self._spot_gates = resolve_gates(m, self.spec.params)

    def model(self, j: int):
        from spad_detector.stream import spot_model_for

        if j not in self.models:
            self.models[j] = spot_model_for(self.manifest, self._run_params, self._spot_gates, j, self.budget)
        return self.models[j]

    def ratio(self, j: int, stats) -> float:
        var = stats.variance()
        if var is None:
            return math.inf
        return self.headline(j, stats.mean, var, stats.total_variance())

    def headline(self, j: int, histogram: np.ndarray, error: np.ndarray, total_error: np.ndarray | None = None,
                 error_bound: bool = False) -> float:
        """The headline ratio of spot ``j`` (as ``detect`` states it) for ``histogram`` (photons per pulse) and its
        ``error``: a Monte Carlo variance, or with ``error_bound`` a deterministic bound (scaled by the photon
        scale, not its square); ``total_error`` the pixel totals' (optional for a bound)."""
        from spad_detector.render_noise import NoiseRatio

        T = histogram.shape[-1]
        s = self.budget.photon_scale

        def scaled(a):  # a bound scales with the photons, a variance with their square
            return a * s if error_bound else a * s * s

        nr = NoiseRatio(threshold=self.spec.target)
        nr.add_spot(self.model(j), histogram.reshape(-1, T).astype(np.float64) * s,
                    scaled(error.reshape(-1, T).astype(np.float64)), self.budget.n_pulses,
                    total_variance=None if total_error is None else scaled(
                        np.reshape(total_error, -1).astype(np.float64)),
                    error_bound=error_bound)
        return float(nr.report()["ratio"])


def rendered_spp(ideal_dir, default: int) -> int:
    """Largest samples per pixel any spot of a rendered capture received: from the manifest's
    ``render.noise_target.spots`` (written by a noise-target render), else ``default`` (the spp asked for)."""
    import json

    m = json.loads((Path(ideal_dir) / "manifest.json").read_text())
    nt = (m.get("render") or {}).get("noise_target") or {}
    spots = [sp for sp in nt.get("spots") or [] if sp and "spp" in sp]  # (quadrature spots have no spp)
    return max(sp["spp"] for sp in spots) if spots else int(default)


def render_group(job, run: TargetRun, group: list[int], seed: int, digest: str, log=None, progress=None):
    """Render one group of spots to the noise target; returns ``(results, info per spot, checkpoint path)``.

    Two stages, so that the capture stays unbiased: a *pilot* render at the
    base ``spp`` (``R0`` replicates) only decides how many samples are needed
    (``spp * ratio / (PLAN_MARGIN * target)``, the ``1/spp`` law, rounded up to
    a multiple of ``R0``, capped at ``max_spp``); the capture is then a fresh render with
    that many samples, ``R0`` replicates with their own seeds, rendered and
    checkpointed one replicate at a time. (Keeping the pilot, or adding
    samples until an estimate looks good enough, would make the number of
    samples depend on the values it averages: a stopping-rule bias.) The ratio
    the capture reaches is measured on the capture itself and reported as it
    is, met or not.

    ``job`` is a :class:`transient_mi.render_capture.RenderJob` whose ``noise_target`` is set.
    """
    from spad_detector.render_noise import spp_for_threshold
    from transient_mi.integrators._replicates import DEFAULT_REPLICATES, effective_replicates

    spec = run.spec
    m = job.manifest
    H, W, T = m["height"], m["width"], m["time"]["n_bins"]
    f = getattr(job.integrator, "replicates_for", None)
    R0 = effective_replicates(job.spp, f(True) if f is not None else DEFAULT_REPLICATES)
    ckpt = job.ideal_dir / PARTIAL_DIR / f"group_{group[0]:05d}.npz"
    camera = m["capture"] == "camera"
    name = f"spots {group[0]}-{group[-1]}" if len(group) > 1 else f"spot {group[0]}"
    say = log or (lambda line: None)

    def render(reps: int, spp: int, offset: int) -> GroupState:
        kw = dict(seed=seed, spp=spp, progress=progress, replicate_offset=offset, replicates=reps)
        if len(group) == 1:
            res = [job.integrator.render_transient(job.scene, job.sensor, spot=None if camera else group[0], **kw)]
        else:
            res = job.integrator.render_transient(job.scene, job.sensor, spots=group, **kw)
        return GroupState.from_results(res)

    saved = _load_plan(ckpt, digest, len(group)) if job.resume else None
    if saved is None:
        t0 = time.perf_counter()
        pilot = render(R0, job.spp, 0)
        rate = job.spp / max(time.perf_counter() - t0, 1e-9)
        pilot_ratios = [run.ratio(j, pilot.stats[g]) for g, j in enumerate(group)]
        worst = max(pilot_ratios)
        spp_final = spp_for_threshold(job.spp, worst, PLAN_MARGIN * spec.target, R0)
        spp_final = min(spp_final, R0 * (spec.max_spp // R0))
        plan = {"pilot_spp": job.spp, "pilot_ratio": worst, "spp": spp_final, "rate": rate}
        state = None
        _save_plan(ckpt, digest, plan, None)
        say(f"{name}: pilot at spp {job.spp}: noise ratio {worst:.3g} (target {spec.target:g}); rendering the "
            f"capture with spp {spp_final}, ~{spp_final / rate:.0f} s")
    else:
        plan, state = saved
        rate = plan["rate"]
        say(f"{name}: resumed: spp {plan['spp']}, {0 if state is None else state.reps} of {R0} replicates done")
    n = plan["spp"] // R0
    t0 = time.perf_counter()
    done0 = 0 if state is None else state.reps
    for r in range(done0, R0):
        st = render(1, n, R0 + r)
        if state is None:
            state = st
        else:
            state.merge(st)
        _save_plan(ckpt, digest, plan, state)
        if r + 1 < R0:
            per_rep = (time.perf_counter() - t0) / (r + 1 - done0)
            say(f"{name}: replicate {r + 1}/{R0} of spp {plan['spp']} done, ~{per_rep * (R0 - r - 1):.0f} s left")
    ratios = [run.ratio(j, state.stats[g]) for g, j in enumerate(group)]
    worst = max(ratios)
    info = [{"spp": plan["spp"], "replicates": R0, "ratio": ratios[g], "met": ratios[g] <= spec.target,
             "pilot_spp": plan["pilot_spp"], "pilot_ratio": plan["pilot_ratio"]} for g in range(len(group))]
    say(f"{name}: spp {plan['spp']}, noise ratio {worst:.3g} "
        + ("(target met)" if worst <= spec.target else
           f"(target {spec.target:g} NOT met{': max_spp reached' if plan['spp'] >= spec.max_spp - R0 else ''})"))
    return state.results((H, W, T), n), info, ckpt


def _save_plan(path: Path, digest: str, plan: dict, state: GroupState | None) -> None:
    import json

    meta = json.dumps({"digest": digest, "plan": plan}, sort_keys=True)
    if state is not None:
        state.save(path, meta)
        return
    path.parent.mkdir(exist_ok=True)
    with atomic_file(path, fsync=True) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, reps=np.int64(0), digest=np.array(meta))


def _load_plan(path: Path, digest: str, n_spots: int):
    """``(plan, state)`` from a checkpoint of this configuration, or None."""
    import json

    if not path.is_file():
        return None
    try:
        z = np.load(path)
        meta = json.loads(str(z["digest"]))
    except Exception:
        return None
    if meta.get("digest") != digest:
        return None
    if int(z["reps"]) == 0:
        return meta["plan"], None
    state = GroupState.load(path, str(z["digest"]), n_spots)
    return (meta["plan"], state) if state is not None else None
