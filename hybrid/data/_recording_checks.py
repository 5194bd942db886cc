"""The checks a [`Recording`][hybrid.Recording] passes when it is built.

Each channel becomes a finite, read-only float64 vector of one common length;
the time base ``t`` (s) must strictly increase and be uniform (30 Hz for the
paper's camera): timestamp jitter below ``JITTER_FRAMES`` of a step is absorbed
by rebuilding ``t`` as the closest uniform grid, gaps and a ``t`` written in
milliseconds are refused. Metadata must be JSON-able and gains the units of
the required channels. Every problem raises
[`InputError`][hybrid.InputError] with a message that names the
recording, the column and the rows, and says how to fix it.

Messages name a sample by its number from 0 (``sample 12``); a loader that knows the file
line each sample came from passes them (``lines``), and the messages then say
``line 14 (sample 12)``, the same words for every check.
"""

from __future__ import annotations

import contextlib
import contextvars
import json
import math
from collections.abc import Iterator, Mapping
from typing import Any

import numpy as np

from ..util._errors import InputError

__all__ = [
    "FILL_GAPS_MAX",
    "FILL_VALUES_HINT",
    "GAP_FRAMES",
    "JITTER_FRAMES",
    "MS_STEP_S",
    "REQUIRED",
    "TIME_RTOL",
    "TIME_UNITS",
    "UNITS",
    "WRAP_PERIODS",
    "fill_gaps",
    "columns_flag",
    "fill_values",
    "mapped_by",
    "range_flag",
    "ranged_by",
    "sample_text",
    "samples_text",
    "time_step",
    "time_unit_guess",
]

#: Required channels, in file order.
REQUIRED: tuple[str, ...] = ("t", "v_in", "w")
#: Units a time column may be given in, and their length in seconds.
TIME_UNITS: dict[str, float] = {
    "s": 1.0,
    "ms": 1e-3,
    "us": 1e-6,
    "µs": 1e-6,
    "ns": 1e-9,
    "min": 60.0,
    "h": 3600.0,
}
#: Units of the required channels, stored in ``metadata["units"]``.
UNITS: dict[str, str] = {"t": "s", "v_in": "V", "w": "mm"}
#: Largest ``max|dt - median dt| / median dt`` kept as it is; far above the rounding
#: of 17-digit CSV text, far below a dropped camera frame.
TIME_RTOL: float = 1e-3
#: Timestamp jitter (max |t - closest uniform grid|, in steps) up to which t is rebuilt
#: as that grid: every row is then unambiguously frame k of one clock. Millisecond
#: timestamps of a 30 Hz camera are off by up to 0.015 step from rounding alone.
#: Larger deviations (a frame rate that changed) are refused.
JITTER_FRAMES: float = 0.25
#: A step longer than this many median steps is a gap (dropped frames): refused, unless filled (`fill_gaps`).
GAP_FRAMES: float = 1.5
#: The most missing frames (or values, `fill_values`) in a row `fill_gaps` may be asked to fill: a longer
#: gap is cut, not guessed.
FILL_GAPS_MAX: int = 10
#: What a refusal of missing (empty, non-finite) values of the drive or output offers: `fill_values`.
FILL_VALUES_HINT: str = (
    "a few missing values in a row of the drive or output: --fill-gaps N (fill_gaps=N) fills them"
)
#: A median step of this many seconds or more (a rate below 0.1 Hz) is refused as t
#: written in milliseconds (33.3 at 30 fps), unless the metadata given declares
#: ``units: {"t": "s"}``. Slow legitimate recordings (a 1 Hz benchmark, dt = 1 s) pass;
#: an IPMC's RC time constants (0.1-1 s) cannot be identified below 0.1 Hz anyway.
MS_STEP_S: float = 10.0

_RESERVED = frozenset((*REQUIRED, "metadata"))
_SHOW_ROWS = 5


def sample_text(k: int, lines: Any = None, t: float | None = None) -> str:
    """Sample ``k`` (from 0) in a message: ``"line 14 (sample 12)"`` where the file's `lines` are known
    (the line of each sample, from 1), else ``"sample 12"``; with `t`, its time too."""
    at = f"; t = {t:.6g} s" if t is not None else ""
    if lines is not None:
        return f"line {int(lines[k])} (sample {k}{at})"
    return f"sample {k}" + (f" (t = {t:.6g} s)" if t is not None else "")


