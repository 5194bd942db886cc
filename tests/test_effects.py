"""Effects (hybrid.discovery._effects) against independent references, and the hidden-effect generator."""

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.signal

import hybrid
from hybrid import AbstractSimulation, InputError, Positive, RCNetwork, encode, make_drive
from hybrid.discovery._effect_set import EFFECTS, NAMED_ONLY
from hybrid.discovery._effect_stack import EffectStack, extend
from hybrid.discovery._effects import (
    FOH_SERIES_BELOW,
    Backlash,
    BackRelaxation,
    Creep,
    Delay,
    Drift,
    DriveEven,
    DriveSaturation,
    EvenResponse,
    Hysteresis,
    Lag,
    Resonance,
    Saturation,
    affine_recurrence,
    first_order_foh,
    play,
)
from hybrid.discovery._hysteresis import bouc_wen_and_memory, bouc_wen_state
from hybrid.ipmc._synthetic import SyntheticStrip, random_effect, random_strip, synthetic_recording

DT = 1 / 30
#: The built-ins a simulation without a state-space form (the RC network) takes: all but the inside ones.
OUTSIDE = [name for name, cls in EFFECTS.items() if cls.place != "inside"]


@pytest.fixture(scope="module")
def signal():
    rng = np.random.default_rng(0)
    return np.cumsum(rng.standard_normal(600)) * 0.05


def test_affine_recurrence_matches_a_loop():
    rng = np.random.default_rng(1)
    a, b = rng.uniform(0.2, 1.0, 257), rng.standard_normal(257)
    x, expected = 0.7, []
    for ai, bi in zip(a, b):
        x = ai * x + bi
        expected.append(x)
    np.testing.assert_allclose(affine_recurrence(jnp.asarray(a), jnp.asarray(b), 0.7), expected, rtol=1e-12)


def test_back_relaxation_is_a_lagged_first_order_lowpass(signal):
    y = BackRelaxation(relaxation_time_s=2.0, relaxation_fraction=0.4).apply(jnp.asarray(signal), DT)
    a = np.exp(-DT / 2.0)
    slow = scipy.signal.lfilter([0.0, 1.0 - a], [1.0, -a], signal)  # exact ZOH of 1/(τs + 1)
    np.testing.assert_allclose(y, signal - 0.4 * slow, atol=1e-12)


def test_creep_is_a_lagged_first_order_lowpass_added(signal):
    y = Creep(creep_time_s=2.0, creep_fraction=0.07).apply(jnp.asarray(signal), DT)
    a = np.exp(-DT / 2.0)
    slow = scipy.signal.lfilter([0.0, 1.0 - a], [1.0, -a], signal)  # exact ZOH of 1/(τs + 1)
    np.testing.assert_allclose(y, signal + 0.07 * slow, atol=1e-12)
    step = Creep(creep_time_s=3.0, creep_fraction=0.1).apply(jnp.ones(3000), 0.01)
    assert float(step[-1]) == pytest.approx(1.1, abs=1e-4)  # a held drive's response creeps on by β


def test_back_relaxation_step_relaxes_by_the_fraction():
    step = jnp.ones(3000)
    y = BackRelaxation(relaxation_time_s=3.0, relaxation_fraction=0.6).apply(step, 0.01)
    assert float(y[0]) == pytest.approx(1.0)
    assert float(y[300]) == pytest.approx(1 - 0.6 * (1 - np.exp(-300 * 0.01 / 3.0)), rel=1e-9)
    assert float(y[-1]) == pytest.approx(0.4, abs=1e-4)


def test_resonance_matches_scipy_lsim(signal):
    """lsim interpolates the input linearly between samples: the first-order hold used here."""
    f, z = 3.0, 0.08
    w = 2 * np.pi * f
    y = Resonance(resonance_frequency_hz=f, resonance_damping=z).apply(jnp.asarray(signal), DT)
    system = scipy.signal.StateSpace([[0, 1], [-w * w, -2 * z * w]], [[0], [w * w]], [[1, 0]], [[0]])
    _, expected, _ = scipy.signal.lsim(system, signal, np.arange(len(signal)) * DT, X0=[signal[0], 0.0])
    np.testing.assert_allclose(y, expected, atol=1e-10)


@pytest.mark.parametrize("tau", [0.2 * DT, 3 * DT, 40 * DT, 1e4 * DT])
def test_lag_matches_scipy_lsim_from_rest_at_its_first_value(signal, tau):
    """lsim's linear interpolation between samples is the lag's first-order hold; it starts settled at s[0]."""
    y = Lag(lag_time_s=tau).apply(jnp.asarray(signal + 1.0), DT)
    t = np.arange(len(signal)) * DT
    system = scipy.signal.StateSpace([[-1 / tau]], [[1 / tau]], [[1.0]], [[0.0]])
    _, expected, _ = scipy.signal.lsim(system, signal + 1.0, t, X0=[signal[0] + 1.0])
    np.testing.assert_allclose(y, expected, atol=1e-10)
    assert Lag(lag_time_s=tau).derived(jnp.asarray(signal), DT)["lag_samples"] == pytest.approx(tau / DT)


def test_a_lag_longer_than_the_record_is_not_material(signal):
    """A lag the record never sees settle is an integral of the signal once the readout's gain scales it.

    A probe's drive dead zone + baseline drift named a 1953 s lag on a 100 s record (its standard error
    5.6e4 s) where the drift was refused.
    """
    duration = (len(signal) - 1) * DT
    for tau, material in ((3 * DT, True), (0.5 * duration, True), (0.9 * DT, False), (20 * duration, False)):
        lag = Lag(lag_time_s=tau)
        derived = lag.derived(jnp.asarray(signal), DT)
        assert derived["lag_records"] == pytest.approx(tau / duration)
        named, why = lag.material(derived, lag.parameters(), Lag.thresholds)
        assert named is material, why
    assert "never sees settle" in why and "× the record" in why


