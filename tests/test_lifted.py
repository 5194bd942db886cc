"""Linear recurrences run in blocks (`hybrid.core._lifted`): the plain recursion's numbers and derivatives."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hybrid.core._lifted import lifted_blocks, lifted_response


def _recursion(Ad, Bd, C, D, u):
    """y[n] = C x[n] + D u[n], x[n+1] = Ad x[n] + Bd u[n] from x[0] = 0, one step at a time in numpy."""
    x, out = np.zeros(Ad.shape[0]), []
    for un in u:
        out.append(C @ x + D * un)
        x = Ad @ x + Bd * un
    return np.array(out)


# A lightly damped mode (eigenvalues 0.97 e^{±0.3i}) and a three-state system with a slow and a fast pole.
SYSTEMS = [
    (
        0.97 * np.array([[np.cos(0.3), -np.sin(0.3)], [np.sin(0.3), np.cos(0.3)]]),
        [0.2, -0.1],
        [1.0, 0.0],
        0.05,
    ),
    (np.array([[0.999, 0.0, 0.0], [0.2, 0.5, 0.0], [0.0, 0.3, -0.4]]), [1.0, 0.0, 0.5], [0.3, 0.2, 1.0], 0.0),
]


@pytest.mark.parametrize("system", SYSTEMS)
@pytest.mark.parametrize("length", [1, 5, 31, 32, 33, 100, 1000])
@pytest.mark.parametrize("block", [1, 5, 16, 32])
def test_the_lifted_response_equals_the_plain_recursion(system, length, block):
    Ad, Bd, C, D = (np.asarray(a, float) for a in system)
    u = np.random.default_rng(length).normal(size=length)
    got = np.asarray(
        lifted_response(*lifted_blocks(*(jnp.asarray(a) for a in (Ad, Bd, C, D)), block), jnp.asarray(u))
    )
    expected = _recursion(Ad, Bd, C, D, u)
    assert got.shape == expected.shape
    # ≤ 1e-12 of the largest output: the blocks only re-associate the sums
    assert np.max(np.abs(got - expected)) <= 1e-12 * np.max(np.abs(expected))


def test_the_lifted_response_derivatives_match_central_differences():
    """Forward and reverse mode in the system and the input (the blocks' own JVP, `_block_states`)."""
    length = 301
    u = jnp.asarray(np.random.default_rng(1).normal(size=length))
    weights = jnp.linspace(0.5, 1.5, length)

    def loss(theta):  # the mode rotated and scaled by θ, its input and output gains by θ[2]: every path
        r, a = 0.97 * jnp.exp(theta[0]), 0.3 + theta[1]
        Ad = r * jnp.array([[jnp.cos(a), -jnp.sin(a)], [jnp.sin(a), jnp.cos(a)]])
        Bd, C = jnp.array([0.2, -0.1]) * (1.0 + theta[2]), jnp.array([1.0, theta[2]])
        y = lifted_response(*lifted_blocks(Ad, Bd, C, 0.05, 32), u * (1.0 + theta[2]))
        return jnp.sum(weights * jnp.sin(y) ** 2)

    theta = jnp.array([-0.01, 0.02, 0.1])
    forward = jax.jacfwd(loss)(theta)
    reverse = jax.grad(loss)(theta)
    step = 1e-6
    for i in range(3):
        e = np.zeros(3)
        e[i] = step
        fd = (float(loss(theta + e)) - float(loss(theta - e))) / (2 * step)
        # central differences: truncation ~ step² ≈ 1e-12, rounding ~ 1e-16/step ≈ 1e-10 of the loss
        assert float(forward[i]) == pytest.approx(fd, rel=1e-6, abs=1e-8)
        assert float(reverse[i]) == pytest.approx(fd, rel=1e-6, abs=1e-8)
    assert np.all(np.abs(np.asarray(forward)) > 1e-3)  # the loss depends on every θ
