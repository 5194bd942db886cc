"""`fit`: physical parameters and network weights fitted jointly, end to end.

Solvers (objects, their options as fields: [`hybrid.core._solvers`][]):

- [`LevenbergMarquardt`][hybrid.LevenbergMarquardt] (default): on the structured Jacobian
  ([`hybrid.core._levenberg_marquardt`][]), several starts `vmap`-ed in one program.
- [`OptimistixLM`][hybrid.OptimistixLM]: `optimistix.LevenbergMarquardt` on the flattened
  parameters, Jacobian by autodiff of the whole model — fine for the physics-only model
  (a handful of parameters), slow for the D-MLP models. It returns its final
  iterate (validation only picks among starts).
- [`Adam`][hybrid.Adam]: `optax.adam` on ½‖r‖², with the same validation bookkeeping.

The training split drives the optimiser; the validation split picks the best
iterate of each start and the best start; the test split is only reported.
The D-MLP's fixed input/output scalings are those of start 0 for every start.
"""

from __future__ import annotations

import dataclasses
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..data._header_units import unit_kind
from ..data._recording import in_shared_units
from ..util._errors import InputError, PluginError
from ..util._programs import FIT_PROGRAMS
from ..util._watchdog import stage
from ._arguments import as_names, as_recordings, check_model, check_seed
from ._level_limit import level_limits, limit_sentence
from ._levenberg_marquardt import LMSettings, lm_init, lm_run
from ._metrics import metrics as compute_metrics
from ._models import Model
from ._parameters import at_bound_said
from ._problem import Problem, Series, robust_rms, robust_std, segment_ids, series_from_recording
from ._readout import WindowedMLP
from ._result import FitResult, drive_outside_range, fit_warnings, one_frequency_drive, user_simulation
from ._screen import screened_starts
from ._simulation import unit_in, unit_suffix
from ._solvers import (
    SOLVERS as SOLVERS,
    AbstractSolver,
    Adam,
    LevenbergMarquardt,
    OptimistixLM,
    resolve_solver,
)

#: A training part whose drive's spread is below this fraction of the whole recording's is at rest.
REST_FRACTION = 0.01


def check_training_drive(series, recordings, blocks: int = 1, fix: str | None = None) -> None:
    """Refuse a training part whose drive is at rest (a record that starts quiet, split contiguously).

    The drive's standard deviation over the training samples, pooled over the
    recordings, below `REST_FRACTION` of its deviation over every sample: the
    dynamics are never excited where the model learns, and a fit would end at its
    start values with a misleading "plateau" warning. `fix`: what the message
    advises (default: `fit`'s blocks, or trimming the quiet start).
    """
    train = np.concatenate([np.asarray(s.v_in)[a:b] for s in series for a, b in s.segments_of("train")])
    whole = np.concatenate([np.asarray(s.v_in) for s in series])
    if len(train) and np.std(train) < REST_FRACTION * np.std(whole):
        where = "; ".join(
            f"{r.name}: samples {', '.join(f'{a}-{b - 1}' for a, b in s.segments_of('train'))}"
            for r, s in zip(recordings, series)
        )
        more = max(5, 2 * int(blocks))
        if fix is None:
            fix = (
                f"Cut each recording into blocks so that every part spans it (hybrid fit --blocks {more}; "
                f"fit(..., blocks={more})), or trim the quiet start"
            )
        raise InputError(
            f"the drive is at rest in the training part ({where}; its spread there is "
            f"{100 * np.std(train) / np.std(whole):.2g} % of the recording's): nothing there excites the dynamics. "
            + fix
        )


