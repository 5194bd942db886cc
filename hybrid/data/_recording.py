"""One experiment on the rig: drive voltage in, tip displacement out.

A [`Recording`][hybrid.Recording] holds the time base ``t`` (s), the drive voltage ``v_in``
(V) and the tip displacement ``w`` (mm) of one IPMC trial, sampled uniformly
(the paper's camera runs at 30 frames per second), plus any extra channels and
JSON-able metadata. It is validated once, when it is built
(`hybrid.data._recording_checks`), so everything downstream can assume
finite, equally long, uniformly sampled arrays.

`Recording.split` cuts it into the paper's contiguous train / test /
validation parts (30 %, 50 %, 20 %, Section IV.B; `hybrid.data._split`),
and `Recording.load` / `Recording.save` read and write ``.csv``
(with a ``<file>.csv.json`` metadata sidecar), ``.npz`` and ``.mat`` files that
round-trip exactly (`hybrid.data._loaders`, `hybrid.data._writers`).

Messages about arrays name samples from 0 (``sample 12``); messages about a
file give its line (from 1) and the sample: ``line 14 (sample 12)``.
"""

from __future__ import annotations

import dataclasses
import math
import os
import pathlib
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..util._errors import InputError
from ._header_units import prefix_factor
from ._loaders import path_argument, read_file
from ._recording_checks import (
    REQUIRED,
    UNITS,
    as_vector,
    check_extra_name,
    check_finite,
    check_metadata,
    check_time,
    is_constant,
    range_flag,
    source_name,
    time_step,
    wild_sample,
    wrapped_angle,
)
from ._split import Split, split_recording
from ._writers import write_file

__all__ = ["Recording", "in_shared_units"]