@pytest.mark.parametrize("h", [1e-7, 1e-4, 0.0199, FOH_SERIES_BELOW, 0.0201, 0.3, 5.0, 40.0])
def test_the_lags_closed_form_first_order_hold_is_the_matrix_exponentials(h):
    """(Φ, Γ₀, Γ₁) of τẋ = u − x against scipy's exponential of the augmented matrix, on both sides of
    the series' threshold, with a finite derivative there (the branch not taken must not leak a NaN)."""
    import scipy.linalg

    e = scipy.linalg.expm(np.array([[-h, h, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]]))
    expected = (e[0, 0], e[0, 1], e[0, 2])
    found = first_order_foh(jnp.asarray(h))
    for got, want in zip(found, expected):
        assert float(got) == pytest.approx(want, rel=1e-13, abs=1e-300)
    slope = jax.grad(lambda x: first_order_foh(x)[2])(jnp.asarray(h))
    assert np.isfinite(float(slope))
    step = 1e-6 * h
    numeric = float(first_order_foh(jnp.asarray(h + step))[2]) - float(
        first_order_foh(jnp.asarray(h - step))[2]
    )
    assert float(slope) == pytest.approx(numeric / (2 * step), rel=1e-6)


def test_resonance_rings_at_its_frequency():
    rate = 200.0
    y = np.asarray(
        Resonance(resonance_frequency_hz=7.0, resonance_damping=0.02).apply(
            jnp.concatenate([jnp.zeros(10), jnp.ones(4000)]), 1 / rate
        )
    )
    f, p = scipy.signal.periodogram(y[10:] - 1.0, fs=rate)
    assert f[np.argmax(p)] == pytest.approx(7.0 * np.sqrt(1 - 0.02**2), abs=0.1)


def test_a_mode_at_or_above_the_nyquist_frequency_is_not_material():
    # A chamber read at 1 Hz got a 0.98 Hz "mode": aliased, the samples show another frequency or none.
    thresholds = Resonance.thresholds
    for rate, material in ((30.0, True), (2.5, True), (1.9, False), (1.0, False)):
        mode = Resonance(resonance_frequency_hz=0.98, resonance_damping=0.1)
        parameters = mode.parameters()
        derived = mode.derived(np.zeros(10), 1 / rate)
        assert derived["over_nyquist"] == pytest.approx(0.98 * 2 / rate)
        ok, said = mode.material(derived, parameters, thresholds)
        assert ok is material and ("Nyquist" in said) is (not material), said


def _bouc_wen_by_ode(signal, k, initial):
    """u of du = k (ds − |ds| |u| u) along the piecewise-linear path of `signal`, by scipy's ODE solver."""
    import scipy.integrate

    u, out = initial, [initial]
    for prev, v in zip(signal[:-1], signal[1:]):
        d = v - prev
        u = scipy.integrate.solve_ivp(
            lambda _, x, d=d: k * (d - abs(d) * abs(x) * x), (0.0, 1.0), [u], rtol=1e-11, atol=1e-13
        ).y[0, -1]
        out.append(u)
    return np.array(out)


@pytest.mark.parametrize("initial", [0.0, 0.6, -0.9])
def test_hysteresis_matches_the_bouc_wen_ode(signal, initial):
    # The exact per-sample tanh/tan solution against numerical integration of the Bouc–Wen
    # law (n = 2, γ = 0) over each sample, where ds is constant: u = `initial` at the first.
    k, height = 3.0, 0.2
    expected = signal + height * _bouc_wen_by_ode(signal, k, initial)
    effect = Hysteresis(hysteresis_height=height, hysteresis_rate=k, hysteresis_initial_state=initial)
    y = effect.apply(jnp.asarray(signal), DT)
    np.testing.assert_allclose(y, expected, atol=1e-9)
    assert float(y[0]) == pytest.approx(signal[0] + height * initial, abs=1e-12)


def test_bouc_wen_state_has_finite_gradients_from_a_saturated_start():
    # u0 = ±1 (on a branch): atanh(1) is infinite, so the phase is taken just inside it.
    s = jnp.concatenate([jnp.linspace(0.0, 1.0, 50), jnp.linspace(1.0, -1.0, 100)])
    for u0 in (1.0, -1.0):
        grads = jax.grad(lambda k, u0: jnp.sum(bouc_wen_state(s, k, u0)), argnums=(0, 1))(3.0, u0)
        assert all(np.isfinite(float(g)) for g in grads)
        assert float(grads[0]) != 0.0  # the reversal's transition depends on k


def test_hysteresis_forgets_its_initial_state():
    # After s has moved many 1/k one way, the loop state no longer depends on where it began.
    s = jnp.concatenate([jnp.zeros(5), jnp.linspace(0.0, 2.0, 200)])
    ends = [
        float(
            Hysteresis(hysteresis_height=0.1, hysteresis_rate=20.0, hysteresis_initial_state=z0).apply(s, DT)[
                -1
            ]
        )
        for z0 in (-0.9, 0.0, 0.9)
    ]
    np.testing.assert_allclose(ends, 2.0 + 0.1, atol=1e-12)


def test_bouc_wen_memory_is_the_derivative_in_the_initial_state():
    # Against central finite differences of the state in its start u0 at 0.
    s = jnp.asarray(np.random.default_rng(3).normal(size=300).cumsum() * 0.05)
    k, h = 7.0, 1e-6
    fd = (bouc_wen_state(s, k, h) - bouc_wen_state(s, k, -h)) / (2 * h)
    state, memory = bouc_wen_and_memory(s, k)
    np.testing.assert_array_equal(state, bouc_wen_state(s, k))
    np.testing.assert_allclose(memory, fd, rtol=1e-6, atol=1e-9)
    assert float(memory[0]) == 1.0 and float(memory[-1]) < 0.1  # it starts whole and is forgotten


def test_hysteresis_is_rate_independent():
    t = np.linspace(0, 1, 400)
    slow = np.sin(2 * np.pi * t)
    effect = Hysteresis(hysteresis_height=0.1, hysteresis_rate=20.0)
    # Same path of s at a different sampling rate dt: the output depends on s only.
    a = np.asarray(effect.apply(jnp.asarray(slow), 0.001))
    b = np.asarray(effect.apply(jnp.asarray(slow), 1.0))
    np.testing.assert_array_equal(a, b)
    # The loop: at s = 0 the rising branch lies 2W above the falling one (W > 0).
    loop = np.asarray(effect.apply(jnp.asarray(np.concatenate([slow, slow])), 0.01))[400:]
    falling_index = np.argmin(np.abs(t - 0.5))
    assert loop[0] - loop[falling_index] == pytest.approx(0.2, rel=0.05)


