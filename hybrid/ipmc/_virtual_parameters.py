"""The virtual IPMC's parameters: every constant of the strip, its actuation and its camera, validated.

The equations they enter are in the docstring of `hybrid.ipmc._virtual_ipmc`
(the signal chain). Defaults::

    L = 22 mm, W = 5.5 mm, h_E = 1 µm, ρ_E = 1.06e-7 Ω·m,
    h_M = 183 µm, σ_M = 10.26 S/m                         Table 1
    ξρ/ξh = 20, α_E = 0.5, α_I = 0.6, α_C = 0.5            Eqs 4–9
    C_clamp = 20 mF, R_s = 0.5 Ω, N + 1 = 46 compartments
    τ_b = 6 s, β = 0.25                                   back-diffusion
    gain = 2 mm/V (static), compression = 0.15 at 3 V     electromechanics
    f_n = 12 Hz, ζ = 0.6                                  first mode
    12-bit DAC, 0..5 V → ±3 V                             actuation
    camera = drive rate (30 fps), T_exp = 1/60 s, oversample = 16
    noise s = 0.02 mm, pixel rounding off
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

from ..util._errors import InputError

__all__ = ["VirtualIPMCParameters"]


def _check_real(name, value, low=None, high=None, low_open=False, high_open=False):
    ok = isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)
    if ok and low is not None:
        ok = value > low if low_open else value >= low
    if ok and high is not None:
        ok = value < high if high_open else value <= high
    if not ok:
        lo = "" if low is None else f"{'>' if low_open else '≥'} {low}"
        hi = "" if high is None else f"{'<' if high_open else '≤'} {high}"
        rng = " and ".join(s for s in (lo, hi) if s)
        raise InputError(f"{name} = {value!r} is invalid; give a finite number {rng}.")


def _check_int(name, value, low, high=None):
    ok = isinstance(value, numbers.Integral) and not isinstance(value, bool) and value >= low
    if ok and high is not None:
        ok = value <= high
    if not ok:
        bound = f"≥ {low}" + ("" if high is None else f" and ≤ {high}")
        raise InputError(f"{name} = {value!r} is invalid; give an integer {bound}.")


@dataclass(frozen=True)
class VirtualIPMCParameters:
    """Every parameter of the virtual IPMC strip (`hybrid.ipmc._virtual_ipmc`'s docstring: the equations).

    **Arguments:**

    Strip, Table 1 of the paper:

    - `length_m`, `width_m`: L = 22 mm, W = 5.5 mm.
    - `electrode_thickness_m`: h_E = 1 µm.
    - `electrode_resistivity_ohm_m`: ρ_E = 1.06e-7 Ω·m (Pt).
    - `membrane_thickness_m`: h_M = 183 µm (Nafion 117).
    - `membrane_conductivity_s_per_m`: σ_M = 10.26 S/m.
    - `interface_ratio`: ξρ/ξh (IMRR/IMTR), RI_clamp = (ξρ/ξh) RE_clamp; > 0.

    RC line (Eqs 4–9, whole-strip values split over the compartments):

    - `alpha_e`, `alpha_i`, `alpha_c`: attenuation coefficients α_E, α_I, α_C
      (clamp value / tip value), in (0, 1].
    - `clamp_capacitance_f`: C_clamp, double-layer capacitance of the whole
      strip with clamp-end properties (F).
    - `source_resistance_ohm`: R_s, amplifier output + clamp contact resistance
      in series with the line (Ω, ≥ 0).
    - `n_compartments`: N + 1, the number of compartments k = 0..N (≥ 1).

    Slow charge dynamics:

    - `relaxation_time_s`: τ_b, back-diffusion time constant (s).
    - `relaxation_fraction`: β ∈ [0, 1), fraction of the bending charge lost
      under a held voltage.

    Electromechanics and mechanics:

    - `gain_mm_per_v`: small-signal static (DC, relaxed) tip displacement per
      volt (mm/V, > 0).
    - `compression`: static shortfall of the tip displacement at ±full_scale_v
      relative to the small-signal slope, in [0, 0.9]; 0 is linear.
    - `mode_frequency_hz`, `damping_ratio`: the first bending mode (Hz, > 0).

    Actuation:

    - `dac_bits`: DAC resolution (12: codes 0..4095).
    - `dac_reference_v`: DAC output range 0..V_ref (V); the amplifier maps it
      onto ±full_scale_v, so it only documents the rig.
    - `full_scale_v`: V_fs, amplifier rails (V).

    Camera and noise:

    - `camera_fps`: frame rate (Hz); None = the drive's sample rate (frames at
      the drive samples).
    - `exposure_s`: exposure of each frame (s), 0 ≤ T_exp ≤ frame period;
      0 samples instantaneously.
    - `oversample`: internal simulation steps per drive interval (≥ 1).
    - `noise_std_mm`: std of the Gaussian measurement noise (mm, ≥ 0).
    - `pixel_mm`: camera pixel scale the measurement is rounded to (mm), or
      None for no rounding.
    """

    length_m: float = 22e-3
    width_m: float = 5.5e-3
    electrode_thickness_m: float = 1e-6
    electrode_resistivity_ohm_m: float = 1.06e-7
    membrane_thickness_m: float = 183e-6
    membrane_conductivity_s_per_m: float = 10.26
    interface_ratio: float = 20.0
    alpha_e: float = 0.5
    alpha_i: float = 0.6
    alpha_c: float = 0.5
    clamp_capacitance_f: float = 20e-3
    source_resistance_ohm: float = 0.5
    n_compartments: int = 46
    relaxation_time_s: float = 6.0
    relaxation_fraction: float = 0.25
    gain_mm_per_v: float = 2.0
    compression: float = 0.15
    mode_frequency_hz: float = 12.0
    damping_ratio: float = 0.6
    dac_bits: int = 12
    dac_reference_v: float = 5.0
    full_scale_v: float = 3.0
    camera_fps: float | None = None
    exposure_s: float = 1.0 / 60.0
    oversample: int = 16
    noise_std_mm: float = 0.02
    pixel_mm: float | None = None

    def __post_init__(self):
        positive = (
            "length_m",
            "width_m",
            "electrode_thickness_m",
            "electrode_resistivity_ohm_m",
            "membrane_thickness_m",
            "membrane_conductivity_s_per_m",
            "interface_ratio",
            "clamp_capacitance_f",
            "relaxation_time_s",
            "gain_mm_per_v",
            "mode_frequency_hz",
            "damping_ratio",
            "dac_reference_v",
            "full_scale_v",
        )
        for name in positive:
            _check_real(name, getattr(self, name), low=0.0, low_open=True)
        for name in ("source_resistance_ohm", "exposure_s", "noise_std_mm"):
            _check_real(name, getattr(self, name), low=0.0)
        for name in ("alpha_e", "alpha_i", "alpha_c"):
            _check_real(name, getattr(self, name), low=0.0, low_open=True, high=1.0)
        _check_real("relaxation_fraction", self.relaxation_fraction, low=0.0, high=1.0, high_open=True)
        _check_real("compression", self.compression, low=0.0, high=0.9)
        _check_int("n_compartments", self.n_compartments, low=1)
        _check_int("oversample", self.oversample, low=1)
        _check_int("dac_bits", self.dac_bits, low=1, high=24)
        for name in ("camera_fps", "pixel_mm"):
            if getattr(self, name) is not None:
                _check_real(name, getattr(self, name), low=0.0, low_open=True)
        if self.camera_fps is not None and self.exposure_s > 1.0 / self.camera_fps:
            raise InputError(
                f"exposure_s = {self.exposure_s} s is longer than the frame period "
                f"1/camera_fps = {1.0 / self.camera_fps} s; use an exposure no longer "
                "than one frame."
            )