def samples_text(samples: Any, lines: Any = None) -> str:
    """The first few of ``samples`` (from 0): ``"samples 12, 13 (2 in all)"``, or with the file's
    `lines` ``"lines 14, 15 (samples 12, 13; 2 in all)"``; one alone as `sample_text` says it."""
    samples = np.asarray(samples, dtype=int)
    if len(samples) == 1:  # one: "line 14 (sample 12)", not "lines 14 (samples 12; 1 in all)"
        return sample_text(int(samples[0]), lines)
    more = ", ..." if len(samples) > _SHOW_ROWS else ""
    shown = ", ".join(str(int(r)) for r in samples[:_SHOW_ROWS]) + more
    if lines is None:
        return f"samples {shown} ({len(samples)} in all)"
    numbers = ", ".join(str(int(lines[r])) for r in samples[:_SHOW_ROWS]) + more
    return f"lines {numbers} (samples {shown}; {len(samples)} in all)"


#: The flag that cuts a record's samples, as a message about a record names it (`range_flag`).
_RANGE_FLAG: contextvars.ContextVar[str] = contextvars.ContextVar("range_flag", default="--range")


def range_flag() -> str:
    """``--range``, or the flag `ranged_by` set while a record loads: what a message says cuts the record."""
    return _RANGE_FLAG.get()


def ranged_by(flag: str) -> contextlib.AbstractContextManager[None]:
    """While the block runs, messages about a record name `flag` as what cuts it (``--test-range`` for a
    --test record: a probe followed "(--range 0:1500)" on one and halved its estimation record)."""
    return _flag_set(_RANGE_FLAG, flag)


@contextlib.contextmanager
def _flag_set(flag_var: contextvars.ContextVar[str], flag: str) -> Iterator[None]:
    """`flag_var` set to `flag` while the block runs."""
    token = flag_var.set(flag)
    try:
        yield
    finally:
        flag_var.reset(token)


#: The flag that names a record's columns, as a message about a record names it (`columns_flag`).
_COLUMNS_FLAG: contextvars.ContextVar[str] = contextvars.ContextVar("columns_flag", default="--columns")


def columns_flag() -> str:
    """``--columns``, or the flag `mapped_by` set while a record loads: what a message says maps its columns."""
    return _COLUMNS_FLAG.get()


def mapped_by(flag: str) -> contextlib.AbstractContextManager[None]:
    """While the block runs, messages about a record name `flag` as what maps its columns
    (``--test-columns`` for a --test record: the ``--columns`` a probe was offered for one broke the
    fitted records, which have the other names)."""
    return _flag_set(_COLUMNS_FLAG, flag)


#: Significant digits of the rate that `time_step` keeps (at most 5 ppm of it).
RATE_DIGITS = 6


def time_step(t: np.ndarray) -> float:
    """The sampling step of a time base, s: one over its rate to `RATE_DIGITS` significant digits.

    The rate is the span's: ``(n - 1) / (t[-1] - t[0])``. For a rebuilt grid that is the
    least-squares slope's; for times kept as read it is not biased by their rounding as the
    median step is (times written to 7 digits, 0.03333 and 0.03334 s: a median of 0.03333 s
    says 30.003 Hz). Every rate the project reports (``Recording.rate``, ``metadata["rate_hz"]``)
    is ``1 / time_step``.

    Rounding the rate moves it by at most 5 ppm, below the tolerance of the clock that
    sampled it (a crystal's is 20-100 ppm), and gives every recording made at one rate the
    same step to the last bit: ``np.arange(n) / 50`` spans 0.02 s per step only to within
    an ulp that changes with n. The models' compiled programs depend on the step, so a
    script that diagnoses recordings of several lengths compiles them once per rate, not
    once per recording (`pytest tests/test_buckets.py -k rate`).
    """
    span = float(t[-1] - t[0])
    if not span > 0 or not math.isfinite(span):
        return span / max(len(t) - 1, 1)  # what the checks refuse, with their own messages
    return 1.0 / float(f"{(len(t) - 1) / span:.{RATE_DIGITS}g}")


