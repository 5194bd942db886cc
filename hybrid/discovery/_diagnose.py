"""What the simulation gets wrong, which physical effect causes it, and what adding it gains.

`diagnose(recordings)`:

0. **Glitches.** w's runs of a few samples that it jumps into and back out of,
   undriven (a tracker that lost its marker), are bridged by straight lines
   before any fit, and said (`DiagnoseSettings.bridge_glitches`).
1. **Baseline.** The physics simulation (any [`AbstractSimulation`][];
   `hybrid.diagnose` defaults to the paper's RC network) with a linear gain and
   offset is fitted by Levenberg–Marquardt on the training part of each
   recording (first 60 %). The simulation as given and a 511-point Sobol design
   over its parameters' typical ranges (`AbstractSimulation.typical_ranges`:
   for the RC network C_clamp, ξρ and the α's) are screened by one simulation each; LM runs from the best
   of them, one per lane of the search (at least 16, and as many as the first step's candidate lanes: 31
   with the built-in effects), in one compiled program (`fit_lanes`: the lanes one after the other on
   each device, the devices side by side); the validation part (next 10 %) picks the best.
2. **Candidates.** The same simulation followed by each effect of
   [`hybrid.discovery._effects`][] is refitted jointly (physical parameters, effect, gain
   and offset), warm-started from the baseline, from a few data-scaled starting
   values per effect, and for the dead time, the hysteresis loop and the mode
   from design points screened jointly with the effect
   ([`hybrid.discovery._starts`][]).
   Every start is one lane of a single compiled LM program: an
   [`EffectStack`][] holds all effects, and a lane switches on one of them.
   The validation part picks each effect's lane, except that a lane whose
   effect is immaterial gives way to a material one within a standard error
   of its validation loss (`_choose_lane`).
3. **Re-baseline.** The effect-free simulation is refitted from every
   candidate's end point. An extension can "gain" only because its start led
   the shared RC parameters out of the baseline's local minimum; the refit
   takes that gain away, so what is left is the effect's own.
4. **Evidence on held-out data** (the last 30 % of each block, never used for fitting or
   selection): held-out NMSE and its gain over the baseline, BIC on the
   training part, the Ljung–Box whiteness statistic of the held-out residual,
   and whether the fitted effect is physically material (e.g. a delay of at
   least half a sample, a relaxation of at least 10 %). A cause is named only
   when its extension is material, improves the held-out NMSE by at least
   `min_gain`, lowers BIC by at least `min_bic_drop` and leaves a held-out
   residual whose correlated part is no larger than the baseline's (Ljung–Box Q
   in the baseline's units, or white at 99 %); among those,
   the largest held-out gain wins. The gain must also hold against every
   effect-free fit (from all starts and refits) that matches the baseline on
   training data within `min_bic_drop`: where the recording is too short to pin a
   slow strip's dynamics, such fits extrapolate differently, and landing on a
   better extrapolation is not an effect. Otherwise the answer is ``"none"``: a false
   discovery is worse than a miss.
5. **Extended model.** The named cause's fit, with standard errors of every
   parameter in physical units (Gauss–Newton covariance σ²(JᵀJ)⁻¹ mapped through
   the reparameterisation, inflated for residual autocorrelation). With
   ``hybrid=True`` the hybrid model (simulation + D-MLP) is fitted with and
   without the effect too.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ..core._arguments import as_recordings, check_simulation, require_float64
from ..core._fit import PAPER_UNITS, non_finite_error, recording_units, unit_labels, unit_mismatch
from ..core._held_start import HeldStart, held_at_start
from ..core._levenberg_marquardt import LMSettings
from ..core._models import Model
from ..core._problem import Problem, unmeasured_runs
from ..core._result import (
    aliased,
    drive_outside_range,
    implausible,
    narrowed,
    one_frequency_drive,
    sub_sample,
    user_methods,
    user_simulation,
)
from ..core._screen import N_SCREEN, screen_starts
from ..core._simulation import unit_in
from ..data._recording import in_shared_units
from ..util._errors import InputError, PluginError
from ..util._programs import DIAGNOSE_PROGRAMS
from ..util._watchdog import stage
from ._ambiguity import ambiguities
from ._decision import derived_quantities, evaluate_candidate, free_names
from ._diagnosis import (
    MIN_DIAGNOSE_SAMPLES,
    SPLIT_ORDER,
    Candidate,
    DiagnoseSettings,
    Diagnosis,
    HeldoutSignals,
)
from ._effect_set import resolve_effects, searched_places
from ._effect_stack import EffectStack
from ._evidence import diverged_warnings, fitted_model, heldout_evidence, not_pinned, parameter_uncertainties
from ._joint import joint_pair, named_jointly
from ._noise_floor import bounded_by_residual, bridged, glitch_runs
from ._redundant import drop_redundant
from ._refine import refinable, refined, refined_effects, refinement_reason, refused
from ._search import (
    N_LANES,
    fit_lanes,
    held_out_blocks,
    initial_thetas,
    lane_tangents,
    lanes_problem,
    padding_lane,
    split_signals,
)
from ._start import covered_try, settle_samples, settled_try, start_misfit
from ._step import Search, Step, nonfinite_warnings, search_step
from ._unexplained import pooled_noise_floor, remainder

#: Spread (std) of w and v_in that `diagnose` takes, in any unit: it fits in the recording's own units.
DIAGNOSE_SPREAD = (1e-6, 1e6)


def _host_std(x: np.ndarray) -> float:
    """`robust_std` in numpy: no compiled program per recording length."""
    top = float(np.max(np.abs(x))) if x.size else 0.0
    if not np.isfinite(top) or top == 0.0:
        return float(np.std(x)) if np.isfinite(top) else float("inf")
    scale = np.ldexp(1.0, int(np.frexp(top)[1]))
    return float(np.std(x / scale) * scale)


def _check_magnitudes(recording) -> None:
    """Refuse a column whose spread is outside `DIAGNOSE_SPREAD`: the search would overflow or stall.

    `hybrid.fit` normalises w and v_in inside the fit; `diagnose`'s search, its
    screens and its standard errors still work in the recording's units, so a w
    written ×1e300 (or in a unit a million times too small) is refused with the fix.
    """
    low, high = DIAGNOSE_SPREAD
    for column, typical in (("w", "a tip displacement in mm"), ("v_in", "a drive in V")):
        spread = _host_std(np.asarray(getattr(recording, column), float))
        if not low <= spread <= high:
            raise InputError(
                f"recording '{recording.name}': {column} has a standard deviation of {spread:.3g}, "
                f"outside the {low:g} to {high:g} that diagnose fits in the recording's own units: "
                f"rescale {column} (as {typical}, say)"
            )


def shape_key(problem, settings) -> tuple:
    """What the search's compiled programs depend on: `problem`'s structure, shapes and dtypes, and `settings`."""
    leaves, treedef = jax.tree_util.tree_flatten(problem)
    return (
        treedef,
        tuple((getattr(x, "shape", None), str(getattr(x, "dtype", type(x)))) for x in leaves),
        settings,
    )


def prepare_search(
    recordings, simulation, settings: DiagnoseSettings, effects=None, say=lambda _: None
) -> Search:
    """What every step of `diagnose`'s search shares (`Search`), for checked `recordings` of one rate.

    `settings` comes back completed: what `simulation` keeps fixed and every
    effect's materiality threshold (the report shows both).
    """
    effects = resolve_effects(effects, simulation)
    frozen_names = settings.frozen_for(simulation)
    blocks, reached = held_out_blocks(recordings, settings)
    if blocks != settings.blocks:
        say(
            f"{blocks} blocks, not {settings.blocks}: the fewest whose held-out parts see where the output "
            "sits flat at an extreme"
        )
    settings = dataclasses.replace(
        settings,
        frozen=frozen_names,
        materiality=settings.materiality_for(effects),
        blocks_used=blocks,
        extremes_held_out=reached,
    )
    problem, _, model = lanes_problem(recordings, simulation, settings, effects)
    return Search(
        problem=problem,
        model=model,
        simulation=simulation,
        settings=settings,
        frozen=frozenset(frozen_names),
        lm=LMSettings(max_steps=settings.max_steps, patience_rtol=settings.patience_rtol),
        rate=recordings[0].rate,
        duration=recordings[0].duration,
        # the samples the losses count: a sample not measured (quality 0) weighs nothing, and is not one
        n_train=sum(b - a for s in problem.series for a, b in s.recorded_segments_of("train")),
        n_val=sum(b - a for s in problem.series for a, b in s.recorded_segments_of("validation")),
        say=say,
    )


def final_fit(steps: list[Step], chosen: Candidate, present: tuple[str, ...]) -> Candidate:
    """The model the search hands back, before each cause is weighed as if named last (`drop_redundant`).

    The baseline where nothing was named; otherwise the last step's `chosen`
    candidate, or the last step's refit of it where that fits better on both
    parts (`better_fit`).
    """
    if not present:
        return steps[0].current
    last = steps[-1]
    return last.current if last.chosen is None and better_fit(last.current, chosen) else chosen


def better_fit(refit: Candidate, fit: Candidate) -> bool:
    """Whether `refit`, the same effects refitted from another start, fits better than `fit`: on both parts.

    A step refits the model it extends from every lane's end point and weighs
    its candidates against the refit with the least validation loss
    (`search_step`). The model handed back takes the last step's refit only
    where it is also no worse on the training part: on the 10 % of a
    recording that is validation, the least loss of hundreds of iterates can
    belong to one that fits the training part several times worse. Where the
    refit is better on both, it is the fit of the named effects that the
    weighing of each as if named last (`drop_redundant`) needs: from the
    chosen lane's fit, worse on training than the model without it, a real
    cause can be dropped (back_relaxation + saturation seed 2 of
    `experiments/design_loop.py`, diagnosed with its rich drive: saturation
    was dropped against the back-relaxation alone, and is kept from the refit).
    """
    return (
        refit is not fit and refit.validation_loss < fit.validation_loss and refit.train_rss <= fit.train_rss
    )


def diagnose(
    recordings,
    *,
    simulation=None,
    effects=None,
    hybrid: bool = False,
    settings: DiagnoseSettings = DiagnoseSettings(),
    hybrid_max_steps: int = 150,
    progress: bool = False,
) -> Diagnosis:
    """Find what `simulation` gets wrong on `recordings`.

    **Arguments:**

    - `recordings`: one Recording or several of the same strip (fitted jointly).
    - `simulation`: the physics simulation to diagnose, any [`AbstractSimulation`][]
      (`hybrid.diagnose` defaults to the paper's RC network, discretised exactly, and takes a
      ``--physics`` spec too: ``"lti:2"``, ``"file.py:Class"``, resolved as the command line does).
    - `effects`: the effects to search, each a built-in's name, an
      [`AbstractEffect`][] subclass or instance (a plug-in); None: every
      built-in ([`EFFECTS`][]).
    - `hybrid`: also fit the hybrid model (simulation + D-MLP) with and without
      the named effect and report both held-out errors.
    - `settings`: see [`DiagnoseSettings`][].
    - `progress`: print what is being fitted.

    **Returns:** a [`Diagnosis`][]; ``Diagnosis.to_dict()`` is ``report.json``.
    """
    t0 = time.perf_counter()
    given, given_effects = settings, effects  # as asked: a held-start rerun resolves them again
    recordings = as_recordings(recordings, "diagnose")  # a path is loaded; anything else is refused
    recordings = in_shared_units(recordings, "diagnose")  # one model fits them: one scale
    # what reading them and putting them in one unit said (t rebuilt, a unit converted, sizes a power of
    # 1000 apart): in the report too, where a reader of report.json alone sees it (a verifier's mV drive
    # read as V was said on stderr only)
    shared_notes = list(dict.fromkeys(n for r in recordings for n in r.notes))
    require_float64(
        "diagnose",
        "its noise floor, information criteria and held-out tests compare errors far below float32's "
        "1e-7; in float32 a start design turns NaN",
    )
    check_simulation(simulation, "diagnose")
    if not isinstance(settings, DiagnoseSettings):
        raise InputError(
            f"diagnose: settings must be a DiagnoseSettings, got {type(settings).__name__}: "
            "use dataclasses.replace(hybrid.DiagnoseSettings(), max_steps=...)"
        )
    rates = {round(r.rate, 9) for r in recordings}
    if len(rates) > 1:
        raise InputError(
            f"recordings diagnosed together must share a sample rate, got {sorted(rates)} Hz: resample first"
        )
    for r in recordings:  # before any fitting: a constant column would fail only after minutes
        r.check_length(
            MIN_DIAGNOSE_SAMPLES,
            "diagnose (a held-out part long enough for residual tests)",
            f"record at least {MIN_DIAGNOSE_SAMPLES} samples ({MIN_DIAGNOSE_SAMPLES / r.rate:.3g} s at "
            f"{r.rate:.6g} Hz), better several minutes",
        )
        r.check_signals()
        _check_magnitudes(r)
    recordings, glitches = _bridge_glitches(recordings) if settings.bridge_glitches else (recordings, [])
    rate = recordings[0].rate
    if simulation is None:
        raise InputError(
            "diagnose needs a simulation: pass simulation=hybrid.RCNetwork(method='zoh') (the paper's "
            "physics) or any AbstractSimulation, or use hybrid.diagnose, which defaults to the RC network"
        )

    def say(text):  # the watchdog's heartbeat names the stage; progress prints it
        stage(f"diagnose: {text}")
        if progress:
            print(f"diagnose: {text}", flush=True)

    search = prepare_search(recordings, simulation, settings, effects, say)
    if DIAGNOSE_PROGRAMS.admit(shape_key(search.problem, search.lm)) and progress:  # maps never run out
        print("diagnose: released the compiled programs of earlier recordings' shapes", flush=True)
    problem, model, settings, frozen = search.problem, search.model, search.settings, search.frozen
    effects, lm, n_train = search.effects, search.lm, search.n_train
    assert problem.sim_tangents is not None  # a search problem always has its directions
    n_rows = int(problem.sim_tangents.shape[0])
    off = np.zeros(len(effects) + 1)  # every effect off, the frame timing on
    off[-1] = 1.0

    # 1. Baseline: the best starts of a screened design (lanes), one compiled program.
    n_lanes = search.n_lanes  # every stage runs this many lanes: one compiled program for all
    say(f"screening {N_SCREEN} designs of the simulation's parameters for the baseline's starts")
    grid, escaped = screen_starts(problem, simulation, N_LANES, N_SCREEN, frozen)  # whatever the effects
    stack = model.simulation
    assert isinstance(stack, EffectStack)  # a search fits an EffectStack
    base = stack.with_active(off)
    thetas = initial_thetas(problem, [base.replace(**g) for g in grid], model.readout, frozen)
    say(f"baseline from {len(grid)} starts")
    # Fewer starts than lanes (a larger effect set, or few free parameters): the rest stop at once.
    if len(grid) < n_lanes:
        thetas = jnp.concatenate([thetas, jnp.stack([padding_lane(thetas[0])] * (n_lanes - len(grid)))])
        grid += grid[:1] * (n_lanes - len(grid))
    base_tangents = lane_tangents(model, frozen, None, n_rows)
    base_states = fit_lanes(
        problem,
        np.tile(off, (len(grid), 1)),
        np.stack([base_tangents] * len(grid)),
        thetas,
        lm,
        settings.effect_free_patience,
    )
    if not np.isfinite(np.asarray(base_states.best_val)).any():  # no start could move
        raise non_finite_error(simulation, recordings)
    best = int(np.nanargmin(np.asarray(base_states.best_val)))
    escapes = _escapes_warning(simulation, escaped, N_SCREEN)
    theta_base = base_states.best_theta[best]
    n_base = len(free_names(model, frozen, None))
    baseline = evaluate_candidate(
        problem, theta_base, off, "none", n_train, n_base, settings.materiality, frozen
    )

    # 2–4. Stepwise: every remaining effect on top of the current model, weighed
    # incrementally; stop at the first step that names nothing.
    current, current_val, current_fits = (
        baseline,
        float(base_states.best_val[best]),
        list(base_states.best_theta),
    )
    steps: list[Step] = []
    present: tuple[str, ...] = ()
    alone: Step | None = None  # the first step's own answer, while a joint pair awaits its second step
    extra, joint_tried = None, False
    while len(present) < min(settings.max_causes, len(effects)):
        step = search_step(search, current, current_val, current_fits, present, extra)
        extra = None
        if alone is not None and step.cause != steps[-1].joint_with:  # the pair's second not confirmed
            say(f"{steps[-1].joint_with} not confirmed beside {present[0]}: the first step's own answer")
            steps, step, present = [], alone, ()
        alone = None
        if not present:
            baseline = step.current  # refitted from a candidate's end point when that was better
            if settings.max_causes >= 2 and not joint_tried:
                joint_tried = True
                pair = joint_pair(search, step)
                if pair is not None:
                    alone, step = step, named_jointly(step, pair)
                    extra = {pair.second: [pair.theta]}
        steps.append(step)
        if step.chosen is None:
            break
        present += (step.chosen.name,)
        current, current_val, current_fits = step.chosen, step.chosen_val, step.chosen_fits
    extended = final_fit(steps, current, present)
    # `present` stays the search's history (step k named present[k - 1]); `kept`, the causes the
    # final model needs once each is weighed as if named last.
    kept, extended, dropped = drop_redundant(search, extended, present, steps[0].current)
    cause = kept[0] if kept else "none"
    names = [r.name for r in recordings]
    held = isinstance(simulation, HeldStart)
    start = start_misfit(problem, extended.theta, extended.active, names, held)
    # The causes may meet a start that the effect-free model misses: a lag, with `lti:N` from rest, can
    # stand in for a record that starts settled at its first drive. The held start is tried then too.
    first = steps[0].current
    effect_free = start_misfit(problem, first.theta, first.active, names, held) if kept else start
    covered = not start["off"] and effect_free["off"]
    if (start["off"] or covered) and given.settle_when_off and not held and len(recordings) == 1:
        n_held = settle_samples(len(recordings[0].w))
        missed = "the effect-free model misses" if covered else "the model misses"
        say(f"{missed} the record's start: again, the simulation held at a fitted drive for {n_held} samples")
        try:
            again = diagnose(
                recordings,
                simulation=held_at_start(simulation, n_held, recordings[0]),
                effects=given_effects,
                hybrid=hybrid,
                settings=dataclasses.replace(given, settle_when_off=False),
                hybrid_max_steps=hybrid_max_steps,
                progress=progress,
            )
        except InputError as error:  # e.g. a plug-in that refuses the longer drive: this diagnosis stands
            said = start["sentence"] or effect_free["sentence"]
            start = {
                **start,
                "settled": {"samples": n_held, "automatically": True, "error": str(error)},
                "sentence": f"{said}. A held start of {n_held} samples could not be tried: {error}",
            }
        else:
            if covered:
                tried = covered_try(
                    effect_free, start, again, n_held, kept, extended, given.min_gain, recordings[0].v_in
                )
            else:
                tried = settled_try(start, again.evidence["start"], n_held, cause, kept, baseline, extended)
            if tried["settled"]["kept"]:  # the held start fits, and it was the initial state
                again.evidence["start"] = tried
                again.seconds = time.perf_counter() - t0
                again.glitches_bridged = glitches  # it read the recordings as bridged here
                # once each: the rerun read the same recordings (their notes, the unmeasured runs) too
                again.warnings = list(
                    dict.fromkeys(shared_notes + _glitch_warnings(glitches, rate) + again.warnings)
                )
                return again
            start = tried  # held, the start is still missed, or the causes earn their place: said so

    # 5. The final model: uncertainties, evidence, the noise floor and what is left above it.
    theta_base = baseline.theta
    v_te, w_te, w_hat_base = split_signals(problem, theta_base, off, "test")
    _, _, w_hat_ext = split_signals(problem, extended.theta, extended.active, "test")
    # the held-out blocks as `split_signals` cuts them (round the samples w was not measured at)
    segments = [(i, a, b) for i, s in enumerate(problem.series) for a, b in s.recorded_segments_of("test")]
    extended_model = fitted_model(problem, extended.theta, kept)
    units = unit_labels(extended_model, recordings)  # the recordings' units, as the report gives them
    # On a problem of the handed-back model's own structure (its effects alone), not the search's: the
    # same standard errors (the switched-off effects' Jacobian columns are zero; tests/test_effects.py),
    # from a program that traces and compiles a few effects, not every one searched (13 built-ins: ~6 s
    # of the first call, `benchmarks/diagnose_effect_set.py`), and never the larger problem of a search
    # that keeps more causes than its shared room.
    own = Problem(extended_model, problem.series, frozen)
    uncertainties = parameter_uncertainties(
        own, own.flatten(extended_model, frozen), w_te - w_hat_ext, units=units
    )
    unpinned = not_pinned(uncertainties, extended_model, problem.series)
    blocks = np.concatenate([np.full(b - a, k) for k, (_, a, b) in enumerate(segments)])
    of_recording = np.concatenate([np.full(b - a, i) for i, a, b in segments])
    evidence = heldout_evidence(
        v_te, w_te, w_hat_base, w_hat_ext, rate, segments=blocks, recordings=of_recording
    )
    evidence["equally_good_effect_free_fits"] = steps[0].equally_good.to_dict()  # report.json's shape
    evidence["start"] = start
    # where the rivals were fitted: `hybrid design` says where a drive goes beyond it (extrapolates them)
    evidence["drive_range"] = [
        float(min(np.min(r.v_in) for r in recordings)),
        float(max(np.max(r.v_in) for r in recordings)),
    ]
    heldout = HeldoutSignals(
        t=np.concatenate([recordings[i].t[a:b] for i, a, b in segments]),
        v_in=v_te,
        w=w_te,
        baseline=w_hat_base,
        extended=w_hat_ext,
        recording=of_recording,
        segment=blocks,
        sample=np.concatenate([np.arange(a, b) for _, a, b in segments]),
    )
    say("noise floor and what lies above it")
    signals = recording_units(recordings) or (PAPER_UNITS["w"], PAPER_UNITS["v_in"])  # (w's, the drive's)
    floor = bounded_by_residual(pooled_noise_floor(recordings), w_te - w_hat_ext, heldout.segment)
    places = searched_places(search.effects, simulation)
    fitted_stack = extended_model.simulation
    assert isinstance(fitted_stack, EffectStack)  # a search's model
    inner_names = set(fitted_stack.inner.parameters())
    unexplained = remainder(
        problem,
        recordings,
        extended,
        heldout,
        floor,
        settings,
        rate,
        equally_good=steps[-1].equally_good,
        places=places,
        w_unit=signals[0],
        loose=tuple(name for name in unpinned if name in inner_names),
        v_unit=signals[1],
    )
    drives = [np.asarray(r.v_in, float) for r in recordings]
    rivals = ambiguities(
        steps,
        w_te,
        floor.std,
        drives,
        rate,
        search.effects,
        open_remainder=unexplained is not None,
        min_bic_drop=settings.min_bic_drop,
    )
    gone = {d.name for d in dropped}  # a dropped cause's rivals are moot: the final model does without it
    rivals = [entry for entry in rivals if entry["named"] not in gone]
    rival_models = {}
    for entry in rivals:  # each side of an ambiguity as a loadable model (`hybrid design` reads them)
        k = entry["step"]
        before = present[: k - 1]
        files = {}
        for name in [entry["named"], *(r["name"] for r in entry["rivals"])]:
            key = f"step{k}_{name}"
            if name == "none":  # an open last step's "nothing more": the model that step extended
                rival_models[key] = fitted_model(problem, steps[k - 1].current.theta, before)
            else:
                fitted = next(c for c in steps[k - 1].candidates if c.name == name)
                rival_models[key] = fitted_model(problem, fitted.theta, (*before, name))
            files[name] = f"{key}.eqx"
        entry["models"] = files
    hybrid_report = None
    if hybrid:
        hybrid_report = hybrid_fits(
            recordings, simulation, extended, problem, kept, settings, hybrid_max_steps, progress
        )
    models = {  # each labels its parameters in the recordings' units, saved and loaded with it
        name: dataclasses.replace(model, signal_units=signals)
        for name, model in {
            "baseline": fitted_model(problem, baseline.theta, ()),
            "extended": extended_model,
            **rival_models,
        }.items()
    }
    found = Diagnosis(
        cause=cause,
        baseline=baseline,
        extended=extended,
        candidates=steps[0].candidates,
        uncertainties=uncertainties,
        evidence=evidence,
        hybrid=hybrid_report,
        settings=settings,
        recordings=names,
        seconds=time.perf_counter() - t0,
        heldout=heldout,
        lanes=[lane for step in steps for lane in step.lanes],
        steps=steps,
        noise_floor=floor,
        unexplained=unexplained,
        effects=search.effects,
        places=places,
        not_pinned=unpinned,
        ambiguous=rivals,
        models=models,
        units=units,
        signal_units=dict(zip(("w", "v_in"), signals)),
        dropped=[d.to_dict() for d in dropped],
        glitches_bridged=glitches,
        warnings=shared_notes
        + _glitch_warnings(glitches, rate)
        + escapes
        + nonfinite_warnings(steps, search.effects)
        + model_warnings(models["extended"], frozen, search.rate)
        + drive_outside_range(models["extended"].simulation, [r.v_in for r in recordings], signals[1])
        + one_frequency_drive([(r.v_in, r.rate) for r in recordings])
        + unit_mismatch(recordings, simulation)
        + narrowed(user_methods(simulation, search.effects), search.rate)
        + diverged_warnings(uncertainties),
        final_derived=derived_quantities(problem, jnp.asarray(extended.theta), extended.active)
        if kept
        else {},
    )
    builtins = resolve_effects(None, simulation)
    room = float(np.mean((w_te - w_hat_ext) ** 2)) / max(floor.variance, 1e-300)  # held out, over the floor
    pointers = {c["name"]: c["points_at"] for c in found.causes if c.get("points_at")}
    swaps = (
        refinable(search.effects, kept, unexplained, builtins, room, settings.min_gain, pointers)
        if given.refine
        else {}
    )
    if not swaps:
        return found
    why = refinement_reason(kept, room, settings.min_gain, unexplained, pointers, swaps)
    say(f"{why}: again with {', '.join(f'{b} for {a}' for a, b in swaps.items())}")
    try:
        again = diagnose(
            recordings,
            simulation=simulation,
            effects=refined_effects(search.effects, swaps),
            hybrid=hybrid,
            settings=dataclasses.replace(given, refine=False),
            hybrid_max_steps=hybrid_max_steps,
            progress=progress,
        )
    except (InputError, PluginError) as error:  # this diagnosis stands, and says why the other is missing
        found.evidence["refined"] = refused(swaps, error)
        return found
    again.glitches_bridged = glitches  # it read the recordings as bridged here
    again.warnings = list(dict.fromkeys(shared_notes + _glitch_warnings(glitches, rate) + again.warnings))
    kept_diagnosis, tried = refined(found, again, swaps, settings.min_gain, why)
    kept_diagnosis.evidence["refined"] = tried
    kept_diagnosis.settings = dataclasses.replace(kept_diagnosis.settings, refine=given.refine)  # as asked
    kept_diagnosis.seconds = time.perf_counter() - t0
    return kept_diagnosis


def _bridge_glitches(recordings) -> tuple[list, list[dict]]:
    """The recordings with w's glitches bridged by straight lines (`glitch_runs`), and the runs of each that had any.

    A glitch is a run of a few samples that w jumps into and back out of,
    undriven: a tracker that lost its marker for a few frames, a logger that
    read 0 while its sensor dropped out. Left in, each is a large residual
    that no model of the plant can fit: it bends every fit and dilutes every
    gain, and the remainder reads it as unexplained. Each run is put on the
    straight line between the samples either side of it, as `--fill-gaps`
    fills a dropped frame (`DiagnoseSettings.bridge_glitches`).

    So is each run of samples a ``quality`` column (rig's: 1 measured, 0 not)
    marks 0 with measured samples either side (``"unmeasured"``): the tracker
    held w there, and a probe's 15 frames of a covered tip, held, turned an
    all-clear into "unexplained, 94 %, it follows the drive". A run at the
    record's start or end has no line to lie on: it stays as recorded
    (``"unmeasured_ends"``); like the others it weighs nothing in any fit or
    score (`lanes_problem`).
    """
    out, found = [], []
    for r in recordings:
        every = unmeasured_runs(r.extra.get("quality"))
        unmeasured = [(a, b) for a, b in every if a > 0 and b < r.n - 1]  # a sample either side: bridged
        ends = [run for run in every if run not in unmeasured]
        w = bridged(r.w, unmeasured) if unmeasured else r.w
        runs = glitch_runs(w, r.v_in)
        if runs:
            w = bridged(w, runs)
        if unmeasured or ends or runs:
            r = dataclasses.replace(r, w=w)
            entry: dict[str, Any] = {"recording": r.name, "runs": [[int(a), int(b)] for a, b in runs]}
            if unmeasured:
                entry["unmeasured"] = [[int(a), int(b)] for a, b in unmeasured]
            if ends:
                entry["unmeasured_ends"] = [[int(a), int(b)] for a, b in ends]
            found.append(entry)
        out.append(r)
    return out, found


def _escapes_warning(simulation, escaped: list[dict], n_screen: int) -> list[str]:
    """One sentence where a plug-in simulation's output was not finite at some of the points screened for
    the baseline's starts (`screen_starts`: its typical ranges), else none.

    A probe's plug-in gave NaN for tau > 2 s, inside its own typical range: the search stepped around it
    without a word. The library's own simulations are left out (finite over their constraints by design),
    and so are the LM steps that the fits refused: a trial step far outside the typical ranges may make an
    explicit integration escape (the examples' motor and oscillator do), which LM steps around by design.
    """
    own = user_simulation(simulation)  # a plug-in held at a fitted drive (--settle) too
    if own is None or not escaped:
        return []
    example = ", ".join(f"{k}={v:.4g}" for k, v in escaped[0].items())
    return [
        f"simulation {type(own).__name__}: its output was not finite (NaN or inf) at {len(escaped)} of "
        f"the {n_screen} points screened for the baseline's starts over its typical ranges (e.g. {example}), "
        "so no fit started there, and a better fit there may have been out of reach; if the system is defined "
        "there, simulate gives NaN or inf (a square root or log of a negative, a division by zero, a state that "
        "escapes): make it finite over its typical ranges, or narrow them (and its constraints) to where it is "
        "defined"
    ]


def _glitch_warnings(glitches: list[dict], rate: float) -> list[str]:
    """One sentence per recording whose glitches `_bridge_glitches` bridged."""
    out = []
    keep = "diagnose with --keep-glitches to fit them as recorded"
    for g in glitches:
        if g.get("unmeasured"):
            held = g["unmeasured"]
            count = sum(b - a + 1 for a, b in held)
            out.append(
                f"recording '{g['recording']}': w's {count} sample(s) of quality 0 inside the record ({len(held)} "
                f"run(s), the longest {max(b - a + 1 for a, b in held)} samples, the first at t = "
                f"{held[0][0] / rate:.4g} s), not measured there (a tracker held it), were bridged by straight "
                f"lines and left out of every fit and score; {keep}"
            )
        if g.get("unmeasured_ends"):
            edge = g["unmeasured_ends"]
            out.append(
                f"recording '{g['recording']}': w's {sum(b - a + 1 for a, b in edge)} sample(s) of quality 0 at "
                f"the record's {' and '.join('start' if a == 0 else 'end' for a, _ in edge)}, not measured there, "
                f"were left out of every fit and score; {keep}"
            )
        if not g["runs"]:
            continue
        lengths = sorted({b - a + 1 for a, b in g["runs"]})
        spread = f"{lengths[0]}–{lengths[-1]}" if len(lengths) > 1 else f"{lengths[0]}"
        out.append(
            f"recording '{g['recording']}': w's {len(g['runs'])} glitch(es), runs of {spread} samples that w jumps "
            f"into and back out of (the first at t = {g['runs'][0][0] / rate:.4g} s), were bridged by straight "
            "lines before any fit (a tracker that lost its marker, a sensor that dropped out); if the system "
            "flips and flips back by itself (a relay, a contact that chatters), diagnose with --keep-glitches "
            "(DiagnoseSettings(bridge_glitches=False))"
        )
    return out


#: A dimensionless readout gain farther than this factor from 1 puts the simulation's output on a scale
#: of its own (`model_warnings`).
GAIN_FACTOR = 1.2
#: A readout gain within this factor of a power of 1000 reads as a unit mismatch (mA for A).
UNIT_STEP = 1.1


def model_warnings(model: Model, frozen, rate: float | None = None) -> list[str]:
    """What about the final model's fit should not be taken at face value.

    A simulation parameter outside its plausible range ([`implausible`][]): the
    fit may have bent the simulation to take up an effect it lacks (a plug-in
    with a 0.1 s sensor lag: its shaft's damping fitted below its plausible
    range, and "no effect needed" at 1.3× the floor). A readout gain of no
    unit (the simulation's output in the recording's unit) far from 1: sizes
    in the simulation's output unit or its states' (an output effect's level,
    a state's map) are on the simulation's own scale, not the measured one;
    near a power of 1000, a unit mismatch (a battery user's drive in mA for a
    cell model in A); negative, the output upside down (their current's sign
    flipped), which the gain took up without a word. A fitted frequency at or
    above the Nyquist frequency of samples at `rate` ([`aliased`][]).
    """
    out = (
        implausible(
            model,
            frozen,
            ", or the fit bent the simulation to take up an effect it lacks (a lag, a friction): what the "
            "diagnosis says rests on a model that is not the system there",
        )
        + aliased(model, frozen, rate)
        + sub_sample(model, frozen, rate)
    )
    gain = model.readout.parameters().get("gain")
    if (
        gain is not None
        and model.units.get("gain") == "1"
        and (float(gain) < 0 or abs(math.log(abs(float(gain)) or 1e-300)) > math.log(GAIN_FACTOR))
    ):
        unit = unit_in(model.simulation.output_unit, getattr(model.simulation, "drive_unit", "V"))
        g = float(gain)
        said = [f"the readout's gain is {g:.4g} (w = {g:.4g}·y + offset)"]
        if g < 0:
            said.append(
                "the simulation's output y is upside down: y and w have opposite signs (a drive or a sensor "
                "wired or defined the other way: a current's direction, a displacement's axis)"
            )
        if abs(math.log(abs(g) or 1e-300)) > math.log(GAIN_FACTOR):
            who = "y" if g < 0 else "the simulation's output y"
            said.append(
                f"{who}, and every size in its unit ({unit}) or its states' (an output effect's level, a "
                f"state's map), is on the simulation's own scale, {1 / abs(g):.3g}× the measured one"
            )
            power = round(math.log10(abs(g)) / 3) * 3
            if power and abs(math.log10(abs(g)) - power) < math.log10(UNIT_STEP):
                said.append(
                    f"{abs(g):.3g} is near 10^{power}, the step between units (mA and A, mm and m): check the "
                    "drive's and w's units against those the simulation expects"
                )
            advice = (
                "to read them in the measured unit, fix the simulation's scale: freeze a parameter that "
                "sets it (frozen_by_default in the plug-in, docs/plugins.md)"
            )
            held = sorted(n for n in frozen if n in model.simulation.parameters())
            # the scale may be fixed already: then its value is off, or the fit bent to what it lacks
            if held:
                advice += (
                    f"; where one that sets it is fixed already ({', '.join(held)} here), the gain says that its "
                    f"fixed value is {abs(g):.3g}× off (a motor constant, a sensor's sensitivity from a datasheet), "
                    "or that the fit bent the simulation to take up an effect it lacks"
                )
            said.append(advice)
        out.append(said[0] + ": " + "; ".join(said[1:]))
    return out


def hybrid_fits(recordings, simulation, extended, problem, causes, settings, max_steps, progress) -> dict:
    """Hybrid model (simulation + D-MLP) without and with the named effects, held-out metrics."""
    from ..core._fit import fit
    from ..core._models import make_model
    from ..core._solvers import LevenbergMarquardt

    out: dict[str, Any] = {}
    variants = [("baseline", simulation)]
    if causes:
        variants.append(("extended", fitted_model(problem, extended.theta, causes).simulation))
    for key, sim in variants:
        stage(f"diagnose: hybrid model, {key}")
        if progress:
            print(f"diagnose: hybrid model, {key}", flush=True)
        result = fit(
            make_model("hybrid", simulation=sim),
            recordings,
            solver=LevenbergMarquardt(max_steps=max_steps),
            frozen=set(settings.frozen),
            split=settings.split,
            split_order=SPLIT_ORDER,
            blocks=settings.split_blocks,
            weight_decay=0.1,
            progress=progress,
        )
        out[key] = {
            "nmse": result.metrics["test"]["nmse_variance"],
            "nmse_eq18": result.metrics["test"]["nmse"],
            "fitting": result.metrics["test"]["fitting"],
            "parameters": result.parameters,
            "seconds": result.seconds,
        }
    if "extended" not in out:
        out["extended"] = out["baseline"]
    out["gain"] = out["baseline"]["nmse"] / out["extended"]["nmse"]
    return out
