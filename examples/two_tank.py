"""Two tanks in cascade (Torricelli outflow): a physics plug-in for hybrid, worked in full.

A pump drives water into the upper tank; it drains through an outlet into the
lower tank, which drains through its own outlet. A sensor reads the lower
tank's level as a voltage. With levels h1, h2 (cm), tank cross-sections
A1, A2 (cm²), effective outlet areas a1, a2 (cm², discharge coefficient
included), the pump's flow per volt k (cm³/s per V) and g = 981 cm/s²:

    A1 dh1/dt = k·max(u, 0) − a1·√(2 g h1)
    A2 dh2/dt = a1·√(2 g h1) − a2·√(2 g h2)

`simulate` returns h2 (cm) at each sample time; the model's readout
(`hybrid.make_model("physics", ...)`: gain · h2 + offset) maps it to the
sensor's volts, so the sensor's calibration is fitted with the physics.

Choices, and why:

- *Torricelli near an empty tank.* √h has an infinite slope at h = 0, so a
  tank that empties (or starts empty) makes the gradient NaN. The outflow is
  a·√(2g)·h/√(|h| + H_LAMINAR): √h above a few millimetres of water, linear (laminar)
  below, smooth and finite everywhere. The pump cannot run backwards: a negative
  drive gives no inflow.
- *Initial state.* The tanks start in equilibrium with the first sample's drive
  (recordings begin with the pump steady), from the closed form of the
  regularised outflow; a first drive ≤ 0 means empty tanks.
- *Integration: fixed-step RK4 (the tanks are stated as rates of their levels, a
  `hybrid.AbstractStateSpace`, which integrates them in `lax.scan`), SUBSTEPS steps per sample with the
  drive held (unrolled), not diffrax.* Speed does not decide it: measured on 3000
  samples (2 shared CPU cores, float64), RK4 and diffrax (Tsit5, adaptive, rtol 1e-8,
  one `diffeqsolve` per sample in a scan) both simulate in ~4.5 ms; an LM Jacobian
  (`jax.linearize`, 5 tangents) takes 64 ms with RK4 and 46 ms with diffrax, a
  reverse-mode gradient 39 ms and 79 ms. What decides it is autodiff:
  `fit`'s LM and `sensitivity` differentiate the simulation in forward mode and
  the `adam` solver in reverse mode. diffrax's default adjoint is a `custom_vjp`
  that `jax.linearize` refuses ("can't apply forward-mode autodiff (jvp) to a
  custom_vjp function"), and `adjoint=diffrax.ForwardMode()` makes reverse mode
  fail (a `while_loop`); the plain scan supports both. Fixed steps also keep the
  output a smooth function of the parameters (an adaptive controller's step
  choices switch as they move, which roughens LM's Jacobian). With the default
  tanks the linearised time constants are seconds (0.4 s near an empty tank) and a
  sample 0.1 s, so four RK4 steps per sample agree with scipy's solve_ivp to ~1e-8
  (`tests/test_plugins.py` checks ≤ 1e-6). Outlets far larger relative to the
  tanks, or samples of several seconds, need more SUBSTEPS (RK4 is unstable once a
  step exceeds ~2.8 time constants).
- *Which parameters a fit moves.* The levels are seen only through the sensor's
  fitted gain. Scaling every level by λ (pump flow / λ, outlets / √λ, gain · λ)
  changes nothing at all, so the pump's flow per volt is fixed by default
  (calibrate it). Scaling the lower tank's level alone (area_2 · λ, outlet_2 · √λ,
  gain · λ) changes only the laminar regime of a nearly empty tank, and scaling
  area_1 with outlet_1 barely changes it either: on a step drive the Jacobian's
  (columns normalised) smallest singular values are 5e-6 and 1e-3 with the areas
  free, 0.07 with them fixed. So both areas, measured with a ruler, are fixed by
  default too, and a fit moves the two outlets (what clogs and wears).
  `hybrid diagnose` and the CLI's fit apply `frozen_by_default`; from Python pass
  ``frozen=set(TwoTank().frozen_by_default)`` to `hybrid.fit`.

Use it:

    hybrid fit recording.csv --model physics --physics examples/two_tank.py:TwoTank
    hybrid diagnose recording.csv --physics examples/two_tank.py:TwoTank

or, from Python, ``hybrid.fit(hybrid.make_model("physics", simulation=TwoTank()), recording,
frozen=set(TwoTank().frozen_by_default))``. See docs/plugins.md.
"""

from __future__ import annotations

from typing import ClassVar

import jax
import jax.numpy as jnp

