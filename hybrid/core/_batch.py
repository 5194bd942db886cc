"""`fit_batch`: many recordings × many starts fitted in one compiled program.

Each recording gets its own fit (its own model), exactly as [`hybrid.fit`][]
would give it with the default ``solver=LevenbergMarquardt(...)``: the same starts, the same Levenberg–Marquardt
loop, the validation split picking the best iterate and the best start. What
changes is how the work is laid out:

- every (recording, start) pair becomes one element of a batch axis: the
  recordings' data, fixed scalings and starting θ are stacked, and one
  `jax.vmap`-ed `lm_init` + `lm_run` (a `lax.while_loop`) runs them all;
- `batch_size` bounds memory: the elements run in `lax.map` chunks of that
  many, each chunk `vmap`-ed (a Hybrid model's Jacobian is ~75 MB per fit at
  5,400 training samples);
- with several devices (`jax.devices()`), the batch axis is sharded over a
  1-D `Mesh` (`NamedSharding(mesh, P("batch"))`) and each device runs its own
  part under `jax.shard_map`; nothing is communicated between devices.

Multi-host: call ``jax.distributed.initialize()`` (coordinator address, number
of processes and process id, or the cluster's environment) at the start of
every process, before any other JAX call; `jax.devices()` then lists the
devices of all hosts and the same `fit_batch` call, run by every process with
the same recordings, shards the batch over all of them. Results come back as
global arrays; this module gathers them with `jax.device_get`, which in a
multi-host run needs ``jax.experimental.multihost_utils.process_allgather``
instead (not exercised here: one machine).

All recordings in one call must have the same number of samples and the same
sample rate (their split segments and the step are compiled into the program;
rates within `RATE_RTOL` count as one, the first recording's); group them by
length otherwise. A second call with the same shapes reuses the compiled program.
"""

from __future__ import annotations

import dataclasses
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..data._mapping import RATE_RTOL
from ..util._errors import InputError, PluginError
from ..util._programs import FIT_PROGRAMS, process_compiles
from ._arguments import as_recordings, check_dt, check_model
from ._devices import device_mesh, repeat_last
from ._fit import (
    check_training_drive,
    default_frozen,
    fit_shape_key,
    fit_units,
    non_finite_fit,
    readout_back,
    recording_units,
    start_model,
)
from ._levenberg_marquardt import lm_init, lm_run
from ._metrics import metrics as compute_metrics
from ._models import Model
from ._problem import Problem, Series, series_from_recording
from ._result import FitResult, drive_outside_range, fit_warnings, one_frequency_drive
from ._simulation import AbstractSimulation
from ._solvers import AbstractSolver, LevenbergMarquardt, resolve_solver


@dataclasses.dataclass(frozen=True)
class BatchFitResult:
    """What [`fit_batch`][] returns.

    **Fields:**

    - `results`: one [`FitResult`][] per recording, in order (`history` is
      empty: the batch runs to the end in one call).
    - `seconds`: wall time of the whole call.
    - `compile_seconds`: of which XLA compiled (`jax.monitoring`'s compile events; 0 when
      an earlier call with the same shapes compiled the program, which is reused).
    - `devices`: number of devices the batch was sharded over.
    - `batch`: number of (recording, start) fits run.
    """

    results: list[FitResult]
    seconds: float
    compile_seconds: float
    devices: int
    batch: int

    @property
    def fits_per_second(self) -> float:
        """Recordings fitted per second of run time, compilation excluded."""
        run = max(self.seconds - self.compile_seconds, 1e-12)
        return len(self.results) / run

    def __len__(self):
        return len(self.results)

    def __getitem__(self, index) -> FitResult:
        return self.results[index]


