"""Peak memory of fitting a 20,000-sample recording (target: within 4 GB).

    python benchmarks/memory.py [--samples 20000] [--steps 5]

The Hybrid model (RC network N = 45 + the paper's D-MLP, 1,727 parameters with
ξh frozen: 1,726 free) fitted by `hybrid.fit` (LM, weight decay 0.1) to a
virtual-IPMC PRBS recording of `--samples` samples at 30 Hz (train 30 %: 6,000
residuals). Memory does not grow with the number of steps (a fixed-size LM
state), so a few steps measure the peak. Each case runs in its own process and
reports its peak resident set size (`ru_maxrss`), which includes the Python +
JAX + XLA baseline (also measured: the same process up to just before `fit`).
Writes `benchmarks/results/memory.json`.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time

import _common as c


def child(samples, steps, kind):
    jax = c.setup_jax()
    import hybrid as hy
    from hybrid.ipmc import virtual_recording

    drive = hy.make_drive("prbs", samples / 30.0, seed=0, min_hold=0.2, max_hold=4.0)
    rec = virtual_recording(drive, seed=0)
    model = hy.make_model(kind, key=jax.random.key(0))
    baseline = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2
    t0 = time.perf_counter()
    solver = hy.LevenbergMarquardt(max_steps=steps)
    result = hy.fit(model, rec, frozen={"xi_h"}, solver=solver, weight_decay=0.1, progress=False)
    seconds = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2
    print(
        json.dumps(
            {
                "kind": kind,
                "samples": rec.n,
                "steps": steps,
                "peak_gb": peak,
                "baseline_before_fit_gb": baseline,
                "fit_seconds": seconds,
                "n_parameters": result.settings["n_parameters"],
                "n_residuals": result.settings["n_residuals"],
            }
        )
    )


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=20_000)
    parser.add_argument("--steps", type=int, default=5)
    parser.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.samples, args.steps, args.child)
        return
    c.setup_jax()
    out = {"command": "python benchmarks/memory.py", "machine": c.machine(), "target_gb": 4.0}
    for kind in ("hybrid", "physics"):
        proc = subprocess.run(
            [
                sys.executable,
                __file__,
                "--child",
                kind,
                "--samples",
                str(args.samples),
                "--steps",
                str(args.steps),
            ],
            capture_output=True,
            text=True,
        )
        if proc.returncode:
            out[kind] = {"error": proc.stderr.strip().splitlines()[-1]}
        else:
            out[kind] = json.loads(proc.stdout.strip().splitlines()[-1])
        print(kind, out[kind], flush=True)
    out["within_target"] = all(out[k].get("peak_gb", 1e9) <= 4.0 for k in ("hybrid", "physics"))
    c.write("memory.json", out)


if __name__ == "__main__":
    main()
