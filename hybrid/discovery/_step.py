"""One step of `diagnose`'s stepwise search: every effect not yet named, on top of the current model.

Step 1 starts from the effect-free baseline; each later step from the model the
step before it extended. A step

1. fits every remaining effect switched on *in addition to* the named ones, as
   lanes of one compiled LM program (each refits the named effects too, where
   the shared problem has directions for them: `refitted`), warm-started from the current model and
   from design points screened jointly with a dead time, a loop or a mode
   (`hybrid.discovery._starts`; from the second step on, the design of the model
   extended so far);
2. refits the current model (no new effect) from every lane's end point: a
   lane can gain only because its start led the shared parameters out of the
   current model's local minimum, and the refit takes that gain away;
3. weighs each effect against the current model with the same rules at every
   step — material, held-out gain ≥ `min_gain`, BIC drop ≥ `min_bic_drop`,
   a residual no more correlated, and the gain holding against every fit of
   the current model as good on training data — so a later cause is judged
   *incrementally*.

The step's answer is the eligible effect with the largest held-out gain, or
none; `diagnose` stops at the first step without one.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable

import jax.numpy as jnp
import numpy as np

from ..core._levenberg_marquardt import LMSettings, LMState
from ..core._models import Model
from ..core._problem import Problem
from ..core._simulation import from_library
from ..util._errors import InputError, PluginError
from . import residual_tests as rt
from ._decision import choose_lane, equally_good_fits, evaluate_candidate, lane_effect
from ._diagnosis import Candidate, DiagnoseSettings, EquallyGoodFits, Lane
from ._effect_stack import EffectStack, drive_forces
from ._effects import AbstractEffect, StartContext, shown
from ._search import (
    best_lag,
    direction_count,
    finite_theta,
    fit_lanes,
    inside_signals,
    lane_count,
    lane_tangents,
    padding_lane,
    resume,
    search_problem,
    searched_effects,
    simulation_output,
    split_data,
    split_signals,
    theta_with_readout,
)
from ._starts import dead_times


@dataclasses.dataclass
class Search:
    """What every step shares: the data, the universal model, the settings."""

    problem: Problem
    model: Model
    simulation: object
    settings: DiagnoseSettings
    frozen: frozenset
    lm: LMSettings
    rate: float
    duration: float
    n_train: int
    n_val: int
    say: Callable[[str], None]
    n_lanes: int = 0
    larger: dict = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        if not self.n_lanes:
            self.n_lanes = lane_count(first_step_lanes(self.effects, self.rate, self.duration))

    @property
    def effects(self) -> tuple[AbstractEffect, ...]:
        """The effects the search can name, in the stack's order."""
        stack = self.model.simulation
        assert isinstance(stack, EffectStack)  # a search fits an EffectStack
        return searched_effects(stack)

    @functools.cached_property
    def onsets(self) -> tuple[int, ...]:
        """The delay's extra shifts around where w starts to follow the drive on the training part
        (`dead_times`): read from the data alone, once for every step."""
        return dead_times(*split_data(self.problem, "train"))

    def has_room(self, effects) -> bool:
        """Whether the shared problem has Jacobian directions for a lane fitting `effects` (names)."""
        assert self.problem.sim_tangents is not None  # a search problem always has its directions
        return direction_count(self.model, self.frozen, effects) <= self.problem.sim_tangents.shape[0]

    def problem_for(self, *effect_sets) -> Problem:
        """The shared problem where it has directions for a lane fitting each of `effect_sets`, else a larger one.

        The search's steps and refits stay within the shared problem
        (`refitted`); only the redundancy check (`drop_redundant`), with more
        causes kept than it has room for, needs a larger problem (its own
        programs). The final model's uncertainties take a problem of its own.
        """
        if all(self.has_room(e) for e in effect_sets):
            return self.problem
        n_effects = max(len(e) for e in effect_sets)
        if n_effects not in self.larger:
            self.larger[n_effects] = search_problem(self.model, self.problem.series, self.frozen, n_effects)[
                0
            ]
        return self.larger[n_effects]


