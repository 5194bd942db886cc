"""What the board plays: the Timer1 setting for a sample rate, and the board's report of a stream.

`Timing` is the setting `rig.Board.configure` sends (and
`sample_timing` picks it); `PlayReport` is what
`rig.Board.play` returns: the board's own account of what it played and
when (its timer ticks), with the faults that were counted but not fatal.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from . import protocol as P
from ._errors import RigError

__all__ = ["F_CPU", "PlayReport", "Timing", "sample_timing"]

F_CPU = 16_000_000


@dataclasses.dataclass(frozen=True)
class Timing:
    """Timer1 setting for a sample rate: ``period = (top + 1) * prescaler / F_CPU``."""

    prescaler_code: int
    top: int
    f_cpu: int = F_CPU

    @property
    def prescaler(self) -> int:
        return P.PRESCALERS[self.prescaler_code]

    @property
    def period_cycles(self) -> int:
        """Sample period in CPU cycles."""
        return (self.top + 1) * self.prescaler

    @property
    def period(self) -> float:
        """Sample period, s."""
        return self.period_cycles / self.f_cpu

    @property
    def rate(self) -> float:
        """Sample rate actually played, Hz."""
        return 1.0 / self.period


def sample_timing(rate: float, f_cpu: int = F_CPU) -> Timing:
    """The Timer1 setting closest to ``rate`` Hz, using the finest prescaler that fits 16 bits.

    At 30 Hz: prescaler 64, top 8332, so 30.0012 Hz (40 ppm fast).
    """
    if not (isinstance(rate, (int, float)) and math.isfinite(rate) and rate > 0):
        raise RigError(f"sample rate {rate!r} Hz is not a positive number")
    for code in sorted(P.PRESCALERS):
        ticks = f_cpu / (rate * P.PRESCALERS[code])
        top = round(ticks) - 1
        if top <= 0xFFFF:
            if top < 100:
                raise RigError(
                    f"sample rate {rate:g} Hz is too fast for the board: keep it below "
                    f"{f_cpu / 101 / 8:.0f} Hz (the I2C write alone takes ~80 us)"
                )
            return Timing(code, top, f_cpu)
    raise RigError(
        f"sample rate {rate:g} Hz is too slow for Timer1: give at least {f_cpu / 1024 / 65536:.3f} Hz"
    )


@dataclasses.dataclass
class PlayReport:
    """What the board says it played.

    Attributes:
        n: samples in the drive.
        played: samples the board played (``== n`` when complete).
        ticks: timer periods from START to the last sample.
        timing: the Timer1 setting (``timing.period`` s per tick).
        underruns: episodes ``(index, length, tick)``: sample ``index`` came
            ``length`` ticks late and played at ``tick``.
        underrun_ticks: ticks in which no sample was ready (the last code held).
        bad_frames_board: frames the board rejected (NAK) during the stream.
        bad_frames_host: corrupt frames the host threw away.
        dac_errors: DAC writes that were not acknowledged.
        resent_samples: samples sent again after a NAK.
        statuses: ``(host monotonic time, ticks, played)`` of each STATUS.
        start_time: host monotonic time at which START was acknowledged.
        complete: the board reported DONE.
        error: the fault's message when the stream ended early, else None.
    """

    n: int
    timing: Timing
    played: int = 0
    ticks: int = 0
    underruns: list = dataclasses.field(default_factory=list)
    underrun_ticks: int = 0
    bad_frames_board: int = 0
    bad_frames_host: int = 0
    dac_errors: int = 0
    resent_samples: int = 0
    statuses: list = dataclasses.field(default_factory=list)
    start_time: float = math.nan
    complete: bool = False
    error: str | None = None

    def sample_ticks(self, n: int | None = None) -> np.ndarray:
        """The timer tick at which each of the first ``n`` samples played.

        Sample i plays at tick i plus the ticks lost in underruns before it;
        its time after START is ``(tick + 1) * timing.period`` (sample 0 plays at
        the first compare match, one period after START).
        """
        n = self.played if n is None else n
        ticks = np.arange(n, dtype=np.int64)
        for index, length, _tick in sorted(self.underruns):
            ticks[index:] += length
        return ticks

    def metadata(self) -> dict:
        """JSON-able summary for a recording's metadata."""
        return {
            "samples": self.n,
            "played": self.played,
            "ticks": self.ticks,
            "complete": self.complete,
            "rate_hz": self.timing.rate,
            "period_s": self.timing.period,
            "timer": {"prescaler": self.timing.prescaler, "top": self.timing.top},
            "underruns": [list(u) for u in self.underruns],
            "underrun_ticks": self.underrun_ticks,
            "bad_frames_board": self.bad_frames_board,
            "bad_frames_host": self.bad_frames_host,
            "dac_errors": self.dac_errors,
            "resent_samples": self.resent_samples,
            "error": self.error,
        }
