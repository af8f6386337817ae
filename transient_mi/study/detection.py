"""Detection without the disk: one ideal capture, many detector settings, spot by spot in memory.

A photon-budget study detects the same ideal capture dozens of times; writing
and re-reading an EXR counts stack for each would cost more than the physics.
:class:`Detection` produces, for one detector setting and budget, exactly the
counts :func:`spad_detector.detect_stack` would write (the same
per-spot gates, photon scale, engine choice and random stream
``SeedSequence(seed, spawn_key=(spot,))``; a test checks byte equality), so
any row of a study can be reproduced on disk with ``transient-mi detect``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from transient_core.errors import UserInputError
from transient_core.stack import StackError, missing_spots, read_intensity, read_manifest, spot_filename

#: Ideal captures up to this size (float32 bytes) are kept in memory; larger ones are re-read per spot.
CACHE_LIMIT_BYTES = 1 << 30


class IdealCapture:
    """An ideal capture directory (expected photons per pulse per bin), read spot by spot.

    Spots are cached in memory when the whole capture is at most
    ``cache_limit_bytes``; otherwise every :meth:`spot` call reads the file
    (memory bounded by one spot).
    """

    def __init__(self, path, cache_limit_bytes: int = CACHE_LIMIT_BYTES):
        self.path = Path(path)
        m = read_manifest(self.path)
        if m["kind"] != "ideal" or m["quantity"] != "photons_per_pulse":
            raise UserInputError(f"{self.path}: kind={m['kind']!r}, quantity={m['quantity']!r}; a study needs an "
                                 "ideal NLOS capture (expected photons per pulse)")
        missing = missing_spots(self.path, m)
        if missing or m["status"] != "complete":
            raise StackError(f"{self.path}: the capture is incomplete ({len(missing)} spot files missing)")
        self.manifest = m
        t = m["time"]
        self.shape = (m["n_files"], m["height"], m["width"], t["n_bins"])
        self._cache: dict[int, np.ndarray] | None = {} if 4 * int(np.prod(self.shape)) <= cache_limit_bytes \
            else None

    @property
    def n_files(self) -> int:
        return self.shape[0]

    def spot(self, j: int) -> np.ndarray:
        """Spot ``j``: float32 ``[H, W, T]`` (read-only when cached)."""
        if self._cache is not None and j in self._cache:
            return self._cache[j]
        data = read_intensity(self.path, j, self.manifest)
        if self._cache is not None:
            data.setflags(write=False)
            self._cache[j] = data
        return data


class Detection:
    """One detector setting and photon budget applied to an :class:`IdealCapture`.

    Parameters
    ----------
    ideal : IdealCapture
    params : DetectorParams
        May use ``auto_gate`` (resolved per laser spot for array captures, as
        :func:`~spad_detector.detect_stack` does).
    exposure_s, pulses : optional
        The budget per laser spot (one of them).
    engine : {"auto", "analytic", "exact"}
    """

    def __init__(self, ideal: IdealCapture, params, *, exposure_s: float | None = None, pulses: int | None = None,
                 engine: str = "auto"):
        from spad_detector.budget import resolve_budget
        from spad_detector.detect import check_engine
        from spad_detector.gate import auto_gate

        self.ideal = ideal
        self.params = params.validate()
        self.engine = check_engine(engine)
        m = ideal.manifest
        self.budget = resolve_budget(self.params, m.get("laser"), pulses=pulses, exposure_s=exposure_s)
        if self.params.crosstalk_prob > 0 and m["capture"] == "confocal":
            raise UserInputError(f"crosstalk_prob={self.params.crosstalk_prob!r}: cannot be modelled on a confocal "
                                 "capture (its pixels were recorded under different laser spots)")
        p = self.params
        n = m["n_files"]
        if p.auto_gate:
            if m["capture"] == "array":
                gates = [auto_gate(m, p.gate_transition_ps, p.auto_gate_depth_min_m, p.auto_gate_depth_max_m, spot=j)
                         for j in range(n)]
            else:
                gates = [auto_gate(m, p.gate_transition_ps, p.auto_gate_depth_min_m, p.auto_gate_depth_max_m)] * n
            self.spot_params = [p.replace(gate_open_ps=g[0], gate_close_ps=g[1], auto_gate=False) for g in gates]
        else:
            self.spot_params = [p] * n
        self._models: dict[int, object] = {}
        self.manifest = self._counts_manifest()

    @property
    def n_pulses(self) -> int:
        return self.budget.n_pulses

    def model(self, j: int):
        """The :class:`~spad_detector.model.DetectorModel` of spot ``j`` (its own gate)."""
        if j not in self._models:
            from spad_detector.model import build_model

            t = self.ideal.manifest["time"]
            self._models[j] = build_model(self.spot_params[j], bin_width_ps=t["bin_width_ps"], n_bins=t["n_bins"],
                                          t0_ps=t["t0_ps"], repetition_rate_hz=self.budget.repetition_rate_hz)
        return self._models[j]

    def scaled_ideal(self, j: int) -> np.ndarray:
        """Spot ``j`` as float64 ``[H*W, T]`` photons per pulse with the budget's photon scale applied."""
        from spad_detector.detect import check_ideal

        _, H, W, T = self.ideal.shape
        arr = check_ideal(self.ideal.spot(j), where=f"{self.ideal.path / spot_filename(j)}")
        if self.budget.photon_scale != 1.0:
            arr = arr * self.budget.photon_scale
        return arr.reshape(H * W, T)

    def render_noise(self) -> dict:
        """How much of this budget's count variance is the ideal capture's rendering noise
        (:mod:`spad_detector.render_noise`; ``available: false`` without stored variance)."""
        from transient_core.stack import has_error_bound, has_variance, is_error_bound, read_error_bound, read_variance
        from spad_detector.render_noise import NoiseRatio, unavailable

        m = self.ideal.manifest
        bound_kind = is_error_bound(m)  # a pure quadrature capture: the "variance" files hold its error bound
        two_parts = has_error_bound(m) and not bound_kind  # quadrature + Monte Carlo remainder
        if not has_variance(m) and not two_parts:
            return unavailable("the ideal capture stores no variance")
        if m.get("channels"):
            return unavailable("a multi-channel capture stores per-channel variances, not its intensity's")
        _, H, W, T = self.ideal.shape
        nr = NoiseRatio()
        sc = self.budget.photon_scale
        vs = sc if bound_kind else sc ** 2  # a bound scales with the photons, a variance with their square
        for j in range(self.ideal.n_files):
            if has_variance(m):
                var, tvar = read_variance(self.ideal.path, j, m)
            else:
                var, tvar = np.zeros((H, W, T), np.float32), np.zeros((H, W), np.float32)
            bnd = tbnd = None
            if two_parts:
                bnd, tbnd = read_error_bound(self.ideal.path, j, m)
                bnd = bnd.reshape(H * W, T).astype(np.float64) * sc
                tbnd = tbnd.reshape(-1).astype(np.float64) * sc
            nr.add_spot(self.model(j), self.scaled_ideal(j), var.reshape(H * W, T).astype(np.float64) * vs,
                        self.n_pulses, total_variance=tvar.reshape(-1).astype(np.float64) * vs,
                        error_bound=bound_kind, bound=bnd, total_bound=tbnd)
        rep = nr.report()
        # rendering-noise ceiling on the SNR (independent of the budget): mu / sqrt(V) = 1 / relative error
        rep["snr_ceiling_bins"] = float(np.sqrt(nr.mu2_sum / nr.var_sum)) if nr.var_sum > 0 else None
        return rep

    def counts(self, j: int, seed: int) -> tuple[np.ndarray, dict]:
        """Counts of spot ``j`` for detection seed ``seed``: uint32 ``[H, W, T]`` and the engine's info."""
        from spad_detector.detect import run_spot, to_uint32
        from spad_detector.stream import spot_rng

        _, H, W, T = self.ideal.shape
        counts, info = run_spot(self.model(j), self.scaled_ideal(j), self.n_pulses, spot_rng(seed, j), self.engine,
                                (H, W))
        return to_uint32(counts, where=spot_filename(j)).reshape(H, W, T), info

    def _counts_manifest(self) -> dict:
        m = dict(self.ideal.manifest)
        m.update(kind="counts", quantity="counts", status="complete", laser=self.budget.laser,
                 detector={**self.params.to_dict(), "pulses": self.n_pulses, "exposure_s": self.budget.exposure_s,
                           "engine": self.engine})
        return m

    def capture(self, seed: int, on_spot=None):
        """A :class:`recon.Capture` whose spots are detected on demand (memory: one spot at a time).

        ``on_spot(j, counts, info)`` is called after spot ``j`` is detected;
        ``info`` is the engine's, plus ``detect_s`` (seconds spent).
        """
        import time

        from recon.capture import Capture

        def load(j: int) -> np.ndarray:
            t0 = time.perf_counter()
            c, info = self.counts(j, seed)
            if on_spot is not None:
                on_spot(j, c, dict(info, detect_s=time.perf_counter() - t0))
            return c

        return Capture.from_manifest(self.manifest, load, source=f"{self.ideal.path} (detected in memory)")
