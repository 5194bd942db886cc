"""The search of `diagnose`: Levenberg–Marquardt lanes, all in one compiled program.

A lane is one LM run from its own start with its own switches: every effect
lives in one [`EffectStack`][] (`universal_model`), and a lane switches on at
most one of them beyond those already named; `fit_lanes` runs a batch of lanes in a single compiled
program, one after another on each device and the devices side by side. Also here: the least-squares problem every lane shares
(`lanes_problem`), its predictions on each part of the split (`predictions`,
`split_signals`), and the lag that best aligns a model with the data (`best_lag`);
each effect's starts are its own (`AbstractEffect.starts`, `AbstractEffect.screened_starts`).
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import NamedSharding, PartitionSpec

from ..core._devices import device_mesh, spread_devices
from ..core._level_limit import flat_extremes
from ..core._levenberg_marquardt import LMSettings, LMState, lm_init, lm_run
from ..core._models import Model
from ..core._problem import (
    Problem,
    Series,
    bucket_length,
    bucketed_series,
    series_from_recording,
    span_rows,
    split_segments,
    unmeasured_mask,
    unmeasured_runs,
    without_unmeasured,
)
from ..core._readout import LinearReadout
from ._diagnosis import MAX_BLOCKS_FACTOR, SPLIT_ORDER, DiagnoseSettings
from ._effect_set import resolve_effects
from ._effect_stack import EffectStack
from ._effects import AbstractEffect, FrameTiming

#: Effects a lane's Jacobian has room for in the problem every step of the search shares: the
#: directions of the `SHARED_ROOM` effects with the most parameters. Each direction costs one
#: tangent of the simulation, zero or not: room for more is paid on every step. A third step's
#: lane fits in it whenever its three effects have no more parameters than those two (most
#: sets); where one does not, it holds the earliest named effect (`_step.refitted`).
SHARED_ROOM = 2
#: The baseline's LM starts, and the least LM runs per stage (candidate starts, padded): one
#: compiled program. `lane_count` raises the lanes to the first step's candidate lanes, so that
#: every stage has one lane count; the baseline keeps its starts whatever the effects searched,
#: so a larger effect set is measured against the same baseline (with as many starts as lanes,
#: the twelve built-ins' 29 gave drift seed 0 of `experiments/discrepancy.py` another baseline
#: than the seven original effects' 18, and no cause). 18: the seven's count.
N_LANES = 18


# --------------------------------------------------------------------------- #
# Batched LM over lanes (one compiled program for every candidate)
# --------------------------------------------------------------------------- #


def with_active(problem: Problem, active, tangents=None):
    """The problem with the effects' switches (and Jacobian directions) of one lane."""
    problem = eqx.tree_at(lambda p: p.sim_static.active, problem, active)
    if tangents is not None:
        problem = eqx.tree_at(lambda p: p.sim_tangents, problem, tangents, is_leaf=lambda x: x is None)
    return problem


def lane_tangents(model: Model, frozen, effects, n_rows: int) -> np.ndarray:
    """Unit directions in θ_sim for the inner simulation's free parameters and those of `effects`.

    `effects`: None, one effect's name, or a tuple of names (the effects a lane fits).
    """
    stack = model.simulation
    assert isinstance(stack, EffectStack)  # a search fits an EffectStack
    labels = simulation_labels(stack, frozen)
    wanted = _fitted_names(model, frozen, effects)
    if len(wanted) > n_rows:
        raise ValueError(f"{len(wanted)} directions for a problem with room for {n_rows}")
    basis = np.zeros((n_rows, len(labels)))
    for row, name in enumerate(wanted):
        basis[row, labels.index(name)] = 1.0
    return basis


def direction_count(model: Model, frozen, effects) -> int:
    """Jacobian directions a lane fitting `effects` takes (`lane_tangents`' rows that are not zero)."""
    return len(_fitted_names(model, frozen, effects))


