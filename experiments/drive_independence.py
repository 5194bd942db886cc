"""Does what `diagnose` leaves near the noise floor still follow the drive? Per draw of the open-world table.

    python experiments/drive_independence.py [--effects none,delay+back_relaxation,...] [--seeds 4]
                                             [--duration 60] [--rate 30]
                                             [--out experiments/results/drive_independence.json]

The draws are `experiments/discrepancy.py`'s (the same strips, effects, drive and
noise for the same effect and seed; `diagnose` with its default simulation and
effects, as that script runs it). For each, the final model's held-out residual
is tested for independence of the drive (`hybrid.discovery.residual_tests.drive_independence`:
both prewhitened by the drive's AR model, χ² over the lags where the drive
leads), as ``report.json``'s ``evidence.extended.drive_independence`` has it, and
the row says whether the verdict carries the sentence "Yet it still follows the
drive" (p below `hybrid.discovery._verdict.FOLLOWS_DRIVE_P`, and nothing flagged
unexplained). A pair counts as fully named when every hidden effect is among the
causes; on a draw that names only some of them, a missing part the drive causes
should leave the residual correlated with the drive, and on an effect-free draw
whose fit reaches the floor it should not.

Writes the JSON (every row: the named causes, whether `unexplained` is set, the
held-out MSE over the estimated floor, the test's statistic and p-value for the
baseline and the final model, the verdict) and a table beside it (.md).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE))

DEFAULT_EFFECTS = (
    "none,back_relaxation+saturation,hysteresis+drift,delay+back_relaxation,saturation+resonance"
)


def _row(effect: str, seed: int, args) -> dict:
    from discrepancy import draw, expected_names

    from hybrid import CAUSES, diagnose
    from hybrid.ipmc import hidden_effects

    _, _, recording = draw(effect, seed, args.duration, args.rate, "prbs-multilevel", 0.01)
    t0 = time.perf_counter()
    found = diagnose(recording)
    report = found.to_dict()
    expected, _ = expected_names(list(hidden_effects(recording)), CAUSES)
    named = [c["name"] for c in report["causes"]]
    floor = found.noise_floor.variance if found.noise_floor is not None else float("nan")
    final_mse = float(np.mean((found.heldout.w - found.heldout.extended) ** 2))
    tests = {k: found.evidence[k]["drive_independence"] for k in ("baseline", "extended")}
    return {
        "effect": effect,
        "seed": seed,
        "hidden": expected,
        "named": named,
        "all_named": bool(expected) and set(expected) <= set(named),
        "some_named": bool(set(expected) & set(named)) and not set(expected) <= set(named),
        "unexplained": found.unexplained is not None,
        "mse_over_floor": final_mse / floor if floor > 0 else float("nan"),
        "baseline_p": tests["baseline"]["p_value"] if tests["baseline"] else None,
        "extended_statistic": tests["extended"]["statistic"] if tests["extended"] else None,
        "extended_p": tests["extended"]["p_value"] if tests["extended"] else None,
        "follows_drive": "Yet it still follows the drive" in report["verdict"],
        "verdict": report["verdict"],
        "seconds": time.perf_counter() - t0,
    }


def _kind(r: dict) -> str:
    if not r["hidden"]:
        return "effect-free"
    return "fully named" if r["all_named"] else ("half named" if r["some_named"] else "none named")


def _table(rows: list[dict], command: str) -> str:
    lines = [
        "# Does the remainder still follow the drive? (the open-world draws)",
        "",
        f"Command: `{command}`",
        "",
        "Per draw: the causes named, `unexplained` set, the final model's held-out MSE over the estimated noise "
        "floor, the held-out residual's independence of the drive (p, baseline and final model), and whether "
        "the verdict says the remainder still follows the drive.",
        "",
        "| hidden | seed | named | kind | unexpl. | MSE / floor | p baseline | p final | follows the drive |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        p = [f"{x:.2g}" if x is not None else "—" for x in (r["baseline_p"], r["extended_p"])]
        lines.append(
            f"| {r['effect']} | {r['seed']} | {', '.join(r['named']) or '∅'} | {_kind(r)} | "
            f"{'yes' if r['unexplained'] else ''} | {r['mse_over_floor']:.2f} | {p[0]} | {p[1]} | "
            f"{'yes' if r['follows_drive'] else ''} |"
        )
    lines += [
        "",
        "| kind | draws | flagged unexplained | follows the drive (not flagged) | neither |",
        "|---|---|---|---|---|",
    ]
    for kind in ("effect-free", "fully named", "half named", "none named"):
        some = [r for r in rows if _kind(r) == kind]
        if some:
            flagged = sum(r["unexplained"] for r in some)
            follows = sum(r["follows_drive"] for r in some)
            lines.append(
                f"| {kind} | {len(some)} | {flagged} | {follows} | {len(some) - flagged - follows} |"
            )
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--effects", default=DEFAULT_EFFECTS)
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--duration", type=float, default=60.0)
    parser.add_argument("--rate", type=float, default=30.0)
    parser.add_argument("--out", default="experiments/results/drive_independence.json")
    args = parser.parse_args(argv)
    import jax

    jax.config.update("jax_enable_x64", True)
    command = "python experiments/drive_independence.py " + " ".join(
        argv if argv is not None else sys.argv[1:]
    )
    rows = []
    for effect in args.effects.split(","):
        for seed in range(args.seeds):
            row = _row(effect, seed, args)
            rows.append(row)
            print(
                f"{effect:28s} seed {seed}: {_kind(row):12s} named {row['named']}, unexplained "
                f"{row['unexplained']}, p {row['extended_p']}, follows {row['follows_drive']}",
                flush=True,
            )
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"command": command.strip(), "rows": rows}, indent=2) + "\n")
    out.with_suffix(".md").write_text(_table(rows, command.strip()))
    print(f"wrote {out} and {out.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
