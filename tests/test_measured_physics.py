"""The physics of experiments/measured.py: HeldStart, the tanks' overflow, the (Duffing) oscillator.

References are independent of the library: scipy.signal's `lsim` (a linear
system from a steady state, the drive interpolated linearly), scipy's
`solve_ivp`, and the tanks' closed-form steady states.
"""

from __future__ import annotations

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.signal
from scipy.integrate import solve_ivp

import hybrid
from hybrid import LTI, HeldStart, InputError, resolve_physics

ROOT = Path(__file__).resolve().parents[1]


def _example(spec):
    sim = resolve_physics(str(ROOT / "examples" / spec))
    return sim, sys.modules[type(sim).__module__]


# --- HeldStart ---------------------------------------------------------------------------------


def test_held_start_is_the_system_started_in_steady_state_at_the_held_drive():
    inner = LTI(3, tau_1=0.3, f_2=0.4, zeta_2=0.6, lowpass_2=0.5, bandpass_2=0.2, direct=0.1)
    dt, u0 = 0.05, 1.7
    sim = HeldStart(inner, settle_samples=2000, initial_drive=u0)  # 100 s: > 40 of the slowest time constant
    u = np.sin(np.linspace(0.0, 12.0, 300))
    A, B, C, D = (np.asarray(x) for x in inner.state_space())
    system = scipy.signal.cont2discrete((A, B[:, None], C[None, :], np.array([[float(D)]])), dt, method="zoh")
    x0 = -np.linalg.solve(A, B) * u0  # steady state at u0
    _, expected, _ = scipy.signal.dlsim(system, u, x0=x0)
    got = np.asarray(sim.simulate(u, dt))
    np.testing.assert_allclose(got, expected[:, 0], atol=1e-9)
    # one parameter more, fitted like the others: its gradient is the steady-state gain's share
    assert sim.parameter_names() == inner.parameter_names() + ("initial_drive",)
    g = jax.grad(lambda s: jnp.sum(s.simulate(u, dt)[:5]))(sim)
    assert np.isfinite(float(g.own["initial_drive"])) and float(g.own["initial_drive"]) != 0.0


def test_held_start_replace_freeze_and_fit_recover_the_initial_drive():
    inner = LTI(1, tau_1=2.0)
    truth = HeldStart(inner, 200, initial_drive=2.5)
    dt = 0.1
    v = np.repeat([0.0, 1.0, -1.0, 0.5], 50)
    w = 3.0 * np.asarray(truth.simulate(v, dt)) + 0.2
    rec = hybrid.Recording(t=np.arange(len(v)) * dt, v_in=v, w=w)
    start = hybrid.make_model("physics", simulation=truth.replace(initial_drive=0.0))
    result = hybrid.fit(
        start,
        rec,
        frozen={"tau_1", "direct"},
        split=(0.8, 0.1, 0.1),
        progress=False,
        solver=hybrid.LevenbergMarquardt(max_steps=100),
    )
    assert abs(float(result.model.parameters()["initial_drive"]) - 2.5) < 1e-4
    assert float(truth.replace(tau_1=3.0).parameters()["tau_1"]) == pytest.approx(3.0)
    spec = truth.trainable(frozenset({"initial_drive"}))
    assert spec.own["initial_drive"] is False and spec.inner.raw["tau_1"] is True


@pytest.mark.parametrize(
    "bad, message",
    [(0, "positive whole number"), (2.5, "positive whole number"), (True, "positive whole number")],
)
def test_held_start_refuses_a_bad_settle_length(bad, message):
    with pytest.raises(InputError, match=message):
        HeldStart(LTI(1), bad)


# --- the tanks' overflow ----------------------------------------------------------------------------


