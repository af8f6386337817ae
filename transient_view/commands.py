"""The viewer's two commands, ``transient-mi view`` and ``transient-mi video`` (typer functions).

They are registered in the full command line (:mod:`transient_mi.cli`) and, for a fast start, run by
:mod:`transient_cli` without loading drjit or Mitsuba (nothing here needs them): :func:`main` is
that short path. User mistakes (:class:`transient_core.errors.UserInputError`) become one line
``error: ...`` with exit status 2, as in the full command line.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
import typer.main

__all__ = ["view", "video", "main", "click_exceptions", "usage_error_line"]

COMMANDS = ("view", "video")


def view(
    path: Path = typer.Argument(..., help="An EXR stack capture, a y-tal .h5 file, a recon output or a dataset "
                                           "(or demo) directory."),
    port: int = typer.Option(5006, "--port", help="TCP port (0: any free port)."),
    host: str = typer.Option("127.0.0.1", "--host", help="Address to listen on (default: this machine only)."),
    no_browser: bool = typer.Option(False, "--no-browser", help="Do not open a web browser."),
    ground_truth: Optional[Path] = typer.Option(None, "--ground-truth", help="Mesh to overlay and score "
                                                "reconstructions against (default: found beside the data)."),
) -> None:
    """Start the viewer on PATH and print its address (read-only; Ctrl+C stops it). See docs/view.md."""
    from transient_core.errors import UserInputError

    from transient_view import require_bokeh

    if not 0 <= port <= 65535:
        raise UserInputError(f"--port {port}: allowed 0..65535")
    require_bokeh()
    from transient_view.data import discover
    from transient_view.server import is_loopback, make_server

    lib = discover(path, ground_truth=ground_truth)
    try:
        server = make_server(lib, host=host, port=port)
    except OSError as e:
        raise UserInputError(f"--host {host} --port {port}: cannot listen there ({e.strerror or e})") from None
    shown = f"[{host}]" if ":" in host else host
    url = f"http://{shown}:{server.port}/"
    typer.echo(f"transient-mi view: {len(lib.captures)} capture(s), {len(lib.recons)} reconstruction(s) under "
               f"{lib.root}", err=True)
    if not is_loopback(host):
        typer.echo(f"warning: listening on {host}: anyone who can reach this machine can see the data", err=True)
    typer.echo(f"serving at {url} (Ctrl+C to stop)", err=False)
    import sys

    sys.stdout.flush()
    if not no_browser:
        import webbrowser

        server.io_loop.add_callback(lambda: webbrowser.open(url))
    try:
        server.io_loop.start()
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()


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
    from transient_view.video import write_video

    info = write_video(capture, out, spot=spot, fps=fps, stride=stride, first_bin=first_bin, last_bin=last_bin,
                       scale=scale, normalize=normalize, cmap=cmap)
    typer.echo(f"wrote {info['path']}: {info['n_frames']} frames of {info['width']}x{info['height']} px "
               f"at {info['fps']:g} fps (bins {info['bins'][0]}..{info['bins'][1]} step {info['bins'][2]})")


def click_exceptions():
    """``(ClickException, Exit, Abort)`` of the click that typer runs on (typer >= 0.16 vendors its own)."""
    import typer.core

    ck = getattr(typer.core, "_click", None)
    if ck is None:
        import click as ck
    exc = getattr(ck, "exceptions", ck)
    return exc.ClickException, getattr(exc, "Exit", typer.Exit), getattr(exc, "Abort", typer.Abort)


def _given_value(param, argv: list[str]):
    """The text the user gave for option ``param`` (last occurrence), or None."""
    opts = list(getattr(param, "opts", []) or []) + list(getattr(param, "secondary_opts", []) or [])
    if getattr(param, "param_type_name", "") != "option":
        return None
    found = None
    for i, a in enumerate(argv):
        for o in opts:
            if a == o and i + 1 < len(argv):
                found = argv[i + 1]
            elif a.startswith(o + "=") and o.startswith("--"):
                found = a[len(o) + 1:]
    return found


def usage_error_line(e, argv: list[str]) -> str:
    """One line for a click usage error: the parameter, the value given and what is allowed."""
    msg = " ".join(e.format_message().split())
    param = getattr(e, "param", None)
    if param is not None and type(e).__name__ == "BadParameter":
        name = (param.opts[-1] if getattr(param, "param_type_name", "") == "option" and param.opts
                else (param.human_readable_name or param.name).upper())
        value = _given_value(param, argv)
        what = e.message if hasattr(e, "message") else msg
        what = " ".join(str(what).split())
        shown = f" {value!r}" if value is not None else ""
        return f"{name}{shown}: {what[:1].lower() + what[1:]}"
    cmd = getattr(getattr(e, "ctx", None), "command_path", None)
    return f"{msg[:1].lower() + msg[1:]}" + (f" (see {cmd} --help)" if cmd else "")


def main(argv: list[str]) -> int:
    """Run ``view`` or ``video`` (``argv[0]``) with the rest of ``argv``; the exit status."""
    from transient_core.errors import UserInputError

    ClickException, Exit, Abort = click_exceptions()
    app = typer.Typer(add_completion=False, pretty_exceptions_enable=False)
    app.command("view")(view)
    app.command("video")(video)
    try:
        typer.main.get_command(app)(args=list(argv), standalone_mode=False, prog_name="transient-mi")
    except UserInputError as e:
        typer.echo(f"error: {e}", err=True)
        return 2
    except Exit as e:
        return e.exit_code
    except ClickException as e:
        typer.echo(f"error: {usage_error_line(e, list(argv))}", err=True)
        return e.exit_code
    except (Abort, KeyboardInterrupt):
        typer.echo("Aborted!", err=True)
        return 1
    return 0
