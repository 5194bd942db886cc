"""The RC network (Eqs 4–14) against independent references.

References: a hand-written numpy transcription of Table 1 and Eqs 4–13
(tests/helpers.py), scipy.signal (bilinear_zpk + sosfilt, freqs_zpk,
cont2discrete + dlsim), an exact matrix-exponential solution for a smooth
input, the diffrax reference, and central finite differences.
"""

import equinox as eqx
import helpers as h
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.signal

from hybrid import InputError, RCNetwork, Strip, reference_response

PARAMETER_SETS = [
    # (xi_rho, xi_h, alpha_E, alpha_I, alpha_C, C_clamp, N)
    (10.0, 1.0, 0.5, 0.5, 0.5, 0.05, 45),  # library defaults
    (3.0, 0.7, 0.2, 0.8, 0.35, 0.01, 5),
    (50.0, 2.5, 0.9, 0.1, 0.6, 0.2, 45),
    (0.8, 1.3, 0.05, 0.95, 0.99, 1e-3, 1),
]


def _network(params, **kwargs):
    xi_rho, xi_h, a_E, a_I, a_C, C_clamp, n = params
    return RCNetwork(xi_rho, xi_h, a_E, a_I, a_C, C_clamp, n_stages=n, **kwargs)


# --------------------------------------------------------------------------- Table 1
def test_strip_constants_by_hand():
    strip = Strip()
    # RE_clamp = 1.06e-7 Ω·m × 22e-3 m / (5.5e-3 m × 1e-6 m) = 1.06e-7 × 4e6 = 0.424 Ω
    assert strip.RE_clamp == pytest.approx(0.4240, rel=1e-12)
    # R_M = 22e-3 / (10.26 × 5.5e-3 × 183e-6) = 22e-3 / 1.032669e-5 = 2130.40 Ω (4 digits by hand)
    assert strip.R_M == pytest.approx(2130.4, rel=1e-4)
    # and both against the Table 1 transcription in helpers, to rounding
    assert strip.RE_clamp == pytest.approx(h.table1_RE_clamp(), rel=1e-14)
    assert strip.R_M == pytest.approx(h.table1_R_M(), rel=1e-14)


def test_strip_rejects_bad_geometry():
    with pytest.raises(InputError):
        Strip(length=-1.0)
    with pytest.raises(InputError):
        Strip(width=float("nan"))
    with pytest.raises(InputError):
        Strip.from_dict({"length": 0.02, "colour": 1.0})


# --------------------------------------------------------------------------- Eqs 4–13
@pytest.mark.parametrize("params", PARAMETER_SETS)
def test_stage_elements_and_zpk_match_hand_implementation(params):
    net = _network(params)
    RE, RI, C, RM = h.stage_elements_np(*params)
    e = net.stage_elements()
    # Eqs 4–9 and Table 1, 1e-12 relative (a few float64 roundings apart)
    np.testing.assert_allclose(e["RE"], RE, rtol=1e-12)
    np.testing.assert_allclose(e["RI"], RI, rtol=1e-12)
    np.testing.assert_allclose(e["C"], C, rtol=1e-12)
    np.testing.assert_allclose(e["RM"], RM, rtol=1e-12)
    assert e["RE"].shape == (params[-1] + 1,)
    G, Z, P = h.stage_zpk_np(*params)
    G_lib, Z_lib, P_lib = net.stage_zpk()
    # Eqs 11–13, 1e-12 relative
    np.testing.assert_allclose(G_lib, G, rtol=1e-12)
    np.testing.assert_allclose(Z_lib, Z, rtol=1e-12)
    np.testing.assert_allclose(P_lib, P, rtol=1e-12)


