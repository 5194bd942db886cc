"""When a recording cannot tell two explanations apart: the named cause's rivals, and why.

A step of the search names the eligible effect with the largest held-out gain
(`hybrid.discovery._step`). The effects that also passed every rule of that
step are its rivals. A rival is *indistinguishable* from the named cause on
this recording when either

- **the named cause is not significantly better**: the paired difference of
  squared held-out errors, d_t = e²_rival(t) − e²_named(t), is cut into
  contiguous chunks as long as its decorrelation length (the effective-sample
  factor of d, 1 + 2 Σ ρ_k over its positive lags), and a one-sided sign test
  asks whether the named cause wins (mean d > 0) in more chunks than chance
  would give: indistinguishable when its p-value exceeds `ALPHA`. A sign test
  over decorrelated chunks, not a t-test on the mean: held-out errors of slow
  dynamics are few independent pieces with heavy tails, and there a rival 100×
  worse in nearly every chunk can still lie within two standard errors of the
  mean. Nor does the mean's test, one-sided on its autocorrelation-corrected
  standard error, find the named cause better (p > `ALPHA`): where both
  explain most chunks to the noise and the rival misses a few by much, the
  sign test is a coin toss and the mean is not (a loudspeaker whose amplifier
  clips, tried as a new user would: the drive's saturation at gain 98.5
  against the output's at 48.5, 302 of 600 chunks won, sign test p 0.45); or
- **its predictions are the named cause's to within the noise**: the RMS of
  the difference between the two models' held-out predictions is below the
  measurement noise's standard deviation (`NoiseFloor`). Then no single sample
  tells them apart, and with a model only approximately right, a ranking
  that rests on differences smaller than the noise is a weak reason for the
  name. The tests may still find the named cause significantly better over
  many samples (``named_better``: either one-sided p ≤ `ALPHA`); the rival
  is listed then too, and the sentence says both: the named cause fits
  significantly better, and the two predict alike to within the noise (a
  15-sample delay on a second-order plant, tried as a new user would: gain 30
  against a resonance's 18.7, sign test p 4e-16, predictions 0.06 mm apart
  RMS under the noise; the report said the recording "cannot tell" them).

Both criteria are computed from the held-out (test) part alone, which no fit
saw. A candidate that passed every rule of the step but materiality
(`Candidate.refused_for_size`) and gains *more* held out than the named cause
is a rival too (``"too_small": true``), whatever the tests say: a cause that
a better, smaller fit beats may stand in for it or for an effect outside the
library (a piezo stage's creep under a staircase, tried as a new user would:
`drift` named at 2.39× while `backlash`, 6.07×, was too small to count).
Where the recording shows why the rivals look alike, the report says it:

- the drive's level and time are correlated (|r| ≥ `LEVEL_TIME_R` between
  the drive's running mean, over a tenth of the recording, and time): an
  effect of the level (a saturation, an even response) and one of time (a
  drift) act alike on a staircase that rises as it goes (said too of an open
  last step whose rivals are all effects of the level: a drift would act alike);
- a rival acts at a frequency (a parameter in Hz) where the drive has less
  than `THIN_POWER` of its power (within a factor 1.25 either way).

**An open last step.** When the search's last step names nothing, which
effect, if any, is still missing can be an open question too. Its rivals are
"nothing more" (the model extended so far) and at most `OPEN_RIVALS` of that
step's candidates, by held-out gain (the entry has ``"named": "none"``,
``"open": true``, and ``"evidence"`` saying which of these made it open):

- ``"remainder"``: the final model leaves a remainder above the noise floor
  (``unexplained``); the rivals are the candidates better than nothing more
  on the held-out part (gain at least `HINT_GAIN`) whose held-out predictions
  differ from nothing more's by at least the noise floor (RMS): a different model, not
  nothing more again; and better held out than every effect-free fit as good
  on training (the step's bar): where one of those does as well, the remainder
  is how the model extrapolates (`remainder`'s ``underdetermined``: effect-free
  seed 7 of `experiments/design_loop.py`, 10.5× the floor, every candidate
  0.98× over the bar), which no effect and no designed drive between effects
  answers;
- ``"significant"``: the final model is at the floor, yet a candidate is
  better than nothing more in significantly many decorrelated held-out chunks
  (the sign test above, p ≤ `ALPHA`, the candidate's wins) and by a held-out
  gain of at least `HINT_GAIN` over the best effect-free fit as good on
  training data (the step's bar, so a better fit of the simulation alone, which
  any candidate's lane may find, is not taken for an effect): a second effect
  too small to pass every rule on this recording, the commonest way a pair is
  half named;
- ``"confound"``: the final model is at the floor, the drive's level and time
  are correlated (|r| ≥ `LEVEL_TIME_R`), and a material effect *of time* (a
  drift) passes the step's BIC rule on training data (ΔBIC ≤ −`min_bic_drop`)
  and is better held out than nothing more (gain above 1; not over the step's
  bar, which an effect-free fit with biased parameters sets here): on such a
  drive the simulation's own response to the rising level, its
  parameters biased, absorbs the drift, so the held-out part cannot tell them
  apart while the training part prefers the drift (a heated block under a
  staircase with its sensor's baseline falling 3 K over 60 s, tried as a new
  user would, their data not in the repo: `baseline_drift` ΔBIC −159, held-out
  gain 1.07, the block's resistance fitted 11 % low, and the report said nothing
  was missing; `tests/test_ambiguity.py` makes a like plant with scipy).

A designed drive (`hybrid design`) asks the next recording whether one of
them is there. An effect-free recording that the model explains, and where
no candidate wins significantly, gets no entry and no design. The sign test's
numbers of an open entry count nothing more's wins (``named_wins``,
``p_value``); ``candidate_p_value`` is the candidate's.

`cause` and `causes` keep the best explanation; ``report.json``'s
``ambiguous`` lists each step whose named cause has indistinguishable rivals,
and the open last step.
"""

