"""Where a test run's time goes to compiling: a pytest plug-in, by test file and by program.

    PYTHONPATH=benchmarks .venv/bin/python -m pytest -q -n 2 --dist loadfile -p compile_probe
    .venv/bin/python benchmarks/compile_probe.py          # sums the run's files into the table below

Each test process records JAX's own timings (`jax.monitoring`): XLA's backend
compile, tracing and lowering to MLIR, and reads from the compilation cache,
per test and per compiled program's name (``jit(scan)`` and ``jit(add)`` are
operations run op by op; ``jit(_fit_lanes_compiled)`` is a search's LM
program). It writes them to ``benchmarks/results/compile_probe/<pid>.json`` at
the end of its session; run without arguments, this file sums them over the
processes of the last run and writes ``benchmarks/results/compile_probe.json``.
A test that starts a `hybrid` command in a subprocess compiles there, out of
sight of this plug-in: its time counts as the test's wall time only.
"""

from __future__ import annotations

import collections
import json
import os
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
RAW = RESULTS / "compile_probe"
EVENTS = {
    "/jax/core/compile/backend_compile_duration": "compile_s",
    "/jax/core/compile/jaxpr_trace_duration": "trace_s",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower_s",
    "/jax/compilation_cache/cache_retrieval_time_sec": "cache_read_s",
}

_totals: collections.Counter = collections.Counter()
_programs: dict[str, list[float]] = collections.defaultdict(lambda: [0.0, 0])
_tests: list[dict] = []
_running: dict = {}  # the test in progress: its totals and clock at its start


def _listen(event, duration, fun_name=None, **_):
    key = EVENTS.get(event)
    if key is None:
        return
    _totals[key] += duration
    if key == "compile_s":
        entry = _programs[str(fun_name)]
        entry[0] += duration
        entry[1] += 1


def pytest_configure(config):
    import jax

    jax.monitoring.register_event_duration_secs_listener(_listen)
    if not hasattr(config, "workerinput"):  # the controller (or a run without xdist) starts afresh
        RAW.mkdir(parents=True, exist_ok=True)
        for old in RAW.glob("*.json"):
            old.unlink()


def pytest_runtest_protocol(item, nextitem):
    _running.update(before=dict(_totals), start=time.monotonic())


def pytest_runtest_teardown(item, nextitem):
    before = _running["before"]
    row = {"id": item.nodeid, "wall_s": time.monotonic() - _running["start"]}
    row.update({key: _totals[key] - before.get(key, 0.0) for key in EVENTS.values()})
    _tests.append(row)


def pytest_sessionfinish(session):
    RAW.mkdir(parents=True, exist_ok=True)
    out = {"tests": _tests, "programs": {k: v for k, v in _programs.items()}}
    (RAW / f"{os.getpid()}.json").write_text(json.dumps(out))


def summarise() -> dict:
    """The last run's processes summed: totals, by test file and by program."""
    files: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
    programs: dict[str, list[float]] = collections.defaultdict(lambda: [0.0, 0])
    totals: collections.Counter = collections.Counter()
    for path in sorted(RAW.glob("*.json")):
        data = json.loads(path.read_text())
        for row in data["tests"]:
            name = row["id"].split("::")[0]
            for key, value in row.items():
                if key != "id":
                    files[name][key] += value
                    totals[key] += value
            files[name]["tests"] += 1
        for name, (seconds, count) in data["programs"].items():
            programs[name][0] += seconds
            programs[name][1] += count
    by_file = sorted(files.items(), key=lambda kv: -kv[1]["wall_s"])
    by_program = sorted(programs.items(), key=lambda kv: -kv[1][0])
    return {
        "command": "PYTHONPATH=benchmarks pytest -q -n 2 --dist loadfile -p compile_probe; "
        "python benchmarks/compile_probe.py",
        "totals_s": {k: round(v, 1) for k, v in totals.items()},
        "programs_compiled": int(sum(c for _, c in programs.values())),
        "by_file": {name: {k: round(v, 1) for k, v in c.items()} for name, c in by_file},
        "by_program": {name: {"compile_s": round(s, 1), "count": int(c)} for name, (s, c) in by_program},
    }


if __name__ == "__main__":
    summary = summarise()
    (RESULTS / "compile_probe.json").write_text(json.dumps(summary, indent=1) + "\n")
    print(json.dumps(summary["totals_s"]), summary["programs_compiled"], "programs")
    for name, row in list(summary["by_file"].items())[:15]:
        print(f"{row['wall_s']:7.1f} s  compile {row['compile_s']:6.1f} s  {name}")
    for name, row in list(summary["by_program"].items())[:15]:
        print(f"{row['compile_s']:7.1f} s  {row['count']:5d}  {name}")
