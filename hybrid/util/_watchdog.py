"""Long commands never hang in silence: a heartbeat while they work, an error if they stall.

[`Watchdog`][] runs beside a command (the CLI wraps `fit`, `diagnose`,
`table2` and `sensitivity` in one). Every `heartbeat` seconds it prints one
line to stderr — the command, the stage it is in ([`stage`][]), the wall time
and the CPU time so far — so a user sees that work is being done even while
one compiled program runs for minutes with nothing else to say.

It also watches the process's CPU time (all threads). Work of this package is
never idle: a compiled program, a compilation or a file write keeps at least
one core busy. If CPU time grows by less than `idle_fraction` of the wall time
for `stall` seconds, the process is stuck — as it was when jaxlib 0.10's
CPU runtime deadlocked in `diagnose` (issue 20, `experiments/xla_cpu_deadlock.py`):
every thread parked on a futex, forever. The watchdog then prints one line
that says so and where, and ends the process with exit status 3
(`os._exit`: the main thread is blocked inside XLA and cannot be interrupted).
A stretch in which the process did not run at all (suspended, or the machine
asleep: the watchdog's own sleep overran by far) restarts the count.

The thresholds come from the environment for unusual machines:
``HYBRID_HEARTBEAT_S`` (default 30) and ``HYBRID_STALL_S`` (default 300; 0
turns the stall check off).
"""

from __future__ import annotations

import os
import sys
import threading
import time

#: Exit status when a stall is detected (2 is bad input, 130 an interrupt). No plug-in can forge it:
#: the command line reports a plug-in's ``sys.exit(3)`` or ``os._exit(3)`` with exit status 2
#: (`hybrid.physics._plugins.exit_guard`), and a stall always prints its line first.
STALL_EXIT_STATUS = 3

_stage = {"text": "starting"}


def stage(text: str) -> None:
    """Name what the running command is doing now (shown by the heartbeat and a stall report).

    In the main thread of a command started by its console script (`hybrid_launch`), a Ctrl-C that
    Python swallowed (raised inside a garbage-collection callback of JAX's) is raised here.
    """
    _stage["text"] = text
    launch = sys.modules.get("hybrid_launch")  # not imported: the library used from Python
    if (
        launch is not None
        and threading.current_thread() is threading.main_thread()
        and launch.take_interrupt()
    ):
        raise KeyboardInterrupt


def current_stage() -> str:
    return _stage["text"]


def _seconds_from_env(name: str, default: float) -> float:
    text = os.environ.get(name, "").strip()
    if not text:
        return default
    try:
        value = float(text)
    except ValueError:
        return default
    return value if value >= 0 else default


class Watchdog:
    """Context manager: heartbeat lines on `stream`, and exit status 3 on a stall.

    **Arguments:**

    - `command`: shown in every line (e.g. ``"hybrid diagnose"``).
    - `heartbeat`: seconds between heartbeat lines; 0 or `quiet` prints none.
    - `stall`: seconds of (almost) no CPU work after which the process is
      declared stuck; 0 turns the check off.
    - `idle_fraction`: CPU seconds per wall second below which time counts as idle.
    - `quiet`: no heartbeat (the stall check still runs: a hang is never quiet).
    - `on_stall`: called with the message instead of exiting (tests).
    """

    def __init__(
        self,
        command: str,
        *,
        heartbeat: float | None = None,
        stall: float | None = None,
        idle_fraction: float = 0.02,
        quiet: bool = False,
        stream=None,
        on_stall=None,
    ):
        self.command = command
        self.heartbeat = _seconds_from_env("HYBRID_HEARTBEAT_S", 30.0) if heartbeat is None else heartbeat
        self.stall = _seconds_from_env("HYBRID_STALL_S", 300.0) if stall is None else stall
        self.idle_fraction = idle_fraction
        self.quiet = quiet
        self.stream = sys.stderr if stream is None else stream
        self.on_stall = on_stall
        self._stop = threading.Event()
        self._thread = None

    def __enter__(self):
        stage("starting")
        if (self.heartbeat > 0 and not self.quiet) or self.stall > 0:
            self._thread = threading.Thread(target=self._run, name="hybrid-watchdog", daemon=True)
            self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        return False

    def _run(self):
        t0 = time.monotonic()
        tick = min(x for x in (self.heartbeat if not self.quiet else 0, self.stall / 10, 5.0) if x > 0)
        last_beat = t0
        idle_since = None
        wall_prev, cpu_prev = t0, time.process_time()
        while not self._stop.wait(tick):
            wall, cpu = time.monotonic(), time.process_time()
            step = wall - wall_prev
            busy = (cpu - cpu_prev) >= self.idle_fraction * step
            if step > 3 * tick + 5:  # we did not run for a while (suspended): not a stall
                idle_since = None
            elif busy:
                idle_since = None
            elif idle_since is None:
                idle_since = wall_prev
            wall_prev, cpu_prev = wall, cpu
            if self.stall > 0 and idle_since is not None and wall - idle_since >= self.stall:
                message = (
                    f"{self.command}: error: no CPU work for {wall - idle_since:.0f} s while "
                    f"{current_stage()} ({wall - t0:.0f} s in): the process is stuck (a deadlock "
                    f"in the XLA runtime looks like this); stopping instead of hanging. Please report "
                    f"it with your jax/jaxlib versions (see experiments/xla_cpu_deadlock.py)."
                )
                if self.on_stall is not None:
                    self.on_stall(message)
                    return
                print(message, file=self.stream, flush=True)
                os._exit(STALL_EXIT_STATUS)
            if self.heartbeat > 0 and not self.quiet and wall - last_beat >= self.heartbeat:
                last_beat = wall
                print(
                    f"{self.command}: still working: {current_stage()} ({wall - t0:.0f} s, CPU {cpu:.0f} s)",
                    file=self.stream,
                    flush=True,
                )
