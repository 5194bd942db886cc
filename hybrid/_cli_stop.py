"""Stopping `hybrid fit` early without losing it: SIGINT, SIGTERM and ``--time-limit``.

[`FitStop`][] is the `stop` function [`hybrid.fit`][] looks at between LM steps.
Inside its `with` block the first SIGINT or SIGTERM only sets a flag (a second
one acts at once, as if there were no handler); once a signal has come or the
time limit has passed, the fit ends after the step it is in and returns the
best model so far, which ``hybrid fit`` saves to ``<out stem>.partial.eqx``
(never over ``--out``) and then exits with `exit_status`.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from types import FrameType
from typing import Any, NoReturn

#: Exit status of a fit stopped by ``--time-limit`` (as GNU ``timeout``); a signal gives 128 + its number.
TIME_LIMIT_EXIT_STATUS = 124
SIGNALS = (signal.SIGINT, signal.SIGTERM)


def partial_path(out) -> str:
    """Where a stopped fit saves its best model: ``m.eqx`` -> ``m.partial.eqx``."""
    text = str(out)
    stem = text[: -len(".eqx")] if text.lower().endswith(".eqx") else text
    return f"{stem}.partial.eqx"


class FitStop:
    """Context manager and `stop` function: true once SIGINT/SIGTERM came or `time_limit` s have passed.

    - `time_limit`: seconds from entering the block (None: no limit).
    - `reason`: ``"SIGINT"``, ``"SIGTERM"`` or ``"--time-limit"`` once stopped, else None.
    - `exit_status`: 130 (SIGINT), 143 (SIGTERM) or `TIME_LIMIT_EXIT_STATUS` — distinct from
      2 (bad input) and 3 (the watchdog's stall).
    """

    def __init__(self, time_limit: float | None = None):
        self.time_limit = time_limit
        self.signal = None
        self.timed_out = False
        self._previous: dict[int, Callable[[int, FrameType | None], Any] | int | None] = {}
        self._deadline = None

    def __enter__(self):
        if self.time_limit is not None:
            self._deadline = time.monotonic() + self.time_limit
        if threading.current_thread() is threading.main_thread():  # handlers can only be set there
            for sig in SIGNALS:
                self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc):
        self._restore()
        return False

    def _restore(self):
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous = {}

    def _handle(self, signum, frame):
        if self.signal is None:
            self.signal = signum
            return
        self._restore()  # a second signal: what it would have done without us
        if signum == signal.SIGINT:
            raise KeyboardInterrupt
        os.kill(os.getpid(), signum)

    def __call__(self) -> bool:
        if self._deadline is not None and not self.timed_out and time.monotonic() >= self._deadline:
            self.timed_out = True
        return self.signal is not None or self.timed_out

    @property
    def reason(self) -> str | None:
        if self.signal is not None:
            return signal.Signals(self.signal).name
        return "--time-limit" if self.timed_out else None

    @property
    def exit_status(self) -> int:
        if self.signal is not None:
            return 128 + int(self.signal)
        return TIME_LIMIT_EXIT_STATUS

    def exit(self, said: str) -> NoReturn:
        """One line on stderr, ``hybrid: {said}; exit status N``, then exit with `exit_status`."""
        print(f"hybrid: {said}; exit status {self.exit_status}", file=sys.stderr, flush=True)
        raise SystemExit(self.exit_status)