def refitted(search: Search, present: tuple[str, ...], name: str | None = None) -> tuple[str, ...]:
    """The named effects (of `present`, in naming order) a lane refits beside `name`: all where they fit.

    A step's lanes share one problem (`Search.problem`), whose Jacobian has
    directions for the two effects with the most parameters (`SHARED_ROOM`).
    A lane refits every named effect beside its own where their parameters
    fit in them: at the third step, most sets. A later cause may undo an early
    name (hysteresis + drift seed 2 of `experiments/discrepancy.py`: backlash
    named first, drift second, hysteresis third with the backlash's play
    fitted to 0, and the backlash dropped). Where they do not, the lane holds
    the earliest named effects at the values that the step before fitted
    jointly, rather than compile a larger problem for a step that most
    diagnoses never reach (~10 s of XLA compiling on a 60 s recording).
    """
    own = (name,) if name is not None else ()
    return next((present[k:] for k in range(len(present)) if search.has_room(present[k:] + own)), ())


def _probe_context(rate: float, duration: float) -> StartContext:
    """The signal the lanes are counted on before any data is fitted (a two-sample ramp)."""
    ramp = np.array([-1.0, 1.0])
    return StartContext(signal=ramp, rate=rate, duration=duration, drive=ramp, measured=ramp, lag_samples=1)


def first_step_lanes(effects, rate: float, duration: float) -> int:
    """Lanes of the first step: every effect's starts and its screened ones (counts only)."""
    probe = _probe_context(rate, duration)
    return sum(len(e.starts(probe)) + e.n_screened for e in effects)


@dataclasses.dataclass(frozen=True)
class Step:
    """One step's outcome (`Diagnosis.steps`)."""

    current: Candidate
    """The model the step extended (step 1: the baseline), refitted if a lane's end point fits it better."""
    candidates: list[Candidate]
    """Every remaining effect's chosen lane, weighed against `current`."""
    chosen: Candidate | None
    """The eligible candidate with the largest held-out gain, or None."""
    chosen_val: float
    """`chosen`'s validation loss (nan if none)."""
    chosen_fits: list
    """θ of every lane fitting `chosen`'s effect: the next step's "as good on training" fits."""
    equally_good: EquallyGoodFits
    """The fits of `current` as good on training data; their least held-out error: a bar a gain must clear."""
    lanes: list[Lane]
    """Every lane of the step (not in report.json)."""
    joint_with: str | None = None
    """The effect `chosen` was named with, fitted jointly (`hybrid.discovery._joint`): the next step's cause."""
    nonfinite: dict = dataclasses.field(default_factory=dict)
    """Effects whose lanes met non-finite predictions (`nonfinite_lanes`): by name, starts moved and steps refused."""

    @property
    def cause(self) -> str | None:
        """The effect the step named, or None."""
        return self.chosen.name if self.chosen is not None else None

    @property
    def bar(self) -> float:
        """The held-out NMSE a candidate's gain is measured against by the step's last rule (`heldout_bar`)."""
        return heldout_bar(self.current, self.equally_good)


def heldout_bar(current: Candidate, equally_good: EquallyGoodFits) -> float:
    """The least held-out NMSE of `current` and of its fits as good on training (nan ones ignored).

    A better fit of the simulation alone, which any candidate's lane may find,
    clears no effect: a candidate's gain must also hold over this bar.
    """
    return min(current.heldout.nmse, equally_good.heldout_nmse_min)


#: A start whose simulation escapes (non-finite output) is tried again this much nearer to its
#: effect's defaults, at most `RETRIES` times, then at the defaults.
TAME, RETRIES = 0.1, 3


def _finite_lanes(problem, stack, starts, departures, readout, frozen) -> tuple[list, list[bool]]:
    """θ of each start, a start whose simulation is not finite pulled towards its effect's defaults.

    A softening spring started too soft, or a force too large for the fitted
    dynamics, makes the simulation escape to infinity; that lane would be lost
    (and its NaN would reach the least-squares gain). Its departure from the
    effect's defaults is scaled by `TAME` until the output is finite, and at
    worst the lane starts at the defaults. Also returns, per start, whether it
    was moved so.
    """
    w = problem.recorded(problem.target("train"), "train")
    lanes, moved = [], []
    for start, (effect, values, active) in zip(starts, departures):
        theta, simulation = finite_theta(problem, start, readout, frozen, w), start
        moved.append(theta is None)
        for scale in [TAME**k for k in range(1, RETRIES + 1)] + [0.0]:
            if theta is not None:
                break
            base = effect.defaults
            tamed = {n: base[n] + scale * (v - base[n]) if n in base else v for n, v in values.items()}
            simulation = stack.replace(**tamed).with_active(active)
            theta = finite_theta(problem, simulation, readout, frozen, w)
        # Not finite even at the defaults: gain 1 and offset 0; LM stops it at once (its cost is not finite).
        lanes.append(
            theta if theta is not None else theta_with_readout(problem, simulation, readout, frozen, 1.0, 0.0)
        )
    return lanes, moved


