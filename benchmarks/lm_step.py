"""One Levenberg–Marquardt step at the paper's size: ours against optimistix's.

    python benchmarks/lm_step.py [--residuals 3000] [--skip-optimistix]

Problem: the Hybrid model (RC network N = 45, D-MLP 11 × 10, window 60), all
6 physical parameters and 1,721 weights free (1,727 in all), on `--residuals`
training samples of a step drive.

Measured in separate subprocesses (so peak memory is each one's own):

- ``structured``: one accepted step of `hybrid`'s LM — structured Jacobian,
  JᵀJ, Cholesky solve, new residuals — after compilation;
- ``optimistix``: one step of `optimistix.LevenbergMarquardt` on the same
  flattened residual function (Jacobian by `jax.linearize` of the whole model,
  QR solve), after compilation.

Reports seconds per step (minimum of repeats), peak resident memory (GB), and
the ratios optimistix / structured, to `benchmarks/results/lm_step.json`.
Targets (issue 2): structured step ≤ 0.5 s and ≤ 1.5 GB on the 2-core machine.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

RESULTS = Path(__file__).parent / "results"


def _problem(n_residuals):
    import jax
    import jax.numpy as jnp
    import numpy as np

    import hybrid as hy
    from hybrid.core import Problem, Series

    rng = np.random.default_rng(0)
    n = n_residuals
    v = np.repeat(rng.uniform(-2, 2, n // 30 + 1), 30)[:n]
    w = np.tanh(v) + 0.01 * rng.standard_normal(n)
    series = Series(jnp.asarray(v), jnp.asarray(w), 1 / 30, (("train", ((0, n),)), ("validation", ((0, n),))))
    model = hy.make_model("hybrid", key=jax.random.key(0))
    problem = Problem(model, [series])
    return problem, problem.flatten(model)


def _peak_gb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2


def run_structured(n_residuals, repeats=5):
    import equinox as eqx
    import jax

    from hybrid.core import LMSettings, lm_init, lm_step

    problem, theta = _problem(n_residuals)
    # A strongly damped first step is always accepted; repeating it from the same
    # state times the expensive branch (new Jacobian, JᵀJ, Jᵀr, Cholesky, costs).
    settings = LMSettings(max_steps=10**6, patience=0, ftol=0.0, gtol=0.0, lambda0=1.0)
    init = eqx.filter_jit(lm_init)
    step = eqx.filter_jit(lm_step)
    state0 = init(problem, theta, settings)
    t0 = time.perf_counter()
    state = step(problem, state0, settings)
    jax.block_until_ready(state)
    compile_s = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        state = step(problem, state0, settings)
        jax.block_until_ready(state)
        times.append(time.perf_counter() - t0)
    if int(state.accepted) != 1:
        raise RuntimeError("the timed step was not accepted: the benchmark would time the cheap branch")
    return {
        "seconds_per_step": min(times),
        "compile_and_first_step_s": compile_s,
        "step": "accepted (Jacobian + normal equations + Cholesky + costs)",
        "peak_gb": _peak_gb(),
        "n_parameters": int(theta.size),
    }


def run_optimistix(n_residuals, repeats=2):
    import equinox as eqx
    import jax
    import optimistix as optx

    problem, theta = _problem(n_residuals)
    solver = optx.LevenbergMarquardt(rtol=1e-8, atol=1e-8)
    fn = lambda th, args: (problem.residuals(th), None)
    f_struct = jax.eval_shape(lambda: problem.residuals(theta))
    state = eqx.filter_jit(solver.init)(fn, theta, None, {}, f_struct, None, frozenset())
    step = eqx.filter_jit(lambda y, s: solver.step(fn, y, None, {}, s, frozenset()))
    t0 = time.perf_counter()
    y, state, _ = step(theta, state)
    jax.block_until_ready(y)
    compile_s = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        y, state, _ = step(y, state)
        jax.block_until_ready(y)
        times.append(time.perf_counter() - t0)
    return {
        "seconds_per_step": min(times),
        "compile_and_first_step_s": compile_s,
        "peak_gb": _peak_gb(),
        "n_parameters": int(theta.size),
    }


def _child(which, n_residuals):
    import jax

    jax.config.update("jax_enable_x64", True)
    result = {"structured": run_structured, "optimistix": run_optimistix}[which](n_residuals)
    print(json.dumps(result))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--residuals", type=int, default=3000)
    parser.add_argument("--skip-optimistix", action="store_true")
    parser.add_argument("--child", choices=("structured", "optimistix"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        _child(args.child, args.residuals)
        return
    out = {"residuals": args.residuals, "command": "python benchmarks/lm_step.py"}
    for which in ("structured",) + (() if args.skip_optimistix else ("optimistix",)):
        proc = subprocess.run(
            [sys.executable, __file__, "--child", which, "--residuals", str(args.residuals)],
            capture_output=True,
            text=True,
        )
        if proc.returncode != 0:
            out[which] = {"error": proc.stderr.strip().splitlines()[-1] if proc.stderr else "failed"}
        else:
            out[which] = json.loads(proc.stdout.strip().splitlines()[-1])
        print(which, out[which], flush=True)
    if "seconds_per_step" in out.get("optimistix", {}):
        out["time_ratio_optimistix_over_structured"] = (
            out["optimistix"]["seconds_per_step"] / out["structured"]["seconds_per_step"]
        )
        out["memory_ratio_optimistix_over_structured"] = (
            out["optimistix"]["peak_gb"] / out["structured"]["peak_gb"]
        )
    s = out["structured"]
    out["targets"] = {
        "step_le_0.5_s": s.get("seconds_per_step", 1e9) <= 0.5,
        "peak_le_1.5_GB": s.get("peak_gb", 1e9) <= 1.5,
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "lm_step.json").write_text(json.dumps(out, indent=2))
    print(json.dumps({k: v for k, v in out.items() if k not in ("structured", "optimistix")}, indent=2))


if __name__ == "__main__":
    main()
