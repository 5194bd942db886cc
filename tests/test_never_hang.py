"""Long commands never hang in silence (issue 20).

- The real CLI, in a subprocess with a timeout and a cold compilation cache,
  runs `hybrid diagnose` on two 20 s, 30 Hz recordings of one strip written
  with 6 decimals. The case that deadlocked (jaxlib 0.10) was two 240 s
  recordings; what hung was a batched LAPACK call per recording side by side
  in the screens' loops, whatever the length (`docs/diagnose.md`), so two
  recordings keep its condition. 20 s (600 samples, a drive of 4–5 levels)
  still runs every stage of the search, a second step included, and names the
  hidden back-relaxation; the cold compile is most of the run (~60 CPU s at
  12 or 20 s against ~80 at 120 s), so a shorter record saves almost nothing more.
  `experiments/diagnose_multi.py` runs the 240 s case 20 times;
  `tests/test_loop_safe_linalg.py` fails if any screen lowers to a LAPACK call.
  Three LM steps per lane: the hang was in the screens, before any lane runs.
  A hang now fails this test instead of stalling CI.
- No deadline: on a loaded machine a healthy run may take any time. A hang is
  told from progress: the command's own watchdog ends it with status 3 when it
  does no CPU work for ``HYBRID_STALL_S`` seconds, and the test ends it (and
  fails) when its CPU time stands still for `STALL_S` seconds while it lives
  (`run_while_progressing`).
- The heartbeat shows work being done, and the watchdog ends a stalled process
  with exit status 3 and one line, instead of waiting forever.
"""

import io
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from hybrid.ipmc._synthetic import SyntheticStrip, discrepancy_drive, synthetic_recording
from hybrid.util._watchdog import STALL_EXIT_STATUS, Watchdog, stage

ROOT = Path(__file__).resolve().parents[1]
#: Seconds without any CPU progress of the command (it alive) before the test calls it hung.
STALL_S = 240
#: Length of each recording (s) at 30 Hz (the hang needed two recordings, not their length).
SECONDS = 20.0


def _write_csv(recording, path):
    rows = np.column_stack([recording.t, recording.v_in, recording.w])
    np.savetxt(path, rows, delimiter=",", fmt="%.6f", header="t,v_in,w", comments="")


def _cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of process `pid` (all its threads), from /proc."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def run_while_progressing(command, env, stall_s=STALL_S, poll_s=5.0):
    """Run `command` to its end, however long it takes, unless its CPU time stands still for `stall_s` seconds.

    Returns (returncode, stdout, stderr, seconds). A process whose CPU time does
    not move for `stall_s` seconds while it lives is hung (a deadlock does no
    work; a slow machine still does some): it is killed and the test fails.
    """
    import tempfile

    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        start = time.monotonic()
        proc = subprocess.Popen(command, cwd=ROOT, env=env, stdout=out, stderr=err, text=True)
        last_cpu, last_change = 0.0, time.monotonic()
        while proc.poll() is None:
            try:  # wait up to a poll's time: a command that ends is seen at once, not at the next poll
                proc.wait(timeout=poll_s)
                break
            except subprocess.TimeoutExpired:
                pass
            try:
                cpu = _cpu_seconds(proc.pid)
            except (OSError, IndexError):  # ended between poll and read
                continue
            if cpu > last_cpu + 0.05:
                last_cpu, last_change = cpu, time.monotonic()
            elif time.monotonic() - last_change > stall_s:
                proc.kill()
                proc.wait()
                err.seek(0)
                raise AssertionError(
                    f"no CPU progress for {stall_s} s after {last_cpu:.0f} CPU s: hung\n" + err.read()[-3000:]
                )
        out.seek(0)
        err.seek(0)
        return proc.returncode, out.read(), err.read(), time.monotonic() - start