def as_vector(name: str, column: str, values: Any) -> np.ndarray:
    """Convert one channel to a read-only float64 copy of shape ``(n,)``.

    Arguments:
        name: the recording's name, for messages.
        column: the channel's name, for messages.
        values: anything ``numpy.asarray`` turns into a 1-D real array.

    Returns:
        A read-only float64 vector that owns its data.
    """
    if values is None:
        raise InputError(f"recording '{name}' is missing column '{column}': give t, v_in and w")
    try:
        array = np.array(values, dtype=np.float64, copy=True)
    except (TypeError, ValueError) as error:
        raise InputError(
            f"recording '{name}' has non-numeric values in column '{column}' "
            f"({error}): give real numbers only"
        ) from None
    if array.ndim != 1:
        raise InputError(
            f"recording '{name}' has column '{column}' of shape {array.shape}, "
            "not a vector: give one value per sample"
        )
    array.setflags(write=False)
    return array


def check_extra_name(name: str, column: Any) -> None:
    """Reject extra-channel names that no file format could store back."""
    if not isinstance(column, str) or not column or column != column.strip():
        raise InputError(
            f"recording '{name}' has extra channel name {column!r}: use a "
            "non-empty string without leading or trailing spaces"
        )
    if column in _RESERVED:
        raise InputError(
            f"recording '{name}' has an extra channel named '{column}', which is "
            "reserved: rename it (t, v_in, w and metadata are taken)"
        )
    if any(c in column for c in ',"\n\r#'):
        raise InputError(
            f"recording '{name}' has extra channel name {column!r} with a comma, "
            "quote, '#' or line break: rename it so it fits a CSV header"
        )


def check_metadata(name: str, metadata: Any) -> dict:
    """Return a JSON-normalised deep copy of ``metadata`` with defaults filled in."""
    if metadata is None:
        metadata = {}
    if not isinstance(metadata, Mapping):
        raise InputError(f"recording '{name}' has metadata of type {type(metadata).__name__}: give a dict")
    try:
        copy = json.loads(json.dumps(dict(metadata), allow_nan=False))
    except (TypeError, ValueError) as error:
        raise InputError(
            f"recording '{name}' has metadata that is not JSON-able ({error}): "
            "use only dicts, lists, strings, finite numbers, booleans and None"
        ) from None
    copy.setdefault("units", dict(UNITS))
    copy.setdefault("source", name)
    if "strip" in copy and not isinstance(copy["strip"], dict):
        raise InputError(
            f"recording '{name}' has metadata 'strip' of type "
            f"{type(copy['strip']).__name__}: give the strip geometry as a dict"
        )
    return copy


def check_finite(name: str, column: str, values: np.ndarray) -> None:
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise InputError(
            f"recording '{name}' has non-finite values in column '{column}' at "
            f"{samples_text(bad)}: remove or interpolate them"
            + (f" ({FILL_VALUES_HINT})" if column in ("v_in", "w") else "")
        )


#: A step this share off the record's opening step is a change of the rate, not a timestamp's jitter (ms
#: rounding of a 30 Hz clock moves a step by 3 %).
CHANGED_STEP = 0.1
#: ... over at least this many steps in a row (one late timestamp moves the two steps beside it).
CHANGED_RUN = 3


