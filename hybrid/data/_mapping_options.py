"""The options of [`load_mapped`][hybrid.data._mapping.load_mapped], parsed and checked
before any file is read: the mapping (``input``, ``output``, ``time`` and the
``columns`` string, whose grammar `hybrid.data._mapping` gives; ``units`` may be
a string in the same grammar, ``"v_in=V,w=mm"``), the ``sample_range``
(``"start:stop"``), the ``rate`` and the ``units``. Each problem raises one
[`InputError`][hybrid.InputError] saying how to fix it.
"""

from __future__ import annotations

import math
import numbers
import pathlib
import re
from collections.abc import Mapping
from typing import Any

from ..util._errors import InputError
from ._recording_checks import TIME_UNITS
from ._table import OPTION

__all__ = ["ROLES", "mapping_roles", "parse_columns", "parse_sample_range", "parse_units"]

#: Role names accepted in ``columns`` and ``units`` -> the channel they fill.
ROLES: dict[str, str] = {"input": "v_in", "v_in": "v_in", "output": "w", "w": "w", "time": "t", "t": "t"}

_EXAMPLE = "e.g. 'input=uEst,output=yEst'"
_RANGE = re.compile(r"^\s*([+-]?\d+)?\s*:\s*([+-]?\d+)?\s*$")


def parse_columns(text: Any) -> dict[str, str]:
    """``"input=uEst,output=yEst"`` (grammar in `hybrid.data._mapping`) or ``{"input": "uEst", "output":
    "yEst"}`` -> ``{"v_in": "uEst", "w": "yEst"}``."""
    if isinstance(text, Mapping):  # from Python: the same roles, each name as it is (no quotes to strip)
        return _roles(
            [(str(role), _column_name(name)) for role, name in text.items()],
            text,
            "columns mapping",
            "column",
            "e.g. {'input': 'uEst', 'output': 'yEst'}",
        )
    return _pairs(text, "columns mapping", "column", _EXAMPLE)


def parse_units(text: Any) -> dict[str, str]:
    """``"v_in=V,w=mm"`` -> ``{"v_in": "V", "w": "mm"}``: the columns grammar with units for names."""
    return _pairs(text, "units", "unit", "e.g. 'input=V,output=V'")


def _column_name(name: Any) -> Any:
    """A dict's column: a name, or a column's number (an int, as ``input=0`` in the string)."""
    integral = isinstance(name, numbers.Integral) and not isinstance(name, bool)
    return str(int(name)) if integral else name


def _pairs(text: Any, what: str, kind: str, example: str) -> dict[str, str]:
    if not isinstance(text, str) or not text.strip():
        problem = "is empty" if isinstance(text, str) else "is not a string"
        also = " (or a dict of them, {'input': 'uEst', 'output': 'yEst'})" if kind == "column" else ""
        raise InputError(f"the {what} {text!r} {problem}: give role={kind} pairs{also}, {example}")
    pairs = []
    for entry in _split(text, what):
        role, equals, name = entry.partition("=")
        if not equals:
            raise InputError(
                f"the {what} {text!r} has entry {entry.strip()!r} without '=': "
                f"write role={kind} pairs separated by commas, {example}"
            )
        name = name.strip()
        if len(name) > 1 and name[0] == name[-1] == '"':
            name = name[1:-1]
        elif "=" in name:
            raise InputError(
                f"the {what} {text!r} has entry {entry.strip()!r} with two '=': separate the "
                f"pairs with commas, {example}"
            )
        pairs.append((role, name))
    return _roles(pairs, text, what, kind, example)


def _roles(pairs, text: Any, what: str, kind: str, example: str) -> dict[str, str]:
    """(role, name) pairs -> names by channel, each role known, given once and named."""
    if not pairs:
        raise InputError(f"the {what} {text!r} is empty: give role={kind} pairs, {example}")
    roles: dict[str, str] = {}
    for role, name in pairs:
        key = role.strip().lower()
        if key not in ROLES:
            raise InputError(
                f"the {what} {text!r} names the role {role.strip()!r}: the roles are "
                f"input (or v_in), output (or w) and time (or t), {example}"
            )
        if not isinstance(name, str):
            raise InputError(
                f"the {what} {text!r} gives {key} the {kind} {name!r}: give the {kind}'s name as a string"
            )
        if not name.strip():
            raise InputError(f"the {what} {text!r} gives {key} an empty {kind}: give the {kind}")
        channel = ROLES[key]
        if channel in roles:
            raise InputError(
                f"the {what} {text!r} gives the {OPTION[channel]} twice ({roles[channel]!r} "
                f"and {name!r}): give each role once"
            )
        roles[channel] = name
    return roles


def _split(text: str, what: str) -> list[str]:
    """``text`` cut at commas outside double quotes."""
    entries: list[str] = []
    current: list[str] = []
    quoted = False
    for char in text:
        if char == '"':
            quoted = not quoted
        if char == "," and not quoted:
            entries.append("".join(current))
            current = []
        else:
            current.append(char)
    if quoted:
        raise InputError(f"the {what} {text!r} has an unclosed '\"': close the quoted name")
    return [*entries, "".join(current)]


