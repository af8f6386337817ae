"""``transient-mi export``: a capture in another layout (y-tal HDF5)."""

from __future__ import annotations

from pathlib import Path

import typer

FORMATS = ("ytal",)


def export(
    capture: Path = typer.Argument(..., help="Capture: an EXR stack directory (or any file recon reads)."),
    output: Path = typer.Argument(..., help="File to write, e.g. capture.h5."),
    to: str = typer.Option(..., "--to", help="Layout to write: ytal (y-tal's HDF5_TAL)."),
    compression: int = typer.Option(0, "--compression", help="gzip level 0-9 of the histograms (0: none)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing OUTPUT file."),
) -> None:
    """Write CAPTURE to OUTPUT in another layout (atomically; streamed one laser spot at a time).

    A confocal capture is written with the laser grid equal to the sensor grid, so y-tal sees it as confocal."""
    from recon import load_capture
    from transient_core.lock import output_lock
    from transient_core.errors import UserInputError
    from recon.io.ytal import write_ytal

    if to not in FORMATS:
        raise UserInputError(f"--to {to!r}: allowed {', '.join(FORMATS)}")
    if output.suffix.lower() not in (".h5", ".hdf5"):
        raise UserInputError(f"OUTPUT {output}: a y-tal file needs the suffix .h5 or .hdf5")
    if output.is_dir():
        raise UserInputError(f"OUTPUT {output}: is a directory; give a file name such as {output / 'capture.h5'}")
    if output.exists() and not overwrite:
        raise UserInputError(f"OUTPUT {output}: exists; pass --overwrite to replace it")
    if not 0 <= compression <= 9:
        raise UserInputError(f"--compression {compression}: must be 0-9")
    cap = load_capture(capture)
    with output_lock(output, option="OUTPUT"):
        path = write_ytal(cap, output, compression=compression)
    typer.echo(f"wrote {path}: {cap.describe()}")


def register(app: typer.Typer) -> None:
    app.command("export")(export)
