"""``transient-mi view``: a local web viewer of captures, detection and reconstruction."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer


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

    from transient_mi.view import require_bokeh

    if not 0 <= port <= 65535:
        raise UserInputError(f"--port {port}: allowed 0..65535")
    require_bokeh()
    from transient_mi.view.data import discover
    from transient_mi.view.server import is_loopback, make_server

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


def register(app: typer.Typer) -> None:
    app.command("view")(view)
