"""Units written in a column's name, as loggers and spreadsheets write them: ``Time [ms]``,
``u (V)``, ``Displacement/µm`` (ISO 80000's quantity/unit), for
[`load_mapped`][hybrid.data._mapping.load_mapped].

The rule (conservative: a word in brackets that is not clearly a unit is part of the name):

* a name ending in ``[unit]`` or ``(unit)``, or written ``name/unit`` (``name/(unit)`` for a
  compound unit), with something before it, gives ``unit`` when `is_unit` accepts it;
* so does ``name_unit``, as scripts write it (``time_s``, ``drive_V``, ``pos_mm``), where the
  word after the last ``_`` is a unit of two characters or more, or one of `LONE_UNITS`
  (``v_in`` is no unit: the project's drive; ``temp_C``, ``phase_A`` are names);
* `is_unit` accepts an SI symbol with an optional SI prefix (``s``, ``ms``, ``µm``, ``mV``,
  ``kHz``, ``Ω``, ``°C``, ...), ``%``, ``°``, ``deg``, ``rad``, ``ppm``, ``dB``, ``a.u.``,
  ``counts``, ``px``, ``min``, ``h``, ``rpm``, and products and quotients of them with
  powers (``m/s^2``, ``N·m``, ``mm/s``); anything else (``(filtered)``, ``(cmd)``, ``(VDC)``,
  ``[samples]``) is not a unit;
* for the time column the unit must be a time unit (`TIME_UNITS`, also written ``sec``,
  ``msec``, ``μs``): it scales the column to seconds. A time column whose name ends in
  brackets holding anything else (``Time [samples]``, ``Time (V)``) is refused, unless its
  unit is given (``--units t=…``, a units row or the sidecar);
* for the drive and the output it is the signal's unit label unless ``--units``, a units row
  or the sidecar gives one; where both give one and they differ, the given one is kept and
  a note says so.
"""

from __future__ import annotations

import re

from ._recording_checks import TIME_UNITS

__all__ = ["LONE_UNITS", "header_unit", "is_unit", "prefix_factor", "speed_unit", "time_unit", "unit_kind"]

_PREFIX = r"(?:da|[yzafpnµμumcdhkMGTPE])"
_SYMBOL = r"(?:s|m|g|V|A|Ω|ohm|Ohm|Hz|N|Pa|W|J|C|F|H|T|K|S|Wb|L|l|mol|cd|lx|rad|sr|bar|eV)"
_SPECIAL = (
    r"(?:%|‰|°C|°F|°|deg|degC|ppm|dB|dBm|a\.u\.|au|arb\.\s?u\.|counts|cts|px|pixels?|rpm|min|h|psi|mmHg)"
)
_POWER = r"(?:\^-?\d+|[²³]|⁻¹|⁻²)?"
_TOKEN = rf"(?:{_SPECIAL}|{_PREFIX}?{_SYMBOL}){_POWER}"
_UNIT = re.compile(rf"{_TOKEN}(?:\s*[/·*.⋅]\s*{_TOKEN}|\s+{_TOKEN})*")
_BRACKETS = re.compile(r"^(?P<name>.*?\S)\s*(?:\[(?P<square>[^\[\]]*)\]|\((?P<round>[^()]*)\))\s*$")
_SLASH = re.compile(r"^(?P<name>[^/]*?\S)\s*/\s*(?P<unit>\S.*)$")
_UNDERSCORE = re.compile(r"^(?P<name>.*?[^\s_])_(?P<unit>[^_\s]+)$")
#: One-letter units read after an underscore (``drive_V``, ``time_s``); any other letter there is a name.
LONE_UNITS = frozenset({"V", "s", "m", "N", "W"})
#: A quantity per unit time: mm/s, rad/s, L/min, m s⁻¹, m·s^-1, rpm (not an acceleration, m/s²).
_RATE = re.compile(r"^(?:.+?(?:\s*/\s*(?:s|sec|ms|min|h)|\s*[·.* ]\s*(?:s\^-1|s⁻¹))|rpm|RPM|r/min)$")
#: A position: a length (m with an SI prefix, in, inch, ft) or an angle (rad, mrad, deg, degree(s), °,
#: rev(olution)(s), turn(s)), or pixels, as units rows and plug-ins spell them.
_LENGTH_OR_ANGLE = (
    rf"(?:{_PREFIX}?m|in|inch(?:es)?|ft|feet|m?rad|deg|degrees?|°|revs?|revolutions?|turns?|px|pixels?)"
)
_POSITION = re.compile(rf"^{_LENGTH_OR_ANGLE}$")
#: A speed: a position per unit time (m/s, mm/s, rad/s, deg/s, °/s, px/s), or revolutions per minute.
_SPEED = re.compile(
    rf"^(?:{_LENGTH_OR_ANGLE}\s*/\s*(?:s|sec|ms|min|h)|{_LENGTH_OR_ANGLE}\s*[·.* ]\s*(?:s\^-1|s⁻¹)|rpm|RPM|r/min)$"
)
#: A temperature: degrees Celsius or Fahrenheit, or kelvin (symbols or spelled out).
_TEMPERATURE = re.compile(
    r"^(?:°\s*[CF]|deg(?:rees?)?\s*[CF]|degC|degF|K|℃|℉|[Kk]elvin|[Cc]elsius|[Ff]ahrenheit)$"
)
#: Spellings of the time units, lower case, -> the key of `TIME_UNITS`.
_TIME_SPELLINGS = {
    "s": "s",
    "sec": "s",
    "secs": "s",
    "second": "s",
    "seconds": "s",
    "ms": "ms",
    "msec": "ms",
    "us": "us",
    "µs": "µs",
    "μs": "µs",
    "ns": "ns",
    "min": "min",
    "h": "h",
}


