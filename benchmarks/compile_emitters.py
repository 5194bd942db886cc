"""XLA:CPU's quick compiles (`hybrid.use_quick_compiles`) against XLA's defaults: compiling and running.

    python benchmarks/compile_emitters.py [--duration 60] [--rate 30]

Each setting in its own fresh process (XLA reads ``XLA_FLAGS`` when its backend
starts), the processes one after the other:

- ``quick``: what the `hybrid` command and the test suite use
  (`use_quick_compiles`: ``--xla_cpu_use_fusion_emitters=false
  --xla_backend_optimization_level=1``);
- ``loop``: the loop emitters at LLVM's level 2 (XLA's default level), the
  quick compiles before the level was added;
- ``fusion``: XLA's defaults (fusion emitters, level 2).

Each process runs `diagnose` on two recordings of the same length
(`_common.relaxing_strip`, seeds 0 and 1): the first call compiles the
search's programs, the second reuses them (and compiles only what a step the
first did not take needs). Compiling is XLA's backend compile, summed over
programs (JAX's ``backend_compile_duration`` events); the rest of a call
(tracing and running) is reported as ``running_s``. Reported: each call's
seconds, and the ratios quick / fusion and quick / loop of compiling, of the
first call and of the second call's running, and whether each setting named
the same cause with the same gain (to 1e-9). No persistent compilation cache:
every program is compiled. Writes `benchmarks/results/compile_emitters.json`.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import _common as c

FLAGS = {
    "quick": None,
    "loop": "--xla_cpu_use_fusion_emitters=false --xla_backend_optimization_level=2",
    "fusion": "--xla_cpu_use_fusion_emitters=true --xla_backend_optimization_level=2",
}


def child(duration: float, rate: float) -> dict:
    jax = c.setup_jax()  # use_quick_compiles, unless XLA_FLAGS already chose
    from hybrid.util import compile_counter

    compiling = compile_counter()
    from hybrid import diagnose

    calls = []
    for seed in (0, 1):
        recording = c.relaxing_strip(seed, duration, rate)
        found, call = c.timed(compiling, diagnose, recording)
        calls.append({**call, "named": found.cause, "gain": found.gain})
    return {"xla_flags": os.environ.get("XLA_FLAGS", ""), "jax": jax.__version__, "calls": calls}


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        print(json.dumps(child(float(sys.argv[2]), float(sys.argv[3]))))
        return
    args = c.recording_arguments(__doc__, duration=60.0)
    c.setup_jax()  # for `machine()` below; each child builds its own XLA_FLAGS
    runs = {}
    for name, flags in FLAGS.items():
        env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "HYBRID_JAX_CACHE")}
        if flags:
            env["XLA_FLAGS"] = flags
        proc = subprocess.run(
            [sys.executable, __file__, "--child", str(args.duration), str(args.rate)],
            env=env,
            capture_output=True,
            text=True,
            check=True,
        )
        runs[name] = json.loads(proc.stdout.strip().splitlines()[-1])
    calls = {name: run["calls"] for name, run in runs.items()}
    quick = calls["quick"]
    ratios = {
        f"{key}_quick_over_{peer}": quick[call][field] / calls[peer][call][field]
        for peer in ("fusion", "loop")
        for key, call, field in (
            ("compiling", 0, "compiling_s"),
            ("first_call", 0, "s"),
            ("second_call_running", 1, "running_s"),
        )
    }
    same = all(
        a["named"] == b["named"] and abs(a["gain"] - b["gain"]) <= 1e-9 * abs(b["gain"])
        for peer in ("fusion", "loop")
        for a, b in zip(quick, calls[peer])
    )
    out = {
        "samples": int(args.duration * args.rate),
        "rate_hz": args.rate,
        "duration_s": args.duration,
        "runs": runs,
        **ratios,
        "same_cause_and_gain": same,
        "machine": c.machine(),
        "command": f"python benchmarks/compile_emitters.py --duration {args.duration:g} --rate {args.rate:g}",
    }
    c.write("compile_emitters.json", out)
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
