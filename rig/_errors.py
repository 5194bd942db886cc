"""Errors of the rig: every fault becomes one `RigError` with one clear line."""

from __future__ import annotations

from typing import TYPE_CHECKING

from hybrid import InputError

if TYPE_CHECKING:
    from ._playback import PlayReport

__all__ = ["RigError", "Terminated"]


class RigError(InputError):
    """A hardware or acquisition fault (serial port, board, camera, tracking).

    A subclass of `hybrid.InputError`, so the command line prints it as
    one line and exits with status 2.
    """

    #: The partial report of a failed `Board.play`, attached there (an annotation only:
    #: other RigErrors have no such attribute, so read it with ``getattr(error, "report", None)``).
    report: PlayReport


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread by the command line's handler so that the
    clean-up written for Ctrl-C (close the recording, flag it interrupted) runs."""

    def __str__(self) -> str:
        return "terminated by SIGTERM"
