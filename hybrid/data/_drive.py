"""What a drive is: [`Drive`][hybrid.Drive], a sampled drive voltage, and the checks
every generator applies to its parameters.

A drive is sampled at ``rate`` Hz (30 Hz, the camera's frame rate, by default,
`DEFAULT_RATE`) for ``duration`` s, with ``n = round(duration * rate)``
samples at ``t = arange(n) / rate`` (`time_base`). Bad parameters raise
[`InputError`][hybrid.InputError].
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from ..util._errors import InputError

__all__ = ["DEFAULT_RATE", "Drive"]

#: Default sampling rate, Hz: the paper's camera records 30 frames per second.
DEFAULT_RATE: float = 30.0


@dataclasses.dataclass(frozen=True, eq=False)
class Drive:
    """A sampled drive voltage.

    Arguments:
        t: sample times, s, shape ``(n,)``, ``arange(n) / rate``.
        v: drive voltage, V, shape ``(n,)``.
        name: the generator, one of [`DRIVES`][hybrid.DRIVES].
        params: every parameter that made it (duration, rate, amplitude, ...,
            seed where used), JSON-able, for a recording's metadata.
    """

    t: np.ndarray
    v: np.ndarray
    name: str
    params: dict[str, Any]

    def __post_init__(self) -> None:
        for field in ("t", "v"):
            array = np.array(getattr(self, field), dtype=np.float64)
            array.setflags(write=False)
            object.__setattr__(self, field, array)

    @property
    def n(self) -> int:
        """Number of samples."""
        return len(self.t)

    def __len__(self) -> int:
        return len(self.t)

    @property
    def rate(self) -> float:
        """Sampling rate, Hz."""
        return float(self.params["rate"])

    @property
    def duration(self) -> float:
        """Time covered, s: ``n / rate``."""
        return self.n / self.rate

    @property
    def metadata(self) -> dict[str, Any]:
        """``{"name": ..., "params": {...}}``, ready for a recording's metadata."""
        return {"name": self.name, "params": dict(self.params)}


# --------------------------------------------------------------------------- #
# Parameter checks
# --------------------------------------------------------------------------- #


def checked_number(drive: str, param: str, value: Any, *, positive: bool = False) -> float:
    """``value`` as a finite float, non-negative (or positive) where asked."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise InputError(
            f"{drive} drive parameter {param}={value!r} is not a number: give a real number"
        ) from None
    if not math.isfinite(number):
        raise InputError(f"{drive} drive parameter {param}={value!r} is not finite: give a finite number")
    if positive and number <= 0:
        raise InputError(f"{drive} drive parameter {param}={number:g} must be positive: give a value > 0")
    return number


def checked_amplitude(drive: str, amplitude: Any) -> float:
    amplitude = checked_number(drive, "amplitude", amplitude)
    if amplitude < 0:
        raise InputError(
            f"{drive} drive amplitude {amplitude:g} V is negative: give a value >= 0 "
            "(use phase or bipolar for the sign)"
        )
    return amplitude


def checked_frequency(drive: str, param: str, value: Any, rate: float) -> float:
    """A frequency in (0, rate / 2): positive and below the Nyquist frequency."""
    frequency = checked_number(drive, param, value, positive=True)
    if frequency >= rate / 2:
        raise InputError(
            f"{drive} drive {param}={frequency:g} Hz is not below the Nyquist "
            f"frequency {rate / 2:g} Hz of a {rate:g} Hz rate: lower it or raise the rate"
        )
    return frequency


def time_base(drive: str, duration: Any, rate: Any) -> tuple[np.ndarray, float, float]:
    """The time base ``arange(n) / rate``; returns ``(t, duration, rate)``."""
    duration = checked_number(drive, "duration", duration, positive=True)
    rate = checked_number(drive, "rate", rate, positive=True)
    n = round(duration * rate)
    if n < 2:
        raise InputError(
            f"{drive} drive of {duration:g} s at {rate:g} Hz has {n} sample(s): "
            "give a longer duration or a higher rate (at least 2 samples)"
        )
    return np.arange(n, dtype=np.float64) / rate, duration, rate


def checked_count(drive: str, param: str, value: Any, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise InputError(f"{drive} drive {param} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def checked_seed(drive: str, seed: Any) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"{drive} drive seed {seed!r} is not a non-negative integer: give e.g. seed=0")
    return int(seed)
