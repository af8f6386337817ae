"""``transient-mi study``: photon-budget and array-size studies (see docs/studies.md)."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from ._options import noise_target_value, whole_number

study_app = typer.Typer(
    name="study",
    help="Studies on one scene: reconstruction error and SNR against photon budget, error and time against "
         "SPAD array size.",
    no_args_is_help=True,
    add_completion=False,
)


def _numbers(values: Optional[List[str]], option: str, *, lo: float = 0.0, lo_open: bool = True,
             scale: float = 1.0) -> Optional[tuple]:
    """Comma-separated and/or repeated numbers -> tuple (times ``scale``); None when the option is absent."""
    from transient_core.errors import UserInputError
    from transient_mi.study.validate import numbers_list

    if not values:
        return None
    items = [v.strip() for text in values for v in text.split(",")]
    parsed = []
    for v in items:
        try:
            parsed.append(float(v))
        except ValueError:
            raise UserInputError(f"{option} {v!r}: not a number (give comma-separated numbers, e.g. "
                                 f"{option} 0.001,0.01)") from None
    vals = numbers_list(parsed, option, lo=lo, lo_open=lo_open)
    return tuple(v * scale for v in vals)


def _ints(text: Optional[str], option: str, example: str) -> Optional[tuple]:
    from transient_core.errors import UserInputError

    if text is None:
        return None
    try:
        return tuple(int(v) for v in text.split(","))
    except ValueError:
        raise UserInputError(f"{option} {text!r}: expected comma-separated integers, e.g. {option} {example}") \
            from None


def _common(scene: str, define, voxels: Optional[str]):
    from transient_mi.scene_io import parse_defines
    from transient_mi.study.validate import voxels as check_voxels

    defines = parse_defines(define)
    vox = _ints(voxels, "--voxels", "64,64,32")
    if vox is not None:
        vox = check_voxels(vox[0] if len(vox) == 1 else vox, "--voxels")
    return scene, defines, vox


def _log(msg: str) -> None:
    typer.echo(msg, err=True)


SCENE_ARG = typer.Argument("paper_mannequin", help="Shipped scene name or XML file (default: the paper's "
                                                   "mannequin scene).")
OUT_OPT = typer.Option(..., "-o", "--out", help="Output directory (created; must not exist or be empty).")
DEFINE_OPT = typer.Option(None, "-D", "--define", help="Scene parameter name=value ($name in the XML). Repeatable.")
VOXELS_OPT = typer.Option(None, "--voxels", help="Reconstruction voxels: N or NX,NY,NZ (default 64,64,32).")
SEED_OPT = typer.Option(0, "--seed", help="Render seed (and metrics' sampling seed).")
GT_OPT = typer.Option(None, "--ground-truth", help="Ground truth for other scenes: a mesh (.obj/.ply/...) or point "
                                                   "targets (.json/.npy/.csv). The paper scene knows its own.")
QUICK_OPT = typer.Option(False, "--quick", help="Coarser render (paper scene: 8 ps bins, 256 spp).")
OVERWRITE_OPT = typer.Option(False, "--overwrite", help="Replace a non-empty output directory.")


@study_app.command("photon-budget")
def photon_budget(
    scene: str = SCENE_ARG,
    out: Path = OUT_OPT,
    define: Optional[List[str]] = DEFINE_OPT,
    exposures_ms: Optional[List[str]] = typer.Option(
        None, "--exposures-ms", help="Exposure per laser spot, ms, comma-separated or repeated "
                                     "(default 1e-4,1e-3,0.01,0.1,1: 5 to 5e4 pulses at 50 MHz)."),
    laser_powers_w: Optional[List[str]] = typer.Option(
        None, "--laser-powers-w", help="Laser average powers, W (default: the scene's). Power, unlike exposure, "
                                       "changes the per-pulse flux and so pile-up."),
    dark_count_rates_cps: Optional[List[str]] = typer.Option(
        None, "--dark-count-rates-cps", help="Dark-count rates, counts/s (default 25,1e5,1e7)."),
    dead_times_ns: Optional[List[str]] = typer.Option(
        None, "--dead-times-ns", help="SPAD dead times, ns (default 10,1000)."),
    seeds: int = typer.Option(3, "--seeds", parser=whole_number("--seeds"), metavar="<int>", help="Number of detection seeds (0..N-1), at least 2."),
    voxels: Optional[str] = VOXELS_OPT,
    seed: int = SEED_OPT,
    ground_truth: Optional[Path] = GT_OPT,
    quick: bool = QUICK_OPT,
    overwrite: bool = OVERWRITE_OPT,
    noise_target: Optional[str] = typer.Option(
        None, "--noise-target", help="Render until rendering variance <= this share of the photon variance at the "
                                     "largest budget; 'none' renders the scene's spp (default 0.1, 0.01 for the "
                                     "quadrature, none with --quick; docs/noise.md)."),
) -> None:
    """One render of SCENE, then detection over decades of photon budget x dark-count rates x dead times x seeds,
    reconstruction of each; reconstruction error and per-bin SNR against detected photons (CSV, JSON, plots,
    summary.md)."""
    from transient_core.errors import UserInputError
    from transient_mi.study import run_photon_budget_study

    scene, defines, vox = _common(scene, define, voxels)
    kw = {}
    for key, vals in (("exposures_s", _numbers(exposures_ms, "--exposures-ms", scale=1e-3)),
                      ("laser_powers_w", _numbers(laser_powers_w, "--laser-powers-w")),
                      ("dark_count_rates_cps", _numbers(dark_count_rates_cps, "--dark-count-rates-cps",
                                                        lo_open=False)),
                      ("dead_times_ns", _numbers(dead_times_ns, "--dead-times-ns", lo_open=False))):
        if vals is not None:
            kw[key] = vals
    if vox is not None:
        kw["voxels"] = vox
    if not 2 <= seeds <= 1000:
        raise UserInputError(f"--seeds {seeds}: need between 2 and 1000 detection seeds (the SNR is measured over "
                             "them)")
    if not 0 <= seed < 2**32:
        raise UserInputError(f"--seed {seed}: must be in [0, 2**32)")
    if noise_target is not None:
        kw["noise_target"] = noise_target_value(noise_target)
    r = run_photon_budget_study(scene, out, defines=defines, seeds=tuple(range(seeds)), seed=seed, quick=quick,
                                ground_truth=ground_truth, overwrite=overwrite, log=_log, **kw)
    typer.echo(f"wrote {r.out_dir}: {len(r.rows)} runs; summary {r.summary}")


@study_app.command("array-size")
def array_size(
    scene: str = SCENE_ARG,
    out: Path = OUT_OPT,
    define: Optional[List[str]] = DEFINE_OPT,
    arrays: str = typer.Option("4,8,16,32,64", "--arrays", help="SPAD array sides, comma-separated."),
    exposure_ms: float = typer.Option(10.0, "--exposure-ms", help="Exposure per laser spot, ms (the paper's: 10)."),
    voxels: Optional[str] = VOXELS_OPT,
    seed: int = SEED_OPT,
    ground_truth: Optional[Path] = GT_OPT,
    keep_captures: bool = typer.Option(False, "--keep-captures", help="Keep every ideal and counts capture."),
    quick: bool = QUICK_OPT,
    overwrite: bool = OVERWRITE_OPT,
) -> None:
    """Render, detect and reconstruct SCENE for each SPAD array size; error metrics and time per step against
    array size (CSV, JSON, plot, summary.md)."""
    import math

    from transient_core.errors import UserInputError
    from transient_mi.study import run_array_size_study

    scene, defines, vox = _common(scene, define, voxels)
    sizes = _ints(arrays, "--arrays", "4,8,16,32,64")
    if not (math.isfinite(exposure_ms) and exposure_ms > 0):
        raise UserInputError(f"--exposure-ms {exposure_ms:g}: must be a finite number > 0")
    if not 0 <= seed < 2**32:
        raise UserInputError(f"--seed {seed}: must be in [0, 2**32)")
    kw = {"voxels": vox} if vox is not None else {}
    for n in sizes:
        if not 1 <= n <= 256:
            raise UserInputError(f"--arrays {arrays!r}: sizes must be between 1 and 256")
    r = run_array_size_study(scene, out, arrays=sizes, defines=defines, exposure_s=exposure_ms * 1e-3, seed=seed,
                             quick=quick, ground_truth=ground_truth, keep_captures=keep_captures,
                             overwrite=overwrite, log=_log, **kw)
    typer.echo(f"wrote {r.out_dir}: {len(r.rows)} array sizes; summary {r.summary}")


@study_app.command("methods")
def methods(
    scene: str = SCENE_ARG,
    out: Path = OUT_OPT,
    define: Optional[List[str]] = DEFINE_OPT,
    arrays: str = typer.Option("8,16,32", "--arrays", help="SPAD array sides, comma-separated."),
    exposures_ms: Optional[List[str]] = typer.Option(
        None, "--exposures-ms", help="Exposure per laser spot, ms, comma-separated or repeated (default 1,10)."),
    methods: str = typer.Option("bp,fbp,phasor,midpoint-lct,midpoint-fk", "--methods",
                                help="Reconstruction methods, comma-separated."),
    bounds: Optional[str] = typer.Option(
        None, "--bounds", help="xmin,xmax,ymin,ymax,zmin,zmax in metres (default: the paper's volume for the paper "
                               "scene, else recon's default from the first capture)."),
    voxels: Optional[str] = VOXELS_OPT,
    complete: Optional[str] = typer.Option(
        None, "--complete", help="Also score each reconstruction closed behind its front under a stated prior "
                                 "(elliptical cross-sections; auto or an aspect in [0, 2]), as <method>+completion."),
    fit: Optional[str] = typer.Option(
        None, "--fit", help="Also fit this model (mannequin, patches or mesh; `transient-mi fit`), or these models "
                            "comma-separated, to every array x exposure's counts, as rows fit:<model> (minutes "
                            "per fit)."),
    fit_iterations: Optional[str] = typer.Option(
        None, "--fit-iterations", metavar="N|MODEL=N,...",
        help="The fits' iterations (default the fit command's, 300): one number for every model, or per model "
             "(mannequin=300,mesh=40)."),
    fit_arrays: Optional[str] = typer.Option(
        None, "--fit-arrays", metavar="N,...|MODEL=N,...;...",
        help="Fit only these array sides, comma-separated (default every array of --arrays; a free mesh's fit "
             "grows with pixels x spots), or per model (mesh=8, or mannequin=8,16;mesh=8)."),
    noise_target: Optional[str] = typer.Option(
        None, "--noise-target", help="Render each array until its rendering variance <= this share of the photon "
                                     "variance at the largest exposure; 'none' renders the scene's spp (default 0.1, "
                                     "0.01 for the quadrature, none with --quick; docs/noise.md)."),
    seed: int = SEED_OPT,
    ground_truth: Optional[Path] = GT_OPT,
    quick: bool = QUICK_OPT,
    overwrite: bool = OVERWRITE_OPT,
) -> None:
    """Leaderboard: every reconstruction method x SPAD array size x photon budget on SCENE (one render per array
    size): Chamfer, completeness, IoU, depth MAE, visible-surface errors, time and peak memory (CSV, JSON, plots,
    summary.md)."""
    from transient_core.errors import UserInputError
    from transient_mi.study import run_methods_study

    scene, defines, vox = _common(scene, define, voxels)
    sizes = _ints(arrays, "--arrays", "8,16,32")
    for n in sizes:
        if not 1 <= n <= 256:
            raise UserInputError(f"--arrays {arrays!r}: sizes must be between 1 and 256")
    if not 0 <= seed < 2**32:
        raise UserInputError(f"--seed {seed}: must be in [0, 2**32)")
    kw = {"voxels": vox} if vox is not None else {}
    ex = _numbers(exposures_ms, "--exposures-ms", scale=1e-3)
    if ex is not None:
        kw["exposures_s"] = ex
    if bounds is not None:
        from recon.grid import parse_bounds

        kw["bounds"] = parse_bounds(bounds)
    if noise_target is not None:
        kw["noise_target"] = noise_target_value(noise_target)
    if fit_arrays is not None:
        kw["fit_arrays"] = _fit_arrays(fit_arrays)
    if fit_iterations is not None:
        kw["fit_iterations"] = _fit_iterations(fit_iterations)
    names = tuple(m.strip() for m in methods.split(",") if m.strip())
    fits = None if fit is None else tuple(m.strip() for m in fit.split(",") if m.strip())
    path, rows = run_methods_study(scene, out, arrays=sizes, methods=names, defines=defines, seed=seed, quick=quick,
                                   ground_truth=ground_truth, complete=complete,
                                   fit=fits[0] if fits and len(fits) == 1 else fits, overwrite=overwrite, log=_log,
                                   **kw)
    typer.echo(f"wrote {path}: {len(rows)} reconstructions; summary {path / 'summary.md'}")


def _fit_iterations(text: str):
    """``--fit-iterations``: ``N`` (every model) or ``MODEL=N,...`` (a dict; the study checks the models)."""
    from transient_core.errors import UserInputError

    if "=" not in text:
        return whole_number("--fit-iterations")(text)
    out = {}
    for part in text.split(","):
        model, sep, n = part.partition("=")
        if not sep or not model.strip():
            raise UserInputError(f"--fit-iterations {text!r}: expected N or MODEL=N,... (e.g. mannequin=300,mesh=40)")
        out[model.strip()] = whole_number("--fit-iterations")(n)
    return out


def _fit_arrays(text: str):
    """``--fit-arrays``: ``N,...`` (every model) or ``MODEL=N,...;MODEL=N,...`` (a dict)."""
    from transient_core.errors import UserInputError

    if "=" not in text:
        return _ints(text, "--fit-arrays", "8")
    out = {}
    for part in text.split(";"):
        model, sep, sizes = part.partition("=")
        if not sep or not model.strip():
            raise UserInputError(f"--fit-arrays {text!r}: expected N,... or MODEL=N,...;MODEL=N,... "
                                 "(e.g. mannequin=8,16;mesh=8)")
        out[model.strip()] = _ints(sizes, "--fit-arrays", "mesh=8")
    return out


def register(app: typer.Typer) -> None:
    app.add_typer(study_app, name="study")
