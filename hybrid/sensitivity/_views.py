"""Parameter views: a target's free unconstrained values θ and the map to its named, physical parameters.

The shared machinery of the sensitivity room: which values the fitter moves,
how to rebuild the target from them, and D = ∂θ_phys/∂θ_raw (the delta method).
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from ..core._models import Model
from ..core._simulation import AbstractSimulation
from ..util._errors import InputError


class _View(eqx.Module):
    """The free unconstrained values θ of a target, and how to put them back."""

    static: Any
    unravel: Any = eqx.field(static=True)

    def rebuild(self, theta):
        return eqx.combine(self.unravel(theta), self.static)


def free_theta(target, frozen=frozenset()):
    """θ (free raw values, flattened) and a `_View` for a simulation or a model.

    A model's black-box readout weights (``"network"``) are always left out:
    sensitivities are with respect to named parameters only.
    """
    frozen = frozenset(frozen)
    if isinstance(target, Model):
        spec = target.trainable(frozen | ({"network"} if "network" in target.parameter_names else set()))
    elif isinstance(target, AbstractSimulation):
        unknown = frozen - set(target.parameters())
        if unknown:
            raise InputError(
                f"cannot freeze {sorted(unknown)}: the parameters are {sorted(target.parameters())}"
            )
        spec = target.trainable(frozen)
    else:
        raise InputError(f"sensitivities need an AbstractSimulation or a Model, got {type(target).__name__}")
    dynamic, static = eqx.partition(target, spec)
    theta, unravel = ravel_pytree(dynamic)
    return theta, _View(static, unravel)


def named_parameters(target) -> dict[str, jax.Array]:
    if not isinstance(target, (Model, AbstractSimulation)):
        raise InputError(f"sensitivities need an AbstractSimulation or a Model, got {type(target).__name__}")
    values = target.parameters()
    for name, value in values.items():
        if jnp.ndim(value) != 0:
            raise InputError(
                f"parameter {name} is not a scalar (shape {jnp.shape(value)}): "
                "sensitivities are per scalar parameter"
            )
    return values


def physical_map(view, theta, names):
    """D = ∂θ_phys/∂θ_raw (k_named × n_raw) by forward mode (the reparameterisation's derivative)."""

    def physical(th):
        values = view.rebuild(th).parameters()
        return jnp.stack([jnp.asarray(values[n], th.dtype) for n in names])

    return jax.jacfwd(physical)(theta)


def free_names(D, names, tol=0.0):
    """Named parameters that depend on θ (rows of D that are not all zero)."""
    rows = np.flatnonzero(np.any(np.abs(np.asarray(D)) > tol, axis=1))
    return [names[i] for i in rows], rows


def ordered_names(target) -> list[str]:
    """Parameter names in their class's declaration order (pytree operations sort dict keys)."""
    names = list(named_parameters(target))
    parts = (target.simulation, target.readout) if isinstance(target, Model) else (target,)
    declared = [n for part in parts for n in getattr(part, "constraints", {})]
    rank = {n: i for i, n in enumerate(declared)}
    return sorted(names, key=lambda n: (rank.get(n, len(rank)), names.index(n)))


def raw_to_physical_columns(J_raw, D):
    """∂y/∂θ_phys from ∂y/∂θ_raw when D (named × raw) is square and invertible."""
    D = np.asarray(D)
    if D.shape[0] != D.shape[1]:
        raise InputError(
            f"{D.shape[0]} named parameter(s) depend on {D.shape[1]} free raw value(s): "
            "sensitivities need one raw value per named parameter"
        )
    if np.linalg.cond(D) > 1e12:
        raise InputError(
            "the map from raw to physical parameters is singular at this point "
            "(a parameter at the edge of its range?)"
        )
    return np.linalg.solve(D.T, np.asarray(J_raw).T).T
