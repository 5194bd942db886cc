"""Eqs 18-20 against hand arithmetic, scale behaviour, jit and gradients."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hybrid import InputError
from hybrid.core._metrics import METRICS, fitting, metrics, nmse, nmse_target, nmse_variance

W = [1.0, 2.0, 4.0]
W_HAT = [1.0, 2.0, 2.0]


def test_nmse_by_hand():
    # w_n = [1/4, 1/2, 1], w_hat_n = [1/2, 1, 1]; differences -1/4, -1/2, 0.
    expected = (1 / 16 + 1 / 4 + 0) / 3  # = 5/48
    assert float(nmse(W, W_HAT)) == pytest.approx(expected, rel=1e-14)


def test_nmse_target_by_hand():
    # (w - w_hat) / max|w| = [0, 0, 2/4].
    expected = (0 + 0 + 1 / 4) / 3  # = 1/12
    assert float(nmse_target(W, W_HAT)) == pytest.approx(expected, rel=1e-14)


def test_nmse_variance_by_hand():
    # MSE = (0 + 0 + 4) / 3; mean(w) = 7/3, var(w) = (16 + 1 + 25) / 9 / 3 = 14/9.
    expected = (4 / 3) / (14 / 9)  # = 6/7
    assert float(nmse_variance(W, W_HAT)) == pytest.approx(expected, rel=1e-14)


def test_fitting_by_hand():
    # ||w_n - w_hat_n|| = sqrt(1/16 + 1/4) = sqrt(5)/4; mean(w_n) = 7/12,
    # ||w_n - 7/12|| = sqrt((4^2 + 1^2 + 5^2) / 144) = sqrt(42)/12.
    expected = 100 * (1 - (math.sqrt(5) / 4) / (math.sqrt(42) / 12))
    assert float(fitting(W, W_HAT)) == pytest.approx(expected, rel=1e-13)


def test_metrics_dict_holds_python_floats():
    result = metrics(np.array(W), np.array(W_HAT))
    assert tuple(result) == METRICS
    assert all(type(v) is float for v in result.values())
    assert result["nmse"] == pytest.approx(5 / 48)
    assert result["nmse_target"] == pytest.approx(1 / 12)
    assert result["nmse_variance"] == pytest.approx(6 / 7)


def test_identical_signals():
    w = np.sin(np.linspace(0, 6, 50)) + 0.3
    result = metrics(w, w)
    assert result["nmse"] == 0.0
    assert result["nmse_target"] == 0.0
    assert result["nmse_variance"] == 0.0
    assert result["fitting"] == 100.0


def test_nmse_ignores_prediction_scale_but_nmse_target_does_not():
    w = np.sin(np.linspace(0, 6, 50))
    w_hat = w + 0.05 * np.cos(np.linspace(0, 17, 50))
    assert float(nmse(w, 10 * w_hat)) == pytest.approx(float(nmse(w, w_hat)), rel=1e-12)
    assert float(fitting(w, 10 * w_hat)) == pytest.approx(float(fitting(w, w_hat)), rel=1e-12)
    assert float(nmse_target(w, 10 * w_hat)) > 100 * float(nmse_target(w, w_hat))
    # Scaling both signals leaves every measure unchanged.
    for name in METRICS:
        assert metrics(3 * w, 3 * w_hat)[name] == pytest.approx(metrics(w, w_hat)[name], rel=1e-12)


def test_zero_prediction_stays_zero():
    w = np.array([1.0, -2.0, 4.0])
    assert float(nmse(w, np.zeros(3))) == pytest.approx((1 / 16 + 1 / 4 + 1) / 3)


def test_jit_and_gradient():
    w = jnp.sin(jnp.linspace(0.0, 6.0, 40))
    w_hat = w + 0.1 * jnp.cos(jnp.linspace(0.0, 11.0, 40))
    for function in (nmse, nmse_target, nmse_variance, fitting):
        assert float(jax.jit(function)(w, w_hat)) == pytest.approx(float(function(w, w_hat)), rel=1e-12)
        gradient = jax.grad(function, argnums=1)(w, w_hat)
        assert gradient.shape == w.shape
        assert bool(jnp.all(jnp.isfinite(gradient)))
        assert float(jnp.max(jnp.abs(gradient))) > 0
    # The fitting gradient is finite at a perfect fit, too.
    assert bool(jnp.all(jnp.isfinite(jax.grad(fitting, argnums=1)(w, w))))


def test_gradient_matches_finite_differences():
    w = np.sin(np.linspace(0.0, 6.0, 20))
    w_hat = w + 0.1 * np.cos(np.linspace(0.0, 11.0, 20))
    gradient = np.asarray(jax.grad(nmse_target, argnums=1)(w, w_hat))
    step = 1e-6
    bump = np.zeros_like(w_hat)
    bump[7] = step
    numeric = (float(nmse_target(w, w_hat + bump)) - float(nmse_target(w, w_hat - bump))) / (2 * step)
    assert gradient[7] == pytest.approx(numeric, rel=1e-6)


def test_dtype_follows_input():
    w = np.array(W, dtype=np.float32)
    assert nmse(w, np.array(W_HAT, dtype=np.float32)).dtype == jnp.float32
    assert nmse([1, 2, 4], [1, 2, 2]).dtype == jnp.float64


@pytest.mark.parametrize("function", [nmse, nmse_target, nmse_variance, fitting, metrics])
def test_shape_mismatch(function):
    with pytest.raises(InputError, match="same length"):
        function([1.0, 2.0, 3.0], [1.0, 2.0])


@pytest.mark.parametrize("function", [nmse, nmse_target, nmse_variance, fitting])
def test_empty(function):
    with pytest.raises(InputError, match="empty"):
        function([], [])


def test_non_finite_input():
    with pytest.raises(InputError, match="non-finite values at index 1"):
        nmse([1.0, 2.0, 3.0], [1.0, np.nan, 3.0])


def test_degenerate_targets():
    with pytest.raises(InputError, match="zero everywhere"):
        nmse(np.zeros(4), np.ones(4))
    with pytest.raises(InputError, match="zero everywhere"):
        nmse_target(np.zeros(4), np.ones(4))
    with pytest.raises(InputError, match="constant"):
        nmse_variance(np.ones(4), np.ones(4))
    with pytest.raises(InputError, match="constant"):
        fitting(np.ones(4), np.ones(4))