def test_cli_diagnose_on_two_recordings_completes(tmp_path):
    strip = SyntheticStrip()
    paths = []
    for seed in (1, 2):
        recording = synthetic_recording(
            discrepancy_drive(SECONDS, 30.0, seed=seed),
            strip,
            "back_relaxation",
            {"tau_s": 6.0, "fraction": 0.4},
            seed=seed,
        )
        paths.append(tmp_path / f"strip_{seed}.csv")
        _write_csv(recording, paths[-1])
    env = {**os.environ, "HYBRID_JAX_CACHE": "off", "HYBRID_HEARTBEAT_S": "10", "HYBRID_STALL_S": "180"}
    env.pop("JAX_NUM_CPU_DEVICES", None)  # as a user runs it: a device per core, the lanes side by side
    code, stdout, stderr, seconds = run_while_progressing(
        [
            sys.executable,
            "-m",
            "hybrid.cli",
            "diagnose",
            *map(str, paths),
            "--out",
            str(tmp_path / "diag"),
            "--max-steps",
            "3",
            # A hang does not depend on the effects searched; two keep both search steps (the
            # relaxation is named, then the other is tried on top) at fewer lanes.
            "--effects",
            "back_relaxation,saturation",
        ],
        env,
    )
    assert code == 0, stderr[-3000:]
    assert "cause:" in stdout
    assert (tmp_path / "diag" / "report.json").stat().st_size > 0
    if seconds > 12:  # the heartbeat names the stage while a compiled program runs
        assert "hybrid diagnose: still working: diagnose: " in stderr


def test_a_process_without_cpu_progress_is_called_hung():
    """The guard itself: a process that sleeps (no CPU work) is killed and reported; a busy one is not."""
    import pytest

    env = dict(os.environ)
    with pytest.raises(AssertionError, match="no CPU progress for 2 s"):
        run_while_progressing(
            [sys.executable, "-c", "import time; time.sleep(60)"], env, stall_s=2, poll_s=0.5
        )
    busy = "import time\nend = time.process_time() + 3\nwhile time.process_time() < end: pass\n"
    code, *_ = run_while_progressing([sys.executable, "-c", busy], env, stall_s=2, poll_s=0.5)
    assert code == 0


def test_watchdog_reports_a_stall_and_not_busy_work():
    stalls = []
    with Watchdog("hybrid test", heartbeat=0, stall=1.0, on_stall=stalls.append):
        stage("waiting on nothing")
        time.sleep(3.0)  # no CPU work: what a deadlocked XLA call looks like
    assert len(stalls) == 1 and "no CPU work" in stalls[0] and "waiting on nothing" in stalls[0]

    stalls.clear()
    with Watchdog("hybrid test", heartbeat=0, stall=1.0, on_stall=stalls.append):
        end = time.monotonic() + 2.5
        x = 0
        while time.monotonic() < end:  # busy: never a stall
            x += 1
    assert stalls == []


def test_heartbeat_names_the_stage():
    stream = io.StringIO()
    with Watchdog("hybrid test", heartbeat=0.5, stall=0, stream=stream):
        stage("fit: LM step 3")
        time.sleep(1.6)
    lines = stream.getvalue().splitlines()
    assert len(lines) >= 2 and all(
        line.startswith("hybrid test: still working: fit: LM step 3 (") for line in lines
    )


def test_a_stalled_process_exits_with_status_3_and_one_line():
    code = (
        "import time\nfrom hybrid.util._watchdog import Watchdog, stage\n"
        "with Watchdog('hybrid diagnose', heartbeat=0, stall=1.0):\n"
        "    stage('diagnose: screening')\n    time.sleep(3600)\n"
    )
    # Ended by its watchdog (status 3), not by the sleep's end; a broken watchdog leaves the
    # process sleeping without CPU work, which `run_while_progressing` reports as hung.
    code, _, stderr, _ = run_while_progressing([sys.executable, "-c", code], dict(os.environ), stall_s=120)
    assert code == STALL_EXIT_STATUS
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("hybrid diagnose: error: no CPU work for")
    assert "diagnose: screening" in lines[0]
