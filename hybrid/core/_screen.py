"""Starting points screened by one simulation each: a Sobol design over a simulation's typical ranges.

A physical simulation's loss surface can have broad plateaus that LM does not
cross (the RC network's does), and a simulation's default values may lie far
from a new system's. So a fit may start from screening: a scrambled Sobol
design over the simulation's typical ranges (`AbstractSimulation.typical_ranges`),
each point simulated once, the readout's gain and offset by least squares, and
the points with the least training error kept (`screened_starts`). `fit`
(``screen=``) and `diagnose` (its baseline's lanes, and jointly with an effect
in `hybrid.discovery._starts`) start from them.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ._devices import map_rows
from ._loop_safe_linalg import lstsq
from ._parameters import Positive

#: Design points screened for a fit's or a diagnosis's starts (one simulation each).
N_SCREEN = 512
#: Rows of a design screened by one call of the compiled screen (`screen_design_losses`).
SCREEN_CHUNK = 128


@eqx.filter_jit
def train_signal(problem, simulation):
    """`simulation`'s output on the training part of every recording, concatenated."""
    parts = []
    for series in problem.series:
        signal = simulation.simulate(series.v_in, series.dt)  # once per recording, then its segments
        parts += [signal[a:b] for a, b in series.segments_of("train")]
    return jnp.concatenate(parts)


def gain_offset(s, w, weights):
    """(gain, offset, rss) of w ≈ gain·s + offset by least squares over the samples whose weight is 1.

    `weights` is 0/1 (a padded series' split, `hybrid.core.bucketed_series`):
    a weighted row is (w, s, 1)·weight, so a sample of weight 0 is a row of zeros.
    """
    design = jnp.stack([s * weights, weights], axis=1)
    coef, rss = lstsq(design, w * weights)  # no LAPACK in a batched loop (_loop_safe_linalg)
    return coef[0], coef[1], rss


def train_weights(problem):
    """The training part's 0/1 weights, laid out as `problem.target("train")` (all ones if unpadded)."""
    weights = problem.weights("train")
    return jnp.ones_like(problem.target("train")) if weights is None else weights


#: The share of the Nyquist frequency above which a design point starts no fit (`in_band`).
NYQUIST_SHARE = 0.9


def start_design(simulation, n_points: int, frozen=frozenset()) -> list[dict]:
    """Candidate starts over the free parameters' typical ranges, `simulation`'s values first.

    The ranges come from the simulation (`AbstractSimulation.typical_ranges`,
    in its order; for the RC network C_clamp 1 mF–1 F, ξρ 1–100, each α
    0.1–0.9): a scrambled Sobol design (fixed seed: the same points every run),
    log-spaced for a `Positive` parameter, linear otherwise. The first point is
    the simulation as given, so a user's own guess is always screened. A
    parameter without a range, or in `frozen`, stays at its given value.

    The screens take no start from a point that `in_band` refuses at the
    recordings' rate (a frequency above the Nyquist frequency's alias range).
    """
    import scipy.stats

    given = {k: float(v) for k, v in simulation.parameters().items()}
    ranges = {k: r for k, r in simulation.typical_ranges().items() if k in given and k not in frozen}
    grid = [{k: given[k] for k in ranges}]
    if not ranges:
        return grid
    sobol = scipy.stats.qmc.Sobol(d=len(ranges), scramble=True, seed=20261122)
    unit = sobol.random_base2(max(1, math.ceil(math.log2(max(n_points - 1, 1)))))
    constraints = simulation.constraints
    logarithmic = {k: isinstance(constraints[k], Positive) for k in ranges}
    for u in unit:
        point = {}
        for x, (name, (low, high)) in zip(u, ranges.items()):
            x = float(x)
            point[name] = (
                10 ** (math.log10(low) + x * (math.log10(high) - math.log10(low)))
                if logarithmic[name]
                else low + x * (high - low)
            )
        grid.append(point)
    return grid[:n_points]


def in_band(design: list[dict], units: dict, rate: float) -> np.ndarray:
    """Whether each point of `design` may start a fit of recordings sampled at `rate` (Hz).

    A point with a parameter in Hz (rad/s) above `NYQUIST_SHARE` of the Nyquist
    frequency may not: sampled at `rate`, a mode above the Nyquist frequency is
    an alias of one below and the samples cannot tell them apart, so screened,
    the alias can fit as well and win (`lti:2` at 30 Hz started at an 88.6 Hz
    mode, ζ = 0.005, for a 1.5 Hz one, ζ = 0.3, and the baseline kept it:
    `tests/test_diagnose_starts.py -k nyquist`). The first point (the
    simulation as given, the user's own guess) always may. The screens set the
    others' losses to inf (`least_finite` then passes them by): every other
    point starts as it did.
    """
    tops = {"Hz": NYQUIST_SHARE * rate / 2, "rad/s": NYQUIST_SHARE * math.pi * rate}
    capped = {
        k: tops[str(units.get(k, "")).strip()] for k in design[0] if str(units.get(k, "")).strip() in tops
    }
    ok = np.array([all(point[k] <= top for k, top in capped.items()) for point in design], bool)
    ok[0] = True
    return ok


