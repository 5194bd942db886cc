"""Starting points for `diagnose`'s LM lanes: designs screened by one simulation each.

The RC network's loss surface has broad plateaus, and an effect switched on
from the effect-free fit often stays in that fit's basin (the baseline absorbs
part of a dead time, a loop or a mode as extra lag). So the starts come from
screening: a scrambled Sobol design over the simulation's typical ranges, each point
simulated once, with the gain and offset — and, jointly with an effect, the
effect's linear parameters — by least squares.

- `hybrid.core._screen.screened_starts`: the network alone (the baseline's `N_LANES` starts).
- `delay_starts`: the network with the drive shifted by each of `DELAY_SHIFTS`.
- `hysteresis_starts`: the network plus a Bouc–Wen loop at each of `LOOP_RATES`.
- `resonance_starts`: the network followed by a mode at each frequency of
  `mode_frequencies` and damping of `MODE_DAMPINGS`.
- `joint_starts` (public, `hybrid.joint_starts`): any effect at given values, for a plug-in's
  `screened_starts`.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..core._devices import map_rows
from ..core._loop_safe_linalg import lstsq
from ..core._problem import Problem
from ..core._screen import (
    SCREEN_CHUNK,
    least_finite,
    screen_design,
    screen_design_losses,
    train_weights,
)
from ..util._errors import InputError
from ._effects import Resonance
from ._hysteresis import bouc_wen_and_memory

#: Design points (the first of the baseline's design) screened jointly with an effect: one chunk.
N_JOINT_SCREEN = SCREEN_CHUNK
#: Dead times (samples) screened for the delay candidate's starts.
DELAY_SHIFTS = (2, 4, 7, 10, 13)


#: How many standard errors of a correlation under independence (1/√m) the prewhitened response must
#: reach, and what share of its largest, for `dead_times` to read where it starts.
ONSET_Z = 5.0
ONSET_SHARE = 0.2
#: The shifts `dead_times` gives around the onset it reads: from `ONSET_BEFORE` samples before it to one after.
#: A held drive's response starts a sample after its dead time (a lag's ZOH step) and a second-order one's
#: crosses a fifth of its peak a few samples later still; the delay objective has a basin every few samples,
#: so LM keeps the one it starts in (a 60-sample delay started at the onset read, 61, ended at 61.07).
ONSET_BEFORE = 8


def dead_times(drive, w, order: int = 10) -> tuple[int, ...]:
    """Whole-sample shifts around where the recorded output starts to follow the drive, read from the data
    alone, where it starts beyond `DELAY_SHIFTS`; () where it does not, or where no start is clear.

    The drive is whitened by its own AR(`order`) model and w filtered by the same model, so that their
    cross-correlation at lag k is proportional to the system's impulse response there (Box and Jenkins).
    Its onset is its first lag over `ONSET_SHARE` of its largest and `ONSET_Z` standard errors of a
    correlation of independent series, lags up to an eighth of the record; the shifts run from
    `ONSET_BEFORE` samples before the onset to one after it. A probe's 2 s dead time at 50 Hz (100 samples,
    a 0.3 s lag behind it) was never tried: the screened shifts stop at 13 samples and the effect-free
    model could not mimic it (held-out NMSE 1.2). A plant without one reads an onset of 1–3 (a lag, an
    oscillator).
    """
    u = np.asarray(drive, float) - float(np.mean(drive))
    y = np.asarray(w, float) - float(np.mean(w))
    n = u.size
    max_lag = n // 8
    if y.size != n or max_lag <= DELAY_SHIFTS[-1] or not np.ptp(u) > 0 or n < 4 * (order + max_lag):
        return ()

    def rows(x):  # [x_{i-1}, ..., x_{i-order}] for i = order..n-1
        return np.stack([x[order - j : n - j] for j in range(1, order + 1)], axis=1)

    a = np.linalg.lstsq(rows(u), u[order:], rcond=None)[0]
    fu, fy = u[order:] - rows(u) @ a, y[order:] - rows(y) @ a
    size = 1 << int(math.ceil(math.log2(2 * fu.size)))
    c = np.fft.irfft(np.conj(np.fft.rfft(fu, size)) * np.fft.rfft(fy, size), size)[: max_lag + 1]
    scale = math.sqrt(float(fu @ fu) * float(fy @ fy))
    if not scale > 0:
        return ()
    r = np.abs(c) / scale
    top, clear = float(np.max(r)), ONSET_Z / math.sqrt(fu.size)
    if not top >= clear:
        return ()
    onset = int(np.argmax(r >= max(ONSET_SHARE * top, clear)))
    # a slow plant's response peaks late but starts at once: only a late start is a dead time
    return tuple(range(max(onset - ONSET_BEFORE, 1), onset + 2)) if onset > DELAY_SHIFTS[-1] else ()


def _recorded_mask(series):
    """1 on the recorded samples of a series (every split), 0 on a padded series' padding."""
    if series.weights is None:
        return jnp.ones_like(series.v_in)
    return sum(weight for _, weight in series.weights)


