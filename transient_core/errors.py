"""Exceptions for mistakes in user input.

Anything raised as :class:`UserInputError` is reported by the command line as
one line (``error: ...``) with a non-zero exit status and no traceback. The
message must name the parameter, the value and what is allowed.
"""


class UserInputError(ValueError):
    """Bad input from the user: a parameter, file or value that is not allowed."""
