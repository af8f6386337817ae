"""``detect``: ideal photons per pulse -> photon counts, on in-memory arrays."""

from __future__ import annotations

import numbers

import numpy as np

from transient_core.errors import UserInputError

from .engines import estimated_events, is_exact, run_analytic, run_exact
from .model import DetectorModel, build_model
from .params import DEFAULT_PULSES, ENGINES, DetectorParams

#: ``engine="auto"`` runs the exact engine when the analytic one would approximate and the
#: exact one would simulate at most this many triggering events per spot.
AUTO_EXACT_MAX_EVENTS = 2e7


def check_ideal(ideal, where: str = "ideal") -> np.ndarray:
    """Return ``ideal`` as float64 after checking it is finite and >= 0 (UserInputError otherwise)."""
    arr = np.asarray(ideal)
    if arr.dtype.kind not in "fiu":
        raise UserInputError(f"{where}: dtype {arr.dtype} is not numeric")
    arr = arr.astype(np.float64, copy=False)
    if arr.ndim == 0 or arr.shape[-1] == 0:
        raise UserInputError(f"{where}: shape {arr.shape}; need at least one time bin on the last axis")
    bad = ~np.isfinite(arr) | (arr < 0)
    if np.any(bad):
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        raise UserInputError(f"{where}[{', '.join(map(str, idx))}] = {float(arr[idx])!r}: expected photons per pulse "
                             "must be finite and >= 0")
    return arr


def check_pulses(n_pulses) -> int:
    if isinstance(n_pulses, bool) or not (isinstance(n_pulses, numbers.Integral) or (
            isinstance(n_pulses, float) and n_pulses.is_integer())) or int(n_pulses) < 1:
        raise UserInputError(f"n_pulses={n_pulses!r}: must be a whole number >= 1")
    return int(n_pulses)


def check_engine(engine: str) -> str:
    if engine not in ENGINES:
        raise UserInputError(f"engine={engine!r}: allowed {', '.join(ENGINES)}")
    return engine


def choose_engine(engine: str, model: DetectorModel, ideal2d: np.ndarray, n_pulses: int) -> str:
    """Resolve ``"auto"``: analytic when it is exact, else exact when affordable, else analytic."""
    if engine != "auto":
        return engine
    if is_exact(model, ideal2d, n_pulses):
        return "analytic"
    if estimated_events(model, ideal2d, n_pulses) <= AUTO_EXACT_MAX_EVENTS:
        return "exact"
    return "analytic"


def spatial_blocks(shape: tuple[int, ...]) -> tuple[int, int, int]:
    """``(n_blocks, height, width)`` of an ideal array ``[..., T]``.

    The last two leading axes are the pixel grid (crosstalk neighbours), any
    further leading axes index independent measurements (laser spots); a
    2-D array ``[n, T]`` is one row of ``n`` pixels, a 1-D array one pixel.
    """
    lead = shape[:-1]
    if len(lead) == 0:
        return 1, 1, 1
    if len(lead) == 1:
        return 1, 1, lead[0]
    return int(np.prod(lead[:-2], dtype=np.int64)), lead[-2], lead[-1]


def run_spot(model: DetectorModel, ideal2d: np.ndarray, n_pulses: int, rng: np.random.Generator,
             engine: str, spatial_shape: tuple[int, int], advance=None) -> tuple[np.ndarray, dict]:
    """One spot ``[n_pix, n_bins]`` through the chosen engine (``auto`` resolved here)."""
    eng = choose_engine(engine, model, ideal2d, n_pulses)
    if eng == "exact":
        counts, info = run_exact(model, ideal2d, n_pulses, rng, spatial_shape, advance=advance)
    else:
        counts, info = run_analytic(model, ideal2d, n_pulses, rng, spatial_shape)
        if advance is not None:
            advance(n_pulses)
    info["engine_requested"] = engine
    return counts, info


