"""`diagnose` on one 5-minute, 30 Hz recording: how long, compiling and running, against one fit.

The targets are issue 30's, on a quiet 2-core machine: the command line
within 20 s with a warm compilation cache and 40 s with an empty one, reported
also as ratios to one physics-only `hybrid fit` of the same recording in the
same run, and each in-process call split into compiling (XLA's backend
compile, summed over programs) and the rest (tracing and running).

    python benchmarks/diagnose.py [--duration 300] [--rate 30]

A synthetic strip (seed 0 of `hybrid.ipmc._synthetic.random_strip`) with a hidden
back-relaxation under the discrepancy drive (multilevel PRBS), 9,000 samples.
Reported: the first call in a fresh process (compiling the search's programs
included), a second call on another recording of the same length (compiled
programs reused, as in a sweep or a lab session), and, as the peer in the same
run, one physics-only `hybrid.fit` (one LM start) of the same recording — the
cost of a single effect-free fit that the search (512 screened points, 18
baseline starts, 35 candidate lanes per step, of which those of the 7 effects leading after 6 LM
steps race on, each such effect's best alone where its starts are sizes of one form, and a re-baseline
from the end point of each lane that raced) is measured against.
Then `hybrid diagnose` from the command line, in fresh processes sharing an
empty persistent compilation cache (`HYBRID_JAX_CACHE`): the first (on the
first recording) fills it, the next three (on the other recording; their
median is reported, each run too) are what a lab sees from its second
recording on.
Writes `benchmarks/results/diagnose.json`.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import _common as c
import numpy as np


def main() -> None:
    args = c.recording_arguments(__doc__)
    c.setup_jax()
    from hybrid.util import compile_counter

    compiling = compile_counter()
    from hybrid import LevenbergMarquardt, RCNetwork, diagnose, fit, make_model

    first, second = (c.relaxing_strip(seed, args.duration, args.rate) for seed in (0, 1))

    found, cold = c.timed(compiling, diagnose, first)
    found2, warm = c.timed(compiling, diagnose, second)
    _, peer = c.timed(
        compiling,
        fit,
        make_model("physics", simulation=RCNetwork(method="zoh")),
        [second],
        solver=LevenbergMarquardt(max_steps=120),
        frozen={"xi_h"},
        split=(0.6, 0.1, 0.3),
        split_order=("train", "validation", "test"),
        progress=False,
    )
    cli = []
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "HYBRID_JAX_CACHE": str(Path(tmp) / "cache")}
        # The warm runs read another recording (no data in the cache key); three of them, each a fresh
        # process: one command line's time varies by a few seconds on a shared machine.
        for run, rec in enumerate((first, second, second, second)):
            path = Path(tmp) / f"recording{run}.csv"
            rec.save(path)
            t0 = time.perf_counter()
            subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "hybrid.cli",
                    "diagnose",
                    str(path),
                    "--out",
                    str(Path(tmp) / f"out{run}"),
                    "--quiet",
                ],
                env=env,
                check=True,
                capture_output=True,
            )
            cli.append(time.perf_counter() - t0)
        t0 = time.perf_counter()  # the peer from the command line, with the same cache
        subprocess.run(
            [
                sys.executable,
                "-m",
                "hybrid.cli",
                "fit",
                str(Path(tmp) / "recording1.csv"),
                "--model",
                "physics",
                "--physics",
                "rc",
                "--out",
                str(Path(tmp) / "fit.eqx"),
            ],
            env=env,
            check=True,
            capture_output=True,
        )
        cli_fit = time.perf_counter() - t0
    warm_cli = float(np.median(cli[1:]))
    out = {
        "samples": len(first),
        "rate_hz": args.rate,
        "duration_s": args.duration,
        "diagnose_first_call": cold,
        "diagnose_second_call": warm,
        "physics_fit_first_call": peer,
        "diagnose_first_call_s": cold["s"],
        "diagnose_second_call_s": warm["s"],
        "physics_fit_first_call_s": peer["s"],
        "second_call_over_one_fit": warm["s"] / peer["s"],
        "cli_empty_cache_s": cli[0],
        "cli_warm_cache_s": warm_cli,
        "cli_warm_cache_runs_s": cli[1:],
        "cli_physics_fit_s": cli_fit,
        "cli_empty_cache_over_cli_fit": cli[0] / cli_fit,
        "cli_warm_cache_over_cli_fit": warm_cli / cli_fit,
        "targets_s": {"cli_warm_cache": 20.0, "cli_empty_cache": 40.0},
        "named": [found.cause, found2.cause],
        "machine": c.machine(),
        "command": "python benchmarks/diagnose.py",
    }
    c.RESULTS.mkdir(exist_ok=True)
    (c.RESULTS / "diagnose.json").write_text(json.dumps(out, indent=2))
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
