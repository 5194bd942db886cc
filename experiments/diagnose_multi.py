"""`hybrid diagnose` on several recordings of one strip, run back to back from the CLI (issue 20).

    python experiments/diagnose_multi.py [--recordings 2] [--runs 20] [--duration 240] [--timeout 600]

Writes `--recordings` recordings of one strip (the paper's cascade from the
independent generator `hybrid.ipmc._synthetic`, a back-relaxation hidden, 30 Hz,
columns t,v_in,w with 6 decimals), then runs `hybrid diagnose A.csv B.csv …`
`--runs` times, each in a fresh process with a timeout, with the persistent
compilation cache of a normal user (a temporary folder, warm after the first
run). A run that exceeds the timeout counts as a hang. Prints and writes
`experiments/results/diagnose_multi_<n>.{json,md}`: exit status, seconds and
the named cause of every run.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def write_recordings(folder: Path, count: int, duration: float) -> list[Path]:
    from hybrid.ipmc import SyntheticStrip, discrepancy_drive, synthetic_recording

    paths = []
    for seed in range(1, count + 1):
        rec = synthetic_recording(
            discrepancy_drive(duration, 30.0, seed=seed),
            SyntheticStrip(),
            "back_relaxation",
            {"tau_s": 6.0, "fraction": 0.4},
            seed=seed,
        )
        path = folder / f"strip_{seed}.csv"
        np.savetxt(
            path,
            np.column_stack([rec.t, rec.v_in, rec.w]),
            delimiter=",",
            fmt="%.6f",
            header="t,v_in,w",
            comments="",
        )
        paths.append(path)
    return paths


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--recordings", type=int, default=2)
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--duration", type=float, default=240.0, help="seconds per recording")
    parser.add_argument("--timeout", type=float, default=600.0, help="seconds before a run counts as a hang")
    parser.add_argument("--out", default=None, help="default experiments/results/diagnose_multi_<n>.json")
    args = parser.parse_args(argv)
    import jax

    out = Path(args.out or f"experiments/results/diagnose_multi_{args.recordings}.json")
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        paths = write_recordings(tmp, args.recordings, args.duration)
        env = {**os.environ, "HYBRID_JAX_CACHE": str(tmp / "cache")}
        for i in range(args.runs):
            start = time.monotonic()
            try:
                proc = subprocess.run(
                    [
                        sys.executable,
                        "-m",
                        "hybrid.cli",
                        "diagnose",
                        *map(str, paths),
                        "--out",
                        str(tmp / f"diag_{i}"),
                        "--quiet",
                    ],
                    cwd=ROOT,
                    env=env,
                    capture_output=True,
                    text=True,
                    timeout=args.timeout,
                )
                status, stdout, stderr = proc.returncode, proc.stdout, proc.stderr
            except subprocess.TimeoutExpired:
                status, stdout, stderr = "hang", "", ""
            seconds = time.monotonic() - start
            cause = next(
                (line.split(":", 1)[1].strip() for line in stdout.splitlines() if line.startswith("cause:")),
                None,
            )
            runs.append(
                {
                    "run": i + 1,
                    "status": status,
                    "seconds": round(seconds, 1),
                    "cause": cause,
                    "stderr_tail": stderr[-500:],
                }
            )
            print(f"run {i + 1:2d}: status {status}, {seconds:6.1f} s, cause {cause}", flush=True)
    done = [r for r in runs if r["status"] == 0]
    summary = {
        "command": f"python experiments/diagnose_multi.py --recordings {args.recordings} --runs {args.runs} "
        f"--duration {args.duration:g}",
        "jax": jax.__version__,
        "recordings": args.recordings,
        "duration_s": args.duration,
        "runs": len(runs),
        "completed": len(done),
        "hangs": sum(r["status"] == "hang" for r in runs),
        "failed": sum(r["status"] not in (0, "hang") for r in runs),
        "first_run_s": runs[0]["seconds"] if runs else None,
        "median_warm_s": statistics.median([r["seconds"] for r in done[1:]]) if len(done) > 1 else None,
        "causes": sorted({str(r["cause"]) for r in done}),
        "per_run": runs,
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(summary, indent=2) + "\n")
    md = [
        f"# hybrid diagnose on {args.recordings} × {args.duration:g} s recordings, {len(runs)} runs back to back",
        "",
        f"`{summary['command']}` (jax {summary['jax']})",
        "",
        f"completed {summary['completed']}/{len(runs)}, hangs {summary['hangs']}, failed {summary['failed']}; "
        f"first run (cold cache) {summary['first_run_s']} s, median of the others {summary['median_warm_s']} s; "
        f"causes named: {', '.join(summary['causes'])}",
        "",
        "| run | status | s | cause |",
        "|---|---|---|---|",
    ]
    md += [f"| {r['run']} | {r['status']} | {r['seconds']} | {r['cause']} |" for r in runs]
    out.with_suffix(".md").write_text("\n".join(md) + "\n")
    print(f"completed {summary['completed']}/{len(runs)}, hangs {summary['hangs']}; wrote {out} and .md")
    return 0 if summary["completed"] == len(runs) else 1


if __name__ == "__main__":
    sys.exit(main())
