"""The report of `hybrid diagnose`: ``report.json``, ``report.md`` and five figures.

`write_report(diagnosis, out_dir)` writes

- ``report.json``: ``Diagnosis.to_dict()``, strictly valid JSON (numpy values
  converted, NaN and ±inf as ``null``), written atomically;
- ``residual_time.png``, ``loops.png``, ``spectrum.png``, ``correlation.png``,
  ``segments.png``: the held-out residuals of the baseline and of the extended
  model (the one with the named effect), each figure showing both;
- ``report.md``: a lab-notebook page that names the cause, tabulates the
  evidence and embeds the figures with what to look for in each.

Everything is computed from ``Diagnosis.to_dict()`` and ``Diagnosis.heldout``;
nothing is refitted. The figures are drawn by `hybrid.discovery._report_figures`.
"""

from __future__ import annotations

import datetime
import json
import math
import os
from pathlib import Path

import numpy as np

from ..core._simulation import unit_suffix
from ..util._atomic import atomic_open
from . import residual_tests as rt
from ._ambiguity import sentence as ambiguity_sentence
from ._joint import JOINT_BELOW
from ._report_figures import FIGURES, MAX_LAG, count_loop_levels, format_nmse, save_figure, write_figures
from ._verdict import too_small_sentence

# --------------------------------------------------------------------------- #
# JSON
# --------------------------------------------------------------------------- #


def jsonable(value):
    """`value` with numpy scalars/arrays as Python numbers/lists and NaN, ±inf as None."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        value = float(value)
        return value if math.isfinite(value) else None
    if value is None or isinstance(value, str):
        return value
    if isinstance(value, Path):
        return str(value)
    if hasattr(value, "__array__"):  # JAX arrays and other array-likes
        return jsonable(np.asarray(value))
    raise TypeError(f"report.json cannot hold a {type(value).__name__}: {value!r}")


def _write_atomic(path: Path, text: str) -> None:
    with atomic_open(path) as handle:
        handle.write(text)


# --------------------------------------------------------------------------- #
# Markdown
# --------------------------------------------------------------------------- #


def _num(x, digits: int = 3) -> str:
    if x is None:
        return "—"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, int):
        return str(x)
    return f"{x:.{digits}g}"


def _fixed(x) -> str:
    """One decimal (ΔBIC, Ljung–Box Q)."""
    return "—" if x is None else f"{x:.1f}"


def _pct(x) -> str:
    return "—" if x is None else f"{x:.1f} %"


def _share(x) -> str:
    """A fraction (0–1) as a percentage."""
    return "—" if x is None else f"{100 * x:.1f} %"


def plus_minus(entry: dict) -> str:
    """``value ± std_error unit`` with the standard error to 2 significant digits.

    A parameter the recording does not pin (``pinned`` false, or a standard
    error that is infinite or above the value) reads ``value unit (not pinned
    by this recording: why)``, never ``± inf``. One that is not the training
    part's optimum (``at_training_optimum`` false) says so, with that optimum.
    """
    value, se, unit = entry.get("value"), entry.get("std_error"), entry.get("unit") or ""
    unit = "" if unit == "1" else unit  # dimensionless
    loose = se is not None and (
        not math.isfinite(se) or (value is not None and math.isfinite(value) and se > abs(value))
    )
    if entry.get("pinned") is False or loose:
        why = entry.get("not_pinned") or (
            "its standard error is larger than its value"
            if se is not None and math.isfinite(se)
            else "its standard error is infinite"
        )
        return f"{_num(value, 4)} {unit}".rstrip() + f" (not pinned by this recording: {why})"
    text = _num(value, 4) if se is None else f"{_num(value, 4)} ± {_num(se, 2)}"
    given = entry.get("std_error_given_network")
    if given is not None:
        text += f" (± {_num(given, 2)} with the simulation's parameters fixed)"
    return f"{text} {unit}".rstrip() + _off_optimum(entry)


#: An optimum this many times the value's size away reads as "much further", not as a value to take: a hard
#: clip's sharpness of 20 whose training optimum ran to 1,500 read "174 standard errors away" (a probe).
FAR_OPTIMUM = 10.0


def _off_optimum(entry: dict) -> str:
    """Where a value is not the training part's optimum (``at_training_optimum`` false): how far, and that optimum."""
    step, se, value = entry.get("to_training_optimum"), entry.get("std_error"), entry.get("value")
    if entry.get("at_training_optimum") is not False or step is None or not se or value is None:
        return ""
    if abs(step) > FAR_OPTIMUM * abs(value):  # a hard clip's sharpness heading for a clip: not an error
        return (
            f" (the training part alone takes it much further, to ≈ {_num(value + step, 3)}, "
            f"{abs(step) / se:.0f} standard errors on: the fit stopped here)"
        )
    return (
        " (the fit stopped where the validation part liked it best; the training part alone would move "
        f"it to ≈ {_num(value + step, 3)}, {abs(step) / se:.1f} standard errors away)"
    )


