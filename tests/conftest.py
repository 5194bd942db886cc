"""Tests run in float64: the product of 46 RC stages needs it (entry points choose).

Compiled programs are shared between the test processes of one run, and only
that run: the controller makes an empty JAX compilation cache in a temporary
folder and removes it at the end; every worker (and every `hybrid` command a
test starts, through ``HYBRID_JAX_CACHE``) reads and writes it. Under
``pytest -n 2`` both workers compile the diagnose search and the fitters for
the same shapes; with the cache each program is compiled once per run. Every
program is kept, an operation run op by op too (`min_compile_time` 0, as the
`hybrid` command has it): a quiet `make test` took 529 s against 570 s keeping
only those that compiled in over 0.5 s, one run each, 50 minutes apart. Nothing
is written into the user's ~/.cache, and every run starts cold, as CI does.
A test that needs a cold compile in its own process (the hang guard) turns the
cache off for its subprocess. A run stopped by SIGTERM (a CI timeout, `kill`)
removes its cache as Ctrl-C does; one killed outright cannot, and the next run
removes it: the folder's name holds the controller's process id
(`stale_caches`), and a folder whose process is gone is left over.

Memory maps: every compiled program holds some, and a worker that runs many
test files used to end a run with 43,000–53,000 of Linux's 65,530 (one crashed
in a compilation-cache write). After each test file a worker that holds more
than `hybrid.util._programs.MAX_MAP_FRACTION` of its limit releases its
compiled programs (a later test reads them back from the run's cache), and
each worker's maps at the end of the run are printed in the summary.

Order: under ``--dist loadfile`` pytest-xdist hands out whole files, by
default those with the most tests first, which left the one-test files of
44–48 s (a diagnose each) for the end of the run, one worker idle beside them.
The heaviest files (`HEAVY_FIRST`) are handed out first instead and the run
ends on small files, so the two workers finish together; each file's own
tests keep their order.
"""

import collections
import os
import re
import shutil
import signal
import tempfile
from pathlib import Path

# One CPU device for every process of the run, the `hybrid` commands the tests start included: the two
# workers already keep both cores busy, and a command that spread its lanes over a device per core
# (`hybrid.use_cpu_cores`) would only run three threads on two cores. The lanes on several devices are
# `tests/test_lane_devices.py`'s, and the hang guard runs its command as a user would (`test_never_hang.py`).
os.environ.setdefault("JAX_NUM_CPU_DEVICES", "1")

import jax  # after the device count: JAX reads it when it is imported
import pytest

from hybrid import use_quick_compiles
from hybrid.util._programs import MAX_MAP_FRACTION, map_limit, memory_maps, release_programs

CACHE_ENV = "HYBRID_JAX_CACHE"
#: The run's compilation cache: ``hybrid-test-jax-cache-<controller pid>-<random>`` in the temporary folder.
CACHE_PREFIX = "hybrid-test-jax-cache-"


def stale_caches(folder: str | os.PathLike[str] | None = None) -> list[Path]:
    """The test runs' compilation caches in `folder` (default: the temporary folder) whose controller is gone.

    A run killed outright (SIGKILL, a machine's OOM killer) cannot remove its cache
    (39–46 MB each); the next run does. A folder whose name holds no process id, or
    the id of a live process (another run beside this one), is left alone.
    """
    out = []
    for path in Path(folder or tempfile.gettempdir()).glob(CACHE_PREFIX + "*"):
        match = re.match(rf"{CACHE_PREFIX}(\d+)-", path.name)
        if not (match and path.is_dir()):
            continue
        try:
            os.kill(int(match[1]), 0)
        except ProcessLookupError:
            out.append(path)
        except OSError:  # alive, another user's
            pass
    return out


def _stop_on_sigterm(number, frame):
    """SIGTERM ends the run as Ctrl-C does: pytest's cleanup runs (`pytest_unconfigure` removes the cache)."""
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # a second SIGTERM ends the process at once
    raise KeyboardInterrupt


