"""Close the loop (issue 35, item 5): hidden pair → diagnose → design → record → diagnose again.

    python experiments/design_loop.py [--effects back_relaxation+saturation,drift+hysteresis,...]
                                      [--seeds 4 | --seed-list 0,1] [--held-out drift+saturation,...]
                                      [--held-out-seeds 4,5] [--effect-free 4] [--duration 60] [--rate 30]
                                      [--amplitude 2] [--starts 4] [--steps 300]
                                      [--out experiments/results/design_loop.json]
    python experiments/design_loop.py --merge a.json b.json --out experiments/results/design_loop.json

Each draw of a hidden pair (`experiments/discrepancy.py`'s strips, effects and
multilevel PRBS, made by numpy code separate from the extensions):

1. **before**: `diagnose` on the recording;
2. **design**: where ``report.json``'s ``ambiguous`` has an entry (rivals the
   recording cannot tell apart, or an open last step: nothing more against the
   candidates that gained), `hybrid.design_drive` on the first entry's rival
   models within ±`--amplitude`, at the noise floor the diagnosis measured;
   the designed drive is recorded through *the same hidden-effect generator*
   (`hybrid.ipmc.rerecord`: the same strip, effects and noise std, and the
   values the effects' forms took from the first recording's signal — a
   saturation's level, a loop's span — kept; another noise seed), and
   `diagnose` runs on the old and the new recordings together. The design
   keeps the first `--rich` share of the drive as a multilevel PRBS
   (`design_drive(rich=)`, half by default). Where nothing is ambiguous but a remainder is
   unexplained, `hybrid design` writes a rich drive instead
   (`hybrid.rich_drive`, a multilevel PRBS of its own seed), recorded and
   diagnosed alike;
3. **control**: a multilevel PRBS of the same length and amplitude (another
   seed), recorded and diagnosed with the old one alike.

A draw whose diagnosis asks for neither keeps its *before* result in the
design column (a lab would run no designed experiment; the control column
still adds its recording). Per draw: the criterion T (mean squared difference
of the rivals' predictions / σ², the smallest pair) of the designed drive and
of the control drive under the same rivals (recomputed from the models'
predictions, not taken from the design). `--held-out` pairs and seeds, never
used while the design or the diagnosis was tuned, are reported apart;
`--effect-free` draws check that nothing ambiguous and no design is asked for
on strips with no hidden effect. Writes the JSON rows and a Markdown table
beside it (`--out`). `--merge` joins the rows of several runs (e.g. two seed
lists run side by side; a draw in several files: the later file's row) and
writes the tables.

"Fully named": every hidden effect among the named causes; "exactly": and
nothing else named.
"""

from __future__ import annotations

import argparse
import itertools
import json
import shlex
import sys
import time
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

PAIRS = "back_relaxation+saturation,drift+hysteresis,delay+back_relaxation,saturation+resonance"
HELD_OUT = "drift+saturation,hysteresis+resonance"


def last_step(found, top: int = 3) -> list[dict]:
    """The last step's best candidates against nothing more: held-out gain, the sign test, the separation.

    ``p_value``: one-sided sign test over decorrelated chunks that the candidate's
    squared held-out error is the lower (`hybrid.discovery.paired_difference`);
    ``rms_over_floor``: RMS difference of the two held-out predictions over the
    noise floor's σ; ``gain_over_bar``: the held-out gain over the best effect-free
    fit as good on training. Why a missing second effect raised no question, in numbers.
    """
    from hybrid.discovery import paired_difference

    step = found.steps[-1]
    current, sigma = step.current.heldout_residual, float(found.noise_floor.std)
    rows = []
    for c in step.candidates:
        if c.heldout_residual is None or current is None:
            continue
        test = paired_difference(c.heldout_residual, current)
        rows.append(
            {
                "name": c.name,
                "gain": c.gain,
                "gain_over_bar": step.bar / c.heldout.nmse,
                "eligible": c.eligible,
                "p_value": test["p_value"],
                "rms_over_floor": float(np.sqrt(np.mean((c.heldout_residual - current) ** 2))) / sigma,
            }
        )
    return sorted(rows, key=lambda r: -r["gain"])[:top]