def with_drives(problem: Problem, change) -> Problem:
    """The problem with every drive replaced by `change(v)` (numpy in, numpy out, the same length).

    On the host: the screen that sees the changed drive is the program it was for the drive itself,
    compiled once, whatever the change (a shift, a map through a drive-side effect)."""
    series = tuple(
        eqx.tree_at(lambda s: s.v_in, s, jnp.asarray(change(np.asarray(s.v_in)))) for s in problem.series
    )
    return eqx.tree_at(lambda p: p.series, problem, series)


def delayed(problem: Problem, shift: int) -> Problem:
    """The problem with every drive delayed by `shift` samples (at rest, 0 V, before the recording)."""
    return with_drives(problem, lambda v: np.concatenate([np.zeros(shift, v.dtype), v[:-shift]]))


def delay_starts(
    problem, simulation, rate: float, n_starts: int, frozen=frozenset(), more: tuple[int, ...] = ()
) -> list[dict]:
    """Starts for the delay candidate: the network screened jointly with the dead time.

    Effect-free, the baseline mimics a dead time by slower stages; from there
    LM with the delay switched on must undo the network and shift the delay at
    once, across the delay objective's one-basin-per-few-samples ridges (delay
    seed 3 of `experiments/discrepancy.py`: 12 samples, baseline 138× the noise
    variance, the delay candidate from the baseline gained 1.6×). Screening
    the design (its first `N_JOINT_SCREEN` points) with the drive shifted by each
    of `DELAY_SHIFTS` samples (and `more`: the record's own `dead_times`) puts the network and the delay in
    the same basin; the `n_starts` best pairs, with distinct shifts, are returned.
    """
    design, names, raws, band = screen_design(problem, simulation, frozen, keep=N_JOINT_SCREEN)
    if not names:
        return []
    best = []
    for shift in dict.fromkeys((*DELAY_SHIFTS, *more)):
        losses = np.where(band, screen_design_losses(delayed(problem, shift), simulation, raws), np.inf)
        i = int(np.argmin(losses))
        best.append((float(losses[i]), shift, i))
    best.sort()
    return [{**{k: design[i][k] for k in names}, "delay_s": shift / rate} for _, shift, i in best[:n_starts]]


#: Bouc–Wen rates screened for the hysteresis candidate's starts, in units of 1/range of V_o:
#: after a reversal the loop reaches its other branch (within 4 %) after an excursion of about
#: 2.8/k (π/4 to cross zero, 2 more), 70 % to 3 % of the range.
LOOP_RATES = (4.0, 10.0, 25.0, 100.0)


@eqx.filter_jit
def loop_screen(problem, simulation, raws, rates):
    """Training MSE of `simulation` plus a Bouc–Wen loop at each row of `raws` and each rate.

    The loop is linear in its height and, to first order, in its initial state:
    with u(s; k) from a neutral start and m = ∂u/∂u₀ its memory of that start,
    w ≈ a·s + b·u + d·m + c by least squares, so one simulation per row screens
    every rate with the best height W = b/a and initial state u₀ ≈ d/b. Returns
    (loss, k, W, u₀) per row and rate, in the terms of
    [`hybrid.discovery._effects.Hysteresis`][].
    """
    w, weights = problem.target("train"), train_weights(problem)

    def one(raw):
        sim = simulation.with_raw(raw)
        signals = [sim.simulate(series.v_in, series.dt) for series in problem.series]
        recorded = [
            jnp.where(_recorded_mask(series) > 0, x, x[0]) for x, series in zip(signals, problem.series)
        ]
        span = jnp.maximum(jnp.max(jnp.stack([jnp.ptp(x) for x in recorded])), 1e-12)  # over every recording

        def train(columns):
            return jnp.concatenate(
                [x[a:b] for x, series in zip(columns, problem.series) for a, b in series.segments_of("train")]
            )

        s = train(signals)

        def fit(k):
            loops = [bouc_wen_and_memory(x, k) for x in signals]
            u, memory = train([u for u, _ in loops]), train([m for _, m in loops])
            design = jnp.stack([s, u, memory, jnp.ones_like(s)], axis=1) * weights[:, None]
            coef, rss = lstsq(design, w * weights)  # no LAPACK in a batched loop (_loop_safe_linalg)
            loss = rss / jnp.sum(weights)
            a, b, d = coef[0], coef[1], coef[2]
            height = jnp.clip(b / jnp.where(jnp.abs(a) > 0, a, 1.0), -span, span)
            initial = jnp.clip(d / jnp.where(jnp.abs(b) > 0, b, 1.0), -0.95, 0.95)
            return jnp.where(jnp.isfinite(loss), loss, jnp.inf), k, height, initial

        return jax.vmap(fit)(jnp.asarray(rates) / span)

    return map_rows(one, raws, batch_size=16)


