"""A named cause that another makes redundant is dropped (the backward half of stepwise selection).

The plant is a first-order lag (τ 0.5 s) made here with scipy's `lfilter`,
whose gain drifts by −1.2 %/s under random levels. The final model of a
forward search that named saturation first and drift second is built by
fitting both from a start; weighed as if named last, saturation (no
curvature in the data) fails the step's rules and is dropped, drift is kept.
With a real saturation added to the plant, both are kept.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest
from diagnosis_helpers import diagnosis_of, step
from scipy.signal import lfilter

import hybrid
from hybrid.discovery._decision import evaluate_candidate, free_names
from hybrid.discovery._diagnose import final_fit, prepare_search
from hybrid.discovery._diagnosis import EquallyGoodFits
from hybrid.discovery._redundant import drop_redundant
from hybrid.discovery._report import stepwise_section
from hybrid.discovery._search import fit_lanes, initial_thetas, lane_tangents, padding_lane, with_active
from hybrid.discovery._step import Step

RATE, N = 30.0, 1800
EFFECTS = ["saturation", "drift"]


def _recording(curvature: float, seed: int = 0, drift: float = 0.012) -> hybrid.Recording:
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.uniform(0.0, 2.2, N // 15), 15)
    a = np.exp(-1.0 / (RATE * 0.5))
    s = lfilter([1 - a], [1, -a], u)
    s = s / (1.0 + curvature * s)  # a gain that falls with level (none at curvature 0)
    w = s * np.exp(-drift * np.arange(N) / RATE)
    w = w + 0.005 * np.ptp(w) * np.random.default_rng(seed + 1).normal(size=N)
    return hybrid.Recording.from_arrays(v_in=u, w=w, rate=RATE)


#: tanh(κs)/κ is even in κ: no slope at κ = 0, so saturation starts bent (as its own starts do)
_START = dict(drift_rate_per_s=-0.005, saturation_pos_curvature=0.5, saturation_neg_curvature=0.5)


def _both_named(recording):
    """The search, and the model with saturation and drift on, fitted by the search's own LM lanes."""
    search = prepare_search([recording], hybrid.LTI(1), hybrid.DiagnoseSettings(), EFFECTS)
    return search, _all_on(search, EFFECTS, _START)


def _all_on(search, effects, values, active=None):
    """The model with every one of `effects` on (named in that order), fitted from `values` by one lane;
    with `active`, the effects it switches on (zeros: the effect-free baseline)."""
    problem, model = search.problem, search.model
    if active is None:
        active = np.ones(len(effects) + 1)  # the effects and the frame timing
    effects = tuple(e for e, on in zip(effects, active) if on) or ("none",)
    start = model.simulation.with_active(active).replace(**values)
    theta = initial_thetas(problem, [start], model.readout, search.frozen)[0]
    n_rows = int(problem.sim_tangents.shape[0])
    tangents = lane_tangents(model, search.frozen, tuple(e for e in effects if e != "none"), n_rows)
    lanes = [theta] + [padding_lane(theta)] * (search.n_lanes - 1)
    states = fit_lanes(
        problem,
        np.tile(active, (search.n_lanes, 1)),
        np.stack([tangents] * search.n_lanes),
        jnp.stack(lanes),
        search.lm,
        search.settings.patience,
    )
    return evaluate_candidate(
        problem,
        states.best_theta[0],
        active,
        effects[-1],
        search.n_train,
        len(free_names(model, search.frozen, tuple(e for e in effects if e != "none"))),
        search.settings.materiality,
        search.frozen,
        tuple(effects[:-1]),
    )


def _effect_free(search):
    return _all_on(search, EFFECTS, {}, active=np.zeros(len(EFFECTS) + 1))


