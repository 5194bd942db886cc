"""The `hybrid` and `rig` console scripts: a Ctrl-C while a command starts is acted on, never lost.

Both commands import JAX before their `main` runs (a second or more). Python's own
SIGINT handler raises KeyboardInterrupt wherever the main thread is: inside an
import that is a traceback, and inside a callback that JAX runs during garbage
collection it is printed as "Exception ignored" and lost — the command then ran
on (`rig record` drove the strip for the whole drive, `hybrid simulate` wrote
its file and exited 0). So this module, which imports nothing heavy, is what the
console scripts call: while the command's module is imported a Ctrl-C is only
remembered, and one remembered then ends the command in one line, exit status
130, before it has done anything. From then on a Ctrl-C raises KeyboardInterrupt
as before and is remembered too; where one was swallowed, the next
`hybrid.util.stage` call in the main thread (every stage of a command, every
frame of a recording) raises it again (`take_interrupt`).
"""

from __future__ import annotations

import importlib
import os
import signal
import sys
import threading

_pending = threading.Event()  # a Ctrl-C seen and not yet raised where it cannot be lost


def on_sigint_starting(signum, frame) -> None:
    """SIGINT while the command's module is imported: remembered only."""
    _pending.set()


def on_sigint(signum, frame) -> None:
    """SIGINT while the command runs: KeyboardInterrupt, as Python's own handler, and remembered."""
    _pending.set()
    raise KeyboardInterrupt


def _quiet_about_interrupts(hook):
    """`sys.unraisablehook` that says nothing of a KeyboardInterrupt raised where Python cannot raise it (a
    callback JAX runs during garbage collection): it is remembered (`on_sigint`) and raised again at the
    next `hybrid.util.stage`. Python's own hook printed its traceback beside the command's one line (a probe:
    12 lines on stderr for one Ctrl-C). Anything else goes to `hook`."""

    def unraisable(info) -> None:
        if not (isinstance(info.exc_value, KeyboardInterrupt) and _pending.is_set()):
            hook(info)

    return unraisable


def take_interrupt() -> bool:
    """Whether a Ctrl-C is pending (raised where Python may have swallowed it); it is no longer, after."""
    pending = _pending.is_set()
    _pending.clear()
    return pending


def _launch(module: str, name: str) -> int:
    main_thread = threading.current_thread() is threading.main_thread()
    if main_thread:
        signal.signal(signal.SIGINT, on_sigint_starting)
    try:
        main = importlib.import_module(module).main
    except (
        Exception
    ) as error:  # the package itself or a dependency fails to import: one line, not a traceback
        if any(a in ("-v", "--verbose") for a in sys.argv[1:]):
            raise
        print(
            f"{name}: error: the command could not start: importing {module} raised {type(error).__name__}: "
            f"{error}; the installation is broken or incomplete: reinstall it (make install, or pip install -e . "
            "in the repository; add -v to see the traceback)",
            file=sys.stderr,
        )
        return 1
    finally:
        if main_thread:
            signal.signal(signal.SIGINT, on_sigint)
    if take_interrupt():
        print(f"{name}: interrupted while starting; nothing was done", file=sys.stderr)
        return 130
    sys.unraisablehook = _quiet_about_interrupts(sys.unraisablehook)
    code = main()
    if code == 130:  # interrupted: what it wrote is staged and cleared, its one line said
        # No interpreter teardown: after a Ctrl-C inside XLA's compiling, tearing JAX down could end in a
        # segmentation fault (a probe: 2 of 10 early Ctrl-Cs ended with signal 11 after the one line).
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(130)
    return code


def hybrid() -> int:
    """The `hybrid` command."""
    return _launch("hybrid.cli", "hybrid")


def rig() -> int:
    """The `rig` command."""
    return _launch("rig.cli", "rig")
