"""``transient-mi view``: a local web viewer of captures, detection and reconstruction (the command is
:func:`transient_view.commands.view`; :mod:`transient_cli` runs it without loading Mitsuba)."""

from __future__ import annotations

import typer

from transient_view.commands import view


def register(app: typer.Typer) -> None:
    app.command("view")(view)
