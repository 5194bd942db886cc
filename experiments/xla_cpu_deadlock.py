"""Minimal reproducer of the `hybrid diagnose` hang on two recordings (issue 20).

    python experiments/xla_cpu_deadlock.py [--runs 6] [--timeout 30] [--out experiments/results/xla_cpu_deadlock.json]

The construct, with nothing of `hybrid` in it: `lax.map(f, rows, batch_size=16)`
whose body computes three independent matrix exponentials of 46 × 46 matrices
(`jax.scipy.linalg.expm`: Padé products, then an LU solve, then squarings), as
`diagnose`'s screens did for two recordings (one ZOH discretisation each, plus
the Jacobian's). Each variant runs `--runs` times in a fresh process with a
watchdog; a run that has not finished after `--timeout` s is a hang (the
process sits at 0 % CPU, every XLA worker parked on a futex).

Variants (`--variant`, default all):

- ``jax_expm``: `jax.scipy.linalg.expm` — the construct that hangs.
- ``lu_solve_and_products``: twelve chained products plus one batched
  `jnp.linalg.solve` — the LU solve beside concurrent products is enough.
- ``cholesky_and_products``: the same with `cho_solve`.
- ``products_only``: the same products without a solve — never hangs.
- ``loop_safe_expm``: `hybrid.core._loop_safe_linalg.expm` (Taylor, products only),
  what `hybrid` uses now.
- ``jax_expm_one_core``: `jax_expm` pinned to one core (`os.sched_setaffinity`):
  a pool of one thread cannot deadlock.

Committed run (`--runs 4 --timeout 30`, jax 0.10.2, 2 cores, while the test suite
ran beside it; `experiments/results/xla_cpu_deadlock.json`): jax_expm hung 3/4,
lu_solve_and_products 3/4, cholesky_and_products 1/4, products_only 0/4,
loop_safe_expm 0/4, jax_expm_one_core 0/4. Versions: the jax_expm construct, run
6 times in fresh venvs of each release (an equivalent ad hoc script; rerun with
`VENV/bin/python experiments/xla_cpu_deadlock.py --variant jax_expm --runs 6`),
hung 0/6 on jax/jaxlib 0.4.35, 0.5.3, 0.6.2, 0.7.2, 0.8.3 and 0.9.2, and 6/6 on
0.10.0 and 0.10.2.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

VARIANTS = (
    "jax_expm",
    "lu_solve_and_products",
    "cholesky_and_products",
    "products_only",
    "loop_safe_expm",
    "jax_expm_one_core",
)

_CHILD = r"""
import os, sys
variant = sys.argv[1]
if variant.endswith("_one_core"):
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
import jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_x64", True)
K, ROWS, BATCH, COPIES = 46, 512, 16, 3

def matrix(p, i):
    return -jnp.diag(jnp.linspace(1.0, 5.0, K) * p * (i + 1)) + jnp.diag(jnp.ones(K - 1), -1)

def block(m):
    a = m / 30.0
    if variant.startswith("jax_expm"):
        return jax.scipy.linalg.expm(a)
    if variant == "loop_safe_expm":
        from hybrid.core._loop_safe_linalg import expm
        return expm(a)
    x = a
    for _ in range(12):
        x = jnp.dot(x, a, precision="highest") + a
    spd = jnp.eye(K) * 50.0 + a @ a.T
    if variant == "lu_solve_and_products":
        return x + jnp.linalg.solve(spd, x)
    if variant == "cholesky_and_products":
        return x + jax.scipy.linalg.cho_solve(jax.scipy.linalg.cho_factor(spd), x)
    return x

def row(p):
    return sum(jnp.sum(block(matrix(p, i))) for i in range(COPIES))

run = jax.jit(lambda ps: jax.lax.map(row, ps, batch_size=BATCH))
np.asarray(run(jnp.linspace(0.5, 2.0, ROWS)))
print("done", jax.__version__)
"""


def run_variant(variant: str, runs: int, timeout: float) -> dict:
    """Run `variant` `runs` times, each in a fresh interpreter; count completions and hangs."""
    done = hung = failed = 0
    seconds = []
    for _ in range(runs):
        start = time.perf_counter()
        try:
            proc = subprocess.run(
                [sys.executable, "-c", _CHILD, variant],
                capture_output=True,
                text=True,
                timeout=timeout,
                cwd=Path(__file__).resolve().parents[1],
            )
        except subprocess.TimeoutExpired:
            hung += 1
            continue
        if proc.returncode == 0 and proc.stdout.startswith("done"):
            done += 1
            seconds.append(round(time.perf_counter() - start, 2))
        else:
            failed += 1
            print(proc.stderr[-2000:], file=sys.stderr)
    return {
        "variant": variant,
        "runs": runs,
        "completed": done,
        "hung": hung,
        "failed": failed,
        "seconds": seconds,
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variant", action="append", choices=VARIANTS, help="default: all")
    parser.add_argument("--runs", type=int, default=6)
    parser.add_argument("--timeout", type=float, default=30.0, help="seconds before a run counts as hung")
    parser.add_argument("--out", default="experiments/results/xla_cpu_deadlock.json")
    args = parser.parse_args(argv)
    import jax
    import jaxlib

    results = []
    for variant in args.variant or VARIANTS:
        result = run_variant(variant, args.runs, args.timeout)
        print(
            f"{variant:24s} completed {result['completed']}/{args.runs}, hung {result['hung']}, "
            f"failed {result['failed']}",
            flush=True,
        )
        results.append(result)
    record = {
        "jax": jax.__version__,
        "jaxlib": jaxlib.__version__,
        "cpus": sorted(os.sched_getaffinity(0)),
        "timeout_s": args.timeout,
        "results": results,
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(record, indent=2) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
