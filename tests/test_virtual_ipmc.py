"""The virtual IPMC strip, each stage against an independent reference.

Tolerances are stated per test; everything runs in numpy float64.
"""

import dataclasses
import json
import math

import numpy as np
import pytest
import scipy.integrate
import scipy.optimize
import scipy.signal

from hybrid import InputError
from hybrid.ipmc._virtual_elements import build_ladder, build_model, dac_output, electrical, mechanics
from hybrid.ipmc._virtual_ipmc import VirtualRecording, fine_outputs, simulate_virtual_ipmc
from hybrid.ipmc._virtual_parameters import VirtualIPMCParameters

QUIET = VirtualIPMCParameters(noise_std_mm=0.0)


def _drive(seconds, fs=30.0, seed=0, amplitude=2.0):
    """A PRBS-like step drive: ±amplitude levels held 0.1–3 s."""
    rng = np.random.default_rng(seed)
    n = int(round(seconds * fs))
    v = np.empty(n)
    i, sign = 0, 1.0
    while i < n:
        hold = int(rng.integers(3, 90))
        v[i : i + hold] = sign * amplitude
        sign = -sign if rng.random() < 0.7 else sign
        i += hold
    return np.arange(n) / fs, v


def _step(seconds, volts, params=QUIET, fs=30.0):
    t = np.arange(int(round(seconds * fs))) / fs
    return simulate_virtual_ipmc(t, np.full(t.size, volts), params)


# --- the loaded RC line ---------------------------------------------------------------


def _ladder_voltages(lad, s):
    """Capacitor voltages per volt of drive at complex frequency s (s = 0: DC).

    Independent of the state space: backward impedance recursion from the
    open tip, then the voltage divider forward from the source.
    """
    n = len(lad.re)
    if s == 0:
        shunt = lad.rm.astype(complex)
        cap = np.ones(n, complex)  # no capacitor current at DC: v_k = V_k
    else:
        branch = lad.ri + 1.0 / (s * lad.c)
        shunt = 1.0 / (1.0 / lad.rm + 1.0 / branch)
        cap = (1.0 / (s * lad.c)) / branch
    z = np.empty(n, complex)  # impedance seen at node k looking toward the tip
    z[-1] = shunt[-1]
    for k in range(n - 2, -1, -1):
        z[k] = 1.0 / (1.0 / shunt[k] + 1.0 / (lad.re[k + 1] + z[k + 1]))
    node = np.empty(n, complex)
    node[0] = z[0] / (lad.r_source + lad.re[0] + z[0])
    for k in range(1, n):
        node[k] = node[k - 1] * z[k] / (lad.re[k] + z[k])
    return node * cap


def test_line_dc_charge_matches_resistive_network():
    # Tolerance 1e-12 relative: two exact linear solves of the same network.
    lad = build_ladder(QUIET)
    a_e, b_e, nodes = electrical(lad)
    v_dc = np.linalg.solve(a_e, -b_e)
    expected = _ladder_voltages(lad, 0).real
    np.testing.assert_allclose(v_dc, expected, rtol=1e-12)
    np.testing.assert_allclose(lad.c * v_dc, lad.c * expected, rtol=1e-12)  # q_k = C_k v_k
    # At DC the node voltages equal the capacitor voltages (no branch current).
    np.testing.assert_allclose(nodes @ np.append(v_dc, 1.0), v_dc, rtol=1e-12)
    # R_M ≫ line resistance: the whole strip charges to almost the full drive.
    assert 0.999 < v_dc.min() < v_dc.max() < 1.0


@pytest.mark.parametrize("omega", [0.3, 3.0, 30.0, 300.0])
def test_line_frequency_response_matches_impedance_recursion(omega):
    # Tolerance 1e-10 relative: the loading of each section by the rest of the line.
    lad = build_ladder(QUIET)
    a_e, b_e, _ = electrical(lad)
    s = 1j * omega
    state_space = np.linalg.solve(s * np.eye(len(b_e)) - a_e, b_e)
    np.testing.assert_allclose(state_space, _ladder_voltages(lad, s), rtol=1e-10)