def hysteresis_starts(problem, simulation, n_starts: int, frozen=frozenset()) -> list[dict]:
    """Starts for the hysteresis candidate: the network screened jointly with a Bouc–Wen loop.

    Effect-free, the baseline absorbs part of a loop as lag (other ξρ and α's):
    the falling branch lies behind the rising one, as a slow stage's output
    does. From there LM with the loop switched on can stay in the baseline's
    basin (hysteresis seed 6 of `experiments/discrepancy.py`, C_clamp 2 mF, a
    loop of 20 % of the range: held-out gain 1.8 from the data-scaled starts of
    `_starts`, 16 with this one; measured with the n = 1 element). Screening
    the design (its first `N_JOINT_SCREEN` points) with the loop's best height
    and initial state at each of `LOOP_RATES` puts the network and the loop in
    the same basin; the `n_starts` best are returned.
    """
    design, names, raws, band = screen_design(problem, simulation, frozen, keep=N_JOINT_SCREEN)
    if not names:
        return []
    losses, ks, heights, initials = (
        np.asarray(x) for x in loop_screen(problem, simulation, raws, LOOP_RATES)
    )
    losses = np.where(band[:, None], losses, np.inf)
    order = least_finite(losses, n_starts)
    starts = []
    for flat in order:
        i, j = np.unravel_index(flat, losses.shape)
        starts.append(
            {
                **{k: design[i][k] for k in names},
                "hysteresis_height": float(heights[i, j]),
                "hysteresis_rate": float(ks[i, j]),
                "hysteresis_initial_state": float(initials[i, j]),
            }
        )
    return starts


#: Damping ratios screened for the resonance candidate's starts (the issue's modes: ζ 0.02–0.3).
MODE_DAMPINGS = (0.03, 0.1, 0.3)


def mode_frequencies(rate: float) -> np.ndarray:
    """Mode frequencies (Hz) screened for the resonance candidate: 1 Hz to min(10 Hz, 0.45 × rate), 15 % apart."""
    top = min(10.0, 0.45 * rate)
    return np.geomspace(1.0, top, max(2, math.ceil(math.log(top) / math.log(1.15)) + 1))


