"""Option parsers shared by the sub-commands."""

from __future__ import annotations

import math



class BadOptionValue(Exception):
    """A malformed option value, found while typer parses the command line.

    Deliberately not a ``ValueError``: typer would wrap those into a multi-line usage panel;
    :func:`transient_mi.cli.main` prints this as one ``error: ...`` line, exit status 2.
    """


def whole_number(option: str):
    """A typer ``parser`` for integer options that also accepts integral float notation (``1e6``).

    ``1.5`` (or a non-number) is refused with one line naming the option and the value.
    """

    def parse(value) -> int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        text = str(value).strip()
        try:
            return int(text)
        except ValueError:
            pass
        try:
            f = float(text)
        except ValueError:
            raise BadOptionValue(f"{option} {text!r}: expected a whole number (e.g. 1000000 or 1e6)") from None
        if not (math.isfinite(f) and f.is_integer()):
            raise BadOptionValue(f"{option} {text}: expected a whole number (e.g. 1000000 or 1e6), not a fraction")
        return int(f)

    parse.__name__ = "integer"
    return parse


def noise_target_value(value: str, *, auto: bool = False):
    """``--noise-target`` of ``demo`` and ``study``: a finite number > 0, ``none`` (None: no target) or,
    with ``auto``, ``auto`` (returned as the word: the command's default); anything else is refused in one line
    naming the option and the value."""
    from transient_core.errors import UserInputError

    word = value.strip().lower()
    if word == "none":
        return None
    if auto and word == "auto":
        return "auto"
    try:
        r = float(value)
    except ValueError:
        r = float("nan")
    if not (math.isfinite(r) and r > 0):
        allowed = "a number > 0, auto or none" if auto else "a number > 0 or 'none'"
        raise UserInputError(f"--noise-target {value!r}: expected {allowed}")
    return r
