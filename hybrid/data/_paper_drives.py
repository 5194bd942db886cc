"""The paper's four drives (Section IV.B, Table 2): PRBS, sine, chirp and
pulse train.

Each generator returns a [`Drive`][hybrid.Drive] sampled at ``rate``
Hz for ``duration`` s. Generators are deterministic: the only randomness (PRBS,
randomly modulated sine and chirp) comes from ``numpy.random.default_rng(seed)``.
"""

from __future__ import annotations

import math

import numpy as np

from ..util._errors import InputError
from ._drive import (
    DEFAULT_RATE,
    Drive,
    checked_amplitude,
    checked_frequency,
    checked_number,
    checked_seed,
    time_base,
)

__all__ = ["chirp", "prbs", "pulse", "sine"]


def prbs(
    duration: float,
    rate: float = DEFAULT_RATE,
    amplitude: float = 2.0,
    min_hold: float = 0.5,
    max_hold: float = 5.0,
    levels: str = "binary",
    seed: int = 0,
) -> Drive:
    """Pseudo-random steps with random hold times.

    Each level is held for a whole number of samples drawn uniformly from
    ``[ceil(min_hold * rate), floor(max_hold * rate)]``, so every hold but the
    last (cut off by the duration) lasts between ``min_hold`` and ``max_hold``
    seconds. Holds from 0.5 s to 5 s excite dynamics slower than the paper's
    2 s input window as well as fast ones.

    Arguments:
        duration: length, s.
        rate: sampling rate, Hz.
        amplitude: level magnitude, V (>= 0).
        min_hold: shortest hold, s (at least one sample).
        max_hold: longest hold, s (>= min_hold).
        levels: ``"binary"`` (classic PRBS: the level alternates between
            +amplitude and -amplitude, random start sign) or ``"multilevel"``
            (each level uniform in [-amplitude, amplitude]).
        seed: seed of ``numpy.random.default_rng``.

    Returns:
        The [`Drive`][hybrid.Drive], name ``"prbs"``.
    """
    t, duration, rate = time_base("prbs", duration, rate)
    amplitude = checked_amplitude("prbs", amplitude)
    min_hold = checked_number("prbs", "min_hold", min_hold, positive=True)
    max_hold = checked_number("prbs", "max_hold", max_hold, positive=True)
    seed = checked_seed("prbs", seed)
    if levels not in ("binary", "multilevel"):
        raise InputError(f"prbs drive levels={levels!r} is unknown: use 'binary' or 'multilevel'")
    if min_hold > max_hold:
        raise InputError(
            f"prbs drive min_hold={min_hold:g} s exceeds max_hold={max_hold:g} s: "
            "swap them or make min_hold <= max_hold"
        )
    # The tolerance keeps 0.5 s * 30 Hz = 15 samples from rounding to 16.
    shortest = math.ceil(min_hold * rate - 1e-9)
    longest = math.floor(max_hold * rate + 1e-9)
    if shortest < 1 or shortest > longest:
        raise InputError(
            f"prbs drive holds {min_hold:g}-{max_hold:g} s contain no whole number "
            f"of samples at {rate:g} Hz: widen the range or raise the rate"
        )
    rng = np.random.default_rng(seed)
    n = len(t)
    holds = rng.integers(shortest, longest + 1, size=n // shortest + 1)
    if levels == "binary":
        sign = rng.choice([-1.0, 1.0])
        values = sign * amplitude * (-1.0) ** np.arange(len(holds))
    else:
        values = rng.uniform(-amplitude, amplitude, size=len(holds))
    v = np.repeat(values, holds)[:n]
    params = dict(
        duration=duration,
        rate=rate,
        amplitude=amplitude,
        min_hold=min_hold,
        max_hold=max_hold,
        levels=levels,
        seed=seed,
    )
    return Drive(t, v, "prbs", params)


def sine(
    duration: float,
    rate: float = DEFAULT_RATE,
    amplitude: float = 2.0,
    frequency: float = 0.2,
    offset: float = 0.0,
    phase: float = 0.0,
    modulation_depth: float = 0.0,
    modulation_period: float = 60.0,
    modulation: str = "cosine",
    seed: int = 0,
) -> Drive:
    """A sine wave, ``v = offset + a(t) * sin(2 pi frequency t + phase)``.

    With the default ``modulation_depth = 0`` the amplitude is constant,
    ``a(t) = amplitude``. Otherwise it is slowly modulated,
    ``a(t) = amplitude * (1 - depth/2 * (1 - cos(2 pi t / modulation_period)))``,
    between ``amplitude`` and ``(1 - depth) * amplitude``: at a periodic steady
    state a 2 s window of a pure sine fixes its phase, so only a varying
    amplitude makes history older than the window (slow charge dynamics) matter.
    With ``modulation="random"`` the amplitude instead takes a new random value
    ``amplitude * (1 - depth * U)``, U uniform in [0, 1), at every zero crossing
    (each half cycle), so the drive stays continuous but no window shorter than
    the strip's memory predicts the past half cycles (`modulation_period` is then
    unused).

    Arguments:
        duration: length, s.
        rate: sampling rate, Hz.
        amplitude: peak, V (>= 0).
        frequency: Hz, in (0, rate / 2).
        offset: DC offset, V.
        phase: phase at t = 0, rad.
        modulation_depth: relative depth of the amplitude modulation, in [0, 1].
        modulation_period: period of the amplitude modulation, s (> 0).
        modulation: ``"cosine"`` (slow periodic envelope) or ``"random"``
            (a random amplitude per half cycle).
        seed: seed of the random amplitudes.

    Returns:
        The [`Drive`][hybrid.Drive], name ``"sine"``.
    """
    t, duration, rate = time_base("sine", duration, rate)
    amplitude = checked_amplitude("sine", amplitude)
    frequency = checked_frequency("sine", "frequency", frequency, rate)
    offset = checked_number("sine", "offset", offset)
    phase = checked_number("sine", "phase", phase)
    modulation_depth = checked_number("sine", "modulation_depth", modulation_depth)
    modulation_period = checked_number("sine", "modulation_period", modulation_period)
    if not 0.0 <= modulation_depth <= 1.0:
        raise InputError(f"sine drive modulation_depth must be in [0, 1], got {modulation_depth!r}")
    if not modulation_period > 0:
        raise InputError(f"sine drive modulation_period must be > 0 s, got {modulation_period!r}")
    if modulation not in ("cosine", "random"):
        raise InputError(f"sine drive modulation={modulation!r} is unknown: use 'cosine' or 'random'")
    angle = 2 * np.pi * frequency * t + phase
    if modulation == "random":
        envelope = _half_cycle_envelope(angle, modulation_depth, checked_seed("sine", seed))
    else:
        envelope = 1.0 - 0.5 * modulation_depth * (1.0 - np.cos(2 * np.pi * t / modulation_period))
    v = offset + amplitude * envelope * np.sin(angle)
    params = dict(
        duration=duration,
        rate=rate,
        amplitude=amplitude,
        frequency=frequency,
        offset=offset,
        phase=phase,
        modulation_depth=modulation_depth,
        modulation_period=modulation_period,
        modulation=modulation,
        seed=seed,
    )
    return Drive(t, v, "sine", params)


def _half_cycle_envelope(angle: np.ndarray, depth: float, seed: int) -> np.ndarray:
    """A random level 1 − depth·U per half cycle of sin(angle), switching at its zero crossings."""
    index = np.floor(angle / np.pi).astype(np.int64)
    index -= index.min()
    levels = 1.0 - depth * np.random.default_rng(seed).uniform(size=int(index.max()) + 1)
    return levels[index]


def _chirp_phase(t: np.ndarray, f0: float, f1: float, period: float, method: str) -> np.ndarray:
    """Phase, rad, whose derivative sweeps 2 pi f0 -> 2 pi f1 over ``period`` s."""
    if method == "linear":
        return 2 * np.pi * (f0 * t + (f1 - f0) * t**2 / (2 * period))
    if f0 == f1:
        return 2 * np.pi * f0 * t
    ratio = f1 / f0
    return 2 * np.pi * f0 * period / np.log(ratio) * (ratio ** (t / period) - 1)


def chirp(
    duration: float,
    rate: float = DEFAULT_RATE,
    amplitude: float = 2.0,
    f0: float = 0.02,
    f1: float = 2.0,
    method: str = "logarithmic",
    sweep_period: float | None = None,
    modulation_depth: float = 0.0,
    seed: int = 0,
) -> Drive:
    """A swept sine, ``v = amplitude * sin(phi(t))``, starting at phase 0.

    The instantaneous frequency ``phi'(t) / 2 pi`` goes from ``f0`` at t = 0 to
    ``f1`` at t = T: linearly, ``f0 + (f1 - f0) t / T``, or
    logarithmically (exponentially in time), ``f0 (f1 / f0) ** (t / T)``,
    which spends equal time per decade (the default, for 0.02-2 Hz).
    T is the whole duration (one sweep) unless ``sweep_period`` is given: then
    the sweep restarts every ``sweep_period`` seconds (phase kept continuous),
    so that every contiguous part of a long recording holds every frequency.

    Arguments:
        duration: length T, s.
        rate: sampling rate, Hz.
        amplitude: peak, V (>= 0).
        f0: start frequency, Hz, in (0, rate / 2).
        f1: end frequency, Hz, in (0, rate / 2); may be below f0.
        method: ``"logarithmic"`` or ``"linear"``.
        sweep_period: seconds per sweep, or None for one sweep over the duration.
        modulation_depth: in [0, 1]; above 0 each half cycle gets a random
            amplitude ``amplitude * (1 - depth * U)`` (switching at zero crossings),
            so that a short window does not tell where in the sweep the drive is.
        seed: seed of the random amplitudes.

    Returns:
        The [`Drive`][hybrid.Drive], name ``"chirp"``.
    """
    t, duration, rate = time_base("chirp", duration, rate)
    amplitude = checked_amplitude("chirp", amplitude)
    f0 = checked_frequency("chirp", "f0", f0, rate)
    f1 = checked_frequency("chirp", "f1", f1, rate)
    if method not in ("logarithmic", "linear"):
        raise InputError(f"chirp drive method={method!r} is unknown: use 'logarithmic' or 'linear'")
    period = duration if sweep_period is None else checked_number("chirp", "sweep_period", sweep_period)
    if not period > 0:
        raise InputError(f"chirp drive sweep_period must be > 0 s, got {sweep_period!r}")
    sweeps, within = np.divmod(t, period)
    phase = _chirp_phase(within, f0, f1, period, method)
    phase = phase + sweeps * _chirp_phase(np.array(period), f0, f1, period, method)
    modulation_depth = checked_number("chirp", "modulation_depth", modulation_depth)
    if not 0.0 <= modulation_depth <= 1.0:
        raise InputError(f"chirp drive modulation_depth must be in [0, 1], got {modulation_depth!r}")
    envelope = (
        _half_cycle_envelope(phase, modulation_depth, checked_seed("chirp", seed))
        if modulation_depth
        else 1.0
    )
    v = amplitude * envelope * np.sin(phase)
    params = dict(
        duration=duration,
        rate=rate,
        amplitude=amplitude,
        f0=f0,
        f1=f1,
        method=method,
        sweep_period=sweep_period,
        modulation_depth=modulation_depth,
        seed=seed,
    )
    return Drive(t, v, "chirp", params)


def pulse(
    duration: float,
    rate: float = DEFAULT_RATE,
    amplitude: float = 2.0,
    period: float = 8.0,
    duty: float = 0.5,
    offset: float = 0.0,
    bipolar: bool = True,
) -> Drive:
    """A pulse train with rests between the pulses.

    Each period starts with a pulse lasting ``duty * period`` s and rests at
    0 V for the remainder. With ``bipolar`` the pulses alternate in sign,
    +A, 0, -A, 0, +A, ... (so the strip bends both ways and relaxes between);
    otherwise every pulse is +A. ``offset`` is added throughout.

    Arguments:
        duration: length, s.
        rate: sampling rate, Hz.
        amplitude: pulse height, V (>= 0).
        period: pulse plus rest, s; pulse and rest each need at least one sample.
        duty: pulse fraction of the period, in (0, 1).
        offset: DC offset, V.
        bipolar: alternate the sign of successive pulses.

    Returns:
        The [`Drive`][hybrid.Drive], name ``"pulse"``.
    """
    t, duration, rate = time_base("pulse", duration, rate)
    amplitude = checked_amplitude("pulse", amplitude)
    period = checked_number("pulse", "period", period, positive=True)
    duty = checked_number("pulse", "duty", duty)
    offset = checked_number("pulse", "offset", offset)
    if not 0 < duty < 1:
        raise InputError(
            f"pulse drive duty={duty:g} is outside (0, 1): give the pulse's share of the period, e.g. 0.5"
        )
    per_period = period * rate
    if min(duty, 1 - duty) * per_period < 1:
        raise InputError(
            f"pulse drive with period {period:g} s and duty {duty:g} at {rate:g} Hz "
            "leaves the pulse or the rest shorter than one sample: lengthen the period "
            "or move duty away from 0 and 1"
        )
    # Index arithmetic plus a tiny nudge keeps period boundaries exact.
    position = np.arange(len(t)) / per_period + 1e-9
    cycle = np.floor(position)
    on = (position - cycle) < duty
    sign = np.where(cycle % 2 == 1, -1.0, 1.0) if bipolar else 1.0
    v = offset + amplitude * sign * on
    params = dict(
        duration=duration,
        rate=rate,
        amplitude=amplitude,
        period=period,
        duty=duty,
        offset=offset,
        bipolar=bool(bipolar),
    )
    return Drive(t, v, "pulse", params)