def fit(
    model: Model,
    recordings,
    *,
    solver: AbstractSolver | str = LevenbergMarquardt(),
    starts: int = 1,
    screen: int = 0,
    frozen=None,
    split=(0.3, 0.5, 0.2),
    split_order=("train", "test", "validation"),
    blocks: int = 1,
    weight_decay: float = 0.0,
    perturbation: float = 0.5,
    seed: int = 0,
    progress: bool = True,
    report_every: int = 10,
    stop=None,
    max_steps: int | None = None,
    patience: int | None = None,
    learning_rate: float | None = None,
) -> FitResult:
    """Fit `model` to one or several recordings of the same strip.

    **Arguments:**

    - `model`: starting model (e.g. from [`hybrid.make_model`][]); start 0 begins
      exactly there, the others from fresh network weights and physical
      parameters perturbed by `perturbation` (std of the unconstrained value).
    - `recordings`: a Recording or a list of them; each is split contiguously.
    - `solver`: a solver object with its options: [`LevenbergMarquardt`][hybrid.LevenbergMarquardt]
      (default; `max_steps`, `patience`, …), [`Adam`][hybrid.Adam] (`max_steps`,
      `learning_rate`) or [`OptimistixLM`][hybrid.OptimistixLM]. The strings ``"lm"``,
      ``"optimistix"``, ``"adam"`` are deprecated (a `DeprecationWarning`).
    - `starts`: number of starts (vmapped together for `LevenbergMarquardt` and `Adam`).
    - `screen`: 0 (default), or the points of a design screened for the starts: a
      scrambled Sobol design over the simulation's typical ranges (`AbstractSimulation.typical_ranges`;
      the model's own values are its first point), each simulated once with the
      readout's gain and offset by least squares; the `starts` best by training
      error are the starts, each with its own network weights and no perturbation
      (`hybrid.core._screen`). For a simulation whose values may lie far from
      the system's (a new strip, a plug-in's defaults): from the paper's values LM
      can stay on the RC network's plateaus. Parameters without a typical range,
      and frozen ones, keep their values; starts beyond the design's points are
      perturbed as without it.
    - `frozen`: parameter names kept at their starting values (e.g. ``{"xi_h"}``;
      ``"network"`` freezes all D-MLP weights). None (the default): the simulation's
      `frozen_by_default`, as on the command line and in `diagnose`; ``()`` frees all.
    - `split`, `split_order`: fractions and order of the contiguous splits
      (paper: train 30 %, test 50 %, validation 20 %).
    - `blocks`: cut each recording into this many equal chunks and split each
      chunk by `split` (1: the paper's contiguous split; see
      `hybrid.core._problem.series_from_recording`).
    - `weight_decay`: μ, ridge penalty ½ μ ‖θ_network‖² on black-box readout weights
      (D-MLP); residuals are in units of the training std of w, so μ is relative
      to one sample's squared error. 0 disables it.
    - `seed`: seeds the extra starts.
    - `progress`: show a progress bar on stderr, where stderr is a terminal.
    - `report_every`: iterations between progress reports / history entries.
    - `stop`: optional function of no arguments, called between LM steps (between
      chunks of `report_every` steps for Adam; never inside a compiled step). When it
      returns true the fit ends there and returns what it has: each start's best
      iterate so far (by validation loss, never worse than its start), with
      `FitResult.stopped` true. ``hybrid fit`` passes one that watches SIGINT,
      SIGTERM and ``--time-limit``.
    - `max_steps`, `patience`, `learning_rate`: deprecated; each sets that field of
      `solver` (``solver=hybrid.LevenbergMarquardt(max_steps=...)``), with a
      `DeprecationWarning`, and gives the same fit.

    **Returns:** a [`FitResult`][].
    """
    t_start = time.perf_counter()
    solver = resolve_solver(
        solver, "hybrid.fit", max_steps=max_steps, patience=patience, learning_rate=learning_rate
    )
    if not isinstance(starts, int) or starts < 1:
        raise InputError(f"starts must be a positive integer, got {starts!r}")
    model = check_model(model, "fit")
    recordings = as_recordings(recordings, "fit")  # a path is loaded; anything else is refused
    recordings = in_shared_units(recordings, "fit")  # one model fits them: one scale
    frozen = as_names(
        default_frozen(model) if frozen is None else frozen, "fit", "frozen", model.parameter_names
    )
    seed = check_seed(seed, "fit")
    for recording in recordings:
        recording.check_length(
            model.readout.window, f"the model's input window ({model.readout.window} samples)"
        )
        recording.check_signals()  # a constant drive or w: refused, not fitted to its start values
    # Its programs depend on each recording's length: a script fitting many lengths in one process
    # keeps those of the last few (`hybrid.util._programs.FIT_PROGRAMS`), not of every one.
    FIT_PROGRAMS.admit(fit_shape_key(model, recordings, starts, solver))
    series = [series_from_recording(r, split, split_order, blocks) for r in recordings]
    train_w = np.concatenate([np.asarray(s.target("train")) for s in series])
    if not np.ptp(train_w) > 0:
        raise InputError(
            "the training part of the recording(s) has constant w: "
            "there is nothing to fit (check the displacement column)"
        )
    check_training_drive(series, recordings, blocks)

    # Fit in units where w and v_in are O(1), so that the result does not depend on the
    # recording's units (LM's damping λI and the gain's Jacobian column do otherwise).
    w_unit, v_unit = fit_units(model, series, train_w)
    series = [Series(s.v_in / v_unit, s.w / w_unit, s.dt, s.segments) for s in series]
    given = model
    model = Model(
        model.simulation, model.readout.rescaled(1.0 / v_unit, 1.0 / w_unit), model.kind, model.signal_units
    )

    if not isinstance(screen, int) or isinstance(screen, bool) or screen < 0:
        raise InputError(f"screen must be 0 or a positive number of design points, got {screen!r}")
    bases = [model]
    if screen:
        stage(f"fit: screening {screen} designs of the simulation's parameters for {starts} start(s)")
        points = screened_starts(
            Problem(model, series, frozen, weight_decay),
            model.simulation,
            starts,
            max(screen, starts),
            frozen,
        )
        bases = [dataclasses.replace(model, simulation=model.simulation.replace(**p)) for p in points]
    initial = [  # the screened points as they are; the starts beyond them perturbed (start 0 never is)
        start_model(bases[i], i, seed, frozen, 0.0, series)
        if i < len(bases)
        else start_model(model, i, seed, frozen, perturbation, series)
        for i in range(starts)
    ]
    problem = Problem(initial[0], series, frozen, weight_decay)
    thetas = jnp.stack([problem.flatten(m, frozen) for m in initial])

    if stop is not None and not callable(stop):
        raise InputError(f"stop must be a function of no arguments that returns True to stop, got {stop!r}")
    stopped = False
    if isinstance(solver, LevenbergMarquardt):
        best, history, per_start, stopped, curvature = _run_lm(
            problem, thetas, solver.lm_settings(), progress, report_every, stop
        )
    elif isinstance(solver, Adam):
        curvature = None
        best, history, per_start, stopped = _run_adam(
            problem, thetas, solver.max_steps, solver.learning_rate, progress, report_every, stop
        )
    elif isinstance(solver, OptimistixLM):
        curvature = None
        best, history, per_start = _run_optimistix(
            problem, thetas, solver.max_steps, solver.rtol, solver.atol
        )
    else:
        raise InputError(
            f"hybrid.fit has no runner for {type(solver).__name__}: "
            "use hybrid.LevenbergMarquardt(), hybrid.Adam() or hybrid.OptimistixLM()"
        )

    losses = np.array([s["validation_loss"] for s in per_start], dtype=np.float64)
    if not np.isfinite(losses).any():  # every start's predictions non-finite: no step could move it
        raise non_finite_error(given.simulation, recordings)
    best_start = int(np.nanargmin(losses))
    fitted = problem.model(best[best_start])
    fitted = Model(
        fitted.simulation,
        readout_back(fitted.readout, given.readout, frozen, v_unit, w_unit),
        fitted.kind,
        recording_units(recordings) or given.signal_units,  # its parameters' units are those of the data
    )
    result_metrics = _metrics_by_split(problem, best[best_start], split_order)  # every metric is unit-free
    units = unit_labels(fitted, recordings)
    unpinned, idle = (
        unpinned_warnings(curvature[best_start], fitted, frozen, units) if curvature is not None else ([], [])
    )
    settings = {
        **solver.record(),  # "solver" (its name) and its options: max_steps, patience, learning_rate, ...
        "starts": starts,
        "screen": screen,
        "frozen": sorted(frozen),
        "split": dict(zip(split_order, map(float, split))),
        "blocks": blocks,
        "seed": seed,
        "perturbation": perturbation,
        "weight_decay": problem.weight_decay,
        "n_parameters": int(thetas.shape[1]),
        "n_residuals": int(problem.target("train").shape[0]),
        "recordings": [r.metadata.get("source", "") for r in recordings],
    }
    return FitResult(
        model=fitted,
        parameters={k: float(v) for k, v in fitted.parameters().items()},
        units=units,
        metrics=result_metrics,
        history=history,
        starts=per_start,
        best_start=best_start,
        settings=settings,
        seconds=time.perf_counter() - t_start,
        warnings=[note for r in recordings for note in r.notes]
        + fit_warnings(
            initial[best_start],
            fitted,
            frozen,
            per_start[best_start],
            result_metrics.get("train", {}).get("nmse_variance"),
            int(problem.target("train").shape[0]),
            min(r.rate for r in recordings),
            idle,  # a parameter the prediction does not depend on: said so (`unpinned_warnings`), not "unmoved"
        )
        + clipped_warnings(
            problem, best[best_start], split_order, w_unit, (recording_units(recordings) or ("",))[0]
        )
        + immaterial_effects(fitted, recordings)
        + effects_of_time(fitted, frozen, blocks)
        + no_better_than_the_mean(result_metrics)
        + drive_outside_range(
            fitted.simulation, [r.v_in for r in recordings], (recording_units(recordings) or ("", ""))[1]
        )
        + one_frequency_drive([(r.v_in, r.rate) for r in recordings])
        + unit_mismatch(recordings, fitted.simulation)
        + unpinned,
        stopped=stopped,
    )