def parameter_rows(d: dict) -> list[str]:
    """report.md's rows ``| name | value ± error unit |`` of report.json `d`'s parameters; a fixed one with its unit."""
    frozen = set(d["settings"].get("frozen") or ())
    rows = []
    for name, entry in d["parameters"].items():
        fixed = f"{_num(entry['value'], 4)}{unit_suffix(entry.get('unit'))} (fixed)"
        text = fixed if name in frozen else plus_minus(entry)
        rows.append(f"| {name} | {text} |")
    return rows


_SUFFIXES = (
    ("_percent_of_range", "% of range"),
    ("_percent", "%"),
    ("_samples", "samples"),
    ("_hz", "Hz"),
    ("_s", "s"),
    ("_v", "V"),
    ("_mm", "mm"),
)


def _quantity(key: str, value, units: dict | None = None) -> tuple[str, str]:
    """(label, value with unit) of a derived quantity: its unit in `units` (the effect's `derived_units`),
    else the one its name says (``delay_samples``, ``over_s``)."""
    unit = (units or {}).get(key)
    if unit:
        return key.replace("_", " "), f"{_num(value, 4)} {unit}"
    for suffix, unit in _SUFFIXES:
        if key.endswith(suffix):
            return key[: -len(suffix)].replace("_", " "), f"{_num(value, 4)} {unit}"
    return key.replace("_", " "), _num(value, 4)


def _sizes(cause: dict) -> str:
    """A cause's derived quantities with their units, each level of an output-side one also as recorded."""
    recorded, unit = cause.get("as_recorded") or {}, cause.get("as_recorded_unit", "")
    out = []
    for k, v in cause["derived"].items():
        text = " ".join(_quantity(k, v, cause.get("derived_units")))
        if k in recorded:
            text += f" ({_num(recorded[k], 4)}{' ' + unit if unit else ''} as recorded)"
        out.append(text)
    return ", ".join(out)


def _output_unit_note(d: dict) -> list[str]:
    """A sentence under the parameters where an output-side cause's sizes are in the simulation's unit, not w's.

    A probe's baseline drift on a millimetre sensor read "2.226 V/min" beside an offset in mm (`lti:N`'s
    output is in the drive's unit): right, but read as a unit error.
    """
    places = {e["name"]: e.get("place", "output") for e in d.get("effects") or []}
    named = [c["name"] for c in d.get("causes") or [] if places.get(c["name"]) == "output"]
    gain = (d.get("parameters") or {}).get("gain") or {}
    unit, w_unit = str(gain.get("unit", "")), str((d.get("units") or {}).get("w", ""))
    own = unit.split("/", 1)[1] if "/" in unit else ""
    if not named or not own or not w_unit or own == w_unit or not isinstance(gain.get("value"), int | float):
        return []
    return [
        "",
        f"{', '.join(named)} act{'s' if len(named) == 1 else ''} on the simulation's output before the readout "
        f"(w = gain·y + offset): {'its' if len(named) == 1 else 'their'} parameters are in the simulation's unit, "
        f"{own}; × the gain ({_num(gain['value'], 4)} {unit}) gives w's, {w_unit}.",
    ]