def test_saturation_slope_asymptotes_and_asymmetry():
    effect = Saturation(
        saturation_pos_curvature=0.5, saturation_neg_curvature=-2.0
    )  # κ is even: sign irrelevant
    s = jnp.array([-100.0, -1e-6, 0.0, 1e-6, 100.0])
    y = np.asarray(effect.apply(s, DT))
    np.testing.assert_allclose(y, [-0.5, -1e-6, 0.0, 1e-6, 2.0], rtol=1e-6)
    derived = effect.derived(jnp.array([-1.0, 2.0]), DT)
    assert derived["level_pos"] == pytest.approx(2.0) and derived["level_neg"] == pytest.approx(0.5)
    assert derived["shortfall_pos_percent"] == pytest.approx(100 * (1 - np.tanh(1.0)), rel=1e-9)
    assert derived["shortfall_neg_percent"] == pytest.approx(100 * (1 - np.tanh(2.0) / 2.0), rel=1e-9)
    # a side the signal stays on the straight part of (shortfall below 1 %) gives no level: only its shortfall
    near = effect.derived(jnp.array([-0.05, 2.0]), DT)  # κ₋·0.05 = 0.1: shortfall 0.33 %
    assert "level_neg" not in near and near["shortfall_neg_percent"] == pytest.approx(
        100 * (1 - np.tanh(0.1) / 0.1), rel=1e-9
    )
    assert near["level_pos"] == pytest.approx(2.0)
    assert "level_neg" not in effect.derived(jnp.array([0.5, 2.0]), DT)  # never negative


def test_saturation_contains_the_linear_response_with_finite_gradients():
    s = jnp.linspace(-3.0, 3.0, 61)

    def y(k):  # κ enters as the raw parameter (Real: raw = value), so it can be traced
        effect = Saturation()
        return eqx.tree_at(lambda e: e.raw, effect, {n: k for n in effect.raw}).apply(s, DT)

    np.testing.assert_allclose(np.asarray(y(0.0)), np.asarray(s), atol=0.0)
    grad = jax.jacfwd(y)(0.0)
    assert np.all(np.isfinite(np.asarray(grad))) and np.max(np.abs(np.asarray(grad))) < 1e-12  # even in κ
    k = 1e-3  # the series branch against tanh(κ s)/κ, and finite differences of it
    np.testing.assert_allclose(np.asarray(y(k)), np.tanh(k * np.asarray(s)) / k, rtol=1e-12)
    h = 1e-6
    fd = (np.asarray(y(0.3 + h)) - np.asarray(y(0.3 - h))) / (2 * h)
    np.testing.assert_allclose(np.asarray(jax.jacfwd(y)(0.3)), fd, rtol=1e-6, atol=1e-9)


def test_play_matches_the_backlash_loop(signal):
    """The parallel scan of clamps against the play operator's loop, from rest and from a given state."""
    for h, initial in ((0.07, 0.0), (0.3, 0.2), (5.0, -1.0)):  # 5.0: wider than the signal, never moves
        y, expected = initial, []
        for u in signal:
            y = min(max(y, u - h), u + h)
            expected.append(y)
        got = np.asarray(play(jnp.asarray(signal), h, initial))
        np.testing.assert_allclose(got, expected, atol=1e-14)
    # As an effect: play of half-width h from rest; after a reversal the drive travels 2h first.
    u = jnp.concatenate([jnp.linspace(0.0, 1.0, 11), jnp.linspace(1.0, 0.0, 11)[1:]])
    y = np.asarray(Backlash(backlash_half_width=0.2).apply(u, DT))
    np.testing.assert_allclose(y[:11], np.maximum(np.asarray(u[:11]) - 0.2, 0.0), atol=1e-12)
    np.testing.assert_allclose(y[11:15], 0.8, atol=1e-12)  # u from 0.9 down to 0.6: still in the play
    np.testing.assert_allclose(y[15:], np.asarray(u[15:]) + 0.2, atol=1e-12)  # then it follows, 0.2 above
    derived = Backlash(backlash_half_width=0.2).derived(np.asarray(u), DT)
    assert derived["play_percent_of_range"] == pytest.approx(40.0)
    # a drive that starts away from 0: the play starts centred on it, and moves only once it leaves ±h
    y = np.asarray(Backlash(backlash_half_width=0.2).apply(u + 5.0, DT))
    np.testing.assert_allclose(y[:3], 5.0, atol=1e-12)  # u + 5 up to 5.2: inside the play
    np.testing.assert_allclose(y[3:11], np.asarray(u[3:11]) + 4.8, atol=1e-12)


def test_drive_side_saturation_and_even_are_their_forms_on_the_drive():
    u = np.linspace(-2.0, 3.0, 51)
    effect = DriveSaturation(drive_saturation_pos_curvature=0.5, drive_saturation_neg_curvature=2.0)
    expected = np.where(u >= 0, np.tanh(0.5 * u) / 0.5, np.tanh(2.0 * u) / 2.0)
    np.testing.assert_allclose(np.asarray(effect.apply(jnp.asarray(u), DT)), expected, rtol=1e-12, atol=1e-15)
    assert effect.unpinned_reason("drive_saturation_neg_curvature", np.abs(u)) is not None
    assert effect.unpinned_reason("drive_saturation_neg_curvature", u) is None
    even = DriveEven(drive_even_coefficient=-0.4)
    np.testing.assert_allclose(np.asarray(even.apply(jnp.asarray(u), DT)), u - 0.4 * u**2, rtol=1e-12)
    assert even.derived(u, DT)["even_percent_of_range"] == pytest.approx(100 * 0.4 * 9.0 / 5.0)
    assert DriveSaturation.place == DriveEven.place == Backlash.place == "drive"


