"""Design the drive that tells rival explanations apart: `design_drive`.

When a recording cannot tell two explanations of the same data apart
(``report.json`` → ``ambiguous``), another experiment can: a drive under which
the rivals' predictions differ most. `design_drive` computes it by gradient
through the differentiable rival models, within the rig's limits.

**Criterion: T-optimality** (Atkinson & Fedorov 1975, "The design of
experiments for discriminating between two rival models"), local at the
rivals' fitted parameters:

    T(u) = (1/n) Σ_k (ŵ_a(u)_k − ŵ_b(u)_k)² / σ²,

the mean squared difference of two rivals' predicted outputs in units of the
measurement noise's variance σ² (the diagnosis's noise floor). n·T is the
non-centrality of the lack-of-fit test of one rival when the other is true:
the larger, the surer a recording under u rejects the wrong one. With more
than two rivals the design maximises the smallest pairwise T (a soft minimum
for the gradient; the pair named is reported). Why T and not Box–Hill: with
Gaussian noise of one known σ and equal prior weights, Box–Hill's expected
entropy change grows with the same squared separation, and T needs no prior
model probabilities. Local means the rivals keep their fitted parameters;
refitted on the new recording, the wrong one absorbs part of the difference,
which is why the loop is closed by diagnosing the old and new recordings
together, not by trusting T alone.

**Limits by construction**, not by penalty: projected gradient ascent. After
each Adam step (optax) on the drive's samples, the drive is made feasible
again (`_feasible`: clipped to the range, then each step to ±s·Δt in turn), so
every drive visited, and the one returned, respects the range and the slew
exactly; a parameterisation through tanh instead starved the gradient while
the drive slewed.
The samples are `duration`·`rate` at the rig's `rate`. Several starts
(`starts`, multilevel PRBS) are optimised and the best drive visited is kept; the result
carries the criterion of a multilevel PRBS of the same length and range (the
control) for comparison.

**A rich part, kept** (`rich`): the T-optimal drive for two rivals is often
bang-bang (all its samples at the range's ends), and a recording under it
tells those two apart but nothing else: the diagnosis of the old and new
recordings together must still fit every effect present, and a level-dependent
one (a saturation's curvature) is not seen at two levels (on
`experiments/design_loop.py`'s back_relaxation+saturation seed 1 the joint
diagnosis then named an even response instead of the saturation it had named
before). `rich` ∈ [0, 1) keeps that share of the drive, at its start, as the
control's multilevel PRBS and designs the rest, with T over the whole drive: a
compound design in the spirit of Atkinson's DT-optimum designs
(discrimination and estimation in one experiment). Half by default: on that
draw the joint diagnosis then kept the saturation (T 0.39 against 1.18 all
designed; the control's 0.11); over the loop's twelve designed draws the
count fully named did not move and one wrong name replaced another
(`experiments/results/design_loop.md`), at about half the T. 0: all designed.
"""

from __future__ import annotations

import dataclasses
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..core._models import Model
from ..util._errors import InputError
from ..util._watchdog import stage
from ._diagnosis import MIN_DIAGNOSE_SAMPLES


@dataclasses.dataclass(frozen=True)
class DriveDesign:
    """A designed drive and what it is expected to show (`design_drive`)."""

    t: np.ndarray
    """Sample times, s."""
    v_in: np.ndarray
    """The drive, in the drive's unit, within the limits given."""
    criterion: float
    """T of the drive: mean squared difference of the two closest rivals' predictions / σ²."""
    control_criterion: float
    """T of the control: a multilevel PRBS of the same length and range, slew-limited alike."""
    rich_samples: int
    """Samples at the drive's start kept as the control's multilevel PRBS (`rich`), not designed."""
    pair: tuple[str, str]
    """The two rivals whose predictions are closest under the drive (the criterion's pair)."""
    predictions: dict
    """Each rival's predicted output under the drive, by name."""
    limits: dict
    """The limits the drive respects: ``low``, ``high``, ``slew`` (None: none), ``rate``, ``duration``,
    the rivals' predicted output's ``output_low``, ``output_high`` (None: none), and the shortest ``hold`` (s)."""
    criteria_by_start: list
    """T reached from each random start (the best is kept)."""