def _cell(text) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def _verdict(d: dict) -> str:
    base, ext = d["baseline"], d["extended"]
    head = f"**{d['verdict']}**"
    if not d["causes"]:
        return (
            f"{head}\n\nNo effect passed every test (material, held-out gain ≥ {_num(d['settings']['min_gain'])}, "
            f"ΔBIC ≤ −{_num(d['settings']['min_bic_drop'])}, a residual no more correlated); the baseline "
            f"simulation stands, with held-out NMSE {format_nmse(base['nmse'])} and Fitting {_pct(base['fitting'])}."
        )
    names = " + ".join(c["name"] for c in d["causes"])
    return (
        f"{head}\n\nAdding {names} to the simulation lowers the held-out NMSE from "
        f"{format_nmse(base['nmse'])} to {format_nmse(ext['nmse'])} (gain {d['gain']:.2f}×) and raises Fitting from "
        f"{_pct(base['fitting'])} to {_pct(ext['fitting'])}."
    )


#: How report.md names each place an effect acts.
PLACE_WORDS = {"drive": "on the drive", "inside": "inside the dynamics", "output": "on the output"}


def _places(places: dict) -> str:
    """One line: where the search looked, and where it did not, with why."""
    parts = []
    for place, entry in places.items():
        where = PLACE_WORDS.get(place, place)
        if entry["effects"]:
            parts.append(f"{where}: {', '.join(entry['effects'])}")
        else:
            parts.append(f"{where}: none ({entry['not_searched']})")
    return "Searched " + "; ".join(parts) + "."


#: The head of each step's table of candidates in report.md (`_candidate_row`).
_CANDIDATE_HEADER = (
    "| effect | held-out NMSE | gain | ΔBIC | Ljung–Box Q | size | eligible | reasons against |",
    "|---|---|---|---|---|---|---|---|",
)


def _candidate_row(c: dict, named: str | None) -> str:
    """One candidate's row of a step's table in report.md (`named`: the step's cause, in bold)."""
    mark = f"**{c['name']}**" if c["name"] == named else c["name"]
    return (
        f"| {mark} | {format_nmse(c['heldout_nmse'])} | {_num(c['gain'])} | {_fixed(c['criterion']['delta_bic'])} | "
        f"{_fixed(c['ljung_box']['Q'])} | {_cell(c.get('materiality', ''))} | {_num(bool(c['eligible']))} | "
        f"{_cell('; '.join([r for r in c['reasons'] if r] + _short_fit(c)))} |"
    )


def _short_fit(c: dict) -> list[str]:
    """A candidate whose effect left the race after its first steps: said in its row's reasons."""
    return [] if c.get("raced", True) else ["fitted only the race's first steps (it trailed the leaders)"]


def stepwise_section(d: dict) -> list[str]:
    """The causes in the order found, each with its incremental gain and its parameters."""
    lines = [
        "## Causes, step by step",
        "",
        "Each step fits every remaining effect on top of the model before it and names one only if it passes "
        "every test against that model (incremental held-out gain, ΔBIC, materiality, whiteness, the "
        "as-good-fits guard); the search stops at the first step that names nothing. Then each cause is "
        "weighed as if it were named last (the final model against itself refitted without it), and one "
        "that fails is dropped.",
        "",
        "| step | cause | where | incremental gain | ΔBIC | size | parameters |",
        "|---|---|---|---|---|---|---|",
    ]
    for i, c in enumerate(d["causes"], 1):
        size = _sizes(c)
        params = ", ".join(f"{k} = {plus_minus(v)}" for k, v in c["parameters"].items())
        where = PLACE_WORDS.get(c.get("place") or "", "")
        lines.append(
            f"| {c.get('step', i)} | {c['name']} | {where} | {_num(c['incremental_gain'])} | {_fixed(c['delta_bic'])} | "
            f"{_cell(size)} | {_cell(params)} |"
        )
    readings = [f"{c['name']}: {c['reading']}" for c in d["causes"] if c.get("reading")]
    if readings:
        lines += ["", f"**What it means.** {'; '.join(readings)}."]
    for c in d["causes"]:
        if c.get("named_jointly_with"):
            lines += [
                "",
                f"**Named together.** {c['name']} was {c['joint']}. Step 1 named nothing alone, or a cause "
                f"gaining less than {JOINT_BELOW:g}×, so its leading candidates were also fitted in pairs: two effects can "
                f"spoil each other's lone fit. The incremental gain and ΔBIC of {c['name']} are over "
                f"{c['named_jointly_with']} alone; step 2 confirmed {c['named_jointly_with']}.",
            ]
    for gone in d.get("dropped") or []:
        lines += [
            "",
            f"**Dropped.** {gone['name']}, named at step {gone['step']}: weighed as if named last, "
            + (
                f"beside {', '.join(gone['beside'])}"
                if gone.get("beside")
                else "against the effect-free baseline"
            )
            + f", it gains {_num(gone['gain'])}× held out ({'; '.join(gone['reasons'])}).",
        ]
    return lines + [""]