def mapping_roles(
    *,
    input: Any = None,
    output: Any = None,
    time: Any = None,
    columns: Any = None,
    require_w: bool = True,
) -> dict[str, str]:
    """The checked mapping, channel (``t``, ``v_in``, ``w``) -> the file's name, in that order."""
    roles = parse_columns(columns) if columns is not None else {}
    for channel, value in (("v_in", input), ("w", output), ("t", time)):
        if value is None:
            continue
        value = _column_name(value)
        if not isinstance(value, str) or not value.strip():
            raise InputError(
                f"the {OPTION[channel]} column {value!r} is not a name: give the column's name as a string "
                "(or its number, from 0)"
            )
        if channel in roles:
            raise InputError(
                f"the {OPTION[channel]} column is given twice, as {OPTION[channel]}={value!r} and in "
                f"columns ({roles[channel]!r}): give it once"
            )
        roles[channel] = value.strip()
    for channel, needed in (("v_in", True), ("w", require_w)):
        if needed and channel not in roles:
            raise InputError(
                f"no {OPTION[channel]} column is named: give the {OPTION[channel]}'s column "
                f"(--{OPTION[channel]} COLUMN, or in --columns {_EXAMPLE})"
            )
    if roles.get("v_in") == roles.get("w"):
        raise InputError(
            f"the input and the output are the same column '{roles['v_in']}': map the drive to "
            "input and the measured output to output"
        )
    taken: dict[str, str] = {}
    for channel, name in roles.items():
        if name in taken:
            raise InputError(
                f"column '{name}' is mapped twice, as the {OPTION[taken[name]]} and the "
                f"{OPTION[channel]}: map each column once"
            )
        taken[name] = channel
    return {c: roles[c] for c in ("t", "v_in", "w") if c in roles}


def parse_sample_range(value: Any) -> tuple[int | None, int | None]:
    """``"100:200"`` -> ``(100, 200)``, ``"40650:"`` -> ``(40650, None)``; None -> ``(None, None)``."""
    if value is None:
        return None, None

    def whole(v: Any) -> bool:
        return v is None or (isinstance(v, numbers.Integral) and not isinstance(v, bool))

    bounds: tuple[int | None, ...]
    if isinstance(value, slice) and value.step in (None, 1) and whole(value.start) and whole(value.stop):
        bounds = (value.start, value.stop)
    else:
        match = _RANGE.match(value) if isinstance(value, str) else None
        if not match:
            raise InputError(
                f"sample range {value!r} is not start:stop: give sample numbers from 0 like "
                "'40650:', ':40000' or '100:200'"
            )
        bounds = tuple(None if g is None else int(g) for g in match.groups())
    if any(b is not None and b < 0 for b in bounds):
        raise InputError(
            f"sample range {value!r} has a negative bound: count samples from 0 at the start of "
            "the file (negative indices are not accepted)"
        )
    start, stop = (None if b is None else int(b) for b in bounds)
    return start, stop


def range_bounds(
    path: str | pathlib.Path, value: Any, bounds: tuple[int | None, int | None], n: int
) -> tuple[int, int]:
    """``(start, stop)`` of a parsed sample range in a file of ``n`` samples, checked."""
    start = 0 if bounds[0] is None else bounds[0]
    stop = n if bounds[1] is None else bounds[1]
    if start >= n or stop > n:
        raise InputError(
            f"sample range {value!r} is out of range: recording '{path}' has {n} samples "
            f"(0 to {n - 1}): give start < {n} and stop <= {n}"
        )
    if stop - start < 2:
        raise InputError(
            f"sample range {value!r} holds {max(stop - start, 0)} sample(s): a recording needs at "
            "least 2; give start < stop"
        )
    return start, stop


def rate_argument(rate: Any) -> float | None:
    """The ``rate`` argument as a positive finite number of Hz (a number or its text), or None."""
    if rate is None:
        return None
    try:
        value = float(rate) if not isinstance(rate, bool) else math.nan
    except (TypeError, ValueError):
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise InputError(f"sampling rate {rate!r} is not a positive number of Hz: give e.g. --rate 610.35")
    return value


def units_argument(units: Any, has_time: bool) -> dict[str, str]:
    """The ``units`` argument (a dict or a ``"v_in=V,w=mm"`` string) by channel, checked."""
    if units is None:
        return {}
    if isinstance(units, str):
        units = parse_units(units)
    if not isinstance(units, Mapping):
        raise InputError(
            f"units {units!r} is not a dict: give e.g. {{'v_in': 'V', 'w': 'V'}} or 'v_in=V,w=V'"
        )
    out: dict[str, str] = {}
    for key, value in units.items():
        channel = ROLES.get(str(key).lower())
        if channel is None:
            raise InputError(f"units names {key!r}: give units for t (time), v_in (input) or w (output)")
        if channel in out:
            raise InputError(f"units gives the unit of {OPTION[channel]} twice: give it once")
        if not isinstance(value, str) or not value.strip():
            raise InputError(f"units gives {key!r} the unit {value!r}: give a non-empty label such as 'V'")
        out[channel] = value.strip()
    if "t" in out and out["t"] not in TIME_UNITS:
        raise InputError(f"units gives the time the unit {out['t']!r}: use one of {', '.join(TIME_UNITS)}")
    if "t" in out and not has_time and out["t"] != "s":
        raise InputError(
            f"units gives the time the unit {out['t']!r} but no time column is mapped: t is built "
            "from the rate, in seconds; map the time column (--time) or drop the time unit"
        )
    return out