def outcome(found, expected: list[str]) -> dict:
    """What a diagnosis named against what was hidden."""
    names = [c["name"] for c in found.causes]
    residual = np.asarray(found.heldout.w) - np.asarray(found.heldout.extended)
    return {
        "causes": names,
        "full": set(expected) <= set(names),
        "exact": set(expected) == set(names),
        "wrong": sorted(set(names) - set(expected)),
        "unexplained": found.unexplained is not None,
        "ambiguous": [
            {
                "step": e["step"],
                "named": e["named"],
                "open": bool(e.get("open")),
                "rivals": [r["name"] for r in e["rivals"]],
            }
            for e in found.ambiguous
        ],
        "final_over_floor": float(np.mean(residual**2)) / float(found.noise_floor.variance),
        "last_step": last_step(found),
        "seconds": found.seconds,
    }


def criterion(models: dict, v: np.ndarray, rate: float, noise_std: float) -> float:
    """T of a drive: the smallest pairwise mean squared difference of the rivals' predictions / σ²."""
    outs = [np.asarray(m.predict(np.asarray(v, float), 1.0 / rate)) for m in models.values()]
    return float(min(np.mean((a - b) ** 2) for a, b in itertools.combinations(outs, 2)) / noise_std**2)


def run_draw(effect: str, seed: int, args, group: str) -> dict:
    from discrepancy import draw, expected_names

    from hybrid import CAUSES, Drive, design_drive, diagnose, rich_drive
    from hybrid.ipmc import discrepancy_drive, hidden_effects, rerecord

    t0 = time.perf_counter()
    _, _, old = draw(effect, seed, args.duration, args.rate, "prbs-multilevel", args.noise)
    expected, outside = expected_names(list(hidden_effects(old)), CAUSES)

    def record(drive, noise_seed):  # the same strip: its saturation level, loop span, noise std in mm
        return rerecord(old, drive, seed=noise_seed)

    before = diagnose(old)
    row = {
        "effect": effect,
        "seed": seed,
        "group": group,
        "expected": expected,
        "outside": outside,
        "before": outcome(before, expected),
    }
    control_drive = discrepancy_drive(args.duration, args.rate, seed=10_000 + seed, amplitude=args.amplitude)
    if before.ambiguous:
        entry = before.ambiguous[0]
        models = {name: before.models[file.removesuffix(".eqx")] for name, file in entry["models"].items()}
        sigma = float(before.noise_floor.std)
        t1 = time.perf_counter()
        design = design_drive(
            models,
            duration=args.duration,
            rate=args.rate,
            amplitude=args.amplitude,
            noise_std=sigma,
            starts=args.starts,
            steps=args.steps,
            seed=seed,
            **({} if args.rich is None else {"rich": args.rich}),
        )
        designed = Drive(design.t, design.v_in, "designed", {"rate": args.rate, "duration": args.duration})
        after = diagnose([old, record(designed, 20_000 + seed)])
        row["design"] = {
            "step": entry["step"],
            "rivals": list(models),
            "open": bool(entry.get("open")),
            "seconds": time.perf_counter() - t1,  # the design and the diagnosis of both recordings
            "criterion": criterion(models, design.v_in, args.rate, sigma),
            "control_criterion": criterion(models, control_drive.v, args.rate, sigma),
            "pair": list(design.pair),
            "after": outcome(after, expected),
        }
    elif before.unexplained is not None:  # nothing to tell apart: `hybrid design` writes a rich drive
        t1 = time.perf_counter()
        t, v = rich_drive(duration=args.duration, rate=args.rate, amplitude=args.amplitude, seed=seed)
        rich = Drive(t, v, "rich", {"rate": args.rate, "duration": args.duration})
        after = diagnose([old, record(rich, 20_000 + seed)])
        row["design"] = {
            "step": None,
            "rivals": [],
            "open": False,
            "rich_drive": True,
            "seconds": time.perf_counter() - t1,
            "criterion": None,
            "control_criterion": None,
            "pair": [],
            "after": outcome(after, expected),
        }
    else:
        row["design"] = None
    if group != "effect-free":
        control = diagnose([old, record(control_drive, 30_000 + seed)])
        row["control"] = outcome(control, expected)
    row["seconds"] = time.perf_counter() - t0
    return row


def _mark(o: dict) -> str:
    """both: every hidden effect named and nothing else; both+X: and X besides; else the named set (∅: none)."""
    if not o["causes"]:
        return "∅"
    if o["exact"]:
        return "both"
    if o["full"]:
        return "both+" + ",".join(o["wrong"])
    return "+".join(o["causes"])


def _flag(o: dict) -> str:
    """unexpl.: a remainder above the floor; open: the last step's question is open (``ambiguous``)."""
    flags = ["unexpl."] if o["unexplained"] else []
    flags += ["open" for e in o["ambiguous"] if e["open"]]
    return ", ".join(flags)