#: The blocks `hybrid fit` cuts a recording into when its model holds an effect of time (`effects_of_time`): those
#: `hybrid diagnose` fits with (`DiagnoseSettings.blocks`).
TIME_EFFECT_BLOCKS = 3


def time_effect_names(model: Model, frozen=()) -> list[str]:
    """The effects of `model`'s effect stack that are functions of time (`of_time`: a drift, a baseline's
    wander), switched on and with a parameter free; [] for a model without effects."""
    stack = model.simulation
    effects, active = getattr(stack, "effects", None) or (), getattr(stack, "active", None)
    switches = np.ones(len(effects)) if active is None else np.asarray(active)
    return [
        e.name
        for e, on in zip(effects, switches)
        if getattr(e, "of_time", False) and on and any(k not in frozen for k in getattr(e, "constraints", {}))
    ]


def of_time_said(names) -> str:
    """ "baseline_drift is a function of time", "drift and baseline_drift are functions of time"."""
    return f"{' and '.join(names)} {'is a function' if len(names) == 1 else 'are functions'} of time"


def effects_of_time(fitted: Model, frozen, blocks: int) -> list[str]:
    """A sentence where an effect of time is fitted with the recording in one block: its held-out parts lie after
    the training part, where the effect extrapolates, and the fit is chosen on them.

    A probe's heater with a dead zone of 2 W and a baseline wandering 1.5 °C, fitted with
    ``--effects drive_dead_zone,baseline_drift`` in one block: a dead zone of 0.52 W and a test record
    missed by 0.63 °C (noise 0.2); in 3 blocks, as `diagnose` splits it, 1.79 W and 0.21 °C.
    """
    names = time_effect_names(fitted, frozen)
    if blocks != 1 or not names:
        return []
    return [
        f"{of_time_said(names)}: with the recording in one block its held-out parts lie after the training "
        f"part, where the fit extrapolates {'it' if len(names) == 1 else 'them'} and is chosen on them; "
        f"blocks={TIME_EFFECT_BLOCKS} "
        f"(hybrid fit --blocks {TIME_EFFECT_BLOCKS}) holds parts out between training samples, as hybrid "
        "diagnose does"
    ]