from hybrid import AbstractStateSpace, Positive, UnitInterval, encode

#: Gravity (cm/s²).
G = 981.0
#: Head (cm) below which an outlet's flow turns from √h (turbulent) to ∝ h (laminar).
H_LAMINAR = 0.05
#: RK4 steps per sample (the drive is held over the sample).
SUBSTEPS = 4
#: √(2g) (cm^0.5/s): Torricelli's outflow is outlet · √(2g) · √h.
SQRT_2G = G**0.5 * 2**0.5


class TwoTank(AbstractStateSpace):
    """Two tanks in cascade; the output is the lower tank's level h2 (cm)."""

    # The unconstrained values of the parameters, by name: the only field, so the
    # default config() ({}) and from_config (TwoTank()) rebuild it for load_model.
    raw: dict

    # How each parameter maps from its raw value: all positive (optimised in log).
    constraints: ClassVar[dict] = {
        "pump_flow": Positive(),
        "area_1": Positive(),
        "area_2": Positive(),
        "outlet_1": Positive(),
        "outlet_2": Positive(),
    }
    units: ClassVar[dict] = {
        "pump_flow": "cm^3/(s {drive})",  # per unit of the drive
        "area_1": "cm^2",
        "area_2": "cm^2",
        "outlet_1": "cm^2",
        "outlet_2": "cm^2",
    }
    # A fitted value outside is warned about: bench-top tanks to a water tower's.
    plausible: ClassVar[dict] = {
        "pump_flow": (0.1, 1e3),
        "area_1": (1.0, 1e4),
        "area_2": (1.0, 1e4),
        "outlet_1": (1e-3, 10.0),
        "outlet_2": (1e-3, 10.0),
    }
    # Where diagnose's screened starts spread (log-spaced: Positive), the outlets first.
    typical: ClassVar[dict] = {
        "outlet_1": (0.02, 1.0),
        "outlet_2": (0.02, 1.0),
        "area_1": (5.0, 500.0),
        "area_2": (5.0, 500.0),
        "pump_flow": (1.0, 100.0),
    }
    frozen_by_default: ClassVar[dict] = {
        "pump_flow": "levels are seen only through the sensor's fitted gain: scaling the pump's flow rescales "
        "every level and the gain undoes it exactly; calibrate the pump and keep it fixed",
        "area_1": "measured; scaled with outlet_1 it barely changes the output (the data hardly tell them apart)",
        "area_2": "measured; scaled with outlet_2 and the sensor's gain it changes only a nearly empty tank",
    }
    # The pump's drive the numbers above are written for (the Cascaded Tanks' 0–10 V): fit and diagnose
    # warn about a drive far outside it (recorded in mV, or in a DAC's counts).
    drive_range: ClassVar[tuple] = (0.0, 10.0)
    # The output is not linear in the drive (√ outflow, a pump that cannot reverse):
    # fit must not rescale the drive's volts.
    linear_in_drive: ClassVar[bool] = False
    # The state-space form (hybrid.AbstractStateSpace): simulate follows, and diagnose can
    # search effects inside the dynamics (a limit on either level).
    states: ClassVar[tuple] = ("h1", "h2")
    substeps: ClassVar[int] = SUBSTEPS
    state_units: ClassVar[dict] = {"h1": "cm", "h2": "cm"}
    # The upper tank sits over the lower one: water over its rim, had it one, would fall there
    # (a limit diagnose fits on h1 moves a share of what it cuts into h2).
    spills_into: ClassVar[dict] = {"h1": "h2"}
    # simulate returns the lower level h2: a sensor's gain is then in its volts per cm.
    output_unit: ClassVar[str] = "cm"

    def __init__(self, pump_flow=3.3, area_1=15.5, area_2=15.5, outlet_1=0.18, outlet_2=0.18):
        # The defaults (a bench-top coupled-tank rig) are where a fit starts.
        values = dict(pump_flow=pump_flow, area_1=area_1, area_2=area_2, outlet_1=outlet_1, outlet_2=outlet_2)
        self.raw = encode(values, self.constraints, "TwoTank")  # checks names and ranges

    def prepare(self, p):
        """Outflow and inflow coefficients per tank area (level rates), computed once per run."""
        c1, c2 = p["outlet_1"] * SQRT_2G, p["outlet_2"] * SQRT_2G  # cm^2.5/s: outflow c·√h
        return {
            **p,
            "c1": c1,
            "c2": c2,
            "q1": p["pump_flow"] / p["area_1"],
            "a11": c1 / p["area_1"],
            "a21": c1 / p["area_2"],
            "a22": c2 / p["area_2"],
        }

    def rates(self, x, u, p):
        """(dh1/dt, dh2/dt) (cm/s) at the levels x = (h1, h2) under the pump drive u (V)."""
        o1, o2 = outflow(x[0]), outflow(x[1])
        inflow = p["q1"] * jnp.maximum(u, 0.0)  # the pump cannot run backwards
        return inflow - p["a11"] * o1, p["a21"] * o1 - p["a22"] * o2

    def observe(self, x, p):
        """The sensor reads the lower tank: h2 (cm)."""
        return x[1]

    def initial_state(self, u0, p):
        """Both tanks in equilibrium with the first drive value (empty for a first drive ≤ 0)."""
        inflow = p["pump_flow"] * jnp.maximum(u0, 0.0)
        return equilibrium(p["c1"], inflow), equilibrium(p["c2"], inflow)

    def levels(self, v_in, dt):
        """(h1, h2) (cm) at each sample time: both tanks' levels (`simulate` returns h2)."""
        levels = self.trajectory(v_in, dt)
        return levels["h1"], levels["h2"]


