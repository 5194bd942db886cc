"""Long commands never hang in silence (issue 20).

- The real CLI, in a subprocess with a timeout and a cold compilation cache,
  runs `hybrid diagnose` on two 120 s, 30 Hz recordings of one strip written
  with 6 decimals. The case that deadlocked (jaxlib 0.10) was two 240 s
  recordings; what hung was a batched LAPACK call per recording side by side
  in the screens' loops, whatever the length (`docs/diagnose.md`), so two
  recordings keep its condition and 120 s halves the run (the suite's budget).
  `experiments/diagnose_multi.py` runs the 240 s case 20 times;
  `tests/test_loop_safe_linalg.py` fails if any screen lowers to a LAPACK call.
  Three LM steps per lane: the hang was in the screens, before any lane runs.
  A hang now fails this test instead of stalling CI.
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
#: Seconds before a run counts as hung: ~5× a cold-cache run of the command here (2 cores).
HANG_TIMEOUT = 420
#: Length of each recording (s) at 30 Hz.
SECONDS = 120.0


def _write_csv(recording, path):
    rows = np.column_stack([recording.t, recording.v_in, recording.w])
    np.savetxt(path, rows, delimiter=",", fmt="%.6f", header="t,v_in,w", comments="")


def test_cli_diagnose_on_two_recordings_completes(tmp_path):
    strip = SyntheticStrip()
    paths = []
    for seed in (1, 2):
        recording = synthetic_recording(discrepancy_drive(SECONDS, 30.0, seed=seed), strip, "back_relaxation",
                                        {"tau_s": 6.0, "fraction": 0.4}, seed=seed)
        paths.append(tmp_path / f"strip_{seed}.csv")
        _write_csv(recording, paths[-1])
    env = {**os.environ, "HYBRID_JAX_CACHE": "off", "HYBRID_HEARTBEAT_S": "10"}
    start = time.monotonic()
    proc = subprocess.run([sys.executable, "-m", "hybrid.cli", "diagnose", *map(str, paths), "--out",
                           str(tmp_path / "diag"), "--max-steps", "3"],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=HANG_TIMEOUT)
    seconds = time.monotonic() - start
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "cause:" in proc.stdout
    assert (tmp_path / "diag" / "report.json").stat().st_size > 0
    if seconds > 12:  # the heartbeat names the stage while a compiled program runs
        assert "hybrid diagnose: still working: diagnose: " in proc.stderr


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
    assert len(lines) >= 2 and all(line.startswith("hybrid test: still working: fit: LM step 3 (") for line in lines)


def test_a_stalled_process_exits_with_status_3_and_one_line():
    code = ("import time\nfrom hybrid.util._watchdog import Watchdog, stage\n"
            "with Watchdog('hybrid diagnose', heartbeat=0, stall=1.0):\n"
            "    stage('diagnose: screening')\n    time.sleep(60)\n")
    start = time.monotonic()
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=30)
    assert proc.returncode == STALL_EXIT_STATUS
    assert time.monotonic() - start < 20
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("hybrid diagnose: error: no CPU work for")
    assert "diagnose: screening" in lines[0]