def no_better_than_the_mean(metrics: dict) -> list[str]:
    """A sentence where a held-out part is predicted no better than by its own mean (NMSE over its variance
    ≥ 1): what the model misses outweighs what it explains there.

    A probe's script fitted `lti:2` to records whose baseline wandered by a quarter of their range: test
    parts at 1.02 and 1.07 of their variance (Fitting −0.07 % and −1.85 %), and nothing said so.
    """
    worse = {
        split: metrics[split]["nmse_variance"]
        for split in ("validation", "test")
        if split in metrics and metrics[split].get("nmse_variance", 0.0) >= 1.0
    }
    if not worse:
        return []
    said = " and ".join(f"on the {split} part {value:.3g}× its variance" for split, value in worse.items())
    return [
        f"the fitted model predicts its held-out data no better than their mean (its mean squared error {said}): "
        "what it misses there outweighs what it explains (a change the training part does not show, a "
        "drift, a missing effect: hybrid diagnose says which)"
    ]


def immaterial_effects(fitted: Model, recordings) -> list[str]:
    """A sentence per effect of a fitted effect stack too small to count as a cause (its own `material`).

    A fit starts each effect at one point (`hybrid fit --effects`: its first
    start; Python: the values given) and can end where the effect does next to
    nothing: a piezo user's Bouc–Wen loop stayed 0.25 µm on a 100 µm stage, and
    read "hysteresis does not help" from a fit that never found it (`diagnose`
    starts each effect from several points). On the first recording; quiet
    for a model without effects, or one whose effects do not say.
    """
    stack = fitted.simulation
    effects, derive = getattr(stack, "effects", None), getattr(stack, "derived", None)
    if not effects or derive is None or not recordings:
        return []
    recording = recordings[0]
    try:
        derived = derive(jnp.asarray(recording.v_in), recording.dt)
    except Exception:  # a plug-in's derived that fails here is not the fit's business: nothing to say
        return []
    values = {k: float(v) for k, v in stack.parameters().items()}
    out = []
    for effect in effects:
        if effect.name not in derived:
            continue
        material, why = effect.material(derived[effect.name], values, dict(effect.thresholds))
        if not material:
            out.append(
                f"{effect.name} is too small in the fitted model to count as a cause ({why}): from its "
                "default values a fit may not find it; hybrid diagnose starts each effect from several "
                "points, and its extended model is a start (--start-from DIAG/extended.eqx)"
            )
    return out


def non_finite_fit(simulation, recordings) -> str:
    """Why no start of a fit could move: where the simulation's output (or else the readout's) is not finite.

    Called when every start's validation error is NaN or inf, after the fit (the
    solvers refuse each non-finite step, so each start stays where it began).
    The plug-in probe (`hybrid.physics._plugins.probe_simulation`) runs on the
    first samples only; this runs the simulation as given on each whole drive.
    """
    return _non_finite(simulation, recordings)[0]


def non_finite_error(simulation, recordings) -> PluginError:
    """`non_finite_fit`'s sentence as the error to raise, naming the plug-in at fault: an effect of an
    effect stack whose `apply` is not finite where the simulation is (`_effect_at_fault`), else the simulation."""
    message, plugin = _non_finite(simulation, recordings)
    return PluginError(message, plugin=plugin)


def _non_finite(simulation, recordings) -> tuple[str, type]:
    """(`non_finite_fit`'s sentence, the class it is about)."""
    name = type(simulation).__name__
    at = ", ".join(
        f"{k}={np.asarray(v).item():.4g}" if np.size(v) == 1 else f"{k}=({np.size(v)} values)"
        for k, v in simulation.parameters().items()
    )
    for recording in recordings:
        try:
            out = np.asarray(simulation.simulate(jnp.asarray(recording.v_in), recording.dt), dtype=np.float64)
        except (TypeError, ValueError) as error:  # not an array of one value per sample
            return f"the simulation {name} cannot be run on recording '{recording.name}' ({error})", type(
                simulation
            )
        bad = np.flatnonzero(~np.isfinite(out))
        fault = _effect_at_fault(simulation, recording) if bad.size else None
        if fault is not None:
            effect, count = fault
            own = ", ".join(f"{k}={float(v):.4g}" for k, v in effect.parameters().items())
            return (
                f"effect {type(effect).__name__} (on the {effect.place}) returns non-finite values (NaN or inf) "
                f"at {count} of {out.size} samples of recording '{recording.name}' with its start parameters "
                f"({own}), while the simulation {type(simulation.inner).__name__} it extends is finite there, "
                f"so no step of the fit could be taken: make {type(effect).__name__}.apply finite over its "
                "parameters' range, or start it where it is finite (its defaults; fit's --param NAME=VALUE)"
            ), type(effect)
        if bad.size:
            return (
                f"the simulation {name} returns non-finite values (NaN or inf) at {bad.size} of {out.size} "
                f"samples of recording '{recording.name}', the first at t = {recording.t[bad[0]]:.6g} s, "
                f"with its start parameters ({at}), so no step of the fit could be taken: make its simulate "
                "finite for this drive (a log, a square root or a division of a signal that reaches zero?), "
                "or start it where it is finite (its constructor's defaults; fit's --param NAME=VALUE)"
            ), type(simulation)
    return (
        f"every start's predictions are non-finite (NaN or inf), though the simulation {name} is finite at "
        "its start parameters on every recording: the readout's start values or the recording's scale "
        "overflow; check w's unit and size"
    ), type(simulation)


