"""``transient-mi render``: scene -> EXR histogram stack (+ preview.png)."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from ._options import whole_number


def render(
    scene: Path = typer.Argument(..., help="Mitsuba XML scene (transient_path or transient_nlos_path integrator, "
                                 "transient_film/spad_film), or the name of a shipped scene (e.g. nlos_point_targets; "
                                 "`transient-mi info` lists them) when no such file exists."),
    out: Path = typer.Option(..., "-o", "--out", help="Output capture directory."),
    define: Optional[List[str]] = typer.Option(None, "-D", "--define", help="Scene parameter name=value ($name in the XML). Repeatable."),
    spp: Optional[int] = typer.Option(None, "--spp", parser=whole_number("--spp"), metavar="<int>", help="Samples per pixel, >= 1 (default: the scene's sampler "
                                                         "value)."),
    seed: int = typer.Option(0, "--seed", parser=whole_number("--seed"), metavar="<int>", help="Random seed; same seed, same bytes."),
    variant: Optional[str] = typer.Option(None, "--variant", help="Mitsuba variant (default llvm_ad_mono or $TRANSIENT_MI_VARIANT)."),
    resume: bool = typer.Option(False, "--resume", help="Continue an interrupted capture in OUT (same settings)."),
    noise_target: Optional[float] = typer.Option(
        None, "--noise-target", help="Render each laser spot until its rendering variance is at most this share of "
        "the photon variance at the budget (--pulses/--exposure-s, else the scene's spad_film, else 1e6 pulses), "
        "e.g. 0.1. NLOS captures only; with estimator=quadrature the part of its error that sets the ratio is "
        "refined instead (elements, cells per patch or visibility refinement levels)."),
    pulses: Optional[float] = typer.Option(None, "--pulses", help="With --noise-target: laser pulses per spot."),
    exposure_s: Optional[float] = typer.Option(None, "--exposure-s",
                                               help="With --noise-target: exposure per spot, seconds."),
    max_spp: Optional[float] = typer.Option(None, "--max-spp", help="With --noise-target: cap on samples per "
                                            "pixel per spot (default 2**20)."),
) -> None:
    """Render SCENE into a capture directory: manifest.json, spot_NNNNN.exr, variance/, preview.png."""
    from transient_core.errors import UserInputError
    from transient_mi.render_capture import prepare_render, run_render
    from transient_mi.scene_io import parse_defines
    from transient_mi.scenes import shipped_scene

    if not scene.exists() and shipped_scene(scene) is not None:
        scene = shipped_scene(scene)
    if spp is not None and spp < 1:
        raise UserInputError(f"--spp {spp}: must be >= 1 (omit --spp for the scene's sampler value)")
    spec = None
    if noise_target is None:
        for name, v in (("--pulses", pulses), ("--exposure-s", exposure_s), ("--max-spp", max_spp)):
            if v is not None:
                raise UserInputError(f"{name} {v:g}: only used with --noise-target")
    else:
        from transient_mi.noise_target import DEFAULT_MAX_SPP, NoiseTargetSpec

        if pulses is not None and exposure_s is not None:
            raise UserInputError("--pulses and --exposure-s: give one photon budget, not both")
        spec = NoiseTargetSpec(target=noise_target, params=None, pulses=_whole("--pulses", pulses),
                               exposure_s=exposure_s,
                               max_spp=_whole("--max-spp", max_spp) if max_spp is not None else DEFAULT_MAX_SPP)
    job = prepare_render(scene, out, defines=parse_defines(define), spp=spp or 0, seed=seed, variant=variant,
                         resume=resume, noise_target=spec)
    path = run_render(job)
    typer.echo(f"wrote {path} ({_summary(job.manifest, job.spp)})")


def _summary(m: dict, spp: int) -> str:
    """The capture's shape and how it was rendered: Monte Carlo's spp (the range a noise target chose per spot), or
    the quadrature's worst stated ratio against its noise target (its spots record settings, not spp)."""
    shape = (f"{m['n_files']} spot file(s), {m['height']}x{m['width']} pixels, {m['time']['n_bins']} bins of "
             f"{m['time']['bin_width_ps']:g} ps")
    render = m.get("render") or {}
    nt = render.get("noise_target")
    quadrature = render.get("estimator") == "quadrature"
    if not nt:
        if not quadrature:
            return f"{shape}, spp {spp}"
        from transient_core import stack

        remainder = stack.has_error_bound(m) and not stack.is_error_bound(m)  # light beyond three bounces
        return f"{shape}, quadrature" + (f" + Monte Carlo remainder at spp {spp}" if remainder else "")
    verdict = "met" if nt.get("met") else ("NOT met (refinement cap reached)" if quadrature else
                                           "NOT met (max spp reached)")
    if quadrature:
        worst = max(float(s["ratio"]) for s in nt["spots"])
        return f"{shape}, quadrature: stated error ratio up to {worst:.3g} for noise target {nt['target']:g}: {verdict}"
    spp_used = [s["spp"] for s in nt["spots"]]
    return f"{shape}, spp {min(spp_used)}-{max(spp_used)} for noise target {nt['target']:g}: {verdict}"


def _whole(name: str, v):
    from transient_core.errors import UserInputError

    if v is None:
        return None
    if not float(v).is_integer() or v < 1:
        raise UserInputError(f"{name} {v!r}: must be a whole number >= 1")
    return int(v)


def register(app: typer.Typer) -> None:
    app.command("render")(render)
