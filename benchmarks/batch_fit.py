"""Many strips fitted in one compiled program (`hybrid.fit_batch`) vs `hybrid.fit` in a loop.

    python benchmarks/batch_fit.py [--quick]

- physics-only: 64 virtual strips (interface ratio, C_clamp, gain and
  compression drawn around the defaults; 120 s PRBS at 30 Hz each), ξh fixed,
  ≤ 100 LM steps; `fit_batch` with all 64 `vmap`-ed, against `fit` on the first
  8 one by one (per-fit time × 64, marked extrapolated) — `fit` compiles its
  programs for every call, which is what a loop over strips pays;
- hybrid (full run only): 16 strips, 60 s each, the paper's D-MLP, ≤ 10 LM
  steps, weight decay 0.1, `batch_size=4`, against `fit` on the first 2.

Equality: the largest relative difference of any fitted named parameter, and
of the test NMSE, between the batch and the one-by-one fits that were run. On
virtual strips the α's are nearly unidentifiable (see `hybrid sensitivity`):
rounding differences between a vmapped and a single program move them along
near-null directions without changing the fit, so parameters agree less
closely than NMSEs. Throughput counts
run time after compilation; compile time is reported apart. Writes
`benchmarks/results/batch_fit.json` (`--quick`: `batch_fit_quick.json`, 16
physics strips against 4).
"""

from __future__ import annotations

import argparse
import json
import time

import _common as c
import numpy as np


def strips(n, duration, seed=0):
    import hybrid as hy
    from hybrid.ipmc import VirtualIPMCParameters, virtual_recording

    rng = np.random.default_rng(seed)
    drive = hy.make_drive("prbs", duration, seed=0, min_hold=0.2, max_hold=4.0)
    out = []
    for i in range(n):
        params = VirtualIPMCParameters(
            interface_ratio=float(20 * np.exp(0.3 * rng.normal())),
            clamp_capacitance_f=float(0.02 * np.exp(0.3 * rng.normal())),
            gain_mm_per_v=float(rng.uniform(1.5, 2.5)),
            compression=float(rng.uniform(0.1, 0.2)),
        )
        out.append(virtual_recording(drive, params, seed=i))
    return out


def compare(kind, recordings, n_loop, max_steps, **options):
    import hybrid as hy

    options = {"solver": hy.LevenbergMarquardt(max_steps=max_steps), **options}
    model = hy.make_model(kind)
    t0 = time.perf_counter()
    batch = hy.fit_batch(model, recordings, **options)
    batch_wall = time.perf_counter() - t0
    loop_options = {k: v for k, v in options.items() if k != "batch_size"}
    t0 = time.perf_counter()
    singles = [hy.fit(model, r, progress=False, **loop_options) for r in recordings[:n_loop]]
    loop_wall = time.perf_counter() - t0
    diff = max(
        abs(b.parameters[k] - s.parameters[k]) / max(abs(s.parameters[k]), 1e-12)
        for b, s in zip(batch.results, singles)
        for k in s.parameters
    )
    nmse_diff = max(
        abs(b.metrics["test"]["nmse"] - s.metrics["test"]["nmse"]) / s.metrics["test"]["nmse"]
        for b, s in zip(batch.results, singles)
    )
    per_fit_loop = loop_wall / n_loop
    return {
        "recordings": len(recordings),
        "samples_each": recordings[0].n,
        "options": {k: str(v) for k, v in options.items()},
        "batch_wall_s": batch_wall,
        "batch_compile_s": batch.compile_seconds,
        "batch_fits_per_s_after_compile": batch.fits_per_second,
        "loop_fits_run": n_loop,
        "loop_wall_s": loop_wall,
        "loop_s_per_fit": per_fit_loop,
        "loop_wall_s_extrapolated_to_all": per_fit_loop * len(recordings),
        "speedup_wall_vs_loop": per_fit_loop * len(recordings) / batch_wall,
        "max_relative_parameter_difference_batch_vs_loop": diff,
        "max_relative_test_nmse_difference_batch_vs_loop": nmse_diff,
        "steps_batch": [r.starts[0]["steps"] for r in batch.results[:n_loop]],
        "steps_loop": [r.starts[0]["steps"] for r in singles],
        "test_nmse_median_batch": float(np.median([r.metrics["test"]["nmse"] for r in batch.results])),
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    c.setup_jax()
    out = {
        "command": "python benchmarks/batch_fit.py" + (" --quick" if args.quick else ""),
        "machine": c.machine(),
    }
    n, n_loop = (16, 4) if args.quick else (64, 8)
    out["physics"] = compare("physics", strips(n, 120.0), n_loop, frozen={"xi_h"}, max_steps=100)
    print("physics", out["physics"], flush=True)
    if not args.quick:
        out["hybrid"] = compare(
            "hybrid",
            strips(16, 60.0, seed=1),
            2,
            frozen={"xi_h"},
            max_steps=10,
            weight_decay=0.1,
            batch_size=4,
        )
        print("hybrid", out["hybrid"], flush=True)
    out["load_after"] = c.machine()["load_average_1_5_15"]
    c.write("batch_fit_quick.json" if args.quick else "batch_fit.json", out)
    print(json.dumps(out["physics"], indent=1))


if __name__ == "__main__":
    main()
