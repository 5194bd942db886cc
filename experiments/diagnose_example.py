"""README's worked example: a virtual recording with a hidden effect, then `hybrid diagnose`.

    python experiments/diagnose_example.py [--effect hysteresis] [--seed 0]

Writes the recording to `experiments/results/diagnose_example/recording.csv`
(the hidden truth is in its metadata) and the report (report.md, report.json,
six PNGs) beside it, by running the command line exactly as a user would.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def main(argv=None) -> int:
    import jax

    jax.config.update("jax_enable_x64", True)
    from hybrid.cli import main as hybrid
    from hybrid.ipmc import discrepancy_drive, random_effect, random_strip, synthetic_recording

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--effect", default="hysteresis")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="experiments/results/diagnose_example")
    args = parser.parse_args(argv)
    rng = np.random.default_rng([args.seed, len(args.effect), sum(map(ord, args.effect))])
    strip, params = random_strip(rng), random_effect(args.effect, rng, 30.0)
    recording = synthetic_recording(
        discrepancy_drive(120.0, 30.0, args.seed),
        strip,
        args.effect,
        params,
        noise_fraction=0.01,
        seed=args.seed,
    )
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = recording.save(out / "recording.csv")
    print(f"hidden: {args.effect} {params}; strip {strip}")
    return hybrid(["diagnose", str(path), "--out", str(out), "--quiet"])


if __name__ == "__main__":
    sys.exit(main())
