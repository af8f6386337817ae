"""The ``transient-mi`` command line.

Sub-commands live in :mod:`transient_mi.commands` (one module each, with a
``register(app)`` function). User mistakes (:class:`transient_core.errors.UserInputError`)
are printed as one line ``error: ...`` with exit status 2 and no traceback.
"""

from __future__ import annotations

import importlib
import pkgutil
import sys

import typer
import typer.main

from transient_core.errors import UserInputError

from .commands._options import BadOptionValue

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


def _adjust(cmd) -> None:
    """Show flags (``--resume``, ``--help``) as flags in ``--help``, without a ``<bool>`` value type
    (recursively over sub-commands)."""
    for p in getattr(cmd, "params", []):
        if getattr(p, "is_flag", False):
            p.metavar = ""
    orig = cmd.get_help_option

    def get_help_option(ctx, _orig=orig):
        opt = _orig(ctx)
        if opt is not None:
            opt.metavar = ""
        return opt

    cmd.get_help_option = get_help_option
    for sub in getattr(cmd, "commands", {}).values():
        _adjust(sub)


def command():
    """The click command behind :data:`app`, adjusted by :func:`_adjust`."""
    cmd = typer.main.get_command(app)
    _adjust(cmd)
    return cmd


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``transient-mi`` console script.

    Usage errors (a malformed value, an unknown option, a missing argument) and a
    :class:`~transient_core.errors.UserInputError` raised by a command become one line
    ``error: <message>`` on stderr and exit status 2 (no traceback, no usage panel).
    """
    from transient_view.commands import click_exceptions, usage_error_line

    ClickException, Exit, Abort = click_exceptions()
    args = sys.argv[1:] if argv is None else list(argv)
    try:
        command()(args=args, standalone_mode=False, prog_name="transient-mi")
    except (UserInputError, BadOptionValue) as e:
        typer.echo(f"error: {e}", err=True)
        return 2
    except Exit as e:
        return e.exit_code
    except ClickException as e:
        if type(e).__name__ == "NoArgsIsHelpError":  # `transient-mi` (or `study`) alone: the help, as before
            e.show()
            return e.exit_code
        typer.echo(f"error: {usage_error_line(e, args)}", err=True)
        return e.exit_code
    except Abort:
        typer.echo("Aborted!", err=True)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
