"""An additive drift of the output's baseline, hidden in two plants: is it named as such, never as hysteresis?

    python experiments/baseline_drift.py [--seeds 4] [--duration 90] [--rate 30] [--periods 1.5:4]
                                         [--out experiments/results/baseline_drift.json]

The commonest drift of a real sensor or a warming plant is additive: the zero
of the output creeps while the response stays the same. Each draw hides one in
a plant made here in numpy and scipy, sharing no code with `diagnose`'s effects:

- ``lti:2``: a second-order system (natural frequency 0.3–2 Hz, damping
  0.2–0.9, static gain 1), discretised exactly for a held drive by
  `scipy.signal.cont2discrete`; diagnosed with ``lti:2``.
- ``plug-in``: the first-order lag of docs/plugins.md (τ 0.3–3 s), its exact
  solution in numpy; diagnosed with that page's plug-in, loaded the way the
  command line loads it.

The drift is a random slow wander, not the library's polynomial: a ramp plus a
sine whose period is 1.5–4 times the recording (``--periods``; 0.5:1.5 swings
it one to two times over the recording), 15–40 % of the clean output's range
from start to end, zero at the first sample. The drive is a multilevel
random staircase (levels held 0.5–3 s, range ±1), the noise 1 % of the clean
output's range. Writes the JSON and a Markdown table beside it; every number
in it comes from this command.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def staircase(rng, n: int, rate: float) -> np.ndarray:
    levels, holds = [], []
    while sum(holds) < n:
        levels.append(rng.uniform(-1.0, 1.0))
        holds.append(int(rng.integers(int(0.5 * rate), int(3.0 * rate))))
    return np.repeat(levels, holds)[:n]


def second_order(rng, u: np.ndarray, rate: float) -> tuple[np.ndarray, dict]:
    import scipy.signal

    f, zeta = rng.uniform(0.3, 2.0), rng.uniform(0.2, 0.9)
    w = 2 * np.pi * f
    a = np.array([[0.0, 1.0], [-w * w, -2 * zeta * w]])
    b = np.array([[0.0], [w * w]])
    ad, bd, *_ = scipy.signal.cont2discrete((a, b, np.eye(2), np.zeros((2, 1))), 1.0 / rate, method="zoh")
    x, y = np.zeros(2), np.empty_like(u)
    for k, value in enumerate(u):
        y[k] = x[0]
        x = ad @ x + bd[:, 0] * value
    return y, {"frequency_hz": f, "damping": zeta}


def lag(rng, u: np.ndarray, rate: float) -> tuple[np.ndarray, dict]:
    tau = rng.uniform(0.3, 3.0)
    a = np.exp(-1.0 / (rate * tau))
    state, y = u[0], np.empty_like(u)
    for k, value in enumerate(u):  # as the plug-in: from rest at the first sample's drive
        state = a * state + (1.0 - a) * value
        y[k] = state
    return y, {"tau_s": tau}


def wander(rng, n: int, rate: float, span: float, periods=(1.5, 4.0)) -> tuple[np.ndarray, dict]:
    t = np.arange(n) / rate
    duration = t[-1]
    period = rng.uniform(*periods) * duration
    phase = rng.uniform(0, 2 * np.pi)
    shape = rng.uniform(-1, 1) * t / duration + np.sin(2 * np.pi * t / period + phase) - np.sin(phase)
    size = rng.uniform(0.15, 0.40) * span
    trend = shape / max(np.max(np.abs(shape)), 1e-12) * size
    return trend, {"size_percent_of_range": 100 * size / span, "period_s": period}


def docs_plugin(folder: Path) -> str:
    """The docs/plugins.md lag, written to `folder` as a plug-in file: its --physics spec."""
    page = (ROOT / "docs" / "plugins.md").read_text()
    section = page[page.index("## A plug-in in one file") : page.index("## The interface")]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    (folder / "lag.py").write_text(code)
    return f"{folder / 'lag.py'}:Lag"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--duration", type=float, default=90.0)
    parser.add_argument("--rate", type=float, default=30.0)
    parser.add_argument(
        "--periods",
        default="1.5:4",
        help="LO:HI, the sine's period as a multiple of the recording (default 1.5:4)",
    )
    parser.add_argument("--out", default="experiments/results/baseline_drift.json")
    args = parser.parse_args(argv)
    try:
        periods = tuple(float(x) for x in args.periods.split(":"))
        if len(periods) != 2 or not 0 < periods[0] <= periods[1]:
            raise ValueError
    except ValueError:
        parser.error(f"--periods {args.periods!r}: give LO:HI with 0 < LO <= HI, e.g. 1.5:4")

    import tempfile

    import jax

    jax.config.update("jax_enable_x64", True)
    import hybrid

    n = int(args.duration * args.rate)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        plugin = docs_plugin(Path(tmp))
        for plant, make, physics in (("lti:2", second_order, "lti:2"), ("plug-in", lag, plugin)):
            for seed in range(args.seeds):
                rng = np.random.default_rng(1000 + seed)
                u = staircase(rng, n, args.rate)
                clean, truth = make(rng, u, args.rate)
                span = float(np.ptp(clean))
                trend, drift = wander(rng, n, args.rate, span, periods)
                w = clean + trend + 0.01 * span * rng.normal(size=n)
                recording = hybrid.Recording.from_arrays(v_in=u, w=w, rate=args.rate)
                simulation = hybrid.resolve_physics(physics, [recording])
                t0 = time.perf_counter()
                found = hybrid.diagnose(recording, simulation=simulation)
                seconds = time.perf_counter() - t0
                causes = [c["name"] for c in found.causes]
                rows.append(
                    {
                        "plant": plant,
                        "seed": seed,
                        "truth": truth,
                        "drift": drift,
                        "causes": causes,
                        "dropped": [d["name"] for d in found.dropped],  # named, then found redundant
                        "gain": found.gain,
                        "unexplained": found.unexplained is not None,
                        "seconds": seconds,
                    }
                )
                print(
                    f"{plant:8s} seed {seed}: causes {causes or ['none']}, gain {found.gain:.2f}, "
                    f"unexplained {'yes' if found.unexplained else 'no'} ({seconds:.0f} s)",
                    flush=True,
                )
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    command = "python experiments/baseline_drift.py " + " ".join(argv if argv is not None else sys.argv[1:])
    out.write_text(json.dumps({"command": command.strip(), "rows": rows}, indent=2) + "\n")
    lines = [
        "# An additive baseline drift hidden in two plants",
        "",
        f"Command: `{command.strip()}`",
        "",
        "| plant | seed | drift (% of range) | its period ÷ the recording | causes named | dropped (redundant) | "
        "held-out gain | unexplained |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['plant']} | {r['seed']} | {r['drift']['size_percent_of_range']:.0f} | "
            f"{r['drift']['period_s'] / args.duration:.2f} | "
            f"{', '.join(r['causes']) or 'none'} | {', '.join(r.get('dropped', [])) or '—'} | {r['gain']:.2f} | "
            f"{'yes' if r['unexplained'] else 'no'} |"
        )
    for plant in ("lti:2", "plug-in"):
        mine = [r for r in rows if r["plant"] == plant]
        first = sum(bool(r["causes"]) and r["causes"][0] == "baseline_drift" for r in mine)
        hysteresis = sum("hysteresis" in r["causes"] for r in mine)
        lines.append("")
        lines.append(
            f"{plant}: baseline_drift named first on {first}/{len(mine)} seeds; hysteresis named on {hysteresis}."
        )
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(f"wrote {out} and {out.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
