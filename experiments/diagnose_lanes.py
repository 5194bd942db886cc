"""Every candidate lane of one draw of `experiments/discrepancy.py`: where each LM start ended.

    python experiments/diagnose_lanes.py EFFECT SEED [--effects hysteresis,...] [--duration 60] [--rate 30]
                                         [--drive prbs-multilevel] [--noise 0.01]

`diagnose` runs several LM starts (lanes) per effect and lets one stand for the
effect (`hybrid.discovery._decision._choose_lane`: the validation part picks, and an
immaterial lane gives way to a material one within a standard error). This
prints, for each lane of the effects asked (default: the hidden one), its
validation loss, its training, validation and held-out MSE over the variance of
the added noise, the size of its effect and whether it is material, and which lane was
chosen, so a miss can be traced to the search (no lane found the effect) or to
the choice (a lane found it and another was chosen). The held-out column is
for reading only: `diagnose` never looks at it to choose.
"""

from __future__ import annotations

import argparse
import sys

import jax
import jax.numpy as jnp
import numpy as np


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    jax.config.update("jax_enable_x64", True)
    from discrepancy import draw

    from hybrid import DiagnoseSettings, RCNetwork, diagnose
    from hybrid.discovery import SPLIT_ORDER, lane_effect, lanes_problem, predictions

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("effect")
    parser.add_argument("seed", type=int)
    parser.add_argument(
        "--effects",
        default=None,
        help="comma-separated effects whose lanes to print (default: the hidden effect)",
    )
    parser.add_argument("--duration", type=float, default=60.0)
    parser.add_argument("--rate", type=float, default=30.0)
    parser.add_argument("--drive", default="prbs-multilevel")
    parser.add_argument("--noise", type=float, default=0.01, help="noise std / displacement range")
    args = parser.parse_args(argv)

    _, params, recording = draw(args.effect, args.seed, args.duration, args.rate, args.drive, args.noise)
    settings = DiagnoseSettings()
    found = diagnose(recording, settings=settings)
    problem, *_ = lanes_problem([recording], RCNetwork(method="zoh"), settings)
    noise_var = (args.noise * np.ptp(recording.extra["w_true"])) ** 2
    wanted = args.effects.split(",") if args.effects else [args.effect]

    print(f"{args.effect} seed {args.seed} ({args.duration:g} s at {args.rate:g} Hz), hidden {params}")
    baseline = float(np.mean((found.heldout.w - found.heldout.baseline) ** 2)) / noise_var
    print(
        f"named {found.cause}, held-out gain {found.gain:.2f}; baseline held-out MSE / noise {baseline:.2f}"
    )
    print(
        "| lane | effect | validation loss | MSE / noise: training | validation | held-out | effect size "
        "| material | chosen |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for i, lane in enumerate(found.lanes):
        if lane.effect not in wanted:
            continue
        w_hats = predictions(problem, jnp.asarray(lane.active, float), jnp.asarray(lane.theta))
        mse = {
            split: float(
                np.mean(
                    (problem.recorded(problem.target(split), split) - problem.recorded(w_hats[split], split))
                    ** 2
                )
            )
            / noise_var
            for split in SPLIT_ORDER
        }
        material, size = lane_effect(problem, lane.theta, lane.active, lane.effect, settings.materiality)
        size_text = ", ".join(f"{k} {v:.3g}" for k, v in size.items()) or "—"
        print(
            f"| {i} | {lane.effect} | {lane.validation_loss:.4g} | {mse['train']:.2f} "
            f"| {mse['validation']:.2f} | {mse['test']:.2f} | {size_text} | {'yes' if material else 'no'} "
            f"| {'**yes**' if lane.chosen else ''} |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
