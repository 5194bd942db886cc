"""Effects inside the dynamics: a simulation in state-space form, a feedback force, a state limit.

References are independent of the code under test: scipy's solve_ivp for the
oscillator with a cubic spring, central finite differences for the Jacobian a
fit linearises, and the tank example's own walls (a different code path) for
a limit.
"""

from __future__ import annotations

import collections
import dataclasses
import importlib
import json
from pathlib import Path

import equinox as eqx
import helpers as h
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax import monitoring
from scipy.integrate import solve_ivp
from scipy.special import expit

import hybrid
from hybrid import EffectStack, Friction, InputError, PolynomialStiffness, StateLimit, StateWindow
from hybrid.cli import main
from hybrid.core._problem import bucket_length, series_from_recording
from hybrid.core._serialise import build_simulation, describe_simulation
from hybrid.core._state_space import integrate
from hybrid.discovery._effect_set import searched_places

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
# The examples' classes, loaded the way a user's --physics plug-in is.
MassSpringDamper = type(hybrid.resolve_physics(f"{EXAMPLES}/oscillator.py:MassSpringDamper"))
TwoTank = type(hybrid.resolve_physics(f"{EXAMPLES}/two_tank.py:TwoTank"))
TwoTankOverflow = type(hybrid.resolve_physics(f"{EXAMPLES}/two_tank.py:TwoTankOverflow"))
#: The example's own rim width (its code, not the library's): a limit compared with it is as wide.
EXAMPLE_RIM = importlib.import_module(TwoTankOverflow.__module__).RIM_WIDTH

RATE = 610.35
DT = 1.0 / RATE


