"""The one exception type for bad input.

Every check on user-supplied data (files, arrays, parameters, command-line
arguments) raises [`InputError`][hybrid.InputError] with one sentence that says what is wrong
and how to fix it. The CLI turns it into a single line on stderr and exit
status 2; library users can catch it like any ``ValueError``.
"""


class InputError(ValueError):
    """Bad user input: the message says what is wrong and how to fix it."""


class PluginError(InputError):
    """A plug-in's code failed or returned something unusable: one line naming the plug-in and its method.

    `original` is the exception the plug-in raised (None for a wrong result),
    kept for ``hybrid -v``. `plugin` is the class at fault when the message was
    written where its ``--physics`` or ``--effects`` spec is unknown (the command
    line puts the spec in front).
    """

    def __init__(self, message: str, original: BaseException | None = None, plugin: type | None = None):
        super().__init__(message)
        self.original = original
        self.plugin = plugin
