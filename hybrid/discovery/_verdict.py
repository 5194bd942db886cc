"""The one sentence that leads report.md: the causes, how much they explain, what remains above the noise.

"How much they explain" is measured against what there was to explain: the
baseline's held-out MSE above the noise floor. Saying that back-relaxation and
saturation "explain 93 % of the error" means the final model's held-out MSE is
7 % of the way from the noise floor back to the baseline's.
"""

from __future__ import annotations

import math

from ..core._result import outside_plausible

#: Held-out error over the noise floor up to which the verdict calls the model as good as the data allow.
AT_FLOOR = 1.2
#: The p-value of the held-out residual's independence of the drive (`residual_tests.drive_independence`)
#: below which a remainder is said to follow the drive: one under the unexplained ratio (here), and an
#: unexplained one no map describes (`hybrid.discovery._remainder`).
FOLLOWS_DRIVE_P = 1e-3
#: The noise floor's share of w's variance from which an all-clear says how large an effect the noise can hide.
NOISY_SHARE = 0.1
#: The baseline's held-out NMSE (MSE / var w) from which, with the rest at the floor, w is said not to follow
#: the drive: the simulation explains under a fifth of w, and the rest reads as noise.
LITTLE_EXPLAINED = 0.8


def _names(causes: list[dict]) -> str:
    names = [c["name"] for c in causes]  # as report.json and --effects spell them
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def explained_fraction(baseline_mse: float, final_mse: float, floor: float) -> float:
    """Share of the baseline's held-out error above the floor that the final model removes, in [0, 1]."""
    excess = baseline_mse - floor
    if excess <= 0:
        return 1.0
    return min(1.0, max(0.0, (baseline_mse - final_mse) / excess))


def verdict(diagnosis) -> str:
    """One sentence stating the causes, the share of the error they explain, and what remains.

    Where the final model's simulation was fitted outside its plausible range, the sentence says so:
    the names rest on it. A new user's `lti:2` with an additive wander of a 45 s period read
    "resonance and stiffness explain 90 %" while the plant's own mode had taken the wander (ζ 2.4e-6)
    and the resonance the plant's mode; the warning stood lower down.
    """
    head = _headline(diagnosis)
    if diagnosis.dropped and not diagnosis.causes:  # every cause the search named was dropped
        head = head.rstrip(".") + "; " + "; ".join(dropped_clause(d) for d in diagnosis.dropped) + "."
    outside = implausible_values(diagnosis)
    if not outside:
        return head
    took = (
        "a named cause may be standing in for what the simulation should do, and the simulation for a cause"
        if diagnosis.causes
        else "it may have taken up what a missing effect does"
    )
    return (
        f"{head.rstrip('.')}; but the simulation was fitted outside its plausible range ({', '.join(outside)}; "
        f"see the warnings): {took}."
    )


def dropped_clause(dropped: dict) -> str:
    """Why a named cause was dropped (`hybrid.discovery._redundant`): the rules it failed, and against what.

    A probe's hysteresis, dropped as immaterial, read "beside back_relaxation it gains only 13.25× held
    out": the gain was not the reason.
    """
    beside = dropped.get("beside")
    against = (
        f"beside {_names([{'name': n} for n in beside])}" if beside else "against the effect-free baseline"
    )
    why = "; ".join(dropped.get("reasons") or ()) or f"held-out gain {dropped['gain']:.2f}"
    return (
        f"{dropped['name']}, named at step {dropped['step']}, was dropped: weighed as if named last, "
        f"{against}, {why}"
    )


def implausible_values(diagnosis) -> list[str]:
    """``name = value`` of each free simulation parameter of the final model outside its plausible range."""
    model = (getattr(diagnosis, "models", None) or {}).get("extended")
    simulation = getattr(model, "simulation", None)
    if simulation is None:
        return []
    outside = outside_plausible(simulation, set(diagnosis.settings.frozen_for(simulation)))
    return [f"{name} = {value:.3g}" for name, value in outside.items()]


