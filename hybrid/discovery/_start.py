"""Whether each recording starts where the simulation does: a misfit at the start that the rest lacks.

A simulation starts from its own initial state (at rest, or in equilibrium
with the first drive value); a lab's record often starts with the plant
already moving (water in the tanks from the last run, a strip still relaxing).
The model then misses the record's first samples by an offset of one sign that
dies away with the plant's slowest time constant, and every fit bends the
physics to cut it. No effect on the drive, the output or inside the dynamics
explains that: the initial state does (`hybrid.HeldStart`, ``--settle N``).

`start_misfit` reads the final model's residual over each whole recording
(training, validation and held-out samples alike; `hybrid fit` gives
`misfit_at_start` its fitted physics model's free run): on its first
``START_SHARE`` of samples (at least ``MIN_START``) against the rest, and
against its last as many samples. The start is off when its RMS is at least
``RATIO`` times both and the misfit has one sign there (|mean| ≥ ``ONE_SIGN``
× RMS) or dies away (`dies_away`: an underdamped plant's free oscillation
changes sign while its size falls): a misfit of the start alone. Not noise,
not an effect that swings with the drive, and not a wander or trend that misses
the record's end as much as its start. What it cannot tell from a wrong initial state is a change early in
the record that then settles (a gain drift that the search did not name can
miss the first samples, one-signed, and hardly the last). So the sentence
names both, and the run that tells them apart: the simulation held at a fitted
drive first (``--settle N``); a start that then fits was the initial state.

`diagnose` runs that itself (`DiagnoseSettings.settle_when_off`): one
recording whose start is off is diagnosed again held at a fitted drive for
`settle_samples` samples, and `settled_try` says which diagnosis is kept.
A named cause can meet a start that the effect-free model misses, standing in
for the initial state (a lag, with `lti:N` from rest, on a record that started
settled at its first drive); the held start is then tried too, and
`covered_try` says which is kept.

On Cascaded Tanks with `TwoTank` (started in equilibrium with the first pump
voltage, while the record's output starts at 5.2 V): its first 20 samples
are missed by 3.2× the rest's RMS and 5.1× the last 20's, all one sign, and
nothing is named; held at a fitted drive for 256 samples first, 0.35× the
rest's, and ``limit_h2`` and ``limit_h1`` (spilling into h2) are named.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ..core._held_start import INITIAL_DRIVE
from ._diagnosis import SPLIT_ORDER
from ._search import predictions

#: The held drive `diagnose` tries by itself (`DiagnoseSettings.settle_when_off`): this share of the
#: record's samples, at least MIN_SETTLE. Several of the slowest time constant that a record of that
#: length can pin; a hold too short shows as a start still missed, and the sentence says so.
SETTLE_SHARE = 0.25
MIN_SETTLE = 20
START_SHARE = 0.02  # the start: this share of the recording's samples ...
MIN_START = 10  # ... and at least this many
RATIO = 2.5  # the start's residual RMS over the rest's and over the end's
ONE_SIGN = 0.8  # |mean| / RMS of the start's residual: one sign throughout


def _residuals(problem, theta, active) -> list[np.ndarray]:
    """Each recording's residual w − ŵ at every recorded sample (NaN where no part covers it)."""
    out = [np.full(series.n_recorded, np.nan) for series in problem.series]
    w_hat = predictions(problem, jnp.asarray(active, float), jnp.asarray(theta))  # every split, one run
    for split in SPLIT_ORDER:
        w = problem.recorded(problem.target(split), split)
        r, at = np.asarray(w, float) - np.asarray(problem.recorded(w_hat[split], split), float), 0
        for series, full in zip(problem.series, out):
            for a, b in series.recorded_segments_of(split):
                full[a:b] = r[at : at + b - a]
                at += b - a
    return out


def dies_away(r: np.ndarray, first: int) -> bool:
    """Whether the residual `r`'s RMS falls over its first four windows of `first` samples, window by window,
    and its first window's is ≥ ``RATIO`` times that of the third and fourth together.

    A plant that starts moving and is underdamped is missed by its free oscillation: it changes sign (a
    probe's `lti:2` validation record, ζ 0.3, missed its first 40 samples by 10× the rest's RMS, |mean| 0.53
    RMS, and its windows' RMS fell 0.57, 0.32, 0.19, 0.08), which the one-sign test misses. An effect that
    swings with the drive falls like that only under a drive that does.
    """
    windows = [_rms(r[k * first : (k + 1) * first]) for k in range(4)]
    return bool(
        all(b <= a for a, b in zip(windows, windows[1:]))
        and windows[0] >= RATIO * _rms(r[2 * first : 4 * first])
    )


def start_shape(row: dict) -> str:
    """How the start's misfit looks, for a sentence: all one sign, or dying away (`dies_away`)."""
    return "all one sign" if row["mean_over_rms_first"] >= ONE_SIGN else "dying away"


def _rms(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x**2))) if len(x) else float("nan")


def start_misfit(problem, theta, active, names: list[str], settled: bool) -> dict:
    """`misfit_at_start` of a search problem's model at θ (`active`: its effects' switches)."""
    return misfit_at_start(_residuals(problem, theta, active), names, settled)