def to_uint32(counts: np.ndarray, where: str = "counts") -> np.ndarray:
    if counts.size and counts.max() > np.iinfo(np.uint32).max:
        raise UserInputError(f"{where}: a bin holds {int(counts.max())} counts, more than a uint32 can store; "
                             "use fewer pulses")
    return counts.astype(np.uint32)


def detect(ideal, params: DetectorParams | None = None, n_pulses: int = DEFAULT_PULSES, *,
           bin_width_ps: float, t0_ps: float = 0.0, seed: int | None = 0,
           rng: np.random.Generator | None = None, engine: str = "auto", return_info: bool = False,
           advance=None):
    """Photon counts a SPAD + TCSPC records for ``n_pulses`` laser pulses.

    Parameters
    ----------
    ideal : array_like, shape (..., n_bins)
        Expected photons per pulse per time bin at each pixel's aperture
        (float, finite, >= 0). The last two leading axes are the pixel grid
        ``(height, width)`` used for crosstalk; further leading axes are
        independent measurements (e.g. laser spots), each of ``n_pulses``.
    params : DetectorParams, optional
        Detector model (defaults: the paper's); gate times must be explicit
        (``auto_gate`` needs a capture, see :func:`detect_stack`).
    n_pulses : int
        Laser pulses (TCSPC cycles) per histogram.
    bin_width_ps, t0_ps : float
        Time axis: bin ``b`` covers ``[t0 + b w, t0 + (b + 1) w)`` ps.
    seed : int, optional
        Seed of ``np.random.default_rng`` (ignored when ``rng`` is given).
    rng : numpy.random.Generator, optional
    engine : {"auto", "analytic", "exact"}
        ``auto``: analytic when it is exact for these inputs, else exact when
        it would simulate at most :data:`AUTO_EXACT_MAX_EVENTS` events, else
        analytic (approximate; see :mod:`.engines.analytic`).
    return_info : bool
        Also return a list of per-measurement info dicts.

    Returns
    -------
    counts : ndarray of uint32, same shape as ``ideal``
    infos : list of dict (only with ``return_info``)
    """
    params = (params or DetectorParams()).validate()
    check_engine(engine)
    N = check_pulses(n_pulses)
    arr = check_ideal(ideal)
    T = arr.shape[-1]
    model = build_model(params, bin_width_ps=bin_width_ps, n_bins=T, t0_ps=t0_ps)
    if rng is None:
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or seed < 0):
            raise UserInputError(f"seed={seed!r}: must be a whole number >= 0")
        rng = np.random.default_rng(seed)
    n_blocks, H, W = spatial_blocks(arr.shape)
    flat = arr.reshape(n_blocks, H * W, T)
    out = np.empty(flat.shape, dtype=np.int64)
    infos = []
    for b in range(n_blocks):
        out[b], info = run_spot(model, flat[b], N, rng, engine, (H, W), advance=advance)
        infos.append(info)
    counts = to_uint32(out).reshape(arr.shape)
    return (counts, infos) if return_info else counts


def expected_counts_low_flux(ideal, params: DetectorParams, n_pulses: int, *, bin_width_ps: float,
                             t0_ps: float = 0.0) -> np.ndarray:
    """``N x (pde x gate x ideal + background)`` convolved with the jitter: the mean counts without dead time.

    The low-flux limit of every engine; handy for tests and plots.
    """
    from .model import apply_jitter_kernel

    arr = check_ideal(ideal)
    T = arr.shape[-1]
    model = build_model(params.validate(), bin_width_ps=bin_width_ps, n_bins=T, t0_ps=t0_ps)
    lam = model.intensity(arr.reshape(-1, T))[:, :T]
    return (apply_jitter_kernel(lam, model.kernel_first, model.kernel) * n_pulses).reshape(arr.shape)


__all__ = ["detect", "expected_counts_low_flux", "AUTO_EXACT_MAX_EVENTS"]