def _check(name, value, positive=True, who="design_drive"):
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(f"{who}: {name} must be a finite number, got {value!r}")
    if positive and value <= 0:
        raise InputError(f"{who}: {name} must be > 0, got {value!r}")
    return float(value)


#: The most samples a designed (or rich) drive has: 9 h at 30 Hz, 27 min at the Silverbox's 610 Hz.
MAX_SAMPLES = 1_000_000


def _limits(who, duration, rate, amplitude, bounds, slew):
    """(samples, Δt, low, high, slew) of a drive within the rig's limits, each checked (one line if not)."""
    duration, rate = _check("duration", duration, who=who), _check("rate", rate, who=who)
    if amplitude is not None and bounds is not None:
        raise InputError(
            f"{who}: give the drive's range once, as amplitude=A (|u| ≤ A) or bounds=(low, high), not both"
        )
    if amplitude is None and bounds is None:
        raise InputError(f"{who}: give the drive's range as amplitude=A (|u| ≤ A) or bounds=(low, high)")
    if amplitude is not None:
        low, high = -_check("amplitude", amplitude, who=who), _check("amplitude", amplitude, who=who)
    else:
        low, high = _pair(who, "bounds", bounds)
    if slew is not None:
        slew = _check("slew", slew, who=who)
    n = int(round(duration * rate))
    if n < MIN_DIAGNOSE_SAMPLES:  # a recording under it could not be diagnosed (a probe's 0.5 s design)
        raise InputError(
            f"{who}: {duration:g} s at {rate:g} Hz is {n} samples, fewer than the {MIN_DIAGNOSE_SAMPLES} "
            f"diagnose reads a recording from: give a duration of at least {MIN_DIAGNOSE_SAMPLES / rate:.3g} s "
            "(better several of the system's slowest time constant)"
        )
    if n > MAX_SAMPLES:
        raise InputError(
            f"{who}: {duration:g} s at {rate:g} Hz is {n:.3g} samples, more than the {MAX_SAMPLES:,} a drive "
            f"may have (the design differentiates every rival through all of them): at most "
            f"{MAX_SAMPLES / rate:.6g} s at this rate"
        )
    return n, 1.0 / rate, low, high, slew