def test_clamp_and_tip_follow_attenuation_coefficients():
    # Eqs 7–9: the last compartment (k = N) is the tip, value_clamp / alpha.
    net = RCNetwork(alpha_E=0.25, alpha_I=0.4, alpha_C=0.8, C_clamp=0.02, n_stages=7)
    e = net.stage_elements()
    RI_clamp = h.table1_RI_clamp(10.0, 1.0)
    assert float(e["RE"][0]) == pytest.approx(h.table1_RE_clamp(), rel=1e-13)
    assert float(e["RE"][-1]) == pytest.approx(h.table1_RE_clamp() / 0.25, rel=1e-13)
    assert float(e["RI"][0]) == pytest.approx(RI_clamp, rel=1e-13)
    assert float(e["RI"][-1]) == pytest.approx(RI_clamp / 0.4, rel=1e-13)
    assert float(e["C"][-1]) == pytest.approx(0.02 / 0.8, rel=1e-13)


# --------------------------------------------------------------------------- Eq 14
@pytest.mark.parametrize("params", [PARAMETER_SETS[0], PARAMETER_SETS[2]])
def test_frequency_response_matches_scipy_freqs_zpk(params):
    net = _network(params)
    G, Z, P = h.stage_zpk_np(*params)
    f = np.concatenate([[0.0], np.logspace(-3, 3, 61)])
    _, expected = scipy.signal.freqs_zpk(-Z, -P, np.prod(G), worN=2 * np.pi * f)
    got = np.asarray(net.frequency_response(f))
    # complex relative error ≤ 1e-10 at every frequency
    assert np.max(np.abs(got - expected) / np.abs(expected)) < 1e-10


def test_dc_gain_is_product_and_step_response_final_value():
    params = PARAMETER_SETS[0]
    G, Z, P = h.stage_zpk_np(*params)
    dc = np.prod(G * Z / P)
    net = _network(params)
    # H(0) = Π G_k Z_k / P_k, real, 1e-12 relative
    H0 = complex(net.frequency_response(0.0))
    assert H0.real == pytest.approx(dc, rel=1e-12)
    assert abs(H0.imag) < 1e-15
    # a unit step held 2000 samples at 30 Hz (66 s ≫ 1/P_min ≈ 0.93 s) has settled:
    # both discretisations keep the DC gain exactly (z = 1 ↔ s = 0), 1e-10 relative
    step = np.ones(2000)
    for method in ("tustin", "zoh"):
        y = np.asarray(_network(params, method=method).simulate(step, 1 / 30))
        assert y[-1] == pytest.approx(dc, rel=1e-10), method
        assert abs(y[-1] - y[0]) > 1e-3  # a real transient, not a constant


def test_state_space_realises_the_cascade():
    # the library's (A, B, C, D) has the transfer function of Eq 14 (≤ 1e-10 rel)
    net = RCNetwork(n_stages=12)
    A, B, C, D = (np.asarray(m) for m in net.state_space())
    G, Z, P = h.stage_zpk_np(10.0, 1.0, 0.5, 0.5, 0.5, 0.05, 12)
    f = np.logspace(-2, 2, 9)
    s = 2j * np.pi * f
    H = np.array([C @ np.linalg.solve(si * np.eye(len(B)) - A, B) + D for si in s])
    expected = h.cascade_frequency_response(G, Z, P, f)
    assert np.max(np.abs(H - expected) / np.abs(expected)) < 1e-10


# --------------------------------------------------------------------------- Tustin
def test_tustin_matches_scipy_sosfilt():
    params = PARAMETER_SETS[0]
    dt = 1 / 30
    G, Z, P = h.stage_zpk_np(*params)
    sos = []
    for g, z, p in zip(G, Z, P):
        zd, pd, kd = scipy.signal.bilinear_zpk([-z], [-p], g, fs=1 / dt)
        sos.append(scipy.signal.zpk2sos(zd, pd, kd)[0])
    sos = np.array(sos)
    x = np.random.default_rng(1).normal(size=10_000)
    expected = scipy.signal.sosfilt(sos, x)
    got = np.asarray(_network(params).simulate(x, dt))
    # ≤ 1e-10 relative (same recursion, independent coefficients)
    assert h.relative_error(got, expected) < 1e-10