def test_overflow_with_rims_out_of_reach_is_the_two_tank_model():
    tanks, _ = _example("two_tank.py:TwoTank")
    overflow, _ = _example("two_tank.py:TwoTankOverflow")
    overflow = overflow.replace(level_max_1=1e4, level_max_2=1e4)
    u = np.repeat([1.0, 6.0, 2.0], 60)
    np.testing.assert_allclose(
        np.asarray(overflow.simulate(u, 0.5)), np.asarray(tanks.simulate(u, 0.5)), rtol=1e-9
    )


@pytest.mark.parametrize("spill", [0.01, 0.99])
def test_an_overflowing_upper_tank_reaches_the_closed_form_steady_state(spill):
    sim, module = _example("two_tank.py:TwoTankOverflow")
    sim = sim.replace(level_max_1=5.0, level_max_2=1e4, spill_to_lower=spill)
    p = {k: float(v) for k, v in sim.parameters().items()}
    c1, c2 = (p[k] * np.sqrt(2 * module.G) for k in ("outlet_1", "outlet_2"))
    u = 8.0
    q = p["pump_flow"] * u
    assert q > c1 * np.sqrt(5.0)  # the upper tank would fill above its rim
    h1, h2 = (np.asarray(x)[-1] for x in sim.levels(np.full(4000, u), 0.5))  # 2000 s: settled
    # at the rim, the upper outlet passes c1·√L1 and the spill is the rest of q; spill·(rest) reaches the lower tank
    inflow_2 = c1 * module.outflow(5.0) + spill * (q - c1 * module.outflow(5.0))
    h2_expected = float(module.equilibrium(c2, inflow_2))
    assert abs(h1 - 5.0) < 0.05 * 5.0  # the rim is RIM_WIDTH = 2 % wide
    assert abs(h2 - h2_expected) < 0.02 * h2_expected


# --- the oscillator ----------------------------------------------------------------------------------


def test_mass_spring_damper_matches_scipy_lsim_with_a_linearly_interpolated_drive():
    sim, _ = _example("oscillator.py:MassSpringDamper")
    sim = sim.replace(frequency=69.0, zeta=0.05)
    fs = 610.35
    rng = np.random.default_rng(0)
    u = scipy.signal.lfilter(*scipy.signal.butter(4, 0.3), rng.standard_normal(2000)) * 0.1
    w = 2 * np.pi * 69.0
    t = np.arange(len(u)) / fs
    _, expected, _ = scipy.signal.lsim(([w * w], [1.0, 2 * 0.05 * w, w * w]), u, t)  # linear interpolation
    got = np.asarray(sim.simulate(u, 1 / fs))
    assert np.max(np.abs(got - expected)) < 2e-4 * np.max(np.abs(expected))  # RK4, 4 steps a sample


def test_duffing_matches_solve_ivp_and_its_cubic_term_hardens_the_spring():
    sim, _ = _example("oscillator.py:Duffing")
    assert sim.frozen_by_default == {}
    sim = sim.replace(frequency=60.0, zeta=0.05, cubic=4.0, drive_offset=0.01)
    fs = 610.35
    t = np.arange(600) / fs
    u = 0.3 * np.sin(2 * np.pi * 50.0 * t)
    w = 2 * np.pi * 60.0

    def rate(time, x):
        force = np.interp(time, t, u) - 0.01
        return [x[1], w * w * (force - x[0] - 4.0 * x[0] ** 3) - 2 * 0.05 * w * x[1]]

    expected = solve_ivp(
        rate, (0, t[-1]), [0.0, 0.0], t_eval=t, method="DOP853", rtol=1e-11, atol=1e-13, max_step=1 / fs / 4
    ).y[0]
    got = np.asarray(sim.simulate(u, 1 / fs))
    assert np.max(np.abs(got - expected)) < 2e-4 * np.max(np.abs(expected))  # RK4, 4 steps a sample
    linear = np.asarray(sim.replace(cubic=0.0).simulate(u, 1 / fs))
    assert np.max(np.abs(got - linear)) > 0.05 * np.max(np.abs(linear))  # the cubic term matters at 0.3 V