def test_single_compartment_step_matches_closed_form():
    # One compartment: Thevenin source V_th = u R_M/(R_M + R1), R_th = R1 ∥ R_M,
    # R1 = R_s + RE; the capacitor charges through RI + R_th:
    # v(t) = V_th (1 − exp(−t/τ)), τ = C (RI + R_th).  Tolerance 1e-12.
    p = dataclasses.replace(QUIET, n_compartments=1)
    lad = build_ladder(p)
    assert lad.re[0] == pytest.approx(0.424) and lad.ri[0] == pytest.approx(8.48)
    a_e, b_e, _ = electrical(lad)
    r1 = lad.r_source + lad.re[0]
    rm, ri, c = lad.rm[0], lad.ri[0], lad.c[0]
    v_th = rm / (rm + r1)
    tau = c * (ri + r1 * rm / (r1 + rm))
    h, os_ = 1 / 480, 16
    u = np.full(20, 1.7)
    v = fine_outputs(a_e, b_e, np.eye(1), u, h, os_)[:, 0]
    t = np.arange(v.size) * h
    np.testing.assert_allclose(v, 1.7 * v_th * (1 - np.exp(-t / tau)), rtol=1e-12, atol=1e-15)


def test_exact_discretisation_matches_lsim_and_ode():
    # The oversampled ZOH recursion vs scipy.signal.lsim (ZOH input) on the fine
    # grid, tolerance 1e-10 of the peak; and vs an adaptive ODE solve restarted at
    # each DAC update, tolerance 1e-7 of the peak.
    p = QUIET
    model = build_model(p)
    rng = np.random.default_rng(3)
    u = dac_output(rng.uniform(-3, 3, 12), p)
    dt, os_ = 1 / 30, 16
    h = dt / os_
    y = fine_outputs(model.a, model.b, model.c_out, u, h, os_)
    t = np.arange(u.size * os_ + 1) * h
    u_fine = np.append(np.repeat(u, os_), u[-1])
    sys = (model.a, model.b[:, None], model.c_out, np.zeros((model.c_out.shape[0], 1)))
    _, y_ref, _ = scipy.signal.lsim(sys, u_fine, t, interp=False)
    scale = np.abs(y).max()
    np.testing.assert_allclose(y, y_ref, rtol=0, atol=1e-10 * scale)

    x = np.zeros(len(model.b))
    ends = []
    for n, un in enumerate(u):
        sol = scipy.integrate.solve_ivp(
            lambda _t, x, un=un: model.a @ x + model.b * un,
            (n * dt, (n + 1) * dt),
            x,
            method="Radau",
            jac=model.a,
            rtol=1e-12,
            atol=1e-14,
        )
        x = sol.y[:, -1]
        ends.append(model.c_out @ x)
    np.testing.assert_allclose(y[os_::os_], np.array(ends), rtol=0, atol=1e-7 * scale)


def test_time_constants_in_plausible_range():
    tau = build_model(QUIET).derived["electrical_time_constants_s"]
    assert 0.1 < min(tau) and max(tau) < 1.0


# --- actuation ------------------------------------------------------------------------


def test_dac_quantisation_clipping_and_hold():
    p = QUIET
    step = 2 * p.full_scale_v / 4095
    v = np.random.default_rng(0).uniform(-2.9, 2.9, 1000)
    u = dac_output(v, p)
    codes = (u / p.full_scale_v + 1) * 4095 / 2
    np.testing.assert_allclose(codes, np.round(codes), atol=1e-9)  # on the 12-bit grid
    assert np.abs(u - v).max() <= step / 2 + 1e-12
    assert np.unique(
        np.round(np.diff(np.unique(dac_output(np.linspace(-1, 1, 20000), p))) / step, 9)
    ).tolist() == [1.0]
    np.testing.assert_array_equal(dac_output(np.array([-10.0, -3.0, 3.0, 7.0]), p), [-3, -3, 3, 3])

    # ZOH: a 60 fps camera on a 30 Hz drive sees each DAC value for two frames.
    t, v = _drive(4.0)
    v = v + 5.0 * np.sin(t)  # reaches past the rails
    rec = simulate_virtual_ipmc(t, v, dataclasses.replace(p, camera_fps=60.0))
    assert rec.t.size == 2 * t.size
    np.testing.assert_allclose(rec.t, np.arange(rec.t.size) / 60.0, atol=1e-12)
    np.testing.assert_array_equal(rec.v_in[0::2], dac_output(v, p))
    np.testing.assert_array_equal(rec.v_in[1::2], dac_output(v, p))
    assert rec.v_in.max() == 3.0 and rec.v_in.min() == -3.0


# --- slow dynamics, nonlinearity, mechanics ---------------------------------------------