from __future__ import annotations

import math

import numpy as np

from .residual_tests import effective_sample_factor

#: The tests' level: a rival is indistinguishable when the named cause's wins over decorrelated chunks
#: of the held-out part, and its lower mean squared error, each have a one-sided p-value above it.
ALPHA = 0.05
#: |correlation| of the drive's running mean with time above which level and time are confounded.
LEVEL_TIME_R = 0.5
#: Share of the drive's power near a rival's frequency below which the drive cannot excite it.
THIN_POWER = 0.01
#: An open last step's rivals: at most this many candidates, those with the largest held-out gains above 1.
OPEN_RIVALS = 2
#: Held-out gain over the step's bar (the best effect-free fit as good on training) a candidate needs, with
#: a significant sign test, to open a last step whose remainder is not flagged unexplained; beside a
#: flagged remainder, the held-out gain over nothing more a candidate needs to be a rival.
HINT_GAIN = 1.05

TEST = (
    "a rival (an effect that also passed every rule of the step) is indistinguishable from the named "
    "cause when the named cause's lower squared held-out error wins in no more contiguous chunks (each as "
    f"long as the errors' decorrelation length) than chance would give (one-sided sign test, p > {ALPHA:g}) "
    f"and its mean is not significantly lower (one-sided, on the autocorrelation-corrected standard error, "
    f"p > {ALPHA:g}), or when their held-out predictions differ by less than the noise floor (RMS); a candidate refused for "
    "its size alone that gains more held out than the named cause is a rival too; a last step that named "
    "nothing is open (named 'none') when, beside a remainder above the noise floor, candidates gain "
    f"≥ {HINT_GAIN:g} held out with predictions at least the noise floor apart from nothing more's, or, at the floor, a "
    f"candidate wins significantly many chunks (p ≤ {ALPHA:g}) and gains ≥ {HINT_GAIN:g} held out over every "
    "effect-free fit as good on training, or, where the drive's level and time are correlated "
    f"(|r| ≥ {LEVEL_TIME_R:g}), a material effect of time passes the BIC rule on training and gains above 1 "
    "held out"
)