def noise_section(d: dict) -> list[str]:
    """The noise floor and, when the final model stays above it, where the rest lives."""
    floor, left = d["noise_floor"], d["unexplained"]
    source = floor.get("source") or floor["method"]
    lines = [
        "## Noise floor and what remains",
        "",
        f"Measurement noise of w, from the recording alone: σ = {_num(floor['std'])} "
        f"{d['units']['w']} "
        f"(variance {_num(floor['variance'])} ± {_num(floor['std_error'])}), "
        f"{format_nmse(floor['fraction_of_variance'])} of var(w). A perfect model leaves this much held out. "
        f"Estimated from {source}.",
        "",
    ]
    for warning in floor.get("warnings") or ():
        lines += [f"**Warning:** {warning}.", ""]
    if left is not None and left.get("floor_warning"):
        lines += [f"**Warning:** {left['floor_warning']}.", ""]
    if left is None:
        return lines + [
            "The final model's held-out error is within "
            f"{_num(d['settings']['unexplained_ratio'])}× the floor's upper bound (its estimate + 2 standard "
            "errors): nothing is left unexplained.",
            "",
        ]
    desc = left["description"]
    lines += [
        f"**Unexplained:** the final model's held-out MSE is {_num(left['ratio_to_floor'])}× the floor; "
        f"{_share(left['fraction_above_floor'])} of it lies above the noise "
        f"({format_nmse(left['excess_nmse'])} of var(w)). {desc.get('summary', '')}",
        "",
    ]
    if left.get("underdetermined"):
        lines += [f"Note: {left['underdetermined']}.", ""]
    static, filters = desc.get("static", {}), desc.get("linear_filter", {})
    recovered = {
        "map of the drive level": static.get("drive"),
        "monotone map of the model's output": static.get("output_monotone"),
        "free map of the model's output": static.get("output_free"),
        "map of the drive's rate": desc.get("rate"),
        "map of the drive level before the dynamics": desc.get("drive_map"),
        "trend in time": desc.get("time"),
        "linear filter of the drive": filters.get("drive"),
        "linear filter of the model's output": filters.get("output"),
        "linear filter of the output's square": filters.get("output_square"),
        "linear filter of the output's cube": filters.get("output_cube"),
        f"sinusoid at {_num((desc.get('periodic') or {}).get('frequency_hz'))} Hz": desc.get("periodic"),
    }
    recovered = {k: v for k, v in recovered.items() if isinstance(v, dict) and "fraction" in v}
    if recovered:
        lines += [
            "What each extension, fitted to the residual on the training part, recovers held out:",
            "",
            "| extension | share of the held-out MSE | share of the error above the floor |",
            "|---|---|---|",
        ]
        lines += [
            f"| {name} | {_share(entry['fraction'])} | {_share(entry.get('of_excess'))} |"
            for name, entry in recovered.items()
        ]
        lines.append("")
    lines += [
        f"![Where the remainder lives]({REMAINDER_FIGURE})",
        "",
        "Left: the residual against the drive level and the static map fitted to it (an even map points to a "
        "response ∝ V², a flat middle to a dead zone, bent ends to saturation). Right: the linear filter "
        "fitted to the residual (a dynamic remainder).",
        "",
    ]
    return lines


def short_name(name: str) -> str:
    """A recording's name without the folders of its file: ``/lab/run.csv (u -> y/µm)`` → ``run.csv (u -> y/µm)``.

    Only the part before a mapping's `` (`` is a path: a column named ``Displacement/µm`` keeps its slash.
    """
    path, sep, rest = name.partition(" (")
    return Path(path).name + sep + rest if ("/" in path or "\\" in path) else name


