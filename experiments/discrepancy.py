"""Hidden effect × seed → what `diagnose` names: the confusion table, the gains, the time.

    python experiments/discrepancy.py [--effects none,delay,...] [--seeds 10 | --seed-list 2,3,7] [--duration 120]
                                      [--rate 30] [--drive prbs-multilevel] [--noise 0.01]
                                      [--virtual] [--out experiments/results/discrepancy.json]

Each draw: a strip and an effect from the issue's ranges (`hybrid.ipmc._synthetic`:
ξρ/ξh 1–100, α 0.1–0.9, C_clamp 1 mF–1 F, gain 0.3–5 mm/V; the effect made by
code separate from the extensions that find it), a recording of the drive with
camera exposure and noise, then `diagnose` on it. Prints one line per draw, then
the confusion table (true effect × named cause) and the held-out gains, over all
draws and over the identifiable ones (see `IDENTIFIABLE`), and writes every
candidate's held-out gain, ΔBIC, Ljung–Box Q and reasons to the JSON file (and
both tables to the .md file beside it).

`--drive` takes one of the drives of `hybrid.make_drive`, or `prbs-multilevel`
(random levels in ±A held 0.5–10 s: steps for a delay and a mode, holds for a
relaxation, many levels reached from above and below for saturation and
hysteresis). `--virtual` also runs `diagnose` on recordings of the richer virtual
IPMC (`hybrid.virtual_recording`), whose extra physics is a real discrepancy.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import jax
import numpy as np


def _drive(name: str, duration: float, rate: float, seed: int):
    from hybrid import make_drive
    from hybrid.ipmc._synthetic import discrepancy_drive

    if name == "prbs-multilevel":
        return discrepancy_drive(duration, rate, seed)
    return make_drive(name, duration, rate=rate, seed=seed)


#: A hidden effect is *identifiable* when every effect-free fit leaves a held-out MSE
#: of at least this many times the noise variance. The issue asks for a held-out gain
#: ≥ 2, and no model's held-out MSE goes below the noise variance, so below 2× no
#: extension can gain 2×: the paper's cascade absorbs the effect within the noise (a
#: slow strip's many stages mimic a dead time; a smooth V_o does not excite a mode).
#: The effect-free fits are the search's baseline and every effect-free fit as good
#: on training (``evidence["equally_good_effect_free_fits"]``): each is a concrete
#: effect-free simulation, fitted on training data only, so a draw counted as absorbed
#: is shown to be absorbed. A search that missed a better effect-free fit can only
#: count more draws as identifiable, never fewer.
IDENTIFIABLE = 2.0


def draw(effect: str, seed: int, duration: float, rate: float, drive: str, noise: float):
    """(strip, effect parameters, recording) of one draw: the strip and effect from the issue's ranges."""
    from hybrid.ipmc._synthetic import random_effect, random_strip, synthetic_recording

    rng = np.random.default_rng([seed, len(effect), sum(map(ord, effect))])
    strip, params = random_strip(rng), random_effect(effect, rng, rate)
    recording = synthetic_recording(_drive(drive, duration, rate, seed), strip, effect, params, noise_fraction=noise,
                                    seed=seed)
    return strip, params, recording


def excess_over_noise(recording, found) -> tuple[float, float]:
    """Held-out MSE over the variance of the added noise: the baseline's, and the least of any effect-free fit."""
    hidden = recording.metadata["hidden"]
    noise_var = (hidden["noise_fraction"] * np.ptp(recording.extra["w_true"])) ** 2
    baseline = float(np.mean((found.heldout["w"] - found.heldout["baseline"]) ** 2)) / noise_var
    others = found.evidence["equally_good_effect_free_fits"]["heldout_nmse_min"]
    best = min(1.0, others / found.baseline.heldout["nmse"]) if np.isfinite(others) else 1.0
    return baseline, baseline * best