def check_time(
    name: str, t: np.ndarray, metadata: Any = None, lines: Any = None
) -> tuple[np.ndarray, dict | None]:
    """Require strictly increasing, uniformly spaced sample times in seconds.

    Returns ``(t, None)`` when the steps are uniform within ``TIME_RTOL``. Otherwise,
    with no gap (no step over ``GAP_FRAMES`` median steps, none under 1/``GAP_FRAMES``)
    and every timestamp within ``JITTER_FRAMES`` of a step of the closest uniform grid,
    the times are one frame clock read with jitter: they come back as that grid
    t0 + k·dt (least squares over the frame index k; the median step would be biased
    by millisecond rounding: 33, 33, 34 ms has median 33 ms, 1 % off 30 Hz) with a
    ``time_base`` record of what was done. Gaps and larger irregularities are refused.

    `lines` (the file line of each sample, from 1), where given, go into the messages.
    """
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0) + 1
    if bad.size:
        _refuse_order(name, t, bad, lines)
    step = float(np.median(dt))
    _check_seconds(name, step, metadata)
    deviation = np.abs(dt - step)
    worst = int(np.argmax(deviation))
    if deviation[worst] <= TIME_RTOL * step:
        return t, None
    gaps = np.flatnonzero(dt > GAP_FRAMES * step)
    if gaps.size:
        k = int(gaps[0])
        frames = np.rint(dt[gaps] / step).astype(int)
        loose = np.abs(dt[gaps] - frames * step) > JITTER_FRAMES * step
        if loose.any() and not _on_one_grid(t, gaps, frames, step):  # as `fill_gaps` reads a gap: not whole
            k = int(gaps[np.argmax(loose)])
            raise InputError(
                f"recording '{name}' has a step in time of {dt[k] / step:.3g} median steps into "
                f"{sample_text(k + 1, lines, t[k + 1])} ({dt[k]:.6g} s): no whole number of missing frames, so "
                f"its clock slipped or restarted there; cut the recording there ({range_flag()}, "
                "Recording.segment)"
            )
        raise InputError(
            f"recording '{name}' has a gap in time at {sample_text(k + 1, lines, t[k + 1])}: the "
            f"step into it is {dt[k]:.6g} s, {dt[k] / step:.3g} times the median step {step:.6g} s "
            f"({gaps.size} gap(s) in all): frames are missing there; cut the recording at the "
            f"gap ({range_flag()}, Recording.segment), or fill a few missing frames by straight lines "
            "(--fill-gaps N; fill_gaps=N in Python)"
        )
    short = np.flatnonzero(dt < step / GAP_FRAMES)
    frame = np.arange(t.size, dtype=np.float64)
    k_mean, t_mean = float(np.mean(frame)), float(np.mean(t))
    slope = float(np.sum((frame - k_mean) * (t - t_mean)) / np.sum((frame - k_mean) ** 2))
    grid = (t_mean - slope * k_mean) + slope * frame
    jitter = t - grid
    far = int(np.argmax(np.abs(jitter)))
    worst_jitter = abs(float(jitter[far]))
    # a short step alone is jitter where every time is near the grid (two neighbours each a quarter off)
    if worst_jitter >= JITTER_FRAMES * slope:
        # where the steps first change: a rate that changes part-way shows there, not at the sample
        # furthest from one grid through them all (a probe's 30 Hz → 25 Hz at line 903 named line 1651)
        # the rate the record starts at (the median may lie between two): its first steps, a quarter at most
        opening = float(np.median(dt[: max(3, min(20, dt.size // 4))]))
        off = np.abs(dt - opening) > CHANGED_STEP * opening  # a run of CHANGED_RUN: not one late timestamp
        runs = np.convolve(off.astype(int), np.ones(CHANGED_RUN, int), mode="valid") == CHANGED_RUN
        changed = np.flatnonzero(off) if runs.any() else np.zeros(0, int)
        changed = changed[changed >= np.flatnonzero(runs)[0]] if changed.size else changed
        where = (
            (
                f"the step into {sample_text(int(short[0]) + 1, lines)} is {dt[short[0]]:.6g} s against a "
                f"median step of {step:.6g} s, and "
                if short.size
                else f"the steps first change at {sample_text(int(changed[0]) + 1, lines, t[changed[0] + 1])}, "
                f"{dt[changed[0]]:.6g} s against {opening:.6g} s before ({changed.size} such steps), and "
                if changed.size
                else ""
            )
            + f"{sample_text(far, lines, t[far])} is {_steps_off(worst_jitter / slope)} off the closest "
            "uniform grid"
        )
        raise InputError(
            f"recording '{name}' has non-uniform time: {where} (timestamp jitter below "
            f"{JITTER_FRAMES:g} of a step is absorbed): did the frame rate change? Resample "
            "onto a uniform grid or rebuild t from the sampling rate"
        )
    rms = float(np.sqrt(np.mean(jitter**2)))
    note = (
        f"t rebuilt as a uniform grid t0 + k·dt, dt = {slope:.9g} s ({1 / slope:.6g} Hz), "
        f"the least-squares line through the logged times: their jitter was max "
        f"{worst_jitter * 1e3:.3g} ms ({worst_jitter / slope:.2g} of a step), rms {rms * 1e3:.3g} ms"
    )
    grid.setflags(write=False)
    return grid, {
        "rebuilt": True,
        "dt_s": slope,
        "rate_hz": 1 / slope,
        "t0_s": float(grid[0]),
        "jitter_max_s": worst_jitter,
        "jitter_rms_s": rms,
        "note": note,
    }


def _refuse_order(name: str, t: np.ndarray, bad: np.ndarray, lines: Any) -> None:
    """Refuse times that do not increase (samples `bad`, from 0), saying which of three things it is.

    A step back of more than `GAP_FRAMES` steps is a clock that restarted (two runs in one
    file: sorting would interleave them); a repeated time is a repeated line or a logger's
    rounding; a short step back is lines out of order.
    """
    k = int(bad[0])
    steps = np.diff(t)
    forward = steps[steps > 0]
    step = float(np.median(forward)) if forward.size else 0.0
    back = float(t[k - 1] - t[k])
    more = f" ({bad.size} places in all: {samples_text(bad, lines)})" if bad.size > 1 else ""
    at = sample_text(k, lines)
    if step > 0 and back > GAP_FRAMES * step:
        raise InputError(
            f"recording '{name}' has a clock that restarted at {at}: its time goes back from "
            f"{t[k - 1]:.6g} s to {t[k]:.6g} s{more}: the file holds two runs (sorting would mix them); "
            f"split the file there, or keep one run with {range_flag()} (sample_range=), e.g. :{k} or {k}:"
        )
    if back == 0:
        raise InputError(
            f"recording '{name}' repeats the time {t[k]:.6g} s at {at}{more}: a line written "
            "twice, or times rounded too coarsely; delete the repeated line, or write the times "
            "with more digits (or drop the time column and give the rate)"
        )
    raise InputError(
        f"recording '{name}' has its time going back by {back:.6g} s at {at} (from {t[k - 1]:.6g} s to "
        f"{t[k]:.6g} s){more}: lines out of order; sort the lines by time"
    )


def _check_seconds(name: str, step: float, metadata: Any) -> None:
    """Refuse a time column that steps like milliseconds (see ``MS_STEP_S``)."""
    if step < MS_STEP_S:
        return
    units = metadata.get("units") if isinstance(metadata, Mapping) else None
    if isinstance(units, Mapping) and units.get("t") == "s":
        return  # declared: a recording really sampled this slowly
    looks, units = time_unit_guess(step)
    divide = " or ".join({"ms": "t/1000", "us": "t/1e6"}[u] for u in units)
    raise InputError(
        f"recording '{name}' has t stepping by {step:.4g}: t looks like {looks}, {1 / step:.3g} Hz if "
        f"seconds; write t in seconds ({divide}), or, for a recording really sampled every {step:.4g} s, "
        'say so: --units t=s on the command line (units={"t": "s"} in Python, or in metadata)'
    )


def time_unit_guess(step: float) -> tuple[str, tuple[str, ...]]:
    """(what a time column stepping by `step` looks like, the `TIME_UNITS` it may be in): for messages.

    A step of 33.3 is a 30 Hz camera's in milliseconds; one of 33 333, the same
    camera's in microseconds (0.03 Hz in milliseconds); between 1 000 and 10 000
    either may be (a 0.25 Hz process logged in ms, a 250 Hz one in µs): both are said.
    """
    ms, us = 1e3 / step, 1e6 / step
    if step > 1e4:
        return f"microseconds ({us:.4g} Hz if so; {ms:.3g} Hz if milliseconds)", ("us",)
    if step >= 1e3:
        return f"milliseconds ({ms:.4g} Hz if so) or microseconds ({us:.4g} Hz)", ("ms", "us")
    return f"milliseconds ({ms:.4g} Hz if so)", ("ms",)


def is_constant(values: np.ndarray) -> bool:
    """True when values vary by no more than 1e-12 of their magnitude (or are all 0)."""
    magnitude = float(np.max(np.abs(values))) if values.size else 0.0
    return magnitude == 0.0 or float(np.std(values / magnitude)) <= 1e-12


#: A sample this many times the column's typical deviation from its median away from that median is
#: a corrupt cell, not a measurement: no sensor or DAC spans 10⁶ of its own spread in one sample.
OUTLIER_FACTOR = 1e6


def wild_sample(values: np.ndarray) -> tuple[int, float] | None:
    """(index, how many typical deviations) of a sample `OUTLIER_FACTOR` × the typical deviation away, or None.

    The typical deviation is the median absolute deviation from the median, or, where
    most samples sit at one value (a pulse drive at rest), the median of the others'.
    One 1e300 cell in a column of millimetres would otherwise set the fit's scale:
    `fit` normalises by the column's spread, and every other sample then reads as 0.
    """
    values = np.asarray(values, float)
    if values.size < 3 or not np.all(np.isfinite(values)):
        return None
    median = float(np.median(values))
    deviation = np.abs(values - median)
    typical = float(np.median(deviation))
    if typical == 0.0:
        moved = deviation[deviation > 0]
        typical = float(np.median(moved)) if moved.size > 1 else 0.0
    if typical == 0.0:
        return None
    k = int(np.argmax(deviation))
    times = float(deviation[k] / typical)
    return (k, times) if times > OUTLIER_FACTOR else None


#: The turns an angle sensor wraps at: (period, how to write it, how numpy unwraps it).
WRAP_PERIODS: tuple[tuple[float, str, str], ...] = (
    (2 * math.pi, "2π", "numpy.unwrap(w)"),
    (360.0, "360", "numpy.unwrap(w, period=360)"),
)


def wrapped_angle(values: np.ndarray) -> tuple[str, str, int, int] | None:
    """(period, unwrap, how many wraps, the first's sample) where `values` read as an angle that wraps, or None.

    An encoder or an ``atan2`` gives an angle within one turn (±π, 0–360°): each
    time the angle passes the turn's end it jumps by a whole turn to the other
    end, and a fit reads those jumps as the plant's response. Read as wrapped
    where the values reach over 0.8 of a turn and span (from their 0.5 % to
    their 99.5 % quantile: a sensor's noise reaches past the turn's ends) no more
    than 1.02 of it (`WRAP_PERIODS`; a shaft near the wrap point that crosses it
    for 13 samples of 3200 spans little of the turn, but reaches both its ends),
    move by less than a tenth of it per sample (a shaft at 36° a frame), and
    nine in ten of the steps of more than half a turn continue the steps beside
    them once a turn is taken off (at most 5 × the median of the five either
    side, or of the record's steps): the motion goes on across the jump. A
    switching signal (a relay's) whose steps are not a whole turn is not read as
    wrapped; one whose steps are a whole turn to within its noise cannot be told
    from an angle resting at the wrap point, and is.
    """
    v = np.asarray(values, float)
    if v.size < 20 or not np.all(np.isfinite(v)):
        return None
    d = np.diff(v)
    low, high = np.quantile(v, [0.005, 0.995])
    span, reach = float(high - low), float(np.ptp(v))
    for period, written, unwrap in WRAP_PERIODS:
        if not (reach >= 0.8 * period and span <= 1.02 * period):
            continue
        jumps = np.flatnonzero(np.abs(d) > 0.5 * period)
        if jumps.size == 0:
            continue
        steady = np.abs(d - period * np.round(d / period))  # each step continued across a whole turn
        moving = np.delete(steady, jumps)
        typical = float(np.median(moving)) if moving.size else 0.0
        if not 0.0 < typical < 0.1 * period:
            continue
        continued = 0
        for k in jumps:
            beside = np.r_[steady[max(k - 5, 0) : k], steady[k + 1 : k + 6]]
            local = float(np.median(beside)) if beside.size else 0.0
            continued += bool(steady[k] <= 5.0 * max(local, typical))
        if continued >= 0.9 * jumps.size:
            return written, unwrap, int(jumps.size), int(jumps[0]) + 1
    return None


def source_name(metadata: Any) -> str:
    if isinstance(metadata, Mapping) and isinstance(metadata.get("source"), str):
        return metadata["source"]
    return "<arrays>"


def _steps_off(steps: float) -> str:
    """ "0.3 of a step", "1 step", "41 steps": how far a time is off its grid."""
    if steps < 0.995:
        return f"{steps:.2g} of a step"
    return f"{steps:.2g} step{'' if f'{steps:.2g}' == '1' else 's'}"


def fill_gaps(
    name: str, t: np.ndarray, columns: Mapping[str, np.ndarray], most: int, lines: Any = None
) -> tuple[np.ndarray, dict[str, np.ndarray], Any, np.ndarray]:
    """`t` and `columns` with every gap of at most `most` missing frames filled by straight lines.

    A gap is a step over `GAP_FRAMES` median steps. It spans k median steps (rounded) and holds
    k − 1 missing frames when its length is within `JITTER_FRAMES` of a step of k steps; those
    frames are put on the gap's own even grid, and every column is interpolated linearly across
    it (a camera that dropped frames: what the strip and the drive did there is not known, and a
    straight line is the least that can be said). A gap of more frames, or of no whole number of
    them, is refused with one line. Returns (t, columns, lines, filled): `lines` with each filled
    sample given its gap's first line, and the indices of the filled samples in the new record.
    """
    t = np.asarray(t, np.float64)
    dt = np.diff(t)
    if dt.size == 0 or not np.all(dt > 0):
        return t, dict(columns), lines, np.zeros(0, int)  # the order's own check says what is wrong
    step = float(np.median(dt))
    gaps = np.flatnonzero(dt > GAP_FRAMES * step)
    if not gaps.size:
        return t, dict(columns), lines, np.zeros(0, int)
    frames = np.rint(dt[gaps] / step).astype(int)  # k ≥ 2: a gap is over 1.5 steps
    wholes = np.abs(dt[gaps] - frames * step) <= JITTER_FRAMES * step
    if not wholes.all() and _on_one_grid(t, gaps, frames, step):
        # timestamps jittered either side of a gap can each be a quarter step off: the gap is whole where
        # the stretches between the gaps, their frames counted, lie on one grid (`_on_one_grid`; a probe's
        # ±0.2-step jitter made a one-frame gap 1.74 steps long)
        wholes[:] = True
    for g, k, whole in zip(gaps, frames, wholes):
        if whole and k - 1 <= most:
            continue
        what = (
            f"{k - 1} missing frames, more than --fill-gaps {most} (fill_gaps={most}) fills"
            if whole
            else f"{dt[g] / step:.3g} steps long, no whole number of missing frames"
        )
        raise InputError(
            f"recording '{name}' has a gap in time at {sample_text(int(g) + 1, lines, t[g + 1])} of {what}: "
            f"cut the recording at the gap ({range_flag()}, Recording.segment)"
            + (
                f", or fill up to {k - 1} frames (--fill-gaps {k - 1})"
                if whole and k - 1 <= FILL_GAPS_MAX
                else ""
            )
        )
    # each sample's place in the filled record: sample i moves on by the frames missing before it
    shift = np.zeros(t.size, int)
    shift[gaps + 1] = frames - 1
    place = np.arange(t.size) + np.cumsum(shift)
    n = int(place[-1]) + 1
    filled = np.setdiff1d(np.arange(n), place)
    # the filled samples' times on each gap's own even grid, then every column by the same line
    before = np.searchsorted(place, filled) - 1  # the measured sample before each filled one
    fraction = (filled - place[before]) / (place[before + 1] - place[before])
    new_t = np.empty(n)
    new_t[place] = t
    new_t[filled] = t[before] + fraction * (t[before + 1] - t[before])
    out = {}
    for key, values in columns.items():
        values = np.asarray(values)
        full = np.empty(n, np.result_type(values.dtype, np.float64))
        full[place] = values
        full[filled] = values[before] + fraction * (values[before + 1] - values[before])
        out[key] = full
    if lines is not None:
        lines = np.asarray(lines)
        full_lines = np.empty(n, lines.dtype)
        full_lines[place] = lines
        full_lines[filled] = lines[before]
        lines = full_lines
    return new_t, out, lines, filled


def _on_one_grid(t: np.ndarray, gaps: np.ndarray, frames: np.ndarray, step: float) -> bool:
    """Whether `t`, with `frames` − 1 frames missing in each of `gaps`, is one uniform clock: each gap within
    half a step of its whole number of frames (two quarter steps of jitter), and the stretches between the
    gaps on lines of one slope (least squares within each stretch) whose offsets, the missing frames
    counted, lie within `JITTER_FRAMES` of a step of each other (a clock that slips part of a step at a gap
    moves every time after it; a slope fitted across the gaps would tilt to hide the slip). Each time's own
    jitter is `check_time`'s, on the filled record."""
    if np.any(np.abs(np.diff(t)[gaps] - frames * step) > 2 * JITTER_FRAMES * step):
        return False
    shift = np.zeros(t.size, int)
    shift[gaps + 1] = frames - 1
    place = (np.arange(t.size) + np.cumsum(shift)).astype(np.float64)
    parts = [
        (p - p.mean(), q - q.mean(), p.mean(), q.mean())
        for p, q in zip(np.split(place, gaps + 1), np.split(t, gaps + 1))
    ]
    spread = sum(float(np.sum(p * p)) for p, *_ in parts)
    if spread == 0.0:
        return False
    slope = sum(float(np.sum(p * q)) for p, q, *_ in parts) / spread
    offsets = [(q_mean - slope * p_mean) / slope for _, _, p_mean, q_mean in parts]
    return max(offsets) - min(offsets) <= JITTER_FRAMES


def fill_values(
    name: str,
    t: np.ndarray | None,
    columns: Mapping[str, np.ndarray],
    most: int,
    lines: Any = None,
    labels: Mapping[str, str] | None = None,
    start: int = 0,
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """`columns` with each run of at most `most` missing (non-finite) values bridged by straight lines.

    A cell left empty or a tracker's NaN in the drive or the output is a sample missing from that
    column, as a dropped frame is from all of them (`fill_gaps`): each run of them is put on the
    straight line between the finite values either side, at the samples' times `t` (evenly spaced
    where None). A run at the record's first or last sample has nothing on one side to draw from,
    and a run of more than `most` is cut, not guessed: each is refused with one line. `labels`
    says a column in messages (role -> ``column 'y' (mapped as output)``); `start` is the record's
    first sample in the file (a --range's), for the range a message suggests. Returns (columns,
    filled): role -> the samples filled in it (from 0), for the roles that had any.
    """
    said = dict(labels or {})
    out, filled = dict(columns), {}
    long: list[tuple[int, str, int]] = []  # (first sample, role, length) of each run over `most`
    for role, values in columns.items():
        values = np.asarray(values, np.float64)
        bad = ~np.isfinite(values)
        if not bad.any():
            continue
        k = np.flatnonzero(bad)
        breaks = np.flatnonzero(np.diff(k) != 1)
        firsts, lasts = k[np.r_[0, breaks + 1]], k[np.r_[breaks, k.size - 1]]
        what = said.get(role, f"column '{role}'")
        n = values.size
        if k.size == n:
            raise InputError(
                f"recording '{name}' has no value in {what}: all {n} samples are missing, nothing to fill "
                "from; map the column that holds the signal"
            )
        if firsts[0] == 0 or lasts[-1] == n - 1:
            head = firsts[0] == 0
            a, b = (0, lasts[0]) if head else (firsts[-1], n - 1)
            raise InputError(
                f"recording '{name}' has {b - a + 1} missing value(s) in {what} "
                f"{'from its first' if head else 'up to its last'} sample, at {sample_text(int(a), lines)}: "
                f"--fill-gaps draws a line between the measured values either side, and none comes "
                f"{'before' if head else 'after'} them; fix them, or leave those samples out "
                f"({range_flag()} {f'{start + b + 1}:{start + n}' if head else f'{start}:{start + a}'})"
            )
        runs = lasts - firsts + 1
        long += [(int(f), role, int(r)) for f, r in zip(firsts, runs) if r > most]
        x = (
            np.asarray(t, np.float64)
            if t is not None and np.all(np.diff(t) > 0)
            else np.arange(n, dtype=float)
        )
        values = values.copy()
        values[bad] = np.interp(x[bad], x[~bad], values[~bad])
        out[role], filled[role] = values, k
    if long:
        first, role, length = min(long)
        needed = max(r for _, _, r in long)
        raise InputError(
            f"recording '{name}' has {length} missing values in a row in {said.get(role, f'column {role!r}')} "
            f"from {sample_text(first, lines)}, more than --fill-gaps {most} (fill_gaps={most}) fills"
            + (f" ({len(long)} such runs in all)" if len(long) > 1 else "")
            + f": fix them, or cut the recording there ({range_flag()} A:B)"
            + (f", or fill up to {needed} in a row (--fill-gaps {needed})" if needed <= FILL_GAPS_MAX else "")
        )
    return out, filled
