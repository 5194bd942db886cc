"""Many diagnoses in one process: the memory maps and compiled programs stay bounded (issue 30).

    python benchmarks/diagnose_many.py [--calls 50] [--quick]

Part 1, the issue's loop: `hybrid.diagnose(rec, simulation=hybrid.LTI(1))` on
recordings of 600, 737, 874, 1,011 and 1,148 samples (a first-order lag with a
saturating output, 30 Hz), which used to die on the fifth call (SIGSEGV, out
of memory maps). Part 2: `--calls` more diagnoses, each of a length never
seen before (distinct lengths in 1,025–1,280 samples) and alternating between
two simulations (`LTI(1)` and `LTI(2)`), so that plain caching of repeated
shapes cannot pass it: only the buckets (`hybrid.core.bucket_length`) and the
program budget (`hybrid.util._programs`) can. The times are written to six
decimals, as a lab's file holds them, so each recording's span gives a step
that differs in its last bits: only a step of the rounded rate (`Recording.dt`)
lets them share programs.

Per call it records the memory maps after the call, the programs compiled
(all, and those that took more than a second: the search's), the seconds
compiling and in all, and whether the budget released programs. Reported: the
growth of the maps from the 2nd call to the last (target < 25 %), and the
largest map count against `vm.max_map_count`. No persistent compilation cache:
a released program is compiled again, as in a plain script.
Writes `benchmarks/results/diagnose_many.json`.
"""

from __future__ import annotations

import argparse
import collections
import time

import _common as c
import numpy as np


def lag_recording(n: int, seed: int, order: int = 1):
    """A lag of `order` first-order stages with a saturating output, 30 Hz, in numpy (no library code)."""
    import hybrid as hy

    rng = np.random.default_rng(seed)
    u = np.repeat(rng.uniform(-1, 1, n // 15 + 1), 15)[:n]
    y = u
    for _ in range(order):
        a, x = np.exp(-1.0 / (30.0 * 0.5)), np.zeros(n)
        for k in range(1, n):
            x[k] = a * x[k - 1] + (1 - a) * y[k - 1]
        y = x
    w = np.tanh(2.0 * y) / 2.0 + 0.005 * rng.standard_normal(n)
    t = np.round(np.arange(n) / 30.0, 6)  # as a lab's file holds it: its span's step varies in its last bits
    return hy.Recording(t=t, v_in=u, w=w, name=f"lag{order} {n}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=50)
    parser.add_argument("--quick", action="store_true", help="part 1 and 6 calls of part 2")
    args = parser.parse_args()
    jax = c.setup_jax()
    from jax import monitoring

    import hybrid as hy
    from hybrid.util import DIAGNOSE_PROGRAMS, map_limit, memory_maps

    counts = collections.Counter()

    def listen(event, duration, **_):
        if event == "/jax/core/compile/backend_compile_duration":
            counts["programs"] += 1
            counts["large"] += duration > 1.0
            counts["compile_s"] += duration

    monitoring.register_event_duration_secs_listener(listen)
    calls = [(n, 1) for n in (600, 737, 874, 1011, 1148)]
    rng = np.random.default_rng(0)
    n_more = 6 if args.quick else args.calls
    lengths = rng.choice(np.arange(1025, 1281), size=n_more, replace=False)
    calls += [(int(n), 1 + i % 2) for i, n in enumerate(lengths)]
    rows = []
    for i, (n, order) in enumerate(calls):
        before = dict(counts)
        releases = DIAGNOSE_PROGRAMS.releases
        t0 = time.perf_counter()
        found = hy.diagnose(lag_recording(n, i, order), simulation=hy.LTI(order))
        rows.append(
            {
                "call": i + 1,
                "samples": n,
                "simulation": f"LTI({order})",
                "cause": found.cause,
                "seconds": time.perf_counter() - t0,
                "compile_s": counts["compile_s"] - before.get("compile_s", 0.0),
                "programs": counts["programs"] - before.get("programs", 0),
                "large_programs": counts["large"] - before.get("large", 0),
                "released": DIAGNOSE_PROGRAMS.releases > releases,
                "maps": memory_maps(),
            }
        )
        print(rows[-1], flush=True)
    maps = [r["maps"] for r in rows]
    out = {
        "calls": len(rows),
        "distinct_lengths": len({r["samples"] for r in rows}),
        "simulations": sorted({r["simulation"] for r in rows}),
        "maps_after_2nd": maps[1],
        "maps_last": maps[-1],
        "maps_max": max(maps),
        "growth_2nd_to_last": maps[-1] / maps[1] - 1.0,
        "target_growth": 0.25,
        "max_map_count": map_limit(),
        "releases": DIAGNOSE_PROGRAMS.releases,
        "seconds_total": sum(r["seconds"] for r in rows),
        "rows": rows,
        "machine": c.machine(),
        "command": "python benchmarks/diagnose_many.py" + (" --quick" if args.quick else ""),
    }
    del jax
    c.write("diagnose_many.json" if not args.quick else "diagnose_many_quick.json", out)
    print({k: v for k, v in out.items() if k not in ("rows", "machine")})


if __name__ == "__main__":
    main()