@dataclasses.dataclass(frozen=True, eq=False)
class Recording:
    """One uniformly sampled IPMC experiment.

    Arrays are copied to read-only float64 vectors and validated on
    construction; every problem raises [`InputError`][hybrid.InputError].

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
        name = self.name or source_name(self.metadata)
        object.__setattr__(self, "name", name)
        columns = {c: as_vector(name, c, getattr(self, c)) for c in REQUIRED}
        if not isinstance(self.extra, Mapping):
            raise InputError(
                f"recording '{name}' has extra channels of type "
                f"{type(self.extra).__name__}: give a dict of name -> array"
            )
        extra = {}
        for column, values in self.extra.items():
            check_extra_name(name, column)
            extra[column] = as_vector(name, column, values)
        lengths = {c: len(v) for c, v in {**columns, **extra}.items()}
        if len(set(lengths.values())) > 1:
            listed = ", ".join(f"{c}={k}" for c, k in lengths.items())
            raise InputError(
                f"recording '{name}' has columns of different lengths ({listed}): "
                "give every channel one value per sample"
            )
        if lengths["t"] < 2:
            raise InputError(
                f"recording '{name}' has {lengths['t']} sample(s): a recording needs at least 2 samples"
            )
        for column, values in {**columns, **extra}.items():
            check_finite(name, column, values)
        columns["t"], time_base = check_time(name, columns["t"], self.metadata)
        for column, values in columns.items():
            object.__setattr__(self, column, values)
        object.__setattr__(self, "extra", extra)
        metadata = check_metadata(name, self.metadata)
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
            metadata: JSON-able metadata (see [`Recording`][hybrid.Recording]).
            name: how messages refer to the recording.

        Returns:
            The validated [`Recording`][hybrid.Recording].
        """
        label = name or source_name(metadata)
        if (t is None) == (rate is None):
            raise InputError(
                f"recording '{label}' needs exactly one of t and rate: give the "
                "sample times or the sampling rate in Hz, not both or neither"
            )
        if t is None:
            if not (isinstance(rate, (int, float)) and math.isfinite(rate) and rate > 0):
                raise InputError(
                    f"recording '{label}' has sampling rate {rate!r}: give a positive number of Hz"
                )
            n = len(as_vector(label, "w", w))
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
        """Sampling step, s: the span of ``t`` over its steps, its rate to six significant digits
        (`time_step`): for a grid rebuilt from jittered timestamps its least-squares step, for times
        kept as read their mean step."""
        return time_step(self.t)

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
                f"recording '{self.name}' has {self.n} samples but {what} needs at least {min_samples}: {fix}"
            )
        return self

    def check_signals(self) -> Recording:
        """Require a drive and a displacement that vary.

        A constant (or all-zero) column cannot be fitted, and a fit would print its
        start values as fitted parameters; the likely causes are named. Constant
        means a standard deviation of at most 1e-12 of the column's magnitude.
        An output that reads as an angle wrapping around (a whole turn's jumps
        while it moves on across them, `wrapped_angle`) is refused too, with
        how to unwrap it. Loading does not require this (a rest recording or an interrupted one is
        still a recording); `fit`, `fit_batch`, `diagnose` and `hybrid sensitivity`
        check it first.

        Returns:
            This recording, so the check can be chained.
        """
        units = self.metadata.get("units")
        units = units if isinstance(units, Mapping) else {}
        for column, what, cause in (
            ("v_in", "drive", "is it the right column, or was the drive off?"),
            (
                "w",
                "output",
                "a disconnected or saturated sensor, a failed tracking, or the wrong column?",
            ),
        ):
            values = getattr(self, column)
            if is_constant(values):
                unit = units.get(column)
                unit = unit if isinstance(unit, str) and unit else UNITS[column]
                raise InputError(
                    f"recording '{self.name}': the {what} column {column} is constant "
                    f"({values[0]:.6g} {unit} in all {self.n} samples): {cause}"
                )
            wild = wild_sample(values)
            if wild is not None:
                k, times = wild
                raise InputError(
                    f"recording '{self.name}': {column} at sample {k} (t = {self.t[k]:.6g} s) is {values[k]:.6g}, "
                    f"{times:.3g} times the column's typical deviation from its median: a corrupt cell? fix or "
                    f"delete that line (or leave it out with {range_flag()})"
                )
        wrapped = wrapped_angle(self.w)
        if wrapped is not None:
            turn, unwrap, count, k = wrapped
            mapping = self.metadata.get("mapping")
            source = mapping.get("w") if isinstance(mapping, Mapping) else None
            named = f"w (the file's column '{source}')" if isinstance(source, str) and source != "w" else "w"
            raise InputError(
                f"recording '{self.name}': {named} jumps by a whole turn ({turn}) {count} time(s), from one end "
                f"of its range to the other while it moves on across (the first at sample {k}, t = "
                f"{self.t[k]:.6g} s): an angle that wraps around, as an encoder or atan2 gives it; unwrap that "
                f"column ({unwrap}) and load it again"
            )
        return self

    # ---------------------------------------------------------------- slicing

    def segment(self, index: slice) -> Recording:
        """The contiguous part of the recording selected by ``index``.

        Arguments:
            index: a slice with step 1 (or None), e.g. ``slice(100, 400)``.

        Returns:
            A new [`Recording`][hybrid.Recording]; its metadata gains ``"segment":
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
            A [`Split`][hybrid.Split] with the three recordings and their index ranges.
        """
        return split_recording(self, fractions, order)

    # -------------------------------------------------------------------- I/O

    @classmethod
    def load(cls, path: str | os.PathLike[str], *, require_w: bool = True, **mapping: Any) -> Recording:
        """Read a recording from a ``.csv``, ``.npz`` or ``.mat`` file.

        With any of ``input``, ``output``, ``columns``, ``time``, ``rate``,
        ``sample_range``, ``units`` or ``name`` given (not None), the file's own
        column names are mapped instead: ``Recording.load("dataBenchmark.csv",
        input="uEst", output="yEst")`` reads a benchmark file; see
        `hybrid.data._mapping.load_mapped`. Without them, as follows.

        * ``.csv``: lines starting with ``#`` and blank lines are skipped; the
          first other line is the header, which must name ``t``, ``v_in`` and
          ``w`` exactly (case-sensitive); other columns become extra channels
          in order, except a column of mostly text (a timestamp, a comment),
          which is left out with a note; empty names after the last column
          (a spreadsheet's trailing commas) are ignored. A units row right
          under the header (``s,V,mm``; no number in any cell) gives the
          units of v_in and w, and t's (ms, us, min, h are converted to s),
          with a note. A ``t`` of ISO 8601 date-times is read as seconds
          after the first (``metadata["start_time"]``). A header split by ';' or tabs (no comma) marks a
          spreadsheet's export: its cells are read as such, decimal commas
          (``1,5``) included, with a note. Metadata comes from the sidecar ``<file>.csv.json`` when
          it exists.
        * ``.npz``: arrays ``t``, ``v_in``, ``w``; ``extra_<name>`` (and any
          other array) become extra channels; ``metadata`` is a JSON string.
        * ``.mat`` (v7, or v7.3/HDF5 through h5py): vector variables ``t``,
          ``v_in``, ``w``; other vector variables become extra channels;
          ``metadata`` is a JSON string.

        Arguments:
            path: the file.
            require_w: False to read a drive (``t`` and ``v_in``) that may lack
                ``w`` (e.g. ``hybrid rc``): a missing ``w`` is then filled
                with zeros; every other check is the same.

        Returns:
            The validated [`Recording`][hybrid.Recording], named by ``path``.
        """
        if mapping:
            from ._mapping import load_mapped  # it builds Recordings: imported here, not at the top

            unknown = not mapping.keys() <= (load_mapped.__kwdefaults__ or {}).keys()  # its TypeError
            if unknown or any(value is not None for value in mapping.values()):
                return load_mapped(path, require_w=require_w, **mapping)
        path = path_argument(path, "Recording.load")
        columns, metadata, notes, lines = read_file(path, require_w=require_w)
        if lines is not None:  # the file's lines in the time's messages (the Recording names samples only)
            check_time(str(path), columns["t"], metadata, lines)
        if metadata.get("complete") is False:  # a recorder's sidecar: `rig record` interrupted, kept partial
            why = metadata.get("error") or metadata.get("status") or "no reason given"
            notes = (*notes, f"recording '{path}': its sidecar says it is incomplete ({why}): it ends early")
        extra = {c: v for c, v in columns.items() if c not in REQUIRED}
        return cls(columns["t"], columns["v_in"], columns["w"], extra, metadata, str(path), notes)

    def save(self, path: str | pathlib.Path) -> pathlib.Path:
        """Write the recording so that `load` gives it back exactly.

        ``.csv`` files hold every channel at 17 significant digits and get a
        ``<file>.csv.json`` metadata sidecar next to them; ``.mat`` files need
        extra channel names that are MATLAB identifiers.

        The file (and the sidecar) are written to temporaries and renamed
        over ``path`` once complete (`hybrid.util._atomic`): a full disk or
        any other error leaves what was at ``path`` unchanged.

        Arguments:
            path: the file to write; its suffix picks the format.

        Returns:
            The path written.
        """
        path = path_argument(path, "Recording.save")
        write_file(self, path)
        return path