def _effect_at_fault(stack, recording):
    """(effect, samples) of the first drive- or output-side effect of an effect stack whose `apply` is not
    finite on the signal entering it while the stack's inner simulation is; None where there is none.

    A probe's slew limit, NaN below a rate of 3 V/s and started at 2, was reported as "the simulation
    EffectStack returns non-finite values … make its simulate finite": neither the effect nor its file.
    """
    inner, effects = getattr(stack, "inner", None), getattr(stack, "effects", ())
    if inner is None or not effects or not hasattr(stack, "signals_into"):
        return None
    try:
        v_in = jnp.asarray(recording.v_in)
        if not np.all(np.isfinite(np.asarray(inner.simulate(v_in, recording.dt)))):
            return None
        signals = stack.signals_into(v_in, recording.dt)
        for effect in effects:
            if getattr(effect, "place", None) not in ("drive", "output") or effect.name not in signals:
                continue
            out = np.asarray(effect.apply(jnp.asarray(signals[effect.name]), recording.dt), dtype=np.float64)
            bad = int(np.sum(~np.isfinite(out)))
            if bad:
                return effect, bad
    except (TypeError, ValueError, ArithmeticError):  # the stack's own message says what it can
        return None
    return None


#: The paper's units of the recorded signals, where a recording declares none (or several disagree).
PAPER_UNITS = {"w": "mm", "v_in": "V"}


def recording_units(recordings) -> tuple[str, str] | None:
    """(w's unit, the drive's unit) the recordings declare (`PAPER_UNITS` where one does not), None if they differ."""
    tables = [
        r.metadata.get("units") if isinstance(r.metadata.get("units"), dict) else {} for r in recordings
    ]
    declared = {(str(u.get("w", PAPER_UNITS["w"])), str(u.get("v_in", PAPER_UNITS["v_in"]))) for u in tables}
    return declared.pop() if len(declared) == 1 else None


def unit_mismatch(recordings, simulation) -> list[str]:
    """One sentence where w's unit and the user's simulation's output unit are quantities of different kinds
    (a position and a speed, a temperature), which no readout gain turns one into the other.

    A probe's cart (output in m/s), recorded in the project's columns without units, was read with w in mm,
    the paper's unit: its readout gain printed "1.005 mm/(m/s)" and nothing was said.
    """
    own = user_simulation(simulation)
    declared = recording_units(recordings)
    if own is None or declared is None:
        return []
    unit, w_unit = unit_in(str(own.output_unit or ""), declared[1]), declared[0]
    out_kind, w_kind = unit_kind(unit), unit_kind(w_unit)
    if out_kind is None or w_kind is None or out_kind == w_kind:
        return []
    names = {"rate": "a rate", "position": "a position", "temperature": "a temperature"}
    return [
        f"w is in {w_unit}, {names[w_kind]}, but {type(own).__name__}'s output is in {unit}, "
        f"{names[out_kind]}: a readout gain ({w_unit} per {unit}) cannot turn one into the other, so the "
        f"gain and every size in w's unit rest on a unit that is not the data's; give w's own unit (--units "
        f"w={unit} if it is that; a recording without units is read in {PAPER_UNITS['w']}, the paper's)"
    ]


def unit_labels(model: Model, recordings) -> dict[str, str]:
    """`model.units` in the recordings' declared units of w and the drive (`Model.units_in`).

    Recordings that declare different units leave the paper's (w in mm, the drive in V).
    """
    declared = recording_units(recordings)
    return model.units_in(*declared) if declared is not None else dict(model.units)


def default_frozen(model: Model) -> frozenset[str]:
    """What `fit` and `fit_batch` keep fixed when given no `frozen`: the simulation's `frozen_by_default`."""
    simulation = getattr(model, "simulation", None)
    return frozenset(simulation.frozen_by_default) if simulation is not None else frozenset()


def fit_units(model: Model, series, train_w) -> tuple[float, float]:
    """(w_unit, v_unit): the std of the training w and the rms of v_in, the fit's units.

    Dividing by them exactly (not by a nearby power of two) matters: LM's damping
    λI sees the gain's Jacobian column, so a leftover factor √2 in the scale of w
    already moves the end point along the RC network's near-null directions.
    v_in is scaled only for a simulation linear in the drive (the RC network) and
    a readout that can take it; otherwise its units are part of the physics.
    """
    try:
        model.readout.rescaled(1.0, 1.0)
    except NotImplementedError:
        return 1.0, 1.0
    w_unit = float(robust_std(jnp.asarray(train_w)))
    v_unit = 1.0
    if getattr(model.simulation, "linear_in_drive", False):
        v_unit = float(robust_rms(jnp.concatenate([s.v_in for s in series])))
    ok = lambda x: np.isfinite(x) and x > 0
    return (w_unit if ok(w_unit) else 1.0), (v_unit if ok(v_unit) else 1.0)


def readout_back(fitted, given, frozen, v_unit, w_unit):
    """The fitted readout in the recording's units; what was not fitted stays exactly as given.

    A readout with a frozen part keeps its given fixed leaves (`start_model` does not
    re-initialise it), so those leaves come back bit for bit, not rescaled twice.
    """
    readout = fitted.rescaled(v_unit, w_unit)
    if "network" in frozen or (set(getattr(given, "raw", {})) & frozen):
        spec = given.trainable(frozen)
        readout = eqx.combine(eqx.filter(readout, spec), eqx.filter(given, spec, inverse=True))
    return readout


