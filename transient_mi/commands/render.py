"""``transient-mi render``: scene -> EXR histogram stack (+ preview.png)."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from ._options import whole_number


def render(
    scene: Path = typer.Argument(..., help="Mitsuba XML scene (transient_path integrator, transient_film/spad_film)."),
    out: Path = typer.Option(..., "-o", "--out", help="Output capture directory."),
    define: Optional[List[str]] = typer.Option(None, "-D", "--define", help="Scene parameter name=value ($name in the XML). Repeatable."),
    spp: Optional[int] = typer.Option(None, "--spp", parser=whole_number("--spp"), metavar="<int>", help="Samples per pixel, >= 1 (default: the scene's sampler "
                                                         "value)."),
    seed: int = typer.Option(0, "--seed", parser=whole_number("--seed"), metavar="<int>", help="Random seed; same seed, same bytes."),
    variant: Optional[str] = typer.Option(None, "--variant", help="Mitsuba variant (default llvm_ad_mono or $TRANSIENT_MI_VARIANT)."),
    resume: bool = typer.Option(False, "--resume", help="Continue an interrupted capture in OUT (same settings)."),
) -> None:
    """Render SCENE into a capture directory: manifest.json, spot_NNNNN.exr, preview.png."""
    from recon.errors import UserInputError
    from transient_mi.pipeline import prepare_render, run_render
    from transient_mi.scene_io import parse_defines

    if spp is not None and spp < 1:
        raise UserInputError(f"--spp {spp}: must be >= 1 (omit --spp for the scene's sampler value)")

    job = prepare_render(scene, out, defines=parse_defines(define), spp=spp or 0, seed=seed, variant=variant,
                         resume=resume)
    path = run_render(job)
    m = job.manifest
    typer.echo(f"wrote {path} ({m['n_files']} spot file(s), {m['height']}x{m['width']} pixels, "
               f"{m['time']['n_bins']} bins of {m['time']['bin_width_ps']:g} ps, spp {job.spp})")


def register(app: typer.Typer) -> None:
    app.command("render")(render)