def test_tustin_converges_at_second_order():
    # exact continuous response to u = 1 − cos(πt) (0.5 Hz, u(0) = u'(0) = 0)
    params = PARAMETER_SETS[0]
    G, Z, P = h.stage_zpk_np(*params)
    A, B, C, D = h.cascade_state_space(G, Z, P)
    net = _network(params)
    errors = []
    for rate in (30, 60, 120, 240):
        t = np.arange(4 * rate) / rate
        exact = h.exact_one_minus_cos_response(A, B, C, D, np.pi, t)
        y = np.asarray(net.simulate(h.smooth_ramp_sine(t, 0.5), 1 / rate))
        errors.append(np.max(np.abs(y - exact)))
    ratios = np.array(errors[:-1]) / np.array(errors[1:])
    # second order: ×4 per halving of Δt (first order would give ×2)
    assert np.all(ratios > 3.0), (errors, ratios)
    assert np.all(ratios < 5.0), (errors, ratios)
    # and small in absolute terms at the paper's 30 fps (|y| ≈ 2 V): < 1e-3 relative
    assert errors[0] < 2e-3


# --------------------------------------------------------------------------- ZOH
def test_zoh_matches_scipy_cont2discrete_and_dlsim():
    params = PARAMETER_SETS[2]
    dt = 1 / 30
    G, Z, P = h.stage_zpk_np(*params)
    A, B, C, D = h.cascade_state_space(G, Z, P)
    Ad, Bd, Cd, Dd, _ = scipy.signal.cont2discrete(
        (A, B[:, None], C[None, :], np.array([[D]])), dt, method="zoh"
    )
    u = h.step_drive(200, seed=3)
    _, expected, _ = scipy.signal.dlsim((Ad, Bd, Cd, Dd, dt), u)
    got = np.asarray(_network(params, method="zoh").simulate(u, dt))
    # ≤ 1e-10 relative (two exact ZOH discretisations, different realisations)
    assert h.relative_error(got, expected[:, 0]) < 1e-10


@pytest.mark.parametrize("length", [1, 15, 16, 17, 50])
def test_zoh_blocks_match_dlsim_at_every_length(length):
    """The lifted blocks (`lifted_blocks`: powers, not a scan of full products) on records that end mid-block."""
    params = PARAMETER_SETS[1]
    dt = 1 / 30
    A, B, C, D = h.cascade_state_space(*h.stage_zpk_np(*params))
    system = scipy.signal.cont2discrete((A, B[:, None], C[None, :], np.array([[D]])), dt, method="zoh")
    u = h.step_drive(length, seed=4)
    _, expected, _ = scipy.signal.dlsim((*system[:4], dt), u)
    got = np.asarray(_network(params, method="zoh").simulate(u, dt))
    assert h.relative_error(got, expected[:, 0]) < 1e-10


def test_zoh_matches_diffrax_reference():
    net = RCNetwork(xi_rho=4.0, alpha_E=0.3, alpha_C=0.4, C_clamp=0.02, n_stages=20, method="zoh")
    u = h.step_drive(200, seed=4)
    dt = 1 / 30
    got = np.asarray(net.simulate(u, dt))
    expected = np.asarray(reference_response(net, u, dt, hold="zoh"))
    # ≤ 1e-8 relative (diffrax Kvaerno5 at rtol 1e-10)
    assert h.relative_error(got, expected) < 1e-8