def _markdown(d: dict, figures: dict[str, Path], loop_levels: int | None = None) -> str:
    """The report page from ``report.json``'s content; `loop_levels`: drive levels seen both ways."""
    names = ", ".join(d["recordings"])
    short = ", ".join(short_name(n) for n in d["recordings"])
    ev = d["evidence"]
    lines = [
        f"# Diagnosis of {short} — {datetime.date.today().isoformat()}",
        "",
        _verdict(d),
        "",
        *[line for warning in d.get("warnings") or () for line in (f"**Warning:** {warning}.", "")],
        "| model | held-out NMSE (MSE / var w) | NMSE, Eq 18 | Fitting |",
        "|---|---|---|---|",
    ]
    causes = " + ".join(c["name"] for c in d["causes"])
    extended_label = "extended (no cause named: the baseline)" if not causes else f"extended (+ {causes})"
    for key, label in (("baseline", "baseline (simulation)"), ("extended", extended_label)):
        m = d[key]
        lines.append(
            f"| {label} | {format_nmse(m['nmse'])} | {format_nmse(m.get('nmse_eq18'))} | {_pct(m['fitting'])} |"
        )
    lines += ["", f"Gain (baseline NMSE / extended NMSE): **{d['gain']:.3g}**.", ""]
    if d["causes"]:
        lines += stepwise_section(d)
    for entry in d.get("ambiguous") or []:
        label = "Open" if entry.get("open") else "Ambiguous"
        lines += [f"**{label}.** {ambiguity_sentence(entry)}", ""]
    for entry in d.get("too_small") or []:
        lines += [f"**Too small to count.** {too_small_sentence(entry)}.", ""]
    start = ev.get("start") or {}
    if start.get("sentence"):
        lines += [f"**Start.** {start['sentence'][0].upper()}{start['sentence'][1:]}.", ""]
    refined = ev.get("refined") or {}
    if refined.get("sentence"):
        lines += [f"**Refined.** {refined['sentence'][0].upper()}{refined['sentence'][1:]}.", ""]
    lines += noise_section(d)

    lines += [
        "## Fitted parameters" + ("" if not causes else f" (simulation + {causes})"),
        "",
        "Standard errors: Gauss–Newton covariance on the training part, inflated for the held-out "
        "residual's autocorrelation. The simulation's parameters trade off against each other, and an effect "
        "that trades off with them inherits their spread; in brackets, the error with the simulation's "
        "parameters held at their fitted values (a lower bound).",
        "",
        "| parameter | value ± std. error |",
        "|---|---|",
    ]
    lines += parameter_rows(d)
    lines += _output_unit_note(d)
    derived = [c for c in d.get("causes") or [] if c["derived"]]
    if derived:  # each cause's, in the final model (its parameters above)
        lines += ["", f"Derived quantities of the effect{'s' if len(derived) > 1 else ''} (final model):", ""]
        lines += [f"- {c['name']}: {_sizes(c)}" for c in derived]
    lines.append("")

    lines += [
        "## Candidates",
        "",
        "Each effect fitted jointly with the simulation; a cause needs all of: material, held-out gain ≥ "
        f"{_num(d['settings']['min_gain'])}, ΔBIC ≤ −{_num(d['settings']['min_bic_drop'])} (training part), "
        "and a held-out residual no more correlated than the baseline's (Ljung–Box Q, rescaled by the squared "
        "ratio of the residual variances, no higher than the baseline's, or below the 99 % white limit). "
        "The baseline is the effect-free fit with the least validation loss, refitted from every candidate's "
        "end point too, so a candidate's gain is its effect's, not a better local minimum's; a gain must also "
        "hold against every effect-free fit as good on training (below).",
        "",
    ]
    if d.get("places"):
        lines += [_places(d["places"]), ""]
    spread = ev.get("equally_good_effect_free_fits")
    if spread and spread.get("n"):
        lines += [
            f"Effect-free fits as good as the baseline on training data (within ΔBIC "
            f"{_num(d['settings']['min_bic_drop'])}): {spread['n']}, held-out NMSE "
            f"{format_nmse(spread['heldout_nmse_min'])} to {format_nmse(spread['heldout_nmse_max'])}. A wide range means "
            "the training part does not pin the simulation's slow dynamics; a candidate must also beat the best "
            "of them by the minimum gain.",
            "",
        ]
    lines += [
        *_CANDIDATE_HEADER,
        f"| *baseline* | {format_nmse(d['baseline']['nmse'])} | 1 | 0 | "
        f"{_fixed(d['baseline_fit']['ljung_box']['Q'])} | | | |",
    ]
    lines += [_candidate_row(c, d["cause"]) for c in d["candidates"]] + [""]
    for k, step in enumerate(d.get("steps") or (), 2):  # each later step: why its candidates were refused
        named = step["cause"]
        lines += [
            f"Step {k}, on top of {step['extends']}: "
            + (f"named **{named}**." if named else "named nothing.")
            + " Gains and ΔBIC are over that model.",
            "",
            *_CANDIDATE_HEADER,
            *[_candidate_row(c, named) for c in step["candidates"]],
            "",
        ]

    lines += [
        "## Residual tests (held-out part)",
        "",
        f"{ev['n_heldout']} samples at {_num(ev['rate_hz'])} Hz; 99 % bound on a correlation "
        f"±{ev['bound_99']:.4f}; ACF over lags 1–{MAX_LAG}, CCF over lags −{MAX_LAG}–{MAX_LAG} (the band "
        "assumes a white drive); independent of the drive: χ² of the residual against the drive before it, "
        "both prewhitened (n/a: too few held-out samples, or a drive its own AR model predicts, such as a sine).",
        "",
        "| model | Ljung–Box Q (lags) | p | ACF lags outside | CCF lags outside | independent of the drive: "
        f"χ² (lags), p | loop separation ({d['units']['w']}) |",
        "|---|---|---|---|---|---|---|",
    ]
    for key in ("baseline", "extended"):
        e = ev[key]
        lb = e["ljung_box"]
        drive = e.get("drive_independence")
        independence = (
            f"{_fixed(drive['statistic'])} ({drive['lags']}), {_num(drive['p_value'], 2)}" if drive else "n/a"
        )
        lines.append(
            f"| {key} | {_fixed(lb['Q'])} ({lb['lags']}) | {_num(lb['p_value'], 2)} | "
            f"{e['acf_outside_bound']} / {MAX_LAG} | {e['ccf_outside_bound']} / {2 * MAX_LAG + 1} | "
            f"{independence} | {'n/a' if loop_levels == 0 else _num(e['loop_separation'])} |"
        )
    if loop_levels == 0:
        lines += [
            "",
            "Loop separation n/a: no drive level of the held-out part is visited both rising and falling "
            "(a two-level drive such as PRBS), so hysteresis cannot show as open loops here.",
        ]
    lines.append("")

    if d.get("hybrid"):
        h = d["hybrid"]
        lines += [
            "## Hybrid model (simulation + D-MLP)",
            "",
            "| hybrid model | held-out NMSE | Fitting |",
            "|---|---|---|",
            f"| without the effect | {format_nmse(h['baseline']['nmse'])} | {_pct(h['baseline']['fitting'])} |",
            f"| with {'the effect (none named)' if d['cause'] == 'none' else d['cause']} | {format_nmse(h['extended']['nmse'])} | {_pct(h['extended']['fitting'])} |",
            "",
            f"Gain: {_num(h['gain'])}."
            + (" (No cause named: the same fit twice.)" if d["cause"] == "none" else ""),
            "",
        ]

    captions = {
        "residual_time.png": (
            "Held-out prediction and residual over time",
            "Look for structure left in the residual: a slow trend (drift), ringing after "
            "steps (resonance) or a lag at each edge (delay); white noise is the goal.",
        ),
        "loops.png": (
            "Residual against drive level, rising and falling",
            "Rising and falling means that separate (an open loop) point to hysteresis; ends that bend "
            "away from zero at large |v_in| point to saturation.",
        ),
        "spectrum.png": (
            "Residual spectrum",
            "A peak standing above a flat floor points to an unmodelled resonance at that frequency; "
            "excess power at low frequency points to slow effects (drift, back-relaxation).",
        ),
        "correlation.png": (
            "Residual autocorrelation and residual–drive cross-correlation",
            "Bars outside the dashed 99 % bounds mean the model left dynamics out; a CCF peak at "
            "a positive lag points to a delay, one at small lags to a wrong dynamic response.",
        ),
        "segments.png": (
            "Error by segment",
            "A trend across segments (error growing or shrinking over time) points to drift; "
            "flat bars mean the error is stationary.",
        ),
    }
    lines += ["## Figures", ""]
    for name in figures:
        title, look = captions[name]
        lines += [f"![{title}]({name})", "", look, ""]

    s = d["settings"]
    lines += [
        "## Settings",
        "",
        f"- split: {d['split']} (fractions {', '.join(_num(x) for x in s['split'])})",
    ]
    for key, value in s.items():
        if key == "split":
            continue
        if isinstance(value, dict):
            value = ", ".join(f"{k} {_num(v)}" for k, v in value.items())
        elif isinstance(value, list):
            value = ", ".join(str(v) for v in value) or "—"
        else:
            value = _num(value)
        lines.append(f"- {key.replace('_', ' ')}: {value}")
    lines += [f"- recordings: {names}", f"- time: {d['seconds']:.1f} s", ""]
    return "\n".join(lines)