@pytest.mark.parametrize(
    "effect_class, drive, coefficient, rising, hint",
    [
        # a 0–100 % drive whose map u − 0.0057 u² turns at 87.7 %: a clip at 70 % was fitted so
        (DriveEven, np.linspace(0.0, 100.0, 201), -0.0057, 87.7, "drive_clip"),
        # the same on the output's side, a sensor's full scale: the hint names clip
        (EvenResponse, np.linspace(0.0, 100.0, 201), -0.0057, 87.7, "clip"),
        # a V² force on a two-signed drive turns near its middle: an even response, no hint
        (DriveEven, np.linspace(-3.0, 3.0, 201), 3.0, 52.8, None),
        # monotone over the range, its turn just beyond it (104 %): flat at the end, as a level (a
        # verifier's heater clipped at 70 % of 0–20 W was fitted so)
        (DriveEven, np.linspace(0.0, 100.0, 201), -0.0048, 100.0, "drive_clip"),
        # monotone over the range (the turn well beyond it, 125 %): no turn, no hint
        (DriveEven, np.linspace(0.0, 100.0, 201), -0.004, 100.0, None),
        (DriveEven, np.linspace(0.0, 100.0, 201), 0.02, 100.0, None),
    ],
)
def test_an_even_map_that_turns_near_the_end_of_its_range_reads_as_a_clip(
    effect_class, drive, coefficient, rising, hint
):
    """The share of the range over which x + c x² rises, read against a grid (numpy), and the hint."""
    effect = effect_class(**{effect_class.coefficient: coefficient})
    derived = effect.derived(drive, DT)
    mapped = drive + coefficient * drive**2
    grid = np.linspace(drive.min(), drive.max(), 100_001)
    slope = np.diff(grid + coefficient * grid**2) > 0
    assert derived["rising_percent_of_range"] == pytest.approx(100 * slope.mean(), abs=0.01)
    assert derived["rising_percent_of_range"] == pytest.approx(rising, abs=0.1)
    assert np.asarray(effect.apply(jnp.asarray(drive), DT)) == pytest.approx(mapped, rel=1e-12)
    reading = effect.reading({**effect.parameters(), **derived}, "mm")
    if hint is None:
        assert reading == ""
    else:
        shape = f"rises over {rising:.0f} %" if rising < 100 else "flattens towards the end of the range"
        assert f"--effects builtins,{hint} tests a clip" in reading and shape in reading, reading


def test_delay_whole_and_fractional_samples(signal):
    s = jnp.asarray(signal)
    y = np.asarray(Delay(delay_s=3 * DT).apply(s, DT))
    np.testing.assert_allclose(y[3:], signal[:-3], atol=1e-12)
    np.testing.assert_allclose(y[:2], 0.0)  # at rest before the recording
    y = np.asarray(Delay(delay_s=2.25 * DT).apply(s, DT))
    n = np.arange(len(signal))
    np.testing.assert_allclose(y[3:], np.interp(n - 2.25, n, signal)[3:], atol=1e-12)


def test_drift_is_an_exponential_gain(signal):
    y = np.asarray(Drift(drift_rate_per_s=-0.01).apply(jnp.asarray(signal), DT))
    np.testing.assert_allclose(y, signal * np.exp(-0.01 * DT * np.arange(len(signal))), rtol=1e-12)


def test_drifts_lanes_start_at_no_change_a_fall_and_a_rise_over_the_record(signal):
    """From no drift alone, drift seed 6 of `experiments/discrepancy.py` (a 24 % rise) stayed at 0.0 %."""
    n = len(signal)
    context = hybrid.StartContext(
        signal=signal, rate=1 / DT, duration=(n - 1) * DT, drive=signal, measured=signal, lag_samples=1
    )
    changes = [
        Drift(**start).derived(jnp.asarray(signal), DT)["gain_change_percent"]
        for start in Drift().starts(context)
    ]
    np.testing.assert_allclose(changes, [0.0, -20.0, 25.0], atol=1e-9)


@pytest.mark.parametrize("name", [*EFFECTS, *NAMED_ONLY])
def test_effect_gradients_match_finite_differences(name, signal):
    """Reverse-mode gradients of Σy² w.r.t. each raw parameter against central differences."""
    effect = {**EFFECTS, **NAMED_ONLY}[name]()
    s = jnp.asarray(signal[:200])
    loss = jax.jit(lambda raw: jnp.sum(_apply(effect, raw, s) ** 2))
    raw = effect.raw
    grad = jax.grad(loss)(raw)
    h = 1e-6
    for key in raw:
        fd = (loss({**raw, key: raw[key] + h}) - loss({**raw, key: raw[key] - h})) / (2 * h)
        assert float(grad[key]) == pytest.approx(float(fd), rel=1e-5, abs=1e-8), key


#: Drive-side parameters away from their defaults (the drive is a ±2 V PRBS).
_MOVED = {
    "drive_saturation_pos_curvature": 0.4,
    "drive_saturation_neg_curvature": 0.25,
    "backlash_half_width": 0.1,
}


