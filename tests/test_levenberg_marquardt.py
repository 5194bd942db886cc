"""The LM loop's validation patience: static in `LMSettings`, or a traced argument of one compiled loop."""

import equinox as eqx
import jax
import jax.numpy as jnp
import pytest

from hybrid.core._levenberg_marquardt import LMSettings, lm_init, lm_run


class _LinearProblem(eqx.Module):
    """½‖Aθ − b‖² on training; validation prefers θ = θ_val, so every step away from it is worse there."""

    A: jax.Array
    b: jax.Array
    theta_val: jax.Array
    weight_decay: float = 0.0

    def residuals_and_jacobian(self, theta):
        return self.A @ theta - self.b, self.A

    def cost(self, theta):
        r = self.A @ theta - self.b
        return 0.5 * r @ r

    def validation_loss(self, theta):
        return jnp.sum((theta - self.theta_val) ** 2)


def _problem():
    A = jnp.array([[2.0, 0.3], [0.1, 1.0], [0.5, -0.4]])
    theta_val = jnp.array([1.0, -1.0])
    return _LinearProblem(A, A @ jnp.array([3.0, 2.0]) + jnp.array([0.01, -0.02, 0.03]), theta_val), theta_val


# λ₀ large: many small accepted steps from θ_val towards the least-squares solution, each one
# lowering the training cost and raising the validation loss.
OPTIONS = dict(max_steps=200, lambda0=1e4, ftol=1e-14, gtol=0.0)
SETTINGS = LMSettings(**OPTIONS, patience=0)


@pytest.mark.parametrize("patience", [3, 7])
def test_traced_patience_stops_after_that_many_steps_without_a_better_validation_loss(patience):
    problem, theta0 = _problem()
    run = jax.jit(
        lambda p: lm_run(problem, lm_init(problem, theta0, SETTINGS), SETTINGS, SETTINGS.max_steps, p)
    )
    state = run(jnp.int32(patience))
    assert int(state.accepted) == patience and int(state.best_step) == 0
    assert jnp.array_equal(state.best_theta, theta0)
    # The same as the static setting.
    static = LMSettings(**OPTIONS, patience=patience)
    ref = lm_run(problem, lm_init(problem, theta0, static), static, static.max_steps)
    assert int(ref.accepted) == patience and jnp.allclose(ref.theta, state.theta, rtol=0, atol=0)


def test_traced_patience_zero_never_stops_on_validation():
    problem, theta0 = _problem()
    state = jax.jit(lambda p: lm_run(problem, lm_init(problem, theta0, SETTINGS), SETTINGS, 200, p))(
        jnp.int32(0)
    )
    # It runs on towards the least-squares solution, every step worse on validation.
    assert int(state.accepted) > 7 and int(state.best_step) == 0


def test_patience_rtol_stops_a_lane_that_creeps_and_keeps_its_best_iterate():
    """Validation agrees with training here, so every accepted step is better there, by less and less.

    Without a margin the loop runs until the training cost stalls; with `patience_rtol` a step
    must improve the best validation loss by that fraction to count, so it stops `patience`
    steps into the creep, and the iterate it keeps is still the last (best) one.
    """
    problem, theta0 = _problem()
    solution = jnp.linalg.lstsq(problem.A, problem.b)[0]
    problem = eqx.tree_at(lambda p: p.theta_val, problem, solution)
    creeping = LMSettings(**OPTIONS, patience=5)
    margin = LMSettings(**OPTIONS, patience=5, patience_rtol=0.05)
    plain = lm_run(problem, lm_init(problem, theta0, creeping), creeping, creeping.max_steps)
    stopped = lm_run(problem, lm_init(problem, theta0, margin), margin, margin.max_steps)
    assert int(stopped.accepted) < int(plain.accepted)
    assert int(stopped.best_step) == int(stopped.accepted)  # each step was still (slightly) better
    first = problem.validation_loss(theta0)
    assert problem.validation_loss(stopped.best_theta) < first  # it moved towards the solution