@eqx.filter_jit
def mode_screen(problem, simulation, raws, frequencies, dampings):
    """Training MSE of `simulation` followed by a mode, at each row of `raws` and each (f, ζ).

    The mode ([`hybrid.discovery._effects.Resonance`][], unity DC gain, its own
    recurrence) is linear, so with the gain and offset by least squares one
    simulation per row screens every (f, ζ) pair (`frequencies` and
    `dampings`, paired element-wise). The least squares need only sums over the
    training samples, so each mode's output is summed as the recurrence steps
    (`_mode_sums`) rather than kept, and all rows step together: one pass over
    the samples for the whole screen. Returns the losses, shape (rows, pairs).
    """
    constraints = Resonance.constraints
    raw_f = constraints["resonance_frequency_hz"].to_raw(jnp.asarray(frequencies, float))
    raw_z = constraints["resonance_damping"].to_raw(jnp.asarray(dampings, float))

    def recurrences(dt):  # each pair's (Φ, Γ₀, Γ₁), stacked: (pairs, 2, 2), (pairs, 2), (pairs, 2)
        def one(f, z):
            mode = eqx.tree_at(
                lambda m: m.raw, Resonance(), {"resonance_frequency_hz": f, "resonance_damping": z}
            )
            return mode.recurrence(dt, raw_f.dtype)

        return jax.vmap(one)(raw_f, raw_z)

    def outputs(raw):
        sim = simulation.with_raw(raw)
        return [sim.simulate(series.v_in, series.dt) for series in problem.series]

    signals = map_rows(outputs, raws, batch_size=16)  # per recording: (rows, samples)
    w, weights = problem.target("train"), train_weights(problem)
    full, used = [], 0  # each recording's training weights and targets over its samples (0 elsewhere)
    for series in problem.series:
        omega, target = jnp.zeros_like(series.v_in), jnp.zeros_like(series.v_in)
        for a, b in series.segments_of("train"):
            omega = omega.at[a:b].add(weights[used : used + b - a])
            target = target.at[a:b].set(w[used : used + b - a])
            used += b - a
        full.append((omega, target))
    n = sum(jnp.sum(omega) for omega, _ in full)
    # Centred: the offset absorbs a constant, and the sums' cancellation stays at the residual's scale.
    w_mean = sum(jnp.sum(omega * target) for omega, target in full) / n
    s_mean = sum(x @ omega for x, (omega, _) in zip(signals, full)) / n
    mats = [recurrences(series.dt) for series in problem.series]

    def row_sums(row):
        xs, mean = row
        return sum(
            _mode_sums(m, x - mean, omega, target - w_mean) for m, x, (omega, target) in zip(mats, xs, full)
        )

    sums = map_rows(row_sums, (signals, s_mean), batch_size=s_mean.shape[0])  # one batch: all rows
    s1, s2, sw = sums[..., 0], sums[..., 1], sums[..., 2]
    w2 = sum(jnp.sum(omega * (target - w_mean) ** 2) for omega, target in full)
    # The least-squares residual with a gain and an offset; the target is centred (Σω·(w − w̄) = 0),
    # so it is Σω·(w − w̄)² less the gain's share, gain = n·Σωyw / (n·Σωy² − (Σωy)²).
    det = n * s2 - s1**2
    sloped = det > 1e-12 * n * s2  # a constant output: the offset alone
    gain = jnp.where(sloped, n * sw / jnp.where(sloped, det, 1.0), 0.0)
    loss = jnp.maximum(w2 - gain * sw, 0.0) / n
    return jnp.where(jnp.isfinite(loss), loss, jnp.inf)


def _mode_sums(mats, x, omega, target):
    """Σω·y, Σω·y², Σω·y·target of one signal `x` through each mode, shape (modes, 3).

    `mats`: the modes' `Resonance.recurrence`, stacked; the recurrence is
    `Resonance.apply`'s (from rest at the first value), all modes at once.
    """
    phi, g0, g1 = mats
    dx = jnp.diff(x, append=x[-1:])
    state = jnp.zeros(phi.shape[:2], x.dtype).at[:, 0].set(x[0])

    def step(carry, inputs):
        state, sums = carry
        s, ds, weight, wt = inputs
        y = state[:, 0]
        sums = sums + weight * jnp.stack([y, y * y, y * wt], axis=-1)
        state = jnp.einsum("mij,mj->mi", phi, state) + g0 * s + g1 * ds
        return (state, sums), None

    (_, sums), _ = jax.lax.scan(step, (state, jnp.zeros((phi.shape[0], 3), x.dtype)), (x, dx, omega, target))
    return sums


def resonance_starts(problem, simulation, rate: float, n_starts: int, frozen=frozenset()) -> list[dict]:
    """Starts for the resonance candidate: the network screened jointly with a mode.

    Effect-free, the baseline absorbs a well-damped mode as lag (faster
    stages with a dead-time-like phase): from there LM with the mode switched
    on can stay in that basin, and a dead time can explain the lag better than
    the mode it reached (resonance seed 9 of `experiments/discrepancy.py`,
    5.5 Hz, ζ 0.27: the resonance fit gained 1.2, the delay fit 2.2). Screening
    the design (its first `N_JOINT_SCREEN` points) with a mode at each of
    `mode_frequencies(rate)` × `MODE_DAMPINGS` puts the network and the mode in
    the same basin; the `n_starts` best are returned.
    """
    design, names, raws, band = screen_design(problem, simulation, frozen, keep=N_JOINT_SCREEN)
    if not names:
        return []
    grid = [(f, z) for f in mode_frequencies(rate) for z in MODE_DAMPINGS]
    losses = np.asarray(
        mode_screen(problem, simulation, raws, np.array([f for f, _ in grid]), np.array([z for _, z in grid]))
    )
    losses = np.where(band[:, None], losses, np.inf)
    order = least_finite(losses, n_starts)
    starts = []
    for flat in order:
        i, j = np.unravel_index(flat, losses.shape)
        starts.append(
            {
                **{k: design[i][k] for k in names},
                "resonance_frequency_hz": float(grid[j][0]),
                "resonance_damping": float(grid[j][1]),
            }
        )
    return starts


