"""A command's standard output, whose reader may leave before the command ends (``| head``)."""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator

__all__ = ["reader_may_leave"]


class _ReaderMayLeave:
    """sys.stdout for one command: where its reader leaves (``| head``), the rest goes nowhere and the work goes on.

    Python ignores SIGPIPE, so the next print raised BrokenPipeError and the
    command ended with "hybrid: error: BrokenPipeError" and none of its files
    (a probe's ``hybrid sensitivity ... | head -5``). What a command prints is a
    summary of what it writes: the files are the result, and they are written.
    """

    def __init__(self, stream):
        self._stream = stream

    def write(self, text: str) -> int:
        try:
            return self._stream.write(text)
        except BrokenPipeError:
            self._gone()
            return len(text)

    def flush(self) -> None:
        try:
            self._stream.flush()
        except BrokenPipeError:
            self._gone()

    def _gone(self) -> None:
        # the descriptor onto /dev/null: what the stream still holds (and its flush at exit) goes there
        devnull = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(devnull, self._stream.fileno())
        finally:
            os.close(devnull)

    def __getattr__(self, name):
        return getattr(self._stream, name)


@contextlib.contextmanager
def reader_may_leave() -> Iterator[None]:
    """`_ReaderMayLeave` as sys.stdout while the block runs."""
    stdout = sys.stdout
    sys.stdout = guarded = _ReaderMayLeave(stdout)
    try:
        yield
    finally:
        guarded.flush()  # what is still buffered, here: at the interpreter's exit a broken pipe is an error
        sys.stdout = stdout