def test_linear_hold_reference_and_tustin_match_exact_smooth_response():
    # the diffrax reference with a linear hold, and Tustin, both approximate the
    # continuous response of a smooth input to O(Δt²): checked at 240 Hz
    net = RCNetwork(n_stages=10)
    rate = 240
    t = np.arange(480) / rate
    u = h.smooth_ramp_sine(t, 0.5)
    ref = np.asarray(reference_response(net, u, 1 / rate, hold="linear"))
    G, Z, P = h.stage_zpk_np(10.0, 1.0, 0.5, 0.5, 0.5, 0.05, 10)
    exact = h.exact_one_minus_cos_response(*h.cascade_state_space(G, Z, P), np.pi, t)
    # diffrax with a linear hold vs the exact solution: interpolation error of
    # 1 − cos at Δt = 1/240 s is ≤ Δt² ω² / 8 ≈ 2e-5 of the amplitude
    assert h.relative_error(ref, exact) < 1e-4
    tustin = np.asarray(net.simulate(u, 1 / rate))
    assert h.relative_error(tustin, exact) < 1e-4


# --------------------------------------------------------------------------- gradients
def _loss_of_raw(net, v, dt):
    weights = jnp.linspace(0.5, 1.5, v.shape[0])

    @jax.jit
    def loss(raw):
        y = eqx.tree_at(lambda n: n.raw, net, raw).simulate(v, dt)
        return jnp.sum(weights * jnp.sin(y) ** 2)

    return loss


@pytest.mark.parametrize("method", ["tustin", "zoh"])
def test_gradient_matches_central_finite_differences(method):
    net = RCNetwork(
        xi_rho=6.0, xi_h=1.5, alpha_E=0.3, alpha_I=0.6, alpha_C=0.45, C_clamp=0.03, n_stages=12, method=method
    )
    v = jnp.asarray(h.step_drive(300, seed=5))
    loss = _loss_of_raw(net, v, 1 / 30)
    raw = net.raw
    grad = jax.grad(loss)(raw)
    step = 1e-5
    for name in raw:
        up = dict(raw, **{name: raw[name] + step})
        down = dict(raw, **{name: raw[name] - step})
        fd = (float(loss(up)) - float(loss(down))) / (2 * step)
        # central differences: truncation ~ step² ≈ 1e-10, rounding ~ 1e-16/step ≈ 1e-11
        assert float(grad[name]) == pytest.approx(fd, rel=1e-5, abs=1e-9), name
    # the loss actually depends on every parameter except through the ξ ratio
    assert all(abs(float(g)) > 1e-6 for g in grad.values())
    # ξρ and ξh enter only as ξρ/ξh: ∂/∂log ξρ = −∂/∂log ξh
    assert float(grad["xi_rho"]) == pytest.approx(-float(grad["xi_h"]), rel=1e-10)


@pytest.mark.parametrize("method", ["tustin", "zoh"])
def test_forward_jacobian_matches_central_finite_differences(method):
    """Forward mode in every direction at once (as LM builds J): the lifted blocks' own JVP (`_block_states`)."""
    net = RCNetwork(
        xi_rho=6.0, xi_h=1.5, alpha_E=0.3, alpha_I=0.6, alpha_C=0.45, C_clamp=0.03, n_stages=12, method=method
    )
    v = jnp.asarray(h.step_drive(301, seed=6))  # several blocks, the last one part-filled
    dt = 1 / 30

    def output(raw):
        return eqx.tree_at(lambda n: n.raw, net, raw).simulate(v, dt)

    J = jax.jit(jax.jacfwd(output))(net.raw)
    step = 1e-6
    for name in net.raw:
        up = np.asarray(output(dict(net.raw, **{name: net.raw[name] + step})))
        down = np.asarray(output(dict(net.raw, **{name: net.raw[name] - step})))
        fd = (up - down) / (2 * step)
        # central differences: truncation ~ step² ≈ 1e-12, rounding ~ 1e-16/step ≈ 1e-10 of max |y|
        assert np.max(np.abs(np.asarray(J[name]) - fd)) <= 1e-7 * np.max(np.abs(fd)) + 1e-12, name