def nonfinite_lanes(labels, moved, states, skip=()) -> dict:
    """Per effect, where its lanes met predictions that are not finite (NaN or inf).

    ``starts_moved``: its starts whose simulation was not finite, pulled towards
    the effect's defaults (`_finite_lanes`); ``steps_refused``: the LM trial
    steps its lanes refused because the cost there was not finite
    (`LMState.nonfinite`), of ``steps`` tried. The search cannot fit an effect
    where its predictions are not finite: a parameter region where the
    simulation escapes (a spring too soft), or a plug-in's apply that is not
    defined over all of its constraints' range. Effects that met none are left out.
    """
    refused, tried = np.asarray(states.nonfinite), np.asarray(states.step)
    out = {}
    for name in dict.fromkeys(lab for lab in labels if lab != "none" and lab not in skip):
        idx = [j for j, lab in enumerate(labels) if lab == name]
        starts_moved = sum(bool(moved[j]) for j in idx if j < len(moved))
        steps_refused = int(refused[idx].sum())
        if starts_moved or steps_refused:
            out[name] = {
                "starts_moved": starts_moved,
                "starts": len(idx),
                "steps_refused": steps_refused,
                "steps": int(tried[idx].sum()),
            }
    return out


def nonfinite_warnings(steps, effects) -> list[str]:
    """One sentence per plug-in effect whose lanes met non-finite predictions in any step (`nonfinite_lanes`).

    The library's own effects are left out (the built-ins, and those it makes for
    a plug-in's states, such as a state's limit): theirs is a region where the
    simulation escapes (a spring started too soft, a limit on a velocity), which
    the search steps around by design, and whose advice no user could follow.
    """
    out = []
    for effect in effects:
        tallies = [step.nonfinite[effect.name] for step in steps if effect.name in step.nonfinite]
        if from_library(effect) or not tallies:
            continue
        total = {k: sum(t[k] for t in tallies) for k in tallies[0]}
        where = []
        if total["starts_moved"]:
            where.append(
                f"{total['starts_moved']} of its {total['starts']} starts (moved towards its defaults)"
            )
        if total["steps_refused"]:
            where.append(f"{total['steps_refused']} of the {total['steps']} steps its fits tried (refused)")
        out.append(
            f"effect {type(effect).__name__} ({effect.name}): its predictions were not finite (NaN or inf) at "
            f"{' and at '.join(where)}, so the search could not fit it there and a better fit beyond may have "
            "been out of reach; if the effect is defined there, its apply gives NaN or inf (a square root or "
            "log of a negative, a division by zero): make apply finite over all of its constraints' range, "
            "or narrow the constraints to where it is defined"
        )
    return out


