"""Two drives beyond the paper's four, for identifying hysteresis and
saturation: an up-and-down staircase and triangle sweeps of stepped amplitude.

Each generator returns a [`Drive`][hybrid.Drive] sampled at ``rate``
Hz for ``duration`` s; both are deterministic.
"""

from __future__ import annotations

import numpy as np

from ..util._errors import InputError
from ._drive import DEFAULT_RATE, Drive, checked_amplitude, checked_count, checked_number, time_base

__all__ = ["staircase", "triangle"]


def staircase(
    duration: float,
    rate: float = DEFAULT_RATE,
    amplitude: float = 2.0,
    steps: int = 5,
    step_time: float = 4.0,
) -> Drive:
    """Up-and-down staircase: ``steps`` levels from -amplitude to +amplitude and back.

    The levels ``linspace(-A, A, steps)`` are visited up, then down (without
    repeating the ends), each held ``step_time`` s, over and over: every level is
    reached from below and from above, which separates hysteresis from
    saturation and shows slow relaxation after each step.

    Arguments:
        duration: length, s.
        rate: sampling rate, Hz.
        amplitude: largest |level|, V (>= 0).
        steps: number of levels (>= 2).
        step_time: hold per level, s (at least one sample).

    Returns:
        The [`Drive`][hybrid.Drive], name ``"staircase"``.
    """
    t, duration, rate = time_base("staircase", duration, rate)
    amplitude = checked_amplitude("staircase", amplitude)
    step_time = checked_number("staircase", "step_time", step_time, positive=True)
    steps = checked_count("staircase", "steps", steps, minimum=2)
    if step_time * rate < 1:
        raise InputError(
            f"staircase drive step_time={step_time:g} s is shorter than one sample at {rate:g} Hz"
        )
    levels = np.linspace(-amplitude, amplitude, steps)
    cycle = np.concatenate([levels, levels[-2:0:-1]])
    index = np.floor(np.arange(len(t)) / (step_time * rate) + 1e-9).astype(int) % len(cycle)
    v = cycle[index]
    params = dict(duration=duration, rate=rate, amplitude=amplitude, steps=steps, step_time=step_time)
    return Drive(t, v, "staircase", params)


def triangle(
    duration: float,
    rate: float = DEFAULT_RATE,
    amplitude: float = 2.0,
    period: float = 10.0,
    levels: int = 4,
) -> Drive:
    """Triangle sweeps of stepped amplitude: periods of peak A, then smaller ones.

    Period k has peak ``A * (1 - (k mod levels) / levels)``; a triangle wave
    starts at 0 V, rises to the peak, falls to minus the peak and returns to 0 V.
    Sweeps of several amplitudes trace the minor loops of a hysteresis.

    Arguments:
        duration: length, s.
        rate: sampling rate, Hz.
        amplitude: largest peak, V (>= 0).
        period: one triangle, s (at least 4 samples).
        levels: number of peak amplitudes cycled through (>= 1).

    Returns:
        The [`Drive`][hybrid.Drive], name ``"triangle"``.
    """
    t, duration, rate = time_base("triangle", duration, rate)
    amplitude = checked_amplitude("triangle", amplitude)
    period = checked_number("triangle", "period", period, positive=True)
    levels = checked_count("triangle", "levels", levels, minimum=1)
    if period * rate < 4:
        raise InputError(f"triangle drive period={period:g} s needs at least 4 samples at {rate:g} Hz")
    position = t / period
    cycle = np.floor(position + 1e-12)
    u = position - cycle
    shape = np.where(u < 0.25, 4 * u, np.where(u < 0.75, 2 - 4 * u, 4 * u - 4))
    peaks = amplitude * (1 - (cycle % levels) / levels)
    v = peaks * shape
    params = dict(duration=duration, rate=rate, amplitude=amplitude, period=period, levels=levels)
    return Drive(t, v, "triangle", params)