def start_model(model: Model, index, seed, frozen, perturbation, series) -> Model:
    """Start `index`: 0 is `model` itself; others get new weights and perturbed physics."""
    if index > 0:
        key = jax.random.fold_in(jax.random.key(seed), index)
        k_net, k_phys = jax.random.split(key)
        readout = model.readout
        if isinstance(readout, WindowedMLP):
            depth = len(readout.mlp.layers) - 1
            width = readout.mlp.width_size
            readout = WindowedMLP(readout.window, depth, width, readout.mlp.activation, key=k_net)
        simulation = model.simulation.perturbed(k_phys, perturbation, frozen)
        model = Model(simulation, readout, model.kind, model.signal_units)
    # Fixed scalings (and a least-squares gain for linear readouts) from the training data.
    signal = jnp.concatenate(
        [
            jnp.concatenate([model.mediatory(s.v_in, s.dt)[a:b] for a, b in s.segments_of("train")])
            for s in series
        ]
    )
    target = jnp.concatenate([s.target("train") for s in series])
    if "network" in frozen or (set(getattr(model.readout, "raw", {})) & frozen):
        return model
    return Model(model.simulation, model.readout.initialise(signal, target), model.kind, model.signal_units)


def fit_shape_key(model: Model, recordings, starts: int, solver) -> tuple:
    """What a fit's compiled programs depend on besides the values: the model's structure, the
    recordings' lengths, the starts and the solver (`FIT_PROGRAMS`' shape key)."""
    return (
        type(model.simulation),
        type(model.readout),
        model.kind,
        getattr(model.readout, "window", None),
        tuple(int(r.n) for r in recordings),
        starts,
        type(solver),
    )


#: λ_i/λ_1 of the fit's JᵀJ at or below which a direction is null: no data can move the fit along it.
#: An exact null's ratio is float64's rounding of JᵀJ, ~1e-16; a parameter pinned ten thousand times
#: more loosely than the best pinned one has 1e-8 (its σ_i/σ_1, 1e-4, squared).
NULL_RATIO = 1e-13
#: A parameter is named in a null direction where its part of the directions is at least this.
NULL_COEFFICIENT = 0.05


def unpinned_warnings(JtJ, model: Model, frozen, units: dict | None = None) -> tuple[list[str], list[str]]:
    """(a sentence on the null directions of a physics fit's JᵀJ, its curvature at the end, or none; the
    parameters the prediction does not depend on at all, whose "did not move" the sentence replaces).

    `model` is the fitted model (its values; `units`: its parameters' units as reported, default
    `model.units`). A parameter alone in its null direction that sits at a bound of its two-sided range is
    said to sit there (`at_bound_said`): its raw value's map is flat at the bound, so its column of J
    vanishes however much the prediction depends on it (a diagnosis's frame lag at 0 samples, refitted: a
    probe read "the prediction does not depend on frame_lag").

    Parameters that enter the simulation only as a product or a ratio (a heated
    block's R and C through R·C, k and the readout's gain through k·R·gain) are
    not pinned by any recording: the fit returns one point of a line of equal
    fits, printed as if it were determined (a probe's). JᵀJ in the fit's own
    coordinates (log of a positive parameter) is LM's, at its last accepted
    step: no other program. Black-box readouts (the D-MLP, whose weights have
    null directions of their own) are left to `hybrid sensitivity`.
    """
    if not model.readout.parameters():
        return [], []
    spec = model.trainable(frozenset(frozen))
    readout_names = [
        str(getattr(path[-1], "key", path[-1]))
        for path, _ in jax.tree_util.tree_flatten_with_path(eqx.filter(model.readout, spec.readout))[0]
    ]
    names = model.simulation.free_parameter_order(frozen) + readout_names
    JtJ = np.asarray(JtJ, np.float64)
    if JtJ.shape != (len(names), len(names)) or len(names) < 2 or not np.all(np.isfinite(JtJ)):
        return [], []
    lam, V = np.linalg.eigh((JtJ + JtJ.T) / 2)  # ascending
    if not lam[-1] > 0:
        return [], []
    null = V[:, lam / lam[-1] <= NULL_RATIO]  # k × d: a basis of the directions no data can see
    if not null.size:
        return [], []
    moving = [n for n, row in zip(names, null) if np.linalg.norm(row) >= NULL_COEFFICIENT]
    to_freeze = []  # one parameter per direction, the one that moves most along what is left of them
    basis = null
    while basis.shape[1]:
        i = int(np.argmax(np.linalg.norm(basis, axis=1)))
        to_freeze.append(names[i])
        basis = basis @ np.linalg.svd(basis[i : i + 1], full_matrices=True)[2][1:].T  # those with θ_i fixed
    d = null.shape[1]
    if len(moving) == d:  # each direction one parameter's own: the prediction does not depend on them
        held = _at_bounds(model, moving, units)
        return list(held.values()) + _independent_of([n for n in moving if n not in held]), moving
    listed = ", ".join(moving[:-1]) + f" and {moving[-1]}"
    return [
        f"the recording does not pin {listed} apart: {'a combination' if d == 1 else f'{d} combinations'} of "
        "them can change without changing the prediction (the fit's Jacobian is blind to "
        f"{'it' if d == 1 else 'them'}: the simulation depends on products or ratios of them), so the values "
        f"printed are one point of {'a line' if d == 1 else 'a surface'} of equal fits; freeze {d} of them "
        "(e.g. hybrid fit " + " ".join(f"--freeze {n}" for n in to_freeze) + "; fit(..., frozen=...)) or see "
        "hybrid sensitivity, which names what is pinned"
    ], []


