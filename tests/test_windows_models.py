"""Sliding windows (Sec. II-B) and the model assembly (Fig. 2)."""

import inspect

import helpers as h
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hybrid import (
    InputError,
    LinearReadout,
    Model,
    Passthrough,
    RCNetwork,
    Recording,
    WindowedMLP,
    make_model,
    sliding_windows,
)
from hybrid.core._problem import Problem, series_from_recording
from hybrid.core._windows import segment_windows


def _windows_reference(x, window):
    """out[t, j] = x[t − window + 1 + j], with x[i] = x[0] for i < 0 (edge padding)."""
    x = np.asarray(x)
    out = np.empty((len(x), window))
    for t in range(len(x)):
        for j in range(window):
            i = t - window + 1 + j
            out[t, j] = x[max(i, 0)]
    return out


# --------------------------------------------------------------------------- windows
@pytest.mark.parametrize("n, window", [(20, 1), (20, 5), (7, 7), (4, 9), (1, 3)])
def test_sliding_windows_match_loop_reference(n, window):
    x = np.random.default_rng(n * 31 + window).normal(size=n)
    got = np.asarray(sliding_windows(jnp.asarray(x), window))
    assert got.shape == (n, window)
    np.testing.assert_array_equal(got, _windows_reference(x, window))
    # the newest sample is the last column; no sample from the future appears
    np.testing.assert_array_equal(got[:, -1], x)


def test_sliding_windows_pad_with_first_value():
    x = jnp.arange(1.0, 6.0)  # 1..5
    got = np.asarray(sliding_windows(x, 3))
    np.testing.assert_array_equal(got[0], [1.0, 1.0, 1.0])
    np.testing.assert_array_equal(got[1], [1.0, 1.0, 2.0])
    np.testing.assert_array_equal(got[4], [3.0, 4.0, 5.0])


def test_segment_windows_never_cross_a_boundary():
    # three segments (with a gap) whose values lie in disjoint ranges
    segments = ((0, 10), (10, 25), (30, 36))
    x = np.full(40, -1.0)
    for s, (a, b) in enumerate(segments):
        x[a:b] = 100.0 * (s + 1) + np.arange(b - a)
    window = 6
    got = np.asarray(segment_windows(jnp.asarray(x), window, segments))
    assert got.shape == (sum(b - a for a, b in segments), window)
    row = 0
    for s, (a, b) in enumerate(segments):
        block = got[row : row + b - a]
        # every value in a segment's windows comes from that segment
        assert np.all((block >= 100.0 * (s + 1)) & (block < 100.0 * (s + 2))), s
        np.testing.assert_array_equal(block, _windows_reference(x[a:b], window))
        row += b - a


# --------------------------------------------------------------------------- models
def test_make_model_kinds_and_shapes():
    dt = 1 / 30
    v = jnp.asarray(h.step_drive(80, seed=1))
    sim = RCNetwork(n_stages=5)
    hybrid = make_model("hybrid", simulation=sim, window=5, depth=2, width=4)
    normal = make_model("normal", window=5, depth=2, width=4)
    physics = make_model("physics", simulation=sim)
    assert isinstance(hybrid.simulation, RCNetwork) and isinstance(hybrid.readout, WindowedMLP)
    assert isinstance(normal.simulation, Passthrough) and isinstance(normal.readout, WindowedMLP)
    assert isinstance(physics.simulation, RCNetwork) and isinstance(physics.readout, LinearReadout)
    assert (hybrid.kind, normal.kind, physics.kind) == ("hybrid", "normal", "physics")
    for model in (hybrid, normal, physics):
        assert model.predict(v, dt).shape == (80,)
        assert model.predict(v, dt, ((0, 30), (50, 80))).shape == (60,)
    # the normal model's mediatory signal is the drive itself
    np.testing.assert_array_equal(np.asarray(normal.mediatory(v, dt)), np.asarray(v))
    # the physics model is gain·V_o + offset on the RC output (defaults 1 and 0)
    np.testing.assert_allclose(
        np.asarray(physics.predict(v, dt)), np.asarray(sim.simulate(v, dt)), rtol=1e-15
    )
    # the hybrid model's D-MLP sees the RC output, windowed
    windows = sliding_windows(sim.simulate(v, dt), 5)
    expected = jax.vmap(hybrid.readout.predict_window)(windows)
    np.testing.assert_allclose(np.asarray(hybrid.predict(v, dt)), np.asarray(expected), rtol=1e-14)
    assert set(physics.parameters()) == {
        "xi_rho",
        "xi_h",
        "alpha_E",
        "alpha_I",
        "alpha_C",
        "C_clamp",
        "gain",
        "offset",
    }
    assert normal.parameters() == {}


def test_default_d_mlp_has_paper_size():
    model = make_model("hybrid")
    # 11 hidden layers × 10 neurons on a 60-sample window (paper Sec. II-B):
    # input layer 60·10 + 10, ten hidden-to-hidden 10·10 + 10, output 10 + 1
    by_hand = 60 * 10 + 10 + 10 * (10 * 10 + 10) + 10 + 1
    assert by_hand == 1721
    assert model.readout.n_weights == by_hand
    assert model.readout.window == 60
    assert model.simulation.n_stages == 45


def test_bad_kind_and_bad_frozen_name():
    with pytest.raises(InputError):
        make_model("autoregressive")
    model = make_model("physics", simulation=RCNetwork(n_stages=3))
    with pytest.raises(InputError):
        model.trainable({"network"})  # a physics model has no D-MLP
    with pytest.raises(InputError):
        model.trainable({"xi"})
    with pytest.raises(InputError):
        WindowedMLP(window=0, key=jax.random.key(0))
    # known names are accepted and mark exactly those leaves as fixed
    spec = model.trainable({"xi_h", "gain"})
    assert spec.simulation.raw["xi_h"] is False and spec.simulation.raw["xi_rho"] is True
    assert spec.readout.raw["gain"] is False and spec.readout.raw["offset"] is True


def test_models_are_non_autoregressive():
    # predict has no access to w at all
    assert "w" not in inspect.signature(Model.predict).parameters
    dt = 1 / 30
    n = 120
    v = h.step_drive(n, seed=2)
    w1 = np.sin(np.arange(n) / 7.0)
    w2 = np.random.default_rng(0).normal(size=n)
    model = make_model("hybrid", simulation=RCNetwork(n_stages=5), window=5, depth=2, width=4)
    rec1 = Recording.from_arrays(v_in=v, w=w1, rate=1 / dt)
    rec2 = Recording.from_arrays(v_in=v, w=w2, rate=1 / dt)
    p1 = Problem(model, [series_from_recording(rec1)])
    p2 = Problem(model, [series_from_recording(rec2)])
    theta = p1.flatten(model)
    np.testing.assert_array_equal(np.asarray(theta), np.asarray(p2.flatten(model)))
    for split in ("train", "test", "validation"):
        np.testing.assert_array_equal(
            np.asarray(p1.prediction(theta, split)), np.asarray(p2.prediction(theta, split))
        )
    # the measured w does enter the residuals (so the test above is not vacuous)
    assert not np.allclose(np.asarray(p1.residuals(theta)), np.asarray(p2.residuals(theta)))
