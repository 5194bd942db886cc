"""A lab's long file through the real command line: 10⁶ samples at 100 kHz (target: within 4 GB).

    python benchmarks/long_record.py [--samples 1000000] [--steps 40]

Writes a CSV the way a lab's logger does (columns ``u_cmd,y_meas``, no time
column, 7 significant digits): the response of a lightly damped second-order
system to band-limited noise, sampled at 100 kHz (the top of the rates the
loader accepts). Then, each in its own process so that each peak is its own:

- ``load``: `hybrid.load_mapped` alone (`--columns`, `--rate`);
- ``fit lti:2``: ``hybrid fit FILE --columns input=u_cmd,output=y_meas --rate
  100000 --physics lti:2 --model physics --max-steps STEPS``;
- ``fit hybrid``: the same with ``--model hybrid`` (lti:2 + the paper's D-MLP,
  1,726 network weights) and 3 LM steps. Its Jacobian is 1,726 columns wide;
  `Problem.normal_equations` folds them into JᵀJ a chunk of rows at a time
  (before it did, this case peaked at 9.1 GB on 10⁶ samples).

Reports each one's wall time and peak resident set size (the child's
``ru_maxrss``, which includes Python, JAX and XLA), against the same command
on a 10× shorter file as the peer, and writes `benchmarks/results/long_record.json`.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import scipy.signal

import _common as c

RATE = 100_000.0
HYBRID_STEPS = 3  # each LM step of the hybrid model folds 1,726 columns of J over the record
ROOT = Path(__file__).resolve().parents[1]


def write_csv(path: Path, n: int, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    b, a = scipy.signal.butter(4, 2_000.0, fs=RATE)
    u = scipy.signal.lfilter(b, a, rng.normal(size=n))
    u /= np.std(u)
    w0, zeta = 2 * np.pi * 800.0, 0.1  # a mode at 800 Hz
    ad, bd, cd, dd, _ = scipy.signal.cont2discrete(scipy.signal.tf2ss([w0**2], [1.0, 2 * zeta * w0, w0**2]),
                                                   1.0 / RATE, method="zoh")
    y = scipy.signal.dlsim((ad, bd, cd, dd, 1.0 / RATE), u)[1][:, 0] + 0.01 * rng.normal(size=n)
    with open(path, "w") as f:
        f.write("u_cmd,y_meas\n")
        np.savetxt(f, np.column_stack([u, y]), fmt="%.7g", delimiter=",")


#: Runs argv[1:] and prints that one child's peak RSS (kB) last on stderr: a peak of its own.
_PEAK = ("import resource, subprocess, sys; p = subprocess.run(sys.argv[1:]); "
         "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, file=sys.stderr); sys.exit(p.returncode)")


def child_peak(argv: list[str]) -> dict:
    """Run argv in its own process: exit status, wall seconds and its peak resident set size (GB)."""
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", _PEAK, *argv], cwd=ROOT, capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    lines = proc.stderr.strip().splitlines()
    out = {"returncode": proc.returncode, "seconds": seconds, "peak_gb": int(lines[-1]) / 1024**2}
    if proc.returncode:
        out["stderr"] = lines[-2:-1]
    return out


def measure(n: int, steps: int, folder: Path) -> dict:
    path = folder / f"long_{n}.csv"
    t0 = time.perf_counter()
    write_csv(path, n)
    cases = {"csv_mb": path.stat().st_size / 1e6, "write_seconds": time.perf_counter() - t0}
    load = ("import hybrid, sys; r = hybrid.load_mapped(sys.argv[1], columns='input=u_cmd,output=y_meas', "
            "rate=100000); print(r.n)")
    cases["load"] = child_peak([sys.executable, "-c", load, str(path)])
    cases["fit lti:2"] = child_peak([sys.executable, "-m", "hybrid.cli", "fit", str(path), "--columns",
                                     "input=u_cmd,output=y_meas", "--rate", "100000", "--physics", "lti:2",
                                     "--model", "physics", "--max-steps", str(steps), "--quiet",
                                     "--out", str(folder / f"m_{n}.eqx"), "--json", str(folder / f"fit_{n}.json")])
    cases["fit hybrid"] = child_peak([sys.executable, "-m", "hybrid.cli", "fit", str(path), "--columns",
                                      "input=u_cmd,output=y_meas", "--rate", "100000", "--physics", "lti:2",
                                      "--model", "hybrid", "--max-steps", str(HYBRID_STEPS), "--quiet",
                                      "--out", str(folder / f"h_{n}.eqx")])
    report = folder / f"fit_{n}.json"
    if report.exists():
        fitted = json.loads(report.read_text())
        cases["fit lti:2"]["parameters"] = fitted.get("parameters")
    return cases


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=1_000_000)
    parser.add_argument("--steps", type=int, default=40)
    args = parser.parse_args()
    out = {"command": "python benchmarks/long_record.py", "machine": c.machine(), "target_gb": 4.0,
           "rate_hz": RATE}
    with tempfile.TemporaryDirectory() as tmp:
        for n in (args.samples // 10, args.samples):
            out[str(n)] = measure(n, args.steps, Path(tmp))
            print(n, json.dumps(out[str(n)]), flush=True)
    big = out[str(args.samples)]
    out["within_target"] = all(big[k]["returncode"] == 0 and big[k]["peak_gb"] <= 4.0
                                for k in ("load", "fit lti:2", "fit hybrid"))
    c.write("long_record.json", out)


if __name__ == "__main__":
    main()
