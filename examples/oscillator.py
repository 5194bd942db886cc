"""A mass–spring–damper and its Duffing extension: physics plug-ins for the Silverbox benchmark.

The Silverbox is an electronic circuit built to behave as a mass on a spring
with a damper, driven by a force u (the input voltage V1), its displacement y
read as the output voltage V2. Per unit mass, with the static gain of the
spring folded into the drive's scale (y in volts of drive):

    y'' + 2 zeta omega y' + omega² (y + cubic · y³) = omega² (u − drive_offset)

- `MassSpringDamper`: cubic = 0, the linear first-principles model.
- `Duffing`: cubic (1/V²) free, the restoring force k1·y + k3·y³ the benchmark
  is known for (a hardening spring for cubic > 0).

The readout of `hybrid.make_model("physics", ...)` (gain · y + offset) maps y to
V2. `drive_offset` (V) is the drive's level at which the spring is relaxed: it
matters only with cubic ≠ 0 (with a linear spring a shift of u is a shift of y
that the readout's offset absorbs, so it is frozen by default in
`MassSpringDamper`).

Integration: fixed-step RK4 in `lax.scan`, SUBSTEPS steps per sample, the drive
interpolated linearly between samples (the Silverbox's input is a measured,
band-limited voltage, not a held one: holding it would add half a sample of
delay that the linear model would fold into its damping). With the resonance at
~69 Hz and 610 Hz sampling, one RK4 step spans 0.16 rad of the oscillation;
`tests/test_plugins.py` checks the result against scipy's solve_ivp. The
oscillator starts at rest. The state-space form also lets `hybrid diagnose` search
effects inside the dynamics: on the Silverbox it finds the cubic spring that
`MassSpringDamper` leaves out, as a restoring force fed back into the drive.
"""

from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp

from hybrid import AbstractStateSpace, Positive, Real, encode

#: RK4 steps per sample.
SUBSTEPS = 4


class MassSpringDamper(AbstractStateSpace):
    """A linear oscillator: natural frequency `frequency` (Hz), damping ratio `zeta`; output y (V of drive)."""

    raw: dict

    constraints: ClassVar[dict] = {
        "frequency": Positive(),
        "zeta": Positive(),
        "cubic": Real(),
        "drive_offset": Real(),
    }
    units: ClassVar[dict] = {"frequency": "Hz", "zeta": "1", "cubic": "1/V^2", "drive_offset": "V"}
    plausible: ClassVar[dict] = {
        "frequency": (1e-3, 1e5),
        "zeta": (1e-4, 10.0),
        "cubic": (-1e4, 1e4),
        "drive_offset": (-10.0, 10.0),
    }
    typical: ClassVar[dict] = {
        "frequency": (0.1, 1e3),
        "zeta": (0.01, 2.0),
        "cubic": (-10.0, 10.0),
        "drive_offset": (-0.1, 0.1),
    }
    frozen_by_default: ClassVar[dict] = {
        "cubic": "the linear model: a spring with no cubic term (free it, or use Duffing)",
        "drive_offset": "with a linear spring a shift of the drive is a shift of y, which the readout's offset absorbs",
    }
    states: ClassVar[tuple] = ("position", "velocity")
    # y is in the drive's unit (the static gain folded into the drive's scale).
    state_units: ClassVar[dict] = {"position": "{drive}", "velocity": "{drive}/s"}
    # simulate returns the position y: in the drive's unit too.
    output_unit: ClassVar[str] = "{drive}"
    # An end stop limits the position; nothing limits the velocity directly.
    limited_states: ClassVar[tuple] = ("position",)
    # A dry friction acts on the velocity.
    velocity_states: ClassVar[tuple] = ("velocity",)
    substeps: ClassVar[int] = SUBSTEPS
    drive_between_samples: ClassVar[str] = "linear"
    linear_in_drive: ClassVar[bool] = (
        False  # the cubic term and drive_offset, when freed, are in volts of drive
    )

    def __init__(self, frequency=50.0, zeta=0.1, cubic=0.0, drive_offset=0.0):
        values = dict(frequency=frequency, zeta=zeta, cubic=cubic, drive_offset=drive_offset)
        self.raw = encode(values, self.constraints, type(self).__name__)

    def prepare(self, p):
        """The rates' coefficients, computed once per simulation rather than at every RK4 stage."""
        w = 2.0 * jnp.pi * p["frequency"]
        return {**p, "w2": w * w, "damping": 2.0 * p["zeta"] * w}

    def rates(self, x, u, p):
        """(dy/dt, dv/dt) at the state x = (y, v) under the drive u (V)."""
        y, v = x
        spring = y + p["cubic"] * y * y * y
        return v, p["w2"] * (u - p["drive_offset"] - spring) - p["damping"] * v


class Duffing(MassSpringDamper):
    """`MassSpringDamper` with its cubic stiffness free: the restoring force ω²(y + cubic·y³)."""

    frozen_by_default: ClassVar[dict] = {}