def _headline(diagnosis) -> str:
    causes = diagnosis.causes
    var_w = float(diagnosis.heldout.w.var()) if len(diagnosis.heldout.w) else float("nan")
    base_mse = diagnosis.baseline.heldout.nmse * var_w
    final_mse = diagnosis.extended.heldout.nmse * var_w
    floor = diagnosis.noise_floor.variance if diagnosis.noise_floor is not None else 0.0
    ratio = final_mse / floor if floor > 0 else float("nan")  # the final model's held-out MSE over the floor
    left = diagnosis.unexplained
    question = open_question(diagnosis.ambiguous, also=bool(causes))
    follows = follows_drive(diagnosis) if left is None else ""
    where = ""
    if left is not None:
        summary = left.get("description", {}).get("summary", "")
        where = f": {summary}" if summary else ""
        if left.get("underdetermined"):
            where += f" ({left['underdetermined']})"
    unheard = _noise_hides(diagnosis, base_mse, var_w, floor) if left is None and not ratio > AT_FLOOR else ""
    if causes:
        share = explained_fraction(base_mse, final_mse, floor)
        head = (
            f"{_names(causes)} {'explains' if len(causes) == 1 else 'explain'} {share:.0%} of the simulation's "
            f"held-out error above the noise floor (gain {diagnosis.gain:.2g}×)"
        )
        for d in diagnosis.dropped:
            head += f" ({dropped_clause(d)})"
        if left is None and question:
            return head + f"; what remains is {ratio:.2g}× the measurement noise floor, {question}." + follows
        if left is None:
            if not ratio > AT_FLOOR:
                if follows:
                    return (
                        head
                        + f"; what remains is {ratio:.2g}× the measurement noise floor in size."
                        + follows
                    )
                return head + "; what remains is measurement noise." + unheard
            return (
                head
                + (
                    f"; what remains is {_beside(ratio, diagnosis.settings.unexplained_ratio)}× the measurement "
                    f"noise floor, {_under(ratio, diagnosis.settings.unexplained_ratio)} above which it is called "
                    "unexplained: a perfect "
                    "model would reach 1×, and an effect too small for the rules on this recording, or one outside "
                    "the library, may still take it nearer."
                )
                + follows
            )
        return head + f"; {left['fraction_above_floor']:.0%} of what remains lies above the noise{where}."
    if left is None and not question and not follows and base_mse >= LITTLE_EXPLAINED * var_w:
        explains = max(0.0, 1.0 - base_mse / var_w)
        return (
            f"Nothing can be named from this recording: w barely follows the drive. The simulation explains "
            f"{explains:.0%} of w's held-out variance, and what it leaves is {ratio:.2g}× the measurement noise "
            f"floor, which is {floor / var_w:.0%} of w's variance: check that the output is the response to "
            "this drive (the sensor, its wiring, the column mapped), or drive it harder."
        )
    if left is None and question:
        return (
            f"No effect passes the search's rules: the simulation's held-out error is {ratio:.2g}× the "
            f"measurement noise floor, {question}."
        ) + follows
    if left is None:
        if follows and not ratio > AT_FLOOR:
            return (
                f"No effect of the library is needed by the search's rules: the simulation's held-out error is "
                f"{ratio:.2g}× the measurement noise floor in size." + follows
            )
        if not ratio > AT_FLOOR:
            return (
                f"No effect is needed: the simulation's held-out error is {ratio:.2g}× the measurement noise "
                "floor, as good as the data allow." + unheard
            )
        limit = diagnosis.settings.unexplained_ratio
        return (
            f"No effect of the library is needed by the search's rules: the simulation's held-out error is "
            f"{ratio:.2g}× the measurement noise floor, {_under(ratio, limit)} above which the rest is called "
            "unexplained; a perfect model would reach 1×, and an effect outside the library may still take "
            "it nearer."
        ) + follows
    best = _best_refused(diagnosis)
    small = diagnosis.too_small
    if small and (best is None or small[0]["gain"] >= best.gain):
        return (
            f"No effect in the library passes the search's rules on this recording ({too_small_sentence(small[0])}): "
            f"{left['fraction_above_floor']:.0%} of the simulation's held-out error lies above the noise floor{where}."
        )
    if best is None:
        return (
            f"No effect in the library explains what the simulation misses: {left['fraction_above_floor']:.0%} "
            f"of its held-out error lies above the noise floor{where}."
        )
    return (
        f"No effect in the library passes the search's rules on this recording (the closest, {best.name}, "
        f"{refusal(best, diagnosis.settings.min_gain)}): "
        f"{left['fraction_above_floor']:.0%} of the simulation's held-out error lies above the noise floor{where}."
    )