@pytest.mark.parametrize(
    "effects,drive_on",
    [
        (("saturation", "delay"), True),
        (("drive_saturation", "hysteresis"), True),
        (("drive_saturation", "hysteresis"), False),
        (("backlash", "drift"), False),
        # three drive effects in a chain, all on; then the first off between two on (`_drive_directions`'
        # live columns first: a column out of place would land on another effect's parameter)
        (("drive_dead_zone", "drive_saturation", "backlash"), True),
        (("drive_dead_zone", "drive_saturation", "backlash"), "first off"),
    ],
)
def test_a_stack_jacobian_matches_finite_differences(effects, drive_on):
    """The stack's Jacobian in all its parameters, forward and reverse, against central differences.

    The inner simulation's derivative is its own Jacobian times each direction
    (`inner_response`), plus the path through the drive only while a drive-side
    effect is on: with it off, the drive effect's columns must be exactly zero.
    """
    stack = extend(RCNetwork(method="zoh"), *effects)
    # Away from the defaults, where a curvature of 0 has a derivative of 0 and would hide the drive's path.
    stack = stack.replace(**{k: v for k, v in _MOVED.items() if k in stack.parameters()})
    if drive_on == "first off":
        on = [n != effects[0] for n in effects]
    else:
        on = [drive_on or EFFECTS[n].place != "drive" for n in effects]
    stack = stack.with_active(jnp.asarray(on, float))
    params, static = eqx.partition(stack, stack.trainable(frozenset()))
    flat, unravel = jax.flatten_util.ravel_pytree(params)
    v = jnp.asarray(make_drive("prbs", 8.0, seed=3).v)
    run = jax.jit(lambda x: eqx.combine(unravel(x), static).simulate(v, DT))
    forward, reverse = jax.jacfwd(run)(flat), jax.jacrev(run)(flat)
    step = 1e-6
    central = np.stack(
        [(run(flat.at[i].add(step)) - run(flat.at[i].add(-step))) / (2 * step) for i in range(flat.size)], 1
    )
    scale = np.max(np.abs(central))
    assert np.max(np.abs(forward - central)) < 1e-7 * scale  # central differences: O(h²) + rounding/h
    np.testing.assert_allclose(reverse, forward, rtol=0, atol=1e-12 * scale)
    off = [e for e, o in zip(effects, on) if not o and EFFECTS[e].place == "drive"]
    if off:
        columns = [
            i
            for i, n in enumerate(stack.free_parameter_order(frozenset()))
            if any(n in EFFECTS[e].constraints for e in off)
        ]
        assert columns and np.all(np.asarray(forward)[:, columns] == 0.0)
    order = stack.free_parameter_order(frozenset())
    for e in [e for e, o in zip(effects, on) if o and EFFECTS[e].place == "drive"]:
        columns = [i for i, n in enumerate(order) if n in EFFECTS[e].constraints]
        assert np.max(np.abs(np.asarray(forward)[:, columns])) > 0, e  # a drive effect that is on moves it


class _DrivePolynomial(hybrid.AbstractEffect):
    """A plug-in drive map with more parameters than `DRIVE_JACOBIAN_MAX`: u + Σ c_k·u^k/k, k = 2..10."""

    raw: dict
    name: ClassVar[str] = "drive_polynomial"
    place: ClassVar[str] = "drive"
    constraints: ClassVar = {f"c{k}": hybrid.Real() for k in range(2, 11)}
    units: ClassVar = {f"c{k}": f"1/{{signal}}^{k - 1}" for k in range(2, 11)}
    defaults: ClassVar = {f"c{k}": 0.0 for k in range(2, 11)}

    def __init__(self, **values):
        self.raw = encode({**self.defaults, **values}, self.constraints, self.name)

    def apply(self, s, dt):
        c = self.parameters()
        return s + sum(c[f"c{k}"] * s**k / k for k in range(2, 11))


class _DriveTable(hybrid.AbstractEffect):
    """A plug-in drive map holding an array that is not a parameter: u + gain·table(u), interpolated."""

    raw: dict
    table: jax.Array
    name: ClassVar[str] = "drive_table"
    place: ClassVar[str] = "drive"
    constraints: ClassVar = {"table_gain": hybrid.Real()}
    units: ClassVar = {"table_gain": "1"}
    defaults: ClassVar = {"table_gain": 0.0}

    def __init__(self, **values):
        self.raw = encode({**self.defaults, **values}, self.constraints, self.name)
        self.table = jnp.tanh(jnp.linspace(-3.0, 3.0, 13))

    def apply(self, s, dt):
        return s + self.parameters()["table_gain"] * jnp.interp(s, jnp.linspace(-3.0, 3.0, 13), self.table)


@pytest.mark.parametrize("table_on", [True, False])
def test_a_lanes_jacobian_with_plugin_drive_effects_matches_finite_differences(table_on):
    """A lane's Jacobian (`jax.linearize`, one pass per direction, as `Problem` takes it) with plug-in drive effects.

    The inner simulation's response is differentiated once per parameter of
    each drive effect that is on (`inner_response`), and plainly along each
    direction for one with more than `DRIVE_JACOBIAN_MAX` parameters; the
    derivative along an array a drive effect holds (not a parameter) is taken
    plainly too. Against central differences; with the table's effect off its
    columns are exactly zero.
    """
    moved = {f"c{k}": 0.02 / k for k in range(2, 11)}
    stack = extend(RCNetwork(method="zoh"), _DrivePolynomial(**moved), _DriveTable(table_gain=0.3), "drift")
    stack = stack.with_active(jnp.asarray([1.0, 1.0 if table_on else 0.0, 1.0]))
    params, static = eqx.partition(stack, stack.trainable(frozenset()))
    flat, unravel = jax.flatten_util.ravel_pytree(params)
    v = jnp.asarray(make_drive("prbs", 8.0, seed=5).v)

    def run(x):
        return eqx.combine(unravel(x), static).simulate(v, DT)

    _, linear = jax.linearize(run, flat)
    lane = jax.jit(jax.vmap(linear, out_axes=1))(jnp.eye(flat.size))
    step = 1e-6
    central = np.stack(
        [(run(flat.at[i].add(step)) - run(flat.at[i].add(-step))) / (2 * step) for i in range(flat.size)], 1
    )
    scale = np.max(np.abs(central))
    assert np.max(np.abs(lane - central)) < 1e-7 * scale  # central differences: O(h²) + rounding/h
    table_columns = [i for i, n in enumerate(stack.free_parameter_order(frozenset())) if n == "table_gain"]
    assert table_columns and (np.all(np.asarray(lane)[:, table_columns] == 0.0) != table_on)
    # Along the table itself (an array, not a parameter): moved plainly.
    direction = jnp.cos(jnp.arange(13.0))

    def with_table(t):
        effects = tuple(
            eqx.tree_at(lambda e: e.table, e, t) if e.name == "drive_table" else e for e in stack.effects
        )
        return eqx.tree_at(lambda st: st.effects, stack, effects).simulate(v, DT)

    table = stack.effects[1].table
    along = jax.jvp(with_table, (table,), (direction,))[1]
    central = (with_table(table + step * direction) - with_table(table - step * direction)) / (2 * step)
    if table_on:
        assert float(jnp.max(jnp.abs(along))) > 0
    np.testing.assert_allclose(
        along, central, rtol=0, atol=1e-7 * max(float(jnp.max(jnp.abs(central))), 1e-3)
    )


