"""``transient-mi fit``: fit the hidden scene's model to a counts capture (analysis by synthesis).

The work is done by :func:`transient_mi.fit.fit_capture`; this module only parses the command line.
"""

from __future__ import annotations

from pathlib import Path

import typer

from ._options import whole_number


def fit_command(
    capture: Path = typer.Argument(..., help="Counts capture (transient-mi detect, or the demo's "
                                             "captures/array_NN/counts) of an NLOS scene."),
    out: Path = typer.Option(..., "-o", "--out", help="Output directory: fit.json, fitted.ply, loss.png, fit.png, "
                                                      "checkpoint.json."),
    model: str = typer.Option("mannequin", "--model", help="mannequin (joint angles, position, rotation, height, "
                                                          "reflectance), patches (square patches) or mesh (a free "
                                                          "mesh: any shape)."),
    iterations: int = typer.Option(None, "--iterations", parser=whole_number("--iterations"), metavar="<int>",
                                   help="The optimiser's iterations (default: 16 with Gauss-Newton, 300 with Adam)."),
    optimizer: str = typer.Option("auto", "--optimizer", help="gauss_newton (Levenberg-Marquardt: deterministic "
                                  "forward model only), adam, or auto (gauss_newton with the quadrature, adam with "
                                  "Monte Carlo). --model mesh has its own (Adam on the vertices)."),
    spp: int = typer.Option(0, "--spp", parser=whole_number("--spp"), metavar="<int>",
                            help="Samples per pixel of the derivative render per iteration (0: 8192 per laser spot "
                                 "spread over the pixels, 4 to 64: 32 at 16x16, 8 at 32x32)."),
    spp_residual: int = typer.Option(0, "--spp-residual", parser=whole_number("--spp-residual"), metavar="<int>",
                                     help="Samples per pixel of the residual render per iteration (0: 4 x --spp)."),
    sigma_start_ps: float = typer.Option(250.0, "--sigma-start-ps", help="Temporal blur at the start (coarse to "
                                                                         "fine; ends at the detector's jitter), ps."),
    sigma_end_ps: float = typer.Option(30.0, "--sigma-end-ps", help="Temporal blur at the end (not below the "
                                                                     "detector's jitter), ps."),
    bin_width_ps: float = typer.Option(10.0, "--bin-width-ps", help="The fit's time bins (a whole multiple of the "
                                                                    "capture's), ps."),
    patches: int = typer.Option(3, "--patches", parser=whole_number("--patches"), metavar="<int>",
                                help="--model patches: how many."),
    patch_side_m: float = typer.Option(0.2, "--patch-side-m", help="--model patches: side of each patch, metres."),
    estimator: str = typer.Option("auto", "--estimator", help="Forward model: quadrature (deterministic), "
                                  "monte_carlo, or auto (the quadrature where the scene allows it, see "
                                  "docs/fit.md)."),
    element_size_m: float = typer.Option(0.03, "--element-size-m", help="--estimator quadrature: element size "
                                         "at the end (twice as large for the first half of the iterations), m."),
    start: str = typer.Option("front", "--start", help="--model mesh: start from the backprojection's front surface "
                              "(front) or a closed surface around its occupied voxels (closed)."),
    start_mesh: Path = typer.Option(None, "--start-mesh", help="--model mesh: start from this mesh file instead "
                                    "(e.g. a recon method's surface.ply)."),
    cell_m: float = typer.Option(0.04, "--cell-m", help="--model mesh: the start mesh's resolution (halved at each "
                                 "later stage), metres."),
    stages: int = typer.Option(2, "--stages", parser=whole_number("--stages"), metavar="<int>",
                               help="--model mesh: resolution stages (the mesh subdivided between them), 1 to 3."),
    smoothing: float = typer.Option(10.0, "--smoothing", help="--model mesh: lambda of the large-steps "
                                    "parametrisation (0: per-vertex steps)."),
    align: int = typer.Option(8, "--align", parser=whole_number("--align"), metavar="<int>",
                              help="--model mesh: Levenberg-Marquardt iterations of the start's affine map and "
                                   "reflectance before the vertices move, 0 to 100 (0: none)."),
    carve: int = typer.Option(None, "--carve", parser=whole_number("--carve"), metavar="<int>",
                              help="--model mesh: iterations of one reflectance per face on the aligned start "
                                   "(subdivided once) before its dark faces are dropped, 0 to 200 (0: none; "
                                   "default 40, or 0 with --reflectance face)."),
    grow: int = typer.Option(None, "--grow", parser=whole_number("--grow"), metavar="<int>",
                             help="--model mesh: rings of faces --cell-m wide added around the aligned start's open "
                                  "boundary before carving, whose kept faces the counts choose, 0 to 4 (default 2 "
                                  "where the fit carves, else 0)."),
    reflectance: str = typer.Option("global", "--reflectance", help="--model mesh: one reflectance for the mesh "
                                    "(global) or one per face (face: for objects of several materials; fitted.ply "
                                    "carries them)."),
    albedo_smoothness: float = typer.Option(1.0, "--albedo-smoothness", help="--model mesh --reflectance face: "
                                            "weight of the per-face reflectance's smoothness across edges."),
    carve_tv: float = typer.Option(None, "--carve-tv", help="--model mesh: weight of the carving's total-variation "
                                   "prior on the faces' reflectances, a share of the signal energy (default 4e-4, "
                                   "transient_mi.fit.mesh_carve.TV_WEIGHT; 0: none; docs/fit.md)."),
    pixel_step: int = typer.Option(None, "--pixel-step", parser=whole_number("--pixel-step"), metavar="<int>",
                                   help="--model mesh: fit every n-th pixel along each axis, 1 to 16, dividing the "
                                        "array (1: all; default: the largest step keeping 8 pixels per side, 4 on "
                                        "the paper's 32 x 32 array, 2 on a 16 x 16 one; docs/fit.md)."),
    seed: int = typer.Option(0, "--seed", parser=whole_number("--seed"), metavar="<int>", help="Random seed."),
    resume: bool = typer.Option(False, "--resume", help="Continue the fit in OUT from its checkpoint."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an earlier fit in OUT."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Show progress."),
) -> None:
    """Fit a parametric model of the hidden object to detected counts through the renderer and the detector model:
    Gauss-Newton on the deterministic quadrature, or Adam on its derivatives (see docs/fit.md)."""
    from transient_mi.fit import FitSettings, fit_capture

    settings = FitSettings(iterations=iterations, spp=spp, spp_residual=spp_residual, sigma_start_ps=sigma_start_ps,
                           sigma_end_ps=sigma_end_ps, seed=seed, estimator=estimator, element_size_m=element_size_m,
                           optimizer=optimizer)
    from transient_mi.fit.mesh_settings import MeshSettings, check_mesh_options

    mesh = MeshSettings(start=start, start_mesh=None if start_mesh is None else str(start_mesh), cell_m=cell_m,
                        stages=stages, smoothing=smoothing, align=align, carve=carve, grow=grow,
                        reflectance=reflectance, albedo_smoothness=albedo_smoothness, pixel_step=pixel_step,
                        **({} if carve_tv is None else {"carve_tv": carve_tv}))
    check_mesh_options(mesh)  # whatever --model: a bad value is refused before any work
    result = fit_capture(capture, out, model=model, settings=settings, bin_width_ps=bin_width_ps, n_patches=patches,
                         patch_side_m=patch_side_m, resume=resume, overwrite=overwrite, progress=progress,
                         log=typer.echo, mesh=mesh)
    m = result["metrics"]
    if "fit" in m:
        f, b = m["fit"], m["backprojection"]
        typer.echo(f"against the scene's hidden shapes: fit Chamfer {100 * f['chamfer_m']:.2f} cm, IoU {f['iou']:.2f} "
                   f"(backprojection {100 * b['chamfer_m']:.2f} cm, {b['iou']:.2f}); surface-to-surface Chamfer "
                   f"{100 * f['chamfer_mesh_m']:.2f} cm")
    if "joint_error_max_deg" in m:
        typer.echo(f"pose: joint angles within {m['joint_error_max_deg']:.1f} deg (mean {m['joint_error_mean_deg']:.1f}), "
                   f"position within {100 * m['position_error_m']:.2f} cm")


def register(app: typer.Typer) -> None:
    app.command("fit")(fit_command)