def header_unit(name: str) -> tuple[str, bool] | None:
    """The unit text a column's name ends with, and whether it is in brackets (else after a '/').

    ``"Time [ms]"`` -> ``("ms", True)``, ``"Displacement/µm"`` -> ``("µm", False)``,
    ``"pos_mm"`` -> ``("mm", False)``, ``"u"`` -> None. A bracketed or slashed text is returned
    whether or not it is a unit (`is_unit` says); a word after ``_`` only where it is one.
    """
    text = name.strip()
    match = _BRACKETS.match(text)
    if match:
        unit = match.group("square") if match.group("square") is not None else match.group("round")
        return unit.strip(), True
    match = _SLASH.match(text)
    if match:
        unit = match.group("unit").strip()
        if unit.startswith("(") and unit.endswith(")"):
            unit = unit[1:-1].strip()  # ISO 80000: v/(m/s)
        return unit, False
    match = _UNDERSCORE.match(text)
    if match:
        unit = match.group("unit")
        if (len(unit) >= 2 or unit in LONE_UNITS) and is_unit(unit):
            return unit, False
    return None


def is_unit(text: str) -> bool:
    """Whether `text` is clearly a unit (see the module's rule): ``mV``, ``µm``, ``m/s^2``, ``%``, ``a.u.``."""
    return bool(text) and len(text) <= 16 and _UNIT.fullmatch(text.strip()) is not None


#: The SI prefixes' powers of ten (µ written three ways, as files write it).
_PREFIX_POWER = {
    "y": -24, "z": -21, "a": -18, "f": -15, "p": -12, "n": -9, "µ": -6, "μ": -6, "u": -6, "m": -3,
    "c": -2, "d": -1, "": 0, "da": 1, "h": 2, "k": 3, "M": 6, "G": 9, "T": 12, "P": 15, "E": 18,
}  # fmt: skip
_PREFIXED = re.compile(rf"(?P<prefix>{_PREFIX})?(?P<symbol>{_SYMBOL})")


def prefix_factor(unit: str, to: str) -> float | None:
    """The factor that takes a value in `unit` to `to` where they differ only by an SI prefix, else None.

    ``prefix_factor("µm", "mm")`` is 1e-3, ``prefix_factor("mV", "V")`` 1e-3,
    ``prefix_factor("mm", "mm")`` 1.0; ``prefix_factor("counts", "mm")`` and
    ``prefix_factor("mm", "V")`` are None (no conversion a prefix can make).
    """
    if unit.strip() == to.strip():
        return 1.0
    a, b = _PREFIXED.fullmatch(unit.strip()), _PREFIXED.fullmatch(to.strip())
    if a is None or b is None or a["symbol"] != b["symbol"]:
        return None
    return float(10.0 ** (_PREFIX_POWER[a["prefix"] or ""] - _PREFIX_POWER[b["prefix"] or ""]))


def time_unit(text: str) -> str | None:
    """The `TIME_UNITS` key `text` spells (``sec`` -> ``s``, ``μs`` -> ``µs``), or None."""
    text = text.strip()
    key = _TIME_SPELLINGS.get(text if text in ("ms", "ns") else text.lower())
    return key if key in TIME_UNITS else None


def speed_unit(unit: str) -> bool:
    """Whether `unit` is a speed: a length or an angle per unit time (``m/s``, ``rad/s``, ``°/s``), or ``rpm``;
    not a flow (``L/min``) or another rate."""
    return bool(_SPEED.fullmatch((unit or "").strip()))


def unit_kind(unit: str) -> str | None:
    """``"rate"`` for a quantity per unit time (``mm/s``, ``rad/s``, ``L/min``, ``rpm``: a speed or a
    flow), ``"position"`` for a length or an angle (``µm``, ``mm``, ``rad``, ``°``, ``px``),
    ``"temperature"`` (``°C``, ``K``, ``degF``), else None.

    What an effect's reading says of a force of the signal: a spring where it is a
    position, a damping where it is a speed, a heat loss where it is a temperature
    (`AbstractEffect.reading`).
    """
    text = (unit or "").strip()
    if _RATE.fullmatch(text):
        return "rate"
    if _POSITION.fullmatch(text):
        return "position"
    if _TEMPERATURE.fullmatch(text):
        return "temperature"
    return None