def misfit_at_start(residuals, names: list[str], settled: bool) -> dict:
    """Per recording: the residual's RMS on its first samples against the rest and the end; ``off`` if any is.

    `residuals`: each recording's w − ŵ at every sample (NaN where not
    predicted); `names`: the recordings' names; `settled`: the simulation
    already starts from a held drive (`HeldStart`), which the sentence then
    asks to lengthen.
    """
    rows = []
    for r, name in zip(residuals, names):
        r = np.asarray(r, float)
        first = max(MIN_START, int(round(START_SHARE * len(r))))
        head = r[:first]
        if len(r) < 4 * first or not np.all(np.isfinite(head)):
            rows.append({"recording": name, "checked": False})  # too short, or its start not predicted
            continue
        rms_head, rms_rest, rms_end = _rms(head), _rms(r[first:]), _rms(r[-first:])
        ratio = rms_head / rms_rest if rms_rest > 0 else float("inf")
        to_end = rms_head / rms_end if rms_end > 0 else float("inf")
        one_sign = abs(float(np.mean(head))) / rms_head if rms_head > 0 else 0.0
        fades = dies_away(r, first)
        rows.append(
            {
                "recording": name,
                "checked": True,
                "first_samples": first,
                "rms_first": rms_head,
                "rms_rest": rms_rest,
                "rms_last": rms_end,
                "ratio": ratio,
                "ratio_to_last": to_end,
                "mean_over_rms_first": one_sign,
                "dies_away": fades,
                "off": bool(ratio >= RATIO and to_end >= RATIO and (one_sign >= ONE_SIGN or fades)),
            }
        )
    off = [row for row in rows if row.get("off")]
    return {
        "recordings": rows,
        "off": bool(off),
        "rule": f"first {START_SHARE:.0%} of a recording (≥ {MIN_START} samples): residual RMS ≥ {RATIO}× the "
        f"rest's and the last as many samples', one sign (|mean| ≥ {ONE_SIGN} RMS) or dying away (its RMS "
        f"falling over the first four such windows to under 1/{RATIO} of the first's in the third and fourth)",
        "sentence": _sentence(off, settled, len(rows)) if off else None,
    }


def _sentence(off: list[dict], settled: bool, recordings: int) -> str:
    worst = max(off, key=lambda row: row["ratio"])
    which = "" if len(off) == 1 else f" (and {len(off) - 1} more)"
    head = (
        f"the model misses the first {worst['first_samples']} samples of {worst['recording']}{which} by "
        f"{worst['ratio']:.1f}× its RMS on the rest, {start_shape(worst)}: "
    )
    if settled:
        return head + (
            "no drive held before the record brings the simulation to where it starts (the plant was "
            "moving, not settled), or the hold is shorter than the slowest time constant; try a larger "
            "--settle N, or cut the start off (--range)"
        )
    remedy = (
        "--settle N on the command line (N several of its slowest time constant, in samples), "
        "hybrid.HeldStart(simulation, N) in Python"
    )
    if recordings > 1:  # one held drive cannot start several records: each its own, or a later start
        remedy = f"each record alone with {remedy}, or cut the start off (--range)"
    return head + (
        "the record may not start where the simulation does (its own initial state: at rest, or settled "
        "at the first drive), and then the fit bends the physics to meet it, or something changes early in "
        "the record and settles; if the plant was moving before the record, hold the simulation at a fitted "
        f"drive first, which tells the two apart: {remedy}"
    )


def settle_samples(n_samples: int) -> int:
    """How many samples of held drive `diagnose` tries before a record of `n_samples` whose start is off."""
    return max(MIN_SETTLE, int(round(SETTLE_SHARE * n_samples)))


def settled_try(start: dict, settled: dict, n_held: int, cause: str, causes, baseline, extended) -> dict:
    """The start evidence once a held start was tried: the kept run's, with what the other found.

    `start`: the check of the run from the simulation's own start (off);
    `settled`: the same check with the simulation held at a fitted drive for
    `n_held` samples first; `cause`, `causes`, `baseline`, `extended`: what the
    run from the simulation's own start found (its candidates' held-out NMSE).
    """
    before = max((row for row in start["recordings"] if row.get("off")), key=lambda row: row["ratio"])
    after = next(row for row in settled["recordings"] if row["recording"] == before["recording"])
    without = {
        "cause": cause,
        "causes": list(causes),
        "gain": float(baseline.heldout.nmse / extended.heldout.nmse),
        "ratio": before["ratio"],
    }
    tried = {
        "samples": n_held,
        "ratio": after.get("ratio"),
        "off": bool(settled["off"]),
        "kept": not settled["off"],
    }
    named = f"it names {', '.join(causes)} (gain {without['gain']:.2f}×)" if causes else "it names nothing"
    head = (
        f"the model from the simulation's own start missed the first {before['first_samples']} samples of "
        f"{before['recording']} by {before['ratio']:.1f}× its RMS on the rest, {start_shape(before)}"
    )
    if not settled["off"]:
        return {
            **settled,
            "settled": {**tried, "automatically": True, "without": without},
            "sentence": f"{head}; held at a fitted drive for {n_held} samples before the record (as --settle "
            f"{n_held} would; hybrid.HeldStart in Python), it meets the start ({after.get('ratio', float('nan')):.2f}× the rest): "
            "the record most likely did not start where the simulation does (a change early in the record "
            "that settles can be met this way too), and this diagnosis is of the held simulation (from its own "
            f"start {named}; --no-auto-settle diagnoses from there)",
        }
    return {
        **start,
        "settled": {**tried, "automatically": True, "without": without},
        "sentence": f"{start['sentence']}. Held at a fitted drive for {n_held} samples first (tried), the "
        f"model still misses the start by {after.get('ratio', float('nan')):.1f}× the rest: not the initial state, but "
        "something that changes early in the record and settles; this diagnosis is from the simulation's "
        "own start",
    }