def _noise_hides(diagnosis, base_mse: float, var_w: float, floor: float) -> str:
    """The sentence an all-clear gets where the noise is `NOISY_SHARE` of w's variance or more, or ''.

    A named cause must gain `min_gain` held out, and an exact model leaves the floor: an effect that adds
    e to the held-out MSE can gain at most 1 + e/floor, so one with e < (min_gain − 1)·floor cannot be
    named however well it is modelled. On a clean record that is a tiny effect; where the noise is as
    large as the response, a probe's saturation with a 67 % shortfall (ΔBIC −66 on training, 1.04×
    held out) read "No effect is needed … as good as the data allow", and nothing said it could hide.
    """
    share = floor / var_w if var_w > 0 else 0.0
    if not share >= NOISY_SHARE:
        return ""
    min_gain = diagnosis.settings.min_gain
    hidden = math.sqrt((min_gain - 1.0) * floor / var_w)
    best = _best_refused(diagnosis)
    fits = (
        f" ({best.name} fits the training part better, ΔBIC {f'{best.delta_bic:.0f}'.replace('-', '−')}, and gains {best.gain:.2f}× held "
        "out)"
        if best is not None and best.delta_bic <= -diagnosis.settings.min_bic_drop
        else ""
    )
    return (
        f" But the noise is {share:.0%} of w's variance: an effect whose error is under {min_gain - 1.0:.2g}× the "
        f"noise's variance (an rms under {hidden:.0%} of w's) cannot gain the {min_gain:g}× a cause needs here, "
        f"however well it is modelled, so one that size may be missing unseen{fits}; a quieter recording, or a "
        "larger drive where the effect grows with it, would tell."
    )


def _beside(ratio: float, limit: float) -> str:
    """`ratio` to two significant digits, or more where those would put it on the other side of `limit`
    (or on it): a probe's 1.996 read "2× the … floor, under the 2×"."""
    for digits in range(2, 7):
        text = f"{ratio:.{digits}g}"
        if (float(text) < limit) == (ratio < limit) and float(text) != limit:
            return text
    return text


def _under(ratio: float, limit: float) -> str:
    """ "under the 2×", or where the ratio to the floor's estimate is above it, the floor's bound it is under.

    The remainder is called unexplained above `limit` times the floor counted at the top of its ±2
    standard errors (`hybrid.discovery._unexplained`): an effect-free draw at 2.1× the estimate read
    "2.1× the measurement noise floor, under the 2× above which …", and "under the 2× of the floor's
    upper bound" beside a 2.7× read to a probe as "2.7× is under 2×".
    """
    if not ratio > limit:
        return f"under the {limit:.2g}×"
    return f"yet under {limit:.2g}× the floor's upper bound (its estimate + 2 standard errors),"