def tables(rows: list[dict]) -> str:
    out = []
    for group, title in (
        ("tuning", "The four pairs of the open-world table"),
        ("held-out", "Held-out pairs"),
    ):
        mine = [r for r in rows if r["group"] == group]
        if not mine:
            continue
        order = list(dict.fromkeys(r["effect"] for r in mine))  # runs merged side by side: by pair, then seed
        mine.sort(key=lambda r: (order.index(r["effect"]), r["seed"]))
        out += [
            f"## {title}\n",
            "Per draw (both: both hidden effects named, nothing else; ∅: nothing named; flagged: "
            "`unexplained` set, or an open last step in `ambiguous`; T: the design "
            "criterion, mean squared difference of the rivals' predictions over σ², designed drive / "
            "control PRBS under the same rivals):\n",
            "| hidden | seed | before | flagged | held-out MSE / floor | last step's best (gain, p) "
            "| design asked (rivals) | after design | after control | T design | T control |",
            "|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for r in mine:
            d = r["design"]
            asked = (
                "no"
                if d is None
                else "rich PRBS (unexplained)"
                if d.get("rich_drive")
                else ("open: " if d["open"] else "") + " vs ".join(d["rivals"])
            )
            after = _mark(r["before"]) + " (no design)" if d is None else _mark(d["after"])
            t_design = "" if d is None or d["criterion"] is None else format(d["criterion"], ".3g")
            t_control = (
                "" if d is None or d["control_criterion"] is None else format(d["control_criterion"], ".3g")
            )
            b = r["before"]
            best = b["last_step"][0] if b["last_step"] else None
            lead = "" if best is None else f"{best['name']} ({best['gain']:.3g}, {best['p_value']:.2g})"
            out.append(
                f"| {r['effect']} | {r['seed']} | {_mark(b)} | {_flag(b)} | {b['final_over_floor']:.2f} | {lead} "
                f"| {asked} | {after} | "
                f"{_mark(r['control'])} | {t_design} | {t_control} |"
            )
        out += [
            "",
            "Fully named (every hidden effect named; in brackets: with nothing else named); half named: some "
            "hidden effect named, not all (in brackets: of which flagged); a wrong name: draws that name an "
            "effect not hidden (a draw that asks for no experiment keeps its own):\n",
            "| hidden | draws | before | half named before (flagged) | after one designed experiment "
            "| after one control PRBS | a wrong name: before / design / control |",
            "|---|---|---|---|---|---|---|",
        ]
        specs = list(dict.fromkeys(r["effect"] for r in mine))
        for spec in [*specs, "total"]:
            sel = mine if spec == "total" else [r for r in mine if r["effect"] == spec]
            b = [r["before"] for r in sel]
            a = [r["before"] if r["design"] is None else r["design"]["after"] for r in sel]
            c = [r["control"] for r in sel]
            cells = [f"{sum(o['full'] for o in x)} ({sum(o['exact'] for o in x)})" for x in (b, a, c)]
            half = [
                r["before"]
                for r in sel
                if not r["before"]["full"] and set(r["expected"]) & set(r["before"]["causes"])
            ]
            cells.insert(1, f"{len(half)} ({sum(bool(_flag(o)) for o in half)})")
            cells.append(" / ".join(str(sum(bool(o["wrong"]) for o in x)) for x in (b, a, c)))
            label = "**total**" if spec == "total" else spec
            out.append(f"| {label} | {len(sel)} | " + " | ".join(cells) + " |")
        asked = [r for r in mine if r["design"] is not None and not r["design"].get("rich_drive")]
        rich = sum(bool(r["design"] and r["design"].get("rich_drive")) for r in mine)
        out.append("")
        out.append(
            f"A design was asked for in {len(asked)}/{len(mine)} draws, a rich drive (nothing ambiguous, a "
            f"remainder unexplained) in {rich}"
            + (
                f"; T designed / T control: median {np.median([r['design']['criterion'] / max(r['design']['control_criterion'], 1e-300) for r in asked]):.3g}×."
                if asked
                else "."
            )
        )
        out.append("")
    free = [r for r in rows if r["group"] == "effect-free"]
    if free:
        asked = sum(bool(r["before"]["ambiguous"]) for r in free)
        named = sum(bool(r["before"]["causes"]) for r in free)
        out += [
            "## Effect-free strips\n",
            f"{len(free)} draws: `ambiguous` non-empty (a design asked for) in {asked}; a cause named in {named}; "
            f"a rich drive (a remainder unexplained) in {sum(r['design'] is not None for r in free)}.\n",
            "| seed | named | held-out MSE / floor | last step's best: gain, over the bar, p | after a rich drive |",
            "|---|---|---|---|---|",
        ]
        for r in sorted(free, key=lambda r: r["seed"]):
            b = r["before"]
            best = b["last_step"][0] if b["last_step"] else None
            lead = (
                ""
                if best is None
                else f"{best['name']}: {best['gain']:.3g}, {best.get('gain_over_bar', float('nan')):.3g}, "
                f"{best['p_value']:.2g}"
            )
            after = "" if r["design"] is None else _mark(r["design"]["after"])
            out.append(f"| {r['seed']} | {_mark(b)} | {b['final_over_floor']:.2f} | {lead} | {after} |")
        out.append("")
    seconds = [r["seconds"] for r in rows]
    if seconds:
        out.append(
            f"Seconds per draw (every diagnosis and design of it): median {np.median(seconds):.0f}, max {max(seconds):.0f}."
        )
    return "\n".join(out) + "\n"


def write(rows: list[dict], out: Path, command: str, settings: dict) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    payload = {"command": command, "settings": settings, "rows": rows}
    tmp = out.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(payload, indent=2, default=float) + "\n")
    tmp.replace(out)
    text = (
        f"# Designed experiments vs a control PRBS (issue 35, item 5)\n\nCommand: `{command}`\n\n"
        + tables(rows)
    )
    out.with_suffix(".md").write_text(text)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    jax.config.update("jax_enable_x64", True)
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--effects", default=PAIRS)
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--seed-list", default=None, help="comma-separated seeds instead of --seeds")
    parser.add_argument("--held-out", default=HELD_OUT, help="pairs reported apart ('' for none)")
    parser.add_argument("--held-out-seeds", default="4,5")
    parser.add_argument("--effect-free", type=int, default=4, help="effect-free draws (seeds 0..K-1)")
    parser.add_argument("--effect-free-seeds", default=None, help="comma-separated seeds instead")
    parser.add_argument("--duration", type=float, default=60.0)
    parser.add_argument("--rate", type=float, default=30.0)
    parser.add_argument("--amplitude", type=float, default=2.0, help="the drives' range ±A (the DAC's), V")
    parser.add_argument("--noise", type=float, default=0.01, help="noise std / displacement range")
    parser.add_argument("--starts", type=int, default=4)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument(
        "--rich",
        type=float,
        default=None,
        help="share of the designed drive kept as PRBS (default: design_drive's)",
    )
    parser.add_argument("--merge", nargs="+", default=None, help="JSON files of earlier runs to join")
    parser.add_argument("--out", default="experiments/results/design_loop.json")
    args = parser.parse_args(argv)
    out = Path(args.out)
    command = "python experiments/design_loop.py " + shlex.join(argv)
    if args.merge:
        parts = [json.loads(Path(p).read_text()) for p in args.merge]
        # a draw in several files: the later file's row (a rerun) replaces the earlier
        by_draw = {(r["group"], r["effect"], r["seed"]): r for part in parts for r in part["rows"]}
        rows = list(by_draw.values())
        commands = " ; ".join(p["command"] for p in parts)
        write(rows, out, f"{commands} ; {command}", {"merged": args.merge})
        print(tables(rows))
        return 0
    from hybrid.ipmc import canonical

    seeds = [int(s) for s in args.seed_list.split(",")] if args.seed_list else list(range(args.seeds))
    plan = [(canonical(e), s, "tuning") for e in args.effects.split(",") if e for s in seeds]
    held_seeds = [int(s) for s in args.held_out_seeds.split(",") if s]
    plan += [(canonical(e), s, "held-out") for e in args.held_out.split(",") if e for s in held_seeds]
    free = (
        [int(s) for s in args.effect_free_seeds.split(",") if s]
        if args.effect_free_seeds is not None
        else list(range(args.effect_free))
    )
    plan += [("none", s, "effect-free") for s in free]
    rows = []
    for effect, seed, group in plan:
        row = run_draw(effect, seed, args, group)
        rows.append(row)
        d = row["design"]
        print(
            f"{group:11s} {effect:28s} seed {seed}: before {_mark(row['before'])}; "
            + (
                "no design"
                if d is None
                else f"rich PRBS → {_mark(d['after'])}"
                if d.get("rich_drive")
                else f"design {' vs '.join(d['rivals'])} T {d['criterion']:.3g} "
                f"(control {d['control_criterion']:.3g}) → {_mark(d['after'])}"
            )
            + (f"; control → {_mark(row['control'])}" if "control" in row else "")
            + f" ({row['seconds']:.0f} s)",
            flush=True,
        )
        write(rows, out, command, vars(args))  # after every draw: a stopped run keeps what it did
    print(tables(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
