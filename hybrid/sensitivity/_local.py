"""Local sensitivities: ∂y(t)/∂θ by forward mode, and ∂ log H(j2πf)/∂ log θ in the frequency domain."""

from __future__ import annotations

import dataclasses
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..core._models import Model
from ..core._simulation import unit_in
from ..util._errors import InputError, PluginError
from ._identifiability import Identifiability, identifiability
from ._views import (
    free_names,
    free_theta,
    named_parameters,
    ordered_names,
    physical_map,
    raw_to_physical_columns,
)


@dataclasses.dataclass(frozen=True)
class Sensitivity:
    """Local sensitivities of an output series to the named parameters.

    **Fields:**

    - `names`: the free named parameters, in column order.
    - `values`: their physical values (units in `units`).
    - `units`: unit of each parameter.
    - `dt`: sample interval of the drive, s.
    - `output`: y(t), the output series (V for a simulation's V_o; ŵ in w's unit for a model).
    - `output_unit`: its unit (the simulation's `output_unit`, or the model's w unit; ``""`` if unknown).
    - `jacobian`: (T, k) array, ∂y(t)/∂θ_j in output units per parameter unit.
    - `scales`: s_j, the change of each parameter a unit of the scaled
      coordinates stands for ([`parameter_scales`][hybrid.sensitivity.parameter_scales]):
      |θ_j|, or for θ_j = 0 a typical magnitude.
    """

    names: tuple[str, ...]
    values: dict[str, float]
    units: dict[str, str]
    dt: float
    output: np.ndarray
    output_unit: str
    jacobian: np.ndarray
    scales: dict[str, float]

    @property
    def time(self) -> np.ndarray:
        return np.arange(self.output.shape[0]) * self.dt

    @property
    def output_rms(self) -> float:
        return float(np.sqrt(np.mean(self.output**2)))

    def normalised(self) -> np.ndarray:
        """(T, k): s_j ∂y(t)/∂θ_j / rms(y), the change of y, in units of its rms, per change s_j of θ_j.

        s_j = |θ_j| (`scales`) makes it the change per relative change of θ_j
        (∂y/∂ log θ_j / rms y, up to the sign of θ_j); a parameter at 0 is scaled by a
        typical magnitude instead, so that it is not a null direction merely for being 0.
        """
        s = np.array([self.scales[n] for n in self.names])
        return self.jacobian * s / max(self.output_rms, np.finfo(float).tiny)

    def rms_normalised(self) -> dict[str, float]:
        """rms over time of each column of `normalised()`: one number per parameter."""
        s = np.sqrt(np.mean(self.normalised() ** 2, axis=0))
        return dict(zip(self.names, map(float, s)))

    def identifiability(self, **tolerances) -> Identifiability:
        """[`identifiability`][] of the normalised sensitivities (scaled coordinates: log θ_j where θ_j ≠ 0)."""
        return identifiability(self.normalised() / np.sqrt(self.output.shape[0]), self.names, **tolerances)


@eqx.filter_jit
def _jacobian(view, theta, v_in, dt, model_output):
    def output(th):
        target = view.rebuild(th)
        return target.predict(v_in, dt) if model_output else target.simulate(v_in, dt)

    return output(theta), jax.jacfwd(output)(theta)


def local_sensitivities(target, v_in, dt: float, *, frozen=frozenset()) -> Sensitivity:
    """∂y(t)/∂θ for every free named parameter θ of `target`, by forward mode.

    **Arguments:**

    - `target`: an [`AbstractSimulation`][] (y = its mediatory signal over the
      drive, e.g. V_o of the RC network, Eqs 4–14) or a [`Model`][] (y = ŵ over
      the whole drive; a D-MLP's weights are held fixed).
    - `v_in`: the drive voltage (V), shape (T,).
    - `dt`: its sample interval (s).
    - `frozen`: names of parameters to leave out.

    **Returns:** a [`Sensitivity`][]. The derivative is taken by `jax.jacfwd`
    (one tangent per unconstrained parameter, pushed through the simulation's
    `lax.scan`) and mapped to physical units through the reparameterisation.
    """
    v_in = jnp.asarray(v_in)
    if v_in.ndim != 1 or v_in.shape[0] < 2:
        raise InputError(f"the drive must be a 1-D series of at least 2 samples, got shape {v_in.shape}")
    if not np.all(np.isfinite(np.asarray(v_in))):
        raise InputError("the drive contains NaN or infinite values")
    if not (np.isfinite(dt) and dt > 0):
        raise InputError(f"the sample interval dt must be a positive number of seconds, got {dt!r}")
    named = named_parameters(target)
    theta, view = free_theta(target, frozen)
    if theta.size == 0:
        raise InputError("no free named parameters: nothing to take sensitivities to")
    all_names = ordered_names(target)
    D = physical_map(view, theta, all_names)
    names, rows = free_names(D, all_names)
    model_output = isinstance(target, Model)
    y, J_raw = _jacobian(view, theta, v_in, float(dt), model_output)
    _require_finite(target, named, np.asarray(y), np.asarray(J_raw))
    J = raw_to_physical_columns(J_raw, np.asarray(D)[rows])
    units = target.units if isinstance(target, Model) else _simulation_units(target)
    values = {n: float(named[n]) for n in names}
    return Sensitivity(
        names=tuple(names),
        values=values,
        units={n: units.get(n, "") for n in names},
        dt=float(dt),
        output=np.asarray(y),
        output_unit=target.signal_units[0] if model_output else unit_in(getattr(target, "output_unit", "")),
        jacobian=J,
        scales=parameter_scales(target, values, np.asarray(y), J),
    )


