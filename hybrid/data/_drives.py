"""Drive voltages for identification experiments, by name: [`DRIVES`][hybrid.DRIVES] and
[`make_drive`][hybrid.make_drive].

The paper trains and tests on four input voltages (Section IV.B, Table 2):
PRBS, sine, chirp and pulse train (`hybrid.data._paper_drives`); a
staircase and triangle sweeps (`hybrid.data._hysteresis_drives`) probe
hysteresis and saturation. Each generator returns a
[`Drive`][hybrid.Drive] sampled at ``rate`` Hz (30 Hz, the camera's
frame rate, by default) for ``duration`` s, with ``n = round(duration * rate)``
samples at ``t = arange(n) / rate``. Generators are deterministic: the only
randomness (PRBS, randomly modulated sine and chirp) comes from
``numpy.random.default_rng(seed)``.

Bad parameters raise [`InputError`][hybrid.InputError].
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import Any

import numpy as np

from ..util._errors import InputError
from ._drive import DEFAULT_RATE, Drive
from ._hysteresis_drives import staircase, triangle
from ._paper_drives import chirp, prbs, pulse, sine

__all__ = ["DRIVES", "load_drive", "make_drive"]


_GENERATORS: dict[str, Callable[..., Drive]] = {
    "prbs": prbs,
    "sine": sine,
    "chirp": chirp,
    "pulse": pulse,
    "staircase": staircase,
    "triangle": triangle,
}

#: Names accepted by [`make_drive`][hybrid.make_drive]: the paper's four (Table 2 order), then
#: two more for identifying hysteresis and saturation.
DRIVES: tuple[str, ...] = tuple(_GENERATORS)


def make_drive(name: str, duration: float, rate: float = DEFAULT_RATE, seed: int = 0, **params: Any) -> Drive:
    """Build a drive by name.

    Arguments:
        name: one of [`DRIVES`][hybrid.DRIVES] (``"prbs"``, ``"sine"``, ``"chirp"``,
            ``"pulse"``, ``"staircase"``, ``"triangle"``).
        duration: length, s.
        rate: sampling rate, Hz.
        seed: seed for the random drives (PRBS, randomly modulated sine and
            chirp); the others ignore it.
        **params: the generator's other parameters (see each generator).

    Returns:
        The [`Drive`][hybrid.Drive].
    """
    if name not in _GENERATORS:
        raise InputError(f"drive {name!r} is unknown: use one of {', '.join(DRIVES)}")
    generator = _GENERATORS[name]
    signature = inspect.signature(generator).parameters
    accepted = [p for p in signature if p not in ("duration", "rate", "seed")]
    unknown = [p for p in params if p not in accepted]
    if unknown:
        raise InputError(f"{name} drive has no parameter(s) {', '.join(unknown)}: use {', '.join(accepted)}")
    if "seed" in signature:
        params["seed"] = seed
    return generator(duration, rate, **params)


#: A drive file's units of v_in and their factor to volts.
VOLTS = {"V": 1.0, "mV": 1e-3, "µV": 1e-6, "uV": 1e-6, "kV": 1e3}


def load_drive(path) -> Drive:
    """A drive read from a file: a CSV with columns t and v_in (as `hybrid design` writes), or .npz/.mat.

    The same reader and checks as a recording's (uniform time base, finite
    values); no w is needed. The drive's name is ``"file"`` and its params
    carry the file, the rate and the duration.
    """
    from ._recording import Recording

    recording = Recording.load(path, require_w=False)
    units = recording.metadata.get("units")
    unit = str(units.get("v_in", "V")) if isinstance(units, dict) else "V"
    if unit not in VOLTS:  # a drive is played in volts: a units row of mV would play 1000x too large
        raise InputError(
            f"'{path}': its drive is in {unit!r} (its units row or sidecar), but a drive is played in volts: "
            f"write it in one of {', '.join(VOLTS)}"
        )
    # The reader accepted the time column as uniform within its tolerance (t written to 6 decimals steps
    # by 0.033333 and 0.033334 at 30 Hz): the rate over the whole record, and an exactly uniform grid.
    n = len(recording)
    rate = float((n - 1) / (recording.t[-1] - recording.t[0])) if n > 1 else float(recording.rate)
    params = {"file": str(path), "rate": rate, "duration": n / rate}
    return Drive(np.arange(n) / rate, recording.v_in * VOLTS[unit], "file", params)