def _at_bounds(model: Model, names: list[str], units: dict | None = None) -> dict[str, str]:
    """A sentence for each of `names` whose value in `model` sits at a bound of its two-sided range."""
    values = model.parameters()
    constraints = {**getattr(model.readout, "constraints", {}), **model.simulation.constraints}
    units = units if units is not None else dict(model.units)
    out = {}
    for name in names:
        said = at_bound_said(
            float(values.get(name, float("nan"))), constraints.get(name), unit_suffix(units.get(name))
        )
        if said is not None:  # its column of J vanishes there, however much the prediction depends on it
            out[name] = f"{name} {said} (hybrid fit --freeze {name} keeps it there)"
    return out


def _independent_of(moving: list[str]) -> list[str]:
    """The sentence for `moving`, parameters the prediction does not depend on (none: no sentence)."""
    if not moving:
        return []
    d, listed = len(moving), ", ".join(moving)
    return [
        f"the prediction does not depend on {listed} on this recording (the fit's Jacobian is zero "
        f"along {'it' if d == 1 else 'them'}), so {'its value is' if d == 1 else 'their values are'} "
        "where the fit started, not fitted: a drive that reaches what "
        f"{'it acts on' if d == 1 else 'they act on'} pins {'it' if d == 1 else 'them'} (if the code "
        f"reads {'it' if d == 1 else 'them'} at all: a plug-in's parameter it never uses reads so too); "
        "else freeze "
        + ("it" if d == 1 else "them")
        + " (hybrid fit "
        + " ".join(f"--freeze {n}" for n in moving)
        + ")"
    ]


def clipped_warnings(problem: Problem, theta, split_order, scale: float, unit: str) -> list[str]:
    """A sentence for a record that sits flat at its extreme while the fitted model goes beyond it.

    A clipped sensor, an end stop or an overflow (`level_limits`, as `diagnose`
    reads it): the fit takes the flat runs for the system's response, and its
    parameters are biased to follow them. Over every part of the split, each
    recording's segments apart; levels in the recordings' units (`scale`: the
    fit's scaling of w).
    """
    parts = [
        {
            "w": scale * problem.recorded(problem.target(split), split),
            "w_hat": scale * problem.recorded(problem.prediction(theta, split), split),
            "segment": segment_ids(problem.series, split),
        }
        for split in split_order
    ]
    n = sum(len(p["w"]) for p in parts)
    sentence = limit_sentence(level_limits(parts, None), n, unit)
    if sentence is None:
        return []
    return [
        f"{sentence[0].upper()}{sentence[1:]}. The fit takes the flat runs for the system's response, which "
        "biases its parameters: record within the sensor's range, or run hybrid diagnose, which names the "
        "limit, and fit with it (hybrid fit --effects)"
    ]


def _metrics_by_split(problem: Problem, theta, split_order):
    out = {}
    for split in ("train", "validation", "test"):
        if split in split_order:
            w = problem.target(split)
            w_hat = problem.prediction(theta, split)
            out[split] = compute_metrics(np.asarray(w), np.asarray(w_hat))
    return out


def _progress_bar(total, enabled, desc):
    """The LM progress bar on stderr where `enabled` and stderr is a terminal: a script looping over
    recordings into a log file got thousands of carriage-return lines (a probe), none of them read."""
    from tqdm.auto import tqdm

    return tqdm(total=total, disable=None if enabled else True, desc=desc, unit="step", leave=False)


def _one_start(tree):
    return jax.tree_util.tree_map(lambda x: x[0], tree)


def _with_start_axis(tree):
    return jax.tree_util.tree_map(lambda x: x[None], tree)


@eqx.filter_jit
def lm_init_batch(problem, thetas, settings):
    """`lm_init` for each start (the rows of `thetas`); states with a leading start axis."""
    if thetas.shape[0] == 1:  # see lm_run_batch
        return _with_start_axis(lm_init(problem, thetas[0], settings))
    return jax.vmap(lambda th: lm_init(problem, th, settings))(thetas)


@eqx.filter_jit
def lm_run_batch(problem, states, settings, n_steps):
    """Up to `n_steps` more LM steps of each start (`lm_run`), in one compiled program.

    Pass `n_steps` as a JAX integer: it is then traced, and any number of steps
    reuses the one program. Several starts are `vmap`-ed; a single start runs
    without `vmap`, because under `vmap` the accept/reject `lax.cond` of `lm_step`
    becomes a select that evaluates both branches: every rejected step would
    also form JᵀJ, the costliest part of a step on a long record.
    """
    if states.step.shape[0] == 1:
        return _with_start_axis(lm_run(problem, _one_start(states), settings, n_steps))
    return jax.vmap(lambda s: lm_run(problem, s, settings, n_steps))(states)


#: `_run_lm` runs this many seconds of LM steps, at most, between two looks at `stop`.
STOP_POLL_S = 1.0