#: Limits screened for a state-limit candidate's starts, as fractions of the state's peak at each
#: design point: a limit only acts below the peak, and where depends on the design point's levels.
LIMIT_FRACTIONS = (0.5, 0.7, 0.9)
#: A spilling limit's shares screened with each fraction: nearly all of the cut lost, half, all of it
#: moved. A share far from the truth can hold LM in another basin (an overflow that was lost, started at
#: half: gain 9.5 where the limit without a spill reached 39, `experiments/inside_effects.py` overflow seed 1).
SPILL_SHARES = (0.02, 0.5, 1.0)


@eqx.filter_jit
def state_peaks(
    problem, simulation, states: str | tuple[str, ...], raws, swing: bool = False, lowest: bool = False
):
    """The largest value of any of `states` on the training part at each row of `raws` (the limit off).

    `swing`: the largest swing |x − x_rest| from where each state rests under no drive instead;
    `lowest`: the largest of −x (minus the lowest value: a floor's screen).
    """
    from ..core._state_space import dynamics_of, integrate
    from ._effect_stack import rest_state

    def one(raw):
        core, held, skip = dynamics_of(simulation.with_raw(raw))  # a state limit needs a state-space form
        ks = jnp.asarray([core.states.index(s) for s in ((states,) if isinstance(states, str) else states)])
        if swing:
            rest = jnp.stack(rest_state(core, jnp.result_type(float)))[ks]
        peaks = []
        for series in problem.series:
            x = integrate(core, held(series.v_in), series.dt)[1][skip:][:, ks]
            x = jnp.abs(x - rest) if swing else -x if lowest else x
            peaks += [jnp.max(x[a:b]) for a, b in series.segments_of("train")]
        return jnp.max(jnp.stack(peaks))

    return map_rows(one, raws, batch_size=16)


def limit_starts(
    problem,
    simulation,
    effect,
    level: str,
    n_starts: int,
    frozen=frozenset(),
    share: str | None = None,
    swing: bool = False,
    lowest: bool = False,
) -> list[dict]:
    """Starts for a limit on states (`effect.bounded_states`): the simulation's design screened jointly with it.

    From the effect-free fit a limit switched on rarely moves far: that fit has
    already bent its parameters to reach the clipped levels some other way (on
    the Cascaded Tanks, the overflow model's upper outlet is 10× smaller than
    the Torricelli fit's). So each point of the design (its first
    `N_JOINT_SCREEN`) is screened with the limit at each of `LIMIT_FRACTIONS`
    of that point's own peak of the state (a spilling limit: with each of
    `SPILL_SHARES` too); the `n_starts` best, with distinct fractions, are
    returned.

    `level`: the effect's parameter set to those fractions; `share`: its spill's
    share, screened at each of `SPILL_SHARES` (None: it has none); `swing`: the
    fractions are of the states' largest swing from where they rest (a window
    ±L about rest) rather than of their peak (a ceiling L); `lowest`: of their
    trough (a floor L: each level the fraction of the lowest value).
    """
    from ._effect_stack import EffectStack

    design, names, raws, band = screen_design(problem, simulation, frozen, keep=N_JOINT_SCREEN)
    if not names:
        return []
    sign = -1.0 if lowest else 1.0
    peaks = sign * np.asarray(
        state_peaks(problem, simulation, tuple(effect.bounded_states), raws, swing, lowest)
    )
    stack = EffectStack(simulation, [effect])
    best = []
    for fraction in LIMIT_FRACTIONS:
        levels = fraction * peaks
        row = {**raws, level: jnp.asarray(effect.constraints[level].to_raw(levels))}
        found = []
        for extra in [{share: spill} for spill in SPILL_SHARES] if share else [{}]:
            shares = {k: jnp.full(len(levels), effect.constraints[k].to_raw(v)) for k, v in extra.items()}
            losses = np.where(
                np.isfinite(levels) & band, screen_design_losses(problem, stack, {**row, **shares}), np.inf
            )
            i = int(np.argmin(losses))
            found.append((float(losses[i]), fraction, i, {level: float(levels[i]), **extra}))
        best.append(min(found, key=lambda item: item[0]))
    best.sort(key=lambda item: item[0])
    return [{**{k: design[i][k] for k in names}, **values} for _, _, i, values in best[:n_starts]]


