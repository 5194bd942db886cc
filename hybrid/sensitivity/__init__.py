"""Gradient-based sensitivity, identifiability and parameter uncertainty.

Everything here works on the interfaces, not on the RC network by name: a
target is an [`AbstractSimulation`][] (output: its mediatory signal, V_o for
the RC network of Eqs 4–14) or a [`Model`][] (output: the prediction ŵ, mm).
Its named parameters are whatever `target.parameters()` returns; derivatives
are taken with respect to the unconstrained values the fitter moves and mapped
to physical units by the chain rule (the delta method), so any reparameterisation
([`hybrid.Positive`][], [`hybrid.UnitInterval`][], …) is handled.

- [`local_sensitivities`][]: ∂y(t)/∂θ_j by forward mode (`jax.jacfwd`)
  through the simulation's scan; `normalised()` gives θ_j ∂y/∂θ_j / rms(y).
- [`identifiability`][]: the SVD of the normalised sensitivity matrix. Its
  (near-)zero singular values name the parameter combinations the output
  cannot fix; the cosine between two columns flags near-collinear pairs.
- [`parameter_covariance`][] / [`standard_errors`][]: after a fit, the Fisher
  information, the covariance and the standard errors of the named parameters
  in physical units (network weights, if any, are nuisance parameters and are
  marginalised out), as `scipy.optimize.curve_fit` computes them.
- [`frequency_sensitivity`][]: ∂ log|H(j2πf)|/∂ log θ and ∂∠H/∂ log θ for
  simulations with a `frequency_response` (Eq 14).
- [`sobol_indices`][]: variance-based (Sobol) first-order and total indices of
  the whole output series, by `vmap`-ed sampling.

Float64 is needed for meaningful small singular values: call
``jax.config.update("jax_enable_x64", True)`` in your entry point.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from ..util._errors import InputError
from ..core._models import Model
from ..core._simulation import AbstractSimulation

__all__ = [
    "Covariance",
    "Identifiability",
    "Sensitivity",
    "SobolIndices",
    "frequency_sensitivity",
    "identifiability",
    "local_sensitivities",
    "parameter_covariance",
    "sobol_indices",
    "standard_errors",
]


# --------------------------------------------------------------------------- parameter views
class _View(eqx.Module):
    """The free unconstrained values θ of a target, and how to put them back."""

    static: Any
    unravel: Any = eqx.field(static=True)

    def rebuild(self, theta):
        return eqx.combine(self.unravel(theta), self.static)


def _free_theta(target, frozen=frozenset()):
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
            raise InputError(f"cannot freeze {sorted(unknown)}: the parameters are {sorted(target.parameters())}")
        spec = target.trainable(frozen)
    else:
        raise InputError(
            f"sensitivities need an AbstractSimulation or a Model, got {type(target).__name__}"
        )
    dynamic, static = eqx.partition(target, spec)
    theta, unravel = ravel_pytree(dynamic)
    return theta, _View(static, unravel)


def _named(target) -> dict[str, jax.Array]:
    if not isinstance(target, (Model, AbstractSimulation)):
        raise InputError(
            f"sensitivities need an AbstractSimulation or a Model, got {type(target).__name__}"
        )
    values = target.parameters()
    for name, value in values.items():
        if jnp.ndim(value) != 0:
            raise InputError(f"parameter {name} is not a scalar (shape {jnp.shape(value)}): "
                             "sensitivities are per scalar parameter")
    return values


def _physical_map(view, theta, names):
    """D = ∂θ_phys/∂θ_raw (k_named × n_raw) by forward mode (the reparameterisation's derivative)."""
    def physical(th):
        values = view.rebuild(th).parameters()
        return jnp.stack([jnp.asarray(values[n], th.dtype) for n in names])

    return jax.jacfwd(physical)(theta)


def _free_names(D, names, tol=0.0):
    """Named parameters that depend on θ (rows of D that are not all zero)."""
    rows = np.flatnonzero(np.any(np.abs(np.asarray(D)) > tol, axis=1))
    return [names[i] for i in rows], rows


def _ordered_names(target) -> list[str]:
    """Parameter names in their class's declaration order (pytree operations sort dict keys)."""
    names = list(_named(target))
    parts = (target.simulation, target.readout) if isinstance(target, Model) else (target,)
    declared = [n for part in parts for n in getattr(type(part), "constraints", {})]
    rank = {n: i for i, n in enumerate(declared)}
    return sorted(names, key=lambda n: (rank.get(n, len(rank)), names.index(n)))


def _raw_to_physical_columns(J_raw, D):
    """∂y/∂θ_phys from ∂y/∂θ_raw when D (named × raw) is square and invertible."""
    D = np.asarray(D)
    if D.shape[0] != D.shape[1]:
        raise InputError(
            f"{D.shape[0]} named parameter(s) depend on {D.shape[1]} free raw value(s): "
            "sensitivities need one raw value per named parameter"
        )
    if np.linalg.cond(D) > 1e12:
        raise InputError("the map from raw to physical parameters is singular at this point "
                         "(a parameter at the edge of its range?)")
    return np.linalg.solve(D.T, np.asarray(J_raw).T).T


# --------------------------------------------------------------------------- local sensitivities
@dataclasses.dataclass(frozen=True)
class Sensitivity:
    """Local sensitivities of an output series to the named parameters.

    **Fields:**

    - `names`: the free named parameters, in column order.
    - `values`: their physical values (units in `units`).
    - `units`: unit of each parameter.
    - `dt`: sample interval of the drive, s.
    - `output`: y(t), the output series (V for a simulation's V_o, mm for ŵ).
    - `output_unit`: ``"V"``, ``"mm"`` or ``""``.
    - `jacobian`: (T, k) array, ∂y(t)/∂θ_j in output units per parameter unit.
    """

    names: tuple[str, ...]
    values: dict[str, float]
    units: dict[str, str]
    dt: float
    output: np.ndarray
    output_unit: str
    jacobian: np.ndarray

    @property
    def time(self) -> np.ndarray:
        return np.arange(self.output.shape[0]) * self.dt

    @property
    def output_rms(self) -> float:
        return float(np.sqrt(np.mean(self.output**2)))

    def normalised(self) -> np.ndarray:
        """(T, k): θ_j ∂y(t)/∂θ_j / rms(y), the change of y, in units of its rms,
        per relative change of θ_j (i.e. ∂y/∂ log θ_j / rms y)."""
        theta = np.array([self.values[n] for n in self.names])
        return self.jacobian * theta / max(self.output_rms, np.finfo(float).tiny)

    def rms_normalised(self) -> dict[str, float]:
        """rms over time of each column of `normalised()`: one number per parameter."""
        s = np.sqrt(np.mean(self.normalised() ** 2, axis=0))
        return dict(zip(self.names, map(float, s)))

    def identifiability(self, **tolerances) -> "Identifiability":
        """[`identifiability`][] of the normalised sensitivities (log-parameter coordinates)."""
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
    named = _named(target)
    theta, view = _free_theta(target, frozen)
    if theta.size == 0:
        raise InputError("no free named parameters: nothing to take sensitivities to")
    all_names = _ordered_names(target)
    D = _physical_map(view, theta, all_names)
    names, rows = _free_names(D, all_names)
    model_output = isinstance(target, Model)
    y, J_raw = _jacobian(view, theta, v_in, float(dt), model_output)
    J = _raw_to_physical_columns(J_raw, np.asarray(D)[rows])
    units = target.units if isinstance(target, Model) else _simulation_units(target)
    return Sensitivity(
        names=tuple(names),
        values={n: float(named[n]) for n in names},
        units={n: units.get(n, "") for n in names},
        dt=float(dt),
        output=np.asarray(y),
        output_unit="mm" if model_output else ("V" if _is_rc(target) else ""),
        jacobian=J,
    )


def _simulation_units(simulation) -> dict[str, str]:
    if hasattr(simulation, "parameter_units"):
        return dict(simulation.parameter_units())
    return dict(getattr(type(simulation), "units", {}))


def _is_rc(simulation) -> bool:
    return type(simulation).__name__ == "RCNetwork"


# --------------------------------------------------------------------------- identifiability
@dataclasses.dataclass(frozen=True)
class Identifiability:
    """What the SVD of a (normalised) sensitivity matrix S = U Σ Vᵀ says.

    **Fields:**

    - `names`: parameter of each column of S.
    - `singular_values`: σ_1 ≥ … ≥ σ_k of S; k values even when S has fewer
      rows m than columns k (σ_{m+1} … σ_k are then 0, their directions null).
    - `directions`: (k, k), row i is the right singular vector v_i, a
      combination of parameters (log-parameter coordinates for normalised S);
      its sign is chosen so that its first coefficient of magnitude ≥ 0.1 is positive.
    - `null_directions`: combinations with σ_i ≤ `null_tolerance` · σ_1 (the
      output does not change along them at all), as {name: coefficient}.
    - `near_null_directions`: those with σ_i ≤ `near_null_tolerance` · σ_1.
    - `cosines`: (k, k) cosine between columns (±1: the two parameters change y
      in the same way, up to scale).
    - `collinear_pairs`: (name_a, name_b, cosine) with |cosine| ≥ `collinearity`
      (exactly null pairs included), most collinear first.
    - `tolerances`: the three thresholds used.
    """

    names: tuple[str, ...]
    singular_values: np.ndarray
    directions: np.ndarray
    null_directions: list[dict[str, float]]
    near_null_directions: list[dict[str, float]]
    cosines: np.ndarray
    collinear_pairs: list[tuple[str, str, float]]
    tolerances: dict[str, float]

    def to_dict(self) -> dict[str, Any]:
        return {
            "names": list(self.names),
            "singular_values": [float(s) for s in self.singular_values],
            "relative_singular_values": [float(s / self.singular_values[0]) for s in self.singular_values],
            "null_directions": self.null_directions,
            "near_null_directions": self.near_null_directions,
            "directions": [dict(zip(self.names, map(float, v))) for v in self.directions],
            "collinear_pairs": [{"pair": [a, b], "cosine": c} for a, b, c in self.collinear_pairs],
            "cosines": {a: dict(zip(self.names, map(float, row))) for a, row in zip(self.names, self.cosines)},
            "tolerances": self.tolerances,
        }


def identifiability(
    matrix,
    names,
    *,
    null_tolerance: float = 1e-10,
    near_null_tolerance: float = 1e-2,
    collinearity: float = 0.99,
    keep: float = 0.01,
) -> Identifiability:
    """Name the (nearly) non-identifiable parameter combinations of a sensitivity matrix.

    **Arguments:**

    - `matrix`: (m, k) sensitivity matrix, one column per parameter, e.g.
      `Sensitivity.normalised()` (columns ∂y/∂ log θ_j) or a fit's Jacobian.
    - `names`: the k parameter names.
    - `null_tolerance`: σ_i/σ_1 at or below which a direction is called null.
      Float64 rounding puts an exact null at ~1e-15; the default leaves room.
    - `near_null_tolerance`: σ_i/σ_1 at or below which it is called near-null
      (a relative change of 1 % of the output's rms moves the parameters along
      it by ~1/σ_i: a factor e^1 for σ_i = 0.01).
    - `collinearity`: |cosine| between two columns at or above which the pair
      is flagged (Brun et al. 2001, Water Res. 35: for two parameters the
      collinearity index is 1/√(1 − |cos|), 10 at 0.99).
    - `keep`: coefficients below this magnitude are dropped from the named
      directions (they remain in `directions`).
    """
    S = np.asarray(matrix, dtype=float)
    names = tuple(names)
    if S.ndim != 2 or S.shape[1] != len(names):
        raise InputError(f"sensitivity matrix of shape {S.shape} does not match {len(names)} names")
    if not np.all(np.isfinite(S)):
        raise InputError("the sensitivity matrix has NaN or infinite entries")
    # Fewer rows than parameters: an economy SVD returns only m directions and never
    # shows the null space; the full one does, and the missing singular values are 0.
    _, sigma, Vt = np.linalg.svd(S, full_matrices=S.shape[0] < S.shape[1])
    sigma = np.concatenate([sigma, np.zeros(Vt.shape[0] - sigma.size)])
    if sigma.size == 0 or sigma[0] == 0:
        raise InputError("the output does not depend on any parameter (all sensitivities are zero)")
    Vt = np.array([_orient(v) for v in Vt])
    ratio = sigma / sigma[0]

    def named(v):
        return {n: float(c) for n, c in zip(names, v) if abs(c) >= keep}

    null = [named(v) for v, r in zip(Vt, ratio) if r <= null_tolerance]
    near = [named(v) for v, r in zip(Vt, ratio) if null_tolerance < r <= near_null_tolerance]
    norms = np.linalg.norm(S, axis=0)
    safe = np.where(norms > 0, norms, 1.0)
    cos = (S.T @ S) / np.outer(safe, safe)
    cos[norms == 0, :] = 0.0
    cos[:, norms == 0] = 0.0
    pairs = [
        (names[a], names[b], float(cos[a, b]))
        for a in range(len(names)) for b in range(a + 1, len(names))
        if abs(cos[a, b]) >= collinearity
    ]
    pairs.sort(key=lambda p: -abs(p[2]))
    return Identifiability(
        names=names, singular_values=sigma, directions=Vt, null_directions=null,
        near_null_directions=near, cosines=cos, collinear_pairs=pairs,
        tolerances={"null": null_tolerance, "near_null": near_null_tolerance,
                    "collinearity": collinearity, "keep": keep},
    )


def _orient(v):
    big = np.flatnonzero(np.abs(v) >= 0.1)
    first = big[0] if big.size else int(np.argmax(np.abs(v)))
    return v if v[first] >= 0 else -v


# --------------------------------------------------------------------------- covariance after a fit
@dataclasses.dataclass(frozen=True)
class Covariance:
    """Uncertainty of fitted named parameters, in physical units.

    With r = w − ŵ over the m fitted samples, J = ∂ŵ/∂θ (θ the free
    unconstrained values, network weights included), s² = ‖r‖²/(m − p) the
    residual variance (p the number of free values, or the effective number
    tr((JᵀJ + μP)⁻¹JᵀJ) under weight decay μ), the covariance of θ is
    s² (JᵀJ + μP)⁻¹ (the Gauss–Newton / Laplace approximation, as
    `scipy.optimize.curve_fit` with ``absolute_sigma=False`` for μ = 0), and
    that of the physical parameters θ_phys = g(θ) is D Cov_θ Dᵀ with
    D = ∂g/∂θ (the delta method).

    **Fields:**

    - `names`: the free named parameters.
    - `values`: their fitted values (physical units).
    - `units`: unit of each.
    - `matrix`: (k, k) covariance in physical units (unit_i · unit_j).
      Entries of a parameter that moves along a null direction of J are
      inf (variance) and nan (covariances).
    - `fisher`: (k, k) Fisher information of the named parameters (1/(unit_i unit_j)),
      J_physᵀJ_phys / s² with the network weights profiled out; finite even
      where the covariance is not.
    - `noise_variance`: s² (squared output units, mm² for ŵ).
    - `n_residuals`, `n_free`: m and the number of free raw values.
    - `dof`: m − p.
    - `unidentifiable`: names whose variance is infinite.
    """

    names: tuple[str, ...]
    values: dict[str, float]
    units: dict[str, str]
    matrix: np.ndarray
    fisher: np.ndarray
    noise_variance: float
    n_residuals: int
    n_free: int
    dof: float
    unidentifiable: tuple[str, ...]

    @property
    def std_errors(self) -> dict[str, float]:
        """Standard error of each parameter, physical units (inf if unidentifiable)."""
        return {n: float(np.sqrt(self.matrix[i, i])) for i, n in enumerate(self.names)}

    @property
    def relative_std_errors(self) -> dict[str, float]:
        """Standard error / |value|."""
        return {n: s / abs(self.values[n]) if self.values[n] else float("inf")
                for n, s in self.std_errors.items()}

    @property
    def correlation(self) -> np.ndarray:
        d = np.sqrt(np.diag(self.matrix))
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.matrix / np.outer(d, d)

    def to_dict(self) -> dict[str, Any]:
        def clean(x):
            x = float(x)
            return x if np.isfinite(x) else str(x)

        return {
            "names": list(self.names),
            "values": self.values,
            "units": self.units,
            "std_errors": {k: clean(v) for k, v in self.std_errors.items()},
            "relative_std_errors": {k: clean(v) for k, v in self.relative_std_errors.items()},
            "covariance": [[clean(x) for x in row] for row in self.matrix],
            "correlation": [[clean(x) for x in row] for row in self.correlation],
            "fisher": [[clean(x) for x in row] for row in self.fisher],
            "noise_variance": self.noise_variance,
            "n_residuals": self.n_residuals,
            "n_free": self.n_free,
            "dof": self.dof,
            "unidentifiable": list(self.unidentifiable),
        }


@eqx.filter_jit
def _fit_jacobian(problem, theta):
    r, J = problem.residuals_and_jacobian(theta)
    return r * problem.scale, J * problem.scale  # back to output units (mm)


def parameter_covariance(
    model: Model,
    recordings,
    *,
    frozen=frozenset(),
    split=(0.3, 0.5, 0.2),
    split_order=("train", "test", "validation"),
    blocks: int = 1,
    weight_decay: float = 0.0,
    noise_std: float | None = None,
    rcond: float = 1e-10,
) -> Covariance:
    """Fisher information, covariance and standard errors of a fitted model's named parameters.

    **Arguments:**

    - `model`: the fitted [`Model`][] (any simulation and readout).
    - `recordings`: the Recording(s) it was fitted to.
    - `frozen`, `split`, `split_order`, `blocks`, `weight_decay`: as given to
      [`hybrid.fit`][]; the covariance is that of the training-split fit.
    - `noise_std`: the known standard deviation of w's noise (mm); by default
      it is estimated from the residuals (s² = ‖r‖²/dof).
    - `rcond`: singular values of J below `rcond` · σ_max are null directions:
      parameters moving along them get an infinite variance.

    **Returns:** a [`Covariance`][].
    """
    from ..core._problem import Problem, series_from_recording

    recordings = list(recordings) if isinstance(recordings, (list, tuple)) else [recordings]
    if not recordings:
        raise InputError("no recordings: pass the recording(s) the model was fitted to")
    if not isinstance(model, Model):
        raise InputError(f"parameter_covariance needs a Model, got {type(model).__name__}")
    frozen = frozenset(frozen)
    series = [series_from_recording(r, split, split_order, blocks) for r in recordings]
    problem = Problem(model, series, frozen, weight_decay)
    theta = problem.flatten(model, frozen)
    r, J = (np.asarray(a) for a in _fit_jacobian(problem, theta))
    m, n = J.shape
    named = _named(model)
    all_names = _ordered_names(model)
    D = np.asarray(_physical_map(_ProblemView(problem), theta, all_names))
    names, rows = _free_names(D, all_names)
    D = D[rows]
    if not names:
        raise InputError("no free named parameters: everything named is frozen")

    # Regularised normal matrix (weight decay as ridge rows in units of the scaled residuals).
    mask = np.asarray(problem.penalty_mask(theta))
    mu = float(problem.weight_decay)
    scale2 = float(problem.scale) ** 2
    rows_penalty = np.sqrt(mu * scale2) * np.diag(mask)[mask > 0] if mu else np.zeros((0, n))
    A = np.concatenate([J, rows_penalty])
    _, sigma, Vt = np.linalg.svd(A, full_matrices=A.shape[0] < A.shape[1])  # all n directions
    sigma = np.concatenate([sigma, np.zeros(Vt.shape[0] - sigma.size)])      # (fewer rows: 0s)
    keep = sigma > rcond * sigma[0]
    V, inv_s2 = Vt[keep].T, 1.0 / sigma[keep] ** 2
    cov_unit = (V * inv_s2) @ V.T                       # (JᵀJ + μP)⁻¹ on the identifiable subspace
    if mu:
        JV = J @ V
        p_eff = float(np.sum(inv_s2 * np.sum(JV * JV, axis=0)))  # tr((JᵀJ+μP)⁻¹ JᵀJ)
    else:
        p_eff = float(np.sum(keep))
    dof = m - p_eff
    if noise_std is None:
        if dof <= 0:
            raise InputError(f"{m} residuals for {p_eff:.0f} free parameters: no degrees of freedom "
                             "left to estimate the noise; pass noise_std")
        s2 = float(r @ r) / dof
    else:
        if not (np.isfinite(noise_std) and noise_std > 0):
            raise InputError(f"noise_std must be a positive number (mm), got {noise_std!r}")
        s2 = float(noise_std) ** 2
    cov = s2 * (D @ cov_unit @ D.T)

    null = Vt[~keep]
    bad = np.zeros(len(names), bool)
    if null.size:
        leak = np.linalg.norm(D @ null.T, axis=1) / np.maximum(np.linalg.norm(D, axis=1), np.finfo(float).tiny)
        bad = leak > 1e-6
    cov[bad, :] = np.nan
    cov[:, bad] = np.nan
    cov[bad, bad] = np.inf

    fisher = _efficient_fisher(J, rows_penalty, D, s2)
    return Covariance(
        names=tuple(names),
        values={k: float(named[k]) for k in names},
        units={k: model.units.get(k, "") for k in names},
        matrix=cov,
        fisher=fisher,
        noise_variance=s2,
        n_residuals=int(m),
        n_free=int(n),
        dof=float(dof),
        unidentifiable=tuple(k for k, b in zip(names, bad) if b),
    )


class _ProblemView(eqx.Module):
    problem: Any

    def rebuild(self, theta):
        return self.problem.model(theta)


def _efficient_fisher(J, penalty_rows, D, s2):
    """Fisher information of the named parameters, nuisance (unnamed) values profiled out.

    Named columns of θ are those D depends on; D restricted to them is square
    (one raw value per named parameter), so J_phys = J_named D_n⁻¹.
    """
    named_cols = np.flatnonzero(np.any(D != 0, axis=0))
    other = np.setdiff1d(np.arange(J.shape[1]), named_cols)
    A = np.concatenate([J, penalty_rows]) if penalty_rows.size else J
    F = A.T @ A / s2
    F_nn = F[np.ix_(named_cols, named_cols)]
    if other.size:
        F_no = F[np.ix_(named_cols, other)]
        F_oo = F[np.ix_(other, other)]
        F_nn = F_nn - F_no @ np.linalg.lstsq(F_oo, F_no.T, rcond=None)[0]
    Dn = D[:, named_cols]
    if Dn.shape[0] != Dn.shape[1]:
        return np.full((D.shape[0], D.shape[0]), np.nan)
    Dinv = np.linalg.inv(Dn)
    return Dinv.T @ F_nn @ Dinv


def standard_errors(result, recordings, *, noise_std: float | None = None) -> Covariance:
    """[`parameter_covariance`][] of a [`FitResult`][], with the fit's own settings.

    `recordings` are the recording(s) given to [`hybrid.fit`][] (a FitResult
    keeps only their names). Frozen parameters, split (and its blocks) and weight
    decay are read from `result.settings`. ``standard_errors(result, rec).std_errors`` is a
    dict name → standard error in physical units.
    """
    settings = result.settings
    split = settings.get("split", {"train": 0.3, "test": 0.5, "validation": 0.2})
    return parameter_covariance(
        result.model, recordings,
        frozen=frozenset(settings.get("frozen", ())),
        split=tuple(split.values()), split_order=tuple(split.keys()), blocks=int(settings.get("blocks", 1)),
        weight_decay=float(settings.get("weight_decay", 0.0)),
        noise_std=noise_std,
    )


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
    named = _named(simulation)
    theta, view = _free_theta(simulation, frozen)
    all_names = _ordered_names(simulation)
    D = _physical_map(view, theta, all_names)
    names, rows = _free_names(D, all_names)

    def log_h(th):
        H = view.rebuild(th).frequency_response(f)
        return jnp.concatenate([jnp.log(jnp.abs(H)), jnp.unwrap(jnp.angle(H))])

    J = _raw_to_physical_columns(eqx.filter_jit(jax.jacfwd(log_h))(theta), np.asarray(D)[rows])
    J = J * np.array([float(named[n]) for n in names])
    F = f.shape[0]
    return {"frequency": np.asarray(f), "names": names, "magnitude": J[:F], "phase": J[F:]}


# --------------------------------------------------------------------------- Sobol indices
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
    named = _named(target)
    theta, view = _free_theta(target, frozen)
    if theta.size == 0:
        raise InputError("no free named parameters to sample")
    all_names = _ordered_names(target)
    D = np.asarray(_physical_map(view, theta, all_names))
    names, rows = _free_names(D, all_names)
    if len(names) != theta.size:
        raise InputError("Sobol sampling needs one raw value per named parameter")
    # column order of θ ↔ name: the named parameter whose row of D is non-zero there
    order = [names[int(np.argmax(np.abs(D[rows][:, j])))] for j in range(theta.size)]
    k = theta.size
    key_a, key_b = jax.random.split(jax.random.key(seed))
    A = theta + spread * jax.random.uniform(key_a, (n_base, k), theta.dtype, -1.0, 1.0)
    B = theta + spread * jax.random.uniform(key_b, (n_base, k), theta.dtype, -1.0, 1.0)
    AB = jnp.stack([A.at[:, j].set(B[:, j]) for j in range(k)])           # (k, N, k)
    samples = jnp.concatenate([A, B, AB.reshape(k * n_base, k)])
    model_output = isinstance(target, Model)
    Y = _evaluate_many(view, samples, v_in, float(dt), model_output, batch_size)
    fA, fB, fAB = Y[:n_base], Y[n_base:2 * n_base], Y[2 * n_base:].reshape(k, n_base, -1)
    variance = jnp.var(jnp.concatenate([fA, fB]), axis=0)
    first = jnp.mean(fB * (fAB - fA), axis=1)                               # Saltelli 2010
    total = 0.5 * jnp.mean((fA - fAB) ** 2, axis=1)                         # Jansen 1999
    denominator = jnp.maximum(jnp.sum(variance), jnp.finfo(variance.dtype).tiny)
    S1 = dict(zip(order, map(float, np.asarray(jnp.sum(first, axis=1) / denominator))))
    ST = dict(zip(order, map(float, np.asarray(jnp.sum(total, axis=1) / denominator))))
    return SobolIndices(
        names=tuple(names),
        first_order={n: S1[n] for n in names},
        total={n: ST[n] for n in names},
        n_base=n_base, n_evaluations=int(samples.shape[0]), spread=float(spread),
    )


@eqx.filter_jit
def _evaluate_many(view, samples, v_in, dt, model_output, batch_size):
    def one(th):
        target = view.rebuild(th)
        return target.predict(v_in, dt) if model_output else target.simulate(v_in, dt)

    return jax.lax.map(one, samples, batch_size=batch_size)
