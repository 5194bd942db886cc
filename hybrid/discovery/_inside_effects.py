"""Effects inside the dynamics: a nonlinearity fed back into the drive, a limit on a state.

They act on a simulation in state-space form ([`AbstractStateSpace`][]), whose
rates `integrate` evaluates several times per sample: an inside effect is
evaluated there, sample by sample, not on a whole signal.

=====================  ==========================================  =====================================
name                   what it does                                parameters
=====================  ==========================================  =====================================
``stiffness``          ẋ = f(x, u − k₂y² − k₃y³), y the output     ``stiffness_square`` k₂ ({drive}/{signal}²),
                       (a restoring force that is not linear)      ``stiffness_cube`` k₃ ({drive}/{signal}³)
``limit_<state>``      the state z ↦ min(z, L) after every step,   ``<state>_max`` L (unit of the state);
                       with a soft rim (`RIM_WIDTH`); a share of   with `into`, ``<state>_spill`` (unit of
                       the cut into another state (`into`)         `into` per unit of the state)
``floor_<state>``      the state z ↦ max(z, L) after every step    ``<state>_min`` L (unit of the state)
                       (an end stop below)
``friction_<state>``   ẋ = f(x, u − F·tanh(v/v_s)), v the state    ``<state>_friction`` F ({drive}),
                       (a Coulomb friction on a velocity)          ``<state>_stick_speed`` v_s (its unit)
``window_<group>``     each state z of a group (or one state,      ``<group>_window`` L (unit of the
                       ``window_<state>``) held within z_rest ± L  states)
                       after every step (an electrochemical
                       window on double-layer voltages)
=====================  ==========================================  =====================================

- Stiffness: the spring of a mass–spring system that hardens (k₃ > 0) or
  softens (k₃ < 0) with the stretch, and is asymmetric (k₂); the Silverbox's
  restoring force. The force is in the drive's unit: with y = S(u) the linear
  simulation, the extended model is y = S(u − φ(y)). A polynomial of the
  output, not of a shifted output: a cubic about another centre is k₂ and k₃
  plus a linear term that the simulation's own stiffness and the readout's gain
  take up. ``derived``'s ``force_percent_of_drive`` (every inside feedback gets
  it from the stack) is the largest |φ(y)| as a percentage of the largest |u|.
- State limit: an overflowing tank, an end stop, a saturating integrator. It is
  material when it pulls the state's peak down by 3 % of the state's range or
  more (``cut_percent_of_range``, from the stack: the state with the limit and
  without). One
  effect per state of the simulation (`StateLimit("h1")`, named ``limit_h1``);
  `diagnose` searches one per state by default. The limit is an upper one;
  ``floor_<state>`` (`StateLimit("position", below=True)`, ``<state>_min``)
  is the lower one, searched by default on each state that one of the
  simulation's velocities moves (an end stop below a position as above it;
  a tank's level has none), on any other when named. A rim of width
  δ = `RIM_WIDTH` (0.5 %) of |L − z_rest| instead of a sharp edge, L − δ·softplus((L − z)/δ), so that
  a fit sees a finite slope with respect to L before the state reaches it.
  Where the simulation says where a state's excess goes
  (`AbstractStateSpace.spills_into`: water over the upper tank's rim falls
  into the lower tank), the limit moves a fitted share of the cut there
  (`StateLimit("h1", into="h2")`); otherwise the cut is lost. Where a
  velocity moves the state (`StateLimit("position", velocity="velocity")`,
  found from the rates for the default set), the limit is an end stop: it
  takes away the part of the velocity that pushes into it, so the mass stays
  at the stop and leaves when the drive pulls it back.
- Window: a limit of either sign, the same on every state of a group the
  simulation names (`AbstractStateSpace.state_groups`: the RC network's
  double-layer voltages, ``window_vc``), searched when named. Material as a
  state limit, by ``cut_percent_of_range`` of its first state, both ends counted.
- Friction: a dry (Coulomb) friction on a state that is a velocity, a force of
  nearly constant size F against its sign, smoothed over |v| ≲ v_s (a step has
  no gradient, and a real contact sticks over a small band of speeds). The
  viscous part, a force proportional to the velocity, is the simulation's own
  damping, which its fit already has: a second copy here would trade with it
  and pin neither. One effect per state (`Friction("velocity")`, named
  ``friction_velocity``); `diagnose` searches one on each state the
  simulation says is a velocity (`AbstractStateSpace.velocity_states`) and on
  any other when named (``--effects builtins,friction_<state>``). A friction
  the search did not look for is pointed at by the remainder, which reads
  each state's map fed back into the drive against a step at zero and names
  the state and the effect (`tests/test_inside_effects.py -k friction`).
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ..core._parameters import Positive, Real
from ..core._simulation import unit_in
from ..data._header_units import unit_kind
from ..util._errors import InputError
from ._effects import AbstractEffect, init_values, shown, signal_span, signal_top

#: The rim's width as a share of the limit's distance from the state's rest, |L − x_rest|: `StateLimit`'s
#: default `rim`. A rim 2 % wide, applied after every step, held the Cascaded Tanks' upper tank well
#: below its fitted rim, and diagnose's extended TwoTank scored 0.47 V on the benchmark's validation
#: record; 0.5 % wide it scores 0.23 V (TwoTankOverflow, by hand: 0.40 V; published grey-box 0.19 V):
#: `hybrid diagnose ../shared/data/cascaded-tanks/dataBenchmark.csv --columns input=uEst,output=yEst
#: --rate 0.25 --physics examples/two_tank.py:TwoTank --out D`, then `hybrid fit` of the same columns
#: `--start-from D/extended.eqx --max-steps 0 --test` that file `--test-columns input=uVal,output=yVal
#: --initial-samples 4`.
RIM_WIDTH = 0.005
#: The rim of the models saved before it was an option (`StateLimit.from_config`).
LEGACY_RIM = 0.02
#: Where a spill's share starts (`StateLimit` with `into`): half of the cut lands in `into`.
SPILL_START = 0.5


class PolynomialStiffness(AbstractEffect):
    """A restoring force k₂y² + k₃y³ of the output y, fed back into the drive: y = S(u − φ(y))."""

    raw: dict[str, Array]
    name: ClassVar[str] = "stiffness"
    place: ClassVar[str] = "inside"
    role: ClassVar[str] = "feedback"
    constraints: ClassVar = {"stiffness_square": Real(), "stiffness_cube": Real()}
    units: ClassVar = {"stiffness_square": "{drive}/{signal}^2", "stiffness_cube": "{drive}/{signal}^3"}
    defaults: ClassVar = {"stiffness_square": 0.0, "stiffness_cube": 0.0}
    thresholds: ClassVar = {"force_percent_of_drive": 3.0}

    def __init__(self, **values):
        init_values(self, values)

    def apply(self, y, dt):
        p = self.parameters()
        return y * y * (p["stiffness_square"] + p["stiffness_cube"] * y)

    def starts(self, context):
        # A cubic force of 5 % of the largest drive at the largest |y|, hardening or softening.
        drive = context.drive if context.drive is not None else context.signal
        k3 = 0.05 * signal_top(drive) / signal_top(context.signal) ** 3
        return [
            {"stiffness_square": 0.0, "stiffness_cube": k3},
            {"stiffness_square": 0.0, "stiffness_cube": -k3},
        ]

    def material(self, derived, parameters, thresholds):
        size, need = derived.get("force_percent_of_drive", 0.0), thresholds["force_percent_of_drive"]
        return size >= need, f"force {shown(size, need)} % of the largest drive (needs ≥ {need} %)"

    def derived(self, y, dt):
        """``restoring_percent``: how much of the fitted force pushes back against the output, −100 to 100 %.

        100 · Σ y·φ(y) / Σ |y·φ(y)| over the record: 100 where φ always adds
        to the model's own restoring force (a spring that hardens, a loss that
        grows faster than linearly), −100 where it always takes from it. Read
        over the record because the square term's sign depends on where the
        output goes: on a temperature that only rises, k₂ > 0 is a loss that
        grows, whatever k₃'s sign.
        """
        y = np.asarray(y, float)
        force = y * self.apply(jnp.asarray(y), dt)
        total = float(np.sum(np.abs(force)))
        share = 100.0 * float(np.sum(force)) / total if total > 0 else 0.0
        return {"restoring_percent": float(np.clip(share, -100.0, 100.0))}

    def reading(self, parameters, output_unit):
        # The force adds to the restoring force where the output went (`derived`): a spring that
        # hardens, a damping that grows with speed, a loss that quickens; or takes from it. Without
        # the record's reading, k₃'s sign says it (φ is subtracted from the drive).
        share = parameters.get("restoring_percent")
        grows = share >= 0.0 if share is not None else parameters.get("stiffness_cube", 0.0) >= 0.0
        kind = unit_kind(output_unit)
        if kind == "rate":
            return (
                f"a force of the output fed back against the drive, and the output ({output_unit}) is a rate: "
                "a nonlinear damping ("
                + (
                    "one that grows faster than the speed, fitted as k₂·v² + k₃·v³: a drag, such as a fluid's "
                    "turbulent loss, ∝ v·|v|, or a cube"
                    if grows
                    else "one that eases at speed, fitted as k₂·v² + k₃·v³"
                )
                + "), not a spring"
            )
        if kind == "position":
            return (
                f"a restoring force of the output, a position ({output_unit}): a spring that "
                f"{'hardens' if grows else 'softens'} with the stretch"
            )
        if kind == "temperature":
            return (
                f"a heat flow of the output, a temperature ({output_unit}), fed back against what drives it: "
                f"{'a loss that grows faster than linearly (radiation, ∝ T⁴; convection that quickens)' if grows else 'a loss that eases as it warms (or a gain)'}, "
                "beyond the model's own"
            )
        return (
            "a force of the output fed back against the drive: a nonlinear spring where the output is a "
            "position, a nonlinear damping where it is a speed"
        )


class StateLimit(AbstractEffect):
    """An upper limit L on one state of the dynamics (an overflow, an end stop), applied after every step.

    With `below`, a lower limit instead, a floor L under the state (``floor_<state>``,
    ``<state>_min``): an end stop below a position, a valve seat, a charge that
    cannot reverse.

    With `into` (another state), a share of what the limit cuts off goes there:
    the water over an upper tank's rim falls into the tank below. The share,
    ``<state>_spill``, is in the unit of `into` per unit of the state (1 for two
    levels of tanks of one cross-section whose whole spill lands below);
    `into_unit` is that state's unit, for the report.

    With `velocity` (the state whose value moves this one: a position's
    velocity), the limit is an end stop: as it engages, the part of that
    velocity that pushes into it is taken away (`stopped`), so the mass stays
    at the stop while the drive pushes it there and leaves as soon as the
    drive pulls it back (an inelastic stop: a bumper, a hard stop with little
    bounce). Without it the position was held at the stop while its velocity
    ran on, and had to wind down before the mass could leave. A stop that the
    mass bounces off is not built in.

    `rim`: the limit engages smoothly over a rim this share of its distance
    from the state's rest wide (`RIM_WIDTH`, 0.5 %, by default; see `_rim`), so
    that a fit sees a slope with respect to L before the state reaches it.
    """

    raw: dict[str, Array]
    state: str = eqx.field(static=True)
    into: str | None = eqx.field(static=True)
    into_unit: str = eqx.field(static=True)
    velocity: str | None = eqx.field(static=True)
    rim: float = eqx.field(static=True)
    below: bool = eqx.field(static=True)
    place: ClassVar[str] = "inside"
    role: ClassVar[str] = "limit"
    n_screened: ClassVar[int] = 2
    from_rest: ClassVar[bool] = True  # its rim: a share of the limit's distance from the state's rest

    def __init__(
        self,
        state: str = "x",
        into: str | None = None,
        into_unit: str = "",
        velocity: str | None = None,
        rim: float = RIM_WIDTH,
        below: bool = False,
        **values,
    ):
        if not isinstance(state, str) or not state.isidentifier():
            raise InputError(f"StateLimit needs a state's name (an identifier), got {state!r}")
        if not isinstance(below, bool):
            raise InputError(f"StateLimit({state!r}): below must be True or False, got {below!r}")
        if below and into is not None:
            raise InputError(
                f"StateLimit({state!r}, below=True): a floor spills nothing (into={into!r}); drop into"
            )
        self.below = below
        for role, other in (("into", into), ("velocity", velocity)):
            if other is not None and (
                not isinstance(other, str) or not other.isidentifier() or other == state
            ):
                raise InputError(
                    f"StateLimit({state!r}): {role} must name another state (an identifier) or be None, "
                    f"got {other!r}"
                )
        self.state, self.into, self.into_unit, self.velocity = state, into, str(into_unit), velocity
        self.rim = _checked_rim(rim, f"StateLimit({state!r})", "the limit's distance from the state's rest")
        init_values(self, values)

    # The facts depend on the state: properties, not class constants.
    @property
    def name(self) -> str:  # type: ignore[override]
        return f"{'floor' if self.below else 'limit'}_{self.state}"

    @property
    def acts_on(self) -> str:  # type: ignore[override]
        return self.state

    @property
    def level_name(self) -> str:
        """The parameter of its level: ``<state>_max``, or ``<state>_min`` for a floor."""
        return f"{self.state}_{'min' if self.below else 'max'}"

    @property
    def constraints(self) -> dict:  # type: ignore[override]
        level = {self.level_name: Real()}
        return level if self.into is None else {**level, f"{self.state}_spill": Positive()}

    @property
    def units(self) -> dict:  # type: ignore[override]
        level = {self.level_name: "{signal}"}
        return level if self.into is None else {**level, f"{self.state}_spill": "{into}/{signal}"}

    @property
    def defaults(self) -> dict:  # type: ignore[override]
        level = {self.level_name: -1.0 if self.below else 1.0}
        return level if self.into is None else {**level, f"{self.state}_spill": SPILL_START}

    @property
    def thresholds(self) -> dict:  # type: ignore[override]
        return {"cut_percent_of_range": 3.0}

    def units_for(self, signal_unit: str, drive_unit: str = "") -> dict[str, str]:
        out = super().units_for(signal_unit, drive_unit)
        if self.into is not None:
            into = unit_in(self.into_unit, drive_unit or "(unit of the drive)") or f"(unit of {self.into})"
            share = f"{self.state}_spill"
            out[share] = "1" if into == (signal_unit or "(unit of S)") else out[share].replace("{into}", into)
        return out

    def config(self) -> dict:
        out: dict = {"state": self.state}
        if self.into is not None:
            out.update(into=self.into, into_unit=self.into_unit)
        out.update(rim=self.rim)
        if self.velocity is not None:
            out.update(velocity=self.velocity)
        if self.below:  # a ceiling's config as before floors were built in
            out.update(below=True)
        return out

    @classmethod
    def from_config(cls, config: dict) -> StateLimit:
        # a model saved before the rim was an option was fitted with the rim of then: 2 %
        return cls(**{"rim": LEGACY_RIM, **config})

    def spilled(self, z, dt, origin=0.0):
        """What goes into `into` when the limit takes z down to `apply(z)`: share × the cut."""
        return self.parameters()[f"{self.state}_spill"] * (z - self.apply(z, dt, origin))

    def stopped(self, z, v, origin=0.0):
        """The velocity v of the state z after an end stop: its part into the stop taken away as z meets it.

        The share taken is σ((z − L)/δ), δ the rim's width: none well below
        the limit, half at it, all beyond. Only a positive v (one that drives z
        up, into the stop) is taken; under a floor, mirrored: σ((L − z)/δ) of a
        negative v.
        """
        level, width = self._rim(origin)
        s = self._sign
        return v - jax.nn.sigmoid(s * (z - level) / width) * s * jnp.maximum(s * v, 0.0)

    @property
    def _sign(self) -> float:
        """+1 for a ceiling, −1 for a floor: a floor on z at L is the ceiling on −z at −L."""
        return -1.0 if self.below else 1.0

    def _level(self):
        return self.parameters()[self.level_name]

    def cut(self, unlimited, limited) -> float:
        """How far the limit pulls the state's peak down (a floor: its trough up), one end alone."""
        s = self._sign
        return max(float(np.max(s * np.asarray(unlimited)) - np.max(s * np.asarray(limited))), 0.0)

    def _rim(self, origin=0.0):
        """The limit L and the width δ = `rim`·|L − origin| over which it engages (traced: `apply`, `stopped`).

        `origin`: where the state rests under no drive (the stack passes its initial state
        for a drive of 0: a tank empty, a block at ambient). Measured from there, the rim is
        the same whatever the zero of the state's unit: a ceiling 22 K above a block's ambient
        is one in °C and in K alike. Measured from 0 (|L|), it was 6.3 K wide in K and 0.9 K in
        °C, and the softplus, applied after every step, held the block several widths below L:
        a ceiling at 44 °C written in K was no limit at all (`tests/test_inside_effects.py -k
        zero_of`). For a state that rests at 0 (a tank's level) the two are one.
        """
        top = self._level()
        return top, self.rim * jnp.abs(top - origin) + 1e-12

    def apply(self, z, dt, origin=0.0):
        level, width = self._rim(origin)
        s = self._sign
        return level - s * width * jax.nn.softplus(s * (level - z) / width)

    def derived(self, z, dt, origin: float = 0.0):
        level = float(self._level())
        z = np.asarray(z, float)
        width = self.rim * abs(level - origin)  # from the state's rest (`_rim`), which the stack passes
        at = self._sign * (z - level) >= -2.0 * width
        return {"level": level, "at_limit_percent": 100.0 * float(np.mean(at)) if z.size else 0.0}

    def starts(self, context):
        # Just below the state's peak under the current model, a quarter of its range below, and
        # the recorded output's peak in the simulation's unit: where an observed state that the
        # record shows flat at its top would sit (for a state upstream, one more level to try).
        # A floor: the same from the state's trough up.
        sign = self._sign
        z = sign * np.asarray(context.signal, float)
        peak, span = float(np.max(z)), signal_span(z)
        seen = context.measured
        top = float(np.max(sign * np.asarray(seen))) if seen is not None and len(seen) else peak - 0.5 * span
        return [{self.level_name: sign * level} for level in (peak - 0.05 * span, peak - 0.25 * span, top)]

    def screened_starts(self, context):
        from ._starts import limit_starts

        share = f"{self.state}_spill" if self.into is not None else None
        return limit_starts(
            context.problem,
            context.simulation,
            self,
            self.level_name,
            self.n_screened,
            context.frozen,
            share,
            lowest=self.below,
        )

    def unpinned_reason(self, name, signal):
        sign = self._sign  # a floor: the ceiling of −z
        z = sign * np.asarray(signal, float)
        top = sign * float(self._level())
        if z.size and np.max(z) < top - 2.0 * self.rim * abs(top - float(np.min(z))):  # its least: near rest
            return "the state never reaches the limit in this recording"
        return None

    def reading(self, parameters, output_unit):
        # A piezo stage's gauge that clipped at 85 µm was named an end stop on its position: where
        # the output reads the limited state, the two look alike (an end stop also stops the rate).
        where = " and spills into " + self.into if self.into is not None else ""
        kind = "an end stop below, a valve's seat" if self.below else "an end stop, an overflow"
        if self.velocity is not None:
            kind, where = (
                "an end stop",
                f"{where}, which also stops the state that moves it ({self.velocity}) there",
            )
        return (
            f"{'a lower' if self.below else 'an upper'} limit on the state {self.state} inside the dynamics "
            f"({kind}){where}; "
            "where the output reads this state, a sensor that clips at that level looks alike on a recording "
            "unless the rate of the state shows the stop"
        )

    def material(self, derived, parameters, thresholds):
        # ``cut_percent_of_range`` comes from the stack: the state's peak with the limit and without.
        return _cut_material("limit", self.state, derived, thresholds)


