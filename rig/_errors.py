"""Errors of the rig: every fault becomes one :class:`RigError` with one clear line."""

from __future__ import annotations

from hybrid import InputError

__all__ = ["RigError"]


class RigError(InputError):
    """A hardware or acquisition fault (serial port, board, camera, tracking).

    A subclass of :class:`hybrid.InputError`, so the command line prints it as
    one line and exits with status 2.
    """
