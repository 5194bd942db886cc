"""The quick benchmark (`make bench-quick`, well under 45 s): the simulation ratios and the Jacobian check.

    python benchmarks/quick.py

Measured in this one run, on this machine:

- ``simulate_single_vs_sosfilt``: our time / `scipy.signal.sosfilt`'s for one
  10⁴-sample series through the 46 sections (target ≤ 1.5, goal 1.0);
- ``simulate_batch_speedup_vs_sosfilt_loop``: a Python loop of `sosfilt` over
  1,000 parameter sets / `hybrid.simulate_batch` (target ≥ 1, goal 3);
- ``jacobian_max_relative_difference_vs_fd``: forward-mode ∂V_o/∂θ against
  central differences of `sosfilt`.

Details (compile times, errors against sosfilt, the old stage-major scan) are
in the same file; `benchmarks/simulate.py` adds python-control and diffrax.
Writes `benchmarks/results/quick.json`.
"""

from __future__ import annotations

import time

import _common as c
import jacobian
import simulate


def main():
    t0 = time.perf_counter()
    c.setup_jax()
    out = {"command": "python benchmarks/quick.py", "machine": c.machine()}
    single = simulate.single()
    batch = simulate.batch()
    jac = jacobian.run(repeats=3)
    out.update(
        {
            "simulate_single_vs_sosfilt": single["ratio_hybrid_over_sosfilt"],
            "simulate_batch_speedup_vs_sosfilt_loop": batch["speedup_vs_sosfilt_loop"],
            "jacobian_max_relative_difference_vs_fd": jac["max_relative_difference"],
            "targets": {
                "single_le_1.5x_sosfilt": single["ratio_hybrid_over_sosfilt"] <= 1.5,
                "single_goal_le_1.0x": single["ratio_hybrid_over_sosfilt"] <= 1.0,
                "batch_ge_1x_sosfilt_loop": batch["speedup_vs_sosfilt_loop"] >= 1.0,
                "batch_goal_ge_3x": batch["speedup_vs_sosfilt_loop"] >= 3.0,
            },
            "single": single,
            "batch": batch,
            "jacobian": jac,
        }
    )
    out["seconds"] = time.perf_counter() - t0
    out["load_after"] = c.machine()["load_average_1_5_15"]
    c.write(
        "quick.json",
        out,
        show=(
            "simulate_single_vs_sosfilt",
            "simulate_batch_speedup_vs_sosfilt_loop",
            "jacobian_max_relative_difference_vs_fd",
            "targets",
            "seconds",
        ),
    )


if __name__ == "__main__":
    main()