# --------------------------------------------------------------------------- #
# Entry point
# --------------------------------------------------------------------------- #

#: What is left above the noise floor (a note that nothing is, when nothing is).
REMAINDER_FIGURE = "remainder.png"


def _remainder_figure(diagnosis, path: Path) -> None:
    from ._remainder import plot_remainder

    if diagnosis.unexplained is not None and "reason" not in diagnosis.unexplained["description"]:
        plot_remainder(diagnosis.unexplained["description"], path, diagnosis.signal_units)
        return
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 1.6))
    ax.axis("off")
    ax.text(
        0.5,
        0.5,
        "Nothing above the noise floor to describe:\nthe final model reaches the measurement noise.",
        ha="center",
        va="center",
    )
    save_figure(fig, path, plt)


#: The models `write_report` saves beside the report (each with its ``.json``; `hybrid.load_model` reads them).
MODEL_FILES = ("baseline.eqx", "extended.eqx")


def save_models(diagnosis, out_dir: Path) -> dict[str, Path]:
    """Save the diagnosis's models as loadable models (``hybrid.load_model``).

    The baseline, the extended model and, for each ambiguous step, its named
    cause's and rivals' (``step<k>_<effect>``), which `hybrid design` reads.

    A plug-in effect's module must be imported before loading (``--effects`` does it).
    """
    from ..core._serialise import save_model

    out = {}
    causes = [c["name"] for c in diagnosis.causes]
    for key, model in diagnosis.models.items():
        path = out_dir / f"{key}.eqx"
        effects = causes if key == "extended" else []
        if key.startswith("step"):  # a side of an ambiguity (`Diagnosis.ambiguous`): its own effects
            effects = [e.name for e in model.simulation.effects if e.name != "frame_timing"]
        save_model(path, model, extra={"saved_by": "hybrid diagnose", "causes": effects})
        out[path.name] = path
    return out


