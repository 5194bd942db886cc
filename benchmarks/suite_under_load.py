"""`make test` on fresh clones, back to back, while `hybrid diagnose` processes load the machine (issue 30).

    python benchmarks/suite_under_load.py [--runs 3] [--load 2] [--duration 300] [--timeout 5400]

What CI does, `--runs` times in a row: a fresh clone of this repository's
committed HEAD with `../shared` beside it, then `CI=true bash .ci/run` (which
makes the virtual environment and runs `make test`) with no standard input.
Meanwhile `--load` loops each run `hybrid diagnose` on a 5-minute, 30 Hz
recording (`_common.relaxing_strip`), one after another, for the whole time:
the machine is busier than CI's. A run that has not finished after `--timeout`
seconds (CI's limit) is killed and counts as a hang.

Reported per run: exit status, seconds, pytest's passed/failed counts and its
own seconds, the memory maps each xdist worker held at the end (the suite's
summary line) and how many diagnoses the load finished meanwhile. Each clone
is removed after its run. Writes `benchmarks/results/suite_under_load.json`
once all runs are done.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import _common as c

ROOT = Path(__file__).resolve().parents[1]


class _Load(threading.Thread):
    """`hybrid diagnose RECORDING` in a fresh process, again and again, until stopped."""

    def __init__(self, recording: Path, folder: Path):
        super().__init__(daemon=True)
        self.recording, self.folder = recording, folder
        self.stop = threading.Event()
        self.finished: list[int] = []  # the exit status of each diagnosis
        self._proc: subprocess.Popen | None = None

    def run(self):
        env = {**os.environ, "HYBRID_JAX_CACHE": str(self.folder / "cache")}
        while not self.stop.is_set():
            out = self.folder / "out"
            shutil.rmtree(out, ignore_errors=True)
            self._proc = subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "hybrid.cli",
                    "diagnose",
                    str(self.recording),
                    "--out",
                    str(out),
                    "--quiet",
                ],
                cwd=ROOT,
                env=env,
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
            status = self._proc.wait()
            if not self.stop.is_set():
                self.finished.append(status)

    def halt(self):
        self.stop.set()
        if self._proc is not None and self._proc.poll() is None:
            self._proc.terminate()
            self._proc.wait()


def _suite_numbers(log: str) -> dict:
    """pytest's counts and seconds and the workers' memory maps, read off the end of the run's output."""
    numbers: dict = {}
    for word in ("passed", "failed", "error", "errors"):
        found = re.findall(rf"(\d+) {word}\b", log)
        if found:
            numbers[word] = int(found[-1])
    found = re.findall(r"\bin ([\d.]+)s\b", log)
    if found:
        numbers["pytest_s"] = float(found[-1])
    maps = re.findall(r"memory maps at the end of the run: (.*)", log)
    if maps:
        numbers["memory_maps_at_end"] = maps[-1].strip()
    return numbers


def _one_run(run: int, folder: Path, timeout: float, loads: list[_Load]) -> dict:
    work = folder / f"run{run}"
    work.mkdir()
    subprocess.run(["git", "clone", "-q", str(ROOT), str(work / "repo")], check=True)
    shared = ROOT.parent / "shared"
    if shared.is_dir():
        (work / "shared").symlink_to(shared.resolve())
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], cwd=work / "repo", capture_output=True, text=True, check=True
    ).stdout.strip()
    before = [len(load.finished) for load in loads]
    log_path = work / "ci.log"
    start = time.monotonic()
    with open(log_path, "w") as log:
        proc = subprocess.Popen(
            ["bash", ".ci/run"],
            cwd=work / "repo",
            env={**os.environ, "CI": "true"},
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        try:
            status: int | str = proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, 9)
            proc.wait()
            status = "hang"
    seconds = time.monotonic() - start
    text = log_path.read_text(errors="replace")
    result = {
        "run": run,
        "commit": commit,
        "status": status,
        "seconds": round(seconds, 1),
        **_suite_numbers(text),
        "load_diagnoses_finished": sum(len(load.finished) - b for load, b in zip(loads, before)),
        "load_average_1_5_15_at_end": [round(x, 2) for x in os.getloadavg()],
        "log_tail": text[-1500:],
    }
    shutil.rmtree(work, ignore_errors=True)
    return result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--load", type=int, default=2, help="diagnose loops beside the suite")
    parser.add_argument("--duration", type=float, default=300.0, help="seconds of the load's recordings")
    parser.add_argument("--timeout", type=float, default=5400.0, help="seconds before a run counts as a hang")
    args = parser.parse_args(argv)
    c.setup_jax()
    runs = []
    with tempfile.TemporaryDirectory(prefix="suite-under-load.") as tmp:
        folder = Path(tmp)
        loads = []
        for i in range(args.load):
            (folder / f"load{i}").mkdir()
            path = folder / f"load{i}" / "recording.csv"
            c.relaxing_strip(i, args.duration, 30.0).save(path)
            loads.append(_Load(path, folder / f"load{i}"))
        for load in loads:
            load.start()
        try:
            for run in range(1, args.runs + 1):
                result = _one_run(run, folder, args.timeout, loads)
                runs.append(result)
                shown = {k: v for k, v in result.items() if k != "log_tail"}
                print(f"run {run}: {shown}", flush=True)
        finally:
            for load in loads:
                load.halt()
        failed_loads = sum(status != 0 for load in loads for status in load.finished)
    out = {
        "command": "python benchmarks/suite_under_load.py "
        f"--runs {args.runs} --load {args.load} --duration {args.duration:g} --timeout {args.timeout:g}",
        "runs": runs,
        "all_finished": all(r["status"] != "hang" for r in runs),
        "all_passed": all(r["status"] == 0 for r in runs),
        "load_diagnoses_finished": sum(len(load.finished) for load in loads),
        "load_diagnoses_failed": failed_loads,
        "machine": c.machine(),
    }
    c.write("suite_under_load.json", out, show=("all_finished", "all_passed", "load_diagnoses_finished"))
    return 0 if out["all_passed"] else 1


if __name__ == "__main__":
    sys.exit(main())
