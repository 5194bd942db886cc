"""The sensitivity and identifiability study behind `hybrid sensitivity` and `experiments/sensitivity.py`.

At nominal RC-network parameters (Eqs 4–14), for a primary drive and for each
of the paper's four drives (PRBS, sine, chirp, pulse, as in the Table 2
reproduction), it computes with [`hybrid.sensitivity`][]:

- the normalised sensitivities of V_o to the six physical parameters over time;
- the SVD of that matrix: singular values, null and near-null directions (in
  log-parameter coordinates), near-collinear pairs;
- per drive, what an experimenter needs: the relative standard error each
  parameter would get from a recording of w = gain · V_o + offset with noise of
  `noise` × rms(w), gain and offset unknown and ξh fixed (the Cramér–Rao bound
  σ²(JᵀJ)⁻¹ of the physics-only model, in physical units);
- the sensitivity of |H(j2πf)| and ∠H to each parameter by frequency;
- optionally, Sobol indices by sampling.

Writes ``sensitivity.json``, ``sensitivity.md`` and the figures
``sensitivity_time.png``, ``sensitivity_frequency.png``, ``sensitivity_drives.png``,
``singular_values.png`` to `out_dir`.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from ..util._atomic import write_text
from ..util._errors import InputError
from ..util._figures import save_png

DRIVE_ORDER = ("prbs", "sine", "chirp", "pulse")
#: Fewest samples of a recording given as the primary drive: with fewer samples than
#: parameters most directions are null by construction, and below ~2 s of a 30 Hz
#: camera the network's 0.1-1 s time constants are not seen at all.
MIN_RECORDING = 60
#: Every file written to `out_dir` (each atomically: hybrid.util._atomic).
OUTPUT_FILES = (
    "sensitivity.json",
    "sensitivity.md",
    "sensitivity_time.png",
    "sensitivity_frequency.png",
    "sensitivity_drives.png",
    "singular_values.png",
)


@dataclasses.dataclass(frozen=True)
class SensitivityStudySettings:
    """What the study runs (every field is recorded in ``sensitivity.json``).

    - `parameters`: nominal RC-network parameters (physical units); missing
      ones take [`hybrid.RCNetwork`][]'s defaults.
    - `n_stages`: N (N + 1 sections).
    - `drive`: the primary drive (one of PRBS, sine, chirp, pulse) for the
      top-level singular values and null directions.
    - `duration`, `rate`: seconds and Hz of every drive.
    - `noise`: measurement noise as a fraction of rms(w) for the per-drive
      standard errors.
    - `sobol`: base samples N for Sobol indices (0: skip).
    - `seed`: seeds the drives and the Sobol samples.
    """

    parameters: dict = dataclasses.field(default_factory=dict)
    n_stages: int = 45
    drive: str = "prbs"
    duration: float = 120.0
    rate: float = 30.0
    noise: float = 0.01
    sobol: int = 0
    seed: int = 0


def _drives(settings):
    from ..data._drives import make_drive
    from ._table2 import Table2Settings

    params = Table2Settings().drives
    return {
        name: make_drive(
            name, settings.duration, rate=settings.rate, seed=settings.seed, **params.get(name, {})
        )
        for name in DRIVE_ORDER
    }


def _cramer_rao(model_sens, noise_fraction, fixed=("xi_h",), report_skip=("offset",)):
    """Relative standard errors from σ²(JᵀJ)⁻¹ of ŵ's Jacobian, with `fixed` parameters left out.

    The offset is estimated too (a nuisance parameter) but not reported: its
    nominal value is 0, so it has no relative error.
    """
    names = [n for n in model_sens.names if n not in fixed]
    cols = [model_sens.names.index(n) for n in names]
    J = model_sens.jacobian[:, cols]
    sigma = noise_fraction * model_sens.output_rms
    u, s, vt = np.linalg.svd(J, full_matrices=False)
    cov = sigma**2 * (vt.T / s**2) @ vt
    se = np.sqrt(np.diag(cov))
    return {n: float(se[i] / abs(model_sens.values[n])) for i, n in enumerate(names) if n not in report_skip}


def run_sensitivity_study(
    settings: SensitivityStudySettings = SensitivityStudySettings(),
    out_dir="experiments/results/sensitivity",
    recording=None,
) -> dict:
    """Run the study; returns the content of ``sensitivity.json``.

    `recording`: optionally a Recording whose drive replaces the primary drive.
    """
    import jax

    from .. import sensitivity as S
    from ..core._models import Model
    from ..core._readout import LinearReadout
    from ..physics._rc_network import RCNetwork

    if settings.drive not in DRIVE_ORDER:
        raise InputError(f"drive must be one of {', '.join(DRIVE_ORDER)}, got {settings.drive!r}")
    if not (np.isfinite(settings.noise) and settings.noise > 0):
        raise InputError(f"noise must be a positive fraction of rms(w), got {settings.noise!r}")
    if settings.sobol < 0 or settings.sobol == 1:
        raise InputError(f"sobol must be 0 (skip) or a number of base samples ≥ 2, got {settings.sobol!r}")
    if recording is not None:  # a recording too short or constant to say anything is refused
        recording.check_signals()
        recording.check_length(
            MIN_RECORDING,
            "the sensitivity study (2 s at 30 Hz: the RC network's time constants are 0.1-1 s)",
            "give a longer recording",
        )
    t_start = time.perf_counter()
    network = RCNetwork(n_stages=settings.n_stages)
    if settings.parameters:
        network = network.replace(**settings.parameters)
    nominal = {k: float(v) for k, v in network.parameters().items()}
    drives = _drives(settings)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    signals = {name: (np.asarray(d.v), 1.0 / d.rate) for name, d in drives.items()}
    primary = settings.drive
    if recording is not None:
        primary = f"recording:{recording.name}"
        signals = {primary: (np.asarray(recording.v_in), float(recording.dt)), **signals}

    # Physics-only model: w = V_o (gain 1, offset 0) — a unit gain keeps w in volts' scale.
    physics = Model(network, LinearReadout(1.0, 0.0), "physics")
    vo_sens, w_sens, idents = {}, {}, {}
    for name, (v, dt) in signals.items():
        vo_sens[name] = S.local_sensitivities(network, v, dt)
        w_sens[name] = S.local_sensitivities(physics, v, dt)
        idents[name] = vo_sens[name].identifiability()

    top = idents[primary]
    by_drive = {}
    for name in signals:
        by_drive[name] = {
            "rms_normalised_sensitivity": vo_sens[name].rms_normalised(),
            "relative_std_error": _cramer_rao(w_sens[name], settings.noise),
            "relative_singular_values": [
                float(s / idents[name].singular_values[0]) for s in idents[name].singular_values
            ],
            "collinear_pairs": [{"pair": [a, b], "cosine": c} for a, b, c in idents[name].collinear_pairs],
        }
    best_drive = {}
    for p in by_drive[primary]["relative_std_error"]:
        candidates = {d: by_drive[d]["relative_std_error"][p] for d in DRIVE_ORDER}
        best_drive[p] = min(candidates, key=candidates.__getitem__)

    frequency = np.logspace(np.log10(0.002), np.log10(0.5 * settings.rate * 0.99), 200)
    freq = S.frequency_sensitivity(network, frequency)
    peaks = {}
    for j, n in enumerate(freq["names"]):
        k = int(np.argmax(np.abs(freq["magnitude"][:, j])))
        peaks[n] = {
            "frequency_hz": float(frequency[k]),
            "dlog_gain_dlog_theta": float(freq["magnitude"][k, j]),
        }

    sobol = None
    if settings.sobol:
        v, dt = signals[primary]
        sobol = S.sobol_indices(network, v, dt, n_base=settings.sobol, seed=settings.seed).to_dict()

    result = {
        "command": "hybrid sensitivity --out DIR",
        "names": list(top.names),
        "nominal": nominal,
        "primary_drive": primary,
        "coordinates": "log-parameter: a direction {name: c} changes each parameter by the factor exp(c t)",
        "output": "V_o (V), the RC network's tip voltage",
        **top.summary(),
        "by_drive": by_drive,
        "best_drive_per_parameter": best_drive,
        "frequency_peaks": peaks,
        "sobol": sobol,
        "settings": dataclasses.asdict(settings),
        "x64": bool(jax.config.read("jax_enable_x64")),
    }
    _figures(out_dir, vo_sens[primary], idents, freq, by_drive, primary)
    result["seconds"] = time.perf_counter() - t_start
    write_text(out_dir / "sensitivity.json", json.dumps(result, indent=2))
    write_text(out_dir / "sensitivity.md", _markdown(result))
    return result


def _markdown(result) -> str:
    names = result["names"]
    drives = [d for d in result["by_drive"] if d in DRIVE_ORDER]
    noise = result["settings"]["noise"]
    lines = [
        f"# Sensitivity of V_o at the nominal parameters ({result['settings']['duration']:g} s per drive)",
        "",
        f"Relative standard error of each parameter from a recording of w = gain·V_o + offset with noise "
        f"{100 * noise:g} % of rms(w), gain and offset unknown, ξh fixed (Cramér–Rao bound; smaller is better; "
        "**bold** = the drive to record for that parameter). In brackets: rms of θ ∂V_o/∂θ / rms(V_o).",
        "",
        "| parameter | " + " | ".join(drives) + " |",
        "|---|" + "---|" * len(drives),
    ]
    rows = names + [n for n in result["by_drive"][drives[0]]["relative_std_error"] if n not in names]
    for n in rows:
        cells = []
        for d in drives:
            se = result["by_drive"][d]["relative_std_error"].get(n)
            sens = result["by_drive"][d]["rms_normalised_sensitivity"].get(n)
            text = "—" if se is None else f"{se:.2e}"
            if se is not None and result["best_drive_per_parameter"].get(n) == d:
                text = f"**{text}**"
            cells.append(text if sens is None else f"{text} ({sens:.2f})")
        lines.append(f"| {n} | " + " | ".join(cells) + " |")
    lines += ["", "Relative singular values of the normalised V_o sensitivities:", ""]
    for d in drives:
        values = ", ".join(f"{s:.1e}" for s in result["by_drive"][d]["relative_singular_values"])
        lines.append(f"- {d}: {values}")
    lines += [
        "",
        f"Null directions ({result['primary_drive']}, log coordinates): {result['null_directions']}",
        "",
        "Near-collinear pairs (|cos| ≥ {:g}): {}".format(
            result["tolerances"]["collinearity"],
            ", ".join(
                f"{p['pair'][0]}–{p['pair'][1]} ({p['cosine']:+.4f})" for p in result["collinear_pairs"]
            ),
        ),
        "",
    ]
    return "\n".join(lines)


def _figures(out_dir, sens, idents, freq, by_drive, primary):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = sens.time
    S = sens.normalised()
    fig, axes = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    axes[0].plot(t, sens.output, "k", lw=0.8)
    axes[0].set_ylabel("V_o (V)")
    for j, n in enumerate(sens.names):
        axes[1].plot(t, S[:, j], lw=0.8, label=n, ls="--" if n == "xi_h" else "-")
    axes[1].set_ylabel("θ ∂V_o/∂θ / rms(V_o)")
    axes[1].set_xlabel("t (s)")
    axes[1].legend(ncol=3, fontsize=8)
    axes[0].set_title(f"Normalised sensitivities of V_o ({primary}); ξh's curve is −ξρ's")
    fig.tight_layout()
    save_png(fig, out_dir / "sensitivity_time.png")

    fig, axes = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for j, n in enumerate(freq["names"]):
        axes[0].semilogx(freq["frequency"], freq["magnitude"][:, j], label=n)
        axes[1].semilogx(freq["frequency"], freq["phase"][:, j], label=n)
    axes[0].set_ylabel("∂ log|H| / ∂ log θ")
    axes[1].set_ylabel("∂∠H / ∂ log θ (rad)")
    axes[1].set_xlabel("frequency (Hz)")
    axes[0].legend(ncol=3, fontsize=8)
    axes[0].set_title("Which frequencies carry each parameter (Eq 14)")
    fig.tight_layout()
    save_png(fig, out_dir / "sensitivity_frequency.png")

    drives = [d for d in by_drive if d in DRIVE_ORDER]
    names = list(by_drive[drives[0]]["relative_std_error"])
    fig, ax = plt.subplots(figsize=(8, 4))
    width = 0.8 / len(drives)
    for i, d in enumerate(drives):
        values = [by_drive[d]["relative_std_error"][n] for n in names]
        ax.bar(np.arange(len(names)) + i * width, values, width, label=d)
    ax.set_yscale("log")
    ax.set_xticks(np.arange(len(names)) + 0.4 - width / 2, names)
    ax.set_ylabel("relative standard error")
    ax.set_title("Which drive identifies which parameter (1 % noise, gain and offset unknown, ξh fixed)")
    ax.legend()
    fig.tight_layout()
    save_png(fig, out_dir / "sensitivity_drives.png")

    fig, ax = plt.subplots(figsize=(6, 4))
    for d, ident in idents.items():
        ax.semilogy(
            np.arange(1, len(ident.singular_values) + 1),
            ident.singular_values / ident.singular_values[0],
            "o-",
            label=d,
        )
    ax.axhline(ident.tolerances["null"], color="grey", ls=":", lw=0.8)
    ax.axhline(ident.tolerances["near_null"], color="grey", ls="--", lw=0.8)
    ax.set_xlabel("index")
    ax.set_ylabel("σ_i / σ_1")
    ax.set_title("Singular values of the normalised V_o sensitivities")
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_png(fig, out_dir / "singular_values.png")
