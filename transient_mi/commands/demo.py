"""``transient-mi demo``: the paper's mannequin experiment end to end."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ._options import noise_target_value, whole_number


def demo(
    out: Path = typer.Option(Path("out/demo"), "-o", "--out", help="Output directory."),
    quick: bool = typer.Option(False, "--quick", help="Coarser settings: under 2 minutes on 2 cores."),
    arrays: Optional[str] = typer.Option(None, "--arrays", help="Array sizes, comma-separated (default 4,8,16,32)."),
    seed: int = typer.Option(0, "--seed", parser=whole_number("--seed"), metavar="<int>", help="Seed of rendering and detection."),
    exposure_ms: Optional[float] = typer.Option(None, "--exposure-ms", help="Exposure per laser spot, ms (default 10)."),
    spots: Optional[int] = typer.Option(
        None, "--spots", help="Laser scan grid side N (N x N spots over the 1 m wall; default 2). Render time and "
                              "data grow as N^2; docs/recon.md, 'Sampling designs'."),
    estimator: Optional[str] = typer.Option(
        None, "--estimator", help="Estimator of three-bounce light: quadrature (deterministic, an error estimate "
                                  "instead of noise) or monte_carlo (samples); default: the demo's "
                                  "(docs/demo.md)."),
    noise_target: Optional[str] = typer.Option(
        None, "--noise-target", metavar="R|auto|none",
        help="Largest rendering / photon noise ratio of every capture: auto (default) is 0.01 where the quadrature "
             "renders, 0.1 by Monte Carlo; a number sets it for both; none renders at the scene's settings and "
             "reports the ratio."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a non-empty output directory (an earlier "
                                   "demo's output is replaced without it)."),
) -> None:
    """Render, detect and reconstruct the paper's mannequin for 4x4 to 32x32 SPAD arrays; write figures,
    a metrics table against the ground-truth mesh, and summary.md."""
    import dataclasses
    import math

    from transient_core.errors import UserInputError
    from transient_mi.demo import QUICK, DemoSettings, run_demo

    s = QUICK if quick else DemoSettings()
    changes = {"seed": seed}
    if arrays is not None:
        try:
            changes["arrays"] = tuple(int(a) for a in arrays.split(","))
        except ValueError:
            raise UserInputError(f"--arrays {arrays!r}: expected comma-separated integers, e.g. 4,8,16,32") from None
        if not changes["arrays"] or min(changes["arrays"]) < 1 or max(changes["arrays"]) > 256:
            raise UserInputError(f"--arrays {arrays!r}: sizes must be between 1 and 256")
    if exposure_ms is not None:
        if not (math.isfinite(exposure_ms) and exposure_ms > 0):
            raise UserInputError(f"--exposure-ms {exposure_ms:g}: must be a finite number > 0")
        changes["exposure_s"] = exposure_ms * 1e-3
    if spots is not None:
        if not 1 <= spots <= 64:
            raise UserInputError(f"--spots {spots}: must be between 1 and 64 (N x N laser spots)")
        changes["spots"] = spots
    if estimator is not None:
        if estimator not in ("quadrature", "monte_carlo"):
            raise UserInputError(f"--estimator {estimator!r}: allowed quadrature, monte_carlo")
        changes["estimator"] = estimator
    target = "auto" if noise_target is None else noise_target_value(noise_target, auto=True)
    if target is None:
        changes["noise_target"] = None
    elif target != "auto":
        changes.update(noise_target=target, quadrature_noise_target=None)
    if not 0 <= seed < 2**31:
        raise UserInputError(f"--seed {seed}: must be in [0, 2**31)")
    run_demo(out, settings=dataclasses.replace(s, **changes), quick=quick, overwrite=overwrite,
             log=lambda msg: typer.echo(msg, err=True))


def register(app: typer.Typer) -> None:
    app.command("demo")(demo)
