"""Why `diagnose` misses some hidden hysteresis loops: the search against the truth.

    python experiments/hysteresis_limits.py [--seed-list 2,7,9,13,14,5,6] [--duration 60] [--rate 30]
                                            [--out experiments/results/hysteresis_limits.json]

For each hysteresis draw of `experiments/discrepancy.py` (same strip, loop,
drive and noise), five fits of the same recording, each reported as its
training and held-out MSE over the noise variance (1 is the floor):

- **oracle loop, all**: one Bouc–Wen element (its rate from a grid, height,
  initial state, gain and offset by linear least squares) fitted to the hidden
  Preisach term itself on the true V_o (true strip, no camera, no noise), over
  the whole recording. What one element cannot express: the extension's shape
  against the hidden one's.
- **oracle loop, training**: the same, fitted on the training part only. Where
  its held-out error is far above the first, the training part does not pin
  the loop even without noise or a network to trade with: a wide loop (small
  rate) that never closes over the recorded range fits the training part as a
  gain change plus a slow trend, and extrapolates wrongly.
- **truth point**: the search's hysteresis extension at the true strip (ξρ/ξh,
  α's, C_clamp) with the first oracle loop, gain and offset by least squares.
  Not fitted: what the extension could do if the search knew the strip.
- **LM from truth**: Levenberg–Marquardt from the truth point, the same lane
  (validation picks the iterate, same patience) as the search's candidates.
  Lower training error and higher held-out error than the truth point means the
  training part does not pin the loop: the network and the loop trade off.
- **search baseline** and **search hysteresis**: what `diagnose` fitted, and
  the least held-out error of any effect-free fit it found (the bar a cause
  must beat by `min_gain`).

Writes the table to the JSON file and a .md beside it.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import jax
import numpy as np


def _loop_designs(s, rates):
    """Per rate (× 1/span): k and the least-squares design [s, u, ∂u/∂u₀, 1], one compiled pass each."""
    import jax.numpy as jnp

    from hybrid.discovery import bouc_wen_and_memory

    span = float(np.ptp(s))
    loop = jax.jit(bouc_wen_and_memory)  # k traced: compiled once for every rate
    designs = []
    for rate in rates:
        u, memory = (np.asarray(x) for x in loop(jnp.asarray(s), rate / span))
        designs.append((rate / span, np.stack([s, u, memory, np.ones_like(s)], axis=1)))
    return designs


def _oracle_loop(designs, span, h, fit_on, train, test, noise_var):
    """Least-squares Bouc–Wen element (the best of `designs`) for the hidden term h(s), fitted on `fit_on`."""
    best = None
    for k, design in designs:
        coef = np.linalg.lstsq(design[fit_on], h[fit_on], rcond=None)[0]
        resid = h - design @ coef
        score = float(np.mean(resid[fit_on] ** 2))
        if best is None or score < best[0]:
            a, b, d = coef[:3]
            best = (
                score,
                float(np.mean(resid[train] ** 2)),
                float(np.mean(resid[test] ** 2)),
                {
                    "hysteresis_rate": k,
                    "hysteresis_height": b / (1.0 + a),
                    "hysteresis_initial_state": float(np.clip(d / b, -0.95, 0.95)),
                },
            )
    return {
        "train": best[1] / noise_var,
        "test": best[2] / noise_var,
        "rate_times_range": best[3]["hysteresis_rate"] * span,
    }, best[3]


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    jax.config.update("jax_enable_x64", True)

    import discrepancy

    import hybrid
    from hybrid import EFFECTS, DiagnoseSettings, RCNetwork
    from hybrid.core import LMSettings, series_from_recording
    from hybrid.discovery import (
        SPLIT_ORDER,
        derived_quantities,
        fit_lanes,
        initial_theta,
        lane_tangents,
        search_problem,
        split_signals,
        universal_model,
    )
    from hybrid.ipmc import apply_hidden, rc_cascade_exact

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed-list", default="2,7,9,13,14,5,6")
    parser.add_argument("--duration", type=float, default=60.0)
    parser.add_argument("--rate", type=float, default=30.0)
    parser.add_argument("--drive", default="prbs-multilevel")
    parser.add_argument("--noise", type=float, default=0.01)
    parser.add_argument("--out", default="experiments/results/hysteresis_limits.json")
    args = parser.parse_args(argv)

    settings = DiagnoseSettings()
    frozen = frozenset(settings.frozen_for(RCNetwork()))
    names = list(EFFECTS)
    off = np.zeros(len(names) + 1)
    off[-1] = 1.0
    on = off.copy()
    on[names.index("hysteresis")] = 1.0
    lm = LMSettings(max_steps=settings.max_steps)
    rows = []
    for seed in (int(x) for x in args.seed_list.split(",")):
        strip, params, recording = discrepancy.draw(
            "hysteresis", seed, args.duration, args.rate, args.drive, args.noise
        )
        noise_var = (args.noise * np.ptp(recording.extra["w_true"])) ** 2

        simulation = RCNetwork(method="zoh")
        model = universal_model(simulation)
        series = [series_from_recording(recording, settings.split, SPLIT_ORDER, settings.blocks)]
        problem, n_rows = search_problem(model, series, frozen)
        parts = {
            split: np.concatenate([np.arange(a, b) for a, b in series[0].segments_of(split)])
            for split in ("train", "test")
        }

        def over_noise(theta, active, problem=problem, noise_var=noise_var):
            out = {}
            for split in ("train", "test"):
                _, w, w_hat = split_signals(problem, theta, active, split)
                out[split] = float(np.mean((w - w_hat) ** 2)) / noise_var
            return out

        # Oracle loop on the true V_o (camera grid, true strip).
        v = np.asarray(recording.v_in, float)
        s_true = rc_cascade_exact(strip, v, 1.0 / args.rate)
        h = apply_hidden("hysteresis", params, s_true, 1.0 / args.rate, None) - s_true
        noise_s = (args.noise * np.ptp(s_true + h)) ** 2
        rates = np.geomspace(0.5, 300.0, 40)
        designs, span = _loop_designs(s_true, rates), float(np.ptp(s_true))
        everywhere = np.arange(len(s_true))
        oracle_all, loop = _oracle_loop(designs, span, h, everywhere, parts["train"], parts["test"], noise_s)
        oracle_train, _ = _oracle_loop(
            designs, span, h, parts["train"], parts["train"], parts["test"], noise_s
        )

        rc = {
            "xi_rho": strip.xi_rho / strip.xi_h,
            "alpha_E": strip.alpha_E,
            "alpha_I": strip.alpha_I,
            "alpha_C": strip.alpha_C,
            "C_clamp": strip.C_clamp,
        }
        truth = initial_theta(
            problem, model.simulation.replace(**rc, **loop).with_active(on), model.readout, frozen
        )
        tangents = lane_tangents(model, frozen, "hysteresis", n_rows)
        state = fit_lanes(problem, on[None], tangents[None], truth[None], lm, settings.patience)
        from_truth = state.best_theta[0]

        found = hybrid.diagnose(recording)
        candidate = next(c for c in found.candidates if c.name == "hysteresis")
        baseline = over_noise(found.baseline.theta, off)
        floor_test = discrepancy.excess_over_noise(recording, found)[1]
        loop_height = lambda theta, active, problem=problem: derived_quantities(problem, theta, active)[
            "hysteresis"
        ]["loop_height_percent_of_range"]
        row = {
            "seed": seed,
            "hidden_loop_fraction": params["height_fraction"],
            "C_clamp": strip.C_clamp,
            "named": found.cause,
            "oracle_loop_all": oracle_all,
            "oracle_loop_training": oracle_train,
            "truth_point": {**over_noise(truth, on), "loop_percent": loop_height(truth, on)},
            "lm_from_truth": {**over_noise(from_truth, on), "loop_percent": loop_height(from_truth, on)},
            "search_baseline": baseline,
            "search_hysteresis": {
                **over_noise(candidate.theta, candidate.active),
                "loop_percent": candidate.derived["loop_height_percent_of_range"],
                "reasons": candidate.reasons,
            },
            "effect_free_floor_test": floor_test,
        }
        rows.append(row)
        print(json.dumps(row, default=float), flush=True)

    def cell(d):
        return f"{d['train']:.2f} / {d['test']:.2f}"

    lines = [
        "| seed | loop (hidden) | C_clamp (F) | oracle loop, all [k·range] | oracle loop, training [k·range] | "
        "truth point | LM from truth | search baseline | search hysteresis | effect-free floor (held-out) | named |",
        "|---" * 11 + "|",
    ]
    for r in rows:
        oracle = "".join(
            f"| {cell(r[key])} [{r[key]['rate_times_range']:.1f}] "
            for key in ("oracle_loop_all", "oracle_loop_training")
        )
        lines.append(
            f"| {r['seed']} | {100 * r['hidden_loop_fraction']:.0f} % | {r['C_clamp']:.3f} {oracle}| "
            f"{cell(r['truth_point'])} | {cell(r['lm_from_truth'])} ({r['lm_from_truth']['loop_percent']:.0f} %) | "
            f"{cell(r['search_baseline'])} | {cell(r['search_hysteresis'])} "
            f"({r['search_hysteresis']['loop_percent']:.0f} %) | {r['effect_free_floor_test']:.2f} | {r['named']} |"
        )
    command = "python experiments/hysteresis_limits.py " + " ".join(argv)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(
        json.dumps({"command": command, "settings": vars(args), "rows": rows}, indent=2, default=float)
    )
    out.with_suffix(".md").write_text(
        "# Hidden hysteresis: the search against the truth\n\n"
        f"Command: `{command}`\n\n"
        f"Drive {args.drive}, {args.duration:g} s at {args.rate:g} Hz, noise {100 * args.noise:g} % of range. "
        "Cells: training / held-out MSE over the noise variance (1 is the floor); in brackets the fitted loop "
        "height in % of the range; in square brackets the oracle's rate times the range of V_o. The oracle loops "
        "are one Bouc–Wen element fitted to the hidden term on the true V_o (no camera, no noise), over the whole "
        "recording or its training part only.\n\n" + "\n".join(lines) + "\n"
    )
    print("\n".join(lines))
    print(f"wrote {out} and {out.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
