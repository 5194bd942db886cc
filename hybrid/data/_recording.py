"""One experiment on the rig: drive voltage in, tip displacement out.

A :class:`Recording` holds the time base ``t`` (s), the drive voltage ``v_in``
(V) and the tip displacement ``w`` (mm) of one IPMC trial, sampled uniformly
(the paper's camera runs at 30 frames per second), plus any extra channels and
JSON-able metadata. It is validated once, when it is built, so everything
downstream can assume finite, equally long, uniformly sampled arrays.

:meth:`Recording.split` cuts it into the paper's contiguous train / test /
validation parts (30 %, 50 %, 20 %, Section IV.B), and :meth:`Recording.load` /
:meth:`Recording.save` read and write ``.csv`` (with a ``<file>.csv.json``
metadata sidecar), ``.npz`` and ``.mat`` files that round-trip exactly.

Row numbers in messages about arrays count samples from 0; messages about CSV
files give the line number in the file (from 1).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import pathlib
import re
import zipfile
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..util._errors import InputError

__all__ = ["REQUIRED", "SPLIT_PARTS", "SUFFIXES", "Recording", "Split", "sidecar"]

#: Required channels, in file order.
REQUIRED: tuple[str, ...] = ("t", "v_in", "w")
#: Units of the required channels, stored in ``metadata["units"]``.
UNITS: dict[str, str] = {"t": "s", "v_in": "V", "w": "mm"}
#: Names of the parts of a :class:`Split`.
SPLIT_PARTS: tuple[str, ...] = ("train", "test", "validation")
#: File suffixes :meth:`Recording.load` and :meth:`Recording.save` understand.
SUFFIXES: tuple[str, ...] = (".csv", ".npz", ".mat")
#: Largest ``max|dt - median dt| / median dt`` kept as it is; far above the rounding
#: of 17-digit CSV text, far below a dropped camera frame.
TIME_RTOL: float = 1e-3
#: Timestamp jitter (max |t - closest uniform grid|, in steps) up to which t is rebuilt
#: as that grid: every row is then unambiguously frame k of one clock. Millisecond
#: timestamps of a 30 Hz camera are off by up to 0.015 step from rounding alone.
#: Larger deviations (a frame rate that changed) are refused.
JITTER_FRAMES: float = 0.25
#: A step longer than this many median steps is a gap (dropped frames): refused.
GAP_FRAMES: float = 1.5
#: A median step of this many seconds or more (a rate below 0.1 Hz) is refused as t
#: written in milliseconds (33.3 at 30 fps), unless the metadata given declares
#: ``units: {"t": "s"}``. Slow legitimate recordings (a 1 Hz benchmark, dt = 1 s) pass;
#: an IPMC's RC time constants (0.1-1 s) cannot be identified below 0.1 Hz anyway.
MS_STEP_S: float = 10.0

_RESERVED = frozenset((*REQUIRED, "metadata"))
_NPZ_EXTRA = "extra_"
_MAT_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,62}")
_SHOW_ROWS = 5


# --------------------------------------------------------------------------- #
# Small helpers
# --------------------------------------------------------------------------- #


def _rows_text(rows: np.ndarray, word: str = "rows") -> str:
    """Format the first few of ``rows`` as ``"rows 12, 13 (2 in all)"``."""
    shown = ", ".join(str(int(r)) for r in rows[:_SHOW_ROWS])
    more = ", ..." if len(rows) > _SHOW_ROWS else ""
    return f"{word} {shown}{more} ({len(rows)} in all)"


def _as_vector(name: str, column: str, values: Any) -> np.ndarray:
    """Convert one channel to a read-only float64 copy of shape ``(n,)``.

    Arguments:
        name: the recording's name, for messages.
        column: the channel's name, for messages.
        values: anything ``numpy.asarray`` turns into a 1-D real array.

    Returns:
        A read-only float64 vector that owns its data.
    """
    if values is None:
        raise InputError(
            f"recording '{name}' is missing column '{column}': give t, v_in and w"
        )
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


def _check_extra_name(name: str, column: Any) -> None:
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


def _check_metadata(name: str, metadata: Any) -> dict:
    """Return a JSON-normalised deep copy of ``metadata`` with defaults filled in."""
    if metadata is None:
        metadata = {}
    if not isinstance(metadata, Mapping):
        raise InputError(
            f"recording '{name}' has metadata of type {type(metadata).__name__}: "
            "give a dict"
        )
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


def _check_finite(name: str, column: str, values: np.ndarray) -> None:
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise InputError(
            f"recording '{name}' has non-finite values in column '{column}' at "
            f"{_rows_text(bad)}: remove or interpolate them"
        )


def _check_time(name: str, t: np.ndarray, metadata: Any = None) -> tuple[np.ndarray, dict | None]:
    """Require strictly increasing, uniformly spaced sample times in seconds.

    Returns ``(t, None)`` when the steps are uniform within ``TIME_RTOL``. Otherwise,
    with no gap (no step over ``GAP_FRAMES`` median steps, none under 1/``GAP_FRAMES``)
    and every timestamp within ``JITTER_FRAMES`` of a step of the closest uniform grid,
    the times are one frame clock read with jitter: they come back as that grid
    t0 + k·dt (least squares over the frame index k; the median step would be biased
    by millisecond rounding: 33, 33, 34 ms has median 33 ms, 1 % off 30 Hz) with a
    ``time_base`` record of what was done. Gaps and larger irregularities are refused.
    """
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0) + 1
    if bad.size:
        raise InputError(
            f"recording '{name}' has time that does not strictly increase at "
            f"{_rows_text(bad)}: sort the samples and drop repeated times"
        )
    step = float(np.median(dt))
    _check_seconds(name, step, metadata)
    deviation = np.abs(dt - step)
    worst = int(np.argmax(deviation))
    if deviation[worst] <= TIME_RTOL * step:
        return t, None
    gaps = np.flatnonzero(dt > GAP_FRAMES * step)
    if gaps.size:
        k = int(gaps[0])
        raise InputError(
            f"recording '{name}' has a gap in time at row {k + 1} (t = {t[k + 1]:.6g} s): the "
            f"step into it is {dt[k]:.6g} s, {dt[k] / step:.3g} times the median step {step:.6g} s "
            f"({gaps.size} gap(s) in all): frames are missing there; cut the recording at the "
            "gap (Recording.segment) or fill the missing frames"
        )
    short = np.flatnonzero(dt < step / GAP_FRAMES)
    k = np.arange(t.size, dtype=np.float64)
    k_mean, t_mean = float(np.mean(k)), float(np.mean(t))
    slope = float(np.sum((k - k_mean) * (t - t_mean)) / np.sum((k - k_mean) ** 2))
    grid = (t_mean - slope * k_mean) + slope * k
    jitter = t - grid
    far = int(np.argmax(np.abs(jitter)))
    worst_jitter = abs(float(jitter[far]))
    if short.size or worst_jitter >= JITTER_FRAMES * slope:
        where = (f"the step into row {int(short[0]) + 1} is {dt[short[0]]:.6g} s against a median "
                 f"step of {step:.6g} s" if short.size else
                 f"row {far} (t = {t[far]:.6g} s) is {worst_jitter / slope:.2g} of a step off the "
                 "closest uniform grid")
        raise InputError(
            f"recording '{name}' has non-uniform time: {where} (timestamp jitter below "
            f"{JITTER_FRAMES:g} of a step is absorbed): did the frame rate change? Resample "
            "onto a uniform grid or rebuild t from the sampling rate"
        )
    rms = float(np.sqrt(np.mean(jitter**2)))
    note = (
        f"t rebuilt as a uniform grid t0 + k·dt, dt = {slope:.9g} s ({1 / slope:.6g} Hz), "
        f"the least-squares line through the logged times: their jitter was max "
        f"{worst_jitter * 1e3:.3g} ms, rms {rms * 1e3:.3g} ms ({worst_jitter / slope:.2g} of a step)"
    )
    grid.setflags(write=False)
    return grid, {"rebuilt": True, "dt_s": slope, "rate_hz": 1 / slope, "t0_s": float(grid[0]),
                  "jitter_max_s": worst_jitter, "jitter_rms_s": rms, "note": note}


def _check_seconds(name: str, step: float, metadata: Any) -> None:
    """Refuse a time column that steps like milliseconds (see ``MS_STEP_S``)."""
    if step < MS_STEP_S:
        return
    units = metadata.get("units") if isinstance(metadata, Mapping) else None
    if isinstance(units, Mapping) and units.get("t") == "s":
        return  # declared: a recording really sampled this slowly
    raise InputError(
        f"recording '{name}' has t stepping by {step:.4g}: t looks like milliseconds "
        f"({1000 / step:.4g} Hz if so, {1 / step:.3g} Hz if seconds); write t in seconds "
        f"(t/1000), or declare metadata units {{\"t\": \"s\"}} for a recording really "
        f"sampled every {step:.4g} s"
    )


def _is_constant(values: np.ndarray) -> bool:
    """True when values vary by no more than 1e-12 of their magnitude (or are all 0)."""
    magnitude = float(np.max(np.abs(values))) if values.size else 0.0
    return magnitude == 0.0 or float(np.std(values / magnitude)) <= 1e-12


def _source_name(metadata: Any) -> str:
    if isinstance(metadata, Mapping) and isinstance(metadata.get("source"), str):
        return metadata["source"]
    return "<arrays>"


# --------------------------------------------------------------------------- #
# Recording
# --------------------------------------------------------------------------- #


@dataclasses.dataclass(frozen=True, eq=False)
class Recording:
    """One uniformly sampled IPMC experiment.

    Arrays are copied to read-only float64 vectors and validated on
    construction; every problem raises :class:`~hybrid.util._errors.InputError`.

    Arguments:
        t: sample times, s, shape ``(n,)``, strictly increasing and uniform
            (steps within ``TIME_RTOL`` of their median). Timestamps with jitter
            below ``JITTER_FRAMES`` of a step and no gap are replaced by the
            closest uniform grid, recorded in ``metadata["time_base"]`` and
            ``notes``; a median step of ``MS_STEP_S`` or more is refused as
            milliseconds unless ``metadata["units"]["t"] == "s"``.
        v_in: drive voltage applied to the strip, V, shape ``(n,)``.
        w: tip displacement, mm, shape ``(n,)`` (the target of Eqs 18-20).
        extra: further channels by name, each shape ``(n,)``, in a fixed order
            (e.g. measured current, temperature); names are case-sensitive.
        metadata: JSON-able dict; ``"units"`` ({"t": "s", "v_in": "V",
            "w": "mm"}) and ``"source"`` are filled in when missing, an optional
            ``"strip"`` dict holds the strip geometry, anything else is kept.
        name: how messages refer to this recording (the file path when
            loaded); defaults to ``metadata["source"]``. Not part of equality.
        notes: what validation did to the data, in sentences (e.g. the time
            base rebuilt from jittered timestamps), for callers to show; not
            saved, not part of equality.
    """

    t: np.ndarray
    v_in: np.ndarray
    w: np.ndarray
    extra: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)
    metadata: dict = dataclasses.field(default_factory=dict)
    name: str = ""
    notes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        name = self.name or _source_name(self.metadata)
        object.__setattr__(self, "name", name)
        columns = {c: _as_vector(name, c, getattr(self, c)) for c in REQUIRED}
        if not isinstance(self.extra, Mapping):
            raise InputError(
                f"recording '{name}' has extra channels of type "
                f"{type(self.extra).__name__}: give a dict of name -> array"
            )
        extra = {}
        for column, values in self.extra.items():
            _check_extra_name(name, column)
            extra[column] = _as_vector(name, column, values)
        lengths = {c: len(v) for c, v in {**columns, **extra}.items()}
        if len(set(lengths.values())) > 1:
            listed = ", ".join(f"{c}={k}" for c, k in lengths.items())
            raise InputError(
                f"recording '{name}' has columns of different lengths ({listed}): "
                "give every channel one value per sample"
            )
        if lengths["t"] < 2:
            raise InputError(
                f"recording '{name}' has {lengths['t']} sample(s): a recording "
                "needs at least 2 samples"
            )
        for column, values in {**columns, **extra}.items():
            _check_finite(name, column, values)
        columns["t"], time_base = _check_time(name, columns["t"], self.metadata)
        for column, values in columns.items():
            object.__setattr__(self, column, values)
        object.__setattr__(self, "extra", extra)
        metadata = _check_metadata(name, self.metadata)
        notes = tuple(self.notes)
        if time_base is not None:
            metadata["time_base"] = time_base
            notes += (f"recording '{name}': {time_base['note']}",)
        object.__setattr__(self, "metadata", metadata)
        object.__setattr__(self, "notes", notes)

    # ----------------------------------------------------------------- build

    @classmethod
    def from_arrays(
        cls,
        t: Any = None,
        v_in: Any = None,
        w: Any = None,
        rate: float | None = None,
        *,
        t0: float = 0.0,
        extra: Mapping[str, Any] | None = None,
        metadata: Mapping[str, Any] | None = None,
        name: str = "",
    ) -> Recording:
        """Build a recording, making the time base from ``rate`` when ``t`` is None.

        Arguments:
            t: sample times, s; give either this or ``rate``.
            v_in: drive voltage, V.
            w: tip displacement, mm.
            rate: sampling rate, Hz; ``t = t0 + arange(n) / rate``.
            t0: time of the first sample, s, when ``t`` is built from ``rate``.
            extra: extra channels by name.
            metadata: JSON-able metadata (see :class:`Recording`).
            name: how messages refer to the recording.

        Returns:
            The validated :class:`Recording`.
        """
        label = name or _source_name(metadata)
        if (t is None) == (rate is None):
            raise InputError(
                f"recording '{label}' needs exactly one of t and rate: give the "
                "sample times or the sampling rate in Hz, not both or neither"
            )
        if t is None:
            if not (isinstance(rate, (int, float)) and math.isfinite(rate) and rate > 0):
                raise InputError(
                    f"recording '{label}' has sampling rate {rate!r}: give a "
                    "positive number of Hz"
                )
            n = len(_as_vector(label, "w", w))
            t = t0 + np.arange(n, dtype=np.float64) / float(rate)
        return cls(t, v_in, w, dict(extra or {}), dict(metadata or {}), name)

    # ------------------------------------------------------------ properties

    @property
    def n(self) -> int:
        """Number of samples."""
        return len(self.t)

    def __len__(self) -> int:
        return len(self.t)

    @property
    def dt(self) -> float:
        """Sampling step, s: the median of the time steps."""
        return float(np.median(np.diff(self.t)))

    @property
    def rate(self) -> float:
        """Sampling rate, Hz: ``1 / dt``."""
        return 1.0 / self.dt

    @property
    def duration(self) -> float:
        """Time covered, s: ``n * dt`` (last minus first sample time, plus one step)."""
        return self.n * self.dt

    @property
    def channels(self) -> dict[str, np.ndarray]:
        """All channels in file order: t, v_in, w, then the extras."""
        return {"t": self.t, "v_in": self.v_in, "w": self.w, **self.extra}

    def __eq__(self, other: object) -> bool:
        """Exact equality of every channel (names and order) and of the metadata."""
        if not isinstance(other, Recording):
            return NotImplemented
        mine, theirs = self.channels, other.channels
        return (
            list(mine) == list(theirs)
            and all(np.array_equal(mine[c], theirs[c]) for c in mine)
            and self.metadata == other.metadata
        )

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        extra = f", extra={list(self.extra)}" if self.extra else ""
        return (
            f"Recording(name={self.name!r}, n={self.n}, rate={self.rate:.6g} Hz, "
            f"duration={self.duration:.6g} s{extra})"
        )

    # ---------------------------------------------------------------- checks

    def check_length(
        self,
        min_samples: int,
        what: str = "the model's input window",
        fix: str = "record longer or use a shorter window (--window)",
    ) -> Recording:
        """Require at least ``min_samples`` samples.

        Arguments:
            min_samples: the fewest samples the caller can work with.
            what: what needs them, for the message.
            fix: how to fix a short recording, for the message.

        Returns:
            This recording, so the check can be chained.
        """
        if self.n < min_samples:
            raise InputError(
                f"recording '{self.name}' has {self.n} samples but {what} needs "
                f"at least {min_samples}: {fix}"
            )
        return self

    def check_signals(self) -> Recording:
        """Require a drive and a displacement that vary.

        A constant (or all-zero) column cannot be fitted, and a fit would print its
        start values as fitted parameters; the likely causes are named. Constant
        means a standard deviation of at most 1e-12 of the column's magnitude.
        Loading does not require this (a rest recording or an interrupted one is
        still a recording); `fit`, `fit_batch`, `diagnose` and `hybrid sensitivity`
        check it first.

        Returns:
            This recording, so the check can be chained.
        """
        for column, what, cause in (
            ("v_in", "drive", "is it the right column, or was the drive off?"),
            ("w", "displacement", "is it the right column, or did the tracking fail?"),
        ):
            values = getattr(self, column)
            if _is_constant(values):
                raise InputError(
                    f"recording '{self.name}': the {what} column {column} is constant "
                    f"({values[0]:.6g} {UNITS[column]} in all {self.n} samples): {cause}"
                )
        return self

    # ---------------------------------------------------------------- slicing

    def segment(self, index: slice) -> Recording:
        """The contiguous part of the recording selected by ``index``.

        Arguments:
            index: a slice with step 1 (or None), e.g. ``slice(100, 400)``.

        Returns:
            A new :class:`Recording`; its metadata gains ``"segment":
            {"start", "stop"}``, sample indices into the original recording
            (composed when segmenting a segment).
        """
        if not isinstance(index, slice) or index.step not in (None, 1):
            raise InputError(
                f"recording '{self.name}' was asked for segment {index!r}: give a "
                "slice with step 1, e.g. slice(100, 400)"
            )
        start, stop, _ = index.indices(self.n)
        if stop - start < 2:
            raise InputError(
                f"recording '{self.name}' segment {start}:{stop} has "
                f"{max(stop - start, 0)} sample(s): a segment needs at least 2"
            )
        metadata = dict(self.metadata)
        previous = metadata.get("segment")
        offset = int(previous.get("start", 0)) if isinstance(previous, dict) else 0
        metadata["segment"] = {"start": offset + start, "stop": offset + stop}
        return Recording(
            self.t[start:stop],
            self.v_in[start:stop],
            self.w[start:stop],
            {c: v[start:stop] for c, v in self.extra.items()},
            metadata,
            self.name,
        )

    def split(
        self,
        fractions: Sequence[float] = (0.3, 0.5, 0.2),
        order: Sequence[str] = ("train", "test", "validation"),
    ) -> Split:
        """Cut into contiguous train / test / validation parts, in time order.

        The paper (Section IV.B) splits 30 % / 50 % / 20 %; by default the
        first 30 % of the samples train, the next 50 % test and the last 20 %
        validate. Boundaries are ``round(cumsum(fractions) * n)``.

        Arguments:
            fractions: positive shares of the samples, summing to 1, one per
                entry of ``order``.
            order: the parts in time order, a permutation of
                ``("train", "test", "validation")``.

        Returns:
            A :class:`Split` with the three recordings and their index ranges.
        """
        order = tuple(order)
        fractions = _check_fractions(self.name, fractions, order)
        bounds = [0, *(round(f * self.n) for f in np.cumsum(fractions)[:-1]), self.n]
        slices = {part: slice(bounds[i], bounds[i + 1]) for i, part in enumerate(order)}
        short = {p: s.stop - s.start for p, s in slices.items() if s.stop - s.start < 2}
        if short:
            listed = ", ".join(f"{p} {k}" for p, k in short.items())
            raise InputError(
                f"recording '{self.name}' with {self.n} samples is too short to "
                f"split by {list(fractions)} (samples: {listed}): every part needs "
                "at least 2 samples, so record longer or change the fractions"
            )
        parts = {p: self._part(p, s) for p, s in slices.items()}
        return Split(**parts, slices=slices)

    def _part(self, part: str, index: slice) -> Recording:
        segment = self.segment(index)
        metadata = dict(segment.metadata)
        metadata["split"] = part
        return dataclasses.replace(segment, metadata=metadata)

    # -------------------------------------------------------------------- I/O

    @classmethod
    def load(cls, path: str | pathlib.Path, *, require_w: bool = True) -> Recording:
        """Read a recording from a ``.csv``, ``.npz`` or ``.mat`` file.

        * ``.csv``: lines starting with ``#`` and blank lines are skipped; the
          first other line is the header, which must name ``t``, ``v_in`` and
          ``w`` exactly (case-sensitive); other columns become extra channels
          in order. Metadata comes from the sidecar ``<file>.csv.json`` when
          it exists.
        * ``.npz``: arrays ``t``, ``v_in``, ``w``; ``extra_<name>`` (and any
          other array) become extra channels; ``metadata`` is a JSON string.
        * ``.mat``: vector variables ``t``, ``v_in``, ``w``; other vector
          variables become extra channels; ``metadata`` is a JSON string.

        Arguments:
            path: the file.
            require_w: False to read a drive (``t`` and ``v_in``) that may lack
                ``w`` (e.g. ``hybrid rc``): a missing ``w`` is then filled
                with zeros; every other check is the same.

        Returns:
            The validated :class:`Recording`, named by ``path``.
        """
        path = _path_argument(path, "Recording.load")
        reader = {".csv": _load_csv, ".npz": _load_npz, ".mat": _load_mat}[
            _suffix(path)
        ]
        if not path.exists():
            raise InputError(f"recording file '{path}' does not exist: check the path")
        if not path.is_file():
            raise InputError(f"recording file '{path}' is not a file: give a file path")
        if path.stat().st_size == 0:
            raise InputError(
                f"recording file '{path}' is empty: give a file with a header and data"
            )
        columns, metadata = reader(path, REQUIRED if require_w else REQUIRED[:2])
        if "w" not in columns:
            columns["w"] = np.zeros_like(columns["t"])
        metadata.setdefault("source", str(path))
        extra = {c: v for c, v in columns.items() if c not in REQUIRED}
        return cls(columns["t"], columns["v_in"], columns["w"], extra, metadata, str(path))

    def save(self, path: str | pathlib.Path) -> pathlib.Path:
        """Write the recording so that :meth:`load` gives it back exactly.

        ``.csv`` files hold every channel at 17 significant digits and get a
        ``<file>.csv.json`` metadata sidecar next to them; ``.mat`` files need
        extra channel names that are MATLAB identifiers.

        The file (and the sidecar) are written to temporaries and renamed
        over ``path`` once complete (:mod:`hybrid.util._atomic`): a full disk or
        any other error leaves what was at ``path`` unchanged.

        Arguments:
            path: the file to write; its suffix picks the format.

        Returns:
            The path written.
        """
        from ..util._atomic import staged

        path = _path_argument(path, "Recording.save")
        writer = {".csv": _save_csv, ".npz": _save_npz, ".mat": _save_mat}[_suffix(path)]
        targets = (path, sidecar(path)) if writer is _save_csv else (path,)
        with staged(*targets) as temporaries:
            writer(self, *temporaries)
        return path


@dataclasses.dataclass(frozen=True, eq=False)
class Split:
    """A recording cut into contiguous train / test / validation parts.

    Arguments:
        train: the part used to fit the model.
        test: the part used to evaluate it.
        validation: the part used for early stopping / model selection.
        slices: each part's sample range in the original recording.
    """

    train: Recording
    test: Recording
    validation: Recording
    slices: dict[str, slice]

    def __getitem__(self, part: str) -> Recording:
        if part not in SPLIT_PARTS:
            raise InputError(
                f"split has no part {part!r}: use one of {', '.join(SPLIT_PARTS)}"
            )
        return getattr(self, part)

    def items(self) -> list[tuple[str, Recording]]:
        """The parts as ``(name, recording)`` pairs, in time order."""
        ordered = sorted(self.slices, key=lambda p: self.slices[p].start)
        return [(p, getattr(self, p)) for p in ordered]


def _check_fractions(
    name: str, fractions: Sequence[float], order: tuple[str, ...]
) -> tuple[float, ...]:
    """Validate split fractions and order; return the fractions as floats."""
    if sorted(order) != sorted(SPLIT_PARTS):
        raise InputError(
            f"split order {list(order)} for recording '{name}' is not a "
            "permutation of train, test and validation: name each part once"
        )
    try:
        values = tuple(float(f) for f in fractions)
    except (TypeError, ValueError):
        raise InputError(
            f"split fractions {fractions!r} for recording '{name}' are not "
            "numbers: give three positive numbers that sum to 1"
        ) from None
    if len(values) != len(order):
        raise InputError(
            f"split has {len(values)} fractions for {len(order)} parts: give one "
            "fraction per part of the order"
        )
    if not all(math.isfinite(f) and f > 0 for f in values):
        raise InputError(
            f"split fractions {list(values)} are not all positive: give every "
            "part a positive share"
        )
    if abs(sum(values) - 1.0) > 1e-9:
        raise InputError(
            f"split fractions {list(values)} sum to {sum(values):.6g}, not 1: "
            "scale them so they sum to 1"
        )
    return values


# --------------------------------------------------------------------------- #
# File formats
# --------------------------------------------------------------------------- #


def _suffix(path: pathlib.Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise InputError(
            f"recording '{path}' has unknown suffix '{path.suffix}': use "
            + ", ".join(SUFFIXES)
        )
    return suffix


def sidecar(path: str | pathlib.Path) -> pathlib.Path:
    """The metadata sidecar of a CSV recording: ``run.csv`` -> ``run.csv.json``."""
    path = pathlib.Path(path)
    return path.with_name(path.name + ".json")


def _path_argument(path: Any, where: str) -> pathlib.Path:
    """``path`` as a Path; anything but a str or os.PathLike is an InputError."""
    if not isinstance(path, (str, os.PathLike)) or not str(path).strip():
        raise InputError(
            f"{where} needs a file path (str or pathlib.Path), got {path!r}: give e.g. 'run.csv'"
        )
    return pathlib.Path(path)


def _require(
    path: pathlib.Path, found: Sequence[str], kind: str, required: Sequence[str] = REQUIRED
) -> None:
    missing = [c for c in required if c not in found]
    if missing:
        shown = ", ".join(f"'{c}'" for c in found) or "none"
        raise InputError(
            f"recording '{path}' is missing {kind} {', '.join(missing)} (found "
            f"{shown}): name them exactly t, v_in and w (case-sensitive)"
        )


def _parse_metadata(path: pathlib.Path, text: str, where: str) -> dict:
    try:
        metadata = json.loads(text)
    except ValueError as error:
        raise InputError(
            f"recording '{path}' has unreadable metadata in {where} ({error}): "
            "fix the JSON or delete it"
        ) from None
    if not isinstance(metadata, dict):
        raise InputError(
            f"recording '{path}' has metadata in {where} that is not a JSON "
            "object: write it as {...}"
        )
    return metadata


# ------------------------------------------------------------------- CSV


def _read_text(path: pathlib.Path) -> str:
    try:
        return path.read_text(encoding="utf-8-sig")  # -sig: Excel's byte-order mark
    except UnicodeDecodeError:
        raise InputError(
            f"recording '{path}' is not UTF-8 text: save it as a plain CSV file"
        ) from None
    except OSError as error:
        raise InputError(
            f"recording '{path}' cannot be read ({error.strerror or error}): check "
            "its permissions"
        ) from None


def _csv_lines(path: pathlib.Path) -> list[tuple[int, str]]:
    """Non-blank, non-comment lines with their line numbers (from 1)."""
    lines = []
    for number, line in enumerate(_read_text(path).splitlines(), start=1):
        stripped = line.strip()
        if stripped and not stripped.startswith("#"):
            lines.append((number, stripped))
    return lines


def _csv_header(
    path: pathlib.Path, line: str, required: Sequence[str] = REQUIRED
) -> list[str]:
    _check_delimiter(path, line)
    header = [cell.strip().strip('"').strip() for cell in line.split(",")]
    if any(not cell for cell in header):
        raise InputError(
            f"recording '{path}' has an empty column name in its header: name "
            "every column"
        )
    repeated = sorted({c for c in header if header.count(c) > 1})
    if repeated:
        raise InputError(
            f"recording '{path}' names column(s) {', '.join(repeated)} more than "
            "once: give each column a unique name"
        )
    _require(path, header, "column(s)", required)
    return header


def _check_delimiter(path: pathlib.Path, line: str) -> None:
    """Refuse a header split by ';', tabs or spaces: its columns would read as missing."""
    if "," in line:
        return
    for mark, word in ((";", "';'"), ("\t", "tabs"), (None, "spaces")):
        cells = [c.strip().strip('"') for c in line.split(mark)]
        if len(cells) > 1 and set(cells) & set(REQUIRED):
            raise InputError(
                f"recording '{path}' uses {word} as its delimiter (header {line.strip()!r}): "
                "save it comma-separated with '.' decimals (t,v_in,w)"
            )


def _csv_column(
    path: pathlib.Path, column: str, cells: list[str], numbers: np.ndarray
) -> np.ndarray:
    """Convert one column of cells, naming the first bad cell and its line."""
    try:
        values = np.array(cells, dtype=np.float64)
    except ValueError:
        for cell, number in zip(cells, numbers):
            try:
                float(cell)
            except ValueError:
                raise InputError(
                    f"recording '{path}' has non-numeric cell {cell!r} at line "
                    f"{number}, column '{column}': fix or remove that line"
                ) from None
        raise  # pragma: no cover - numpy and float() disagree
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise InputError(
            f"recording '{path}' has non-finite values in column '{column}' at "
            f"{_rows_text(numbers[bad], 'lines')}: remove or interpolate them"
        )
    return values


def _load_csv(
    path: pathlib.Path, required: Sequence[str] = REQUIRED
) -> tuple[dict[str, np.ndarray], dict]:
    lines = _csv_lines(path)
    if not lines:
        raise InputError(
            f"recording '{path}' has no header or data: give a header line "
            "t,v_in,w and one line per sample"
        )
    header = _csv_header(path, lines[0][1], required)
    rows, numbers = [], []
    for number, line in lines[1:]:
        cells = [cell.strip() for cell in line.split(",")]
        if len(cells) != len(header):
            hint = ""
            if len(cells) > len(header) and "." not in line and re.search(r"\d,\d", line):
                hint = " (decimal commas? write numbers with '.' decimals)"
            raise InputError(
                f"recording '{path}' has {len(cells)} cells at line {number} but "
                f"{len(header)} columns in its header{hint}: make every line match the header"
            )
        rows.append(cells)
        numbers.append(number)
    if not rows:
        raise InputError(
            f"recording '{path}' has a header but no data lines: add one line "
            "per sample"
        )
    numbers = np.asarray(numbers)
    columns = {
        c: _csv_column(path, c, [row[i] for row in rows], numbers)
        for i, c in enumerate(header)
    }
    meta_path = sidecar(path)
    metadata = {}
    if meta_path.exists():
        metadata = _parse_metadata(path, _read_text(meta_path), f"'{meta_path.name}'")
    return columns, metadata


def _save_csv(recording: Recording, path: pathlib.Path, meta_path: pathlib.Path | None = None) -> None:
    channels = recording.channels
    table = np.column_stack(list(channels.values()))
    np.savetxt(path, table, fmt="%.17g", delimiter=",", header=",".join(channels), comments="")
    meta_path = sidecar(path) if meta_path is None else meta_path
    meta_path.write_text(json.dumps(recording.metadata, indent=2) + "\n", encoding="utf-8")


# ------------------------------------------------------------------- NPZ


def _load_npz(
    path: pathlib.Path, required: Sequence[str] = REQUIRED
) -> tuple[dict[str, np.ndarray], dict]:
    try:
        with np.load(path, allow_pickle=False) as archive:
            arrays = {key: archive[key] for key in archive.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as error:
        raise InputError(
            f"recording '{path}' is not a readable .npz archive ({error}): save it "
            "with numpy.savez or Recording.save"
        ) from None
    metadata = {}
    if "metadata" in arrays:
        metadata = _parse_metadata(path, str(arrays.pop("metadata")[()]), "its 'metadata' entry")
    _require(path, list(arrays), "array(s)", required)
    columns = {}
    for key, values in arrays.items():
        column = key[len(_NPZ_EXTRA):] if key.startswith(_NPZ_EXTRA) else key
        columns[column] = _file_vector(path, key, values)
    return columns, metadata


def _save_npz(recording: Recording, path: pathlib.Path) -> None:
    arrays = {"t": recording.t, "v_in": recording.v_in, "w": recording.w}
    arrays |= {_NPZ_EXTRA + c: v for c, v in recording.extra.items()}
    arrays["metadata"] = np.array(json.dumps(recording.metadata))
    with open(path, "wb") as handle:  # an open file stops numpy appending .npz
        np.savez(handle, **arrays)


# ------------------------------------------------------------------- MAT


def _file_vector(path: pathlib.Path, key: str, values: np.ndarray) -> np.ndarray:
    """Check that a stored variable is a real numeric vector; return it flat."""
    values = np.asarray(values)
    if values.dtype.kind not in "biuf":
        raise InputError(
            f"recording '{path}' has variable '{key}' of type {values.dtype} "
            "rather than real numbers: store numeric vectors only"
        )
    if values.ndim > 1 and sum(k > 1 for k in values.shape) > 1:
        raise InputError(
            f"recording '{path}' has variable '{key}' of shape {values.shape}, "
            "not a vector: store one value per sample"
        )
    return values.reshape(-1)


def _is_hdf5(path: pathlib.Path) -> bool:
    """MATLAB v7.3 files are HDF5: a 512-byte MATLAB header, then the HDF5 signature."""
    try:
        with open(path, "rb") as handle:
            head = handle.read(520)
    except OSError:
        return False
    return head[:10] == b"MATLAB 7.3" or head[512:520] == b"\x89HDF\r\n\x1a\n"


def _load_mat(
    path: pathlib.Path, required: Sequence[str] = REQUIRED
) -> tuple[dict[str, np.ndarray], dict]:
    import scipy.io

    try:
        variables = scipy.io.loadmat(str(path))
    except Exception as error:  # scipy raises many types for broken files
        if "7.3" in str(error) or _is_hdf5(path):
            raise InputError(
                f"recording '{path}' is a MATLAB v7.3 (HDF5) .mat file, which cannot be read "
                "here: save it in the v7 format, save(file, 't', 'v_in', 'w', '-v7')"
            ) from None
        raise InputError(
            f"recording '{path}' is not a readable .mat file ({error}): save it "
            "with MATLAB's save(file, 't', 'v_in', 'w', '-v7') or Recording.save"
        ) from None
    variables = {k: v for k, v in variables.items() if not k.startswith("__")}
    metadata = {}
    if "metadata" in variables:
        text = variables.pop("metadata")
        if text.dtype.kind != "U" or text.size != 1:
            raise InputError(
                f"recording '{path}' has a 'metadata' variable that is not one "
                "string: store the metadata as a JSON char array"
            )
        metadata = _parse_metadata(path, str(text.reshape(-1)[0]), "its 'metadata' variable")
    _require(path, list(variables), "variable(s)", required)
    columns = {key: _file_vector(path, key, values) for key, values in variables.items()}
    return columns, metadata


def _save_mat(recording: Recording, path: pathlib.Path) -> None:
    import scipy.io

    bad = [c for c in recording.extra if not _MAT_NAME.fullmatch(c)]
    if bad:
        raise InputError(
            f"recording '{recording.name}' has extra channel(s) {', '.join(bad)} "
            "that are not MATLAB variable names: rename them (letter first, then "
            "letters, digits or _, at most 63) or save as .csv or .npz"
        )
    variables: dict[str, Any] = dict(recording.channels)
    variables["metadata"] = json.dumps(recording.metadata)  # ASCII: MATLAB-safe
    scipy.io.savemat(str(path), variables, oned_as="column")
