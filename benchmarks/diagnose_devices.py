"""`hybrid diagnose` with its lanes on one CPU device and on one per core, interleaved in one run.

    python benchmarks/diagnose_devices.py [--duration 300] [--rate 30] [--repeats 2]

The command gives JAX one CPU device per core (`hybrid.use_cpu_cores`) and
`fit_lanes` deals the search's LM lanes out to them; ``JAX_NUM_CPU_DEVICES=1``
runs them one after another on one device, as before. On a shared machine
whose speed drifts by tens of per cent within minutes, only runs interleaved
in time compare: each device count gets its own persistent compilation cache,
filled by one cold run (`benchmarks/diagnose.py`'s first recording), then the
warm runs (its second recording) alternate between the two counts
`--repeats` times. Every run is a fresh `hybrid diagnose` process, as a lab
runs it; its wall and CPU seconds are recorded with the load average after it.

Writes `benchmarks/results/diagnose_devices.json`.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import _common as c


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=300.0)
    parser.add_argument("--rate", type=float, default=30.0)
    parser.add_argument("--repeats", type=int, default=2, help="warm runs per device count")
    args = parser.parse_args()
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    counts = (cores, 1)
    runs: dict[str, list[dict]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        paths = []
        for seed in (0, 1):
            path = Path(tmp) / f"recording{seed}.csv"
            c.relaxing_strip(seed, args.duration, args.rate).save(path)
            paths.append(path)

        def run(devices: int, path: Path, kind: str) -> None:
            env = {
                **os.environ,
                "HYBRID_JAX_CACHE": str(Path(tmp) / f"cache{devices}"),
                "JAX_NUM_CPU_DEVICES": str(devices),
            }
            env.pop("XLA_FLAGS", None)
            before, t0 = os.times(), time.perf_counter()
            subprocess.run(
                [sys.executable, "-m", "hybrid.cli", "diagnose", str(path), "--out", str(Path(tmp) / "out")]
                + ["--quiet"],
                env=env,
                check=True,
                capture_output=True,
            )
            after = os.times()
            cpu = after.children_user - before.children_user + after.children_system - before.children_system
            entry = {"s": time.perf_counter() - t0, "cpu_s": cpu, "load_average_1": os.getloadavg()[0]}
            runs.setdefault(f"{devices}_devices_{kind}", []).append(entry)
            print(f"{devices} device(s), {kind}: {entry['s']:.1f} s (CPU {cpu:.1f} s)", flush=True)

        for devices in counts:
            run(devices, paths[0], "empty_cache")
        for _ in range(args.repeats):
            for devices in counts:
                run(devices, paths[1], "warm_cache")

    def median(key):
        return statistics.median(r["s"] for r in runs[key])

    out = {
        "duration_s": args.duration,
        "rate_hz": args.rate,
        "cores": cores,
        "runs": runs,
        "warm_cache_one_device_over_per_core": median("1_devices_warm_cache")
        / median(f"{cores}_devices_warm_cache"),
        "empty_cache_one_device_over_per_core": median("1_devices_empty_cache")
        / median(f"{cores}_devices_empty_cache"),
        "command": "python benchmarks/diagnose_devices.py",
    }
    c.setup_jax()  # the machine record lists the devices the command gets
    out["machine"] = c.machine()
    print(c.write("diagnose_devices.json", out))


if __name__ == "__main__":
    main()