#: The files that take longest, heaviest first. Seconds: each file's share of the 60 slowest tests
#: of a quiet `pytest -q -n 2 --dist loadfile --durations=60` on the 2-core machine (955 tests,
#: 588 s), before issue 30's item 3 made test_diagnose and test_never_hang cheaper. A file not
#: named here follows them, those with the most tests first (xdist's own order).
HEAVY_FIRST = (
    "test_diagnose.py",  # 274 s: eight searches and a CLI report
    "test_never_hang.py",  # 97 s: a cold CLI diagnose of two recordings
    "test_fit.py",  # 88 s
    "test_open_world.py",  # 60 s
    "test_open_world_pairs.py",  # 48 s: one test
    "test_batch.py",  # 48 s
    "test_effects.py",  # 44 s
    "test_compile_once.py",  # 44 s: one test
    "test_solvers.py",  # 33 s: old and new spellings fitted side by side (added by issue 32)
    "test_plugin_diagnose.py",  # 30 s
    "test_inside_effects.py",  # ~90 s: a CLI diagnose and refit of the docs' friction plug-in (issue 31)
    "test_plugin_from_docs.py",  # 27 s: a CLI fit and a CLI diagnose (added by issue 32)
    "test_buckets.py",  # 28 s
    "test_ambiguity.py",  # ~45 s alone: two diagnoses, three designs and a CLI design (issue 35)
    "test_diagnose_starts.py",  # 25 s
    "test_fit_interrupt.py",  # 16 s
    "test_style.py",  # 11 s: mypy (added by issue 32)
    "test_cli_mapping.py",  # 15 s
    "test_sensitivity.py",  # 14 s
)

jax.config.update("jax_enable_x64", True)


def pytest_configure(config):
    # XLA:CPU's quick compiles, as the `hybrid` command has (`hybrid.use_quick_compiles`): about 45 % of
    # the suite's time was XLA compiling, and they compile the project's programs in about half the
    # time. Before any JAX work (XLA reads XLA_FLAGS when its backend starts); the workers and the
    # commands the tests start inherit it.
    use_quick_compiles()
    if not hasattr(config, "workerinput"):  # the controller, or a run without xdist
        for path in stale_caches():
            shutil.rmtree(path, ignore_errors=True)
        where = tempfile.mkdtemp(prefix=f"{CACHE_PREFIX}{os.getpid()}-")
        config._hybrid_jax_cache = where
        if signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:
            signal.signal(signal.SIGTERM, _stop_on_sigterm)
        os.environ[CACHE_ENV] = where  # workers start after this and inherit it
    jax.config.update("jax_compilation_cache_dir", os.environ[CACHE_ENV])
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    if hasattr(config.option, "loadscopereorder"):  # pytest-xdist: hand files out in the order below
        config.option.loadscopereorder = False


def pytest_collection_modifyitems(config, items):
    """The files of `HEAVY_FIRST` first, in its order, then the others with the most tests first."""
    counts = collections.Counter(item.path for item in items)

    def rank(item):
        name = item.path.name
        heavy = HEAVY_FIRST.index(name) if name in HEAVY_FIRST else len(HEAVY_FIRST)
        return heavy, -counts[item.path], str(item.path)

    items.sort(key=rank)  # stable: a file's tests keep their order


def pytest_unconfigure(config):
    where = getattr(config, "_hybrid_jax_cache", None)
    if where:
        shutil.rmtree(where, ignore_errors=True)


@pytest.fixture(autouse=True, scope="module")
def _release_programs_when_crowded():
    """After each test file: release the worker's compiled programs if it holds too many memory maps."""
    yield
    maps, limit = memory_maps(), map_limit()
    if maps is not None and limit and maps > MAX_MAP_FRACTION * limit:
        release_programs()


def pytest_sessionfinish(session):
    workeroutput = getattr(session.config, "workeroutput", None)
    if workeroutput is not None:  # an xdist worker: tell the controller how many maps it holds
        workeroutput["memory_maps"] = memory_maps()


_worker_maps = {}


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node, error):
    _worker_maps[node.gateway.id] = getattr(node, "workeroutput", {}).get("memory_maps")


def pytest_terminal_summary(terminalreporter):
    maps = dict(_worker_maps) if _worker_maps else {"main": memory_maps()}
    limit = map_limit()
    text = ", ".join(f"{k} {v}" for k, v in sorted(maps.items()))
    terminalreporter.write_line(f"memory maps at the end of the run: {text} (limit {limit})")
