"""Volts at the strip <-> DAC codes, through the shift-and-amplify stage.

The MCP4725 outputs ``V_dac = code / (2^bits - 1) * V_ref`` (0..5 V); the
analog stage shifts and amplifies it onto the strip::

    V_strip = clip(gain * V_dac + offset, rail_low, rail_high)

The defaults (gain 1.2, offset -3 V, rails +-3 V, V_ref 5 V, 12 bits) map
codes 0..4095 onto -3..+3 V, the rig of ``hybrid.ipmc._virtual_ipmc`` (its
``_dac``): ``code = round((v / 3 + 1) * 4095 / 2)``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib

import numpy as np

from ._errors import RigError

__all__ = ["Calibration", "fit_calibration"]


@dataclasses.dataclass(frozen=True)
class Calibration:
    """The amplifier mapping.

    Arguments:
        gain: strip volts per DAC-output volt (V/V), non-zero.
        offset: strip voltage at DAC output 0 V (V).
        v_ref: DAC full-scale output (V), > 0 (the MCP4725's supply).
        bits: DAC resolution (12 for the MCP4725).
        rail_low, rail_high: the amplifier's output limits (V); commands
            beyond them are clipped.
    """

    gain: float = 1.2
    offset: float = -3.0
    v_ref: float = 5.0
    bits: int = 12
    rail_low: float = -3.0
    rail_high: float = 3.0

    def __post_init__(self):
        for name in ("gain", "offset", "v_ref", "rail_low", "rail_high"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                raise RigError(f"calibration {name}={value!r} is not a finite number")
        if self.gain == 0 or self.v_ref <= 0 or self.rail_low >= self.rail_high:
            raise RigError(
                f"calibration gain={self.gain:g}, v_ref={self.v_ref:g} V, rails "
                f"[{self.rail_low:g}, {self.rail_high:g}] V: need gain != 0, v_ref > 0, low < high rail"
            )
        if not isinstance(self.bits, int) or not 1 <= self.bits <= 16:
            raise RigError(f"calibration bits={self.bits!r}: give an integer 1..16")

    @property
    def top(self) -> int:
        """The largest code, ``2^bits - 1``."""
        return 2**self.bits - 1

    def volts(self, codes) -> np.ndarray:
        """Strip voltage (V) for DAC codes."""
        v_dac = np.asarray(codes, dtype=float) / self.top * self.v_ref
        return np.clip(self.gain * v_dac + self.offset, self.rail_low, self.rail_high)

    def codes(self, volts) -> np.ndarray:
        """The DAC codes (int) nearest to strip voltages ``volts`` (V), clipped at the rails."""
        v = np.clip(np.asarray(volts, dtype=float), self.rail_low, self.rail_high)
        code = np.round((v - self.offset) / self.gain / self.v_ref * self.top)
        return np.clip(code, 0, self.top).astype(np.int64)

    def clipped(self, volts) -> np.ndarray:
        """Which commanded voltages the rig cannot reach (beyond rails or code range)."""
        v = np.asarray(volts, dtype=float)
        reach = self.volts([0, self.top])
        low, high = max(self.rail_low, reach.min()), min(self.rail_high, reach.max())
        step = abs(self.gain) * self.v_ref / self.top
        return (v < low - step / 2) | (v > high + step / 2)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    def save(self, path) -> pathlib.Path:
        path = pathlib.Path(path)
        path.write_text(json.dumps(self.to_dict(), indent=2) + "\n")
        return path

    @classmethod
    def load(cls, path) -> Calibration:
        """Read a calibration written by `save` or ``rig calibrate``."""
        path = pathlib.Path(path)
        try:
            data = json.loads(path.read_text())
        except OSError as error:
            raise RigError(f"calibration file '{path}' cannot be read ({error.strerror or error})") from None
        except ValueError as error:
            raise RigError(f"calibration file '{path}' is not valid JSON ({error})") from None
        if not isinstance(data, dict):
            raise RigError(f"calibration file '{path}' must hold a JSON object")
        fields = {f.name for f in dataclasses.fields(cls)}
        unknown = set(data) - fields - {"fit"}
        if unknown:
            raise RigError(
                f"calibration file '{path}' has unknown field(s) {sorted(unknown)}: "
                f"known are {sorted(fields)}"
            )
        return cls(**{k: v for k, v in data.items() if k in fields})


def fit_calibration(
    codes, volts, v_ref: float = 5.0, bits: int = 12, tolerance_v: float = 0.01
) -> tuple[Calibration, dict]:
    """Fit gain, offset and rails to multimeter readings ``volts`` (V) at DAC ``codes``.

    Readings at a rail fall short of the straight line through the others. The
    fit takes the fewest end points off (lowest or highest codes) such that the
    rest lie on a straight line within ``tolerance_v`` (the meter's accuracy)
    and the removed ones fall short of it; the removed readings estimate the
    rails. At least three points must remain on the line.

    Returns:
        ``(calibration, report)``; the report holds the residuals (V) and which
        points were taken as clipped.
    """
    codes = np.asarray(codes, dtype=float)
    volts = np.asarray(volts, dtype=float)
    if codes.shape != volts.shape or codes.ndim != 1 or len(codes) < 3:
        raise RigError(
            f"calibration needs one reading per code and at least 3 of them, got "
            f"{codes.size} codes and {volts.size} readings"
        )
    if not np.all(np.isfinite(volts)):
        raise RigError("calibration readings must be finite numbers of volts")
    order = np.argsort(codes)
    codes, volts = codes[order], volts[order]
    top = 2**bits - 1
    v_dac = codes / top * v_ref
    n = len(codes)
    best = None
    for trimmed in range(0, n - 2):
        for lo in range(0, trimmed + 1):
            hi = n - (trimmed - lo)
            gain, offset = np.polyfit(v_dac[lo:hi], volts[lo:hi], 1)
            line = gain * v_dac + offset
            if np.max(np.abs(volts[lo:hi] - line[lo:hi])) > tolerance_v:
                continue
            short = np.abs(volts) < np.abs(line) - tolerance_v  # a clipped reading falls short
            if np.all(short[:lo]) and np.all(short[hi:]):
                best = (lo, hi, gain, offset)
                break
        if best:
            break
    if best is None:
        raise RigError(
            f"calibration readings are not a straight line (within {tolerance_v:g} V) with "
            "clipped ends: check the readings and the amplifier"
        )
    lo, hi, gain, offset = best
    if gain == 0:
        raise RigError("calibration readings do not change with the code: is the amplifier powered?")
    ends = gain * np.array([0.0, v_ref]) + offset
    low_clip = volts[:lo] if gain > 0 else volts[hi:]
    high_clip = volts[hi:] if gain > 0 else volts[:lo]
    rail_low = float(low_clip.mean()) if low_clip.size else float(ends.min())
    rail_high = float(high_clip.mean()) if high_clip.size else float(ends.max())
    calibration = Calibration(
        gain=float(gain), offset=float(offset), v_ref=v_ref, bits=bits, rail_low=rail_low, rail_high=rail_high
    )
    residuals = volts - calibration.volts(codes)
    report = {
        "codes": codes.astype(int).tolist(),
        "volts": volts.tolist(),
        "residuals_v": residuals.tolist(),
        "clipped": [bool(i < lo or i >= hi) for i in range(n)],
        "rms_residual_v": float(np.sqrt(np.mean(residuals**2))),
    }
    return calibration, report