#: The signals `in_shared_units` puts in one unit, and how its messages name them.
_SHARED = {"w": "the output (w)", "v_in": "the drive (v_in)"}


def in_shared_units(recordings: Sequence[Recording], where: str) -> list[Recording]:
    """`recordings` fitted together, each signal in the first recording's unit (``metadata["units"]``).

    A recording that gives its output or its drive in another unit of the same
    quantity, differing by an SI prefix (µm beside mm, mV beside V), is
    converted: its values scaled, its units set to the first's, and a note
    (`Recording.notes`) says so. Units a prefix cannot relate (counts beside
    mm) are an `InputError` naming both: one model cannot fit numbers on two
    scales. Recordings already in one unit are returned as they are.
    """
    recordings = list(recordings)
    if len(recordings) < 2:
        return recordings
    first = recordings[0]
    target = {role: str(first.metadata["units"][role]) for role in _SHARED}
    out = [first]
    for r in recordings[1:]:
        changes: dict[str, Any] = {}
        said = []
        units = dict(r.metadata["units"])
        for role, what in _SHARED.items():
            unit = str(units[role])
            factor = prefix_factor(unit, target[role])
            if factor is None:
                raise InputError(
                    f"{where}: recording '{r.name}' gives {what} in {unit}, but '{first.name}' gives it in "
                    f"{target[role]}, and no SI prefix relates them: fit recordings of one scale together "
                    f"(convert one, or give its unit with --units {role}=...; units= in Python)"
                )
            if factor != 1.0:
                changes[role] = np.asarray(getattr(r, role)) * factor
                units[role] = target[role]
                said.append(f"{what} from {unit} to {target[role]} (×{factor:g})")
        if changes:
            note = f"recording '{r.name}': {' and '.join(said)}, the unit of '{first.name}' it is fitted with"
            r = dataclasses.replace(
                r, **changes, metadata={**r.metadata, "units": units}, notes=(*r.notes, note)
            )
        scaled = [n for n in (_scale_apart(first, r, role, what) for role, what in _SHARED.items()) if n]
        if any(n not in r.notes for n in scaled):  # once, however often they are put in one unit
            r = dataclasses.replace(r, notes=(*r.notes, *(n for n in scaled if n not in r.notes)))
        out.append(r)
    return out


#: Recordings fitted together whose signal's sizes differ by this factor or more, and lie within
#: `_PREFIX_NEAR` of a power of 1000, read as one logged in another unit than it says (mV for V).
_SCALE_APART = 300.0
_PREFIX_NEAR = 3.0


def _scale_apart(first: Recording, other: Recording, role: str, what: str) -> str | None:
    """A note where `other`'s signal is near a power of 1000 larger or smaller than `first`'s, in one unit.

    A probe gave two recordings of one motor, the second's drive logged in mV with no unit said:
    0.5–5 beside 500–5000, read as one scale, and the diagnosis blamed a dead zone and an extrapolation.
    """
    size = [float(np.percentile(np.abs(np.asarray(getattr(r, role), float)), 95)) for r in (first, other)]
    if min(size) <= 0.0 or not all(np.isfinite(size)):
        return None
    ratio = size[1] / size[0]
    power = round(math.log10(ratio) / 3) * 3
    if abs(math.log10(ratio)) < math.log10(_SCALE_APART) or abs(math.log10(ratio) - power) > math.log10(
        _PREFIX_NEAR
    ):
        return None
    unit = first.metadata["units"][role]
    return (
        f"recording '{other.name}': {what} is {ratio:.3g}× the size of that in '{first.name}' (near 10^{power}, the "
        f"step between units), both read as {unit}: "
        f"if one was logged in another unit (mV for V, µm for mm), say so (--units {role}=..., a units row "
        "under the header, units= in Python); one model fits them on one scale"
    )
