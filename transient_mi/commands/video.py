"""``transient-mi video``: the time slices of a capture as a GIF or MP4 with a time stamp in ps (the
command is :func:`transient_view.commands.video`; :mod:`transient_cli` runs it without loading Mitsuba)."""

from __future__ import annotations

import typer

from transient_view.commands import video


def register(app: typer.Typer) -> None:
    app.command("video")(video)
