"""The one exception type for bad input.

Every check on user-supplied data (files, arrays, parameters, command-line
arguments) raises [`InputError`][hybrid.InputError] with one sentence that says what is wrong
and how to fix it. The CLI turns it into a single line on stderr and exit
status 2; library users can catch it like any ``ValueError``.
"""


class InputError(ValueError):
    """Bad user input: the message says what is wrong and how to fix it."""