def race(s: Search, problem, actives, tangents, lanes, labels) -> tuple[LMState, list[int]]:
    """The lanes' final LM states, and the lanes culled in the first round: a race in up to three rounds.

    1. Where an effect has more lanes than it keeps (`AbstractEffect.n_kept`),
       every lane takes `start_steps` LM steps, and of each such effect's lanes
       only the `n_kept` with the least validation loss go on; the others keep
       that result. Their starts differ in one size (a dead zone's width, a
       play's), and a few steps tell which basin the data favour. Where more
       effects on the drive and the output race than `racing_effects`, the same
       round ranks them by their best lane and only that many go on (every
       lane of the others is culled); those inside the dynamics always go on.
    2. Every lane still going runs until `race_patience` accepted steps bring
       no clearly better validation loss.
    3. Of each effect's lanes, the leaders (the least validation loss, and
       every lane within reach of it: (1 + `patience_rtol`) to the power of the
       patience left, 1.5 % by default) go on where they stopped until
       `patience` do: the steps they would have taken with that patience from
       the start, to the last bit (`resume`). The other lanes keep their
       result. Most of a lane's steps are its patience's tail after its best
       point; a lane that cannot stand for its effect no longer runs it to the
       end. A lane that stopped on its tolerances or its `max_steps` is done
       either way.

    `race_patience` 0 (or ≥ `patience`): every lane (of those the first round
    kept) runs to `patience`.
    """
    settings = s.settings
    racing = 0 < settings.race_patience < settings.patience
    short = settings.race_patience if racing else settings.patience
    starts: jnp.ndarray | LMState = jnp.stack(lanes)
    culled: list[int] = []
    keep = {e.name: e.n_kept for e in s.effects if e.n_kept and labels.count(e.name) > e.n_kept}
    # Effects inside the dynamics always race: a limit acts only where its state reaches it, a fed-back
    # force only through the dynamics, and 6 steps do not rank them (`experiments/inside_effects.py`
    # overflow seed 1, a tank's overflow: limit_h2 named at 2.59× with them in the field; racing on,
    # limit_h1 at 111×).
    inside = {e.name for e in s.effects if e.place == "inside"}
    names = list(dict.fromkeys(lab for lab in labels if lab not in ("none", *inside)))
    field = settings.racing_effects
    if (keep or 0 < field < len(names)) and settings.start_steps > 0:
        first = fit_lanes(problem, actives, tangents, starts, s.lm, short, steps=settings.start_steps)
        vals = np.where(np.isfinite(first.best_val), first.best_val, np.inf)
        for name, n in keep.items():
            idx = [j for j, lab in enumerate(labels) if lab == name]
            culled += sorted(idx, key=lambda j: vals[j])[n:]
        if keep:
            s.say(f"{len(culled)} lanes culled after {settings.start_steps} steps")
        if 0 < field < len(names):
            best = {n: min(vals[j] for j, lab in enumerate(labels) if lab == n) for n in names}
            left = sorted(names, key=lambda n: best[n])[field:]  # stable: the stack's order breaks ties
            culled += [j for j, lab in enumerate(labels) if lab in left and j not in culled]
            kind = "pairs" if any("+" in n for n in left) else "effects"  # the joint fit races pairs
            s.say(
                f"{len(left)} {kind} left the race after {settings.start_steps} steps, trailing the "
                f"{field} leading{' and those inside the dynamics' if inside & set(labels) else ''}: "
                f"{', '.join(left)}"
            )
        starts = resume(first, [j for j in range(len(labels)) if not first.done[j] and j not in culled])
    heat = fit_lanes(problem, actives, tangents, starts, s.lm, short)
    if not racing:
        return heat, culled
    vals = np.asarray(heat.best_val)
    # Stopped by the short patience, not by its tolerances or its `max_steps`: it may go on (a culled
    # lane never: with `race_patience` ≤ `start_steps` its patience may have stopped it in the first round).
    going = (np.asarray(heat.since_best) >= settings.race_patience) & (np.asarray(heat.step) < s.lm.max_steps)
    going[culled] = False
    reach = (1.0 + settings.patience_rtol) ** (settings.patience - settings.race_patience)
    leaders: list[int] = []
    for name in dict.fromkeys(lab for lab in labels if lab != "none"):
        idx = [j for j, lab in enumerate(labels) if lab == name and np.isfinite(vals[j])]
        if idx:  # still in the race: a lane that the rest of the patience could bring level with the
            # best, were each of its steps to gain just under a clear improvement (`patience_rtol`)
            leaders += [j for j in idx if going[j] and vals[j] <= np.min(vals[idx]) * reach]
    if not leaders:
        return heat, culled
    s.say(f"{len(leaders)} leading lanes on to a patience of {settings.patience}")
    return fit_lanes(problem, actives, tangents, resume(heat, leaders), s.lm, settings.patience), culled


