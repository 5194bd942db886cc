"""The same recording with its drive in V, mV and kV: does `diagnose` name the same causes?

    python experiments/drive_units.py [--effects hysteresis,saturation] [--seeds 4] [--duration 60]
                                      [--rate 30] [--factors 1,1000,0.001]
                                      [--out experiments/results/drive_units.json]

Each draw is `experiments/discrepancy.py`'s (the same strip, hidden effect,
multilevel PRBS and noise). It is diagnosed with the default effects as
recorded (V), then with its drive multiplied by each other factor (1000: the
same drive in mV; 0.001: in kV), w unchanged. A unit change must not change
the diagnosis. Per draw and unit the table gives the named causes, the final
gain, the baseline's held-out NMSE and whether the remainder is flagged
unexplained, and "same" when every unit names the same causes with gains
within 1e-6 of V's. Writes the JSON rows and a Markdown table beside them.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shlex
import sys
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

UNIT = {1.0: "V", 1000.0: "mV", 0.001: "kV"}


def diagnose_in_units(recording, factors) -> list[dict]:
    """One diagnosis per drive unit: named causes, gain, the baseline's held-out NMSE, unexplained or not."""
    from hybrid import RCNetwork, diagnose

    rows = []
    for factor in factors:
        scaled = dataclasses.replace(recording, v_in=np.asarray(recording.v_in) * factor)
        found = diagnose(scaled, simulation=RCNetwork())
        rows.append(
            {
                "factor": factor,
                "unit": UNIT.get(factor, f"V/{factor:g}"),
                "causes": [c["name"] for c in found.causes],
                "gain": float(found.gain),
                "baseline_heldout_nmse": float(found.steps[0].current.heldout.nmse),
                "unexplained": found.unexplained is not None,
            }
        )
    return rows


def same(units: list[dict]) -> bool:
    """Every unit names V's causes with a gain within 1e-6 of V's, and flags the same remainder."""
    ref = units[0]
    return all(
        u["causes"] == ref["causes"]
        and abs(u["gain"] - ref["gain"]) <= 1e-6 * abs(ref["gain"])
        and u["unexplained"] == ref["unexplained"]
        for u in units[1:]
    )


def table(rows: list[dict], command: str) -> str:
    lines = [
        "# One recording, its drive in V, mV and kV",
        "",
        f"Command: `{command}`",
        "",
        "Per draw and drive unit: named causes (∅: none), final gain, the baseline's held-out NMSE, "
        "`u` where the remainder is flagged unexplained.",
        "",
        "| hidden | seed | " + " | ".join(u["unit"] for u in rows[0]["units"]) + " | same |",
        "|---|---|" + "---|" * len(rows[0]["units"]) + "---|",
    ]
    for row in rows:
        cells = [
            f"{', '.join(u['causes']) or '∅'} {u['gain']:.4g} ({u['baseline_heldout_nmse']:.4g})"
            + (" u" if u["unexplained"] else "")
            for u in row["units"]
        ]
        lines.append(f"| {row['hidden']} | {row['seed']} | " + " | ".join(cells) + f" | {row['same']} |")
    n_same = sum(r["same"] for r in rows)
    lines += ["", f"The same diagnosis in every unit: {n_same}/{len(rows)} draws.", ""]
    return "\n".join(lines)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    jax.config.update("jax_enable_x64", True)
    from discrepancy import draw

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--effects", default="hysteresis,saturation")
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--duration", type=float, default=60.0)
    parser.add_argument("--rate", type=float, default=30.0)
    parser.add_argument(
        "--factors", default="1,1000,0.001", help="drive multipliers; the first is the reference"
    )
    parser.add_argument("--out", default="experiments/results/drive_units.json")
    args = parser.parse_args(argv)
    factors = [float(f) for f in args.factors.split(",")]
    rows = []
    for effect in args.effects.split(","):
        for seed in range(args.seeds):
            _, _, recording = draw(effect, seed, args.duration, args.rate, "prbs-multilevel", 0.01)
            units = diagnose_in_units(recording, factors)
            rows.append({"hidden": effect, "seed": seed, "units": units, "same": same(units)})
            print(json.dumps(rows[-1]), flush=True)
    command = "python experiments/drive_units.py " + shlex.join(argv)
    out = Path(args.out)
    json_text = json.dumps({"command": command, "rows": rows}, indent=1)
    md_text = table(rows, command.strip())
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json_text)
    out.with_suffix(".md").write_text(md_text)
    print(md_text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
