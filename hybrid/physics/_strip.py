"""Geometry and materials of an IPMC strip (paper Table 1), in SI units.

The paper's Table 1 gives a Pt-electroded Nafion® 117 strip of length
L = 22 mm and width W = 5.5 mm. From it follow the electrode resistance at the
clamp, RE_clamp = ρ_E L / (W h_E), and the membrane resistance
R_M = ρ_M L / (W h_M) with ρ_M = 1/σ_M. The interface resistance at the clamp,
RI_clamp = ξρ ρ_E L / (W ξh h_E), needs the two unknown ratios ξρ (IMRR) and
ξh (IMTR); it therefore lives with the fitted parameters of
[`hybrid.RCNetwork`][], not here.
"""

from __future__ import annotations

import dataclasses
import math

from ..util._errors import InputError


@dataclasses.dataclass(frozen=True)
class Strip:
    """An IPMC strip: dimensions and material constants (Table 1), SI units.

    **Arguments:**

    - `length`: L, free length of the strip (m). Default 22 mm.
    - `width`: W (m). Default 5.5 mm.
    - `electrode_thickness`: h_E, thickness of each Pt electrode (m). Default 1 µm.
    - `electrode_resistivity`: ρ_E of platinum (Ω·m). Default 1.06e-7.
    - `membrane_thickness`: h_M of Nafion® 117 (m). Default 183 µm.
    - `membrane_conductivity`: σ_M (S/m). Default 10.26.
    """

    length: float = 22e-3
    width: float = 5.5e-3
    electrode_thickness: float = 1e-6
    electrode_resistivity: float = 1.06e-7
    membrane_thickness: float = 183e-6
    membrane_conductivity: float = 10.26

    def __post_init__(self):
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise InputError(
                    f"strip {field.name} must be a positive finite number in SI units, got {value!r}"
                )

    @property
    def electrode_area(self) -> float:
        """A_E = W h_E (m²)."""
        return self.width * self.electrode_thickness

    @property
    def membrane_area(self) -> float:
        """A_M = W h_M (m²)."""
        return self.width * self.membrane_thickness

    @property
    def RE_clamp(self) -> float:
        """Electrode resistance at the clamp, RE_clamp = ρ_E L / A_E (Ω)."""
        return self.electrode_resistivity * self.length / self.electrode_area

    @property
    def R_M(self) -> float:
        """Membrane resistance, R_M = ρ_M L / A_M with ρ_M = 1/σ_M (Ω)."""
        return self.length / (self.membrane_conductivity * self.membrane_area)

    def RI_clamp(self, xi_rho, xi_h):
        """Interface resistance at the clamp, ρ_I L / A_I with ρ_I = ξρ ρ_E, h_I = ξh h_E (Ω).

        Only the ratio ξρ/ξh enters: the two are not separately identifiable from
        voltage and displacement alone.
        """
        return (xi_rho / xi_h) * self.RE_clamp

    def to_dict(self) -> dict:
        """JSON-able description, SI units (m, Ω·m, S/m)."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> Strip:
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise InputError(f"unknown strip field(s) {sorted(unknown)}: valid fields are {sorted(known)}")
        return cls(**{k: float(v) for k, v in data.items()})
