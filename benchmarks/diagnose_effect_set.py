"""What the larger default effect set costs `diagnose`: the built-ins against the original seven, one run.

    python benchmarks/diagnose_effect_set.py [--duration 300] [--rate 30] [--repeats 3]

Issue 31 asks that `diagnose` with the larger default effect set take at most
1.3× its time without it. The recording is `benchmarks/diagnose.py`'s (a
synthetic strip, seed 0, with a hidden back-relaxation under the discrepancy
drive; 9,000 samples at the defaults) and the simulation the RC network. Each
set runs in its own fresh process with the persistent compilation cache off:
a first call (tracing and compiling included, what a lab waits for on its
first recording) and a second call on another recording of the same length
(the compiled programs reused). The sets:

- ``original``: delay, back_relaxation, saturation, hysteresis, drift,
  resonance, even_response (the seven of the first releases);
- ``default``: every built-in the RC network takes (`hybrid.resolve_effects(None, RCNetwork())`).

The sets take turns, `--repeats` rounds of both (a round: original, then
default, each in a fresh process), and each call's least time over the rounds
is kept: on the shared 2-core machine one run each gave ratios from 1.39× to
1.86× for the same code. Writes `benchmarks/results/diagnose_effect_set.json`
with every round's times, the cause found, the least times and the ratios of
the least times, default ÷ original.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import _common as c

ORIGINAL = ("delay", "back_relaxation", "saturation", "hysteresis", "drift", "resonance", "even_response")

_CHILD = """
import json, sys, time
sys.path.insert(0, {here!r})
import _common as c
c.setup_jax()
from hybrid import RCNetwork, diagnose, resolve_effects
effects = {effects!r}
first, second = (c.relaxing_strip(seed, {duration!r}, {rate!r}) for seed in (0, 1))
out = {{"effects": [e.name for e in resolve_effects(effects, RCNetwork())]}}
for key, recording in (("first_call", first), ("second_call", second)):
    t0 = time.perf_counter()
    found = diagnose(recording, simulation=RCNetwork(), effects=effects)
    out[key] = {{"seconds": time.perf_counter() - t0, "cause": found.cause, "gain": found.gain}}
print("RESULT " + json.dumps(out))
"""


def _run(effects, args) -> dict:
    code = _CHILD.format(
        here=str(Path(__file__).parent), effects=effects, duration=args.duration, rate=args.rate
    )
    env = {**os.environ, "HYBRID_JAX_CACHE": "off"}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=False)
    lines = [line for line in done.stdout.splitlines() if line.startswith("RESULT ")]
    if done.returncode != 0 or not lines:
        raise SystemExit(f"the {effects or 'default'} run failed:\n{done.stderr[-2000:]}")
    return json.loads(lines[-1][len("RESULT ") :])


def main() -> None:
    args = c.recording_arguments(__doc__, repeats=3)
    c.setup_jax()
    rounds: dict[str, list] = {"original": [], "default": []}
    for _ in range(max(args.repeats, 1)):
        rounds["original"].append(_run(list(ORIGINAL), args))
        rounds["default"].append(_run(None, args))
    keys = ("first_call", "second_call")
    least = {
        name: {key: min(r[key]["seconds"] for r in runs) for key in keys} for name, runs in rounds.items()
    }
    ratios = {key: least["default"][key] / least["original"][key] for key in keys}
    for name, runs in rounds.items():
        run = runs[0]
        print(
            f"{name:8s} ({len(run['effects'])} effects, {run['first_call']['cause']}, gain "
            f"{run['first_call']['gain']:.2f}): first call {least[name]['first_call']:.1f} s, second call "
            f"{least[name]['second_call']:.1f} s (least of {len(runs)})"
        )
    print(
        f"default ÷ original: first call {ratios['first_call']:.2f}×, second call {ratios['second_call']:.2f}×"
    )
    path = c.write(
        "diagnose_effect_set.json",
        {
            "machine": c.machine(),
            "duration_s": args.duration,
            "rate_hz": args.rate,
            "repeats": args.repeats,
            "runs": rounds,
            "least_seconds": least,
            "ratios": ratios,
        },
    )
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
