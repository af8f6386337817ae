"""``transient-mi video``: the time slices of a capture as a GIF or MP4 with a time stamp in ps."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer


def video(
    capture: Path = typer.Argument(..., help="An EXR stack capture directory or a y-tal .h5 file."),
    out: Path = typer.Option(..., "-o", "--out", help="Video to write: .gif (Pillow) or .mp4 (needs the view extra)."),
    spot: int = typer.Option(0, "--spot", help="Laser spot (stored file) to show."),
    fps: float = typer.Option(20.0, "--fps", help="Frames per second."),
    stride: int = typer.Option(1, "--stride", help="Show every STRIDE-th time bin."),
    first_bin: int = typer.Option(0, "--first-bin", help="First time bin shown."),
    last_bin: Optional[int] = typer.Option(None, "--last-bin", help="Last time bin shown (default: the last)."),
    scale: Optional[int] = typer.Option(None, "--scale", help="Screen pixels per SPAD pixel (default: >= 256 px wide)."),
    normalize: str = typer.Option("global", "--normalize", help="global (one brightness scale) or frame."),
    cmap: str = typer.Option("inferno", "--cmap", help="Matplotlib colour map."),
) -> None:
    """Write the time slices of one laser spot as a video, one frame per bin, stamped with its time in ps."""
    from transient_mi.view.video import write_video

    info = write_video(capture, out, spot=spot, fps=fps, stride=stride, first_bin=first_bin, last_bin=last_bin,
                       scale=scale, normalize=normalize, cmap=cmap)
    typer.echo(f"wrote {info['path']}: {info['n_frames']} frames of {info['width']}x{info['height']} px "
               f"at {info['fps']:g} fps (bins {info['bins'][0]}..{info['bins'][1]} step {info['bins'][2]})")


def register(app: typer.Typer) -> None:
    app.command("video")(video)