def search_step(
    search: Search,
    current: Candidate,
    current_val: float,
    current_fits: list,
    present: tuple[str, ...],
    extra: dict | None = None,
) -> Step:
    """Every effect not in `present` added to `current` (which has exactly `present` switched on).

    `extra`: more lanes, θ (the search's layout) by effect name: a joint fit the
    effect's lanes also start from (`hybrid.discovery._joint`).
    """
    s, settings = search, search.settings
    effects = s.effects
    names = [e.name for e in effects]
    problem = s.problem
    assert problem.sim_tangents is not None  # a search problem always has its directions
    n_rows = int(problem.sim_tangents.shape[0])
    active_cur = np.asarray(current.active, float)
    theta_cur = current.theta
    # A lane refits the named effects that the shared problem has directions for (`refitted`).
    cur_tangents = lane_tangents(s.model, s.frozen, refitted(s, present), n_rows)
    cur_model = problem.model(jnp.asarray(theta_cur))
    stack = cur_model.simulation
    assert isinstance(stack, EffectStack)  # a search fits an EffectStack

    bare = stack.with_active(np.zeros_like(active_cur))  # the inner simulation alone
    s_train = simulation_output(problem, bare, cur_model.readout, s.frozen, "train")
    v_tr, w_tr, w_hat_tr = split_signals(problem, theta_cur, active_cur, "train")
    lag = best_lag(w_tr, w_hat_tr, max_lag=20)
    f, psd = rt.spectrum(w_tr - w_hat_tr, s.rate)
    band = f >= 0.5
    peak = float(f[band][np.argmax(psd[band])]) if band.any() else None
    readout = cur_model.readout.parameters()
    gain, offset = float(readout.get("gain", 1.0)), float(readout.get("offset", 0.0))
    base = dict(
        rate=s.rate,
        duration=s.duration,
        drive=v_tr,
        measured=(w_tr - offset) / gain if gain != 0 and np.isfinite(gain) else None,
        lag_samples=lag,
        residual_peak_hz=peak,
        dead_times=s.onsets,
        problem=s.problem,  # the screens read its data alone: every step's screens share their programs
        simulation=s.simulation,
        frozen=s.frozen,
    )
    into = inside_signals(problem, stack, [e for e in effects if e.place == "inside"], "train")
    # an inside feedback's starts are sized against the force the drive exerts (a heater's power)
    pushes = {**base, "drive": drive_forces(stack, v_tr)}
    context = {
        e.name: StartContext(
            signal={"drive": v_tr, "output": s_train}.get(e.place, into.get(e.name, s_train)),
            **(pushes if e.place == "inside" else base),
        )
        for e in effects
    }
    screened = {}
    # The screens design the simulation jointly with one effect. From the second step on they
    # screen the model extended so far (the named effects on, at their fitted values): its fit has
    # absorbed part of the next effect (a dead time as slower stages), and that effect's lanes
    # started from it alone stay in its basin (delay + back-relaxation draws of
    # `experiments/discrepancy.py`: the delay was never named; seed 0's stayed at its start, 0.75 samples).
    # An inside effect's screen needs the bare state-space form: first step only.
    screening = [
        e for e in effects if e.n_screened and e.name not in present and not (present and e.place == "inside")
    ]
    if screening:
        s.say(f"screening starts for the {', '.join(e.name for e in screening)} candidates")
        # The first step screens the stack with every effect off (`bare`: the inner simulation's output,
        # exactly: an effect that is off is skipped, not multiplied by 0), a later one the model extended
        # so far: one pytree structure, so each screen compiles once per diagnosis, not once for the
        # first step and again for the second (a diagnosis that names an effect: ~4 s of XLA compiling).
        extended = stack.with_active(active_cur) if present else bare
        for e in screening:
            inside = e.place == "inside"  # its screen reads the bare state-space form's states
            at = context[e.name] if inside else dataclasses.replace(context[e.name], simulation=extended)
            screened[e.name] = e.screened_starts(at)[: e.n_screened]
    starts, actives, labels, tangents, departures = [], [], [], [], []
    for i, effect in enumerate(effects):
        name = effect.name
        if name in present:
            continue
        lane = lane_tangents(s.model, s.frozen, refitted(s, present, name) + (name,), n_rows)
        own = effect.starts(context[name])
        counted = len(effect.starts(_probe_context(s.rate, s.duration)))
        if len(own) > counted:  # the lanes were counted on the probe (`first_step_lanes`): one program
            raise PluginError(
                f"effect {type(effect).__name__}: starts(context) gave {len(own)} starts on this recording "
                f"but {counted} on the probe signal the search's lanes are counted on: return as many starts "
                "whatever the data (e.g. a fixed list of fractions of the signal's range; see docs/effects.md)",
                plugin=type(effect),
            )
        for values in own + screened.get(name, []):
            active = active_cur.copy()
            active[i] = 1.0
            try:
                start = stack.replace(**values)
            except InputError as error:  # a plug-in's start out of its own ranges: say which method gave it
                raise PluginError(
                    f"effect {type(effect).__name__}: a start from starts(context) or screened_starts(context) "
                    f"is refused: {error}; return values within its constraints",
                    plugin=type(effect),
                ) from None
            starts.append(start.with_active(active))
            departures.append((effect, values, active))
            actives.append(active)
            labels.append(name)
            tangents.append(lane)
    n_lanes = s.n_lanes
    if len(starts) > n_lanes:  # the lanes were counted on a probe signal (`first_step_lanes`)
        raise InputError(
            f"the effects gave {len(starts)} starts on this recording but {n_lanes} on a probe signal: an "
            "effect's starts(context) must give as many starts whatever the data (see docs/effects.md)"
        )
    lanes, moved = _finite_lanes(problem, stack, starts, departures, cur_model.readout, s.frozen)
    for name, thetas in (extra or {}).items():
        active = active_cur.copy()
        active[names.index(name)] = 1.0
        lane = lane_tangents(s.model, s.frozen, refitted(s, present, name) + (name,), n_rows)
        for theta in thetas[: max(n_lanes - len(lanes), 0)]:
            lanes.append(jnp.asarray(theta))
            actives.append(active)
            labels.append(name)
            tangents.append(lane)
    while len(lanes) < n_lanes:  # one lane count for every step: one compiled program
        lanes.append(padding_lane(theta_cur))  # stops at once: no LM steps spent on it
        actives.append(active_cur)
        labels.append("none")
        tangents.append(cur_tangents)
    added = " + ".join(present) + " + " if present else ""
    s.say(f"{added}each of {len(set(labels) - {'none'})} effects, {len(labels)} lanes")
    states, culled = race(s, problem, np.stack(actives), np.stack(tangents), lanes, labels)
    vals = np.asarray(states.best_val)
    nonfinite = nonfinite_lanes(labels, moved, states, skip=present)
    cand_thetas = states.best_theta

    # The current model refitted from where every lane ended (a lane the race culled after its
    # first steps ended near its start, beside its effect's better lane: not refitted).
    s.say(f"{'baseline' if not present else ' + '.join(present)} refitted from every candidate's end point")
    refit_from = np.array(cand_thetas, copy=True)
    for j in culled:
        refit_from[j] = padding_lane(refit_from[j])  # stops before its first step
    restates = fit_lanes(
        problem,
        np.tile(active_cur, (n_lanes, 1)),
        np.stack([cur_tangents] * n_lanes),
        refit_from,
        s.lm,
        settings.effect_free_patience,
    )
    revals = np.asarray(restates.best_val)
    current_name = present[-1] if present else "none"
    if np.nanmin(revals) < current_val:
        j = int(np.nanargmin(revals))
        current_val = float(revals[j])
        current = evaluate_candidate(
            problem,
            restates.best_theta[j],
            active_cur,
            current_name,
            s.n_train,
            current.n_parameters,
            settings.materiality,
            s.frozen,
            present[:-1],
        )
        current.reasons.append(f"refitted from the {labels[j]} candidate's end point")
        current.validation_loss = current_val

    candidates, chosen_lanes, lanes_of = [], set(), {}
    for name in names:
        if name in present:
            continue
        idx = [j for j, lab in enumerate(labels) if lab == name]
        lanes_of[name] = idx

        def is_material(j, name=name):
            return lane_effect(problem, cand_thetas[j], actives[j], name, settings.materiality)[0]

        if not np.isfinite(vals[idx]).any():  # no lane could take a step: the effect is broken here
            effect = effects[names.index(name)]
            raise PluginError(
                f"effect {type(effect).__name__}: every start of its fit gives non-finite predictions "
                "(NaN or inf) on this recording, though it was finite on the probe signal: its apply is not "
                "finite on this recording's signal (a log, a square root or a division of a signal that "
                "reaches zero?): fix apply",
                plugin=type(effect),
            )
        j = choose_lane(idx, vals, is_material, s.n_val)
        chosen_lanes.add(j)
        cand = evaluate_candidate(
            problem,
            cand_thetas[j],
            actives[j],
            name,
            s.n_train,
            current.n_parameters + len(effects[names.index(name)].constraints),
            settings.materiality,
            s.frozen,
            present,
        )
        cand.validation_loss = float(vals[j])
        cand.raced = not set(idx) <= set(culled)  # every lane culled: its effect left the race
        candidates.append(cand)

    equally_good = equally_good_fits(
        problem,
        list(current_fits) + list(restates.best_theta),
        active_cur,
        current.train_rss,
        s.n_train,
        settings.min_bic_drop,
    )
    weigh(candidates, current, equally_good, settings)
    eligible = [c for c in candidates if c.eligible]
    chosen = max(eligible, key=lambda c: c.gain) if eligible else None
    return Step(
        current=current,
        candidates=candidates,
        chosen=chosen,
        chosen_val=chosen.validation_loss if chosen else float("nan"),
        chosen_fits=[cand_thetas[j] for j in lanes_of[chosen.name]] if chosen else [],
        equally_good=equally_good,
        nonfinite=nonfinite,
        lanes=[
            Lane(
                effect=labels[j],
                step=len(present) + 1,
                validation_loss=float(vals[j]),
                chosen=j in chosen_lanes,
                theta=np.asarray(cand_thetas[j]),
                active=np.asarray(actives[j]),
            )
            for j in range(len(labels))
            if labels[j] != "none"
        ],
    )