def test_a_cause_the_other_makes_redundant_is_dropped_and_a_needed_one_kept():
    search, final = _both_named(_recording(curvature=0.0))
    kept, refit, dropped = drop_redundant(search, final, ("saturation", "drift"), _effect_free(search))
    assert kept == ("drift",)  # left alone, it still clears the rules against the baseline
    (gone,) = dropped
    assert (gone.name, gone.step, gone.beside) == ("saturation", 1, ("drift",))
    assert gone.gain < search.settings.min_gain and gone.reasons  # why, in the step's words
    # the refit is the model without it: saturation off, and as good held out (within 10 %)
    assert refit.active[EFFECTS.index("saturation")] == 0.0 and refit.active[EFFECTS.index("drift")] == 1.0
    assert refit.heldout.nmse == pytest.approx(final.heldout.nmse, rel=0.1)


def test_the_cause_left_alone_after_a_drop_is_weighed_against_the_baseline():
    """No effect hidden: a forward search that named saturation and then drift (imposed here) drops
    one as redundant, and the one left, weighed against the effect-free baseline as step 1 would weigh
    it, fails too: nothing is named (a probe's cubic loss under a sensor drift: a hysteresis dropped as
    immaterial left a back-relaxation that gained 1.49× over the baseline, and it was named)."""
    search, final = _both_named(_recording(curvature=0.0, drift=0.0))
    baseline = _effect_free(search)
    kept, refit, dropped = drop_redundant(search, final, ("saturation", "drift"), baseline)
    assert kept == () and refit is baseline
    assert sorted(d.name for d in dropped) == ["drift", "saturation"]
    assert dropped[-1].beside == () and dropped[-1].reasons  # the last, against the baseline, with why
    assert dropped[-1].gain < search.settings.min_gain
    # without a baseline to weigh it against, the one left stands (as before)
    kept, _, dropped = drop_redundant(search, final, ("saturation", "drift"))
    assert len(kept) == 1 and len(dropped) == 1


def test_two_needed_causes_are_both_kept():
    search, final = _both_named(_recording(curvature=0.6))
    kept, refit, dropped = drop_redundant(search, final, ("saturation", "drift"))
    assert (kept, dropped) == (("saturation", "drift"), [])
    assert refit is final


def test_the_model_handed_back_is_the_last_steps_refit_where_that_fits_better_on_both_parts():
    """`final_fit`: the last step's refit of the chosen model replaces it only where it is better on validation
    *and* no worse on training; a refit better on validation alone (an iterate picked on 10 % of the record)
    does not. The chosen fit here is the same two effects at the refit's start, unfitted."""
    search, refit = _both_named(_recording(curvature=0.6))
    problem, model = search.problem, search.model
    active = refit.active
    start = initial_thetas(
        problem, [model.simulation.with_active(active).replace(**_START)], model.readout, search.frozen
    )[0]
    chosen = evaluate_candidate(
        problem,
        start,
        active,
        "drift",
        search.n_train,
        refit.n_parameters,
        search.settings.materiality,
        search.frozen,
        ("saturation",),
    )
    for fit in (refit, chosen):
        fit.validation_loss = float(with_active(problem, jnp.asarray(fit.active)).validation_loss(fit.theta))
    assert chosen.train_rss > 1.5 * refit.train_rss and chosen.validation_loss > refit.validation_loss
    bar = EquallyGoodFits(n=0, heldout_nmse_min=float("nan"), heldout_nmse_max=float("nan"), definition="-")
    first = dataclasses.replace(chosen, name="saturation")
    named = ("saturation", "drift")

    def steps(last_current):  # step 1 named saturation, step 2 drift (`chosen`), step 3 nothing
        return [
            Step(first, [first], first, 0.0, [], bar, []),
            Step(first, [chosen], chosen, 0.0, [], bar, []),
            Step(last_current, [], None, float("nan"), [], bar, []),
        ]

    assert final_fit(steps(refit), chosen, named) is refit
    assert final_fit(steps(chosen), chosen, named) is chosen  # no refit found: the chosen fit
    lucky = dataclasses.replace(
        chosen, validation_loss=0.5 * refit.validation_loss, train_rss=2 * chosen.train_rss
    )
    assert final_fit(steps(lucky), chosen, named) is chosen  # better on validation alone: not taken
    assert final_fit(steps(refit)[:2], chosen, named) is chosen  # the search stopped at its most causes
    assert final_fit(steps(refit), chosen, ()) is first  # nothing named: the first step's current