@pytest.mark.parametrize("effects", [(), ("saturation", "drift"), ("drive_saturation",), ("stiffness",)])
def test_the_stack_is_differentiated_in_its_drive_as_the_bare_simulation_is(effects):
    """d(output)/d(drive), forward and reverse, against central differences, every drive effect off.

    The inner simulation's own derivative skips the drive's path while no drive
    effect is on (in a search lane the drive is the recording): a caller who
    differentiates the drive itself (a drive's design, a sensitivity to it)
    must still get it. Found when `design_drive` got a zero gradient.
    """
    inner = (
        hybrid.LTI(2, f_1=0.8, zeta_1=0.4, bandpass_1=0.3)
        if "stiffness" in effects
        else RCNetwork(method="zoh")
    )
    stack = extend(inner, *effects) if effects else extend(inner)
    stack = stack.with_active(jnp.asarray([0.0 if EFFECTS[n].place == "drive" else 1.0 for n in effects]))
    if "stiffness" in effects:
        stack = stack.replace(stiffness_cube=0.3)
    v = jnp.asarray(make_drive("prbs", 3.0, seed=3).v)
    weights = jnp.cos(jnp.arange(v.size) / 7.0)
    loss = jax.jit(lambda x: jnp.sum(weights * stack.simulate(x, DT)))
    plain = jax.jit(lambda x: jnp.sum(weights * stack.with_active(jnp.zeros(len(effects))).simulate(x, DT)))
    grad, tangent = jax.grad(loss)(v), jax.jvp(loss, (v,), (weights,))[1]
    assert float(jnp.max(jnp.abs(grad))) > 0  # not the silent zero it was
    step = 1e-5
    for i in (0, 17, 45, v.size - 1):
        central = (loss(v.at[i].add(step)) - loss(v.at[i].add(-step))) / (2 * step)
        assert float(grad[i]) == pytest.approx(
            float(central), rel=1e-6, abs=1e-9 * float(jnp.max(jnp.abs(grad)))
        )
    assert float(tangent) == pytest.approx(float(jnp.dot(grad, weights)), rel=1e-9)
    if not effects:
        np.testing.assert_allclose(np.asarray(jax.grad(plain)(v)), np.asarray(grad), rtol=1e-12, atol=0)


class _CalibratedLag(AbstractSimulation):
    """A lag read through a calibration table: an array field that is not a parameter."""

    raw: dict
    table: jax.Array
    constraints: ClassVar[dict] = {"tau_s": Positive()}
    units: ClassVar[dict] = {"tau_s": "s"}

    def __init__(self, tau_s=0.5, table=(0.0, 0.9, 2.1)):
        self.raw = encode({"tau_s": tau_s}, self.constraints, "_CalibratedLag")
        self.table = jnp.asarray(table, float)

    def simulate(self, v_in, dt):
        a = jnp.exp(-dt / self.parameters()["tau_s"])
        y = jax.lax.scan(lambda y, u: (a * y + (1 - a) * u,) * 2, 0.0, jnp.asarray(v_in))[1]
        return jnp.interp(y, jnp.asarray([-2.0, 0.0, 2.0]), self.table)


def test_a_plugin_array_that_is_not_a_parameter_is_differentiated_plainly():
    """Only `raw` goes through the inner Jacobian; another array field still has its derivative."""
    stack = extend(_CalibratedLag(), "saturation")
    v = jnp.asarray(make_drive("prbs", 8.0, seed=3).v)

    def output(raw_tau, table):
        inner = eqx.tree_at(lambda s: (s.raw, s.table), stack.inner, ({"tau_s": raw_tau}, table))
        return eqx.tree_at(lambda s: s.inner, stack, inner).simulate(v, DT)

    tau, table = stack.inner.raw["tau_s"], stack.inner.table
    d_table = jnp.asarray([0.1, -0.2, 0.3])
    _, along_table = jax.jvp(lambda t: output(tau, t), (table,), (d_table,))
    _, along_tau = jax.jvp(lambda r: output(r, table), (tau,), (jnp.ones_like(tau),))
    step = 1e-6
    for got, moved in (
        (along_table, lambda h: output(tau, table + h * d_table)),
        (along_tau, lambda h: output(tau + h, table)),
    ):
        central = (moved(step) - moved(-step)) / (2 * step)
        assert float(jnp.max(jnp.abs(got - central))) < 1e-7 * float(jnp.max(jnp.abs(central)))


def _apply(effect, raw, s):
    import equinox as eqx

    return eqx.tree_at(lambda e: e.raw, effect, raw).apply(s, DT)


def test_stack_switches_and_parameters():
    v = jnp.asarray(make_drive("prbs", 20.0, seed=2).v)
    inner = RCNetwork()
    stack = extend(inner, *OUTSIDE)
    off = stack.with_active(jnp.zeros(len(OUTSIDE)))
    np.testing.assert_array_equal(off.simulate(v, DT), inner.simulate(v, DT))
    only_delay = stack.with_active(jnp.eye(len(OUTSIDE))[0])
    np.testing.assert_allclose(only_delay.simulate(v, DT), Delay().apply(inner.simulate(v, DT), DT))
    assert set(stack.parameters()) == set(inner.parameters()) | {
        n for name in OUTSIDE for n in EFFECTS[name].constraints
    }
    changed = stack.replace(delay_s=0.2, xi_rho=20.0)
    assert float(changed.parameters()["delay_s"]) == pytest.approx(0.2)
    assert float(changed.parameters()["xi_rho"]) == pytest.approx(20.0)
    assert stack.units["resonance_frequency_hz"] == "Hz"


def test_stack_errors():
    with pytest.raises(InputError, match="unknown effect"):
        EffectStack(RCNetwork(), ("wobble",))
    with pytest.raises(InputError, match="collide"):
        EffectStack(RCNetwork(), ("delay", "delay"))
    with pytest.raises(InputError, match="relaxation_fraction must be strictly between 0 and 1"):
        extend(RCNetwork(), "back_relaxation", relaxation_fraction=1.5)


# --- the hidden-effect generator -------------------------------------------------------


def _recording(effect, params, strip=SyntheticStrip(), seconds=30.0):
    drive = make_drive("prbs", seconds, rate=30.0, seed=5, amplitude=2.0)
    return synthetic_recording(drive, strip, effect, params, noise_fraction=0.0, seed=0)


