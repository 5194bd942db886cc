"""Linear recurrences run in blocks (`hybrid.core._lifted`): the plain recursion's numbers and derivatives."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hybrid.core._lifted import lifted_states


def _recursion(Phi, forcing):
    """x_{t+1} = Φ x_t + f_t from x_0 = 0, one step at a time in numpy: the reference."""
    x, out = np.zeros(Phi.shape[0]), []
    for f in forcing:
        x = Phi @ x + f
        out.append(x)
    return np.array(out)


# A lightly damped mode (eigenvalues 0.97 e^{±0.3i}) and a three-state system with a slow and a fast pole.
MODES = [
    0.97 * np.array([[np.cos(0.3), -np.sin(0.3)], [np.sin(0.3), np.cos(0.3)]]),
    np.array([[0.999, 0.0, 0.0], [0.2, 0.5, 0.0], [0.0, 0.3, -0.4]]),
]


@pytest.mark.parametrize("Phi", MODES)
@pytest.mark.parametrize("length", [1, 5, 31, 32, 33, 100, 1000])
@pytest.mark.parametrize("block", [1, 5, 16, 32])
def test_lifted_states_equal_the_plain_recursion(Phi, length, block):
    forcing = np.random.default_rng(length).normal(size=(length, Phi.shape[0]))
    got = np.asarray(lifted_states(jnp.asarray(Phi), jnp.asarray(forcing), block))
    expected = _recursion(Phi, forcing)
    assert got.shape == expected.shape
    # ≤ 1e-12 of the largest state: the blocks only re-associate the sums
    assert np.max(np.abs(got - expected)) <= 1e-12 * np.max(np.abs(expected))


def test_lifted_states_derivatives_match_central_differences():
    """Forward and reverse mode in Φ and the forcing (the blocks' own JVP, `block_states`)."""
    length = 301
    forcing = jnp.asarray(np.random.default_rng(1).normal(size=(length, 2)))
    weights = jnp.linspace(0.5, 1.5, length)

    def loss(theta):  # Φ rotated and scaled by θ, the forcing scaled by θ[2]: every path of the derivative
        r, a = 0.97 * jnp.exp(theta[0]), 0.3 + theta[1]
        Phi = r * jnp.array([[jnp.cos(a), -jnp.sin(a)], [jnp.sin(a), jnp.cos(a)]])
        x = lifted_states(Phi, forcing * (1.0 + theta[2]), 32)
        return jnp.sum(weights * jnp.sin(x[:, 0]) ** 2)

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