def write_report(diagnosis, out_dir) -> dict[str, Path]:
    """Write ``report.json``, the figures and ``report.md`` of `diagnosis` into `out_dir`.

    **Returns:** ``{"report.json": path, "report.md": path, "<figure>.png": path, ...}``.
    """
    from ..util._errors import InputError
    from ._diagnosis import Diagnosis

    if not isinstance(diagnosis, Diagnosis):
        raise InputError(
            f"write_report needs the Diagnosis that hybrid.diagnose returns, got {type(diagnosis).__name__}"
        )
    if not isinstance(out_dir, (str, os.PathLike)) or not str(out_dir).strip():
        raise InputError(f"write_report needs a folder path (str or pathlib.Path), got {out_dir!r}")
    out_dir = Path(out_dir)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise InputError(
            f"cannot create the report folder {out_dir} ({error.strerror or error}): "
            "give a folder you can write to"
        ) from None
    data = jsonable(diagnosis.to_dict())
    paths = {"report.json": out_dir / "report.json"}
    _write_atomic(paths["report.json"], json.dumps(data, indent=2, allow_nan=False) + "\n")
    paths.update(write_figures(diagnosis, data, out_dir))
    paths[REMAINDER_FIGURE] = out_dir / REMAINDER_FIGURE
    _remainder_figure(diagnosis, paths[REMAINDER_FIGURE])
    paths.update(save_models(diagnosis, out_dir))
    paths["report.md"] = out_dir / "report.md"
    held = diagnosis.heldout
    loop_levels = count_loop_levels(rt.loops(np.asarray(held.w) - np.asarray(held.baseline), held.v_in))
    _write_atomic(paths["report.md"], _markdown(data, {n: paths[n] for n in FIGURES}, loop_levels))
    return paths