def fit_batch(
    model: Model,
    recordings,
    *,
    solver: AbstractSolver | str = LevenbergMarquardt(),
    starts: int = 1,
    frozen=None,
    split=(0.3, 0.5, 0.2),
    split_order=("train", "test", "validation"),
    weight_decay: float = 0.0,
    perturbation: float = 0.5,
    seed: int = 0,
    batch_size: int | None = None,
    devices=None,
    max_steps: int | None = None,
    patience: int | None = None,
) -> BatchFitResult:
    """Fit `model` separately to each recording, all fits in one compiled program.

    **Arguments:**

    - `model`, `solver`, `starts`, `frozen`, `split`, `split_order`,
      `weight_decay`, `perturbation`, `seed`: as in [`hybrid.fit`][], applied to
      every recording. The solver must be a
      [`LevenbergMarquardt`][hybrid.LevenbergMarquardt] (the default).
    - `recordings`: a list of Recordings of equal length and rate (e.g. 64
      strips, or one strip recorded many times). Rows a ``quality`` column
      marks 0 (rig's: w not measured) are left out of every part, as in `fit`;
      recordings with such rows at different samples are refused (one
      compiled program holds one split).
    - `batch_size`: fits `vmap`-ed together per device (default: all of them);
      lower it to bound memory.
    - `devices`: the devices to shard the batch over (default: all of
      `jax.devices()`; a list of one device runs unsharded).
    - `max_steps`, `patience`: deprecated; each sets that field of `solver`
      (``solver=hybrid.LevenbergMarquardt(max_steps=...)``), with a `DeprecationWarning`.

    **Returns:** a [`BatchFitResult`][]; ``result[i]`` equals
    ``hybrid.fit(model, recordings[i], ...)`` to rounding.
    """
    t_start = time.perf_counter()
    solver = resolve_solver(solver, "hybrid.fit_batch", max_steps=max_steps, patience=patience)
    if not isinstance(solver, LevenbergMarquardt):
        raise InputError(
            f"fit_batch runs Levenberg-Marquardt only, got {type(solver).__name__}: pass "
            "solver=hybrid.LevenbergMarquardt(...), or use hybrid.fit for another solver"
        )
    model = check_model(model, "fit_batch")
    recordings = as_recordings(recordings, "fit_batch")  # a path is loaded; anything else is refused
    if isinstance(starts, bool) or not isinstance(starts, int) or starts < 1:
        raise InputError(f"starts must be a positive integer, got {starts!r}")
    if batch_size is not None and (not isinstance(batch_size, int) or batch_size < 1):
        raise InputError(f"batch_size must be a positive integer or None, got {batch_size!r}")
    frozen = default_frozen(model) if frozen is None else frozenset(frozen)
    lengths = sorted({r.n for r in recordings})
    if len(lengths) > 1:
        raise InputError(
            f"fit_batch needs recordings of one length, got {lengths} samples: "
            "group them by length, or crop them to a common length"
        )
    rates = [float(r.rate) for r in recordings]
    if max(rates) - min(rates) > RATE_RTOL * min(rates):
        raise InputError(
            f"fit_batch needs recordings of one sample rate, got {min(rates):.9g} to {max(rates):.9g} Hz: "
            "group them by rate, or resample them to a common rate"
        )
    for recording in recordings:
        recording.check_length(
            model.readout.window, f"the model's input window ({model.readout.window} samples)"
        )
        recording.check_signals()
    FIT_PROGRAMS.admit(("fit_batch", *fit_shape_key(model, recordings, starts, solver)))  # as `fit`'s
    series = [series_from_recording(r, split, split_order) for r in recordings]
    for i, s in enumerate(series):
        if s.segments != series[0].segments:  # one compiled program holds one split: its parts are static
            raise InputError(
                f"fit_batch fits recordings split alike, and recording {i} ({recordings[i].name}) has rows of "
                f"quality 0 (w not measured there, left out of every part) at other samples than recording 0 "
                f"({recordings[0].name}): fit such recordings one by one with hybrid.fit, or cut each to "
                "a stretch of quality 1 (Recording.segment) of one length"
            )
        if not np.ptp(np.asarray(s.target("train"))) > 0:
            raise InputError(f"recording {i} ({recordings[i].name}) has constant w on its training part")
        check_training_drive(  # each recording is fitted alone: each needs a training part that moves
            [s],
            [recordings[i]],
            fix=f"Trim recording {i}'s quiet start (Recording.segment), or fit it alone in blocks "
            "(hybrid.fit(..., blocks=5))",
        )

    # One Problem per (recording, start), sharing the static parts of a template.
    # Each recording in its own units, as fit() does (w / std(w_train), v_in / rms(v_in)).
    problems, flat, units, starts_of = [], [], [], []
    template = None
    for s in series:
        w_unit, v_unit = fit_units(model, [s], np.asarray(s.target("train")))
        s = Series(s.v_in / v_unit, s.w / w_unit, series[0].dt, s.segments)  # one rate (`RATE_RTOL`)
        units.append((w_unit, v_unit))
        scaled = Model(
            model.simulation,
            model.readout.rescaled(1.0 / v_unit, 1.0 / w_unit),
            model.kind,
            model.signal_units,
        )
        initial = [_start_jit(scaled, k, seed, frozen, perturbation, [s]) for k in range(starts)]
        starts_of.append(initial)
        problem = Problem(initial[0], [s], frozen, weight_decay)
        if template is None:
            template = problem
        problem = eqx.tree_at(_DYNAMIC, template, _DYNAMIC(problem))
        for m in initial:
            problems.append(problem)
            flat.append(problem.flatten(m, frozen))
    n_fits = len(problems)
    stacked = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *[_arrays(p) for p in problems])
    thetas = jnp.stack(flat)

    devices = list(jax.devices() if devices is None else devices)
    n_dev = len(devices)
    padded = -(-n_fits // n_dev) * n_dev
    if padded > n_fits:  # repeat the last fit so that every device gets the same share
        stacked = jax.tree_util.tree_map(lambda x: repeat_last(x, padded), stacked)
        thetas = repeat_last(thetas, padded)
    settings = solver.lm_settings()
    compiles = process_compiles()
    compiled_before = compiles["s"]
    if n_dev > 1:
        mesh = device_mesh("batch", devices)
        sharding = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("batch"))
        stacked, thetas = jax.device_put((stacked, thetas), sharding)
        out = _fits_sharded(template, stacked, thetas, settings, batch_size, mesh)
    else:
        with jax.default_device(devices[0]):
            out = _fits_compiled(template, stacked, thetas, settings, batch_size)
    out = jax.device_get(out)
    compile_seconds = compiles["s"] - compiled_before
    best_theta, best_val, steps, accepted, best_step, cost, predictions = out

    results = []
    for r, recording in enumerate(recordings):
        rows = range(r * starts, (r + 1) * starts)
        vals = [float(best_val[i]) for i in rows]
        if not np.isfinite(vals).any():  # no start could move
            message = non_finite_fit(model.simulation, [recording])
            raise PluginError(f"fit_batch, recording {r}: {message}", plugin=type(model.simulation))
        k = int(np.nanargmin(vals))
        i = r * starts + k
        problem = problems[i]
        fitted = problem.model(jnp.asarray(best_theta[i]))
        w_unit, v_unit = units[r]
        fitted = Model(
            fitted.simulation,
            readout_back(fitted.readout, model.readout, frozen, v_unit, w_unit),
            fitted.kind,
            recording_units([recording]) or model.signal_units,
        )
        split_metrics = {}
        for name in ("train", "validation", "test"):
            if name in split_order:
                w = np.asarray(problem.target(name))
                split_metrics[name] = compute_metrics(w, predictions[name][i][: w.shape[0]])
        per_start = [
            {
                "validation_loss": float(best_val[j]),
                "steps": int(steps[j]),
                "accepted_steps": int(accepted[j]),
                "best_step": int(best_step[j]),
                "train_cost": float(cost[j]),
            }
            for j in rows
        ]
        results.append(
            FitResult(
                model=fitted,
                parameters={key: float(v) for key, v in fitted.parameters().items()},
                units=fitted.units,
                metrics=split_metrics,
                history=[],
                starts=per_start,
                best_start=k,
                settings={
                    **solver.record(),
                    "batch": True,
                    "starts": starts,
                    "frozen": sorted(frozen),
                    "split": dict(zip(split_order, map(float, split))),
                    "seed": seed,
                    "perturbation": perturbation,
                    "weight_decay": problem.weight_decay,
                    "n_parameters": int(thetas.shape[1]),
                    "n_residuals": int(problem.target("train").shape[0]),
                    "recordings": [recording.metadata.get("source", "")],
                },
                seconds=float("nan"),
                warnings=list(recording.notes)
                + fit_warnings(
                    starts_of[r][k],
                    fitted,
                    frozen,
                    per_start[k],
                    split_metrics.get("train", {}).get("nmse_variance"),
                    rate=recording.rate,
                )
                + drive_outside_range(
                    fitted.simulation, [recording.v_in], (recording_units([recording]) or ("", ""))[1]
                )
                + one_frequency_drive([(recording.v_in, recording.rate)]),
            )
        )
    seconds = time.perf_counter() - t_start
    for i, res in enumerate(results):  # each fit's share of the wall time
        results[i] = dataclasses.replace(res, seconds=seconds / len(results))
    return BatchFitResult(results, seconds, compile_seconds, n_dev, n_fits)