def test_synthetic_delay_shifts_the_clean_response():
    clean = _recording("none", {}).extra["w_true"]
    late = _recording("delay", {"delay_samples": 4}).extra["w_true"]
    # (sample 4's exposure straddles the end of the dead time)
    np.testing.assert_allclose(late[5:], clean[1:-4], atol=1e-12)
    np.testing.assert_allclose(late[:4], 0.0, atol=1e-12)  # the strip rests during the dead time


def test_synthetic_effect_free_matches_the_exact_zoh_of_the_network():
    rec = synthetic_recording(
        make_drive("prbs", 20.0, rate=30.0, seed=1),
        SyntheticStrip(offset_mm=0.1),
        "none",
        noise_fraction=0.0,
        exposure_fraction=1 / 8,
    )
    # exposure of one fine sample: the camera sees the fine-grid value at each time stamp
    v_o = np.asarray(RCNetwork(method="zoh").simulate(jnp.asarray(rec.v_in), 1 / 30))
    np.testing.assert_allclose(rec.w, 2.0 * v_o + 0.1, rtol=1e-8, atol=1e-10)


def test_synthetic_saturation_shortfall_is_as_asked():
    base = _recording("none", {}).extra["w_true"]
    sat = _recording("saturation", {"shortfall_pos": 0.3, "shortfall_neg": 0.1}).extra["w_true"]
    top, bottom = np.argmax(base), np.argmin(base)
    assert sat[top] / base[top] == pytest.approx(0.7, abs=0.02)
    assert sat[bottom] / base[bottom] == pytest.approx(0.9, abs=0.02)


def test_random_draws_stay_in_the_issue_ranges():
    rng = np.random.default_rng(0)
    for _ in range(50):
        strip = random_strip(rng)
        assert 1.0 <= strip.xi_rho / strip.xi_h <= 100.0
        assert 1e-3 <= strip.C_clamp <= 1.0 and 0.3 <= abs(strip.gain_mm_per_v) <= 5.0
        assert 1 <= random_effect("delay", rng, 30.0)["delay_samples"] <= 15
        res = random_effect("resonance", rng, 20.0)
        assert 1.0 <= res["frequency_hz"] <= 7.0 and 0.02 <= res["damping"] <= 0.3
    with pytest.raises(InputError, match="unknown hidden effect"):
        random_effect("creep", rng, 30.0)


def _relaxing_strip():
    """A strip with a hidden back-relaxation (τ 4 s, half), 40 s of PRBS at 30 Hz, 1 % noise."""
    return synthetic_recording(
        make_drive("prbs", 40.0, rate=30.0, seed=3, amplitude=2.0),
        SyntheticStrip(),
        "back_relaxation",
        {"tau_s": 4.0, "fraction": 0.5},
        noise_fraction=0.01,
        seed=1,
    )


def test_standard_errors_with_the_network_fixed_match_a_fit_with_it_frozen():
    """`std_error_given_network` (a block of the full Fisher information) against an
    independent covariance computed with the network's parameters frozen."""
    from hybrid.core._models import Model
    from hybrid.core._problem import Problem, bucket_length, bucketed_series, series_from_recording
    from hybrid.core._readout import LinearReadout
    from hybrid.discovery._diagnosis import DiagnoseSettings
    from hybrid.discovery._evidence import parameter_uncertainties
    from hybrid.sensitivity import parameter_covariance

    rec = _relaxing_strip()
    inner = RCNetwork(method="zoh")
    model = Model(
        extend(inner, "back_relaxation", relaxation_time_s=4.0, relaxation_fraction=0.4),
        LinearReadout(gain=2.0),
        "physics",
    )
    settings = DiagnoseSettings()
    white = np.random.default_rng(0).normal(size=400)

    def uncertainties(model, padded=False, keep=None):
        series = series_from_recording(rec, settings.split, ("train", "validation", "test"), settings.blocks)
        if padded:  # diagnose's padded problem: the padding must not change a standard error
            series = bucketed_series(series, bucket_length(rec.n) + 100)
        problem = Problem(model, [series], frozenset(settings.frozen_for(inner)))
        return parameter_uncertainties(
            problem, problem.flatten(model, frozenset(settings.frozen_for(inner))), white, keep=keep
        )

    found = uncertainties(model)
    frozen = parameter_covariance(
        model,
        [rec],
        frozen=set(settings.frozen_for(inner)) | set(inner.parameter_names()),
        split=settings.split,
        split_order=("train", "validation", "test"),
        blocks=settings.blocks,
    )
    full = parameter_covariance(
        model,
        [rec],
        frozen=settings.frozen_for(inner),
        split=settings.split,
        split_order=("train", "validation", "test"),
        blocks=settings.blocks,
    )
    for name, se in frozen.std_errors.items():
        # s² = RSS/dof differs between the two by the number of free parameters.
        expected = se * np.sqrt(frozen.dof / full.dof * found[name].inflation)
        assert found[name].std_error_given_network == pytest.approx(expected, rel=1e-6), name
        assert found[name].std_error_given_network <= found[name].std_error * (1 + 1e-9), name
    assert found["C_clamp"].std_error_given_network is None
    # The search's universal model, every other effect switched off, gives the same errors.
    active = jnp.asarray([1.0 if n == "back_relaxation" else 0.0 for n in OUTSIDE])
    universal = Model(
        extend(inner, *OUTSIDE).replace(relaxation_time_s=4.0, relaxation_fraction=0.4).with_active(active),
        LinearReadout(gain=2.0),
        "physics",
    )
    same = uncertainties(universal, padded=True, keep=model.parameters())
    assert set(same) == set(found)
    for name, entry in found.items():
        for key in ("std_error", "std_error_given_network"):
            if getattr(entry, key) is not None:
                assert getattr(same[name], key) == pytest.approx(getattr(entry, key), rel=1e-6), (name, key)


