"""The ``transient-mi`` command's front door.

``transient-mi view`` and ``transient-mi video`` need neither drjit nor Mitsuba: they run from
:mod:`transient_view.commands` without loading them (about a second less to the viewer's first
page). Every other command, and ``--help``, is the full command line, :mod:`transient_mi.cli`.
"""

from __future__ import annotations

import sys

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``transient-mi`` console script; the exit status."""
    args = sys.argv[1:] if argv is None else list(argv)
    if args and args[0] in ("view", "video"):
        from transient_view.commands import main as run_viewer_command

        return run_viewer_command(args)
    from transient_mi.cli import main as full

    return full(args)
