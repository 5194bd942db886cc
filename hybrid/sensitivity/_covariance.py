"""Parameter uncertainty after a fit: Fisher information, covariance and standard errors (delta method)."""

from __future__ import annotations

import dataclasses
from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..core._models import Model
from ..core._parameters import bound_reached
from ..util._errors import InputError
from ._views import free_names, named_parameters, ordered_names, physical_map


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
    - `units`: unit of each, in the recordings' units of w and the drive (as `FitResult.units`).
    - `matrix`: (k, k) covariance in physical units (unit_i · unit_j).
      Entries of a parameter that moves along a null direction of J are
      inf (variance) and nan (covariances).
    - `fisher`: (k, k) Fisher information of the named parameters (1/(unit_i unit_j)),
      J_physᵀJ_phys / s² with the network weights profiled out; finite even
      where the covariance is not.
    - `noise_variance`: s² (squared output units: w's unit² for ŵ).
    - `n_residuals`, `n_free`: m and the number of free raw values.
    - `dof`: m − p.
    - `unidentifiable`: names whose variance is infinite.
    - `to_optimum`: how far each parameter lies from the training part's
      least-squares optimum, that optimum less `values` (physical units; nan if
      unidentifiable, or where no Gauss–Newton step can be solved), by damped Gauss–Newton steps from `values`
      (`_training_optimum`). Zero at a converged fit; a fit stopped early (an
      LM run that keeps its best validation loss) can sit several standard
      errors away, and `matrix` then describes the optimum's spread, not the
      value's.
    - `diverged`: whether ∂ŵ/∂θ is not finite, or over `DIVERGED_JACOBIAN` times w's
      standard deviation in some entry, while ŵ is finite: the simulation's linearisation
      is unstable at these values (a plug-in's integration step too long for a stiff
      friction's sticking: its sensitivities grew to 1e35 over the record). Every
      standard error is then infinite: no direction can be read from such a J.
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
    to_optimum: dict[str, float] = dataclasses.field(default_factory=dict)
    diverged: bool = False

    @property
    def std_errors(self) -> dict[str, float]:
        """Standard error of each parameter, physical units (inf if unidentifiable)."""
        return {n: float(np.sqrt(self.matrix[i, i])) for i, n in enumerate(self.names)}

    @property
    def relative_std_errors(self) -> dict[str, float]:
        """Standard error / |value|."""
        return {
            n: s / abs(self.values[n]) if self.values[n] else float("inf") for n, s in self.std_errors.items()
        }

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
            "to_optimum": {k: clean(v) for k, v in self.to_optimum.items()},
        }


@eqx.filter_jit
def _fit_jacobian(problem, theta):
    r, J = problem.residuals_and_jacobian(theta)
    return r * problem.scale, J * problem.scale  # back to output units (w's)


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
    - `noise_std`: the known standard deviation of w's noise (in w's unit); by
      default it is estimated from the residuals (s² = ‖r‖²/dof).
    - `rcond`: singular values of J below `rcond` · σ_max are null directions:
      parameters moving along them get an infinite variance.

    **Returns:** a [`Covariance`][], its units those of the recordings (`hybrid.fit`'s `FitResult.units`).
    """
    from ..core._fit import unit_labels
    from ..core._problem import Problem, series_from_recording

    recordings = list(recordings) if isinstance(recordings, (list, tuple)) else [recordings]
    if not recordings:
        raise InputError("no recordings: pass the recording(s) the model was fitted to")
    if not isinstance(model, Model):
        raise InputError(f"parameter_covariance needs a Model, got {type(model).__name__}")
    frozen = frozenset(frozen)
    series = [series_from_recording(r, split, split_order, blocks) for r in recordings]
    problem = Problem(model, series, frozen, weight_decay)
    return problem_covariance(
        problem,
        problem.flatten(model, frozen),
        noise_std=noise_std,
        rcond=rcond,
        units=unit_labels(model, recordings),
    )


def problem_covariance(
    problem,
    theta,
    *,
    noise_std: float | None = None,
    rcond: float = 1e-10,
    units: dict[str, str] | None = None,
) -> Covariance:
    """[`parameter_covariance`][] of the model `problem` fits, at `theta`, on its training split.

    For a caller that holds the problem already (`diagnose`: its padded
    problem, whose compiled Jacobian serves every recording of a bucket).
    Padding rows (weight 0) are dropped; `problem.sim_tangents`, if set,
    restricts the physical Jacobian to those directions (the others are null
    directions: infinite variance). `units`: each parameter's unit label
    (`parameter_covariance` passes the recordings', as `FitResult.units`); by
    default the model's own `units`, w in mm and the drive in V: the problem
    keeps no signal units.
    """
    model = problem.model(theta)
    r, J = _training_rows(problem, theta)
    m, n = J.shape
    w = np.asarray(problem.recorded(problem.target("train"), "train"))
    spread = float(np.std(w)) if w.size else 0.0  # w's own: a noise-free fit's residual is 0
    peak = float(np.max(np.abs(J), initial=0.0))
    diverged = not np.all(np.isfinite(J)) or (spread > 0 and peak > DIVERGED_JACOBIAN * spread)
    if diverged:
        J = np.zeros_like(J)  # nothing can be read from it: every direction is then unidentifiable
    named = named_parameters(model)
    all_names = ordered_names(model)
    D = np.asarray(physical_map(_ProblemView(problem), theta, all_names))
    names, rows = free_names(D, all_names)
    D = D[rows]
    if not names:
        raise InputError("no free named parameters: everything named is frozen")

    # A parameter at a bound of its range is held there: its raw value sits where its map is flat, and
    # left free, that near-null direction would leak into every parameter that trades off with it.
    held = _at_bounds(model, named, names)
    columns = np.ones(n)
    for k in held:
        columns[np.abs(D[names.index(k)]) > 0] = 0.0
    J = J * columns
    # Regularised normal matrix (weight decay as ridge rows in units of the scaled residuals).
    mask = np.asarray(problem.penalty_mask(theta))
    mu = float(problem.weight_decay)
    scale2 = float(problem.scale) ** 2
    rows_penalty = np.sqrt(mu * scale2) * np.diag(mask)[mask > 0] if mu else np.zeros((0, n))
    A = np.concatenate([J, rows_penalty])
    _, sigma, Vt = np.linalg.svd(A, full_matrices=A.shape[0] < A.shape[1])  # all n directions
    sigma = np.concatenate([sigma, np.zeros(Vt.shape[0] - sigma.size)])  # (fewer rows: 0s)
    keep = sigma > rcond * sigma[0]
    V, inv_s2 = Vt[keep].T, 1.0 / sigma[keep] ** 2
    cov_unit = (V * inv_s2) @ V.T  # (JᵀJ + μP)⁻¹ on the identifiable subspace
    if mu:
        JV = J @ V
        p_eff = float(np.sum(inv_s2 * np.sum(JV * JV, axis=0)))  # tr((JᵀJ+μP)⁻¹ JᵀJ)
    else:
        p_eff = float(np.sum(keep))
    dof = m - p_eff
    if noise_std is None:
        if dof <= 0:
            raise InputError(
                f"{m} residuals for {p_eff:.0f} free parameters: no degrees of freedom "
                "left to estimate the noise; pass noise_std"
            )
        s2 = float(r @ r) / dof
    else:
        if not (np.isfinite(noise_std) and noise_std > 0):
            raise InputError(f"noise_std must be a positive number (in w's unit), got {noise_std!r}")
        s2 = float(noise_std) ** 2
    cov = s2 * (D @ cov_unit @ D.T)

    null = Vt[~keep]
    bad = np.zeros(len(names), bool)
    if null.size:
        leak = np.linalg.norm(D @ null.T, axis=1) / np.maximum(
            np.linalg.norm(D, axis=1), np.finfo(float).tiny
        )
        bad = leak > 1e-6
    cov[bad, :] = np.nan
    cov[:, bad] = np.nan
    cov[bad, bad] = np.inf
    se = np.sqrt(np.abs(np.diag(cov)))
    # no Gauss–Newton step follows a J that diverged: none is taken
    optimum = (
        None if diverged else _training_optimum(problem, theta, r, J, rows_penalty, D, se, rcond, columns)
    )
    step = np.array([float(optimum[k]) - float(named[k]) if optimum else np.nan for k in names])
    step[bad] = np.nan

    fisher = _efficient_fisher(J, rows_penalty, D, s2)
    return Covariance(
        names=tuple(names),
        values={k: float(named[k]) for k in names},
        units={k: (model.units if units is None else units).get(k, "") for k in names},
        matrix=cov,
        fisher=fisher,
        noise_variance=s2,
        n_residuals=int(m),
        n_free=int(n),
        dof=float(dof),
        unidentifiable=tuple(k for k, b in zip(names, bad) if b),
        to_optimum={k: float(x) for k, x in zip(names, step)},
        diverged=diverged,
    )


#: How many times w's standard deviation an entry of ∂ŵ/∂θ (w's unit per raw parameter value) may reach before
#: the linearisation is taken to have diverged (`Covariance.diverged`): a raw step of one (a factor e of a
#: positive parameter) moves a sane simulation's output by a few of its ranges, not 1e15 of them.
DIVERGED_JACOBIAN = 1e15

#: `_training_optimum`'s most Gauss–Newton steps, and the move (in standard errors) below which it stops.
OPTIMUM_STEPS = 20
OPTIMUM_TOLERANCE = 1e-3


def _training_optimum(problem, theta, r, J, rows_penalty, D, se, rcond, columns) -> dict | None:
    """The named parameters at the least-squares optimum of the training part, from `theta`.

    Gauss–Newton on the identifiable subspace (the minimum-norm step, with the
    covariance's `rcond`), each step halved until the cost falls, until no named
    parameter moves by more than `OPTIMUM_TOLERANCE` standard errors: at a
    converged fit one linear solve and no evaluation. r and J are those at
    `theta` (recorded rows); the weight decay's rows are √μ θ_network. A step
    whose residuals or Jacobian are not finite is halved as one that does not
    lower the cost; None where not even the first step can be solved, or
    where it still moves after `OPTIMUM_STEPS` steps. `columns`: 0 on the θ
    entries held (a parameter at a bound), 1 elsewhere. Each halving's trial
    forms J too (one compiled program, the covariance's); trials are few.
    """
    theta = np.asarray(theta, float)
    penalised = np.abs(rows_penalty).sum(axis=0)  # √μ·scale on each penalised entry, else 0

    def stacked(r, th):
        return np.concatenate([r, (penalised * th)[penalised > 0]])

    def solve(A, b):  # the minimum-norm Gauss–Newton step; None where LAPACK cannot take it
        if not (np.isfinite(A).all() and np.isfinite(b).all()):
            return None
        try:
            return -np.linalg.lstsq(A, b, rcond=rcond)[0]
        except np.linalg.LinAlgError:
            return None

    A = np.concatenate([J, rows_penalty])
    b = stacked(r, theta)
    tiny = np.where(np.isfinite(se) & (se > 0), se, np.inf) * OPTIMUM_TOLERANCE
    for k in range(OPTIMUM_STEPS):
        delta = solve(A, b)
        if delta is None and k == 0:
            return None  # not even a first step: where the optimum lies is not known
        if delta is None or np.all(np.abs(D @ delta) <= tiny):
            break
        cost = b @ b
        for _ in range(10):  # halved until the cost falls
            r_new, J_new = _training_rows(problem, jnp.asarray(theta + delta))
            b_new = stacked(r_new, theta + delta)
            if np.isfinite(b_new).all() and np.isfinite(J_new).all() and b_new @ b_new < cost:
                break
            delta = delta / 2
        else:
            break  # no step along the Gauss–Newton direction lowers the cost: as far as it goes
        theta = theta + delta
        A, b = np.concatenate([J_new * columns, rows_penalty]), b_new
    else:
        return None  # still moving after OPTIMUM_STEPS: where the optimum lies is not known
    return named_parameters(problem.model(jnp.asarray(theta)))


def _at_bounds(model, named: dict, names: list[str]) -> list[str]:
    """The free named parameters of `model` that sit at a bound of their two-sided range (`bound_reached`)."""
    constraints = {
        **getattr(model.readout, "constraints", {}),
        **getattr(model.simulation, "constraints", {}),
    }
    return [k for k in names if bound_reached(float(named[k]), constraints.get(k)) is not None]


def _training_rows(problem, theta) -> tuple[np.ndarray, np.ndarray]:
    """r and J on the training part in w's units, its padding rows (weight 0) dropped."""
    r, J = (np.asarray(a) for a in _fit_jacobian(problem, theta))
    weights = problem.weights("train")
    if weights is None:
        return r, J
    recorded = np.asarray(weights) > 0
    return r[recorded], J[recorded]


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
        result.model,
        recordings,
        frozen=frozenset(settings.get("frozen", ())),
        split=tuple(split.values()),
        split_order=tuple(split.keys()),
        blocks=int(settings.get("blocks", 1)),
        weight_decay=float(settings.get("weight_decay", 0.0)),
        noise_std=noise_std,
    )
