"""A wander of the tachometer's zero on a DC motor: named as what it is, or left unexplained, never a loop?

    python experiments/motor_wander.py [--period 50] [--out experiments/results/motor_wander.json]

A new user's trial, kept: the DC motor of `examples/dc_motor.py` (R 2 Ω, L 0.05 H,
K 0.1 N m/A, J 0.01 kg m², b 0.02 N m s/rad) simulated here with scipy's
`solve_ivp` (LSODA, the drive held over each sample: no code shared with the
library), 80 s at 50 Hz under a 9-level random staircase of ±12 V (levels held
0.2–2 s, 1 s at rest first), 1 % noise of the speed's standard deviation, and an
additive wander of the output's zero: a ramp of 8 % of the speed's range plus a
sine of 4 % and period `--period` s (50: 1.6 cycles over the record, more turns
than `baseline_drift`'s cubic can follow). Diagnosed with the plug-in from
`examples/`, as `hybrid diagnose --physics examples/dc_motor.py:DCMotor` would.

Before hysteresis had to close its loop (rate × range ≥ 1) this draw was named
`hysteresis`, gain 2.65, a "loop" of 563 % of the range at rate × range 0.30 (a new user's run of these data).
Writes the JSON and a Markdown summary beside it; every number comes from
this command.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

ROOT = Path(__file__).resolve().parents[1]
R, L, K, J, B = 2.0, 0.05, 0.1, 0.01, 0.02
RATE, SECONDS = 50.0, 80.0


def staircase(n: int, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    u = np.zeros(n)
    k = int(RATE)  # 1 s at rest
    levels = np.linspace(-12.0, 12.0, 9)
    while k < n:
        hold = int(rng.uniform(0.2, 2.0) * RATE)
        u[k : k + hold] = rng.choice(levels)
        k += hold
    return u


def motor_speed(u: np.ndarray) -> np.ndarray:
    """The speed at each sample, the drive held over the sample before it (solve_ivp, LSODA)."""

    def rate(_, x, v):
        i, w = x
        return [(v - R * i - K * w) / L, (K * i - B * w) / J]

    x, y = np.zeros(2), np.zeros(len(u))
    for k in range(len(u) - 1):
        x = solve_ivp(rate, (0.0, 1.0 / RATE), x, args=(u[k],), rtol=1e-9, atol=1e-11, method="LSODA").y[
            :, -1
        ]
        y[k + 1] = x[1]
    return y


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--period", type=float, default=50.0, help="the wander's sine period, s (default 50)")
    parser.add_argument("--out", default="experiments/results/motor_wander.json")
    args = parser.parse_args(argv)

    import jax

    jax.config.update("jax_enable_x64", True)
    import hybrid

    n = int(SECONDS * RATE)
    t = np.arange(n) / RATE
    u = staircase(n)
    clean = motor_speed(u)
    span = float(np.ptp(clean))
    wander = 0.08 * span * t / SECONDS + 0.04 * span * np.sin(2 * np.pi * t / args.period)
    noise = 0.01 * float(np.std(clean)) * np.random.default_rng(103).normal(size=n)
    recording = hybrid.Recording(
        t, u, clean + wander + noise, metadata={"units": {"t": "s", "v_in": "V", "w": "rad/s"}}
    )
    simulation = hybrid.resolve_physics(str(ROOT / "examples" / "dc_motor.py") + ":DCMotor", [recording])
    t0 = time.perf_counter()
    found = hybrid.diagnose(recording, simulation=simulation)
    seconds = time.perf_counter() - t0
    report = found.to_dict()
    loop = next(c for c in report["candidates"] if c["name"] == "hysteresis")
    row = {
        "period_s": args.period,
        "wander_percent_of_range": 100 * float(np.max(np.abs(wander))) / span,
        "verdict": found.verdict,
        "causes": [c["name"] for c in found.causes],
        "gain": found.gain,
        "unexplained_fraction": None
        if found.unexplained is None
        else found.unexplained["fraction_above_floor"],
        "ambiguous": [e["named"] for e in found.ambiguous],
        "hysteresis_candidate": {
            "gain": loop["gain"],
            "eligible": loop["eligible"],
            "derived": loop.get("derived"),
            "reasons": loop["reasons"],
        },
        "seconds": seconds,
    }
    print(json.dumps(row, indent=2))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    command = "python experiments/motor_wander.py " + " ".join(argv if argv is not None else sys.argv[1:])
    out.write_text(json.dumps({"command": command.strip(), "row": row}, indent=2) + "\n")
    derived = row["hysteresis_candidate"]["derived"] or {}
    above = "—" if row["unexplained_fraction"] is None else f"{100 * row['unexplained_fraction']:.0f} %"
    lines = [
        "# A wander of a DC motor tachometer's zero (examples/dc_motor.py)",
        "",
        f"Command: `{command.strip()}`",
        "",
        f"Wander: a ramp plus a sine of period {args.period:g} s over {SECONDS:g} s, at most "
        f"{row['wander_percent_of_range']:.0f} % of the speed's range.",
        "",
        f"- Verdict: {row['verdict']}",
        f"- Causes named: {', '.join(row['causes']) or 'none'}; held-out gain {row['gain']:.2f}; "
        f"above the noise floor: {above}.",
        f"- The hysteresis candidate: gain {row['hysteresis_candidate']['gain']:.2f}, loop "
        f"{derived.get('loop_height_percent_of_range', float('nan')):.0f} % of the range, rate × range "
        f"{derived.get('loop_rate_times_range', float('nan')):.3g}, eligible "
        f"{'yes' if row['hysteresis_candidate']['eligible'] else 'no'} "
        f"({'; '.join(row['hysteresis_candidate']['reasons']) or 'no reason against'}).",
        f"- diagnose took {seconds:.0f} s.",
    ]
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(f"wrote {out} and {out.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
