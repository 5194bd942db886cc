"""Levenberg–Marquardt on a structured Jacobian, as a jittable, vmappable loop.

Minimises ½‖r(θ)‖² with the damped Gauss–Newton step

    (JᵀJ + λ D) δ = −Jᵀr,   D = I (Levenberg, default) or diag(JᵀJ) (Marquardt),

accepting a step when the gain ratio ρ = (actual decrease)/(predicted decrease)
is positive and updating λ by Nielsen's rule (λ ← λ·max(1/3, 1 − (2ρ − 1)³) on
acceptance, λ ← λ·ν, ν ← 2ν on rejection). JᵀJ and Jᵀr are formed once per
accepted point, at the start of the step after it (`LMState.fresh`), so a
rejected step costs one Cholesky solve and one simulation, and a compiled run
holds one copy of the Jacobian's program.

Why not `optimistix.LevenbergMarquardt` directly: optimistix differentiates the
residual function as a whole (`jax.linearize`/`jacrev` of the full pytree) and
its damped solve materialises `J @ I` through a `FunctionLinearOperator`; at
3,000 residuals × 1,727 parameters that was ~6 s and 8 GB per step. Here the
Jacobian comes from [`hybrid.core._problem.Problem`][] (per-sample network gradients,
forward mode for the physics), folded into JᵀJ a chunk of rows at a time on long
records (`Problem.normal_equations`; any problem that gives `residuals_and_jacobian`
works too), and the step is a Cholesky solve. The solvers
agree where both apply (physics-only models: `tests/test_fit.py`), and
`solver=hybrid.OptimistixLM()` in [`hybrid.fit`][] runs optimistix's own LM.

Validation: after each accepted step the validation loss is evaluated and the
best iterate so far is kept; the loop stops early after `patience` accepted
steps without a validation improvement.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jax import lax


class LMSettings(eqx.Module):
    """Options of the Levenberg–Marquardt loop.

    - `max_steps`: most LM iterations (accepted or rejected).
    - `ftol`: stop when an accepted step lowers the cost by less than `ftol` relative.
    - `gtol`: stop when max |Jᵀr| < `gtol`.
    - `patience`: stop after this many accepted steps without a better validation
      loss (0: never stop on validation).
    - `patience_rtol`: a validation loss counts as better, for `patience`, only when
      it lies below the best so far by more than this fraction (the best iterate is
      kept whatever the margin): a lane creeping down a long valley by 0.01 % a step
      stops, where its next hundred steps would not change a decision.
    - `lambda0`: initial damping λ, relative to max diag(JᵀJ) for ``scaling="identity"``.
    - `scaling`: D = I (``"identity"``, Levenberg) or D = diag(JᵀJ) (``"marquardt"``).
    """

    max_steps: int = eqx.field(static=True, default=300)
    ftol: float = eqx.field(static=True, default=1e-10)
    gtol: float = eqx.field(static=True, default=1e-12)
    patience: int = eqx.field(static=True, default=40)
    patience_rtol: float = eqx.field(static=True, default=0.0)
    lambda0: float = eqx.field(static=True, default=1e-3)
    scaling: str = eqx.field(static=True, default="identity")


class LMState(eqx.Module):
    theta: jax.Array
    cost: jax.Array
    JtJ: jax.Array
    g: jax.Array
    lam: jax.Array
    nu: jax.Array
    best_theta: jax.Array
    best_val: jax.Array
    best_step: jax.Array
    step: jax.Array
    accepted: jax.Array
    since_best: jax.Array
    done: jax.Array
    fresh: jax.Array
    nonfinite: jax.Array
    """Trial steps rejected because the cost there was not finite (NaN or inf predictions)."""


def _cost_and_validation(problem, theta):
    """(cost, validation loss) at θ: from one simulation when the problem can (`Problem.cost_and_validation_loss`)."""
    if hasattr(problem, "cost_and_validation_loss"):
        return problem.cost_and_validation_loss(theta)
    return problem.cost(theta), problem.validation_loss(theta)


def normal_equations(problem, theta):
    """Cost, JᵀJ and Jᵀr, with the weight-decay rows √μ θ_network folded in."""
    if hasattr(problem, "normal_equations"):  # `Problem`: J's network columns folded in chunks of rows
        JtJ, g = problem.normal_equations(theta)
    else:  # any least-squares problem that gives r and J
        r, J = problem.residuals_and_jacobian(theta)
        JtJ, g = J.T @ J, J.T @ r
    if problem.weight_decay:
        mask = problem.penalty_mask(theta)
        JtJ = JtJ + jnp.diag(problem.weight_decay * mask)
        g = g + problem.weight_decay * mask * theta
    return problem.cost(theta), JtJ, g


def lm_init(problem, theta0, settings: LMSettings) -> LMState:
    """The state at θ₀. JᵀJ and Jᵀr are formed by the first step (`fresh`), not here.

    A compiled LM run (init, then a loop of steps) thus holds one copy of the
    Jacobian's program, inside the loop, instead of a second one in the init;
    it does the same arithmetic.
    """
    cost, val = _cost_and_validation(problem, theta0)
    n = theta0.shape[0]
    zero = jnp.zeros((), jnp.int32)
    return LMState(
        theta=theta0,
        cost=cost,
        JtJ=jnp.zeros((n, n), cost.dtype),
        g=jnp.zeros(n, cost.dtype),
        lam=jnp.asarray(jnp.nan, cost.dtype),
        nu=jnp.asarray(2.0, cost.dtype),
        best_theta=theta0,
        best_val=val,
        best_step=zero,
        step=zero,
        accepted=zero,
        since_best=zero,
        done=~jnp.isfinite(cost),
        fresh=jnp.asarray(True),
        nonfinite=zero,
    )


def _refresh(problem, state: LMState, settings: LMSettings) -> LMState:
    """JᵀJ and Jᵀr at the state's θ (after an accepted step, or at the start); λ₀ on the first."""
    _, JtJ, g = normal_equations(problem, state.theta)
    lam0 = jnp.asarray(settings.lambda0, JtJ.dtype)
    if settings.scaling != "marquardt":
        lam0 = lam0 * jnp.max(jnp.diag(JtJ))
    return eqx.tree_at(
        lambda s: (s.JtJ, s.g, s.lam, s.fresh, s.done),
        state,
        (
            JtJ,
            g,
            jnp.where(jnp.isnan(state.lam), lam0, state.lam),
            jnp.asarray(False),
            state.done | (jnp.max(jnp.abs(g)) < settings.gtol),
        ),
    )