def design_raws(simulation, design: list[dict]) -> tuple[list[str], dict]:
    """The design's parameters that `simulation` has, as columns of raw (unconstrained) values."""
    names = [k for k in design[0] if k in simulation.parameter_names()]
    constraints = simulation.constraints  # a wrapper's (HeldStart, EffectStack) include its inner's
    return names, {k: jnp.asarray(constraints[k].to_raw(np.array([g[k] for g in design]))) for k in names}


@eqx.filter_jit
def screen_losses(problem, simulation, raws):
    """Training MSE of `simulation` at each row of `raws` (raw parameters), gain and offset by least squares."""
    w, weights = problem.target("train"), train_weights(problem)

    def one(raw):
        sim = simulation.with_raw(raw)
        signal = train_signal(problem, sim)
        *_, rss = gain_offset(signal, w, weights)
        loss = rss / jnp.sum(weights)
        # a signal that is not finite where it is scored: no start (`lstsq` takes a NaN column for a
        # dependent one, gain 0, and scored it as the constant model, finite)
        finite = jnp.all(jnp.isfinite(signal) | (weights == 0))
        return jnp.where(finite & jnp.isfinite(loss), loss, jnp.inf)

    return map_rows(one, raws, batch_size=16)


def screen_design_losses(problem, simulation, raws) -> np.ndarray:
    """`screen_losses` over a design of any size, `SCREEN_CHUNK` rows at a time (one compiled program)."""
    n = next(iter(raws.values())).shape[0]
    losses = []
    for start in range(0, n, SCREEN_CHUNK):
        chunk = {k: v[start : start + SCREEN_CHUNK] for k, v in raws.items()}
        short = SCREEN_CHUNK - next(iter(chunk.values())).shape[0]
        if short:  # the last rows repeat: one shape for every chunk
            chunk = {k: jnp.concatenate([v, jnp.repeat(v[-1:], short, axis=0)]) for k, v in chunk.items()}
        losses.append(np.asarray(screen_losses(problem, simulation, chunk))[: SCREEN_CHUNK - short])
    return np.concatenate(losses)


def least_finite(losses, n: int) -> np.ndarray:
    """The flat indices of the `n` least finite `losses` (fewer where fewer are finite), least first.

    A design point that `in_band` refuses (its loss set to inf) or where the simulation fails
    has a loss that is not finite: no start.
    """
    flat = np.asarray(losses, float).reshape(-1)
    order = np.argsort(np.where(np.isfinite(flat), flat, np.inf), kind="stable")
    return order[np.isfinite(flat[order])][:n]


def problem_rate(problem) -> float:
    """The sample rate (Hz) of a problem's recordings (they share one)."""
    return 1.0 / float(problem.series[0].dt)


class ScreenDesign(NamedTuple):
    """A design to screen (`screen_design`): its points, the parameters it sets, their raw columns, and
    which points may start a fit at the recordings' rate (`in_band`)."""

    points: list[dict]
    names: list[str]
    raws: dict
    band: np.ndarray


def screen_design(problem, simulation, frozen=frozenset(), n_screen: int = N_SCREEN, keep: int | None = None):
    """`start_design(simulation, n_screen, frozen)`, its first `keep` points, as every screen reads it.

    `keep` cuts the same design (a Sobol design's points depend on its size: the joint screens
    take the first points of the baseline's, not a design of their own). A point `in_band` refuses
    at `problem`'s rate is for the screen to pass by (its loss set to inf).
    """
    points = start_design(simulation, n_screen, frozen)[:keep]
    names, raws = design_raws(simulation, points)
    return ScreenDesign(points, names, raws, in_band(points, simulation.units, problem_rate(problem)))


def screened_starts(problem, simulation, n_starts: int, n_screen: int, frozen=frozenset()) -> list[dict]:
    """The `n_starts` best of an `n_screen`-point design (`screen_starts`' starts)."""
    return screen_starts(problem, simulation, n_starts, n_screen, frozen)[0]


def screen_starts(
    problem, simulation, n_starts: int, n_screen: int, frozen=frozenset()
) -> tuple[list[dict], list[dict]]:
    """(the `n_starts` best of an `n_screen`-point design, by training MSE with least-squares gain;
    the design's points within the recording's band where the simulation's output was not finite).

    The RC network's loss surface has broad plateaus and LM does not cross
    them: on a slow strip (α_C = 0.13, α_I = 0.85, C_clamp = 0.32 F), LM from 15
    of 16 fixed Sobol starts ended with a validation loss about 400× that of
    the true parameters. Screening costs one simulation per point; the best
    screened point there starts at the true parameters' training loss
    (`tests/test_diagnose_starts.py`).
    """
    design, names, raws, band = screen_design(problem, simulation, frozen, n_screen)
    if not names:
        return [{}], []
    raw_losses = screen_design_losses(problem, simulation, raws)
    losses = np.where(band, raw_losses, np.inf)
    order = least_finite(losses, n_starts)
    if not order.size:  # not finite anywhere: the design's first points, for the fit to refuse or say
        order = np.arange(min(n_starts, len(design)))
    escaped = np.flatnonzero(np.asarray(band, bool) & ~np.isfinite(np.asarray(raw_losses, float)))
    return [{k: design[i][k] for k in names} for i in order], [
        {k: design[i][k] for k in names} for i in escaped
    ]