# --------------------------------------------------------------------------- internals
# fit()'s start models, compiled once per start index and reused for every recording
# (run eagerly, the simulation's scans and the least-squares gain compile op by op, per call)
_start_jit = eqx.filter_jit(start_model)

#: A Problem's per-recording parts: the data, w's scale and the drive's unit in θ, the fixed leaves.
_DYNAMIC = lambda p: (p.sim_static, p.readout_static, p.series, p.scale, p.sim_units, p.output_units)


def _arrays(problem):
    """The per-recording arrays of a Problem: data, scale, fixed leaves (scalings, frozen values)."""
    return eqx.filter(_DYNAMIC(problem), eqx.is_array)


def _run_fits(template, arrays, thetas, settings, batch_size):
    """Per-fit results of the stacked problem arrays and θ's: each an LM run on `template` with its arrays."""
    splits = tuple(name for name, _ in template.series[0].segments)
    others = eqx.filter(_DYNAMIC(template), eqx.is_array, inverse=True)

    def one(arrays, theta):
        problem = eqx.tree_at(_DYNAMIC, template, eqx.combine(arrays, others))
        state = lm_init(problem, theta, settings)
        state = lm_run(problem, state, settings, settings.max_steps)
        predictions = {name: problem.prediction(state.best_theta, name) for name in splits}
        return (
            state.best_theta,
            state.best_val,
            state.step,
            state.accepted,
            state.best_step,
            state.cost,
            predictions,
        )

    if batch_size is None:
        return jax.vmap(one)(arrays, thetas)
    return jax.lax.map(lambda a: one(*a), (arrays, thetas), batch_size=batch_size)