def joint_starts(context, effect, values, n_starts: int) -> list[dict]:
    """Starts for `effect` with the simulation screened jointly: for a plug-in's `screened_starts`.

    From the current model's fit an effect switched on often stays in that
    fit's basin: the fit has already bent the simulation's parameters to mimic
    the effect some other way (a sensor that cannot see sign: the effect-free
    fit of |y| is no oscillator at all). So each of the first `N_JOINT_SCREEN`
    points of the simulation's design (`start_design`: a Sobol design over its
    `typical_ranges`, the current values first) is simulated once with the
    effect on at each of `values` (dicts of some of its parameters, the others
    at the effect's current values), the readout's gain and offset by least
    squares; the best point for each of `values` is kept, and the `n_starts`
    best of those are returned, each a start dict of the simulation's
    parameters and the effect's.

    **Arguments:**

    - `context`: the `StartContext` that `screened_starts(context)` gets (its
      `problem`, `simulation` and `frozen`).
    - `effect`: the effect (``self`` in `screened_starts`).
    - `values`: the effect's values to screen, e.g. those of its `starts`.
    - `n_starts`: at most this many starts (the class's `n_screened`).

    An effect inside the dynamics gets the simulation itself in `context` and
    is screened on it; a drive- or output-side one the model extended so far.
    A drive-side effect is screened with the drive mapped through it (at each of
    `values`) before that model, on the host (`with_drives`).
    """
    from ._effect_stack import EffectStack

    simulation = context.simulation
    if context.problem is None or simulation is None:
        raise InputError(
            f"joint_starts({type(effect).__name__}) needs the StartContext of screened_starts (its problem "
            "and simulation): call it from screened_starts(context), not from starts(context)"
        )
    in_stack = isinstance(simulation, EffectStack) and effect.name in simulation.effect_names
    if in_stack:
        at = simulation.effect_names.index(effect.name)
        effect = simulation.effects[at]
    unknown = sorted({k for given in values for k in given} - set(effect.constraints))
    if unknown:
        raise InputError(
            f"joint_starts({type(effect).__name__}): values {values!r} name {', '.join(unknown)}, which are "
            f"not its parameters ({', '.join(effect.constraints)})"
        )
    # A drive-side effect maps the drive on the host into the model extended so far, the effect off: its
    # screen is then the program every drive-side screen shares (the delay's), compiled once, where the
    # effect switched on in the stack compiles one of its own (for drive_even, 1.29× against 1.25× on
    # the first call of benchmarks/diagnose_effect_set.py: docs/benchmarks.md). The map goes before the
    # drive-side effects named so far, not at its place among them: a start, which the lane's fit puts right.
    on_host = in_stack and effect.place == "drive"
    if in_stack:
        active = np.asarray(simulation.active, float).copy()
        active[at] = 0.0 if on_host else 1.0
        stack = simulation.with_active(active)
    else:  # the simulation itself (an inside effect's screen), with this effect alone
        stack = EffectStack(simulation, [effect])
    design, names, raws, band = screen_design(context.problem, stack, context.frozen, keep=N_JOINT_SCREEN)
    dt, n = float(context.problem.series[0].dt), len(design)
    best = []
    for k, given in enumerate(values):
        if on_host:
            mapped = effect.with_values(**given)
            problem = with_drives(
                context.problem, lambda v, m=mapped: np.asarray(m.apply(jnp.asarray(v), dt))
            )
            row = raws
        else:  # the effect's values as columns of the design
            problem = context.problem
            row = {
                **raws,
                **{
                    name: jnp.asarray(effect.constraints[name].to_raw(np.full(n, float(value))))
                    for name, value in given.items()
                },
            }
        losses = np.where(band, screen_design_losses(problem, stack, row), np.inf)
        i = int(np.argmin(losses))
        if np.isfinite(losses[i]):
            best.append((float(losses[i]), k, {**{name: design[i][name] for name in names}, **given}))
    best.sort(key=lambda item: item[:2])
    return [start for *_, start in best[:n_starts]]