#: How closely a held start must meet the record's start before it replaces named causes (`covered_try`):
#: its first samples' residual RMS at most this many times the rest's, well inside `RATIO`.
MET = 1.5
#: How far beyond the drive's range, in spans, a held drive may lie and still be a state the plant was in.
HELD_REACH = 0.5


def covered_try(
    effect_free: dict, start: dict, again, n_held: int, causes, extended, min_gain: float, drive
) -> dict:
    """The start evidence where the causes met a start that the effect-free model missed, once a held start
    was tried.

    `effect_free`: the check of the effect-free model from the simulation's own start (off); `start`:
    the final model's (not off); `again`: the diagnosis of the simulation held at a fitted drive for
    `n_held` samples; `causes`, `extended`: what the run from the simulation's own start named and its
    final candidate. The held diagnosis is kept (``settled.kept``) where it meets the start and the
    causes gain less than `min_gain` over it held out, unless it names them too: they stood in for the
    record's initial state (a lag, with `lti:N` from rest, on a record that starts settled at its first
    drive). It must meet the start clearly (`MET`), and from a held drive within `HELD_REACH` spans of the
    record's `drive`: a drift of the gain under a rising staircase was "met" at 2.47× the rest by `lti:1`
    bent to τ 118 s (truth 0.5 s), held at 9.8 for a drive of 0.2–2. Otherwise the causes stand, and the
    sentence says what the held start found.
    """
    before = max((row for row in effect_free["recordings"] if row.get("off")), key=lambda row: row["ratio"])
    held = again.evidence["start"]
    after = next(row for row in held["recordings"] if row["recording"] == before["recording"])
    gain = float(again.extended.heldout.nmse / extended.heldout.nmse)
    found = [c["name"] for c in again.causes]
    same = sorted(found) == sorted(causes)  # the effect-free model missed the start for want of them
    low, high = float(np.min(drive)), float(np.max(drive))
    level = float(again.extended.parameters.get(INITIAL_DRIVE, float("nan")))
    reach = HELD_REACH * (high - low)
    inside = low - reach <= level <= high + reach  # nan: not inside
    met = not held["off"] and (after.get("ratio") or float("inf")) <= MET
    keep = met and inside and not same and gain < min_gain
    named = ", ".join(causes)
    gains = "gain" if len(causes) > 1 else "gains"
    tried = {
        "samples": n_held,
        "ratio": after.get("ratio"),
        "off": bool(held["off"]),
        "kept": keep,
        "automatically": True,
        "effect_free_ratio": before["ratio"],
        "without": {"causes": list(causes), "gain_over_held": gain},
    }
    head = (
        f"the effect-free model from the simulation's own start missed the first {before['first_samples']} "
        f"samples of {before['recording']} by {before['ratio']:.1f}× its RMS on the rest, {start_shape(before)}, and "
        f"{named} met them"
    )
    hold = f"held at a fitted drive for {n_held} samples before the record (as --settle {n_held} would)"
    if keep:
        names = f"names {', '.join(found)}" if found else "needs no effect"
        return {
            **held,
            "settled": tried,
            "sentence": f"{head}; {hold}, the simulation meets the start ({after.get('ratio', float('nan')):.2f}× "
            f"the rest) and {names}, and {named} {gains} only {gain:.2f}× over that held out (a cause needs "
            f"{min_gain:g}×): {'they' if len(causes) > 1 else 'it'} stood in for the record's initial state "
            "(it did not start where the simulation does), so this diagnosis is of the held simulation "
            "(hybrid.HeldStart in Python; --no-auto-settle diagnoses from the simulation's own start)",
        }
    if same:
        why = f"the simulation names {named} too"
    elif not met:
        why = f"the model still misses the start by {after.get('ratio', float('nan')):.2f}× the rest (needs ≤ {MET:g}×)"
    elif not inside:
        why = f"it meets the start only from a drive of {level:.3g} held, outside the record's {low:.3g} to {high:.3g}"
    else:
        why = f"the simulation meets the start, yet {named} {gains} {gain:.2f}× over that held out"
    return {
        **start,
        "settled": tried,
        "sentence": f"{head}; {hold} (tried), {why}: this diagnosis is from the simulation's own start",
    }
