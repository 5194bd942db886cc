"""Variance-based (Sobol) first-order and total indices of a whole output series, by `vmap`-ed sampling."""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..core._models import Model
from ..util._errors import InputError
from ._views import free_names, free_theta, named_parameters, ordered_names, physical_map


@dataclasses.dataclass(frozen=True)
class SobolIndices:
    """Variance-based sensitivity of the whole output series.

    Each free parameter's unconstrained value is drawn uniformly within
    ±`spread` of its nominal value (log θ ± spread for positive parameters).
    For every sample time t, Saltelli's (2010) estimator gives the first-order
    variance V_j(t) and Jansen's the total V_Tj(t); the indices are aggregated
    over time, weighted by the output's variance (Gamboa et al. 2013):
    S_j = Σ_t V_j(t) / Σ_t V(t).

    **Fields:** `names`, `first_order` and `total` (dicts name → index),
    `n_base` (N), `n_evaluations` (N(k + 2)), `spread`.
    """

    names: tuple[str, ...]
    first_order: dict[str, float]
    total: dict[str, float]
    n_base: int
    n_evaluations: int
    spread: float

    def to_dict(self):
        return dataclasses.asdict(self)


def sobol_indices(
    target,
    v_in,
    dt: float,
    *,
    spread: float = 0.5,
    n_base: int = 256,
    seed: int = 0,
    frozen=frozenset(),
    batch_size: int = 16,
) -> SobolIndices:
    """Sobol first-order and total indices of the output series, by `vmap`-ed sampling.

    **Arguments:**

    - `target`: an [`AbstractSimulation`][] or a [`Model`][] (as for
      [`local_sensitivities`][]).
    - `v_in`, `dt`: the drive (V) and its sample interval (s).
    - `spread`: half-width of the uniform distribution of each unconstrained
      value around its nominal value (0.5: a factor 0.61–1.65 for a positive
      parameter).
    - `n_base`: N, base samples; the output is evaluated N(k + 2) times.
    - `seed`: seeds the samples.
    - `frozen`: parameters kept at their nominal values.
    - `batch_size`: evaluations `vmap`-ed together (`lax.map` over batches
      keeps memory at batch_size × T).
    """
    if not (isinstance(n_base, int) and n_base >= 2):
        raise InputError(f"n_base must be an integer ≥ 2, got {n_base!r}")
    if not (np.isfinite(spread) and spread > 0):
        raise InputError(f"spread must be a positive number, got {spread!r}")
    v_in = jnp.asarray(v_in)
    named_parameters(target)  # refuses a target that is neither a Model nor a simulation
    theta, view = free_theta(target, frozen)
    if theta.size == 0:
        raise InputError("no free named parameters to sample")
    all_names = ordered_names(target)
    D = np.asarray(physical_map(view, theta, all_names))
    names, rows = free_names(D, all_names)
    if len(names) != theta.size:
        raise InputError("Sobol sampling needs one raw value per named parameter")
    # column order of θ ↔ name: the named parameter whose row of D is non-zero there
    order = [names[int(np.argmax(np.abs(D[rows][:, j])))] for j in range(theta.size)]
    k = theta.size
    key_a, key_b = jax.random.split(jax.random.key(seed))
    A = theta + spread * jax.random.uniform(key_a, (n_base, k), theta.dtype, -1.0, 1.0)
    B = theta + spread * jax.random.uniform(key_b, (n_base, k), theta.dtype, -1.0, 1.0)
    AB = jnp.stack([A.at[:, j].set(B[:, j]) for j in range(k)])  # (k, N, k)
    samples = jnp.concatenate([A, B, AB.reshape(k * n_base, k)])
    model_output = isinstance(target, Model)
    Y = _evaluate_many(view, samples, v_in, float(dt), model_output, batch_size)
    fA, fB, fAB = Y[:n_base], Y[n_base : 2 * n_base], Y[2 * n_base :].reshape(k, n_base, -1)
    variance = jnp.var(jnp.concatenate([fA, fB]), axis=0)
    first = jnp.mean(fB * (fAB - fA), axis=1)  # Saltelli 2010
    total = 0.5 * jnp.mean((fA - fAB) ** 2, axis=1)  # Jansen 1999
    denominator = jnp.maximum(jnp.sum(variance), jnp.finfo(variance.dtype).tiny)
    S1 = dict(zip(order, map(float, np.asarray(jnp.sum(first, axis=1) / denominator))))
    ST = dict(zip(order, map(float, np.asarray(jnp.sum(total, axis=1) / denominator))))
    return SobolIndices(
        names=tuple(names),
        first_order={n: S1[n] for n in names},
        total={n: ST[n] for n in names},
        n_base=n_base,
        n_evaluations=int(samples.shape[0]),
        spread=float(spread),
    )


@eqx.filter_jit
def _evaluate_many(view, samples, v_in, dt, model_output, batch_size):
    def one(th):
        target = view.rebuild(th)
        return target.predict(v_in, dt) if model_output else target.simulate(v_in, dt)

    return jax.lax.map(one, samples, batch_size=batch_size)
