"""How many compiled programs a long-running process holds, and releasing them before they crash it.

Every compiled XLA CPU program keeps its machine code in memory maps, and
Linux allows a process `vm.max_map_count` of them (65,530 by default). A
diagnosis compiles about a dozen large programs (~8,000 maps); a script that
diagnoses recordings of many lengths in one process used to add that much
per call until LLVM failed to allocate and the process died (SIGSEGV).

`diagnose` pads recordings to a few lengths (`hybrid.core.bucket_length`),
so its programs depend on a *shape key* — the simulation's structure, the
sample rate and the padded lengths — rather than on each recording. A
[`ProgramBudget`][] remembers the shape keys whose programs are held; when a
call needs a new key and `held` keys already have programs, every compiled
program is released (`jax.clear_caches()`) before the call compiles its own.
It also releases them whenever the process holds more than `max_fraction` of
its allowed maps, whoever compiled them. A released program is compiled again
when it is needed next (or read back from the persistent compilation cache,
which the command line turns on). `hybrid.fit` and `hybrid.fit_batch` compile
for each recording's own length (no buckets: a windowed readout cannot be
padded); they keep their own budget of shape keys (`FIT_PROGRAMS`: the
recordings' lengths and the model's structure), so a script fitting many
lengths holds the programs of the last `FIT_HELD_SHAPES` of them, not of every
one (a probe's loop over 30 lengths grew by about 85 MB a fit, to 3.1 GB).
"""

from __future__ import annotations

import functools
import gc
import threading
from pathlib import Path

#: Shape keys whose programs a process keeps before releasing them all (`ProgramBudget`).
HELD_SHAPES = 2
#: Fraction of `vm.max_map_count` above which every compiled program is released.
MAX_MAP_FRACTION = 0.5


def memory_maps() -> int | None:
    """Memory maps this process holds (Linux: lines of /proc/self/maps), or None where that cannot be read."""
    try:
        with open("/proc/self/maps", "rb") as maps:
            return sum(1 for _ in maps)
    except OSError:
        return None


def map_limit() -> int | None:
    """`vm.max_map_count`, the most memory maps a process may hold (Linux), or None."""
    try:
        return int(Path("/proc/sys/vm/max_map_count").read_text().strip())
    except (OSError, ValueError):
        return None


def release_programs() -> None:
    """Drop every compiled program of this process (JAX's caches) and free their memory maps.

    Then glibc is asked to give the freed heap back to the system (`malloc_trim`, where the C library has
    it): freed, the blocks between live ones stayed resident, and a script diagnosing many lengths in one
    process held more after each release (`pytest tests/test_buckets.py -k heap`: 96 MB of such blocks).
    """
    import jax

    jax.clear_caches()
    gc.collect()
    _trim_heap()


@functools.cache
def _libc():
    """glibc, or None where this process has none (macOS, Windows, musl): then nothing is trimmed."""
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        return libc if hasattr(libc, "malloc_trim") else None
    except OSError:
        return None


def _trim_heap() -> None:
    libc = _libc()
    if libc is not None:
        libc.malloc_trim(0)


def crowded(max_fraction: float | None = None) -> bool:
    """Whether this process holds more than `max_fraction` (default `MAX_MAP_FRACTION`) of its allowed maps.

    False where Linux does not tell (no /proc): nothing to guard against there.
    """
    maps, limit = memory_maps(), map_limit()
    fraction = MAX_MAP_FRACTION if max_fraction is None else max_fraction
    return maps is not None and limit is not None and limit > 0 and maps > fraction * limit


class ProgramBudget:
    """The shape keys whose compiled programs this process holds, and when to release them.

    **Arguments:**

    - `held`: shape keys kept; a call with a new key beyond them releases every program first.
    - `max_fraction`: release everything when the process holds more than this
      fraction of `vm.max_map_count` maps (where Linux tells).

    `admit(key)` is called before a call compiles; it returns True when it released programs.
    `releases` counts them (for tests and benchmarks).
    """

    def __init__(self, held: int = HELD_SHAPES, max_fraction: float = MAX_MAP_FRACTION):
        self.held = int(held)
        self.max_fraction = float(max_fraction)
        self.keys: list = []
        self.releases = 0
        self._lock = threading.Lock()

    def admit(self, key) -> bool:
        with self._lock:
            full = crowded(self.max_fraction)
            if key in self.keys and not full:
                self.keys.remove(key)
                self.keys.append(key)  # most recently used last
                return False
            released = full or len(self.keys) >= self.held
            if released:
                release_programs()
                self.releases += 1
                self.keys = []
            if key in self.keys:
                self.keys.remove(key)
            self.keys.append(key)
            return released


#: The budget `diagnose` keeps (one per process).
DIAGNOSE_PROGRAMS = ProgramBudget()
#: Shape keys whose programs `fit` and `fit_batch` keep (a fit's are smaller than a diagnosis's).
FIT_HELD_SHAPES = 4
#: The budget `fit` and `fit_batch` keep (one per process).
FIT_PROGRAMS = ProgramBudget(held=FIT_HELD_SHAPES)


def compile_counter() -> dict:
    """``{"s": seconds, "programs": count}`` of XLA's backend compiles from now on, kept up to date.

    Summed from JAX's own ``backend_compile_duration`` events (`jax.monitoring`): a
    call's running time is its seconds less what it added here (a program read
    back from the persistent cache counts too, as a short compile).
    """
    from jax import monitoring

    counter: dict = {"s": 0.0, "programs": 0}

    def listen(event: str, duration_secs: float, **_: str | int) -> None:
        if event == "/jax/core/compile/backend_compile_duration":
            counter["s"] += duration_secs
            counter["programs"] += 1

    monitoring.register_event_duration_secs_listener(listen)
    return counter


@functools.cache
def process_compiles() -> dict:
    """One `compile_counter` for the whole process: library code reads the difference over a call.

    A counter per call would leave one more `jax.monitoring` listener behind each time.
    """
    return compile_counter()