class StateWindow(AbstractEffect):
    """A two-sided limit ±L about rest on a group of states at once: an electrochemical window.

    Every state of `states` is held within [x_rest − L, x_rest + L] after
    every step (x_rest: where it rests under no drive), with one fitted
    half-width L, ``<group>_window`` in the states' unit: the double-layer
    voltages of the RC network's compartments, each of which stops charging
    where the electrolyte starts to decompose (electrolysis, a Faradaic current
    past the double layer) at the same voltage, of either sign. A limit on the
    clamp's compartment alone moved the tip voltage by 0.3–0.9 % RMS of its
    range (`experiments/inside_effects.py`'s ``rc_limit``, a rim at 30–50 % of
    its peak), the window on all of them by 1.6–6.9 % (``rc_window``, ±40–60 %).
    One state (`states` of one) is a symmetric limit on it.

    `acts_on` is the first state, whose trajectory the report reads (the
    RC network's clamp compartment, which swings furthest); `rim` as
    `StateLimit`'s, a share of L.
    """

    raw: dict[str, Array]
    group: str = eqx.field(static=True)
    states: tuple[str, ...] = eqx.field(static=True)
    rim: float = eqx.field(static=True)
    place: ClassVar[str] = "inside"
    role: ClassVar[str] = "limit"
    n_screened: ClassVar[int] = 2
    from_rest: ClassVar[bool] = True  # ±L about where each state rests

    def __init__(self, group: str = "x", states=None, rim: float = RIM_WIDTH, **values):
        if not isinstance(group, str) or not group.isidentifier():
            raise InputError(f"StateWindow needs a name for its states (an identifier), got {group!r}")
        states = (group,) if states is None else states
        if (
            isinstance(states, str)
            or not all(isinstance(s, str) and s.isidentifier() for s in states)
            or not states
        ):
            raise InputError(
                f"StateWindow({group!r}): states must be a sequence of the states' names (identifiers), "
                f"got {states!r}"
            )
        self.group, self.states = group, tuple(states)
        self.rim = _checked_rim(rim, f"StateWindow({group!r})", "the half-width")
        init_values(self, values)

    @property
    def name(self) -> str:  # type: ignore[override]
        return f"window_{self.group}"

    @property
    def acts_on(self) -> str:  # type: ignore[override]
        return self.states[0]

    @property
    def bounded_states(self) -> tuple[str, ...]:
        return self.states

    @property
    def constraints(self) -> dict:  # type: ignore[override]
        return {f"{self.group}_window": Positive()}

    @property
    def units(self) -> dict:  # type: ignore[override]
        return {f"{self.group}_window": "{signal}"}

    @property
    def defaults(self) -> dict:  # type: ignore[override]
        return {f"{self.group}_window": 1.0}

    @property
    def thresholds(self) -> dict:  # type: ignore[override]
        return {"cut_percent_of_range": 3.0}

    def config(self) -> dict:
        return {"group": self.group, "states": list(self.states), "rim": self.rim}

    def _half_width(self):
        return self.parameters()[f"{self.group}_window"]

    def apply(self, z, dt, origin=0.0):
        half = self._half_width()
        width = self.rim * half + 1e-12
        top, bottom = origin + half, origin - half
        below = top - width * jax.nn.softplus((top - z) / width)
        return bottom + width * jax.nn.softplus((below - bottom) / width)

    def derived(self, z, dt, origin: float = 0.0):
        half = float(self._half_width())
        z = np.asarray(z, float)
        near = np.abs(z - origin) >= half - 2.0 * self.rim * half
        return {"level": half, "at_limit_percent": 100.0 * float(np.mean(near)) if z.size else 0.0}

    def starts(self, context):
        # Nine tenths, seven tenths and half of the first state's largest swing from where it starts.
        z = np.asarray(context.signal, float)
        swing = signal_top(z - z[0]) if z.size else 1.0
        return [{f"{self.group}_window": f * swing} for f in (0.9, 0.7, 0.5)]

    def screened_starts(self, context):
        from ._starts import limit_starts

        # ± a share of its states' largest swing from where they rest
        level = f"{self.group}_window"
        return limit_starts(
            context.problem, context.simulation, self, level, self.n_screened, context.frozen, swing=True
        )

    def unpinned_reason(self, name, signal):
        z = np.asarray(signal, float)
        half = float(self._half_width())
        if z.size and np.max(np.abs(z - z[0])) < half - 2.0 * self.rim * half:
            return "the states never reach the window in this recording"
        return None

    def reading(self, parameters, output_unit):
        many = len(self.states) > 1
        which = (
            f"the {len(self.states)} states {self.states[0]} … {self.states[-1]}"
            if many
            else f"the state {self.states[0]}"
        )
        return (
            f"a limit of either sign on {which} inside the dynamics, the same ±{self.group}_window about rest"
            + (" on each" if many else "")
            + ": on the double-layer voltages of an electrode, the electrolyte's electrochemical window "
            "(past it a Faradaic current flows and the double layer charges no further); on an integrator, "
            "its saturation"
        )

    def material(self, derived, parameters, thresholds):
        # ``cut_percent_of_range`` comes from the stack, both ends (`cut`)
        return _cut_material("window", self.acts_on, derived, thresholds)


