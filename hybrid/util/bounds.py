"""Bounds on the command line's size arguments: a typo must not run out of memory.

`hybrid rc --stages 100000` or `hybrid simulate --rate 1e9` used to end in a
traceback (out of memory) after a long wait. Every size argument is parsed by
[`integer`][] or [`number`][], which refuse anything not finite or outside its
stated range with one line naming the bound, and [`check_samples`][] bounds
duration × rate. The limits are far beyond what the paper's experiments need
(10 minutes at 30 Hz, N = 45, 11 × 10 D-MLP) and far below what exhausts a
workstation.
"""

from __future__ import annotations

import argparse
import math
import re

from ._errors import InputError

#: Most samples one command may make (duration × rate): 10^7 float64 samples are 80 MB per channel.
MAX_SAMPLES = 10_000_000

STAGES = (1, 1000)  # N of the RC network (N + 1 sections; the paper's 45)
RATE = (0.1, 100_000.0)  # Hz
DURATION = (0.0, 1e7)  # s, exclusive at 0 (the sample count bounds it far sooner)
STARTS = (1, 256)
SCREEN = (0, 100_000)  # design points screened for a fit's starts (0: none)
MAX_STEPS = (1, 1_000_000)
WINDOW = (1, 100_000)  # samples in the D-MLP's window (also ≤ the recording's length)
DEPTH = (0, 50)  # hidden layers of the D-MLP (0: a linear map of the window)
WIDTH = (1, 1000)  # neurons per hidden layer
SOBOL = (0, 100_000)  # Sobol base samples (0: skip)
BLOCKS = (1, 10_000)
RACING = (0, 10_000)  # effects that race on after the race's first round (0: every effect)
SETTLE_MAX = 10_000_000  # samples of held drive before a record (--settle)


class Parser(argparse.ArgumentParser):
    """The command lines' parser: an error is one line (`InputError`, exit 2), and a value may be negative.

    argparse prints its usage before an error, and takes a value that starts with "-" for an option
    unless it is a plain negative number (-5, -0.5): ``hybrid design --bounds -5:0`` and ``rig track
    --clamp -5,120`` ended in "argument …: expected one argument". Any token that starts with a
    minus and a digit is a value here: no option of hybrid's or rig's is named so.
    """

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = re.compile(r"^-\.?\d")

    def error(self, message):
        raise InputError(f"{message} (see `{self.prog} --help`)")


def integer(low: int | None, high: int):
    """An argparse `type`: an integer in [low, high], else one line naming the bound.

    `low` None leaves the lower bound to a check further on (with its own message).
    """
    span = f"from {low} to {high}" if low is not None else f"at most {high}"

    def parse(text: str) -> int:
        try:
            value = int(text.strip())
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number {span}, got {text!r}") from None
        if value > high or (low is not None and value < low):
            raise argparse.ArgumentTypeError(f"must be {span}, got {value}")
        return value

    parse.__name__ = "integer"
    return parse


def number(low: float, high: float, *, include_low: bool = True, unit: str = ""):
    """An argparse `type`: a finite number in [low, high] ((low, high] without `include_low`)."""
    unit = f" {unit}" if unit else ""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        above = value >= low if include_low else value > low
        if not (math.isfinite(value) and above and value <= high):
            side = "at least" if include_low else "more than"
            raise argparse.ArgumentTypeError(
                f"must be finite, {side} {low:g}{unit} and at most {high:g}{unit}, got {text}"
            )
        return value

    parse.__name__ = "number"
    return parse


def check_samples(
    duration: float, rate: float, what: str = "--duration × --rate", limit: int = MAX_SAMPLES
) -> int:
    """The sample count `duration` × `rate`, refused above `limit`."""
    samples = duration * rate
    if not math.isfinite(samples) or samples > limit:
        raise InputError(
            f"{what} is {samples:.3g} samples, more than the limit of {limit:.0e}: "
            "shorten the duration or lower the rate"
        )
    return int(round(samples))