class TwoTankOverflow(TwoTank):
    """Two tanks in cascade whose tanks overflow: the Cascaded Tanks benchmark's missing physics.

    Added to `TwoTank`'s parameters:

    - `level_max_1` (cm): the upper tank's rim. Water above it spills; the share
      `spill_to_lower` of the spill falls into the lower tank, the rest is lost.
    - `level_max_2` (cm): the lower tank's rim (or its level sensor's top),
      above which water is lost.

    After each RK4 step a level above its rim is brought back to it:
    h ← L − δ·softplus((L − h)/δ), δ = `RIM_WIDTH` · L, a rim δ wide instead of
    a sharp edge so that a fit sees a finite slope with respect to L before any
    level reaches it (a hard `min` has zero slope there and LM could never move
    L down to the data).
    """

    constraints: ClassVar[dict] = {
        **TwoTank.constraints,
        "level_max_1": Positive(),
        "level_max_2": Positive(),
        "spill_to_lower": UnitInterval(),
    }
    units: ClassVar[dict] = {**TwoTank.units, "level_max_1": "cm", "level_max_2": "cm", "spill_to_lower": "1"}
    plausible: ClassVar[dict] = {**TwoTank.plausible, "level_max_1": (1.0, 1e4), "level_max_2": (1.0, 1e4)}
    typical: ClassVar[dict] = {**TwoTank.typical, "level_max_1": (5.0, 200.0), "level_max_2": (5.0, 200.0)}

    def __init__(
        self,
        pump_flow=3.3,
        area_1=15.5,
        area_2=15.5,
        outlet_1=0.18,
        outlet_2=0.18,
        level_max_1=100.0,
        level_max_2=100.0,
        spill_to_lower=0.5,
    ):
        values = dict(
            pump_flow=pump_flow,
            area_1=area_1,
            area_2=area_2,
            outlet_1=outlet_1,
            outlet_2=outlet_2,
            level_max_1=level_max_1,
            level_max_2=level_max_2,
            spill_to_lower=spill_to_lower,
        )
        self.raw = encode(values, self.constraints, "TwoTankOverflow")

    def walls(self, x, p):
        """Each level above its rim brought back to it; the upper tank's spill partly into the lower."""
        h1, h2 = x[0], x[1]
        top1 = _rim(h1, p["level_max_1"])
        h2 = h2 + p["spill_to_lower"] * (h1 - top1) * p["area_1"] / p["area_2"]
        return top1, _rim(h2, p["level_max_2"])


#: The rim's width as a share of its height (see `TwoTankOverflow`).
RIM_WIDTH = 0.02


def _rim(h, top):
    """min(h, top) with a rim RIM_WIDTH·top wide: smooth, ≤ top, ≈ h well below it."""
    width = RIM_WIDTH * top
    return top - width * jax.nn.softplus((top - h) / width)


def outflow(h):
    """√h for a head h well above H_LAMINAR, ∝ h below it: smooth, finite slope at an empty tank."""
    return h / jnp.sqrt(jnp.abs(h) + H_LAMINAR)


def equilibrium(c, q):
    """The level h ≥ 0 where the outflow c·h/√(h + H_LAMINAR) equals the inflow q ≥ 0."""
    r = q / c  # h / √(h + H) = r, a quadratic in h; r ≥ 0 keeps every square root away from 0
    return 0.5 * (r * r + r * jnp.sqrt(r * r + 4.0 * H_LAMINAR))
