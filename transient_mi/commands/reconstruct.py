"""``transient-mi recon``: capture (EXR stack or y-tal HDF5) -> volume, pictures, metrics.

The work is done by :func:`recon.pipeline.run` (no Mitsuba needed); this
module only parses the command line.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ._options import whole_number

from transient_core.errors import UserInputError


def _voxels(text: str | None):
    if text is None:
        return None
    parts = [p for p in text.replace(" ", "").split(",") if p]
    try:
        vals = [int(p) for p in parts]
    except ValueError:
        raise UserInputError(f"--voxels {text!r}: expected N or NX,NY,NZ (positive integers)") from None
    if len(vals) not in (1, 3) or any(v < 1 for v in vals):
        raise UserInputError(f"--voxels {text!r}: expected N or NX,NY,NZ (positive integers)")
    return vals[0] if len(vals) == 1 else tuple(vals)


def _pair(text: str | None, name: str):
    if text is None:
        return None
    parts = text.replace(" ", "").split(",")
    try:
        vals = [float(p) if p else None for p in parts]
    except ValueError:
        raise UserInputError(f"{name} {text!r}: expected T_MIN,T_MAX in picoseconds (either may be empty)") from None
    if len(vals) != 2:
        raise UserInputError(f"{name} {text!r}: expected T_MIN,T_MAX in picoseconds (either may be empty)")
    return tuple(vals)


def recon_command(
    capture: Path = typer.Argument(..., help="Capture: an EXR stack directory or a y-tal HDF5 file (.h5/.hdf5)."),
    out: Path = typer.Option(..., "-o", "--out", help="Output directory (written atomically)."),
    method: str = typer.Option("bp", "--method", "-m",
                               help="bp (backprojection), fbp (filtered BP), lct / fk (confocal only), phasor, "
                                    "midpoint-lct / midpoint-fk (array captures via the midpoint approximation)."),
    voxel_size_m: Optional[float] = typer.Option(None, "--voxel-size-m", help="Cubic voxel side in metres."),
    voxels: Optional[str] = typer.Option(None, "--voxels", help="Voxels per axis: N or NX,NY,NZ (default 64)."),
    bounds: Optional[str] = typer.Option(
        None, "--bounds", help="xmin,xmax,ymin,ymax,zmin,zmax in metres (default: the wall extent, z from the "
                               "time axis)."),
    filter: Optional[str] = typer.Option(None, "--filter", help="paper (Gaussian, Laplacian, threshold) or none "
                                         "(default: paper for bp and midpoint-*, none for fbp, lct, fk and "
                                         "phasor, which filter in their own way)."),
    sigma_m: Optional[float] = typer.Option(None, "--sigma-m", help="Gaussian sigma of the paper filter, metres "
                                                                   "(default one voxel)."),
    threshold: Optional[str] = typer.Option(
        None, "--threshold", help="none | otsu | rel:F | abs:V (default rel:0.3, rel:0.1 for midpoint-fk; none with "
                                  "an explicit --filter none)."),
    complete: Optional[str] = typer.Option(
        None, "--complete", help="Close the surface behind the reconstructed front under a stated prior: "
                                 "elliptical cross-sections of aspect auto (estimated from the front) or a number "
                                 "in [0, 2] (1: round). The back is not in the data (docs/recon.md)."),
    ground_truth: Optional[Path] = typer.Option(
        None, "--ground-truth", help="Mesh (.obj/.ply/.stl/...) or points (.json/.npy/.csv) for metrics.json."),
    pileup_correction: bool = typer.Option(False, "--pileup-correction",
                                           help="Coates pile-up correction of a counts capture."),
    pulses: Optional[float] = typer.Option(None, "--pulses", help="Laser pulses for --pileup-correction "
                                                                  "(default from the manifest)."),
    blind_cycles: Optional[int] = typer.Option(None, "--blind-cycles", parser=whole_number("--blind-cycles"), metavar="<int>", help="Whole cycles the detector is blind after a detection, for "
                                     "--pileup-correction (default from the manifest's dead time and period)."),
    time_crop_ps: Optional[str] = typer.Option(None, "--time-crop-ps", help="Keep bins in T_MIN,T_MAX (ps)."),
    time_downsample: Optional[int] = typer.Option(None, "--time-downsample", parser=whole_number("--time-downsample"), metavar="<int>", help="Sum groups of K bins."),
    wavelength_m: Optional[float] = typer.Option(None, "--wavelength-m",
                                                 help="phasor: virtual wavelength, metres (default 4 pixel pitches)."),
    pulse_sigma_m: Optional[float] = typer.Option(None, "--pulse-sigma-m",
                                                  help="phasor: virtual pulse sigma, metres (default 1 wavelength)."),
    snr: Optional[float] = typer.Option(None, "--snr", help="lct: Wiener filter signal-to-noise ratio."),
    midpoint_pitch_m: Optional[float] = typer.Option(
        None, "--midpoint-pitch-m", help="midpoint-*: spacing of the midpoint grid, metres (default half a pixel)."),
    fbp_sigma_m: Optional[float] = typer.Option(None, "--fbp-sigma-m",
                                                help="fbp: width of the time filter, metres of path."),
    no_voxel_integration: bool = typer.Option(False, "--no-voxel-integration",
                                              help="bp: sample each ellipsoid at voxel centres only."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing output directory."),
    no_plots: bool = typer.Option(False, "--no-plots", help="Skip the PNG pictures."),
    seed: int = typer.Option(0, "--seed", parser=whole_number("--seed"), metavar="<int>", help="Seed of the mesh surface sampling for metrics."),
) -> None:
    """Reconstruct the hidden scene of a capture: volume.npz, PNG projections, depth map, metrics.json."""
    from recon.grid import parse_bounds
    from recon.pipeline import run

    if threshold is not None and not threshold.strip():
        raise UserInputError("--threshold '': expected none, otsu, rel:F (0 < F <= 1) or abs:V (V >= 0)")
    if voxels is not None and voxel_size_m is not None:
        raise UserInputError("give either --voxels or --voxel-size-m, not both")
    options = {"wavelength_m": wavelength_m, "pulse_sigma_m": pulse_sigma_m, "snr": snr, "fbp_sigma_m": fbp_sigma_m,
               "midpoint_pitch_m": midpoint_pitch_m,
               "voxel_integration": False if no_voxel_integration else None}
    rec, metrics, path = run(
        capture, out, method, bounds=parse_bounds(bounds) if bounds is not None else None, voxels=_voxels(voxels),
        voxel_size_m=voxel_size_m, filter=filter, sigma_m=sigma_m, threshold=threshold, complete=complete,
        ground_truth=ground_truth, pileup_correction=pileup_correction, pulses=pulses, blind_cycles=blind_cycles,
        time_crop_ps=_pair(time_crop_ps, "--time-crop-ps"),
        time_downsample=time_downsample, overwrite=overwrite, plots=not no_plots, seed=seed, **options)
    g = rec.grid
    nz, ny, nx = g.shape
    peak = rec.argmax_m()
    typer.echo(f"{method}: {nx}x{ny}x{nz} voxels (x,y,z) in {', '.join(f'{b:.4g}' for b in g.bounds)} m")
    typer.echo(f"maximum of the filtered volume at x={peak[0]:.4f} y={peak[1]:.4f} z={peak[2]:.4f} m")
    if metrics:
        keys = ("chamfer_m", "depth_mae_m", "iou", "localisation_error_m")
        shown = ", ".join(f"{k}={metrics[k]:.4g}" for k in keys if metrics.get(k) is not None)
        typer.echo(f"metrics: {shown}")
    typer.echo(f"wrote {path}")


def register(app: typer.Typer) -> None:
    app.command("recon")(recon_command)