def test_a_dropped_cause_is_reported_and_not_among_the_causes():
    """Diagnosis.causes skips it, report.json and report.md list it, the verdict says so."""
    search, final = _both_named(_recording(curvature=0.0))
    base, first = dataclasses.replace(final, name="none"), dataclasses.replace(final, name="saturation")
    diagnosis = diagnosis_of(
        search,
        [step(base, first), step(first, final)],
        cause="drift",
        baseline=base,
        extended=final,
        candidates=[first],
        dropped=[
            {
                "name": "saturation",
                "step": 1,
                "gain": 13.2,
                "reasons": ["not material: its knee lies beyond the signal"],
                "beside": ["drift"],
            }
        ],
    )
    assert [(c["name"], c["step"]) for c in diagnosis.causes] == [("drift", 2)]
    # the rule it failed, not its gain (a probe's hysteresis "gains only 13.25×", dropped as immaterial)
    assert (
        "saturation, named at step 1, was dropped: weighed as if named last, beside drift, not material: "
        "its knee lies beyond the signal" in diagnosis.verdict
    )
    assert "gains only" not in diagnosis.verdict
    report = diagnosis.to_dict()
    assert report["dropped"][0]["name"] == "saturation"
    assert any(
        line.startswith("**Dropped.** saturation, named at step 1") for line in stepwise_section(report)
    )


def _drifting_oscillator(seed: int = 0) -> hybrid.Recording:
    """A 1.5 Hz mass-spring (ζ 0.3, 5 mm/V; scipy's exact ZOH) under random levels, a sensor drift added."""
    from scipy.signal import cont2discrete, dlsim, tf2ss

    rng = np.random.default_rng(seed)
    u = np.repeat(rng.uniform(-2.0, 2.0, N // 20), 20)
    w0 = 2 * np.pi * 1.5
    a, b, c, d, _ = cont2discrete(tf2ss([5.0 * w0**2], [1.0, 2 * 0.3 * w0, w0**2]), 1 / RATE, method="zoh")
    y = dlsim((a, b, c, d, 1 / RATE), u)[1][:, 0]
    t = np.arange(N) / RATE
    y = y + 3.0 * np.sin(2 * np.pi * t / 90.0 + 0.5)  # 3 mm over 90 s: a warming sensor
    y = y + 0.01 * np.std(y) * np.random.default_rng(seed + 1).normal(size=N)
    return hybrid.Recording.from_arrays(v_in=u, w=y, rate=RATE)


def test_a_cause_that_holds_the_simulations_own_mode_is_dropped_once_the_mode_is_found_again():
    """`lti:2`'s effect-free fit modelled a drift with its mode (f₁ 0.03 Hz, ζ 36), `resonance` then
    carried the real mode and `baseline_drift` was named beside it (a user's record): from the final
    model's end point, LM without `resonance` stays degenerate and `resonance` was kept. The refit's
    lane that starts the simulation at the values the search began from finds the mode and drops it.
    """
    recording = _drifting_oscillator()
    effects = ["resonance", "baseline_drift"]
    given = hybrid.resolve_physics("lti:2", recording)  # centred on the data's 1.5 Hz
    search = prepare_search([recording], given, hybrid.DiagnoseSettings(), effects)
    values = dict(f_1=0.0317, zeta_1=35.7, bandpass_1=2.39, resonance_frequency_hz=1.5, resonance_damping=0.3)
    final, problem = _all_on(search, effects, values), search.problem
    inner = problem.model(jnp.asarray(final.theta)).simulation.inner.parameters()
    assert float(inner["f_1"]) < 0.5  # the final model's own mode stayed degenerate
    kept, refit, dropped = drop_redundant(search, final, ("resonance", "baseline_drift"))
    assert kept == ("baseline_drift",) and [d.name for d in dropped] == ["resonance"]
    found = problem.model(jnp.asarray(refit.theta)).simulation.inner.parameters()
    assert float(found["f_1"]) == pytest.approx(1.5, rel=0.02)  # the mode, found again
