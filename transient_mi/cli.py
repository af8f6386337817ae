"""The ``transient-mi`` command line.

Sub-commands live in :mod:`transient_mi.commands` (one module each, with a
``register(app)`` function). User mistakes (:class:`recon.errors.UserInputError`)
are printed as one line ``error: ...`` with exit status 2 and no traceback.
"""

from __future__ import annotations

import importlib
import pkgutil
import sys

import typer

from recon.errors import UserInputError

app = typer.Typer(
    name="transient-mi",
    help="Transient (time-of-flight) rendering, SPAD detection and NLOS reconstruction.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _register_commands() -> None:
    from . import commands

    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"transient_mi.commands.{info.name}")
        reg = getattr(mod, "register", None)
        if reg is not None:
            reg(app)


@app.callback()
def _root() -> None:
    """Transient (time-of-flight) rendering, SPAD detection and NLOS reconstruction."""


_register_commands()


def fail(message: str, code: int = 2) -> "typer.Exit":
    """Print ``error: message`` on stderr and return an Exit to raise."""
    typer.echo(f"error: {message}", err=True)
    return typer.Exit(code)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``transient-mi`` console script.

    Usage errors are reported by typer (exit status 2); a
    :class:`~recon.errors.UserInputError` raised by a command becomes
    ``error: <message>`` on stderr and exit status 2.
    """
    try:
        app(args=argv, standalone_mode=True)
    except UserInputError as e:
        typer.echo(f"error: {e}", err=True)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