def _require_finite(target, named: dict, y: np.ndarray, J: np.ndarray) -> None:
    """Refuse, in one line, an output or a derivative that is not finite (NaN or inf) at the values given.

    A probe's plug-in that returns NaN beyond a time constant of 5 s gave, at 6 s, an output NaN at
    every sample and a Jacobian of zeros without a word: every sensitivity read 0.
    """
    if np.all(np.isfinite(y)) and np.all(np.isfinite(J)):
        return
    simulation = target.simulation if isinstance(target, Model) else target
    bad = int(np.sum(~np.isfinite(y)))
    what = (
        f"its output is not finite (NaN or inf) at {bad} of {y.size} samples"
        if bad
        else "its derivative is not finite (NaN or inf) while its output is"
    )
    at = ", ".join(f"{name}={float(value):.4g}" for name, value in named.items())
    raise PluginError(
        f"{type(simulation).__name__} at {at}: {what} for this drive, so no sensitivity can be read: give "
        "parameter values where it is finite (--param NAME=VALUE), or make its simulate finite there",
        plugin=type(simulation),
    )


def parameter_scales(target, values: dict[str, float], output, jacobian) -> dict[str, float]:
    """s_j, the scale of each parameter in the scaled coordinates of the identifiability SVD.

    s_j = |θ_j| where θ_j ≠ 0 (log coordinates). A parameter at 0 (a residue, a
    feedthrough, a readout's offset) has no relative change: its scale is then the
    half-width of its typical range (`AbstractSimulation.typical_ranges`), and for one
    without a range the change that moves y by its rms, rms(y)/rms(∂y/∂θ_j) (1 if y does
    not depend on it: it stays a null direction).

    **Arguments:** the `target` whose parameters `values` (physical, by name, in the
    columns' order) are; its `output` y (T,) and `jacobian` ∂y/∂θ (T, k).
    """
    simulation = target.simulation if isinstance(target, Model) else target
    typical = simulation.typical_ranges()
    J = np.asarray(jacobian, dtype=float)
    y_rms = float(np.sqrt(np.mean(np.asarray(output, dtype=float) ** 2)))
    out = {}
    for j, (name, value) in enumerate(values.items()):
        low, high = typical.get(name, (np.nan, np.nan))
        width = 0.5 * (float(high) - float(low))
        column_rms = float(np.sqrt(np.mean(J[:, j] ** 2)))
        if value != 0:
            out[name] = abs(value)
        elif np.isfinite(width) and width > 0:
            out[name] = width
        elif column_rms > 0 and y_rms > 0:
            out[name] = y_rms / column_rms
        else:
            out[name] = 1.0
    return out


def _simulation_units(simulation) -> dict[str, str]:
    """The simulation's units, a drive's level in V (the unit `simulate`'s drive is in)."""
    return {k: unit_in(v) for k, v in getattr(simulation, "units", {}).items()}


# --------------------------------------------------------------------------- frequency domain
def frequency_sensitivity(simulation, frequency, *, frozen=frozenset()) -> dict[str, Any]:
    """∂ log|H(j2πf)|/∂ log θ and ∂∠H(j2πf)/∂ log θ (rad) of a linear simulation.

    For a simulation with `frequency_response(frequency_hz)` (the RC network's
    Eq 14). Returns ``{"frequency": (F,), "names": [...], "magnitude": (F, k),
    "phase": (F, k)}``: the relative change of the gain, and the change of the
    phase, per relative change of each parameter.
    """
    if not hasattr(simulation, "frequency_response"):
        raise InputError(f"{type(simulation).__name__} has no frequency_response")
    f = jnp.asarray(frequency, dtype=float)
    named = named_parameters(simulation)
    theta, view = free_theta(simulation, frozen)
    all_names = ordered_names(simulation)
    D = physical_map(view, theta, all_names)
    names, rows = free_names(D, all_names)

    def log_h(th):
        H = view.rebuild(th).frequency_response(f)
        return jnp.concatenate([jnp.log(jnp.abs(H)), jnp.unwrap(jnp.angle(H))])

    J = raw_to_physical_columns(eqx.filter_jit(jax.jacfwd(log_h))(theta), np.asarray(D)[rows])
    J = J * np.array([float(named[n]) for n in names])
    F = f.shape[0]
    return {"frequency": np.asarray(f), "names": names, "magnitude": J[:F], "phase": J[F:]}