def test_a_value_off_the_training_optimum_is_reported_with_that_optimum():
    """`ParameterUncertainty.to_optimum` against scipy's least squares on the same training
    residuals, from a back-relaxation fraction and a gain a few standard errors off; the report
    says which values are not the optimum (`OFF_OPTIMUM` standard errors) and where it lies."""
    import scipy.optimize

    from hybrid.core._models import Model
    from hybrid.core._problem import Problem, series_from_recording
    from hybrid.core._readout import LinearReadout
    from hybrid.discovery._diagnosis import OFF_OPTIMUM, DiagnoseSettings, _optimum
    from hybrid.discovery._evidence import parameter_uncertainties
    from hybrid.discovery._report import plus_minus

    rec = _relaxing_strip()
    inner = RCNetwork(method="zoh")
    settings = DiagnoseSettings()
    # the network held (its parameters trade off along near-null directions): the effect and readout
    frozen = frozenset(settings.frozen_for(inner)) | set(inner.parameter_names())
    series = series_from_recording(rec, settings.split, ("train", "validation", "test"), settings.blocks)
    model = Model(
        extend(inner, "back_relaxation", relaxation_time_s=4.0, relaxation_fraction=0.5),
        LinearReadout(gain=2.0),
        "physics",
    )
    problem = Problem(model, [series], frozen)
    residuals = eqx.filter_jit(lambda p, th: p.residuals(th))
    jacobian = eqx.filter_jit(lambda p, th: jax.jacfwd(p.residuals)(th))
    best = scipy.optimize.least_squares(
        lambda th: np.asarray(residuals(problem, jnp.asarray(th))),
        np.asarray(problem.flatten(model, frozen)),
        jac=lambda th: np.asarray(jacobian(problem, jnp.asarray(th))),
        method="lm",
        xtol=1e-14,
        ftol=1e-14,
        gtol=1e-14,
    )
    optimum = {k: float(v) for k, v in problem.model(jnp.asarray(best.x)).parameters().items()}
    white = np.random.default_rng(0).normal(size=400)
    at = parameter_uncertainties(problem, best.x, white)
    assert all(abs(u.to_optimum) < 1e-2 * u.std_error for u in at.values()), at
    assert not any(u.held_off_optimum for u in at.values())
    off = {
        "relaxation_fraction": optimum["relaxation_fraction"] + 4 * at["relaxation_fraction"].std_error,
        "gain": optimum["gain"] - 1.5 * at["gain"].std_error,
    }
    fitted = problem.model(jnp.asarray(best.x))
    moved = Model(
        fitted.simulation.replace(relaxation_fraction=off["relaxation_fraction"]),
        LinearReadout(gain=off["gain"], offset=optimum["offset"]),
        "physics",
    )
    found = parameter_uncertainties(problem, problem.flatten(moved, frozen), white)
    values = {k: float(v) for k, v in moved.parameters().items()}
    for name, u in found.items():  # within 2 % of a standard error of scipy's optimum
        assert values[name] + u.to_optimum == pytest.approx(optimum[name], abs=0.02 * u.std_error), name
    assert {n for n, u in found.items() if u.held_off_optimum} >= {"relaxation_fraction"}
    assert not found["gain"].held_off_optimum  # 1.5 < OFF_OPTIMUM (2) standard errors
    assert abs(found["gain"].to_optimum) < OFF_OPTIMUM * found["gain"].std_error
    entry = {"value": values["relaxation_fraction"], "std_error": found["relaxation_fraction"].std_error}
    entry.update(_optimum(found["relaxation_fraction"]), unit="1")
    assert entry["at_training_optimum"] is False
    text = plus_minus(entry)
    assert f"the training part alone would move it to ≈ {optimum['relaxation_fraction']:.3g}" in text, text
    assert "standard errors away" in text
    gain = {"value": values["gain"], "std_error": found["gain"].std_error, **_optimum(found["gain"])}
    assert "optimum" not in plus_minus(gain)
    # an optimum far beyond the value (a hard clip's sharpness running on): "much further", not a value
    far = {"value": 20.46, "std_error": 8.3, "to_training_optimum": 1450.0, "at_training_optimum": False}
    text = plus_minus(far)
    assert "takes it much further, to ≈ 1.47e+03, 175 standard errors on" in text and "optimum," not in text


def test_a_line_is_its_sinusoid_from_the_first_sample_and_its_frequency_gradient_is_right():
    """`Line` against numpy's sinusoid (t = k·dt from the first sample, so padding at the end leaves the
    phase alone), and the gradient in every raw parameter, the frequency's included (its amplitudes
    away from 0), against central differences."""
    from hybrid.discovery._effects import Line

    effect = Line(line_frequency_hz=3.1, line_cos=0.4, line_sin=-0.25)
    s = jnp.asarray(np.linspace(-1.0, 1.0, 300))
    t = np.arange(300) * DT
    expected = np.asarray(s) + 0.4 * np.cos(2 * np.pi * 3.1 * t) - 0.25 * np.sin(2 * np.pi * 3.1 * t)
    np.testing.assert_allclose(np.asarray(effect.apply(s, DT)), expected, rtol=0, atol=1e-12)
    padded = effect.apply(jnp.concatenate([s, jnp.zeros(50)]), DT)[:300]
    np.testing.assert_allclose(np.asarray(padded), expected, rtol=0, atol=1e-12)
    loss = jax.jit(lambda raw: jnp.sum(_apply(effect, raw, s) ** 2))
    grad = jax.grad(loss)(effect.raw)
    h = 1e-6
    for key, value in effect.raw.items():
        fd = (loss({**effect.raw, key: value + h}) - loss({**effect.raw, key: value - h})) / (2 * h)
        assert float(grad[key]) == pytest.approx(float(fd), rel=1e-5), key
        assert abs(float(grad[key])) > 1e-3, key  # a direction the fit can move in


def test_a_delay_reads_its_dead_time_with_the_frame_timing_s_share():
    """The frame timing (≤ 1 sample, always fitted) takes part of a dead time: a user read delay_s alone, 0.27 s
    for a 0.30 s delay (9 samples at 30 Hz) whose last sample the frame lag held. The reading gives the sum."""
    from hybrid.discovery._effects import Delay

    text = Delay().reading({"delay_samples": 7.993, "delay_s": 7.993 / 30, "frame_lag": 0.998}, "mm")
    assert text.startswith("a dead time of 8.99 samples (0.3 s) in all with the frame timing's 1;"), text
    assert Delay().reading({"delay_samples": 7.993, "delay_s": 0.2664}, "mm") == ""  # no frame lag given