def paired_difference(named_residual, rival_residual) -> dict:
    """The sign test of e²_rival − e²_named over decorrelated chunks, and the mean with its standard error.

    Returns ``mean`` and ``std_error`` (autocorrelation-corrected) of the
    difference with the one-sided ``mean_p_value`` of a mean that large under
    no difference (normal), the ``chunks`` compared, the named cause's
    ``wins`` and the one-sided ``p_value`` of that many wins or more.
    """
    d = np.asarray(rival_residual, float) ** 2 - np.asarray(named_residual, float) ** 2
    n = d.size
    spread = float(np.var(d, ddof=1)) if n > 1 else 0.0
    factor = effective_sample_factor(d) if spread > 0 else 1.0
    length = max(1, math.ceil(factor))
    k = n // length
    means = d[: k * length].reshape(k, length).mean(axis=1) if k else np.zeros(0)
    decided = means[means != 0]
    wins = int(np.sum(decided > 0))
    mean = float(np.mean(d)) if n else 0.0
    std_error = math.sqrt(spread * factor / n) if n > 1 else float("inf")
    return {
        "mean": mean,
        "std_error": std_error,
        "mean_p_value": _normal_tail(mean / std_error) if std_error > 0 else float(mean <= 0),
        "chunks": int(decided.size),
        "wins": wins,
        "p_value": sign_tail(wins, int(decided.size)),
    }


def _normal_tail(z: float) -> float:
    """P(Z ≥ z) for a standard normal Z: the mean's one-sided p-value."""
    return 0.5 * math.erfc(z / math.sqrt(2.0))


def sign_tail(wins: int, chunks: int) -> float:
    """P(≥ `wins` of `chunks` fair coin tosses): the one-sided sign test's p-value.

    The other side of `paired_difference` needs no second pass: d → −d keeps its
    chunks, so the rival's p-value is ``sign_tail(chunks − wins, chunks)``.
    """
    return sum(math.comb(chunks, j) for j in range(wins, chunks + 1)) / (1 << chunks)