def test_back_relaxation_fraction_and_time_constant():
    # Fast electrics (C_clamp = 0.1 mF: τ ≈ 3 ms), small drive (tanh linear to
    # 1e-4), no exposure: w(t) = W (1 − β (1 − exp(−t/τ_b))) after the mode settles.
    # Tolerance 1e-3 on τ_b; 5e-3 on β, since the charging and the mode lag the
    # start of the relaxation by ≈ 20 ms (a 0.3 % change of its amplitude).
    p = dataclasses.replace(QUIET, clamp_capacitance_f=1e-4, exposure_s=0.0)
    rec = _step(40.0, 0.05, p)
    late = rec.t >= 1.0

    def model(t, a, b, tau):
        return a + b * np.exp(-t / tau)

    (a, b, tau), _ = scipy.optimize.curve_fit(model, rec.t[late], rec.w_true[late], p0=(0.1, 0.02, 5))
    assert tau == pytest.approx(p.relaxation_time_s, rel=1e-3)
    assert b / (a + b) == pytest.approx(p.relaxation_fraction, rel=5e-3)
    w0 = a + b
    at_tau = np.interp(p.relaxation_time_s, rec.t, rec.w_true)
    assert at_tau / w0 == pytest.approx(1 - p.relaxation_fraction * (1 - math.exp(-1)), rel=5e-3)

    # With the default (slow) electrics the late decay is still τ_b.
    rec = _step(40.0, 0.05)
    late = rec.t >= 5.0
    (_, _, tau), _ = scipy.optimize.curve_fit(model, rec.t[late], rec.w_true[late], p0=(0.1, 0.02, 5))
    assert tau == pytest.approx(QUIET.relaxation_time_s, rel=1e-3)


def test_static_gain_and_compression():
    # Held 90 s (15 τ_b): the static tip at ±V_fs falls short of the small-signal
    # slope by `compression` (tolerance 1e-4), and 2× amplitude gives less than 2×.
    p = QUIET
    static = {}
    for volts in (0.01, 1.5, 3.0, -3.0):
        rec = _step(90.0, volts, p)
        static[volts] = rec.w_true[-1] / rec.v_in[-1]
    assert static[0.01] == pytest.approx(p.gain_mm_per_v, rel=1e-4)
    assert 1 - static[3.0] / static[0.01] == pytest.approx(p.compression, abs=1e-4)
    assert static[-3.0] == pytest.approx(static[3.0], rel=1e-9)  # odd symmetry
    ratio = static[3.0] / static[1.5]  # response(2A) / (2 response(A))
    assert ratio < 1
    # tanh(x)/x ≈ 1 − x²/3: the shortfall at half amplitude is ≈ c/4.
    assert ratio == pytest.approx((1 - p.compression) / (1 - p.compression / 4), abs=0.01)

    linear = dataclasses.replace(p, compression=0.0)
    rec_a, rec_b = _step(20.0, 1.0, linear), _step(20.0, 2.0, linear)
    np.testing.assert_allclose(
        rec_b.w_true, 2 * rec_a.w_true * rec_b.v_in[0] / (2 * rec_a.v_in[0]), rtol=1e-9, atol=1e-12
    )


def test_mechanics_is_exact_for_piecewise_linear_input():
    # First mode vs scipy.signal.lsim with linear interpolation (exact FOH), 1e-9.
    p = QUIET
    h = 1 / 480
    w_qs = np.concatenate([[0.0], np.random.default_rng(1).normal(size=600).cumsum() * 0.1])
    w = mechanics(p, h, w_qs)
    wn, z = 2 * np.pi * p.mode_frequency_hz, p.damping_ratio
    sys = scipy.signal.lti([wn * wn], [1, 2 * z * wn, wn * wn])
    _, ref, _ = scipy.signal.lsim(sys, w_qs, np.arange(w_qs.size) * h, interp=True)
    np.testing.assert_allclose(w, ref, rtol=0, atol=1e-9 * np.abs(ref).max())


def test_exposure_averages_the_displacement():
    # 30 fps with a 1/60 s exposure equals the trapezoid mean of the same strip
    # sampled instantaneously at the internal rate over [t_j, t_j + 1/60]; 1e-12.
    t, v = _drive(5.0)
    avg = simulate_virtual_ipmc(t, v, QUIET)
    fine = simulate_virtual_ipmc(t, v, dataclasses.replace(QUIET, camera_fps=480.0, exposure_s=0.0))
    w = fine.w_true
    assert w.size == 16 * t.size + 1
    windows = np.stack([w[16 * j : 16 * j + 9] for j in range(t.size)])
    trapezoid = (windows[:, :-1] + windows[:, 1:]).sum(axis=1) / 16
    np.testing.assert_allclose(avg.w_true, trapezoid, rtol=0, atol=1e-12)
    np.testing.assert_allclose(
        fine.w_true[::16][: t.size],
        simulate_virtual_ipmc(t, v, dataclasses.replace(QUIET, exposure_s=0.0)).w_true,
        rtol=0,
        atol=1e-12,
    )


# --- measurement noise and the recording ----------------------------------------------