def _checked_rim(rim, owner: str, of: str) -> float:
    """A limit's `rim` as a float, or an InputError: a share of `of`, between 0 and 1."""
    if isinstance(rim, bool) or not isinstance(rim, int | float) or not 0.0 < rim < 1.0:
        raise InputError(
            f"{owner}: rim is the rim's width as a share of {of}, a number between 0 and 1 "
            f"(default {RIM_WIDTH}), got {rim!r}"
        )
    return float(rim)


def _cut_material(what: str, state: str, derived: dict, thresholds: dict) -> tuple[bool, str]:
    """A limit's materiality: how far it cuts the range of `state` (``cut_percent_of_range``, from the stack)."""
    size, need = derived.get("cut_percent_of_range", 0.0), thresholds["cut_percent_of_range"]
    at = derived.get("at_limit_percent", 0.0)
    return size >= need, (
        f"the {what} cuts {size:.1f} % off the range of state {state}, which sits at it {at:.1f} % of the time "
        f"(needs a cut ≥ {need} %)"
    )


class Friction(AbstractEffect):
    """A Coulomb friction F·tanh(v/v_s) on the state v (a velocity), fed back against the drive.

    F is in the drive's unit (the force the simulation's drive exerts, its
    `force_unit` where a plug-in says one), v_s in the state's. ``derived``'s
    ``sticking_percent`` is the share of the record the state spends within
    ±v_s, where the force is less than F·tanh(1) (76 % of F); the stack adds
    ``force_percent_of_drive``.
    """

    raw: dict[str, Array]
    state: str = eqx.field(static=True)
    place: ClassVar[str] = "inside"
    role: ClassVar[str] = "feedback"

    def __init__(self, state: str = "velocity", **values):
        if not isinstance(state, str) or not state.isidentifier():
            raise InputError(f"Friction needs a state's name (an identifier), got {state!r}")
        self.state = state
        init_values(self, values)

    # The facts depend on the state: properties, not class constants (as `StateLimit`'s).
    @property
    def name(self) -> str:  # type: ignore[override]
        return f"friction_{self.state}"

    @property
    def acts_on(self) -> str:  # type: ignore[override]
        return self.state

    @property
    def constraints(self) -> dict:  # type: ignore[override]
        return {f"{self.state}_friction": Positive(), f"{self.state}_stick_speed": Positive()}

    @property
    def units(self) -> dict:  # type: ignore[override]
        return {f"{self.state}_friction": "{drive}", f"{self.state}_stick_speed": "{signal}"}

    @property
    def defaults(self) -> dict:  # type: ignore[override]
        return {f"{self.state}_friction": 0.01, f"{self.state}_stick_speed": 0.01}

    @property
    def thresholds(self) -> dict:  # type: ignore[override]
        return {"force_percent_of_drive": 3.0}

    def config(self) -> dict:
        return {"state": self.state}

    def apply(self, v, dt):
        p = self.parameters()
        return p[f"{self.state}_friction"] * jnp.tanh(v / p[f"{self.state}_stick_speed"])

    def derived(self, v, dt):
        v = np.asarray(v, float)
        stick = float(self.parameters()[f"{self.state}_stick_speed"])
        return {"sticking_percent": 100.0 * float(np.mean(np.abs(v) < stick)) if v.size else 0.0}

    def starts(self, context):
        # A force of 5 % and of 20 % of the largest drive, sticking below 5 % of the state's largest |v|:
        # a friction that a fit without it took up in its damping is of the first size, one that stops
        # the motion at small drives of the second.
        drive = context.drive if context.drive is not None else context.signal
        force, speed = signal_top(drive), 0.05 * signal_top(context.signal)
        return [
            {f"{self.state}_friction": 0.05 * force, f"{self.state}_stick_speed": speed},
            {f"{self.state}_friction": 0.2 * force, f"{self.state}_stick_speed": speed},
        ]

    def unpinned_reason(self, name, signal):
        # The width of the turn is seen only on samples inside it: a record that starts at rest has
        # one there (its first), which does not set it; a velocity that crosses zero between samples
        # at speeds far above the stick speed leaves the turn a step, whatever its width.
        v = np.asarray(signal, float)
        if name != f"{self.state}_stick_speed" or not v.size:
            return None
        inside = int(np.sum(np.abs(v) < 2.0 * float(self.parameters()[name])))
        if inside < 3:
            return (
                f"the state {self.state} is near zero, where the friction turns, on {inside} of its "
                f"{v.size} samples: it crosses zero faster than the recording resolves the turn"
            )
        return None

    def reading(self, parameters, output_unit):
        return (
            f"a dry (Coulomb) friction against the motion of the state {self.state}: a force of nearly "
            "constant size that opposes its sign (a bearing, a slide, a brush), in the unit of the force the "
            "drive exerts (the drive's, or the simulation's force_unit, as its value is printed); "
            "the viscous part is the simulation's own damping"
        )

    def material(self, derived, parameters, thresholds):
        size, need = derived.get("force_percent_of_drive", 0.0), thresholds["force_percent_of_drive"]
        return size >= need, f"friction {shown(size, need)} % of the largest drive (needs ≥ {need} %)"
