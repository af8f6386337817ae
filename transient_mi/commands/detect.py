"""``transient-mi detect``: ideal capture -> photon counts with the SPAD + TCSPC model (no re-render)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ._options import whole_number

_D = None  # DetectorParams defaults, filled lazily for the help texts


def _default(name: str) -> str:
    from spad_detector.params import DetectorParams

    global _D
    _D = _D or DetectorParams()
    v = getattr(_D, name)
    return "none" if v is None else f"{v:g}" if isinstance(v, float) else str(v)


def detect(
    ideal: Path = typer.Argument(..., help="Ideal capture directory (kind 'ideal', photons per pulse)."),
    out: Path = typer.Option(..., "-o", "--out", help="Counts capture directory to write (must not hold a capture)."),
    pulses: Optional[int] = typer.Option(None, "--pulses", parser=whole_number("--pulses"), metavar="<int>", help="Laser pulses per spot (default 1e6)."),
    exposure_s: Optional[float] = typer.Option(None, "--exposure-s", help="Exposure per spot in seconds (pulses = exposure x repetition rate)."),
    pde: Optional[float] = typer.Option(None, "--pde", help=f"Photon detection efficiency in [0, 1] (default {_default('pde')})."),
    dark_count_rate_cps: Optional[float] = typer.Option(None, "--dark-count-rate-cps", help=f"Dark counts per second (default {_default('dark_count_rate_cps')})."),
    ambient_rate_cps: Optional[float] = typer.Option(None, "--ambient-rate-cps", help="Ambient background, detected counts per second (default 0)."),
    jitter_ps: Optional[float] = typer.Option(None, "--jitter-ps", help=f"Timing resolution, FWHM of the Gaussian jitter in ps (default {_default('jitter_ps')})."),
    irf_tail_fraction: Optional[float] = typer.Option(None, "--irf-tail-fraction", help="Fraction of detections with an exponential IRF tail (default 0)."),
    irf_tail_ps: Optional[float] = typer.Option(None, "--irf-tail-ps", help="Time constant of the IRF tail in ps."),
    irf_file: Optional[Path] = typer.Option(None, "--irf-file", help="Measured IRF: two columns time_ps, weight (.csv, .txt or .npy); replaces --jitter-ps."),
    gate_open_ps: Optional[float] = typer.Option(None, "--gate-open-ps", help="Gate opens (50 % point), ps on the capture's time axis."),
    gate_close_ps: Optional[float] = typer.Option(None, "--gate-close-ps", help="Gate closes (50 % point), ps."),
    gate_transition_ps: Optional[float] = typer.Option(None, "--gate-transition-ps", help=f"10-90 % time of the gate edges in ps (default {_default('gate_transition_ps')})."),
    auto_gate: bool = typer.Option(False, "--auto-gate", help="Gate on the three-bounce arrivals of the hidden volume (from the capture geometry)."),
    auto_gate_depth_min_m: Optional[float] = typer.Option(None, "--auto-gate-depth-min-m", help=f"Hidden volume for --auto-gate: nearest depth in front of the wall, m (default {_default('auto_gate_depth_min_m')})."),
    auto_gate_depth_max_m: Optional[float] = typer.Option(None, "--auto-gate-depth-max-m", help=f"Farthest depth, m (default {_default('auto_gate_depth_max_m')})."),
    dead_time_ns: Optional[float] = typer.Option(None, "--dead-time-ns", help=f"SPAD dead time in ns (default {_default('dead_time_ns')})."),
    dead_time_model: Optional[str] = typer.Option(None, "--dead-time-model", help="nonparalyzable (default) or paralyzable."),
    tcspc_max_count_rate_hz: Optional[float] = typer.Option(None, "--tcspc-max-count-rate-hz", help=f"TCSPC maximum count rate; dead time 1/rate; 0 = unlimited (default {_default('tcspc_max_count_rate_hz')})."),
    afterpulse_prob: Optional[float] = typer.Option(None, "--afterpulse-prob", help="Afterpulsing probability per avalanche, [0, 1) (default 0)."),
    afterpulse_delay_ns: Optional[float] = typer.Option(None, "--afterpulse-delay-ns", help=f"Mean afterpulse delay after re-arming, ns (default {_default('afterpulse_delay_ns')})."),
    crosstalk_prob: Optional[float] = typer.Option(None, "--crosstalk-prob", help="Crosstalk probability to each 4-neighbour per avalanche (default 0)."),
    repetition_rate_hz: Optional[float] = typer.Option(None, "--repetition-rate-hz", help="Laser repetition rate (default: the capture's, else 50e6)."),
    laser_power_w: Optional[float] = typer.Option(None, "--laser-power-w", help="Average laser power override, W (rescales the photons)."),
    wavelength_nm: Optional[float] = typer.Option(None, "--wavelength-nm", help="Laser wavelength override, nm (rescales the photons)."),
    seed: int = typer.Option(0, "--seed", parser=whole_number("--seed"), metavar="<int>", help="Random seed; same seed, same bytes."),
    engine: str = typer.Option("auto", "--engine", help="auto, analytic or exact."),
    force: bool = typer.Option(False, "--force", help="With --engine exact, run even when the estimated work "
                               "exceeds the limit (it is estimated first and refused past the limit)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a counts capture already in OUT."),
    noise_threshold: float = typer.Option(0.1, "--noise-threshold", help="Warn when the ideal capture's rendering "
                                          "variance exceeds this share of the photon variance (docs/noise.md)."),
) -> None:
    """Turn an ideal capture into photon counts with the SPAD + TCSPC model (see docs/detector.md)."""
    from spad_detector import DetectorParams, detect_stack

    given = dict(pde=pde, dark_count_rate_cps=dark_count_rate_cps, ambient_rate_cps=ambient_rate_cps,
                 jitter_ps=jitter_ps, irf_tail_fraction=irf_tail_fraction, irf_tail_ps=irf_tail_ps,
                 irf_file=str(irf_file) if irf_file is not None else None, gate_open_ps=gate_open_ps,
                 gate_close_ps=gate_close_ps, gate_transition_ps=gate_transition_ps,
                 auto_gate_depth_min_m=auto_gate_depth_min_m, auto_gate_depth_max_m=auto_gate_depth_max_m,
                 dead_time_ns=dead_time_ns, dead_time_model=dead_time_model,
                 afterpulse_prob=afterpulse_prob, afterpulse_delay_ns=afterpulse_delay_ns,
                 crosstalk_prob=crosstalk_prob, repetition_rate_hz=repetition_rate_hz,
                 laser_power_w=laser_power_w, wavelength_nm=wavelength_nm)
    kwargs = {k: v for k, v in given.items() if v is not None}
    if tcspc_max_count_rate_hz is not None:
        kwargs["tcspc_max_count_rate_hz"] = None if tcspc_max_count_rate_hz == 0 else tcspc_max_count_rate_hz
    if auto_gate:
        kwargs["auto_gate"] = True
    params = DetectorParams(**kwargs)
    path = detect_stack(ideal, out, params, pulses=pulses, exposure_s=exposure_s, seed=seed, engine=engine,
                        overwrite=overwrite, noise_threshold=noise_threshold, force=force)
    from transient_core.stack import read_manifest

    m = read_manifest(path)
    d = m["detector"]
    used = sorted(set(d["resolved"]["engines_used"]))
    rn = d["resolved"].get("render_noise") or {}
    noise = (f"; rendering/photon noise {rn['ratio']:.3g}" if rn.get("available") else
             "; rendering noise unknown (no variance stored)")
    typer.echo(f"wrote {path} ({m['n_files']} spot file(s), {d['pulses']} pulses per spot, "
               f"engine {'/'.join(used)}{engine_note(engine, d['resolved']['exact'])}{noise})")


def engine_note(engine: str, exact: bool) -> str:
    """What the engine message adds: ``(exact)`` when every draw was exact, else why it was approximate.

    The wording follows docs/detector.md ("Engines") and the README: ``auto`` runs the analytic engine
    where it is exact, else the exact engine when affordable, else the analytic one (approximate).
    """
    if exact:
        return " (exact)"
    if engine == "auto":
        from spad_detector.detect import AUTO_EXACT_MAX_EVENTS

        return (f" (approximate: the analytic engine is not exact for this capture and the exact one would "
                f"simulate more than {AUTO_EXACT_MAX_EVENTS:.0e} events per spot; --engine exact forces it, "
                "see docs/detector.md)")
    return " (approximate for this capture, see docs/detector.md)"


def register(app: typer.Typer) -> None:
    app.command("detect")(detect)
