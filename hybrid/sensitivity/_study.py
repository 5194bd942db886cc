"""The sensitivity study of any simulation on one drive: `hybrid sensitivity --physics SPEC RECORDING`.

At the simulation's nominal parameters (its defaults, or the values given), on a
recorded drive, for the free parameters (those not in its `frozen_by_default`, as `fit`
leaves them fixed):

- the local sensitivities ∂y(t)/∂θ of the simulation's output y
  ([`local_sensitivities`][hybrid.sensitivity.local_sensitivities]);
- identifiability: the SVD of the scaled sensitivities s_j ∂w/∂θ_j / rms(w) of
  w = gain · y + offset at gain 1, offset 0, over the parameters the standard errors
  below are of, gain and offset included
  ([`Sensitivity.identifiability`][hybrid.sensitivity.Sensitivity.identifiability]), with
  s_j = |θ_j| (log coordinates, as the RC study) where θ_j ≠ 0 and, for a parameter at
  0, a typical magnitude ([`parameter_scales`][hybrid.sensitivity.parameter_scales]):
  null and near-null directions, near-collinear pairs;
- the Cramér–Rao standard errors a recording of w = gain · y + offset with white
  noise of `noise` × rms(w) would give, gain and offset unknown:
  σ² (JᵀJ)⁻¹ with J = ∂w/∂θ in physical units at gain 1, offset 0. A parameter
  that moves along a null direction of J (below `rcond` · σ_max) gets an
  infinite standard error;
- optionally Sobol indices ([`sobol_indices`][hybrid.sensitivity.sobol_indices]).

No IPMC-specific view is applied: the RC network's frequency views and
Table 1 names belong to `hybrid.ipmc._sensitivity_study` (`--physics rc`).
Writes ``sensitivity.json``, ``sensitivity.md``, ``sensitivity_time.png`` and
``singular_values.png``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from ..core._models import Model
from ..core._readout import LinearReadout
from ..core._result import aliased, one_frequency_drive
from ..core._simulation import unit_in, unit_suffix
from ..util._atomic import write_text
from ..util._errors import InputError
from ..util._figures import save_png
from ._local import local_sensitivities

#: Every file `write_simulation_study` writes.
OUTPUT_FILES = ("sensitivity.json", "sensitivity.md", "sensitivity_time.png", "singular_values.png")


def _clean(x):
    x = float(x)
    return x if np.isfinite(x) else str(x)


def cramer_rao(jacobian, names, noise_std: float, rcond: float = 1e-10) -> tuple[dict[str, float], list[str]]:
    """Standard errors sqrt(diag σ²(JᵀJ)⁻¹) by name, and the names with an infinite one.

    `jacobian` (T × k) is ∂w/∂θ in physical units. Its columns are scaled to unit norm
    first (so that `rcond` does not depend on the parameters' units); directions whose
    singular value is then below `rcond` · σ_max are null, and a parameter with a
    component along one (or whose column is zero) is unidentifiable.
    """
    J = np.asarray(jacobian, dtype=float)
    norms = np.linalg.norm(J, axis=0)
    c = np.where(norms > 0, norms, 1.0)
    _, s, vt = np.linalg.svd(J / c, full_matrices=J.shape[0] < J.shape[1])
    s = np.concatenate([s, np.zeros(vt.shape[0] - s.size)])
    keep = s > rcond * s[0] if s.size and s[0] > 0 else np.zeros(s.size, bool)
    cov = noise_std**2 * (vt[keep].T / s[keep] ** 2) @ vt[keep] / np.outer(c, c)
    se = np.sqrt(np.diag(cov))
    null = vt[~keep]
    bad = (np.linalg.norm(null, axis=0) > 1e-6 if null.size else np.zeros(len(names), bool)) | (norms == 0)
    return (
        {n: (float("inf") if b else float(v)) for n, v, b in zip(names, se, bad)},
        [n for n, b in zip(names, bad) if b],
    )


def simulation_study(
    simulation,
    v_in,
    dt: float,
    *,
    noise: float = 0.01,
    sobol: int = 0,
    seed: int = 0,
    drive: str = "drive",
    drive_unit: str = "V",
    rcond: float = 1e-10,
) -> tuple[dict, object]:
    """Sensitivities, identifiability and Cramér–Rao standard errors of `simulation` on the drive `v_in`.

    **Arguments:**

    - `simulation`: any [`AbstractSimulation`][hybrid.AbstractSimulation], at the parameters to study.
    - `v_in`, `dt`: the drive and its sample interval (s).
    - `noise`: the measurement noise as a fraction of rms(w), for the standard errors.
    - `sobol`: base samples N for Sobol indices (0: none).
    - `seed`: seeds the Sobol samples.
    - `drive`: the drive's name in the report.
    - `drive_unit`: the drive's unit, for the units that a plug-in states per ``"{drive}"``.
    - `rcond`: relative singular value below which a direction of J is null.

    **Returns:** (the content of ``sensitivity.json``, the [`Sensitivity`][hybrid.sensitivity.Sensitivity] of y).
    """
    from ._sobol import sobol_indices

    t_start = time.perf_counter()
    if not (np.isfinite(noise) and noise > 0):
        raise InputError(f"noise must be a positive fraction of rms(w), got {noise!r}")
    if sobol < 0 or sobol == 1:
        raise InputError(f"sobol must be 0 (skip) or a number of base samples ≥ 2, got {sobol!r}")
    frozen = dict(simulation.frozen_by_default)
    physics = Model(
        simulation, LinearReadout(1.0, 0.0), "physics"
    )  # w = y: the readout's J columns are y and 1
    w_sens = local_sensitivities(physics, v_in, dt, frozen=frozenset(frozen))
    names = [n for n in w_sens.names if n not in ("gain", "offset")]
    if not names:
        raise InputError(
            f"{type(simulation).__name__} has no free parameter (frozen by default: "
            f"{sorted(frozen)}): nothing to study"
        )
    columns = [w_sens.names.index(n) for n in names]
    y = w_sens.output
    rms = float(np.sqrt(np.mean(y**2)))
    if not (np.isfinite(rms) and rms > 0):
        raise InputError(
            f"{type(simulation).__name__}'s output is zero for this drive: nothing depends on its parameters"
        )
    # gain and offset included: a direction along which the gain absorbs the parameters' change
    # (a plug-in that scales with the readout) makes their standard errors infinite and is named
    ident = w_sens.identifiability()
    S = w_sens.normalised()[:, columns]
    sigma = noise * rms  # rms(w) = rms(y) at gain 1, offset 0
    se, unidentifiable = cramer_rao(w_sens.jacobian, w_sens.names, sigma, rcond)
    relative = {n: (se[n] / abs(w_sens.values[n]) if w_sens.values[n] else None) for n in w_sens.names}
    # w = y nominally: the gain is w's unit per y's (1), the offset in y's unit, the simulation's output's
    output = unit_in(str(getattr(simulation, "output_unit", "") or ""), drive_unit) or "(unit of y)"
    units = {
        **{k: unit_in(v, drive_unit) for k, v in simulation.units.items()},
        "gain": "1",
        "offset": output,
    }
    result = {
        "command": "hybrid sensitivity --physics SPEC RECORDING --out DIR",
        "simulation": type(simulation).__name__,
        "names": names,
        "nominal": {k: float(v) for k, v in simulation.parameters().items()},
        "units": {n: units.get(n, "") for n in w_sens.names},
        "frozen": frozen,
        "primary_drive": drive,
        "samples": int(S.shape[0]),
        "dt": float(dt),
        "coordinates": "scaled: a direction {name: c} moves each parameter by c·scale (scale = |value|, a "
        "relative change, or for a parameter at 0 the half-width of its typical range, else the change that "
        "moves w by its rms)",
        "scales": w_sens.scales,
        "output": "y, the simulation's output for the drive (for the identifiability and the standard errors: "
        "w = gain·y + offset)",
        "rms_normalised_sensitivity": dict(zip(names, map(float, np.sqrt(np.mean(S**2, axis=0))))),
        **ident.summary(),
        "noise": {"fraction_of_rms_w": float(noise), "std": sigma, "rcond": rcond},
        "std_error": {n: _clean(v) for n, v in se.items()},
        "relative_std_error": {n: (None if v is None else _clean(v)) for n, v in relative.items()},
        "unidentifiable": unidentifiable,
        # what the bounds cannot see: a drive of one frequency, a frequency the samples alias
        "warnings": one_frequency_drive([(v_in, 1.0 / dt)], bounds=True)
        + aliased(
            physics,
            frozen,
            1.0 / dt,
            advice="its standard error describes the model at the value given, which the recording cannot tell "
            "from that alias: study a value below the Nyquist frequency, or a recording sampled faster than "
            "twice it",
        ),
        "sobol": (
            sobol_indices(simulation, v_in, dt, n_base=sobol, seed=seed, frozen=frozenset(frozen)).to_dict()
            if sobol
            else None
        ),
    }
    result["warnings"] += sobol_warnings(result["sobol"])
    result["seconds"] = time.perf_counter() - t_start
    return result, w_sens


#: A total Sobol index below its first-order one by more than this is sampling noise (ST ≥ S1 in exact terms).
SOBOL_SLACK = 0.01


def sobol_warnings(sobol: dict | None) -> list[str]:
    """A sentence where the Sobol estimates contradict each other (a total index below its first-order one).

    A probe's `--sobol 64` gave tau_a's total index 0.087 below its first-order 0.105, which no exact
    value can be, without a word: too few base samples for the indices to be read.
    """
    if not sobol:
        return []
    first, total = sobol.get("first_order", {}), sobol.get("total", {})
    below = [n for n in first if n in total and total[n] < first[n] - SOBOL_SLACK]
    if not below:
        return []
    n = below[0]
    return [
        f"the Sobol indices from {sobol.get('n_base', '?')} base samples are noisy: {n}'s total index "
        f"{total[n]:.3g} is below its first-order index {first[n]:.3g}, which exact indices never are"
        + (f" (and {len(below) - 1} more)" if len(below) > 1 else "")
        + "; take more base samples (--sobol 1024; sobol= in Python) before reading them"
    ]


def write_simulation_study(result: dict, sensitivity, out_dir) -> None:
    """``sensitivity.json``, ``sensitivity.md`` and the two figures, each written atomically."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    _figures(result, sensitivity, out_dir)
    write_text(out_dir / "sensitivity.json", json.dumps(result, indent=2))
    write_text(out_dir / "sensitivity.md", _markdown(result))


def _markdown(result) -> str:
    noise = result["noise"]["fraction_of_rms_w"]
    lines = [
        f"# Sensitivity of {result['simulation']} at its nominal parameters ({result['primary_drive']}, "
        f"{result['samples']} samples)",
        "",
        f"Standard error each parameter would get from a recording of w = gain·y + offset with white noise "
        f"{100 * noise:g} % of rms(w), gain and offset unknown (Cramér–Rao bound; inf: not identifiable). "
        "Scaled sensitivity: rms of scale·∂y/∂θ / rms(y).",
        "",
        "| parameter | nominal | standard error | relative | scaled sensitivity |",
        "|---|---|---|---|---|",
    ]
    for n, se in result["std_error"].items():
        rel = result["relative_std_error"][n]
        sens = result["rms_normalised_sensitivity"].get(n)
        unit = result["units"].get(n, "")
        se_text = se if isinstance(se, str) else f"{se:.3g}{unit_suffix(unit)}"
        rel_text = "—" if rel is None else (rel if isinstance(rel, str) else f"{rel:.2e}")
        nominal = result["nominal"].get(n, 1.0 if n == "gain" else 0.0)
        lines.append(
            f"| {n} | {nominal:.6g} | {se_text} | {rel_text} | {'—' if sens is None else f'{sens:.3g}'} |"
        )
    frozen = ", ".join(f"{k} ({v})" for k, v in result["frozen"].items()) or "none"
    values = ", ".join(f"{s:.1e}" for s in result["relative_singular_values"])
    pairs = ", ".join(
        f"{p['pair'][0]}–{p['pair'][1]} ({p['cosine']:+.4f})" for p in result["collinear_pairs"]
    )
    lines += [
        "",
        f"Frozen (left out, as `fit` does): {frozen}.",
        "",
        f"Relative singular values of the scaled sensitivities of w (gain and offset included): {values}",
        "",
        f"Null directions (scaled coordinates): {_directions(result['null_directions'])}",
        "",
        f"Near-null directions: {_directions(result['near_null_directions'])}",
        "",
        f"Near-collinear pairs (|cos| ≥ {result['tolerances']['collinearity']:g}): {pairs or 'none'}",
        "",
    ]
    sobol = result.get("sobol")
    if sobol:
        lines += [
            f"Sobol indices ({sobol.get('n_base', '?')} base samples, parameters drawn ±{sobol.get('spread', 0):g} "
            "around the nominal values, in log for a positive one): first-order S1 and total ST of the output's variance.",
            "",
            "| parameter | S1 | ST |",
            "|---|---|---|",
            *(
                f"| {n} | {sobol['first_order'][n]:.3g} | {sobol['total'][n]:.3g} |"
                for n in sobol.get("first_order", {})
            ),
            "",
        ]
    lines += [f"Warning: {said}\n" for said in result.get("warnings", [])]
    return "\n".join(lines)


def _directions(directions) -> str:
    return "; ".join(" ".join(f"{c:+.4f}·{n}" for n, c in d.items()) for d in directions) or "none"


def _figures(result, sensitivity, out_dir) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = result["names"]
    t = sensitivity.time
    y = sensitivity.output
    rms = max(float(np.sqrt(np.mean(y**2))), np.finfo(float).tiny)
    fig, axes = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    axes[0].plot(t, y, "k", lw=0.8)
    axes[0].set_ylabel("y")
    for n in names:
        j = sensitivity.names.index(n)
        axes[1].plot(t, sensitivity.jacobian[:, j] * result["scales"][n] / rms, lw=0.8, label=n)
    axes[1].set_ylabel("scale · ∂y/∂θ / rms(y)")
    axes[1].set_xlabel("t (s, from the drive's first sample)")
    axes[1].legend(ncol=3, fontsize=8)
    drive = result["primary_drive"]
    drive = drive if len(drive) <= 60 else f"…{drive[-59:]}"
    axes[0].set_title(f"Scaled sensitivities of {result['simulation']}'s output ({drive})", fontsize=10)
    fig.tight_layout()
    save_png(fig, out_dir / "sensitivity_time.png")

    fig, ax = plt.subplots(figsize=(6, 4))
    values = np.asarray(result["relative_singular_values"])
    ax.semilogy(np.arange(1, values.size + 1), np.maximum(values, 1e-17), "o-")
    ax.axhline(result["tolerances"]["null"], color="grey", ls=":", lw=0.8)
    ax.axhline(result["tolerances"]["near_null"], color="grey", ls="--", lw=0.8)
    ax.set_xlabel("index")
    ax.set_ylabel("σ_i / σ_1")
    ax.set_title("Singular values of the scaled sensitivities")
    fig.tight_layout()
    save_png(fig, out_dir / "singular_values.png")
