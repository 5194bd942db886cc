"""Plants and hidden effects made with scipy, not with this repo, diagnosed from the command line as a new user would.

    python experiments/new_user_probes.py [--only NAME,...] [--out experiments/results/new_user_probes.json]

Each probe is a CSV (t, v_in, w) written by numpy/scipy alone: a linear plant
(`scipy.signal.lsim`), or a Duffing oscillator, a mass on a spring with a dry
friction or a Bouc–Wen spring (`scipy.integrate.solve_ivp`), a
multilevel drive, an effect placed before, inside or after the plant, and
white noise of 1 % of the output's range; and a pendulum that swings far or meets
a stop, diagnosed with a user's own small-angle plug-in (`PENDULUM`). Each is
diagnosed by ``hybrid diagnose FILE --physics lti:N`` (or the plug-in) in its own process. The table gives
the named causes with their incremental gains (their fitted parameters in
the JSON), whether the remainder is flagged unexplained, the ambiguity entries (step, named, rivals) and the
report's first sentence. Which effect is hidden is in each probe's
``hidden`` field; none of the code here is the library's.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import scipy.signal as sg
from scipy.integrate import solve_ivp


def _drive(n, rate, seed, lo=-2.0, hi=2.0, hold=(0.2, 1.0)):
    rng = np.random.default_rng(seed)
    v, i = np.empty(n), 0
    while i < n:
        k = max(1, int(rng.uniform(*hold) * rate))
        v[i : i + k] = rng.uniform(lo, hi)
        i += k
    return v


def _play(u, r):
    out = np.empty_like(u)
    out[0] = 0.0
    for i in range(1, len(u)):
        out[i] = min(max(out[i - 1], u[i] - r), u[i] + r)
    return out


def _slew(u, per_sample):
    out = np.empty_like(u)
    out[0] = u[0]
    for i in range(1, len(u)):
        out[i] = out[i - 1] + np.clip(u[i] - out[i - 1], -per_sample, per_sample)
    return out


def probes() -> dict[str, dict]:
    """name → {t, u, y (noise-free), physics, hidden, noise_seed}."""
    out = {}

    def add(name, t, u, y, physics, hidden, noise_seed):
        out[name] = {"t": t, "u": u, "y": y, "physics": physics, "hidden": hidden, "noise_seed": noise_seed}

    # 1. lti:2 (1.5 Hz, ζ 0.3, 1.2 mm/V), 60 s at 50 Hz, two seeds
    rate, n = 50.0, 3000
    t = np.arange(n) / rate
    wn, z, g = 2 * np.pi * 1.5, 0.3, 1.2
    plant = sg.lti([g * wn**2], [1, 2 * z * wn, wn**2])

    def sim(p, u):
        return sg.lsim(p, u, t)[1]

    for seed in (0, 1):
        u = _drive(n, rate, seed)
        add(f"slew{seed}", t, u, sim(plant, _slew(u, 3.0 / rate)), "lti:2", "drive slew limit 3 V/s", 99)
        add(
            f"delay{seed}",
            t,
            u,
            np.concatenate([np.zeros(15), sim(plant, u)[:-15]]),
            "lti:2",
            "delay 15 samples",
            99,
        )
        add(f"bump{seed}", t, u, sim(plant, u) + 0.1 * (t > 35), "lti:2", "output step 0.1 at 35 s", 99)
        y = sim(plant, u)
        add(f"asym{seed}", t, u, np.where(y > 0, 1.3 * y, y), "lti:2", "output gain 1.3 for y > 0", 99)
        add(f"clean{seed}", t, u, sim(plant, u), "lti:2", "none", 99)
        uo = _drive(n, rate, seed, 1.0, 4.0)
        add(
            f"offsat{seed}",
            t,
            uo,
            3.0 * np.tanh(sim(plant, uo) / 3.0),
            "lti:2",
            "drive 1-4 V, output 3 tanh(y/3)",
            99,
        )
    # a sensor's dead band, a sensor re-zeroed mid-record, a gain that drops mid-record (drive seed 0)
    u = _drive(n, rate, 0)
    y = sim(plant, u)
    add(
        "out_dead_band",
        t,
        u,
        np.sign(y) * np.maximum(np.abs(y) - 0.5, 0.0),
        "lti:2",
        "output dead band ±0.5",
        13,
    )
    add("rezeroed", t, u, y + np.where(t > 36.0, 0.6, 0.0), "lti:2", "output + 0.6 from t = 36 s", 13)
    add("gain_drop", t, u, y * np.where(t > 30.0, 0.7, 1.0), "lti:2", "output gain × 0.7 from t = 30 s", 13)
    # 2. lti:1 (τ 0.5 s, 0.8 mm/V) and lti:2 (1.2 Hz, ζ 0.35), drive seed 3, holds 0.2–1.5 s
    u = _drive(n, rate, 3, hold=(0.2, 1.5))
    p1 = sg.lti([0.8], [0.5, 1.0])
    wn, z = 2 * np.pi * 1.2, 0.35
    p2 = sg.lti([wn**2], [1, 2 * z * wn, wn**2])
    a = np.exp(-1 / (0.3 * rate))
    add("dsat", t, u, sim(p1, np.clip(u, -1.4, 1.4)), "lti:1", "drive clipped at ±1.4 V", 7)
    add("blash", t, u, sim(p1, _play(u, 0.3)), "lti:1", "drive backlash 0.3 V", 7)
    add("lag2", t, u, sg.lfilter([1 - a], [1, -a], sim(p2, u)), "lti:2", "sensor lag 0.3 s", 7)
    add(
        "bdrift",
        t,
        u,
        sim(p1, u) + 0.4 * (t / 60) ** 2 - 0.2 * (t / 60),
        "lti:1",
        "additive quadratic drift",
        7,
    )
    y = sim(p1, u)
    add("even", t, u, y + 0.25 * y**2, "lti:1", "output y + 0.25 y²", 7)
    add("gdrift", t, u, sim(p1, u) * (1 - 0.35 * t / 60), "lti:1", "gain falling 35 %/min", 7)
    add("ohyst", t, u, _play(sim(p1, u), 0.15), "lti:1", "output play 0.15", 7)
    add("dsq", t, u, sim(p1, 0.4 * u * np.abs(u)), "lti:1", "drive 0.4 u|u|", 7)
    # 3. a biased electrostatic drive, a thermal plant at 1 Hz, a Duffing oscillator at 1 kHz
    u = _drive(n, rate, 1, 4.0, 6.0, hold=(0.2, 1.5))
    add("bias_sq", t, u, sg.lsim(sg.lti([0.02], [0.3, 1.0]), u**2, t)[1], "lti:1", "w ∝ lag(V²), V 4–6 V", 11)
    rate_t, n_t = 1.0, 7200
    tt = np.arange(n_t) / rate_t
    u = _drive(n_t, rate_t, 2, 0.0, 50.0, hold=(120, 900))
    pt = sg.lti([0.4], [300.0, 1.0])
    y = sg.lsim(pt, u, tt)[1]
    a = np.exp(-1 / 20.0)
    add("thermal_lag", tt, u, sg.lfilter([1 - a], [1, -a], y), "lti:1", "sensor lag 20 s on τ 300 s", 11)
    # a heater driven in 0–100 % of its power that delivers no more than 70 %: a clip on a one-signed drive
    u = _drive(n_t, rate_t, 3, 0.0, 100.0, hold=(120, 600))
    add(
        "heater_clip",
        tt,
        u,
        sg.lsim(pt, np.minimum(u, 70.0), tt)[1],
        "lti:1",
        "drive clipped at 70 of 0–100",
        11,
    )
    add(
        "thermal_drift",
        tt,
        u,
        y + 1.5 * (tt / tt[-1]) - 1.0 * (tt / tt[-1]) ** 2,
        "lti:1",
        "additive drift",
        11,
    )
    rate_d, n_d = 1000.0, 10000
    td = np.arange(n_d) / rate_d
    u = _drive(n_d, rate_d, 3, -1.0, 1.0, hold=(0.05, 0.3))
    wn, z = 2 * np.pi * 8, 0.08
    k3 = 3.0 * wn**2

    def duffing(time, s):
        i = min(int(time * rate_d), n_d - 1)
        x, v = s
        return [v, wn**2 * u[i] - 2 * z * wn * v - wn**2 * x - k3 * x**3]

    sol = solve_ivp(duffing, (0, td[-1]), [0, 0], t_eval=td, max_step=1 / rate_d, rtol=1e-8, atol=1e-10)
    add("duffing1k", td, u, sol.y[0], "lti:2", "cubic stiffness 3 ω²", 11)
    # 5. inside the dynamics of a 1.2 Hz, ζ 0.2 mass on a spring (solve_ivp), drive seeds 1–3, and after it:
    # a Coulomb friction of 0.3 (drive units) sticking below 0.01 /s, a Bouc–Wen hysteretic spring
    # (α 0.3, A 1, β = γ = 0.5, n 1), a sensor that cannot see sign (w = |y|)
    wn, z = 2 * np.pi * 1.2, 0.2
    mass = sg.lti([wn**2], [1, 2 * z * wn, wn**2])
    u = _drive(n, rate, 1)
    add("abs_sensor", t, u, np.abs(sim(mass, u)), "lti:2", "sensor blind to sign, w = |y|", 5)

    def held(u, rhs, x0):
        def f(time, x):
            return rhs(x, u[min(int(time * rate), n - 1)])

        return solve_ivp(f, (0, t[-1]), x0, t_eval=t, max_step=1 / rate / 4, rtol=1e-7, atol=1e-9).y[0]

    u = _drive(n, rate, 2)
    friction = held(
        u,
        lambda x, d: [x[1], wn**2 * (d - x[0]) - 2 * z * wn * x[1] - wn**2 * 0.3 * np.tanh(x[1] / 0.01)],
        [0, 0],
    )
    add("coulomb", t, u, friction, "lti:2", "Coulomb friction 0.3 on the velocity", 5)

    def bouc_wen(x, d, alpha=0.3):
        dz = x[1] - 0.5 * abs(x[1]) * x[2] - 0.5 * x[1] * abs(x[2])
        return [x[1], wn**2 * d - 2 * z * wn * x[1] - wn**2 * (alpha * x[0] + (1 - alpha) * x[2]), dz]

    add(
        "bouc_wen",
        t,
        _drive(n, rate, 3),
        held(_drive(n, rate, 3), bouc_wen, [0, 0, 0]),
        "lti:2",
        "Bouc–Wen spring",
        5,
    )
    # 4. an additive wander, 15 % peak to peak, period 45 s (1.3 cycles in 60 s), on the lti:2 plant
    for seed in (0, 1, 2):
        u = _drive(n, rate, seed)
        y = sim(plant, u)
        add(
            f"wander{seed}",
            t,
            u,
            y + 0.15 * np.ptp(y) * np.sin(2 * np.pi * t / 45.0 + seed),
            "lti:2",
            "wander",
            99,
        )
    # 6. a user's own plug-in (`PENDULUM`: small angles, linear), 120 s at 50 Hz, a drive of levels in ±1 held
    # 0.5–3 s, w in degrees: a real pendulum (0.8 Hz, ζ 0.15) swinging to ±1.6 rad, its restoring force ω² sin θ
    # (solve_ivp); and the linear one against an inelastic stop at 0.5 rad, stepped here at 1 kHz (at the stop the
    # angle is held and the rate into it is lost)
    rate_p, n_p = 50.0, 6000
    tp = np.arange(n_p) / rate_p
    wp, zp = 2 * np.pi * 0.8, 0.15
    for seed in (0, 1):
        u = _drive(n_p, rate_p, seed, -1.0, 1.0, hold=(0.5, 3.0))

        def swing(time, x, u=u):
            return [
                x[1],
                -(wp**2) * np.sin(x[0])
                - 2 * zp * wp * x[1]
                + 0.6 * wp**2 * u[min(int(time * rate_p), n_p - 1)],
            ]

        angle = solve_ivp(
            swing, (0, tp[-1]), [0, 0], t_eval=tp, max_step=0.5 / rate_p, rtol=1e-9, atol=1e-11
        ).y[0]
        add(
            f"pendulum_sin{seed}",
            tp,
            u,
            np.degrees(angle),
            "pendulum.py:Pendulum",
            "sin θ restoring force",
            seed,
        )
        angle, x, h = np.empty(n_p), np.zeros(2), 1 / rate_p / 20
        for i in range(n_p):
            angle[i] = x[0]
            for _ in range(20):
                x = x + h * np.array([x[1], -(wp**2) * x[0] - 2 * zp * wp * x[1] + 0.9 * wp**2 * u[i]])
                if x[0] > 0.5:
                    x = np.array([0.5, min(x[1], 0.0)])
        add(
            f"pendulum_stop{seed}",
            tp,
            u,
            np.degrees(angle),
            "pendulum.py:Pendulum",
            "end stop at 0.5 rad",
            seed,
        )
    return out


#: The probes' own plug-ins, as a user writes one (docs/plugins.md): written beside the CSV.
PENDULUM = '''"""A driven pendulum for small angles: angle'' = -(2 pi f)^2 angle - 2 zeta (2 pi f) rate + torque u."""
from typing import ClassVar

from hybrid import AbstractStateSpace, Positive, encode


class Pendulum(AbstractStateSpace):
    raw: dict
    constraints: ClassVar[dict] = {"frequency": Positive(), "zeta": Positive(), "torque": Positive()}
    units: ClassVar[dict] = {"frequency": "Hz", "zeta": "1", "torque": "rad/(s^2 {drive})"}
    plausible: ClassVar[dict] = {"frequency": (0.01, 100.0), "zeta": (1e-4, 5.0), "torque": (1e-3, 1e3)}
    typical: ClassVar[dict] = {"frequency": (0.1, 10.0), "zeta": (0.005, 1.0)}
    frozen_by_default: ClassVar[dict] = {"torque": "scales the angle, which the readout's gain does"}
    states: ClassVar[tuple] = ("angle", "rate")
    state_units: ClassVar[dict] = {"angle": "rad", "rate": "rad/s"}
    output_unit: ClassVar[str] = "rad"
    velocity_states: ClassVar[tuple] = ("rate",)

    def __init__(self, frequency=1.0, zeta=0.1, torque=10.0):
        self.raw = encode({"frequency": frequency, "zeta": zeta, "torque": torque}, self.constraints, "Pendulum")

    def prepare(self, p):
        w = 2 * 3.141592653589793 * p["frequency"]
        return {"w2": w * w, "c": 2 * p["zeta"] * w, "b": p["torque"]}

    def rates(self, x, u, p):
        angle, rate = x
        return rate, -p["w2"] * angle - p["c"] * rate + p["b"] * u
'''
PLUGINS = {"pendulum.py": PENDULUM}


def write(probe: dict, path: Path) -> None:
    y = probe["y"]
    w = y + 0.01 * np.ptp(y) * np.random.default_rng(probe["noise_seed"]).standard_normal(len(y))
    np.savetxt(path, np.c_[probe["t"], probe["u"], w], delimiter=",", header="t,v_in,w", comments="")


def row(name: str, probe: dict, folder: Path) -> dict:
    path = folder / f"{name}.csv"
    write(probe, path)
    out = folder / f"out_{name}"
    physics = probe["physics"]
    source = PLUGINS.get(physics.split(":")[0])
    if source is not None:
        (folder / physics.split(":")[0]).write_text(source)
        physics = str(folder / physics)
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "hybrid.cli",
            "diagnose",
            str(path),
            "--physics",
            physics,
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    if done.returncode != 0:
        return {"probe": name, "hidden": probe["hidden"], "error": done.stderr.strip().splitlines()[-1:]}
    report = json.loads((out / "report.json").read_text())
    lead = (out / "report.md").read_text().splitlines()[2].strip("*")
    return {
        "probe": name,
        "physics": probe["physics"],
        "hidden": probe["hidden"],
        "causes": [(c["name"], round(c["incremental_gain"], 3)) for c in report["causes"]],
        "parameters": {
            k: [v["value"], v.get("unit")] for c in report["causes"] for k, v in c["parameters"].items()
        },
        "unexplained": bool(report.get("unexplained")),
        "ambiguous": [
            (e["step"], e["named"], [r["name"] for r in e["rivals"]]) for e in report.get("ambiguous") or []
        ],
        "lead": lead,
        "remainder": ((report.get("unexplained") or {}).get("description") or {}).get("summary", ""),
    }


def table(rows: list[dict], command: str) -> str:
    lines = [
        "# New-user probes: scipy-made plants and effects, diagnosed from the command line",
        "",
        f"Command: `{command}`",
        "",
        "| probe | physics | hidden | named (incremental gain) | unexplained | ambiguous (step: named vs rivals) |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['probe']} | | {r['hidden']} | error: {r['error']} | | |")
            continue
        named = ", ".join(f"{n} ({g:.3g})" for n, g in r["causes"]) or "∅"
        amb = "; ".join(f"{s}: {n} vs {', '.join(v)}" for s, n, v in r["ambiguous"]) or "—"
        lines.append(
            f"| {r['probe']} | {r['physics']} | {r['hidden']} | {named} | {'yes' if r['unexplained'] else 'no'} | {amb} |"
        )
    lines += ["", "First sentence of each report:", ""]
    lines += [f"- {r['probe']}: {r.get('lead', '')[:400]}" for r in rows if "error" not in r]
    lines += [
        "",
        "What each flagged remainder reads as (report.json → unexplained → description → summary):",
        "",
    ]
    lines += [f"- {r['probe']}: {r['remainder'][:500]}" for r in rows if r.get("remainder")]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", default="", help="probe names, comma-separated (default: all)")
    parser.add_argument("--out", default="experiments/results/new_user_probes.json")
    args = parser.parse_args(argv)
    all_probes = probes()
    names = [n for n in args.only.split(",") if n] or list(all_probes)
    unknown = sorted(set(names) - set(all_probes))
    if unknown:
        parser.error(f"unknown probe(s) {', '.join(unknown)}: choose from {', '.join(all_probes)}")
    with tempfile.TemporaryDirectory(prefix="probes-") as folder:
        rows = []
        for name in names:
            rows.append(row(name, all_probes[name], Path(folder)))
            print(json.dumps(rows[-1])[:300], flush=True)
    command = "python experiments/new_user_probes.py " + shlex.join(argv)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"command": command.strip(), "rows": rows}, indent=1))
    out.with_suffix(".md").write_text(table(rows, command.strip()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