def _drive(n=1500, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * DT
    return sum(0.02 * np.sin(2 * np.pi * f * t + rng.uniform(0, 6)) for f in (20.0, 45.0, 71.0, 90.0))


def _duffing_scipy(u, frequency, zeta, k2, k3):
    """y'' + 2ζωy' + ω²(y + k2 y² + k3 y³) = ω² u, u linear between samples, from rest."""
    w = 2 * np.pi * frequency
    t = np.arange(len(u)) * DT

    def rhs(time, x):
        drive = np.interp(time, t, u)
        y, v = x
        return [v, w * w * (drive - y - k2 * y * y - k3 * y**3) - 2 * zeta * w * v]

    sol = solve_ivp(rhs, (0, t[-1]), [0.0, 0.0], t_eval=t, rtol=1e-10, atol=1e-12, max_step=DT / 4)
    return sol.y[0]


def test_stiffness_inside_an_oscillator_matches_solve_ivp():
    u = _drive()
    stack = EffectStack(
        MassSpringDamper(frequency=69.0, zeta=0.05),
        [PolynomialStiffness(stiffness_square=0.5, stiffness_cube=8.0)],
    )
    y = np.asarray(stack.simulate(jnp.asarray(u), DT))
    reference = _duffing_scipy(u, 69.0, 0.05, 0.5, 8.0)
    linear = np.asarray(MassSpringDamper(frequency=69.0, zeta=0.05).simulate(jnp.asarray(u), DT))
    # RK4, 4 steps a sample at 9 samples a period (the tolerance of the examples' own tests).
    assert np.max(np.abs(y - reference)) < 2e-4 * np.max(np.abs(reference))
    assert np.max(np.abs(linear - reference)) > 50 * np.max(np.abs(y - reference))  # the spring matters
    # Switched off, the stack is the simulation itself.
    off = np.asarray(stack.with_active(jnp.zeros(1)).simulate(jnp.asarray(u), DT))
    np.testing.assert_allclose(off, linear, rtol=0, atol=1e-15)


def test_feedback_jacobian_matches_finite_differences():
    """LM linearises the simulation in forward mode: through the RK4 loop and the feedback."""
    u = jnp.asarray(_drive(400))
    stack = EffectStack(
        MassSpringDamper(frequency=69.0, zeta=0.05), [PolynomialStiffness(stiffness_cube=5.0)]
    )

    _assert_jacobian_is_central_differences(stack, u, DT, {"stiffness_cube": 1e-4, "frequency": 1e-6})


def _assert_jacobian_is_central_differences(stack, u, dt, steps):
    """Forward-mode derivatives of the output in each raw parameter of `steps` against central differences."""
    names = list(steps)

    def output(*values):
        return stack.with_raw({**stack.raw, **dict(zip(names, values))}).simulate(u, dt)

    at = [stack.raw[name] for name in names]
    jac = jax.jacfwd(output, argnums=tuple(range(len(names))))(*at)
    for k, name in enumerate(names):
        step = steps[name]
        plus = output(*(a + step if j == k else a for j, a in enumerate(at)))
        minus = output(*(a - step if j == k else a for j, a in enumerate(at)))
        fd = np.asarray((plus - minus) / (2 * step))
        assert np.max(np.abs(fd)) > 1e-3, name  # the parameter does move the output here
        np.testing.assert_allclose(np.asarray(jac[k]), fd, rtol=1e-5, atol=1e-7 * np.max(np.abs(fd)))


def _lti_with_cubic_scipy(sim, u, dt, k3):
    """ẋ = A x + B (u − k3 y³), y = C x + D (u − k3 y³) with y³ of the state part, u held; from rest."""
    A, B, C, D = (np.asarray(m) for m in sim.state_space())
    t = np.arange(len(u)) * dt

    def rhs(time, x):
        drive = u[min(int(np.floor(time / dt + 1e-9)), len(u) - 1)]
        return A @ x + B * (drive - k3 * (C @ x) ** 3)

    sol = solve_ivp(rhs, (0, t[-1]), np.zeros(len(B)), t_eval=t, rtol=1e-10, atol=1e-12, max_step=dt / 4)
    part = C @ sol.y
    return part + D * (u - k3 * part**3)


def test_lti_state_space_form_is_exact_and_its_feedback_second_order():
    """LTI's state-space form: without effects it is LTI.simulate (exact ZOH), with a cubic fed back it
    converges to solve_ivp at second order in the substep (Heun's rule for the force)."""
    rng = np.random.default_rng(0)
    u = np.repeat(rng.uniform(-1, 1, 60), 10)
    dt = 0.01
    sim = hybrid.LTI(3, tau_1=0.05, f_2=2.0, zeta_2=0.3, lowpass_2=0.5, bandpass_2=0.2, direct=0.1)
    plain, states = integrate(sim, jnp.asarray(u), dt)
    np.testing.assert_allclose(np.asarray(plain), np.asarray(sim.simulate(jnp.asarray(u), dt)), atol=1e-13)
    assert states.shape == (600, 3) and sim.states == ("lag_1", "low_2", "band_2")
    reference = _lti_with_cubic_scipy(sim, u, dt, 0.8)
    stack = EffectStack(sim, [PolynomialStiffness(stiffness_cube=0.8)])
    y = np.asarray(stack.simulate(jnp.asarray(u), dt))
    error = np.max(np.abs(y - reference))
    assert error < 2e-3 * np.ptp(reference)  # 2 substeps a sample (LTI's default)
    values = {k: float(v) for k, v in sim.parameters().items()}
    finer = type("LTIFourSubsteps", (hybrid.LTI,), {"substeps": 4})(3, **values)
    error4 = np.max(
        np.abs(np.asarray(integrate(finer, jnp.asarray(u), dt, lambda x, y: 0.8 * y**3)[0]) - reference)
    )
    assert 3.0 < error / error4 < 5.5  # halving the substep quarters the error: second order


def _tank_drive(n=600, seed=1):
    rng = np.random.default_rng(seed)
    return np.repeat(rng.uniform(0.0, 9.0, n // 20), 20)


@pytest.mark.parametrize("method", ["tustin", "zoh"])
def test_rc_network_state_space_form_is_its_own_discretisation(method):
    """Stepped once per sample, the network's state-space form is `simulate` (the block-lifted cascade)
    to rounding, and its Tustin form is scipy's bilinear discretisation of the continuous realisation."""
    import scipy.signal

    rng = np.random.default_rng(1)
    u = rng.uniform(-1, 1, 137)  # ends mid-block
    net = hybrid.RCNetwork(C_clamp=0.005, n_stages=12, method=method)
    y, states = integrate(net, jnp.asarray(u), 1 / 30)
    simulated = np.asarray(net.simulate(jnp.asarray(u), 1 / 30))
    np.testing.assert_allclose(np.asarray(y), simulated, rtol=0, atol=1e-12 * np.max(np.abs(simulated)))
    assert states.shape == (137, 13) and net.states[0] == "vc_0" and net.states[-1] == "vc_12"
    # each state is a compartment's double-layer voltage: under a steady 1 V, no current flows into C_k
    # and it equals the node voltage, the product of the sections' DC gains G Z/P up to k (Eq 14 at s = 0)
    G, Z, P = h.stage_zpk_np(10.0, 1.0, 0.5, 0.5, 0.5, 0.005, 12)
    settled = np.asarray(integrate(net, jnp.ones(600), 1 / 30)[1][-1])
    np.testing.assert_allclose(settled, np.cumprod(G * Z / P), rtol=1e-8)
    A, B, C, D = (np.asarray(m) for m in net.state_space())
    system = (A, B[:, None], C[None, :], np.atleast_2d(D))
    form = {"tustin": "bilinear", "zoh": "zoh"}[method]
    discrete = scipy.signal.cont2discrete(system, 1 / 30, method=form)
    _, reference, _ = scipy.signal.dlsim(discrete[:4] + (1 / 30,), u)
    np.testing.assert_allclose(simulated, reference[:, 0], rtol=0, atol=1e-10 * np.max(np.abs(simulated)))


def _rc_with_cubic_scipy(net, drive, t, k3):
    """ẋ = A x + B (u(t) − k3 y³), y = C x + D (u − k3 y³) with y³ of the state part; u(t) smooth; from rest."""
    A, B, C, D = (np.asarray(m) for m in net.state_space())

    def rhs(time, x):
        return A @ x + B * (drive(time) - k3 * (C @ x) ** 3)

    sol = solve_ivp(rhs, (0, t[-1]), np.zeros(len(B)), t_eval=t, rtol=1e-11, atol=1e-13, method="LSODA")
    part = C @ sol.y
    return part + D * (drive(t) - k3 * part**3)


def test_rc_network_with_a_cubic_fed_back_converges_at_second_order():
    """A force fed back into the network's Tustin form: the trapezoidal rule with the next force
    predicted (Heun) converges to solve_ivp's continuous solution at second order in the sample interval."""

    def drive(t):
        return 0.8 * np.sin(2 * np.pi * 0.7 * t) + 0.5 * np.sin(2 * np.pi * 1.9 * t)  # 0 at t = 0: from rest

    net = hybrid.RCNetwork(C_clamp=0.005, n_stages=8)
    stack = EffectStack(net, [PolynomialStiffness(stiffness_cube=0.6)])
    errors = []
    for rate in (20.0, 40.0):
        t = np.arange(int(6 * rate)) / rate
        reference = _rc_with_cubic_scipy(net, drive, t, 0.6)
        y = np.asarray(stack.simulate(jnp.asarray(drive(t)), 1 / rate))
        errors.append(np.max(np.abs(y - reference)) / np.ptp(reference))
    assert errors[0] < 1e-2  # 0.36 % at 20 Hz when written
    assert 3.0 < errors[0] / errors[1] < 5.5  # halving the interval quarters the error: second order


def _soft_window_np(z, half, rim):
    """±half about 0 with rims rim·half wide, in numpy: the top's softplus, then the bottom's."""
    width = rim * half
    below = half - width * np.logaddexp(0.0, (half - z) / width)
    return -half + width * np.logaddexp(0.0, (below + half) / width)


@pytest.mark.parametrize("method", ["zoh", "tustin"])
def test_a_window_holds_every_compartment_of_the_network_after_every_step(method):
    """`window_vc`: each double-layer voltage is taken into ±L after every step, against the network's
    realisation stepped here in numpy (scipy's discretisation of `state_space`), the window applied to
    each state; a window the states never reach is the network itself."""
    import scipy.signal

    net = hybrid.RCNetwork(C_clamp=0.005, n_stages=6, method=method)
    (window,) = hybrid.resolve_effects(["window_vc"], net)
    assert isinstance(window, StateWindow) and window.states == net.states and window.name == "window_vc"
    rng = np.random.default_rng(3)
    u = np.repeat(rng.uniform(-2.0, 2.0, 30), 10)
    dt = 1 / 30
    free = np.asarray(integrate(net, jnp.asarray(u), dt)[1])
    half = 0.5 * float(np.max(np.abs(free)))
    stack = EffectStack(net, [StateWindow("vc", net.states, vc_window=half)])
    y = np.asarray(stack.simulate(jnp.asarray(u), dt))
    A, B, C, D = (np.asarray(m) for m in net.state_space())
    system = (A, B[:, None], C[None, :], np.atleast_2d(D))
    Ad, Bd, *_ = scipy.signal.cont2discrete(system, dt, method={"zoh": "zoh", "tustin": "bilinear"}[method])
    Bd = Bd[:, 0]
    if method == "zoh":  # x_{k+1} = Φ x_k + Γ u_k
        step = lambda x, k: Ad @ x + Bd * u[k]
        x = np.zeros(len(B))
    else:  # the trapezoidal rule, x_{k+1} = Φ x_k + Γ(u_k + u_{k+1}) from x_0 = Γ u_0, Φ scipy's bilinear one
        Gamma = np.linalg.solve(np.eye(len(B)) - A * dt / 2, B * dt / 2)
        step = lambda x, k: Ad @ x + Gamma * (u[k] + u[min(k + 1, len(u) - 1)])
        x = _soft_window_np(Gamma * u[0], half, window.rim)
    out = []
    for k in range(len(u)):
        out.append(C @ x + D * u[k])
        x = _soft_window_np(step(x, k), half, window.rim)
    np.testing.assert_allclose(y, np.array(out), rtol=0, atol=1e-9 * np.ptp(out))
    states = stack.signals_into(jnp.asarray(u), dt)["window_vc"]
    assert np.max(np.abs(states)) <= half  # the clamp's voltage never leaves the window
    derived = stack.derived(jnp.asarray(u), dt)["window_vc"]
    expected = np.max(free[:, 0]) - np.max(states) + np.min(states) - np.min(free[:, 0])  # both ends
    assert derived["cut_percent_of_range"] == pytest.approx(100 * expected / np.ptp(free[:, 0]), rel=1e-9)
    assert window.material(derived, {}, window.thresholds)[0] and derived["cut_percent_of_range"] > 40
    rebuilt = build_simulation(describe_simulation(stack)).with_raw(stack.raw)  # as a saved model is read
    assert rebuilt.effects[0].states == net.states and rebuilt.effects[0].rim == window.rim
    np.testing.assert_allclose(np.asarray(rebuilt.simulate(jnp.asarray(u), dt)), y, rtol=0, atol=1e-12)
    wide = EffectStack(net, [StateWindow("vc", net.states, vc_window=100.0)])
    np.testing.assert_allclose(
        np.asarray(wide.simulate(jnp.asarray(u), dt)),
        np.asarray(net.simulate(jnp.asarray(u), dt)),
        atol=1e-12,
    )


def test_a_window_reads_its_unit_from_the_states_and_says_what_it_cannot_pin():
    net = hybrid.RCNetwork(n_stages=4)
    stack = EffectStack(net, ["window_vc", "window_vc_2"], drive_unit="mV")
    units = [e.units_for(stack.signal_unit(e), stack.drive_unit) for e in stack.effects]
    assert units == [{"vc_window": "mV"}, {"vc_2_window": "mV"}]
    small = StateWindow("vc", net.states, vc_window=5.0)
    assert "never reach the window" in small.unpinned_reason("vc_window", np.linspace(0.0, 1.0, 50))
    assert small.unpinned_reason("vc_window", np.linspace(0.0, 6.0, 50)) is None
    with pytest.raises(InputError, match="states must be a sequence"):
        StateWindow("vc", "vc_0")
    with pytest.raises(InputError, match="does not have"):
        hybrid.resolve_effects([StateWindow("vc", ("vc_0", "vc_9"))], net)


def test_state_limit_is_the_tank_examples_overflow_without_spill():
    u = jnp.asarray(_tank_drive())
    walls = TwoTankOverflow(level_max_1=9.0, level_max_2=1e4, spill_to_lower=1e-12)
    stack = EffectStack(TwoTank(), [StateLimit("h1", h1_max=9.0, rim=EXAMPLE_RIM)])
    h2 = np.asarray(stack.simulate(u, 4.0))
    np.testing.assert_allclose(h2, np.asarray(walls.simulate(u, 4.0)), rtol=1e-9, atol=1e-9)
    levels = stack.signals_into(u, 4.0)
    assert np.max(levels["limit_h1"]) <= 9.0  # never above the rim
    unlimited = np.asarray(TwoTank().trajectory(u, 4.0)["h1"])
    assert np.max(unlimited) > 10.0  # the drive does reach past it: the limit acts
    derived = stack.derived(u, 4.0)["limit_h1"]
    assert derived["level"] == pytest.approx(9.0) and derived["at_limit_percent"] > 5.0
    # How far the limit pulls the peak down, against the unlimited level computed here.
    expected_cut = 100.0 * (np.max(unlimited) - np.max(levels["limit_h1"])) / np.ptp(unlimited)
    assert derived["cut_percent_of_range"] == pytest.approx(expected_cut, rel=1e-9)
    assert expected_cut > 5.0


def test_a_limit_that_spills_is_the_tank_examples_overflow_into_the_lower_tank():
    """`into`: a share of what the rim cuts off h1 lands in h2, as `TwoTankOverflow.walls` spills (its own code)."""
    u = jnp.asarray(_tank_drive())
    for share in (0.3, 0.9):
        walls = TwoTankOverflow(level_max_1=9.0, level_max_2=1e4, spill_to_lower=share)
        stack = EffectStack(
            TwoTank(), [StateLimit("h1", into="h2", h1_max=9.0, h1_spill=share, rim=EXAMPLE_RIM)]
        )
        np.testing.assert_allclose(
            np.asarray(stack.simulate(u, 4.0)), np.asarray(walls.simulate(u, 4.0)), rtol=1e-9, atol=1e-9
        )
    lost = np.asarray(
        EffectStack(TwoTank(), [StateLimit("h1", h1_max=9.0, rim=EXAMPLE_RIM)]).simulate(u, 4.0)
    )
    assert np.max(np.asarray(stack.simulate(u, 4.0)) - lost) > 0.5  # the spill does raise the lower tank


def test_a_spills_jacobian_matches_finite_differences():
    """LM linearises through the spill: the output's derivative in the share and in the level."""
    u = jnp.asarray(_tank_drive(300))
    stack = EffectStack(TwoTank(), [StateLimit("h1", into="h2", h1_max=9.0, h1_spill=0.5)])
    _assert_jacobian_is_central_differences(stack, u, 4.0, {"h1_spill": 1e-5, "h1_max": 1e-5})


@pytest.mark.parametrize(("made_with", "picked"), [(1e-6, 0.02), (0.999, 1.0)])
def test_a_spilling_limits_screen_picks_the_share_the_data_were_made_with(made_with, picked):
    """Tanks whose upper rim loses its spill, or drops all of it into the lower tank (TwoTankOverflow's own
    walls make the data): the screened starts of `limit_h1` carry the share that fits them."""
    from hybrid.discovery._diagnose import prepare_search
    from hybrid.discovery._starts import limit_starts

    u = _tank_drive(600, seed=3)
    truth = TwoTankOverflow(level_max_1=6.0, level_max_2=1e4, spill_to_lower=made_with)
    h2 = np.asarray(truth.simulate(jnp.asarray(u), 4.0))
    assert np.ptp(h2) > 1.0
    record = hybrid.Recording.from_arrays(v_in=u, w=0.3 * h2 + 0.1, rate=0.25)
    limit = hybrid.resolve_effects(["limit_h1"], TwoTank())[0]
    search = prepare_search([record], TwoTank(), hybrid.DiagnoseSettings(), [limit])
    starts = limit_starts(search.problem, TwoTank(), limit, "h1_max", 2, search.frozen, "h1_spill")
    assert len(starts) == 2 and starts[0]["h1_spill"] == picked


def _wall_scipy(frequency, zeta, drive, t, top):
    """y'' = ω²(u − y) − 2ζωy' with a stop at `top` (scipy, an event per hit): the mass meets it and stays
    there while the drive pushes it on, and leaves when the drive pulls it back (an inelastic stop)."""
    w = 2 * np.pi * frequency

    def acc(s, y, v):
        return w * w * (drive(s) - y) - 2 * zeta * w * v

    def hit(s, x):
        return x[0] - top

    hit.terminal, hit.direction = True, 1
    out, s, x = np.full(len(t), np.nan), 0.0, np.zeros(2)
    while s < t[-1]:
        sol = solve_ivp(
            lambda s_, x_: [x_[1], acc(s_, *x_)], (s, t[-1]), x, events=hit, dense_output=True,
            rtol=1e-10, atol=1e-12, max_step=0.01,
        )  # fmt: skip
        moving = (t >= s) & (t <= sol.t[-1])
        out[moving] = sol.sol(t[moving])[0]
        s = sol.t[-1]
        if sol.status != 1:
            break
        grid = np.linspace(s, t[-1], 100_001)  # at the stop, at rest, until the drive pulls the mass back
        free = np.nonzero(acc(grid, top, 0.0) < 0)[0]
        leave = grid[free[0]] if len(free) else t[-1]
        out[(t >= s) & (t <= leave)] = top
        s, x = leave, np.array([top - 1e-12, 0.0])
    return out


def test_an_end_stop_is_the_oscillator_meeting_a_stop():
    """A limit on the position that stops its velocity (`StateLimit(velocity=…)`) against scipy's oscillator
    with an event per hit; the limit without the velocity holds the position while its velocity runs on."""
    rate, top = 200.0, 0.6
    t = np.arange(int(8 * rate)) / rate

    def drive(s):
        return np.sin(2 * np.pi * 0.7 * s) + 0.3 * np.sin(2 * np.pi * 2.3 * s)

    reference = _wall_scipy(2.0, 0.1, drive, t, top)
    assert (
        np.isfinite(reference).all() and np.mean(reference >= top - 1e-9) > 0.05
    )  # it does stay at the stop
    oscillator, u = MassSpringDamper(frequency=2.0, zeta=0.1), jnp.asarray(drive(t))
    stop = StateLimit("position", velocity="velocity", position_max=top)
    y = np.asarray(EffectStack(oscillator, [stop]).simulate(u, 1 / rate))
    # The rim (2 % of the level) and a hit's time known to a substep bound the agreement.
    assert np.max(np.abs(y - reference)) < 0.04 * np.ptp(reference)  # 3.3 % when written
    held = np.asarray(
        EffectStack(oscillator, [StateLimit("position", position_max=top)]).simulate(u, 1 / rate)
    )
    assert np.max(np.abs(held - reference)) > 0.2 * np.ptp(reference)  # the velocity left to run on: 32 %


def test_an_end_stop_below_is_the_mirror_of_one_above():
    """``floor_position`` (`StateLimit(below=True)`, stopping the velocity) against scipy's oscillator meeting
    a stop below: `_wall_scipy` with the drive and the stop negated, read back negated. Its cut is the
    trough's rise, its level ``position_min``, and it is saved and rebuilt with its side."""
    rate, bottom = 200.0, -0.6
    t = np.arange(int(8 * rate)) / rate

    def drive(s):
        return np.sin(2 * np.pi * 0.7 * s) + 0.3 * np.sin(2 * np.pi * 2.3 * s)

    reference = -_wall_scipy(2.0, 0.1, lambda s: -drive(s), t, -bottom)
    assert np.mean(reference <= bottom + 1e-9) > 0.05  # it does stay at the stop
    oscillator, u = MassSpringDamper(frequency=2.0, zeta=0.1), jnp.asarray(drive(t))
    stop = StateLimit("position", velocity="velocity", below=True, position_min=bottom)
    assert stop.name == "floor_position" and list(stop.constraints) == ["position_min"]
    stack = EffectStack(oscillator, [stop])
    y = np.asarray(stack.simulate(u, 1 / rate))
    assert np.max(np.abs(y - reference)) < 0.04 * np.ptp(reference)  # as the stop above it
    free = np.asarray(oscillator.simulate(u, 1 / rate))
    derived = stack.derived(u, 1 / rate)["floor_position"]
    lifted = 100 * (np.min(y) - np.min(free)) / np.ptp(free)
    assert derived["cut_percent_of_range"] == pytest.approx(lifted, rel=1e-6) and lifted > 10
    assert derived["level"] == pytest.approx(bottom)
    rebuilt = build_simulation(describe_simulation(stack)).with_raw(stack.raw)
    assert [e.name for e in rebuilt.effects] == ["floor_position"]
    np.testing.assert_allclose(np.asarray(rebuilt.simulate(u, 1 / rate)), y)


@pytest.mark.parametrize("below", [False, True])
def test_an_end_stops_jacobian_matches_finite_differences(below):
    rate = 100.0
    t = np.arange(int(6 * rate)) / rate
    u = jnp.asarray(np.sin(2 * np.pi * 0.7 * t) + 0.3 * np.sin(2 * np.pi * 2.3 * t))
    level = "position_min" if below else "position_max"
    stop = StateLimit("position", velocity="velocity", below=below, **{level: -0.6 if below else 0.6})
    stack = EffectStack(MassSpringDamper(frequency=2.0, zeta=0.1), [stop])
    # a step of 1e-6 in the level: the 0.5 % rim is curved enough that 1e-5 leaves central differences
    # themselves 4e-4 off at the record's end (1e-6 and 1e-7 agree with forward mode to 1e-8)
    _assert_jacobian_is_central_differences(stack, u, 1 / rate, {level: 1e-6, "frequency": 1e-6})


def test_a_limit_stops_the_velocity_that_moves_its_state():
    """The default limits: on a position, its velocity found from the rates (∂ẋ/∂v > 0), and a floor under
    it (an end stop below); none on a level, and no floor under one."""

    class Pendulum(MassSpringDamper):  # the same rates under other names, as a user's plug-in names them
        states = ("angle", "rate")
        state_units = {"angle": "rad", "rate": "rad/s"}
        limited_states = ("angle", "rate")
        velocity_states = ("rate",)

    def stops(simulation):
        return {e.name: e.velocity for e in hybrid.resolve_effects(None, simulation) if e.role == "limit"}

    assert stops(MassSpringDamper()) == {"limit_position": "velocity", "floor_position": "velocity"}
    assert stops(Pendulum()) == {"limit_angle": "rate", "limit_rate": None, "floor_angle": "rate"}
    assert stops(hybrid.LTI(3)) == {  # ṗ = ω·q
        "limit_lag_1": None,
        "limit_low_2": "band_2",
        "floor_low_2": "band_2",
    }
    assert stops(TwoTank()) == {"limit_h1": None, "limit_h2": None}
    stop = hybrid.resolve_effects(["limit_position"], MassSpringDamper())[0]  # by name too
    assert stop.velocity == "velocity"
    assert "(an end stop), which also stops the state that moves it (velocity) there" in stop.reading(
        {"position_max": 1.0}, "V"
    )
    u = jnp.asarray(np.sin(np.arange(300) / 20.0))
    stack = EffectStack(MassSpringDamper(), [StateLimit("position", velocity="velocity", position_max=0.3)])
    rebuilt = build_simulation(describe_simulation(stack)).with_raw(stack.raw)
    assert rebuilt.effects[0].velocity == "velocity"
    y = np.asarray(stack.simulate(u, 0.01))
    np.testing.assert_allclose(np.asarray(rebuilt.simulate(u, 0.01)), y)
    held = EffectStack(MassSpringDamper(), [StateLimit("position", position_max=0.3)])
    moved = np.max(np.abs(y - np.asarray(held.simulate(u, 0.01))))
    assert moved > 1e-3  # the saved stop does stop the velocity


def test_a_limit_naming_a_state_amiss_is_refused_in_one_line():
    class Leaky(TwoTank):
        spills_into = {"h1": "h3"}

    for build, words in (
        (
            lambda: hybrid.resolve_effects(None, Leaky()),
            "spills_into must map a state to another of its states",
        ),
        (lambda: StateLimit("h1", into="h1"), "into must name another state"),
        (
            lambda: hybrid.resolve_effects([StateLimit("h1", into="h9")], TwoTank()),
            "spills into the state 'h9'",
        ),
        (lambda: StateLimit("position", velocity="position"), "velocity must name another state"),
        (
            lambda: hybrid.resolve_effects([StateLimit("position", velocity="speed")], MassSpringDamper()),
            "stops the velocity the state 'speed', which MassSpringDamper does not have",
        ),
    ):
        with pytest.raises(InputError) as caught:
            build()
        assert words in str(caught.value) and "\n" not in str(caught.value)


def test_a_limit_acts_under_a_held_start_while_the_system_settles_too():
    """`HeldStart` (a record that starts where a held drive left the tanks) keeps the inside place."""
    u = jnp.asarray(_tank_drive(300, seed=2))
    held = hybrid.HeldStart(
        TwoTank(), 40, initial_drive=8.5
    )  # settles above the rim: overflowing at the start
    stack = EffectStack(held, [StateLimit("h1", h1_max=9.0, rim=EXAMPLE_RIM)])
    walls = hybrid.HeldStart(
        TwoTankOverflow(level_max_1=9.0, level_max_2=1e4, spill_to_lower=1e-12), 40, initial_drive=8.5
    )
    np.testing.assert_allclose(
        np.asarray(stack.simulate(u, 4.0)), np.asarray(walls.simulate(u, 4.0)), rtol=1e-9, atol=1e-9
    )
    assert stack.signals_into(u, 4.0)["limit_h1"].shape == u.shape  # the settling samples dropped


def test_a_test_records_initial_drive_is_refitted_through_an_effect_stack():
    """diagnose's extended model of a --settle record wraps the HeldStart: scoring still re-fits its start."""
    u = jnp.asarray(_tank_drive(200, seed=4))
    stack = EffectStack(hybrid.HeldStart(TwoTank(), 40, initial_drive=7.0), [StateLimit("h1", h1_max=30.0)])
    truth = hybrid.Model(stack, hybrid.LinearReadout(gain=0.3, offset=0.1), "physics")
    record = hybrid.Recording.from_arrays(v_in=np.asarray(u), w=np.asarray(truth.predict(u, 4.0)), rate=0.25)
    start = eqx.tree_at(lambda m: m.simulation, truth, stack.replace(initial_drive=3.0))
    refitted, value = hybrid.refit_initial_drive(start, record, 4, bounds=(0.0, 10.0))
    assert value == pytest.approx(7.0, abs=1e-3)
    assert float(refitted.simulation.parameters()["initial_drive"]) == pytest.approx(value)


def test_units_follow_the_drive_and_the_state():
    stack = EffectStack(TwoTank(), [PolynomialStiffness(), StateLimit("h1")], drive_unit="V")
    assert stack.units["h1_max"] == "cm"  # the state's unit
    assert stack.units["stiffness_cube"] == "V/cm^3"  # a force in the drive's unit per cube of h2 (cm)
    stack = EffectStack(MassSpringDamper(), [PolynomialStiffness()], drive_unit="kV")
    assert stack.units["stiffness_square"] == "1/kV"  # the oscillator's y is in the drive's unit: kV/kV^2
    assert stack.units["stiffness_cube"] == "1/kV^2"


def test_saved_stack_with_a_state_limit_round_trips():
    u = jnp.asarray(_tank_drive(200))
    stack = EffectStack(TwoTank(), [StateLimit("h1", h1_max=7.5)])
    config = describe_simulation(stack)
    rebuilt = build_simulation(config)
    rebuilt = rebuilt.with_raw(stack.raw)
    assert [e.name for e in rebuilt.effects] == ["limit_h1"]
    np.testing.assert_allclose(np.asarray(rebuilt.simulate(u, 4.0)), np.asarray(stack.simulate(u, 4.0)))


def test_resolve_effects_adds_inside_effects_only_where_there_are_states():
    names = [e.name for e in hybrid.resolve_effects(None, TwoTank())]
    assert "stiffness" in names and names[-2:] == ["limit_h1", "limit_h2"]
    lti = [e.name for e in hybrid.resolve_effects(None, hybrid.LTI(3))]  # LTI has a (linear) state-space form
    # limits on the low-pass states only, a floor under the one a velocity moves (an end stop below), a
    # friction on the band-pass one (its velocity_states); a tank's level gets no floor
    assert "stiffness" in lti and lti[-4:] == ["limit_lag_1", "limit_low_2", "floor_low_2", "friction_band_2"]
    oscillator = [e for e in hybrid.resolve_effects(None, MassSpringDamper()) if e.role == "limit"]
    assert [(e.name, e.velocity) for e in oscillator] == [
        ("limit_position", "velocity"),
        ("floor_position", "velocity"),
    ]
    assert [e.name for e in hybrid.resolve_effects(["floor_h1"], TwoTank())] == ["floor_h1"]
    # the RC network has the form, but its inside effects are searched only when named (too dear a default)
    network = hybrid.RCNetwork(n_stages=4)
    assert not [e for e in hybrid.resolve_effects(None, network) if e.place == "inside"]
    named = hybrid.resolve_effects(["stiffness", "limit_vc_0", "limit_vc_4"], network)
    assert [e.name for e in named] == ["stiffness", "limit_vc_0", "limit_vc_4"]
    places = searched_places(hybrid.resolve_effects(None, network), network)
    assert (
        places["inside"]["effects"] == []
        and "not by default for RCNetwork" in places["inside"]["not_searched"]
    )
    assert [e.name for e in hybrid.resolve_effects(["limit_h2"], TwoTank())] == ["limit_h2"]


@pytest.mark.parametrize(
    ("simulation", "effects", "words"),
    [
        (hybrid.Passthrough(), ["stiffness"], "has no state-space form"),
        (TwoTank(), [StateLimit("level")], "does not have: its states are h1, h2"),
        (TwoTank(), ["limit_h3"], "unknown effect 'limit_h3'"),
        # a few: each named
        (
            TwoTank(),
            ["limit_h3"],
            "limit_h1, limit_h2, floor_h1, floor_h2, friction_h1, friction_h2, window_h1, window_h2;",
        ),
        # The RC network's 46 states: one pattern, not 46 names
        (
            hybrid.RCNetwork(),
            ["limit_x"],
            "limit_<state> (limit_vc_0 … limit_vc_45), floor_<state> (floor_vc_0 … floor_vc_45), "
            "friction_<state> (friction_vc_0 … friction_vc_45), "
            "window_<state> (window_vc_0 … window_vc_45), window_vc (a window on every state of vc);",
        ),
    ],
)
def test_inside_effects_where_they_cannot_act_are_refused_in_one_line(simulation, effects, words):
    with pytest.raises(InputError) as caught:
        hybrid.resolve_effects(effects, simulation)
    assert words in str(caught.value) and "\n" not in str(caught.value)
    if not isinstance(effects[0], str):
        with pytest.raises(InputError):
            EffectStack(simulation, effects)


@pytest.mark.parametrize(
    ("options", "words"),
    [
        ({"below": True, "into": "h2"}, "a floor spills nothing (into='h2'); drop into"),
        ({"below": "yes"}, "below must be True or False, got 'yes'"),
    ],
)
def test_a_floor_asked_to_spill_or_given_a_side_that_is_not_a_bool_is_refused_in_one_line(options, words):
    with pytest.raises(InputError) as caught:
        StateLimit("h1", **options)
    assert words in str(caught.value) and "\n" not in str(caught.value)


# --- a user's inside effect, from the docs, through the command line -------------------------------

FRICTION_RATE, FRICTION_FORCE, STICK_SPEED = 30.0, 0.12, 0.3


def _friction_lab_scipy(u, dt, rtol=1e-10, atol=1e-12, max_step=None):
    """The friction lab's 2 Hz, ζ 0.1 oscillator (no noise, no readout) by solve_ivp, `u` linear between samples."""
    t = np.arange(len(u)) * dt
    w, zeta = 2 * np.pi * 2.0, 0.1

    def rhs(time, x):
        drive = np.interp(time, t, u) - FRICTION_FORCE * np.tanh(x[1] / STICK_SPEED)
        return [x[1], w * w * (drive - x[0]) - 2 * zeta * w * x[1]]

    step = dt / 4 if max_step is None else max_step
    return solve_ivp(rhs, (0, t[-1]), [0.0, 0.0], t_eval=t, rtol=rtol, atol=atol, max_step=step).y[0]


def _friction_lab(folder: Path, samples: int = 600, seed: int = 3, name: str = "lab.csv") -> None:
    """A 2 Hz mass on a spring sliding with Coulomb friction, 20 s at 30 Hz, made by solve_ivp.

    20 s (600 samples, 40 periods) name it as 40 s did (gain 122 against 86, force 0.1199 V
    against 0.1198) at about half the search's running time.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(samples) / FRICTION_RATE
    u = sum(0.35 * np.sin(2 * np.pi * f * t + rng.uniform(0, 6)) for f in (0.31, 0.77, 1.3, 1.9, 2.6))
    y = _friction_lab_scipy(u, 1 / FRICTION_RATE, rtol=1e-9, atol=1e-11, max_step=0.01)
    out = 2.0 * y + 0.1 + 0.003 * np.ptp(y) * rng.normal(size=y.size)
    units = {"t": "s", "v_in": "V", "w": "cm"}  # a position in cm: the saved models' units follow it
    hybrid.Recording.from_arrays(v_in=u, w=out, rate=FRICTION_RATE, metadata={"units": units}).save(
        folder / name
    )


def test_the_docs_friction_effect_is_found_inside_an_oscillator_from_the_command_line(
    tmp_path, capsys, monkeypatch
):
    code = h.docs_python_block("effects.md", "## An effect inside the dynamics", "## The interface")
    h.assert_public_imports_only(code)
    (tmp_path / "friction.py").write_text(code)
    _friction_lab(tmp_path)
    # Two rivals, not every built-in: saturation is what a friction most looks like from outside
    # (a response that falls short at small drive is not it, but a gain that changes is), and the
    # stiffness is the other inside feedback; the whole default set is searched on the Silverbox.
    run = h.run_hybrid(
        tmp_path,
        "diagnose",
        "lab.csv",
        "--physics",
        f"{EXAMPLES}/oscillator.py:MassSpringDamper",
        "--effects",
        "friction.py:CoulombFriction,saturation,stiffness",
        "--out",
        "report",
        "--quiet",
    )
    assert run.returncode == 0, run.stderr[-2000:]
    report = json.loads((tmp_path / "report" / "report.json").read_text())
    assert report["cause"] == "coulomb_friction", (report["cause"], report["candidates"])
    force = report["parameters"]["friction_force"]
    assert force["value"] == pytest.approx(FRICTION_FORCE, rel=0.3)
    assert force["unit"] == "V" and report["parameters"]["stick_speed"]["unit"] == "V/s"
    assert report["places"]["inside"]["effects"] == ["coulomb_friction", "stiffness"]
    h.import_file(tmp_path / "friction.py", "lab_friction")  # a saved model's plug-in, before it is loaded
    extended = hybrid.load_model(tmp_path / "report" / "extended.eqx")
    assert extended.units["offset"] == "cm" and extended.units["friction_force"] == "V"

    # The model diagnose extended is refitted as it is (hybrid fit --start-from), the plug-in imported
    # through --effects; starting values cannot be given twice.
    refit = h.run_hybrid(
        tmp_path,
        "fit",
        "lab.csv",
        "--model",
        "physics",
        "--physics",
        f"{EXAMPLES}/oscillator.py:MassSpringDamper",
        "--effects",
        "friction.py:CoulombFriction",
        "--start-from",
        "report/extended.eqx",
        "--max-steps",
        "5",
        "--out",
        "refit.eqx",
        "--json",
        "refit.json",
        "--quiet",
    )
    assert refit.returncode == 0, refit.stderr[-2000:]
    refitted = json.loads((tmp_path / "refit.json").read_text())["parameters"]
    assert refitted["friction_force"] == pytest.approx(force["value"], rel=0.05)
    # the refusal through the same command line in this process (`hybrid.cli.main`)
    monkeypatch.chdir(tmp_path)
    code = main(
        ["fit", "lab.csv", "--start-from", "report/extended.eqx", "--param", "zeta=0.2", "--out", "x.eqx"]
    )
    err = capsys.readouterr().err
    assert code != 0 and "--param" in err and "Traceback" not in err
    assert not (tmp_path / "x.eqx").exists()


def test_a_remainder_that_lives_inside_the_dynamics_says_whether_that_place_was_searched():
    from hybrid.discovery._effect_set import resolve_effects, searched_places
    from hybrid.discovery._unexplained import place_hint

    cubic = {"kind": "nonlinear_dynamic", "level_limit": []}
    bare = hybrid.Passthrough()
    none = searched_places(resolve_effects(None, bare), bare)
    assert (
        none["inside"]["effects"] == []
        and "Passthrough has no state-space form" in none["inside"]["not_searched"]
    )
    assert "Passthrough has no state-space form" in place_hint(cubic, none)
    rc = searched_places(resolve_effects(None, hybrid.RCNetwork()), hybrid.RCNetwork())
    assert "not by default for RCNetwork" in place_hint(cubic, rc)  # it has the form, but it is dear
    tanks = searched_places(resolve_effects(None, TwoTank()), TwoTank())
    assert "(stiffness, limit_h1, limit_h2), none explains the rest" in place_hint(cubic, tanks)
    held = hybrid.HeldStart(hybrid.RCNetwork(), 20)  # the wrapper's simulation is the one named
    assert "not by default for RCNetwork" in place_hint(
        cubic, searched_places(resolve_effects(None, held), held)
    )
    held = hybrid.HeldStart(hybrid.LTI(2), 20)  # LTI has a (linear) state-space form
    assert "(stiffness, limit_low_1, floor_low_1, friction_band_1), none explains the rest" in place_hint(
        cubic, searched_places(resolve_effects(None, held), held)
    )
    # level_limits' own shape: a side the record sits flat at is flagged
    flat_top = {"top": {"level": 2.0, "flag": True}, "bottom": {"level": -2.0, "flag": False}}
    assert place_hint({"kind": "static", "level_limit": flat_top}, tanks) is not None  # a flat top
    # no side flagged (a quantised output, static on the output): not sent inside, as it was
    neither = {"top": {"level": 2.9, "flag": False}, "bottom": {"level": -2.1, "flag": False}}
    assert place_hint({"kind": "static", "level_limit": neither}, tanks) is None
    assert place_hint({"kind": "static", "level_limit": {"reason": "no samples"}}, tanks) is None


def test_a_start_that_makes_the_dynamics_escape_is_pulled_towards_the_effects_defaults():
    """A softening spring started far too soft sends an LTI to infinity: its lane starts nearer the
    defaults (finite), and a start that stays finite is kept as given."""
    from hybrid.discovery._search import lanes_problem, simulation_output
    from hybrid.discovery._step import _finite_lanes

    rng = np.random.default_rng(0)
    u = np.repeat(rng.uniform(-1, 1, 30), 10)
    y = np.asarray(hybrid.LTI(2).simulate(jnp.asarray(u), 0.1))
    recording = hybrid.Recording.from_arrays(v_in=u, w=y + 0.01 * rng.normal(size=y.size), rate=10.0)
    settings = hybrid.DiagnoseSettings()
    problem, _, model = lanes_problem([recording], hybrid.LTI(2), settings, effects=["stiffness"])
    stack, frozen = model.simulation, frozenset(settings.frozen_for(hybrid.LTI(2)))
    i = [e.name for e in stack.effects].index("stiffness")
    active = np.zeros(len(stack.effects))
    active[i] = 1.0
    effect = stack.effects[i]
    wild, mild = {"stiffness_cube": -1e9}, {"stiffness_cube": 0.05}
    starts = [stack.replace(**v).with_active(jnp.asarray(active)) for v in (wild, mild)]
    escaped = simulation_output(problem, starts[0], model.readout, frozen, "train")
    assert not np.all(np.isfinite(escaped))  # the wild start does escape
    lanes, moved = _finite_lanes(
        problem,
        stack,
        starts,
        [(effect, v, jnp.asarray(active)) for v in (wild, mild)],
        model.readout,
        frozen,
    )
    assert all(np.all(np.isfinite(np.asarray(theta))) for theta in lanes)
    assert moved == [
        True,
        False,
    ]  # which starts were moved (a plug-in effect's are reported: nonfinite_lanes)
    cubes = [float(problem.model(theta).simulation.parameters()["stiffness_cube"]) for theta in lanes]
    assert -1e9 < cubes[0] <= 0.0 and cubes[1] == pytest.approx(0.05)


# --- where a remainder inside the dynamics lives: a map of a state --------------------------------


def test_the_response_to_a_force_on_the_drive_matches_finite_differences():
    """`force_responses` (forward mode through the stepped dynamics) against central differences of `simulate`."""
    from hybrid.discovery._effect_stack import force_responses, state_trajectories

    rng = np.random.default_rng(4)
    u = _drive(n=400)
    stack = hybrid.extend(
        MassSpringDamper(frequency=40.0, zeta=0.05), "stiffness", "saturation", stiffness_cube=30.0
    )
    forces = np.stack([0.01 * np.tanh(rng.normal(size=u.size)), 0.02 * np.sin(np.arange(u.size) / 7.0)])
    got = np.asarray(force_responses(stack, jnp.asarray(u), DT, jnp.asarray(forces)))
    eps = 1e-4
    for force, row in zip(forces, got):
        diff = (
            np.asarray(stack.simulate(u - eps * force, DT)) - np.asarray(stack.simulate(u + eps * force, DT))
        ) / (2 * eps)
        assert np.max(np.abs(row - diff)) <= 1e-6 * np.max(np.abs(diff))
    states = np.asarray(state_trajectories(stack, jnp.asarray(u), DT))
    # the first state is the position, the simulation's output (before the output's saturation)
    bare = stack.with_active(np.array([1.0, 0.0]))
    np.testing.assert_allclose(states[:, 0], np.asarray(bare.simulate(u, DT)), rtol=0, atol=1e-12)


def test_a_friction_no_searched_effect_explains_is_placed_on_the_velocity_with_its_step(tmp_path):
    """The docs' friction lab (solve_ivp), diagnosed with the stiffness alone: the remainder names its state.

    The search cannot name the friction (no effect of it is searched); the
    remainder's map of each state fed back into the drive places it on the
    velocity, as a step at zero of 2 × 0.12 V (first order, about the fitted
    model whose damping took up part of it: 0.20 V seen, within 30 %).
    """
    _friction_lab(tmp_path)
    recording = hybrid.Recording.load(tmp_path / "lab.csv")
    found = hybrid.diagnose(recording, simulation=MassSpringDamper(), effects=["stiffness"], progress=False)
    assert found.cause == "none" and found.unexplained is not None
    description = found.unexplained["description"]
    print(description["summary"])  # the figures docs/diagnose.md quotes (pytest -s)
    fed = description["state_feedback"]
    assert description["kind"] == "nonlinear_dynamic" and description["recovered"]["named"] == "state_map"
    assert fed["best"] == "velocity" and fed["states"]["velocity"]["unit"] == "V/s"
    velocity, position = fed["states"]["velocity"], fed["states"]["position"]
    assert velocity["of_excess"] >= 0.6 and position["of_excess"] < 0.2
    assert velocity["form"] == "step" and velocity["force_unit"] == "V"
    assert velocity["forms"]["step"]["size"] == pytest.approx(2 * FRICTION_FORCE, rel=0.3)
    assert "state velocity fed back into its drive" in description["summary"]
    assert "as a Coulomb friction has" in description["summary"]
    # a step at zero is what the built-in friction takes: the summary points at it, named for the state
    assert "a dry friction on its state velocity may" in description["summary"]
    assert "--effects builtins,friction_velocity" in description["summary"]
    assert "an effect of your own" not in description["summary"]
    # the oscillator's own parameters are pinned here: no word that its states may not be the system's
    assert not set(found.not_pinned) & {"frequency", "zeta"}
    assert "the states are the fitted model's" not in description["summary"]

    # A second recording of another length in the same bucket (a lab's next one, in one session):
    # the state maps' two programs serve it as the search's do, compiled once.
    assert bucket_length(571) == bucket_length(len(recording.t))
    _friction_lab(tmp_path, samples=571, seed=8, name="next.csv")
    compiles = collections.Counter()

    def listen(event, duration, fun_name=None, **_):
        if event == "/jax/core/compile/backend_compile_duration":
            compiles[fun_name] += 1

    monitoring.register_event_duration_secs_listener(listen)
    try:
        again = hybrid.diagnose(
            hybrid.Recording.load(tmp_path / "next.csv"),
            simulation=MassSpringDamper(),
            effects=["stiffness"],
            progress=False,
        )
    finally:
        monitoring.unregister_event_duration_listener(listen)
    assert again.unexplained["description"]["state_feedback"]["best"] == "velocity"
    assert not [name for name in compiles if "state_trajectories" in name or "force_responses" in name], (
        compiles
    )


def test_the_built_in_friction_inside_an_oscillator_matches_solve_ivp_and_its_derivatives(tmp_path):
    _friction_lab(tmp_path, samples=300)
    recording = hybrid.Recording.load(tmp_path / "lab.csv")
    u, dt = np.asarray(recording.v_in), recording.dt
    friction = Friction("velocity", velocity_friction=FRICTION_FORCE, velocity_stick_speed=STICK_SPEED)
    stack = EffectStack(MassSpringDamper(frequency=2.0, zeta=0.1), [friction])
    y = np.asarray(stack.simulate(jnp.asarray(u), dt))
    reference = _friction_lab_scipy(u, dt)
    linear = np.asarray(MassSpringDamper(frequency=2.0, zeta=0.1).simulate(jnp.asarray(u), dt))
    # RK4, 4 steps a sample at 15 samples a period, and a tanh 0.3 V/s wide on speeds to ~8 V/s: 1.5e-3
    # of the range where the friction turns (the full 600 samples), against 0.26 without the friction.
    assert np.max(np.abs(y - reference)) < 3e-3 * np.max(np.abs(reference))
    assert np.max(np.abs(linear - reference)) > 30 * np.max(np.abs(y - reference))
    assert friction.name == "friction_velocity" and friction.acts_on == "velocity"
    assert friction.units_for("V/s", "V") == {"velocity_friction": "V", "velocity_stick_speed": "V/s"}
    _assert_jacobian_is_central_differences(
        stack, jnp.asarray(u[:200]), dt, {"velocity_friction": 1e-5, "velocity_stick_speed": 1e-5}
    )
    # by name, for a state the simulation has; one it lacks is refused with the names it has
    (named,) = hybrid.resolve_effects(["friction_velocity"], MassSpringDamper())
    assert isinstance(named, Friction) and named.state == "velocity"
    with pytest.raises(InputError, match="did you mean 'friction_velocity'"):
        hybrid.resolve_effects(["friction_velocty"], MassSpringDamper())
    # by default on the states a simulation calls velocities (`velocity_states`), on no other

    def frictions(simulation):
        return [e.name for e in hybrid.resolve_effects(None, simulation) if isinstance(e, Friction)]

    assert frictions(MassSpringDamper()) == ["friction_velocity"]
    assert frictions(hybrid.LTI(4)) == ["friction_band_1", "friction_band_2"]
    assert frictions(hybrid.LTI(1)) == frictions(TwoTank()) == []
    assert [e.name for e in hybrid.resolve_effects(["friction_h1"], TwoTank())] == ["friction_h1"]

    class Misnamed(MassSpringDamper):
        velocity_states = ("speed",)

    with pytest.raises(
        InputError, match=r"velocity_states must be a tuple of its states \(position, velocity\)"
    ):
        hybrid.resolve_effects(None, Misnamed())


def test_the_built_in_friction_the_remainder_points_at_is_named_with_its_force(tmp_path):
    """The lab of the test above, searched with the friction it pointed at: named, F and v_s near the truth."""
    _friction_lab(tmp_path)
    recording = hybrid.Recording.load(tmp_path / "lab.csv")
    found = hybrid.diagnose(
        recording, simulation=MassSpringDamper(), effects=["stiffness", "friction_velocity"], progress=False
    )
    assert [c["name"] for c in found.causes] == ["friction_velocity"], found.verdict
    assert found.causes[0]["place"] == "inside"  # where it acts, beside its name (a probe found it nowhere)
    assert found.unexplained is None, found.verdict
    parameters = found.causes[0]["parameters"]
    values = {k: v["value"] for k, v in parameters.items()}
    print(found.verdict, values, f"gain {found.gain:.3g}")  # the figures README quotes (pytest -s)
    # 0.1199 V and 0.304 V/s when written (first order in the noise: 0.3 % of the range)
    assert parameters["velocity_friction"]["value"] == pytest.approx(FRICTION_FORCE, rel=0.05)
    assert parameters["velocity_stick_speed"]["value"] == pytest.approx(STICK_SPEED, rel=0.2)
    assert (
        parameters["velocity_friction"]["unit"] == "V" and parameters["velocity_stick_speed"]["unit"] == "V/s"
    )
    assert "Coulomb" in found.causes[0]["reading"]
    assert found.gain > 20


def test_a_final_model_bent_out_of_its_plausible_range_or_on_a_scale_of_its_own_is_warned_about():
    """`model_warnings`: what a new user's two-mass drive with a sensor lag met in silence.

    The fit took up a 0.1 s sensor lag by bending the plant (a damping below its plausible range) and
    said "no effect needed"; its readout gain (0.24, w and the simulation's output both in rad/s) put
    every size in the output's unit on a scale of its own.
    """
    from hybrid.core._readout import LinearReadout
    from hybrid.discovery._diagnose import model_warnings

    def model(zeta, gain):
        built = hybrid.make_model("physics", simulation=MassSpringDamper(frequency=2.0, zeta=zeta))
        return dataclasses.replace(built, readout=LinearReadout(gain=gain), signal_units=("V", "V"))

    assert model_warnings(model(0.1, 1.05), frozenset()) == []  # plausible, the measured scale
    bent = model_warnings(model(50.0, 1.0), frozenset())
    assert len(bent) == 1 and "zeta = 50 is outside its plausible range 0.0001 to 10" in bent[0]
    assert "take up an effect it lacks" in bent[0]
    assert model_warnings(model(50.0, 1.0), frozenset({"zeta"})) == []  # a frozen value is the user's
    scaled = model_warnings(model(0.1, 0.2438), frozenset())
    assert (
        len(scaled) == 1 and "the readout's gain is 0.2438" in scaled[0] and "4.1× the measured" in scaled[0]
    )
    assert "(V)" in scaled[0]
    assert "upside down" not in scaled[0] and "step between units" not in scaled[0]
    assert "fixed already" not in scaled[0]  # nothing frozen: the scale may be free
    # a scale fixed already (a chamber user's conductance frozen at its true value): the gain is the fit's,
    # or the fixed value is off by it (a probe's motor constant frozen at 10 for a true 12: gain 1.2)
    (bent_scale,) = model_warnings(model(0.1, 0.2438), frozenset({"zeta"}))
    assert "fixed already (zeta here)" in bent_scale and "take up an effect it lacks" in bent_scale
    assert "its fixed value is 0.244× off" in bent_scale
    # a negative gain: the output is the simulation's upside down (a current's sign flipped)
    (flipped,) = model_warnings(model(0.1, -0.9), frozenset())
    assert "upside down" in flipped and "step between units" not in flipped
    # a gain near 1/1000: a drive in mA for a simulation in A (and near 1000, the other way)
    for g, power in ((1.04e-3, -3), (-980.0, 3)):
        (units,) = model_warnings(model(0.1, g), frozenset())
        assert f"near 10^{power}, the step between units" in units, units
        assert ("upside down" in units) is (g < 0)
    (far,) = model_warnings(model(0.1, 2e-3), frozenset())  # twice 1/1000: no unit step
    assert "step between units" not in far
    # w in another unit than the simulation's output: the gain converts units, and says nothing of scale
    other = dataclasses.replace(model(0.1, 0.2438), signal_units=("mm", "V"))
    assert model_warnings(other, frozenset()) == []


def test_a_force_of_a_speed_output_reads_as_a_damping_and_of_a_position_as_a_spring():
    """One form, two physics: a polynomial force of the output is a spring on mm, a drag on mm/s."""
    stiff = PolynomialStiffness(stiffness_cube=0.01)
    assert "damping" in stiff.reading({"stiffness_cube": 0.01}, "rad/s")
    assert "not a spring" in stiff.reading({"stiffness_cube": 0.01}, "L/min")
    assert "hardens" in stiff.reading({"stiffness_cube": 0.01}, "mm")
    assert "softens" in stiff.reading({"stiffness_cube": -0.01}, "µm")
    neither = stiff.reading({"stiffness_cube": 0.01}, "V")  # the unit does not say: both readings given
    assert "spring where the output is a position" in neither and "damping where it is a speed" in neither
    # Where the output went decides, not k₃'s sign alone: on a temperature that only rises (0 to 70 in
    # the simulation's unit), k₂ = 9.4e-4 with k₃ = −5.3e-6 (a chamber's radiative loss, ∝ T⁴, as
    # `diagnose` fitted it with `lti:1`) is a loss that quickens: y·φ(y) > 0 over the whole record.
    y = np.linspace(0.0, 70.0, 400)
    chamber = PolynomialStiffness(stiffness_square=9.4e-4, stiffness_cube=-5.3e-6)
    share = chamber.derived(y, 1.0)["restoring_percent"]
    phi = 9.4e-4 * y**2 - 5.3e-6 * y**3
    assert share == pytest.approx(100 * np.sum(y * phi) / np.sum(np.abs(y * phi)), rel=1e-12)
    assert share == pytest.approx(100.0)
    values = {"stiffness_square": 9.4e-4, "stiffness_cube": -5.3e-6, "restoring_percent": share}
    assert "grows faster than linearly" in chamber.reading(values, "degC")
    # on a position that swings both ways the square term cancels and k₃ < 0 softens the spring
    swing = chamber.derived(y - 35.0, 1.0)
    assert swing["restoring_percent"] < 0
    assert "softens" in chamber.reading({**values, **swing}, "mm")
    # An end stop on the state the output reads and a sensor that clips there look alike: both said.
    stop = StateLimit("position").reading({"position_max": 85.0}, "µm")
    assert "end stop" in stop and "a sensor that clips at that level looks alike" in stop
    assert "spills into h2" in StateLimit("h1", into="h2").reading({"h1_max": 1.0}, "V")


def test_a_causes_reading_takes_the_final_models_derived_quantities():
    """`Diagnosis.causes` reads a cause from the final model's values *and* its derived quantities on the
    recording (`final_derived`): the chamber's fit (k₂ > 0, k₃ < 0) on a temperature is a loss that grows,
    as its restoring share says, where k₃'s sign alone would read one that eases."""
    from hybrid.discovery._diagnosis import Candidate, Diagnosis, EquallyGoodFits
    from hybrid.discovery._step import Step

    values = {"stiffness_square": 9.4e-4, "stiffness_cube": -5.3e-6}
    chamber = PolynomialStiffness(**values)
    fit = Candidate(
        name="stiffness",
        parameters=values,
        derived={},
        train_rss=1.0,
        n_parameters=4,
        bic=0.0,
        heldout=None,
        ljung_box={},
        gain=3.9,
        delta_bic=-50.0,
    )
    bar = EquallyGoodFits(n=0, heldout_nmse_min=float("nan"), heldout_nmse_max=float("nan"), definition="-")

    def diagnosis(share):
        return Diagnosis(
            cause="stiffness",
            baseline=dataclasses.replace(fit, name="none"),
            extended=fit,
            candidates=[fit],
            uncertainties={},
            evidence={},
            hybrid=None,
            settings=hybrid.DiagnoseSettings(),
            recordings=["r"],
            seconds=0.0,
            heldout=None,
            steps=[Step(fit, [fit], fit, 0.0, [], bar, [])],
            effects=(chamber,),
            signal_units={"w": "degC", "v_in": "W"},
            final_derived={"stiffness": {"restoring_percent": share}},
        )

    rising = chamber.derived(np.linspace(0.0, 70.0, 400), 1.0)["restoring_percent"]
    (cause,) = diagnosis(rising).causes
    assert (
        cause["derived"]["restoring_percent"] == rising and "grows faster than linearly" in cause["reading"]
    )
    (cause,) = diagnosis(-rising).causes  # the same values, the force taking from the restoring one
    assert "eases as it warms" in cause["reading"]


def test_a_quadratic_drag_on_a_motors_speed_is_read_as_a_damping_from_the_command_line(tmp_path):
    """A speed ω' = −aω + b(u − cω|ω|) (solve_ivp), recorded in rad/s and diagnosed with `lti:1`.

    The stiffness takes the drag (its cube fits ω|ω|): the report must not call it a spring.
    """
    rng = np.random.default_rng(0)
    rate, n = 25.0, 1000
    t = np.arange(n) / rate
    u = np.repeat(rng.uniform(-10, 10, n // 25 + 1), 25)[:n]
    a, b, c = 2.0, 3.0, 0.02
    sol = solve_ivp(
        lambda s, x: [-a * x[0] + b * (u[min(int(s * rate), n - 1)] - c * x[0] * abs(x[0]))],
        (0, t[-1]),
        [0.0],
        t_eval=t,
        max_step=0.5 / rate,
    )
    w = sol.y[0] + rng.normal(0, 0.005 * np.ptp(sol.y[0]), n)
    np.savetxt(tmp_path / "motor.csv", np.c_[t, u, w], delimiter=",", header="t,u,w\ns,V,rad/s", comments="")
    run = h.run_hybrid(
        tmp_path,
        *("diagnose", "motor.csv", "--columns", "time=t,input=u,output=w", "--physics", "lti:1"),
        *("--effects", "stiffness", "--out", "report", "--quiet"),
    )
    assert run.returncode == 0, run.stderr[-2000:]
    report = json.loads((tmp_path / "report" / "report.json").read_text())
    assert report["cause"] == "stiffness", report["candidates"]
    reading = report["causes"][0]["reading"]
    assert "(rad/s) is a rate" in reading and "damping" in reading and "not a spring" in reading
    assert reading in run.stdout
    assert f"stiffness: {reading}" in (tmp_path / "report" / "report.md").read_text()


def test_a_limit_never_reached_and_a_friction_never_turned_are_said_to_be_unpinned_for_that():
    # `not_pinned` hands each effect the signal that enters it (here a state's trajectory, through
    # `signals_into`), and the effect says why the recording cannot set its parameter.
    from hybrid.discovery._diagnosis import ParameterUncertainty
    from hybrid.discovery._evidence import not_pinned

    def series(v_in, rate):
        return series_from_recording(
            hybrid.Recording.from_arrays(v_in=v_in, w=np.zeros_like(v_in), rate=rate)
        )

    u = _tank_drive()
    record = series(u, 0.25)
    peak = float(np.max(np.asarray(TwoTank().trajectory(jnp.asarray(u), 4.0)["h1"])))
    unknown = {"h1_max": ParameterUncertainty(float("inf"), "cm", 1.0)}

    def why(stack):
        return not_pinned(unknown, hybrid.make_model("physics", simulation=stack), [record]).get("h1_max")

    # above the unlimited level's peak by more than the rim: never reached; at 90 % of it: reached
    assert why(EffectStack(TwoTank(), [StateLimit("h1", h1_max=1.1 * peak)])) == (
        "the state never reaches the limit in this recording"
    )
    reached = why(EffectStack(TwoTank(), [StateLimit("h1", h1_max=0.9 * peak)]))
    assert reached is not None and "never reaches" not in reached

    drive = _drive(600)
    moving = series(drive, 50.0)
    oscillator = MassSpringDamper(frequency=2.0, zeta=0.1)
    speed = np.abs(np.asarray(oscillator.trajectory(jnp.asarray(drive), 0.02)["velocity"]))
    stick = {"velocity_stick_speed": ParameterUncertainty(float("inf"), "V/s", 1.0)}

    def turn(stick_speed):
        friction = Friction("velocity", velocity_friction=0.01, velocity_stick_speed=stick_speed)
        model = hybrid.make_model("physics", simulation=EffectStack(oscillator, [friction]))
        return not_pinned(stick, model, [moving])["velocity_stick_speed"]

    # a turn narrower than the samples resolve (a micro-V/s against speeds to 0.7 V/s): only the start
    # at rest lies inside it
    assert turn(1e-6).startswith("the state velocity is near zero, where the friction turns, on 1 of its 600")
    # a turn 5 % of the largest speed wide has many samples in it: the numbers' reason is given instead
    wide = turn(0.05 * float(np.max(speed)))
    assert "friction turns" not in wide and "does not change with it" in wide


class _Block(hybrid.AbstractStateSpace):
    """A heated block, heater W -> temperature, first order about an ambient (a test plug-in)."""

    raw: dict
    constraints = {"capacity": hybrid.Positive(), "resistance": hybrid.Positive(), "ambient": hybrid.Real()}
    units = {"capacity": "J/K", "resistance": "K/W", "ambient": "K"}
    plausible = {"capacity": (0.1, 1e5), "resistance": (1e-3, 100.0), "ambient": (-300.0, 400.0)}
    states = ("temperature",)
    state_units = {"temperature": "K"}
    output_unit = "K"
    limited_states = ("temperature",)
    substeps = 2

    def __init__(self, capacity=12.0, resistance=1.5, ambient=22.0):
        self.raw = hybrid.encode(
            dict(capacity=capacity, resistance=resistance, ambient=ambient), self.constraints, "Block"
        )

    def rates(self, x, u, p):
        return ((u - (x[0] - p["ambient"]) / p["resistance"]) / p["capacity"],)

    def initial_state(self, u0, p):
        return (p["ambient"] + p["resistance"] * u0,)

    def observe(self, x, p):
        return x[0]


def test_a_limits_rim_does_not_depend_on_the_zero_of_the_states_unit():
    """One block and one ceiling 22 K above its ambient, in °C (ambient 22) and in K (295.15).

    The rim was 2 % of |L| wide: 0.9 in °C, 6.3 in K, and the softplus applied after every step held
    the block in K 33 K below the ceiling, under its ambient (the probe's false all-clear). Measured
    from the state's rest (its initial state under no drive; τ = 1.8 s), the two are one response shifted by
    273.15, and the block's top sits within a small share of the rise below the ceiling (its
    unlimited response, integrated here by scipy's solve_ivp, goes far past it).
    """
    rate, dt = 30.0, 1 / 30.0
    u = np.repeat(np.r_[0.0, np.random.default_rng(5).choice([0.0, 10.0, 20.0], 12)], 300)  # W, 10 s each
    tops = {}
    for ambient in (22.0, 295.15):
        stack = EffectStack(
            _Block(ambient=ambient), [StateLimit("temperature", temperature_max=ambient + 22.0)]
        )
        tops[ambient] = np.asarray(stack.simulate(jnp.asarray(u), dt))
    np.testing.assert_allclose(tops[295.15] - 273.15, tops[22.0], rtol=0, atol=1e-9)
    free = solve_ivp(
        lambda t, x: [(u[min(int(t * rate), u.size - 1)] - x[0] / 1.5) / 1.2],  # above ambient
        (0, u.size / rate),
        [0.0],
        max_step=dt / 4,
        t_eval=np.arange(u.size) / rate,
    ).y[0]
    assert free.max() > 25.0  # the rise the limit cuts: up to 30 K
    assert 22.0 - 0.1 * 22.0 < tops[22.0].max() - 22.0 <= 22.0


def test_a_limits_rim_is_an_option_saved_with_it():
    """`rim` (default `RIM_WIDTH`, 0.5 %) travels in the config; a model saved before it was an option
    was fitted with the 2 % rim of then and loads with it."""
    from hybrid.discovery._inside_effects import LEGACY_RIM, RIM_WIDTH

    assert StateLimit("h1").rim == RIM_WIDTH == 0.005
    narrow = StateLimit("h1", into="h2", rim=0.01)
    assert StateLimit.from_config(narrow.config()).rim == 0.01
    assert StateLimit.from_config({"state": "h1"}).rim == LEGACY_RIM == 0.02
    for bad in (0.0, 1.0, -0.1, True, "0.01"):
        with pytest.raises(InputError, match="rim is the rim's width"):
            StateLimit("h1", rim=bad)
    u = jnp.asarray(_tank_drive())  # the wider rim holds the level further below the limit
    tops = {
        rim: float(
            np.max(
                EffectStack(TwoTank(), [StateLimit("h1", h1_max=9.0, rim=rim)]).signals_into(u, 4.0)[
                    "limit_h1"
                ]
            )
        )
        for rim in (0.005, 0.02)
    }
    assert tops[0.02] < tops[0.005] <= 9.0


class _Cart(hybrid.AbstractStateSpace):
    """tau·v' = u − v: one state, a speed in m/s, and no velocity_states (a probe's cart)."""

    raw: dict
    constraints = {"tau": hybrid.Positive()}
    units = {"tau": "s"}
    states = ("speed",)
    state_units = {"speed": "m/s"}

    def __init__(self, tau=1.0):
        self.raw = hybrid.encode({"tau": tau}, self.constraints, "_Cart")

    def rates(self, x, u, p):
        return ((u - x[0]) / p["tau"],)


def test_a_state_whose_unit_is_a_speed_gets_a_friction_by_default():
    """A probe's cart named no velocity_states: its Coulomb friction was not searched, and diagnose named
    a drive dead zone and a nonlinear damping instead (with the friction named, 37× and the force to 1 %).
    A state in a speed's unit is a velocity where the simulation names none; one it names wins, and a
    flow (L/min) or a level (m) is no speed."""
    from hybrid.core._state_space import velocities
    from hybrid.data._header_units import speed_unit

    cart = _Cart()
    assert velocities(cart) == ("speed",)
    assert "friction_speed" in [e.name for e in hybrid.resolve_effects(None, cart)]
    assert velocities(MassSpringDamper()) == ("velocity",)  # named: as named
    for unit in ("m/s", "mm/s", "rad/s", "°/s", "deg/s", "rpm", "m·s⁻¹", "degrees/s", "rev/s", "in/s"):
        assert speed_unit(unit), unit
    for unit in ("L/min", "m", "V", "m/s²", "W", "", "K/s"):
        assert not speed_unit(unit), unit
    level = type("_Level", (_Cart,), {"state_units": {"speed": "m"}})()
    assert velocities(level) == () and "friction_speed" not in [
        e.name for e in hybrid.resolve_effects(None, level)
    ]


def test_a_damping_reading_says_the_form_fitted_not_one_drag_law():
    """On a speed, a probe's v³ damping (fitted k₃ 1.98 for 2.0) and its v·|v| drag were both read "a drag
    ∝ v·|v|": the reading now says the form fitted, with v·|v| and a cube as the drags it covers."""
    grows = PolynomialStiffness().reading({"stiffness_cube": 2.0}, "m/s")
    eases = PolynomialStiffness().reading({"stiffness_cube": -2.0}, "m/s")
    assert "grows faster than the speed, fitted as k₂·v² + k₃·v³" in grows and "or a cube" in grows
    assert "eases at speed, fitted as k₂·v² + k₃·v³" in eases and "drag" not in eases


def _rc_behind_a_window(path, seconds: float = 20.0, rate: float = 30.0, seed: int = 4) -> float:
    """The paper's network (Eqs 11–13 in numpy, `helpers.stage_zpk_np`) as an ODE in its 46 double-layer
    voltages, each spilling past ±W (a steep smooth leak of the charging current, either sign), solved by
    solve_ivp under random levels in [−2, 2] V held 0.1–1 s; W half the largest unlimited |v_C|; noise 0.5 %
    of the range. Writes the CSV; returns W."""
    G, Z, P = h.stage_zpk_np(10.0, 1.0, 0.5, 0.5, 0.5, 0.02, 45)
    rng = np.random.default_rng(seed)
    n = int(seconds * rate)
    t = np.arange(n) / rate
    u = h.held_levels(rng, t, -2.0, 2.0, 0.1, 1.0)

    def rhs(time, x, window):
        v = u[min(int(time * rate + 1e-9), n - 1)]
        dx = np.empty(len(G))
        for k in range(len(G)):
            dx[k] = G[k] * Z[k] * v - P[k] * x[k]
            v = G[k] * v + (1 - P[k] / Z[k]) * x[k]
        if window is not None:
            up, down = expit((x - window) / (0.002 * window)), expit((-window - x) / (0.002 * window))
            dx = dx - np.maximum(dx, 0.0) * up - np.minimum(dx, 0.0) * down
        return dx

    def tip(states):  # V_o = the states' part plus the drive through every section's direct gain
        out = np.zeros(states.shape[1])
        for k in range(len(G)):
            out = G[k] * out + (1 - P[k] / Z[k]) * states[k]
        return out + np.prod(G) * u

    def run(window):
        sol = solve_ivp(
            rhs,
            (0, t[-1]),
            np.zeros(len(G)),
            t_eval=t,
            args=(window,),
            rtol=1e-9,
            atol=1e-11,
            max_step=0.25 / rate,
        )
        return sol.y

    free = run(None)
    window = 0.5 * float(np.max(np.abs(free)))
    y = tip(run(window))
    w = y + 0.005 * np.ptp(y) * rng.normal(size=n)
    np.savetxt(path, np.c_[t, u, w], delimiter=",", header="t,v_in,w\ns,V,V", comments="")
    return window


def test_an_electrolytes_window_on_every_compartment_is_named_window_vc_not_a_drive_saturation(tmp_path):
    """A window on every double-layer voltage looks from outside like a drive that stops at its levels:
    searched beside the drive's saturation, the window is named, with its half-width. 20 s and two effects keep the network's 46 states stepped per sample affordable here;
    `experiments/inside_effects.py --cases rc_window` diagnoses 60 s with every built-in beside it."""
    window = _rc_behind_a_window(tmp_path / "strip.csv")
    run = h.run_hybrid(
        tmp_path,
        "diagnose",
        "strip.csv",
        "--physics",
        "rc:zoh",
        "--effects",
        "drive_saturation,window_vc",
        "--out",
        "d",
        "--quiet",
    )
    assert run.returncode == 0, run.stderr[-2000:]
    report = json.loads((tmp_path / "d" / "report.json").read_text())
    assert [c["name"] for c in report["causes"]] == ["window_vc"], report["verdict"]
    half = report["parameters"]["vc_window"]
    assert half["unit"] == "V" and half["value"] == pytest.approx(window, rel=0.05)
    assert report["unexplained"] is None