def _fitted_names(model: Model, frozen, effects) -> list[str]:
    """The free parameters a lane fits: the inner simulation's, the frame timing's and those of `effects`."""
    effects = () if effects is None else (effects,) if isinstance(effects, str) else tuple(effects)
    stack = model.simulation
    assert isinstance(stack, EffectStack)  # a search fits an EffectStack
    by_name = {e.name: e for e in stack.effects}
    wanted = [n for n in stack.inner.parameter_names() if n not in frozen]
    wanted += [n for n in FrameTiming.constraints if n not in frozen]
    for effect in effects:
        wanted += [n for n in by_name[effect].constraints if n not in frozen]
    return wanted


def _run_lanes(problem, actives, tangents, states, restart, patience, steps, settings):
    def one(lane):
        active, basis, state, fresh = lane
        p = with_active(problem, active, basis)
        state = jax.lax.cond(fresh, lambda s: lm_init(p, s.theta, settings), lambda s: s, state)
        return lm_run(p, state, settings, steps, patience)

    # Lanes run one after another: each stops when it converges (a vmap would run
    # every lane until the slowest is done, and every effect's branch in every lane).
    return jax.lax.map(one, (actives, tangents, states, restart))


@eqx.filter_jit
def _fit_lanes_compiled(problem, actives, tangents, states, restart, patience, steps, settings):
    return _run_lanes(problem, actives, tangents, states, restart, patience, steps, settings)


@eqx.filter_jit
def _fit_lanes_sharded(problem, actives, tangents, states, restart, patience, steps, settings, mesh):
    """`_run_lanes` on every device of `mesh` at once, each on its own share of the lanes."""
    dynamic, static = eqx.partition(problem, eqx.is_array)

    def local(dynamic, actives, tangents, states, restart, patience, steps):
        return _run_lanes(
            eqx.combine(dynamic, static), actives, tangents, states, restart, patience, steps, settings
        )

    lanes, shared = PartitionSpec("lanes"), PartitionSpec()
    return jax.shard_map(
        local,
        mesh=mesh,
        in_specs=(shared, lanes, lanes, lanes, lanes, shared, shared),
        out_specs=lanes,
        check_vma=False,  # no collectives: every device's lanes are independent
    )(dynamic, actives, tangents, states, restart, patience, steps)


def _start_states(thetas: np.ndarray) -> LMState:
    """Placeholder states holding each lane's θ₀, for a program that starts them (`lm_init`) itself.

    Host (numpy) arrays, as `fit_lanes` moves every input: no program per shape.
    """
    n, p = thetas.shape
    real, count, flag = thetas.dtype, np.int32, np.bool_
    fields: dict[str, Any] = dict(
        theta=thetas,
        cost=np.zeros(n, real),
        JtJ=np.zeros((n, p, p), real),
        g=np.zeros((n, p), real),
        lam=np.zeros(n, real),
        nu=np.zeros(n, real),
        best_theta=thetas,
        best_val=np.zeros(n, real),
        best_step=np.zeros(n, count),
        step=np.zeros(n, count),
        accepted=np.zeros(n, count),
        since_best=np.zeros(n, count),
        done=np.ones(n, flag),
        fresh=np.ones(n, flag),
        nonfinite=np.zeros(n, count),
    )
    return LMState(**fields)


def resume(states: LMState, lanes) -> LMState:
    """`states` (from `fit_lanes`) with `lanes` (indices) to go on and every other lane done.

    Passed back to `fit_lanes` with a longer patience, each of `lanes` takes
    the steps it would have taken had that been its patience from the start
    (LM's state is all there: θ, λ, the best point, the steps since it). Name
    only lanes that the patience stopped: one stopped on its tolerances would
    step on past them.
    """
    done = np.ones_like(np.asarray(states.done))
    done[np.asarray(lanes, int)] = False
    return eqx.tree_at(lambda s: s.done, states, done)


