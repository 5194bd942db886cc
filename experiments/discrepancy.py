"""Hidden effect × seed → what `diagnose` names (the start of the confusion experiment).

    python experiments/discrepancy.py [--effects none,delay,...] [--seeds 1] [--duration 120]
                                      [--drive prbs] [--noise 0.01] [--out experiments/results/discrepancy.json]

Each draw: a strip and an effect from the issue's ranges (`hybrid._synthetic`),
a recording of the drive, `diagnose` on it. Prints one line per draw and writes
every candidate's held-out gain, ΔBIC and Ljung–Box Q to the JSON file.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax
import numpy as np


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    jax.config.update("jax_enable_x64", True)
    from hybrid import make_drive
    from hybrid._diagnose import diagnose
    from hybrid._synthetic import HIDDEN_EFFECTS, random_effect, random_strip, synthetic_recording

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--effects", default=",".join(HIDDEN_EFFECTS))
    parser.add_argument("--seeds", type=int, default=1)
    parser.add_argument("--duration", type=float, default=120.0)
    parser.add_argument("--rate", type=float, default=30.0)
    parser.add_argument("--drive", default="prbs")
    parser.add_argument("--noise", type=float, default=0.01, help="noise std / displacement range")
    parser.add_argument("--out", default="experiments/results/discrepancy.json")
    args = parser.parse_args(argv)

    rows = []
    for effect in args.effects.split(","):
        for seed in range(args.seeds):
            rng = np.random.default_rng([seed, len(effect), sum(map(ord, effect))])
            strip, params = random_strip(rng), random_effect(effect, rng, args.rate)
            drive = make_drive(args.drive, args.duration, rate=args.rate, seed=seed)
            recording = synthetic_recording(drive, strip, effect, params, noise_fraction=args.noise, seed=seed)
            t0 = time.perf_counter()
            found = diagnose(recording)
            seconds = time.perf_counter() - t0
            print(f"{effect:16s} seed {seed}: named {found.cause:16s} gain {found.gain:7.2f}  ({seconds:.0f} s)",
                  flush=True)
            rows.append({
                "effect": effect, "seed": seed, "effect_params": params, "named": found.cause,
                "gain": found.gain, "seconds": seconds,
                "candidates": {c.name: {"gain": c.gain, "delta_bic": c.delta_bic, "Q": c.ljung_box["Q"],
                                        "material": c.material, "eligible": c.eligible, "derived": c.derived}
                               for c in found.candidates},
                "baseline_Q": found.baseline.ljung_box["Q"],
            })
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"command": "python experiments/discrepancy.py " + " ".join(argv),
                               "settings": vars(args), "rows": rows}, indent=2, default=float))
    hits = sum(r["named"] == r["effect"] for r in rows)
    print(f"named right: {hits}/{len(rows)}; wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
