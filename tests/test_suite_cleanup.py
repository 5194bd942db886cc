"""What a test run leaves behind: its compilation cache goes when the run is stopped, or at the next run.

The suite's compiled programs live in a temporary folder for the run (conftest.py). A run
stopped by SIGTERM (a CI timeout) used to leave it, 39–46 MB each; one killed outright still
does, and the next run removes it.
"""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import conftest

HERE = Path(__file__).parent


def _dead_pid() -> int:
    done = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    )
    return int(done.stdout)


def test_a_cache_whose_run_is_gone_is_stale_and_no_other_is(tmp_path):
    dead = tmp_path / f"{conftest.CACHE_PREFIX}{_dead_pid()}-abc"
    alive = tmp_path / f"{conftest.CACHE_PREFIX}{os.getpid()}-def"  # a run beside this one
    old = tmp_path / f"{conftest.CACHE_PREFIX}xyz"  # no process id in its name: not ours to judge
    other = tmp_path / "something-else-123-"
    for path in (dead, alive, old, other):
        path.mkdir()
    (tmp_path / f"{conftest.CACHE_PREFIX}{_dead_pid()}-file").write_text("")  # a file, not a cache
    assert conftest.stale_caches(tmp_path) == [dead]


def test_a_run_stopped_by_sigterm_removes_its_cache(tmp_path):
    """A pytest run (with this conftest, under xdist as `make test` runs) is sent SIGTERM mid-test."""
    (tmp_path / "conftest.py").write_text((HERE / "conftest.py").read_text())
    marker = tmp_path / "started"
    (tmp_path / "test_waits.py").write_text(
        "import pathlib, time\n"
        "def test_waits():\n"
        f"    pathlib.Path({str(marker)!r}).write_text('')\n"
        "    time.sleep(600)\n"
    )
    temp = tmp_path / "tmp"
    temp.mkdir()
    env = {**os.environ, "TMPDIR": str(temp)}
    env.pop(conftest.CACHE_ENV, None)  # the controller makes its own
    run = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "pytest",
            "-q",
            "-n",
            "1",
            "-p",
            "no:cacheprovider",
            str(tmp_path / "test_waits.py"),
        ],
        cwd=tmp_path,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        for _ in range(600):  # a hang guard, not a timing: the test has started, or the run has ended
            if marker.exists() or run.poll() is not None:
                break
            time.sleep(0.5)
        assert marker.exists(), run.communicate()[0][-2000:]
        caches = list(temp.glob(conftest.CACHE_PREFIX + "*"))
        assert [p.name.split("-")[4] for p in caches] == [str(run.pid)]  # the controller's, by its pid
        run.send_signal(signal.SIGTERM)
        output = run.communicate(timeout=300)[0]
    finally:
        if run.poll() is None:
            run.kill()
    assert run.returncode != 0, output[-2000:]
    assert not list(temp.glob(conftest.CACHE_PREFIX + "*")), output[-2000:]