def _run_lm(problem, thetas, settings: LMSettings, progress, report_every, stop=None):
    """LM from each row of `thetas`: (best θ per start, history, per-start records, stopped, JᵀJ per start).

    JᵀJ is each start's at its last accepted step (`unpinned_warnings` reads its null directions).

    Steps run in compiled chunks that end on every `report_every`-th step (a
    history entry); on a long record, where one step takes seconds, a chunk is
    as many steps as fit in `STOP_POLL_S` (at least one), so that `stop` is
    looked at between steps.
    """
    max_steps = settings.max_steps
    stage(f"fit: compiling and starting LM on the {problem.kind} model ({thetas.shape[0]} start(s))")
    states = lm_init_batch(problem, thetas, settings)
    history = []
    requested = 0  # steps asked of every running start so far
    seconds_per_step = None
    stopped = False
    with _progress_bar(max_steps, progress, f"LM {problem.kind}") as bar:
        while not bool(jnp.all(states.done)):
            if stop is not None and stop():
                stopped = True
                break
            chunk = report_every - requested % report_every
            if seconds_per_step is not None:
                chunk = max(1, min(chunk, int(STOP_POLL_S / max(seconds_per_step, 1e-9))))
            else:
                chunk = 1  # the first chunk (compiling) measures nothing: one step
            t0 = time.perf_counter()
            before = int(jnp.max(states.step))
            states = lm_run_batch(problem, states, settings, jnp.asarray(chunk, jnp.int32))
            step = int(jnp.max(states.step))
            if requested:  # the first call also compiled the program: it measures nothing
                seconds_per_step = (time.perf_counter() - t0) / max(step - before, 1)
            requested += chunk
            stage(f"fit: LM on the {problem.kind} model, step {step} of at most {max_steps}")
            done = bool(jnp.all(states.done))
            if requested % report_every == 0 or done:
                history.append(
                    {
                        "step": step,
                        "train_cost": [float(c) for c in states.cost],
                        "validation_loss": [float(v) for v in states.best_val],
                    }
                )
            bar.n = step
            bar.set_postfix(
                cost=f"{float(jnp.min(states.cost)):.3e}", val=f"{float(jnp.min(states.best_val)):.3e}"
            )
            bar.refresh()
    if stopped:
        step = int(jnp.max(states.step))
        if not history or history[-1]["step"] != step:
            history.append(
                {
                    "step": step,
                    "train_cost": [float(c) for c in states.cost],
                    "validation_loss": [float(v) for v in states.best_val],
                }
            )
    per_start = [
        {
            "validation_loss": float(states.best_val[i]),
            "steps": int(states.step[i]),
            "accepted_steps": int(states.accepted[i]),
            "best_step": int(states.best_step[i]),
            "train_cost": float(states.cost[i]),
        }
        for i in range(thetas.shape[0])
    ]
    return states.best_theta, history, per_start, stopped, np.asarray(states.JtJ)


def _run_adam(problem, thetas, max_steps, learning_rate, progress, report_every, stop=None):
    import optax

    optimiser = optax.adam(learning_rate)
    n = problem.target("train").shape[0]

    @eqx.filter_jit
    def run(problem, thetas, opt_states, best, best_val, n_steps):
        def one(theta, opt_state, best, best_val):
            def body(_, carry):
                theta, opt_state, best, best_val = carry
                grad = jax.grad(lambda th: problem.cost(th) / n)(theta)
                updates, opt_state = optimiser.update(grad, opt_state, theta)
                theta = optax.apply_updates(theta, updates)
                val = problem.validation_loss(theta)
                better = val < best_val
                return theta, opt_state, jnp.where(better, theta, best), jnp.where(better, val, best_val)

            return jax.lax.fori_loop(0, n_steps, body, (theta, opt_state, best, best_val))

        return jax.vmap(one)(thetas, opt_states, best, best_val)

    opt_states = jax.vmap(optimiser.init)(thetas)
    best = thetas
    best_val = jax.vmap(problem.validation_loss)(thetas)
    history = []
    step = 0
    stopped = False
    with _progress_bar(max_steps, progress, f"Adam {problem.kind}") as bar:
        while step < max_steps:
            if stop is not None and stop():
                stopped = True
                break
            chunk = min(report_every, max_steps - step)
            thetas, opt_states, best, best_val = run(problem, thetas, opt_states, best, best_val, chunk)
            step += chunk
            costs = jax.vmap(problem.cost)(thetas)
            history.append(
                {
                    "step": step,
                    "train_cost": [float(c) for c in costs],
                    "validation_loss": [float(v) for v in best_val],
                }
            )
            stage(f"fit: Adam on the {problem.kind} model, step {step} of at most {max_steps}")
            bar.n = step
            bar.refresh()
    per_start = [{"validation_loss": float(v), "steps": step} for v in best_val]
    return best, history, per_start, stopped


def _run_optimistix(problem, thetas, max_steps, rtol, atol):
    import optimistix as optx

    solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol)
    best, per_start = [], []
    for theta in thetas:
        solution = optx.least_squares(
            lambda th, _: problem.objective_residuals(th), solver, theta, max_steps=max_steps, throw=False
        )
        best.append(solution.value)
        per_start.append(
            {
                "validation_loss": float(problem.validation_loss(solution.value)),
                "steps": int(solution.stats["num_steps"]),
                "result": str(solution.result)
                if solution.result != optx.RESULTS.successful
                else "successful",
            }
        )
    return jnp.stack(best), [], per_start