def lm_step(problem, state: LMState, settings: LMSettings, patience=None) -> LMState:
    """One LM iteration (a no-op once `state.done`).

    `patience`, if given, replaces `settings.patience` and may be a traced
    integer (several stages with different patience share one compiled loop).
    """
    state = lax.cond(state.fresh & ~state.done, lambda s: _refresh(problem, s, settings), lambda s: s, state)
    diag = jnp.diag(state.JtJ)
    if settings.scaling == "marquardt":
        D = jnp.maximum(diag, 1e-9 * jnp.max(diag) + jnp.finfo(diag.dtype).tiny)
    else:
        D = jnp.ones_like(diag)
    A = state.JtJ + jnp.diag(state.lam * D)
    factor = jax.scipy.linalg.cho_factor(A)
    delta = -jax.scipy.linalg.cho_solve(factor, state.g)
    theta_new = state.theta + delta
    cost_new, val = _cost_and_validation(problem, theta_new)
    predicted = -(delta @ state.g) - 0.5 * delta @ (state.JtJ @ delta)
    rho = (state.cost - cost_new) / jnp.where(predicted > 0, predicted, jnp.inf)
    accept = jnp.isfinite(cost_new) & jnp.all(jnp.isfinite(delta)) & (rho > 1e-4)

    def accepted(state):
        cost = cost_new
        better = val < state.best_val
        clearly_better = val < state.best_val - settings.patience_rtol * jnp.abs(state.best_val)
        lam = state.lam * jnp.maximum(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
        relative_decrease = (state.cost - cost) / jnp.maximum(state.cost, jnp.finfo(cost.dtype).tiny)
        since_best = jnp.where(clearly_better, 0, state.since_best + 1)
        converged = relative_decrease < settings.ftol  # |Jᵀr| < gtol: checked when JᵀJ is formed (`_refresh`)
        if patience is not None:
            converged = converged | ((patience > 0) & (since_best >= patience))
        elif settings.patience:
            converged = converged | (since_best >= settings.patience)
        return LMState(
            theta=theta_new,
            cost=cost,
            JtJ=state.JtJ,
            g=state.g,
            lam=lam,
            fresh=jnp.asarray(True),
            nu=jnp.asarray(2.0, state.nu.dtype),
            best_theta=jnp.where(better, theta_new, state.best_theta),
            best_val=jnp.where(better, val, state.best_val),
            best_step=jnp.where(better, state.step + 1, state.best_step),
            step=state.step + 1,
            accepted=state.accepted + 1,
            since_best=since_best,
            done=converged,
            nonfinite=state.nonfinite,
        )

    def rejected(state):
        lam = state.lam * state.nu
        return eqx.tree_at(
            lambda s: (s.lam, s.nu, s.step, s.done, s.nonfinite),
            state,
            (
                lam,
                state.nu * 2.0,
                state.step + 1,
                lam > 1e16 * jnp.maximum(jnp.max(diag), 1.0),
                state.nonfinite + (~jnp.isfinite(cost_new)).astype(state.nonfinite.dtype),
            ),
        )

    new = lax.cond(accept, accepted, rejected, state)
    new = eqx.tree_at(lambda s: s.done, new, new.done | (new.step >= settings.max_steps))
    return jax.tree_util.tree_map(lambda a, b: jnp.where(state.done, a, b), state, new)


def lm_run(problem, state: LMState, settings: LMSettings, n_steps: int, patience=None):
    """Up to `n_steps` more iterations, stopping early when done (`patience`: see `lm_step`)."""

    def cond(carry):
        i, s = carry
        return (i < n_steps) & ~s.done

    def body(carry):
        i, s = carry
        return i + 1, lm_step(problem, s, settings, patience)

    _, state = lax.while_loop(cond, body, (jnp.zeros((), jnp.int32), state))
    return state
