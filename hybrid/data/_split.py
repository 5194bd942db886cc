"""Cutting a recording into the paper's train / test / validation parts.

`split_recording` (behind `Recording.split
<hybrid.data._recording.Recording.split>`) cuts a recording into contiguous
parts in time order, 30 %, 50 % and 20 % of the samples by default (Section
IV.B), and returns them as a [`Split`][hybrid.Split].
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from ..util._errors import InputError

if TYPE_CHECKING:
    from ._recording import Recording

__all__ = ["SPLIT_PARTS", "Split", "split_recording"]

#: Names of the parts of a [`Split`][hybrid.Split].
SPLIT_PARTS: tuple[str, ...] = ("train", "test", "validation")


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
            raise InputError(f"split has no part {part!r}: use one of {', '.join(SPLIT_PARTS)}")
        return getattr(self, part)

    def items(self) -> list[tuple[str, Recording]]:
        """The parts as ``(name, recording)`` pairs, in time order."""
        ordered = sorted(self.slices, key=lambda p: self.slices[p].start)
        return [(p, getattr(self, p)) for p in ordered]


def _check_fractions(name: str, fractions: Sequence[float], order: tuple[str, ...]) -> tuple[float, ...]:
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
            f"split fractions {list(values)} are not all positive: give every part a positive share"
        )
    if abs(sum(values) - 1.0) > 1e-9:
        raise InputError(
            f"split fractions {list(values)} sum to {sum(values):.6g}, not 1: scale them so they sum to 1"
        )
    return values


def split_recording(recording: Recording, fractions: Sequence[float], order: Sequence[str]) -> Split:
    """Cut ``recording`` into contiguous parts; see `Recording.split`.

    Arguments:
        recording: the recording to cut.
        fractions: positive shares of the samples, summing to 1, one per part.
        order: the parts in time order, a permutation of `SPLIT_PARTS`.

    Returns:
        A [`Split`][hybrid.Split]; each part's metadata gains ``"segment"`` and ``"split"``.
    """
    name, n = recording.name, recording.n
    order = tuple(order)
    fractions = _check_fractions(name, fractions, order)
    bounds = [0, *(round(f * n) for f in np.cumsum(fractions)[:-1]), n]
    slices = {part: slice(bounds[i], bounds[i + 1]) for i, part in enumerate(order)}
    short = {p: s.stop - s.start for p, s in slices.items() if s.stop - s.start < 2}
    if short:
        listed = ", ".join(f"{p} {k}" for p, k in short.items())
        raise InputError(
            f"recording '{name}' with {n} samples is too short to "
            f"split by {list(fractions)} (samples: {listed}): every part needs "
            "at least 2 samples, so record longer or change the fractions"
        )
    parts = {p: _part(recording, p, s) for p, s in slices.items()}
    return Split(**parts, slices=slices)


def _part(recording: Recording, part: str, index: slice) -> Recording:
    segment = recording.segment(index)
    metadata = dict(segment.metadata)
    metadata["split"] = part
    return dataclasses.replace(segment, metadata=metadata)