# Module-level programs: the template's arrays are arguments, its structure and the settings static
# (`eqx.filter_jit`), so a second call with the same shapes reuses the compiled program (a closure
# jitted per call compiled again every time: 10-15 s per call of ten 1,200-sample recordings).
@eqx.filter_jit
def _fits_compiled(template, arrays, thetas, settings, batch_size):
    return _run_fits(template, arrays, thetas, settings, batch_size)


@eqx.filter_jit
def _fits_sharded(template, arrays, thetas, settings, batch_size, mesh):
    """`_run_fits` on every device of `mesh`, each on its share of the batch; the template replicated."""
    dynamic, static = eqx.partition(template, eqx.is_array)

    def local(dynamic, arrays, thetas):
        return _run_fits(eqx.combine(dynamic, static), arrays, thetas, settings, batch_size)

    spec = jax.sharding.PartitionSpec("batch")
    # check_vma=False: the library's scans start from constants (not device-varying); no
    # collectives are used, so the per-device programs are independent.
    return jax.shard_map(
        local, mesh=mesh, in_specs=(jax.sharding.PartitionSpec(), spec, spec), out_specs=spec, check_vma=False
    )(dynamic, arrays, thetas)


# --------------------------------------------------------------------------- many simulations
def simulate_batch(simulations, v_in, dt: float, *, batch_size: int | None = 8):
    """Mediatory signals of many parameter sets: (B, T), in one compiled program.

    **Arguments:**

    - `simulations`: a list of B simulations of one type and shape (e.g.
      `RCNetwork`s with different parameters), or one simulation whose array
      leaves all have a leading batch axis of size B (as `jax.vmap` makes them).
    - `v_in`: the drive (V), shape (T,) shared by all, or (B, T).
    - `dt`: sample interval (s).
    - `batch_size`: simulations `vmap`-ed together; `lax.map` runs the chunks one
      after the other, so each chunk's (batch_size, T) work stays in cache
      (8 is ~2.5× faster than vmapping 1,000 RC networks at once on a CPU,
      `benchmarks/simulate.py`). None vmaps all of them.
    """
    if isinstance(simulations, (list, tuple)):
        if not simulations:
            raise InputError("no simulations: pass a non-empty list")
        kinds = {type(s) for s in simulations}
        if len(kinds) > 1 or not issubclass(kinds.pop(), AbstractSimulation):
            raise InputError(
                "simulate_batch needs simulations of one type such as hybrid.RCNetwork(), got "
                f"{', '.join(sorted({type(s).__name__ for s in simulations}))}"
            )
        structures = {jax.tree_util.tree_structure(s) for s in simulations}
        shapes = {tuple(jnp.shape(x) for x in jax.tree_util.tree_leaves(s)) for s in simulations}
        if len(structures) > 1 or len(shapes) > 1:
            raise InputError(
                f"simulate_batch needs simulations of one shape, got {type(simulations[0]).__name__}s that "
                "differ in their settings (an order, a number of stages, a discretisation): batch each "
                "kind separately"
            )
        simulations = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *simulations)
    if not isinstance(simulations, AbstractSimulation):
        raise InputError(
            f"simulate_batch needs a list of simulations such as hybrid.RCNetwork(), got "
            f"{type(simulations).__name__}"
        )
    check_dt(dt, "simulate_batch")
    v_in = jnp.asarray(v_in)
    if v_in.ndim not in (1, 2):
        raise InputError(f"v_in must have shape (T,) or (B, T), got {v_in.shape}")
    sizes = {int(jnp.shape(x)[0]) for x in jax.tree_util.tree_leaves(simulations) if jnp.ndim(x) > 0}
    if v_in.ndim == 2 and sizes and sizes != {v_in.shape[0]}:
        raise InputError(
            f"v_in has {v_in.shape[0]} drives (shape {v_in.shape}) for {min(sizes)} simulations: give one "
            "drive per simulation, shape (B, T), or one drive shared by all, shape (T,)"
        )
    if batch_size is not None and (not isinstance(batch_size, int) or batch_size < 1):
        raise InputError(f"batch_size must be a positive integer or None, got {batch_size!r}")
    return _simulate_batch(simulations, v_in, float(dt), batch_size)


@eqx.filter_jit
def _simulate_batch(simulations, v_in, dt, batch_size):
    shared = v_in.ndim == 1

    def one(args):
        simulation, v = args if not shared else (args, v_in)
        return simulation.simulate(v, dt)

    xs = simulations if shared else (simulations, v_in)
    if batch_size is None:
        return jax.vmap(one)(xs)
    return jax.lax.map(one, xs, batch_size=batch_size)