def weigh(candidates, current: Candidate, equally_good: EquallyGoodFits, settings: DiagnoseSettings) -> None:
    """Set each candidate's gain, ΔBIC and eligibility against `current` (the model it extends)."""
    bar = heldout_bar(current, equally_good)
    for cand in candidates:
        cand.gain = current.heldout.nmse / max(cand.heldout.nmse, 1e-300)
        cand.delta_bic = cand.bic - current.bic
        # Whiter: the residual's autocovariances at lags ≥ 1 (Q scaled by the squared
        # variance ratio) no larger than the current model's. Q alone compares correlations:
        # when both residuals are far from white (Q in the thousands), an extension that
        # removes most of the error can leave a smaller residual as correlated, relative
        # to its own size, as before. Or white already: a residual of isolated
        # spikes (missed step responses) can pass a whiteness test its extension fails.
        shrink = cand.ljung_box["variance"] / max(current.ljung_box["variance"], 1e-300)
        correlated = cand.ljung_box["Q"] * shrink**2
        whiter = correlated <= max(current.ljung_box["Q"], rt.white_limit(cand.ljung_box["lags"]))
        first = current.name == "none"
        model, fit = (
            ("the baseline", "an effect-free fit") if first else ("the model before it", "a fit without it")
        )
        checks = [
            (cand.material, f"not material: {cand.materiality}"),
            (
                cand.gain >= settings.min_gain,
                f"held-out gain {shown(cand.gain, settings.min_gain, 2)} < {settings.min_gain}",
            ),
            (
                cand.delta_bic <= -settings.min_bic_drop,
                f"ΔBIC {cand.delta_bic:.1f} > −{settings.min_bic_drop}",
            ),
            (
                whiter,
                f"held-out residual more correlated than {model}'s: Q {correlated:.0f} in "
                f"{model}'s units > {current.ljung_box['Q']:.0f}",
            ),
            (
                bar >= current.heldout.nmse or bar / max(cand.heldout.nmse, 1e-300) >= settings.min_gain,
                f"{fit} as good on training reaches held-out NMSE {bar:.3g}: "
                f"gain over it {bar / max(cand.heldout.nmse, 1e-300):.2f} < {settings.min_gain}",
            ),
        ]
        cand.eligible = all(ok for ok, _ in checks)
        cand.reasons += [why for ok, why in checks if not ok]