# --------------------------------------------------------------------------- parameters
def test_parameters_round_trip_physical_values():
    net = RCNetwork(xi_rho=7.0, xi_h=0.5, alpha_E=0.2, alpha_I=0.9, alpha_C=0.3, C_clamp=0.011)
    p = {k: float(v) for k, v in net.parameters().items()}
    expected = dict(xi_rho=7.0, xi_h=0.5, alpha_E=0.2, alpha_I=0.9, alpha_C=0.3, C_clamp=0.011)
    assert p == pytest.approx(expected, rel=1e-13)


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(alpha_E=1.5),
        dict(alpha_I=0.0),
        dict(alpha_C=1.0),
        dict(C_clamp=-0.01),
        dict(xi_rho=0.0),
        dict(xi_h=float("nan")),
        dict(C_clamp=float("inf")),
        dict(n_stages=0),
        dict(n_stages=2.5),
        dict(method="euler"),
    ],
)
def test_invalid_construction_raises_input_error(kwargs):
    with pytest.raises(InputError):
        RCNetwork(**kwargs)


def test_replace_sets_values_and_rejects_unknown_names():
    net = RCNetwork(n_stages=5)
    other = net.replace(xi_rho=25.0, alpha_C=0.7)
    assert float(other.parameters()["xi_rho"]) == pytest.approx(25.0, rel=1e-14)
    assert float(other.parameters()["alpha_C"]) == pytest.approx(0.7, rel=1e-14)
    # the rest is untouched, and the original is not modified
    assert float(other.parameters()["alpha_E"]) == pytest.approx(0.5, rel=1e-14)
    assert float(net.parameters()["xi_rho"]) == pytest.approx(10.0, rel=1e-14)
    assert other.n_stages == 5
    with pytest.raises(InputError):
        net.replace(xi=3.0)
    with pytest.raises(InputError):
        net.replace(alpha_E=2.0)


def test_only_the_xi_ratio_matters():
    v = h.step_drive(500, seed=6)
    a = np.asarray(RCNetwork(xi_rho=20.0, xi_h=2.0, n_stages=10).simulate(v, 1 / 30))
    b = np.asarray(RCNetwork(xi_rho=10.0, xi_h=1.0, n_stages=10).simulate(v, 1 / 30))
    c = np.asarray(RCNetwork(xi_rho=10.0, xi_h=2.0, n_stages=10).simulate(v, 1 / 30))
    assert h.relative_error(a, b) < 1e-12
    assert h.relative_error(c, b) > 1e-4  # a different ratio does change V_o


def test_reference_response_rejects_unknown_hold():
    with pytest.raises(InputError):
        reference_response(RCNetwork(n_stages=2), np.ones(4), 0.1, hold="cubic")


def test_gradients_and_vmap_through_physical_values_given_to_replace_and_the_constructor():
    """A sensitivity study differentiates in physical units: replace(C_clamp=c) and LTI(2, f_1=f) traced."""
    from hybrid import LTI

    v = jnp.asarray(h.step_drive(300, seed=5))
    by_replace = lambda c: jnp.sum(RCNetwork(n_stages=10).replace(C_clamp=c).simulate(v, 1 / 30) ** 2)
    by_constructor = lambda f: jnp.sum(LTI(2, f_1=f, zeta_1=0.3).simulate(v, 1 / 30) ** 2)
    for loss, x, step in ((by_replace, 0.02, 1e-8), (by_constructor, 1.3, 1e-6)):
        fd = (float(loss(x + step)) - float(loss(x - step))) / (2 * step)
        # central differences: truncation ~ step², rounding ~ 1e-16 · loss / step
        assert float(jax.grad(loss)(x)) == pytest.approx(fd, rel=1e-6), loss
    ends = jax.vmap(lambda f: LTI(2, f_1=f).simulate(v, 1 / 30)[-1])(jnp.array([1.0, 2.0]))
    assert np.asarray(ends) == pytest.approx(
        [float(LTI(2, f_1=f).simulate(v, 1 / 30)[-1]) for f in (1.0, 2.0)]
    )
    with pytest.raises(InputError, match="C_clamp must be positive"):  # a concrete value is still checked
        RCNetwork().replace(C_clamp=-1.0)