def level_time_correlation(drives: list[np.ndarray]) -> float:
    """The largest |corr(running mean of the drive, time)| over the recordings (0 for a constant drive)."""
    best = 0.0
    for u in drives:
        u = np.asarray(u, float)
        if u.size < 20:
            continue
        width = max(2, u.size // 10)
        level = np.convolve(u, np.ones(width) / width, mode="valid")
        if np.ptp(level) == 0:
            continue
        r = float(np.corrcoef(level, np.arange(level.size))[0, 1])
        best = max(best, abs(r)) if math.isfinite(r) else best
    return best


def power_near(drives: list[np.ndarray], rate: float, frequency: float) -> float:
    """Share of the drives' power (mean removed) between frequency/1.25 and frequency·1.25."""
    total = near = 0.0
    for u in drives:
        u = np.asarray(u, float) - np.mean(u)
        if u.size < 4:
            continue
        power = np.abs(np.fft.rfft(u)) ** 2
        f = np.fft.rfftfreq(u.size, 1.0 / rate)
        total += float(np.sum(power[1:]))
        near += float(np.sum(power[(f >= frequency / 1.25) & (f <= frequency * 1.25)]))
    return near / total if total > 0 else 0.0


def _frequencies(candidate, effects) -> dict[str, float]:
    """The candidate's own parameters whose unit is Hz, by name."""
    own = next((e for e in effects if e.name == candidate.name), None)
    if own is None:
        return {}
    return {
        k: float(candidate.parameters[k])
        for k, unit in own.units.items()
        if unit == "Hz" and k in candidate.parameters and math.isfinite(candidate.parameters[k])
    }


def _rival(named, c, scale: float, noise_std: float) -> dict:
    """`c` weighed against `named` on the held-out part: the sign test and the predictions' RMS difference."""
    test = paired_difference(named.heldout_residual, c.heldout_residual)
    apart = float(np.sqrt(np.mean((c.heldout_residual - named.heldout_residual) ** 2)))
    return {
        "name": c.name,
        "gain": c.gain,
        "heldout_nmse": c.heldout.nmse,
        "mse_difference": test["mean"] / scale,
        "mse_difference_std_error": test["std_error"] / scale,
        "chunks": test["chunks"],
        "named_wins": test["wins"],
        "p_value": test["p_value"],
        "mean_p_value": test["mean_p_value"],
        "prediction_rms_difference": apart,
        "within_noise": bool(math.isfinite(noise_std) and apart < noise_std),
        # the held-out tests prefer the named cause: either one is significant
        "named_better": bool(test["p_value"] <= ALPHA or test["mean_p_value"] <= ALPHA),
    }


def unlike(effects, candidate) -> bool:
    """Whether `candidate`'s fit is not its effect at all (`AbstractEffect.unlike`, shown its values and
    its derived quantities): no threshold admits it, so it is neither "too small" nor a too-small rival."""
    effect = next((e for e in effects or () if e.name == candidate.name), None)
    return effect is not None and bool(effect.unlike({**candidate.parameters, **candidate.derived}))


def ambiguities(
    steps,
    w_test,
    noise_std: float,
    drives,
    rate: float,
    effects,
    open_remainder: bool = False,
    min_bic_drop: float = 10.0,
) -> list[dict]:
    """Each step whose named cause has indistinguishable rivals (``report.json``'s ``ambiguous``).

    `steps`: the search's steps (`Step`); `w_test`: the recorded held-out
    output (for the scale of the errors); `noise_std`: the noise floor's
    standard deviation (NaN: unknown, that criterion is skipped); `drives`: the
    recordings' drives; `effects`: the searched effects (for their units);
    `open_remainder`: whether the final model leaves a remainder above the
    noise floor (which opens a last step that named nothing on weaker evidence);
    `min_bic_drop`: the search's BIC rule (``"confound"`` evidence).
    """
    scale = float(np.var(w_test)) or 1.0
    out = []
    for k, step in enumerate(steps, 1):
        named = step.chosen
        if getattr(step, "joint_with", None):  # named with the next step's cause on their joint fit
            continue
        if named is None:
            if k == len(steps):
                out.extend(
                    _open_step(k, step, scale, noise_std, drives, rate, effects, open_remainder, min_bic_drop)
                )
            continue
        if named.heldout_residual is None:
            continue
        rivals = []
        for c in step.candidates:
            if c is named or c.name == named.name or c.heldout_residual is None:
                continue
            small = c.refused_for_size and c.gain > named.gain and not unlike(effects, c)
            if not (c.eligible or small):
                continue
            rival = _rival(named, c, scale, noise_std)
            # neither the sign test nor the mean's tells them apart, or they predict alike to the noise
            if small or not rival["named_better"] or rival["within_noise"]:
                rival["why"] = _why(named, [c.name], step.candidates, drives, rate, effects)  # its own
                rivals.append({**rival, "too_small": True} if small else rival)
        if rivals:
            out.append(
                {
                    "step": k,
                    "named": named.name,
                    "gain": named.gain,
                    "rivals": rivals,
                    "why": _why(named, [r["name"] for r in rivals], step.candidates, drives, rate, effects),
                    "recordings": len(drives),
                }
            )
    return out


def _open_step(
    k: int,
    step,
    scale: float,
    noise_std: float,
    drives,
    rate: float,
    effects,
    remainder: bool,
    min_bic_drop: float,
) -> list[dict]:
    """The open last step's entry (at most one): nothing more vs its best candidates, where one is there."""
    current = step.current
    if current is None or current.heldout_residual is None:
        return []
    found = sorted(
        (
            c
            for c in step.candidates
            # an immaterial candidate is below the size that counts as a cause (a loop the recording
            # never closes, a delay within the frame timing): no drive would make it one
            if c.heldout_residual is not None
            and math.isfinite(c.gain)
            and c.gain > 1.0
            and c.material is not False
        ),
        key=lambda c: -c.gain,
    )
    of_time = {e.name: e.of_time for e in effects}
    level_and_time = level_time_correlation(drives) >= LEVEL_TIME_R
    rivals, confounded = [], []
    for c in found:
        rival = _rival(current, c, scale, noise_std)
        rival["candidate_p_value"] = sign_tail(rival["chunks"] - rival["named_wins"], rival["chunks"])
        gain = step.bar / max(c.heldout.nmse, 1e-300)  # over every effect-free fit as good on training
        if remainder:
            # a candidate that predicts what nothing more predicts, to within the noise, is no alternative,
            # nor one that an effect-free fit as good on training matches held out: what is left is
            # then how the model extrapolates (the remainder's "underdetermined"), not a missing effect
            # (and a candidate that gains under HINT_GAIN over nothing more is no experiment's worth: a new
            # user's pendulum was asked to design a drive against a saturation gaining 1.03)
            keep = not rival["within_noise"] and gain > 1.0 and c.gain >= HINT_GAIN
        else:
            # no remainder flagged: only a significant, not-small gain over every effect-free fit as good
            keep = rival["candidate_p_value"] <= ALPHA and gain >= HINT_GAIN
        if keep:
            rivals.append(rival)
        elif (
            not remainder
            and level_and_time
            and of_time.get(c.name, False)
            and c.material
            and c.delta_bic <= -min_bic_drop
        ):  # the training part prefers a drift that the rising level hides held out (no bar: there an
            # effect-free fit with its parameters biased does as well, which is the confound itself)
            rival["delta_bic"] = float(c.delta_bic)
            confounded.append(rival)
    evidence = "remainder" if remainder else "significant"
    if not rivals and confounded:
        rivals, evidence = confounded, "confound"
    rivals = rivals[:OPEN_RIVALS]
    if not rivals:
        return []
    return [
        {
            "step": k,
            "named": "none",
            "gain": 1.0,
            "open": True,
            "evidence": evidence,
            "rivals": rivals,
            "why": _why(current, [r["name"] for r in rivals], step.candidates, drives, rate, effects, True),
            "recordings": len(drives),
        }
    ]


def _why(named, rival_names, candidates, drives, rate: float, effects, open_step: bool = False) -> list[str]:
    """What in this recording makes the rivals look alike, where it can be seen.

    `open_step`: the rivals are those of an open last step (nothing more against its candidates). Where
    they are all effects of the level on a drive whose level follows time, an effect of time would act
    alike: a probe's staircase hiding a saturation left it open against nothing more, with no reason,
    while the same drive hiding a drift gave the correlation.
    """
    out = []
    of_time = {e.name: e.of_time for e in effects}
    # an effect of time (a drift) against one of the level ("none": the simulation's own response)
    sides = {of_time.get(name, False) for name in [named.name, *rival_names]}
    r = level_time_correlation(drives)
    if r >= LEVEL_TIME_R and sides == {True, False}:
        out.append(
            f"the drive's level and time are correlated (|r| = {r:.2f} between its running mean and time): "
            "an effect of the level and one of time act alike on this drive"
        )
    elif r >= LEVEL_TIME_R and open_step and sides == {False}:
        out.append(
            f"the drive's level and time are correlated (|r| = {r:.2f} between its running mean and time): "
            "an effect of time (a drift) would act on this drive as these effects of the level do"
        )
    for c in [named, *(c for c in candidates if c.name in rival_names)]:
        for name, f in _frequencies(c, effects).items():
            share = power_near(drives, rate, f)
            if f > 0 and share < THIN_POWER:
                out.append(
                    f"the drive has {100 * share:.2g} % of its power near {c.name}'s {name} = {f:.3g} Hz"
                )
    return out


def _reasons(entry: dict, rivals: list[dict]) -> str:
    """The reasons (``why``) that concern `rivals`, each rival's own where the entry gives them, in order.

    A probe's staircase named `saturation` with `drift` and `drive_saturation` its rivals: "the drive's
    level and time are correlated" was said of the drive's saturation too, a second effect of the level.
    """
    if not all("why" in r for r in rivals):  # an entry written before each rival had its own
        return "; ".join(entry["why"])
    return "; ".join(reason for reason in entry["why"] if any(reason in r["why"] for r in rivals))


def _gains(named_gain: float, rivals: list[dict]) -> int:
    """Significant digits that tell the gains of one sentence apart (3, up to 6): 6.5912 and 6.5875 both
    read 6.59 at 3."""
    gains = [named_gain, *(r["gain"] for r in rivals)]
    for digits in range(3, 7):
        shown = [f"{g:.{digits}g}" for g in gains]
        if len(set(shown)) == len(set(gains)):
            return digits
    return 6


def sentence(entry: dict) -> str:
    """report.md's sentence for one ``ambiguous`` entry."""
    rivals = _listed(entry["rivals"])
    why = _reasons(entry, entry["rivals"])
    these = "these recordings" if entry.get("recordings", 1) > 1 else "this recording"
    if entry.get("open"):
        if entry.get("evidence") == "confound":
            r = entry["rivals"][0]
            return (
                f"Step {entry['step']} named nothing and the model reaches the noise floor, yet on the training "
                f"part {r['name']} lowers the BIC by {-r['delta_bic']:.0f} while held out it gains only "
                f"{r['gain']:.3g}: the simulation's parameters may have absorbed it, so whether it is there is "
                "open"
                + (f" ({why})." if why else ".")
                + " A drive designed to separate them (hybrid design) would tell."
            )
        if entry.get("evidence") == "significant":
            r = entry["rivals"][0]
            who = rivals if len(entry["rivals"]) == 1 else f"each of {rivals}"
            return (
                f"Step {entry['step']} named nothing and what the model leaves is not flagged as unexplained, "
                f"yet {who} fits the "
                f"held-out part better in significantly many pieces (sign test p = {r['candidate_p_value']:.2g}"
                + (", the first" if len(entry["rivals"]) > 1 else "")
                + "): "
                f"too small to name on {these}, so whether it is there is open"
                + (f" ({why})." if why else ".")
                + " A drive designed to separate them (hybrid design) would tell."
            )
        return (
            f"Step {entry['step']} named nothing, yet the model leaves a remainder above the noise floor: {these} "
            f"cannot tell whether {rivals} or nothing of the library is missing"
            + (f" ({why})." if why else ".")
            + " A drive designed to separate them (hybrid design) would tell."
        )
    alike = [r for r in entry["rivals"] if not r.get("too_small") and not _named_better(r)]
    close = [r for r in entry["rivals"] if not r.get("too_small") and _named_better(r)]
    small = [r for r in entry["rivals"] if r.get("too_small")]
    out = []
    if alike:
        digits = _gains(entry["gain"], alike)
        named = f"step {entry['step']}'s {entry['named']} (gain {entry['gain']:.{digits}g})"
        how = "on the held-out part the named cause is not significantly better (sign test, mean)"
        if all(r["within_noise"] for r in alike):
            how += ", and their predictions differ by less than the noise"
        why = _reasons(entry, alike)
        out.append(
            f"{these[0].upper()}{these[1:]} cannot tell {named} from {_listed(alike, digits)}: {how}"
            + (f" ({why})." if why else ".")
            + " Another drive is needed to separate them."
        )
    if close:  # within the noise, yet the tests prefer the named cause: say both, not "cannot tell"
        digits = _gains(entry["gain"], close)
        named = f"step {entry['step']}'s {entry['named']} (gain {entry['gain']:.{digits}g})"
        p = max(min(r["p_value"], r["mean_p_value"]) for r in close)
        why = _reasons(entry, close)
        out.append(
            f"{named[0].upper()}{named[1:]} fits the held-out part significantly better than "
            f"{_listed(close, digits)} "
            f"(p ≤ {p:.2g}), yet their held-out predictions differ by less than the noise: on this drive "
            f"{'the two are' if len(close) == 1 else 'they are all'} close, and the name rests on differences "
            "smaller than the noise"
            + (f" ({why})." if why else ".")
            + " Another drive would separate them more clearly."
        )
    if small:
        out.append(
            f"Step {entry['step']} named {entry['named']} (gain {entry['gain']:.3g}), yet {_listed(small)} "
            f"{'fits' if len(small) == 1 else 'fit'} the held-out part better and {'was' if len(small) == 1 else 'were'} "
            f"refused only for {'its' if len(small) == 1 else 'their'} size: {entry['named']} may stand in for "
            "a small effect, or for one outside the library, so the name is not sure. If an effect that small "
            "matters here, count it with --materiality NAME=VALUE (see 'too small'); else try other effects "
            "(--effects) or a drive designed to separate them (hybrid design)."
        )
    return " ".join(out)


def _named_better(rival: dict) -> bool:
    """Whether the held-out tests prefer the named cause (an entry written before ``named_better``: from its p-values)."""
    return rival.get("named_better", rival["p_value"] <= ALPHA or rival["mean_p_value"] <= ALPHA)


def _listed(rivals: list[dict], digits: int = 3) -> str:
    return ", ".join(f"{r['name']} (gain {r['gain']:.{digits}g})" for r in rivals)
