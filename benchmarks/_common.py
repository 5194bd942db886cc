"""Shared helpers of the benchmarks: timing, the RC sections as scipy SOS, machine notes.

Timing follows diffrax's `benchmarks/against_scan.py`: the minimum over repeats,
`block_until_ready` on JAX results, compile time measured apart (first call
minus a steady-state call, or `lower().compile()`).
"""

from __future__ import annotations

import json
import os
import platform
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).parent / "results"


def setup_jax():
    import jax

    from hybrid import use_cpu_cores, use_quick_compiles

    use_cpu_cores()  # as the `hybrid` command does: one CPU device per core
    use_quick_compiles()  # and XLA:CPU's quick compiles
    jax.config.update("jax_enable_x64", True)
    return jax


def timed(compiling: dict, fn, *args, **kwargs):
    """(fn's result, its seconds split into compiling and the rest), `compiling` from `hybrid.util.compile_counter`."""
    before = dict(compiling)
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    seconds, compiled = time.perf_counter() - t0, compiling["s"] - before["s"]
    return out, {
        "s": seconds,
        "compiling_s": compiled,
        "running_s": seconds - compiled,
        "programs": compiling["programs"] - before["programs"],
    }


def best_of(fn, *args, repeats=5):
    """Minimum wall time (s) of `fn(*args)` over `repeats` calls, and the last result."""
    import jax

    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn(*args)
        jax.block_until_ready(out)
        times.append(time.perf_counter() - t0)
    return min(times), out


def first_call(fn, *args):
    """Wall time (s) of the first call (trace + compile + run)."""
    import jax

    t0 = time.perf_counter()
    out = fn(*args)
    jax.block_until_ready(out)
    return time.perf_counter() - t0, out


def recording_arguments(doc: str, duration: float = 300.0, repeats: int | None = None):
    """The command line of a benchmark on `relaxing_strip`'s recordings: --duration (s) and --rate (Hz).

    `repeats`: also a --repeats option with this default (rounds of a timing, the least kept).
    """
    import argparse

    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--duration", type=float, default=duration)
    parser.add_argument("--rate", type=float, default=30.0)
    if repeats is not None:
        parser.add_argument("--repeats", type=int, default=repeats)
    return parser.parse_args()


def relaxing_strip(seed: int, duration: float, rate: float):
    """A synthetic strip (seed `seed` of `random_strip`) with a hidden back-relaxation under the discrepancy drive."""
    from hybrid.ipmc import discrepancy_drive, random_effect, random_strip, synthetic_recording

    rng = np.random.default_rng(seed)
    strip, params = random_strip(rng), random_effect("back_relaxation", rng, rate)
    return synthetic_recording(
        discrepancy_drive(duration, rate, seed), strip, "back_relaxation", params, seed=seed
    )


def sos_sections(network, dt):
    """The network's Tustin sections as scipy SOS rows [b0, b1, 0, 1, a1, 0], written
    from `scipy.signal.bilinear_zpk` of each section's zero, pole and gain (Eqs 11–13)."""
    import scipy.signal

    G, Z, P = (np.asarray(a) for a in network.stage_zpk())
    rows = []
    for g, z, p in zip(G, Z, P):
        zd, pd, kd = scipy.signal.bilinear_zpk([-z], [-p], g, fs=1.0 / dt)
        rows.append([kd, -kd * zd[0], 0.0, 1.0, -pd[0], 0.0])
    return np.array(rows)


def machine():
    """Where the numbers were taken: CPU count, load average, JAX backend/devices."""
    import jax

    load = os.getloadavg() if hasattr(os, "getloadavg") else (float("nan"),) * 3
    return {
        "platform": platform.platform(),
        "python": platform.python_version(),
        "cpus": os.cpu_count(),
        "load_average_1_5_15": [round(x, 2) for x in load],
        "jax": jax.__version__,
        "backend": jax.default_backend(),
        "devices": [str(d) for d in jax.devices()],
        "x64": bool(jax.config.jax_enable_x64),
    }


def write(name, data, show=()):
    """Write `data` to results/`name` (JSON), then print each key of `show` with its value."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / name
    path.write_text(json.dumps(data, indent=2, default=float))
    for key in show:
        print(f"{key}: {data[key]}")
    return path


def relative_error(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))