def test_noise_std_and_seeded_determinism():
    t, v = _drive(300.0)
    p = VirtualIPMCParameters()
    a = simulate_virtual_ipmc(t, v, p, seed=1)
    b = simulate_virtual_ipmc(t, v, p, seed=1)
    c = simulate_virtual_ipmc(t, v, p, seed=2)
    noise = a.w - a.w_true
    # 9000 samples: the std's standard error is 0.75 %; tolerance 4 %.
    assert noise.std() == pytest.approx(p.noise_std_mm, rel=0.04)
    assert abs(noise.mean()) < 4 * p.noise_std_mm / math.sqrt(noise.size)
    np.testing.assert_array_equal(a.w, b.w)
    np.testing.assert_array_equal(a.w_true, c.w_true)
    assert not np.array_equal(a.w, c.w)

    pix = simulate_virtual_ipmc(t, v, dataclasses.replace(p, pixel_mm=0.05), seed=1)
    np.testing.assert_allclose(pix.w / 0.05, np.round(pix.w / 0.05), atol=1e-9)
    assert np.abs(pix.w - a.w).max() <= 0.025 + 1e-12


def test_recording_shape_and_metadata():
    t, v = _drive(300.0)
    rec = simulate_virtual_ipmc(t + 12.5, v)
    assert isinstance(rec, VirtualRecording)
    np.testing.assert_array_equal(rec.t, t + 12.5)
    for arr in (rec.v_in, rec.w, rec.w_true):
        assert arr.shape == t.shape and np.all(np.isfinite(arr))
    meta = json.loads(json.dumps(rec.metadata))
    assert meta["seed"] == 0 and meta["parameters"]["n_compartments"] == 46
    assert meta["drive_rate_hz"] == pytest.approx(30.0) and meta["internal_rate_hz"] == pytest.approx(480.0)
    assert 3.5 < rec.w_true.max() < 6 and -6 < rec.w_true.min() < -3.5
    # Starts at rest: the first frame has barely moved.
    assert abs(rec.w_true[0]) < 0.05


# --- bad input ------------------------------------------------------------------------


@pytest.mark.parametrize(
    "change",
    [
        {"length_m": 0.0},
        {"width_m": -1.0},
        {"electrode_resistivity_ohm_m": float("nan")},
        {"interface_ratio": float("inf")},
        {"clamp_capacitance_f": 0},
        {"alpha_e": 0.0},
        {"alpha_i": 1.5},
        {"alpha_c": -0.2},
        {"source_resistance_ohm": -0.1},
        {"n_compartments": 0},
        {"n_compartments": 4.0},
        {"n_compartments": True},
        {"relaxation_time_s": 0.0},
        {"relaxation_fraction": 1.0},
        {"relaxation_fraction": -0.1},
        {"gain_mm_per_v": 0.0},
        {"compression": 0.95},
        {"compression": -0.01},
        {"mode_frequency_hz": 0.0},
        {"damping_ratio": 0.0},
        {"dac_bits": 0},
        {"full_scale_v": -3.0},
        {"camera_fps": 0.0},
        {"exposure_s": -1e-3},
        {"camera_fps": 100.0, "exposure_s": 0.02},
        {"oversample": 0},
        {"oversample": 2.5},
        {"noise_std_mm": -0.1},
        {"pixel_mm": 0.0},
        {"length_m": "22 mm"},
    ],
)
def test_bad_parameters_raise(change):
    with pytest.raises(InputError):
        VirtualIPMCParameters(**change)


@pytest.mark.parametrize(
    "t, v, kwargs",
    [
        (np.arange(10) / 30, np.zeros(9), {}),  # lengths differ
        (np.zeros((2, 5)), np.zeros((2, 5)), {}),  # not 1-D
        (np.zeros(1), np.zeros(1), {}),  # too short
        (np.arange(10) / 30, np.r_[np.zeros(9), np.nan], {}),  # non-finite voltage
        (np.r_[np.arange(9) / 30, np.inf], np.zeros(10), {}),  # non-finite time
        (np.r_[0, 0.03, 0.07, 0.1], np.zeros(4), {}),  # non-uniform
        (np.arange(10)[::-1] / 30, np.zeros(10), {}),  # decreasing
        (np.arange(10) / 30, ["a"] * 10, {}),  # not numbers
        (np.arange(10) / 30, np.zeros(10), {"seed": -1}),
        (np.arange(10) / 30, np.zeros(10), {"seed": 1.5}),
        (np.arange(10) / 30, np.zeros(10), {"params": {"length_m": 0.02}}),
        (np.arange(10) / 100, np.zeros(10), {}),  # 1/60 s exposure > 10 ms frame period
    ],
)
def test_bad_drive_raises(t, v, kwargs):
    with pytest.raises(InputError):
        simulate_virtual_ipmc(t, v, **kwargs)
