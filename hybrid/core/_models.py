"""Models = a physics simulation followed by a readout (paper Fig. 2).

- Hybrid: V_i → simulation → V_o → window → D-MLP → ŵ  (the paper's proposal)
- Normal: V_i → window → D-MLP → ŵ                      (the paper's baseline)
- Physics: V_i → simulation → V_o → gain · V_o + offset  (the simulation alone)

The paper's simulation is its RC network (Eqs 4–14); `hybrid.make_model`
supplies it by default (`hybrid.ipmc`), this module takes any.

All are non-autoregressive: the measured displacement is never an input.
The simulation runs over the whole drive of a recording (the drive is known at
all times and carries no target information); the readout's windows are formed
inside each segment (see [`hybrid.core._windows`][]).
"""

from __future__ import annotations

from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ..util._errors import InputError
from ._arguments import check_key, check_simulation, simulated
from ._readout import AbstractReadout, LinearReadout, WindowedMLP
from ._simulation import AbstractSimulation, Passthrough, unit_in

ModelKind = Literal["hybrid", "normal", "physics"]
MODEL_KINDS = ("hybrid", "normal", "physics")


class Model(eqx.Module):
    """A simulation and a readout, fitted together.

    **Arguments:**

    - `simulation`: the physics part (an [`AbstractSimulation`][]).
    - `readout`: the per-sample map to w (an [`AbstractReadout`][]).
    - `kind`: a label (``"hybrid"``, ``"normal"``, ``"physics"`` or your own).
    - `signal_units`: (w's unit, the drive's unit) that `units` labels the parameters in; `fit`
      and `diagnose` set those of the recordings (the paper's mm and V by default).
    """

    simulation: AbstractSimulation
    readout: AbstractReadout
    kind: str = eqx.field(static=True, default="custom")
    signal_units: tuple[str, str] = eqx.field(static=True, default=("mm", "V"))

    def mediatory(self, v_in: Float[Array, " time"], dt: float) -> Float[Array, " time"]:
        """The mediatory signal (V_o for the RC network) over the whole drive."""
        return simulated(self.simulation, v_in, dt)

    def predict(self, v_in, dt, segments=None) -> Float[Array, " samples"]:
        """ŵ (mm) for each `(start, stop)` segment (default: the whole drive)."""
        v_in = jnp.asarray(v_in)
        if segments is None:
            segments = ((0, v_in.shape[0]),)
        return self.readout(self.mediatory(v_in, dt), segments)

    def parameters(self) -> dict[str, Array]:
        """Interpretable parameters by name, physical units (see `units`)."""
        return {**self.simulation.parameters(), **self.readout.parameters()}

    @property
    def units(self) -> dict[str, str]:
        """Each named parameter's unit, for w and the drive in `signal_units` (see `units_in`)."""
        return self.units_in(*self.signal_units)

    def units_in(self, w_unit: str, drive_unit: str = "V") -> dict[str, str]:
        """Each named parameter's unit for w in `w_unit` and the drive in `drive_unit`.

        The readout's follow the simulation's `output_unit` (a linear readout's
        gain: w's unit per the output's); ``"{drive}"`` in any unit is the drive's.
        """
        signal = unit_in(str(getattr(self.simulation, "output_unit", "") or ""), drive_unit)
        return {**self.simulation.units_in(drive_unit), **self.readout.units_for(signal, w_unit)}

    @property
    def parameter_names(self) -> tuple[str, ...]:
        names = self.simulation.parameter_names() + tuple(getattr(self.readout, "raw", {}))
        if isinstance(self.readout, WindowedMLP):
            names += ("network",)
        return names

    def trainable(self, frozen=frozenset()) -> Model:
        """Filter spec (bools, same structure) of the free leaves; `frozen` names stay fixed."""
        frozen = frozenset(frozen)
        unknown = frozen - set(self.parameter_names)
        if unknown:
            raise InputError(
                f"cannot freeze {sorted(unknown)}: this {self.kind} model's parameters are "
                f"{list(self.parameter_names)}"
            )
        return Model(
            self.simulation.trainable(frozen), self.readout.trainable(frozen), self.kind, self.signal_units
        )


def make_model(
    kind: ModelKind = "hybrid",
    *,
    simulation: AbstractSimulation | None = None,
    window: int = 60,
    depth: int = 11,
    width: int = 10,
    key=None,
) -> Model:
    """The paper's Hybrid or Normal model, or the physics-only simulation, for any physics.

    **Arguments:**

    - `kind`: ``"hybrid"`` (simulation + D-MLP), ``"normal"`` (D-MLP on V_i) or
      ``"physics"`` (simulation + linear gain and offset).
    - `simulation`: the physics part, needed for hybrid and physics (an
      [`AbstractSimulation`][]; `hybrid.make_model` defaults it to the paper's
      RC network and takes a ``--physics`` spec such as ``"lti:2"`` too).
    - `window`, `depth`, `width`: D-MLP shape (paper: 60, 11, 10).
    - `key`: PRNG key for the D-MLP weights (default `jax.random.key(0)`).
    """
    if not isinstance(kind, str) or kind not in MODEL_KINDS:
        raise InputError(f"model must be one of {', '.join(MODEL_KINDS)}, got {kind!r}")
    check_simulation(simulation, "make_model")
    check_key(key, "make_model")
    if key is None:
        key = jax.random.key(0)
    if kind == "normal":
        return Model(Passthrough(), WindowedMLP(window, depth, width, key=key), "normal")
    if simulation is None:
        raise InputError(
            f"make_model({kind!r}) needs a simulation: pass simulation=hybrid.RCNetwork() (the paper's "
            "physics) or any AbstractSimulation, or use hybrid.make_model, which defaults to the RC network"
        )
    if kind == "physics":
        return Model(simulation, LinearReadout(), "physics")
    return Model(simulation, WindowedMLP(window, depth, width, key=key), "hybrid")