def rich_drive(
    *,
    duration: float,
    rate: float,
    amplitude: float | None = None,
    bounds: tuple[float, float] | None = None,
    slew: float | None = None,
    seed: int = 0,
    hold: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(t, drive): a multilevel PRBS within the rig's limits, the drive to record where nothing is ambiguous.

    The design's control (`DriveDesign.control_criterion`): levels uniform over
    the range, each held 0.5–5 s, slew-limited like a design. What `hybrid
    design` writes when a diagnosis leaves a remainder that no searched effect
    explains and no rivals to tell apart: a rich drive, so that the recordings
    diagnosed together carry what one did not. Limits as `design_drive`'s
    (`hold`: each level held at least that long, up to twice it or 5 s).
    """
    n, dt, low, high, slew = _limits("rich_drive", duration, rate, amplitude, bounds, slew)
    hold_s = 0.0 if hold is None else _check("hold", hold, who="rich_drive")
    drive = _control(_levels(n, low, high, dt, seed, hold_s), low, high, slew, dt)
    return np.arange(n) / rate, drive


def _feasible(u, low, high, slew, dt):
    """`u` made to respect the limits: clipped to [low, high], then each step to ±slew·Δt in turn.

    The forward pass keeps every sample in the range (each is clipped into
    [low, high] ∩ [u_{k−1} − sΔt, u_{k−1} + sΔt], never empty) and every step
    within the slew; it is the identity on a drive that already respects both.
    """
    u = jnp.clip(u, low, high)
    if slew is None:
        return u
    reach = slew * dt

    def follow(previous, wanted):
        now = jnp.clip(wanted, previous - reach, previous + reach)
        return now, now

    return jnp.concatenate([u[:1], jax.lax.scan(follow, u[0], u[1:])[1]])


#: Weight of the squared excursion of a rival's predicted output beyond `output_bounds` (in units of
#: σ², as T is) in the design's loss: a step past the bound costs far more than it can separate.
OUTPUT_WEIGHT = 100.0
#: Shares of the range's half-width, around its middle, that the control's levels are narrowed to, in
#: turn, until every rival's prediction under the control keeps within `output_bounds`.
NARROWED = (1.0, 0.75, 0.5, 0.35, 0.25, 0.15, 0.1, 0.05)


def _pair(who: str, name: str, value) -> tuple[float, float]:
    """(low, high) of a range argument `name`, both finite and low < high (one line if not)."""
    if not isinstance(value, (tuple, list)) or len(value) != 2:
        raise InputError(f"{who}: {name} must be (low, high), got {value!r}")
    low = _check(f"{name}' low", value[0], False, who)
    high = _check(f"{name}' high", value[1], False, who)
    if not low < high:
        raise InputError(f"{who}: {name} must have low < high, got {value!r}")
    return low, high


def _beyond(outs, output) -> jax.Array:
    """The mean squared excursion of the predictions `outs` beyond the output's range, summed over rivals."""
    if output is None:
        return jnp.zeros(())
    low, high = output
    return jnp.sum(
        jnp.stack([jnp.mean(jax.nn.relu(o - high) ** 2 + jax.nn.relu(low - o) ** 2) for o in outs])
    )


def _within(outs, output) -> jax.Array:
    """Whether every prediction in `outs` keeps within the output's range (and is finite)."""
    if output is None:
        return jnp.all(jnp.stack([jnp.all(jnp.isfinite(o)) for o in outs]))
    low, high = output
    return jnp.all(jnp.stack([jnp.all((o >= low) & (o <= high)) for o in outs]))


def _pulled_back(u, control, evaluate, output, halvings: int = 12) -> tuple[float, jax.Array]:
    """(least T, drive): the drive nearest `u` on the way to `control` whose predictions keep within `output`.

    `control` keeps within, and every drive between two that respect the
    range and the slew respects them too (a convex set): bisection on
    control + α (u − control), α ∈ [0, 1], `halvings` times.
    """
    low, high = 0.0, 1.0
    for _ in range(halvings):
        mid = 0.5 * (low + high)
        if bool(_within(evaluate(control + mid * (u - control))[1][1], output)):
            low = mid
        else:
            high = mid
    drive = control + low * (u - control)
    pairs = evaluate(drive)[1][0]
    return float(jnp.min(pairs)), drive


def _criterion(models, u, dt, noise_std, softness):
    """(soft minimum over pairs of T, T of every pair, each model's prediction) for the drive `u`."""
    outs = [m.predict(u, dt) for m in models]
    pairs = jnp.stack(
        [jnp.mean((outs[i] - outs[j]) ** 2) for i in range(len(outs)) for j in range(i + 1, len(outs))]
    ) / (noise_std**2)
    if pairs.shape[0] == 1:
        return pairs[0], pairs, outs
    return -softness * jax.nn.logsumexp(-pairs / softness), pairs, outs


def _control(levels, low, high, slew, dt) -> np.ndarray:
    """The control drive: its `_levels` made feasible (slew-limited)."""
    return np.asarray(_feasible(jnp.asarray(levels), low, high, slew, dt))


#: Orders of the control's levels tried, the one kept whose level is least correlated with time.
ORDERS = 32


def _levels(n, low, high, dt, seed, hold: float = 0.0):
    """The control's levels: a multilevel PRBS over [low, high], holds 0.5–5 s (at least `hold` s, up to twice it).

    One level in each of as many equal strata of the range as the drive holds levels (uniform over the
    range, as independent draws are, and reaching near both ends), in the order (of `ORDERS` shuffles)
    whose level is least correlated with time over the drive and over its first half (the rich part
    a design keeps). Independent draws in their own order left a probe's 60 s rich drive within
    1.02–3.87 of 0.5–5, and a design's first 30 s falling with time (r = −0.9) on a diagnosis that
    asked to tell a drift from a level effect.
    """
    rng = np.random.default_rng(seed)
    rate = 1.0 / dt
    shortest = max(0.5, hold)
    longest = max(5.0, 2.0 * hold)
    holds = rng.integers(
        max(1, math.ceil(shortest * rate)), max(2, math.floor(longest * rate)) + 1, size=n + 1
    )
    m = int(np.searchsorted(np.cumsum(holds), n)) + 1  # the levels the drive reaches
    holds = holds[:m]
    strata = (np.arange(m) + rng.uniform(size=m)) / m
    t = np.arange(n, dtype=float)
    best, least = None, np.inf
    for _ in range(ORDERS):
        u = np.repeat(low + (high - low) * rng.permutation(strata), holds)[:n]
        score = max(_abs_correlation(u, t), _abs_correlation(u[: n // 2], t[: n // 2]))
        if score < least:
            best, least = u, score
    return best


def _seam(n: int, rich: float, hold_n: int, levels: np.ndarray) -> int:
    """The samples kept as the control (`rich` of `n`); with a hold, at the control's level change nearest.

    The designed part's blocks begin where the kept part ends: cut inside a
    level, the kept part would end on a piece of it shorter than the hold
    (down to 12 samples of a 60-sample hold), then change level.
    """
    kept = int(round(rich * n))
    if hold_n <= 1 or kept == 0:
        return kept
    changes = np.flatnonzero(np.diff(levels)) + 1  # where each of the control's levels but the first begins
    return int(changes[np.argmin(np.abs(changes - kept))]) if changes.size else kept


def _abs_correlation(u, t) -> float:
    """|Pearson r| of `u` and `t`; 0 where either is constant."""
    du, dt_ = u - u.mean(), t - t.mean()
    scale = math.sqrt(float(np.sum(du * du) * np.sum(dt_ * dt_)))
    return abs(float(np.sum(du * dt_))) / scale if scale > 0 else 0.0


def _held(u, kept: int, hold: int):
    """`u` with its samples after the first `kept` constant over consecutive blocks of `hold` samples.

    The mean over each block: the nearest such drive (least squares), which
    keeps a drive within a range within it.
    """
    if hold <= 1:
        return u
    tail = u[kept:]
    ids = jnp.arange(tail.shape[0]) // hold
    blocks = -(-tail.shape[0] // hold)
    sums = jax.ops.segment_sum(tail, ids, blocks)
    counts = jax.ops.segment_sum(jnp.ones_like(tail), ids, blocks)
    return jnp.concatenate([u[:kept], (sums / counts)[ids]])


def design_drive(
    models: dict,
    *,
    duration: float,
    rate: float,
    amplitude: float | None = None,
    bounds: tuple[float, float] | None = None,
    slew: float | None = None,
    noise_std: float = 1.0,
    starts: int = 4,
    steps: int = 300,
    learning_rate: float = 0.05,
    seed: int = 0,
    rich: float = 0.5,
    output_bounds: tuple[float, float] | None = None,
    hold: float | None = None,
) -> DriveDesign:
    """The drive within the rig's limits under which rival models' predictions differ most (T-optimal).

    **Arguments:**

    - `models`: the rivals, ``{name: hybrid.Model}`` (two or more), e.g. the
      ``step<k>_<effect>.eqx`` files that `hybrid diagnose --out` saves for an
      ambiguous step, loaded with `hybrid.load_model`.
    - `duration` (s), `rate` (Hz): the drive's length and the rig's sample rate.
    - `amplitude`: |u| ≤ amplitude (the DAC's range), or `bounds` = (low, high).
    - `slew`: the largest |du/dt| (drive unit per second); None: no limit.
    - `noise_std`: the measurement noise's standard deviation in the output's
      unit (the diagnosis's noise floor), the criterion's scale.
    - `starts`, `steps`, `learning_rate`, `seed`: starts (the control, then
      random multilevel PRBS), Adam steps each, its step size as a fraction of
      the range's half-width, and the seed.
    - `rich`: the share of the drive, at its start, kept as the control's
      multilevel PRBS (not designed), in [0, 1); T is over the whole drive.
      0.5 by default (see the module's docstring); 0: all designed. With a
      `hold`, the kept part ends at the control's level change nearest that
      share, so that no level at the seam is held shorter.
    - `output_bounds`: (low, high) that every rival's predicted output must
      keep within (a cell's voltage window, an actuator's travel), in the
      output's unit; None: no limit. The rivals' predictions are the only
      knowledge of the output there is, so each must keep within. The loss adds
      `OUTPUT_WEIGHT` × their squared excursion beyond it (in σ², as T), only
      drives visited whose predictions all keep within are kept, and the
      control (the first start and the rich part) is narrowed around the drive
      range's middle (`NARROWED`) until they do; where none does, one line says so.
    - `hold`: the shortest time (s) the drive may stay at a level (a relay, a
      heater's contactor, a valve); None: one sample. The designed part is held
      over consecutive blocks of that many samples (after each step, each
      block is set to its mean, the nearest such drive), changing only where a
      block begins (ramping there at the slew); the control's levels are held
      at least that long too.
    """
    import optax

    if not isinstance(models, dict) or len(models) < 2:
        raise InputError("design_drive needs two or more rival models, as {name: hybrid.Model}")
    for name, model in models.items():
        if not isinstance(model, Model):
            raise InputError(f"design_drive: rival {name!r} is a {type(model).__name__}, not a hybrid.Model")
    n, dt, low, high, slew = _limits("design_drive", duration, rate, amplitude, bounds, slew)
    output = None if output_bounds is None else _pair("design_drive", "output_bounds", output_bounds)
    hold_s = 0.0 if hold is None else _check("hold", hold)
    # at least the hold asked for, never half a sample short (a verifier's 3.33 s at 40 Hz held 3.325 s)
    hold_n = max(1, math.ceil(hold_s * rate - 1e-9))
    if hold_n > n:
        raise InputError(
            f"design_drive: a hold of {hold_s:g} s is longer than the drive ({n / rate:g} s): shorten it"
        )
    noise_std = _check("noise_std", noise_std)
    if isinstance(rich, bool) or not isinstance(rich, (int, float)) or not 0.0 <= rich < 1.0:
        raise InputError(f"design_drive: rich must be a share in [0, 1), got {rich!r}")
    for label, value in (("starts", starts), ("steps", steps)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise InputError(f"design_drive: {label} must be a whole number ≥ 1, got {value!r}")
    names = list(models)
    rivals = [models[k] for k in names]
    params, static = eqx.partition(rivals, eqx.is_inexact_array)
    softness = 0.1  # of the soft minimum over pairs, in units of T

    @jax.jit
    def loss_and_pairs(u, params):
        value, pairs, outs = _criterion(eqx.combine(params, static), u, dt, noise_std, softness)
        penalty = OUTPUT_WEIGHT * _beyond(outs, output) / noise_std**2
        return penalty - value, (pairs, outs)

    optimiser = optax.adam(learning_rate * 0.5 * (high - low))  # steps in the drive's unit

    control_levels = _levels(n, low, high, dt, seed, hold_s)
    kept = _seam(n, rich, hold_n, control_levels)  # the control's first samples, never moved

    def on_grid(u):  # the designed part held (`hold`), then the range and the slew
        return _feasible(_held(jnp.asarray(u), kept, hold_n), low, high, slew, dt)

    control = np.asarray(on_grid(_control(control_levels, low, high, slew, dt)))
    if output is not None:  # the control narrowed until every rival's prediction keeps within
        middle = 0.5 * (low + high)
        for share in NARROWED:
            narrowed = on_grid(middle + share * (control - middle))
            if bool(_within(loss_and_pairs(narrowed, params)[1][1], output)):
                control = np.asarray(narrowed)
                break
        else:
            raise InputError(
                f"design_drive: no multilevel PRBS within the drive's range keeps every rival's predicted output "
                f"within [{output[0]:g}, {output[1]:g}], even narrowed to {NARROWED[-1]:.0%} of its half-width "
                f"around its middle ({middle:g}): widen the output's bounds, or move the drive's range"
            )
    prefix = jnp.asarray(control[:kept])

    @jax.jit
    def step(u, state, params):
        (_, (pairs, outs)), grad = jax.value_and_grad(loss_and_pairs, has_aux=True)(u, params)
        grad = jnp.where(jnp.isfinite(grad), grad, 0.0)
        updates, state = optimiser.update(grad, state, u)
        # the kept part put back; it is feasible, so the projection moves only what follows it
        moved = optax.apply_updates(u, updates).at[:kept].set(prefix)
        return on_grid(moved), state, jnp.min(pairs), _within(outs, output)

    rng = np.random.default_rng(seed)
    best_u, best_value, by_start = None, -np.inf, []
    for start in range(starts):
        # the control first, so the design never ends worse than it; then random levels
        levels = control if start == 0 else _levels(n, low, high, dt, int(rng.integers(2**31)), hold_s)
        u = on_grid(jnp.asarray(levels).at[:kept].set(prefix))
        state = optimiser.init(u)
        reached, reached_u = -np.inf, u
        loose, loose_u = -np.inf, u  # the best visited, within the output's bounds or not
        stage(
            f"design: start {start + 1} of {starts} ({'the control PRBS' if start == 0 else 'random levels'})"
        )
        for _ in range(steps + 1):
            # `value` is u's criterion, the least T over the pairs (the gradient follows its soft minimum,
            # which for T ≪ `softness` is near the pairs' mean): keep the u with the best criterion visited
            new_u, new_state, value, within = step(u, state, params)
            if math.isfinite(float(value)) and float(value) > loose:
                loose, loose_u = float(value), u
            if bool(within) and math.isfinite(float(value)) and float(value) > reached:
                reached, reached_u = float(value), u
            u, state = new_u, new_state
        if output is not None and loose > reached:  # the penalty keeps it near the bound, often just past:
            # back towards the control (within them) until it keeps within
            back, pulled = _pulled_back(
                loose_u, jnp.asarray(control), lambda x: loss_and_pairs(x, params), output
            )
            if back > reached:
                reached, reached_u = back, pulled
        by_start.append(reached if math.isfinite(reached) else float("nan"))
        if reached > best_value:
            best_u, best_value = reached_u, reached
    if best_u is None:
        raise InputError(
            "design_drive: the rivals' predictions were not finite from any start"
            if output is None
            else f"design_drive: no drive visited kept every rival's predicted output within "
            f"[{output[0]:g}, {output[1]:g}] and finite"
        )
    u = np.asarray(best_u)
    pairs, outs = loss_and_pairs(jnp.asarray(u), params)[1]  # the compiled criterion, not an eager rerun
    pairs = np.asarray(pairs)
    which = [(names[i], names[j]) for i in range(len(names)) for j in range(i + 1, len(names))]
    control_pairs = np.asarray(loss_and_pairs(jnp.asarray(control), params)[1][0])
    return DriveDesign(
        t=np.arange(n) / rate,
        v_in=u,
        criterion=float(np.min(pairs)),
        control_criterion=float(np.min(control_pairs)),
        rich_samples=kept,
        pair=which[int(np.argmin(pairs))],
        predictions={k: np.asarray(out) for k, out in zip(names, outs)},
        limits={
            "low": low,
            "high": high,
            "slew": slew,
            "rate": rate,
            "duration": n / rate,
            "output_low": None if output is None else output[0],
            "output_high": None if output is None else output[1],
            "hold": hold_n / rate,
        },
        criteria_by_start=by_start,
    )
