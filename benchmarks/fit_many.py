"""Many fits in one process: the memory maps and the resident memory stay bounded.

    python benchmarks/fit_many.py [--calls 100]

`hybrid.fit` compiles its programs for each recording's own length (no buckets:
a windowed readout cannot be padded), about 700 memory maps per new length for
a physics-only `LTI(1)` model. A script fitting a hundred recordings of distinct
lengths would pass `vm.max_map_count` (65,530) and die, and before that hold
gigabytes. `fit` keeps the programs of its last `FIT_HELD_SHAPES` shape keys
and releases every compiled program for a new one beyond them, or when the
process holds more than half of its allowed maps (`FIT_PROGRAMS`, hybrid/util/_programs.py).
Here `--calls` fits of distinct lengths (1,500-4,000 samples, a first-order lag
with a saturating output, 30 Hz, times written to six decimals), each with at
most 20 LM steps. Reported per call: the maps and the resident memory (MB)
after it, its seconds and seconds compiling, and whether the maps fell (a
release). Writes `benchmarks/results/fit_many.json`.
"""

from __future__ import annotations

import argparse
import collections
import time

import _common as c
import numpy as np
from diagnose_many import lag_recording


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=100)
    args = parser.parse_args()
    jax = c.setup_jax()
    from jax import monitoring

    import hybrid as hy
    from hybrid.util import map_limit, memory_maps

    counts: collections.Counter = collections.Counter()

    def listen(event, duration, **_):
        if event == "/jax/core/compile/backend_compile_duration":
            counts["compile_s"] += duration

    monitoring.register_event_duration_secs_listener(listen)
    rng = np.random.default_rng(0)
    lengths = rng.choice(np.arange(1500, 4001), size=args.calls, replace=False)
    model = hy.Model(hy.LTI(1), hy.LinearReadout(), "physics")
    rows = []
    maps_before = memory_maps()
    for i, n in enumerate(lengths):
        compiling = counts["compile_s"]
        t0 = time.perf_counter()
        result = hy.fit(
            model, lag_recording(int(n), i), solver=hy.LevenbergMarquardt(max_steps=20), progress=False
        )
        maps = memory_maps()
        rows.append(
            {
                "call": i + 1,
                "samples": int(n),
                "seconds": time.perf_counter() - t0,
                "compile_s": counts["compile_s"] - compiling,
                "maps": maps,
                "rss_mb": _rss_mb(),
                "released": maps is not None and maps_before is not None and maps < maps_before,
                "test_nmse": float(result.metrics["test"]["nmse"]),
            }
        )
        maps_before = maps
        print(rows[-1], flush=True)
    maps = [r["maps"] for r in rows if r["maps"] is not None]
    out = {
        "calls": len(rows),
        "distinct_lengths": len({r["samples"] for r in rows}),
        "maps_max": max(maps) if maps else None,
        "rss_mb_max": max((r["rss_mb"] for r in rows if r["rss_mb"] is not None), default=None),
        "max_map_count": map_limit(),
        "releases": sum(r["released"] for r in rows),
        "maps_per_call_median": float(np.median(np.diff(maps))) if len(maps) > 1 else None,
        "seconds_total": sum(r["seconds"] for r in rows),
        "rows": rows,
        "machine": c.machine(),
        "command": "python benchmarks/fit_many.py" + (f" --calls {args.calls}" if args.calls != 100 else ""),
    }
    del jax
    c.write("fit_many.json", out)
    print({k: v for k, v in out.items() if k not in ("rows", "machine")})


def _rss_mb() -> float | None:
    """This process's resident memory (MB, Linux's VmRSS), or None where /proc cannot tell."""
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return None


if __name__ == "__main__":
    main()