def fit_lanes(
    problem, actives, tangents, starts, settings: LMSettings, patience: int, steps: int | None = None
):
    """LM from each (switches, Jacobian directions, start) lane; one compiled program per lane count.

    `starts`: θ₀ of each lane (rows), or the lanes' `LMState`s from an earlier
    call (`resume`), which go on from there; a lane whose state is done stays
    as it is. With several devices (`spread_devices`: on a CPU,
    `hybrid.use_cpu_cores`) the lanes are dealt out to them in turn, those that
    will run first (`_running_first`), and each device runs its share one after
    another: the same arithmetic as on one device, side by side. `patience`, and `steps` (the
    most LM iterations a lane takes in this call; default `settings.max_steps`, which caps a
    lane's iterations over all calls), are arguments of the program, not part of it: the stages
    share one compilation. Returns the
    lanes' final `LMState`s as numpy arrays, one row per lane.
    """
    actives = np.asarray(actives, float)
    tangents = np.asarray(tangents, float)
    if isinstance(starts, LMState):
        states = jax.tree_util.tree_map(np.asarray, starts)
        restart = np.zeros(states.theta.shape[0], bool)
    else:
        states = _start_states(np.asarray(starts))
        restart = np.ones(states.theta.shape[0], bool)
    stop_after = jnp.asarray(patience, jnp.int32)
    n_steps = jnp.asarray(settings.max_steps if steps is None else steps, jnp.int32)
    devices = spread_devices()
    if len(devices) < 2:
        return jax.device_get(
            _fit_lanes_compiled(
                problem,
                jnp.asarray(actives),
                jnp.asarray(tangents),
                jax.tree_util.tree_map(jnp.asarray, states),
                jnp.asarray(restart),
                stop_after,
                n_steps,
                settings,
            )
        )
    n, d = restart.shape[0], len(devices)
    share = -(-n // d)
    extra = share * d - n  # padding lanes (θ not finite: they stop before their first step)
    order = _running_first(states, restart)
    actives, tangents, restart = actives[order], tangents[order], restart[order]
    states = jax.tree_util.tree_map(lambda x: x[order], states)

    def deal(x, fill):  # lane i to device i mod d: row-major (share, d) read column by column
        x = np.concatenate([x, fill(x, extra)])
        return x.reshape((share, d) + x.shape[1:]).swapaxes(0, 1).reshape(x.shape)

    def same(x, k):
        return np.repeat(x[:1], k, axis=0)

    def nan(x, k):
        return np.full((k,) + x.shape[1:], np.nan, x.dtype)

    actives, tangents = deal(actives, same), deal(tangents, same)
    # A padding lane restarts (`lm_init` sets its whole state) from a θ that is not finite.
    theta = deal(states.theta, nan)
    states = eqx.tree_at(lambda s: s.theta, jax.tree_util.tree_map(lambda x: deal(x, same), states), theta)
    restart = deal(restart, lambda x, k: np.ones(k, bool))
    mesh = device_mesh("lanes")
    lanes = NamedSharding(mesh, PartitionSpec("lanes"))
    replicated = NamedSharding(mesh, PartitionSpec())
    arrays, rest = eqx.partition(problem, eqx.is_array)
    out = _fit_lanes_sharded(
        eqx.combine(jax.device_put(arrays, replicated), rest),
        jax.device_put(actives, lanes),
        jax.device_put(tangents, lanes),
        jax.device_put(states, lanes),
        jax.device_put(restart, lanes),
        jax.device_put(stop_after, replicated),
        jax.device_put(n_steps, replicated),
        settings,
        mesh,
    )

    back = np.argsort(order)

    def gather(x):  # back to the dealt order, padding dropped, then to the lanes' own order
        return x.reshape((d, share) + x.shape[1:]).swapaxes(0, 1).reshape(x.shape)[:n][back]

    return jax.tree_util.tree_map(gather, jax.device_get(out))


def _running_first(states: LMState, restart) -> np.ndarray:
    """The lanes' order for dealing: those that will take steps first, the rest after (stable).

    Dealt in turn, lane k of this order to device k mod d, the lanes that run
    spread evenly over the devices, whatever their places: a resumed race
    (`resume`) runs a few leaders among many finished lanes, and dealt by their
    own places two neighbours in one effect's lanes could share a device while
    another idles. Which lane runs where changes no lane's arithmetic.
    """
    theta = np.asarray(states.theta)
    starts = np.asarray(restart) & np.all(np.isfinite(theta), axis=tuple(range(1, theta.ndim)))
    runs = starts | (~np.asarray(restart) & ~np.asarray(states.done))  # a padding lane (θ NaN) stops at once
    return np.argsort(~runs, kind="stable")


def search_problem(model: Model, series, frozen, max_causes: int = 1) -> tuple[Problem, int]:
    """The least-squares problem every lane of every step shares, and its number of Jacobian directions.

    A lane fits the inner simulation's free parameters, the frame timing and
    at most `max_causes` effects: `n_rows` directions, room for the
    `max_causes` effects with the most parameters, so that every step of the
    search runs the same compiled programs.
    """
    stack = model.simulation
    assert isinstance(stack, EffectStack)  # a search fits an EffectStack
    simulation = stack.inner
    sizes = sorted((len(e.constraints) for e in searched_effects(stack)), reverse=True)
    n_rows = (
        len([n for n in simulation.parameter_names() if n not in frozen])
        + len(FrameTiming.constraints)
        + sum(sizes[: max(max_causes, 1)])
    )
    n_sim = len(simulation_labels(stack, frozen))
    return Problem(model, series, frozen, sim_tangents=jnp.zeros((n_rows, n_sim))), n_rows


def lanes_problem(recordings, simulation, settings: DiagnoseSettings, effects=None):
    """(problem, n_rows, model): the least-squares problem `diagnose` fits on `recordings`.

    Each recording is padded to its bucket's length (`bucket_length`) and its
    split carried as weights (`bucketed_series`): the compiled programs of the
    search depend on the buckets, not on the recordings' exact lengths, so a
    session that diagnoses many recordings reuses them (`problem.series`, whose
    `recorded_segments_of` are each recording's own samples). Its θ is the layout of
    `Diagnosis.lanes[i].theta`; `split_signals(problem, theta, active, split)`
    predicts a lane on a split.
    """
    effects = resolve_effects(effects, simulation)
    model = universal_model(simulation, effects, drive_unit(recordings))
    padded = [
        bucketed_series(s, bucket_length(s.v_in.shape[0]))
        for s in (
            series_from_recording(r, settings.split, SPLIT_ORDER, settings.split_blocks, measured_only=False)
            for r in recordings
        )
    ]
    if settings.bridge_glitches:  # samples w was not measured at weigh nothing (`_bridge_glitches`)
        padded = [
            _unweighted(s, unmeasured_runs(r.extra.get("quality")), r.name)
            for s, r in zip(padded, recordings)
        ]
    problem, n_rows = search_problem(
        model, padded, frozenset(settings.frozen_for(simulation)), _shared_room(settings, len(effects))
    )
    return problem, n_rows, model


def _unweighted(series: Series, runs, name: str = "") -> Series:
    """A padded `series` whose samples in `runs` ((first, last), w not measured there) are in no split.

    They weigh 0 in every fit and loss, and its recorded segments (`recorded_segments_of`, which
    `Problem.recorded` and so every held-out score read) go round them (`without_unmeasured`, which
    refuses a split left without a sample).
    """
    if not runs or series.weights is None or series.spans is None:
        return series
    measured = ~unmeasured_mask(runs, series.v_in.shape[0])
    weights = tuple((split, jax.device_put(np.array(weight) * measured)) for split, weight in series.weights)
    kept = without_unmeasured([(split, np.asarray(rows)) for split, rows in series.spans], runs, name)
    spans = tuple((split, span_rows(pieces)) for split, pieces in kept)
    return eqx.tree_at(lambda s: (s.weights, s.spans), series, (weights, spans))


def held_out_blocks(recordings, settings: DiagnoseSettings) -> tuple[int, bool]:
    """(blocks, reached): the fewest blocks whose held-out parts see every recording's flat extremes.

    A recording's flat extremes are the runs where it sits at its largest or
    smallest value (`flat_extremes`: the trace of an overflow, an end stop, a
    sensor's range). Each side's runs must have a sample in a held-out part.
    Tried from `settings.blocks` to `MAX_BLOCKS_FACTOR` times it; where no count
    reaches them all: (`settings.blocks`, False). A recording without flat
    extremes keeps `settings.blocks`. Computed from the recordings alone, before
    any fit.
    """
    if not settings.held_out_limits:
        return settings.blocks, True
    runs = [[idx for idx in flat_extremes(r.w).values() if idx.size] for r in recordings]

    def reached(blocks: int) -> bool:
        for recording, sides in zip(recordings, runs):
            if not sides:
                continue
            held_out = np.zeros(recording.n, bool)
            for a, b in dict(split_segments(recording, settings.split, SPLIT_ORDER, blocks))["test"]:
                held_out[a:b] = True
            if not all(held_out[idx].any() for idx in sides):
                return False
        return True

    for blocks in range(settings.blocks, MAX_BLOCKS_FACTOR * settings.blocks + 1):
        if reached(blocks):
            return blocks, True
    return settings.blocks, False


def _shared_room(settings: DiagnoseSettings, n_effects: int) -> int:
    """Effects a lane of the search's shared problem has Jacobian directions for."""
    return max(1, min(SHARED_ROOM, settings.max_causes, n_effects))


def drive_unit(recordings) -> str:
    """The drive's unit, from the first recording's metadata ("V" where it does not say)."""
    units = getattr(recordings[0], "metadata", {}).get("units", {})
    return str(units.get("v_in", "V")) if isinstance(units, dict) else "V"


def searched_effects(stack: EffectStack) -> tuple[AbstractEffect, ...]:
    """The effects a search's stack can name: all but the frame timing (always on, last)."""
    return tuple(e for e in stack.effects if not isinstance(e, FrameTiming))


def padding_lane(theta) -> jax.Array:
    """θ of a lane that only fills a batch: not finite, so LM stops before its first step."""
    return jnp.full_like(jnp.asarray(theta), jnp.nan)


def lane_count(n_first_step: int) -> int:
    """Lanes per stage: at least `N_LANES`, and room for every lane of the search's first step."""
    return max(N_LANES, n_first_step)


def universal_model(simulation, effects=None, drive_unit: str = "V") -> Model:
    """Every effect of `effects` (None: the built-ins; switched off) and, last and always on, the frame timing."""
    effects = resolve_effects(effects, simulation) + (FrameTiming(),)
    stack = EffectStack(simulation, effects, active=jnp.zeros(len(effects)), drive_unit=drive_unit)
    return Model(stack, LinearReadout(), "physics")


def initial_theta(problem, simulation, readout, frozen):
    """θ for `simulation` with the least-squares gain and offset on the training part."""
    return initial_thetas(problem, [simulation], readout, frozen)[0]


def initial_thetas(problem, simulations, readout, frozen):
    """θ for each of `simulations` (one structure, other values), each with its least-squares gain and offset.

    Each simulation's output comes from `predictions` (the program every
    stage already runs: gain 1, offset 0), and the gain and offset are fitted
    on the recorded training samples by numpy: no program of its own. A
    simulation whose output is not finite (a start that makes the dynamics
    escape) gets gain 1 and offset 0 (`finite_theta` says None instead).
    """
    w = problem.recorded(problem.target("train"), "train")
    thetas = []
    for simulation in simulations:
        theta = finite_theta(problem, simulation, readout, frozen, w)
        thetas.append(
            theta if theta is not None else theta_with_readout(problem, simulation, readout, frozen, 1.0, 0.0)
        )
    return jnp.stack(thetas)


def finite_theta(problem, simulation, readout, frozen, w=None):
    """θ for `simulation` with its least-squares gain and offset, or None where its output is not finite."""
    if w is None:
        w = problem.recorded(problem.target("train"), "train")
    s = simulation_output(problem, simulation, readout, frozen, "train")
    if not np.all(np.isfinite(s)):
        return None
    (gain, offset), *_ = np.linalg.lstsq(np.stack([s, np.ones_like(s)], axis=1), w, rcond=None)
    if not (np.isfinite(gain) and np.isfinite(offset)):
        gain, offset = 1.0, 0.0
    return theta_with_readout(problem, simulation, readout, frozen, gain, offset)


def theta_with_readout(problem, simulation, readout, frozen, gain: float, offset: float):
    """θ of `simulation` read out with this gain and offset."""
    fitted = eqx.tree_at(
        lambda r: r.raw, readout, {"gain": jnp.asarray(gain, float), "offset": jnp.asarray(offset, float)}
    )
    return problem.flatten(Model(simulation, fitted, "physics"), frozen)


def simulation_output(problem, simulation, readout, frozen, split: str) -> np.ndarray:
    """`simulation`'s output (a stack of the search's structure) on the recorded samples of `split`.

    Read off `predictions` with gain 1 and offset 0: the program every stage
    runs already, so no program of its own.
    """
    unit = eqx.tree_at(
        lambda r: r.raw, readout, {"gain": jnp.asarray(1.0, float), "offset": jnp.asarray(0.0, float)}
    )
    theta = problem.flatten(Model(simulation, unit, "physics"), frozen)
    return problem.recorded(predictions(problem, simulation.active, theta)[split], split)


@eqx.filter_jit
def predictions(problem, active, theta):
    """ŵ on every part (`SPLIT_ORDER`) from one simulation (one compiled program for all)."""
    p = with_active(problem, active)
    sim_theta, readout_theta = p.split_theta(theta)
    readout = p.readout(readout_theta)
    signals = p._signals(sim_theta)
    return {
        split: jax.vmap(readout.predict_window)(p._windows(readout, signals, split)) for split in SPLIT_ORDER
    }


def split_data(problem, split) -> tuple[np.ndarray, np.ndarray]:
    """(drive, w) on `split` ("train", "validation" or "test"), all recordings concatenated: the data alone."""
    v = np.concatenate(
        [np.asarray(s.v_in)[a:b] for s in problem.series for a, b in s.recorded_segments_of(split)]
    )
    return v, problem.recorded(problem.target(split), split)


def split_signals(problem, theta, active, split):
    """(drive, w, ŵ) on `split` ("train", "validation" or "test"), all recordings concatenated."""
    w_hat = predictions(problem, jnp.asarray(active, float), jnp.asarray(theta))[split]
    return (*split_data(problem, split), problem.recorded(w_hat, split))


def inside_signals(problem, stack: EffectStack, effects, split: str) -> dict[str, np.ndarray]:
    """The signal entering each of `effects` under `stack`, on the recorded samples of `split`, by name.

    For the start values of effects inside the dynamics (a state's trajectory);
    nothing is computed when there are none.
    """
    if not effects:
        return {}
    parts: dict[str, list] = {e.name: [] for e in effects}
    for series in problem.series:
        signals = stack.signals_into(series.v_in, series.dt)
        for a, b in series.recorded_segments_of(split):
            for e in effects:
                parts[e.name].append(signals[e.name][a:b])
    return {name: np.concatenate(chunks) for name, chunks in parts.items()}


def simulation_labels(stack: EffectStack, frozen) -> list[str]:
    """The parameter name of each entry of θ_sim, in `ravel_pytree` order (read off the stack itself)."""
    return stack.free_parameter_order(frozen)


def best_lag(w, w_hat, max_lag):
    """Whole-sample lag of ŵ that best explains w by a gain and offset (0 if none helps)."""
    best, best_err = 0, np.inf
    for lag in range(0, max_lag + 1):
        x = np.concatenate([np.full(lag, w_hat[0]), w_hat[: len(w_hat) - lag]])
        design = np.stack([x, np.ones_like(x)], axis=1)
        coef, *_ = np.linalg.lstsq(design, w, rcond=None)
        err = np.mean((w - design @ coef) ** 2)
        if err < best_err * (1 - 1e-6):
            best, best_err = lag, err
    return best