def follows_drive(diagnosis) -> str:
    """The sentence a remainder under the unexplained ratio gets when it still follows the drive, or ''.

    A held-out error near the noise floor in size is not yet noise: a missing
    part of the response that the drive causes, smaller than the noise, leaves
    the residual correlated with the drive that came before it, which noise
    does not (`residual_tests.drive_independence`, p < `FOLLOWS_DRIVE_P`; its
    numbers are report.json's ``evidence.extended.drive_independence``).
    """
    test = (diagnosis.evidence.get("extended") or {}).get("drive_independence")
    if not test or not test["p_value"] < FOLLOWS_DRIVE_P:
        return ""
    # a parameter the fit left short of its training optimum leaves such a part by itself (a plug-in
    # pendulum's frame lag kept at its start: at the optimum, the same test found no dependence)
    short = {
        name: abs(u.to_optimum) / u.std_error
        for name, u in (getattr(diagnosis, "uncertainties", None) or {}).items()
        if u.held_off_optimum
    }
    where = (
        " The fit stopped short of the training part's optimum in "
        + ", ".join(f"{name} ({z:.1f} standard errors)" for name, z in short.items())
        + ", which alone can leave such a part (report.md's parameters give that optimum)."
        if short
        else ""
    )
    return (
        f" Yet it still follows the drive ({drive_test_words(test)}): part of the response that the drive "
        "causes is left, not noise alone." + where
    )


def drive_test_words(test: dict) -> str:
    """A `residual_tests.drive_independence` result that rejects, as the sentences quote it."""
    return (
        "the held-out residual against the drive before it, both prewhitened: "
        f"χ²({test['lags']}) = {test['statistic']:.0f}, p = {test['p_value']:.1g}"
    )


def open_question(ambiguous: list[dict], also: bool = False) -> str:
    """The clause an open last step (`hybrid.discovery._ambiguity`) puts in an all-clear, or ''.

    `also`: whether causes were named (the effect would be missing *too*).

    A new user's rising staircase with a sensor drifting: the report led with "No effect is needed" and
    said lower down that whether baseline_drift was missing was open.
    """
    entry = next((e for e in ambiguous if e.get("open")), None)
    if entry is None:
        return ""
    names = " or ".join(r["name"] for r in entry["rivals"]) or "an effect"
    return (
        f"yet whether {names} is {'also ' if also else ''}missing is open on this recording: a drive designed "
        "to separate them would tell (hybrid design)"
    )


def too_small_sentence(entry: dict) -> str:
    """A candidate refused for its size alone (`Diagnosis.too_small`), and how to count it.

    "Set", not "lower": a threshold may be a ceiling (a resonance's `max_damping`, which a mode of ζ 0.98
    must raise) as well as a floor; and "such", not "that small": a heavily damped mode is no small one.
    """
    names = " and ".join(f"{k} (now {v:g})" for k, v in entry["thresholds"].items()) or "its threshold"
    return (
        f"{entry['name']} gains {entry['gain']:.3g}× held out and passes every other rule, but falls short of "
        f"what a cause must be ({entry['materiality']}); if such an effect counts here, set {names} to admit "
        "it with --materiality NAME=VALUE"
    )


def refusal(candidate, min_gain: float) -> str:
    """Why the closest candidate was not named: its gain under the rule's, or the rules it failed beside it.

    A candidate that gained more than `min_gain` over the model it extends was refused by another rule
    (an effect-free fit as good on training that does as well held out, the BIC, the residual's
    whiteness): a new user's pendulum read "gains 2.18× held out, under the 1.5× asked".
    """
    if candidate.gain < min_gain:
        return f"gains {candidate.gain:.2f}× held out, under the {min_gain:g}× asked"
    failed = [r for r in candidate.reasons if not r.startswith("held-out gain ")]
    return f"gains {candidate.gain:.2f}× held out, but " + ("; ".join(failed) or "not every rule holds")


def _best_refused(diagnosis):
    """The material candidate of the last step with the largest held-out gain above 1, or None."""
    candidates = diagnosis.steps[-1].candidates if diagnosis.steps else []
    found = [c for c in candidates if c.material and math.isfinite(c.gain) and c.gain > 1.0]
    return max(found, key=lambda c: c.gain) if found else None