def _table(rows, effects, causes) -> str:
    lines = ["| hidden \\ named | " + " | ".join(causes) + " | right | gain (median, min) |",
             "|---" * (len(causes) + 3) + "|"]
    for effect in effects:
        mine = [r for r in rows if r["effect"] == effect]
        if not mine:
            continue
        counts = [sum(r["named"] == c for r in mine) for c in causes]
        right = sum(r["named"] == effect for r in mine)
        gains = [r["gain"] for r in mine]
        lines.append(f"| {effect} | " + " | ".join(str(c) if c else "·" for c in counts)
                     + f" | {right}/{len(mine)} | {np.median(gains):.2f}, {min(gains):.2f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    jax.config.update("jax_enable_x64", True)
    from hybrid import CAUSES, diagnose
    from hybrid.ipmc._synthetic import HIDDEN_EFFECTS

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--effects", default=",".join(HIDDEN_EFFECTS))
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--seed-list", default=None,
                        help="comma-separated seeds (instead of --seeds/--first-seed), e.g. to rerun misses longer")
    parser.add_argument("--duration", type=float, default=120.0)
    parser.add_argument("--rate", type=float, default=30.0)
    parser.add_argument("--drive", default="prbs-multilevel")
    parser.add_argument("--noise", type=float, default=0.01, help="noise std / displacement range")
    parser.add_argument("--virtual", action="store_true", help="also diagnose the richer virtual IPMC")
    parser.add_argument("--out", default="experiments/results/discrepancy.json")
    args = parser.parse_args(argv)

    effects = args.effects.split(",")
    if args.seed_list:
        seeds = [int(x) for x in args.seed_list.split(",")]
    else:
        seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    rows = []
    for effect in effects:
        for seed in seeds:
            strip, params, recording = draw(effect, seed, args.duration, args.rate, args.drive, args.noise)
            found = diagnose(recording)
            excess, least = excess_over_noise(recording, found)
            print(f"{effect:16s} seed {seed}: named {found.cause:16s} gain {found.gain:7.2f}  baseline/noise "
                  f"{excess:6.1f}  effect-free/noise {least:6.1f}  ({found.seconds:.0f} s)  {params}", flush=True)
            rows.append({
                "effect": effect, "seed": seed, "effect_params": params, "strip": dataclasses.asdict(strip),
                "named": found.cause, "gain": found.gain, "seconds": found.seconds,
                "baseline_mse_over_noise": excess, "effect_free_mse_over_noise": least,
                "identifiable": bool(least >= IDENTIFIABLE),
                "baseline_nmse": found.baseline.heldout["nmse"], "extended_nmse": found.extended.heldout["nmse"],
                "parameters": found.to_dict()["parameters"] if found.cause != "none" else {},
                "candidates": {c.name: {"gain": c.gain, "delta_bic": c.delta_bic, "Q": c.ljung_box["Q"],
                                        "material": c.material, "eligible": c.eligible, "derived": c.derived,
                                        "reasons": c.reasons}
                               for c in found.candidates},
                "baseline_Q": found.baseline.ljung_box["Q"],
            })

    virtual = []
    if args.virtual:
        from hybrid.ipmc._virtual_ipmc import virtual_recording

        for drive_name in ("prbs-multilevel", "prbs"):
            recording = virtual_recording(_drive(drive_name, args.duration, args.rate, 0), seed=0)
            found = diagnose(recording)
            print(f"virtual IPMC ({drive_name}): named {found.cause} gain {found.gain:.2f} "
                  f"{found.extended.derived}", flush=True)
            virtual.append({"drive": drive_name, "named": found.cause, "gain": found.gain,
                            "baseline_nmse": found.baseline.heldout["nmse"],
                            "extended_nmse": found.extended.heldout["nmse"],
                            "parameters": found.to_dict()["parameters"],
                            "candidates": {c.name: {"gain": c.gain, "delta_bic": c.delta_bic,
                                                    "eligible": c.eligible, "derived": c.derived,
                                                    "reasons": c.reasons}
                                           for c in found.candidates}})

    table = _table(rows, effects, CAUSES)
    table_identifiable = _table([r for r in rows if r["identifiable"] or r["effect"] == "none"], effects, CAUSES)
    seconds = [r["seconds"] for r in rows]
    command = "python experiments/discrepancy.py " + " ".join(argv)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"command": command, "settings": vars(args), "rows": rows, "virtual_ipmc": virtual},
                              indent=2, default=float))
    summary = ["# Discrepancy search: hidden effect × named cause\n", f"Command: `{command}`\n",
               f"Drive {args.drive}, {args.duration:g} s at {args.rate:g} Hz, noise {100 * args.noise:g} % of range, "
               f"seeds {', '.join(map(str, seeds))}.\n", "All draws:\n", table, "",
               f"Draws whose effect is identifiable (every effect-free fit leaves a held-out MSE ≥ {IDENTIFIABLE:g}× "
               "the noise variance, so a gain of 2 is possible; all effect-free draws):\n", table_identifiable, ""]
    if seconds:
        summary.append(f"diagnose time per recording: median {np.median(seconds):.1f} s, max {max(seconds):.1f} s "
                       "(the first includes compilation).\n")
    for v in virtual:
        summary.append(f"Virtual IPMC ({v['drive']}): named **{v['named']}**, held-out gain {v['gain']:.2f}.")
    out.with_suffix(".md").write_text("\n".join(summary) + "\n")
    print(table)
    print(table_identifiable)
    hits = sum(r["named"] == r["effect"] for r in rows)
    print(f"named right: {hits}/{len(rows)}; wrote {out} and {out.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
