"""The baseline's starting points: a screened design lands on the right plateau of the RC network's loss."""

import numpy as np
import pytest

from hybrid import RCNetwork
from hybrid.core._models import Model
from hybrid.core._problem import Problem, series_from_recording
from hybrid.core._readout import LinearReadout
from hybrid.core._screen import screened_starts, start_design
from hybrid.discovery._diagnosis import SPLIT_ORDER, DiagnoseSettings
from hybrid.ipmc._synthetic import SyntheticStrip, discrepancy_drive, synthetic_recording

#: A slow strip (tip capacitance 8× the clamp's): from 15 of the 16 fixed Sobol starts used
#: before screening, LM ended with a validation loss about 400× that of the true parameters.
SLOW = SyntheticStrip(
    xi_rho=2.5401,
    xi_h=1.1330,
    alpha_E=0.3618,
    alpha_I=0.8455,
    alpha_C=0.1251,
    C_clamp=0.3165,
    gain_mm_per_v=1.968,
    offset_mm=-0.076,
)


def _train_mse(problem, simulation, values):
    """Training MSE with the least-squares gain and offset, computed here with numpy."""
    series = problem.series[0]
    signal = np.asarray(simulation.replace(**values).simulate(series.v_in, series.dt))
    s = np.concatenate([signal[a:b] for a, b in series.segments_of("train")])
    w = np.asarray(problem.target("train"))
    design = np.stack([s, np.ones_like(s)], axis=1)
    coef, *_ = np.linalg.lstsq(design, w, rcond=None)
    return float(np.mean((w - design @ coef) ** 2))


def test_screened_starts_reach_the_loss_of_the_true_parameters():
    settings = DiagnoseSettings()
    recording = synthetic_recording(
        discrepancy_drive(60.0, 30.0, seed=5), SLOW, "none", {}, noise_fraction=0.01, seed=5
    )
    simulation = RCNetwork(method="zoh")
    series = [series_from_recording(recording, settings.split, SPLIT_ORDER, settings.blocks)]
    problem = Problem(
        Model(simulation, LinearReadout(), "physics"), series, frozenset(settings.frozen_for(simulation))
    )
    truth = {
        "C_clamp": SLOW.C_clamp,
        "xi_rho": SLOW.xi_rho / SLOW.xi_h,
        "alpha_E": SLOW.alpha_E,
        "alpha_I": SLOW.alpha_I,
        "alpha_C": SLOW.alpha_C,
    }
    floor = _train_mse(problem, simulation, truth)

    starts = screened_starts(problem, simulation, 16, 512, settings.frozen_for(simulation))
    assert len(starts) == 16
    losses = [_train_mse(problem, simulation, s) for s in starts]
    assert losses == sorted(losses) or np.allclose(losses, sorted(losses), rtol=1e-6)
    assert losses[0] <= 1.5 * floor  # on the true plateau before any LM step
    # The design's first point, the simulation as given, is not: screening is what finds the plateau.
    first = start_design(simulation, 1, settings.frozen_for(simulation))[0]
    assert first == {k: float(v) for k, v in simulation.parameters().items() if k != "xi_h"}
    assert _train_mse(problem, simulation, first) >= 5 * floor
    assert len(start_design(simulation, 512)) == 512


def test_loop_screen_recovers_a_known_bouc_wen_loop():
    """`loop_screen` reads height and initial state off a least-squares solve: exact on a loop from a neutral start."""
    import jax.numpy as jnp

    from hybrid.core._screen import design_raws
    from hybrid.data._recording import Recording
    from hybrid.discovery._hysteresis import bouc_wen_state
    from hybrid.discovery._starts import loop_screen

    settings = DiagnoseSettings()
    drive = discrepancy_drive(60.0, 30.0, seed=1)
    simulation = RCNetwork(method="zoh")
    design = start_design(simulation, 3, settings.frozen_for(simulation))
    point = design[2]
    s = np.asarray(simulation.replace(**point).simulate(jnp.asarray(drive.v), 1 / 30.0))
    k, height = 10.0 / np.ptp(s), 0.15 * np.ptp(s)
    _, raws = design_raws(simulation, [point, design[1]])

    def screen(initial):
        w = 2.0 * (s + height * np.asarray(bouc_wen_state(jnp.asarray(s), k, initial))) - 0.3
        recording = Recording(t=np.asarray(drive.t), v_in=np.asarray(drive.v), w=w)
        series = [series_from_recording(recording, settings.split, SPLIT_ORDER, settings.blocks)]
        problem = Problem(
            Model(simulation, LinearReadout(), "physics"), series, frozenset(settings.frozen_for(simulation))
        )
        return np.var(w), [np.asarray(x) for x in loop_screen(problem, simulation, raws, (10.0, 40.0))]

    var, (losses, ks, heights, initials) = screen(0.0)
    assert losses[0, 0] < 1e-20 * var  # the true point and rate fit exactly
    assert ks[0, 0] == pytest.approx(k, rel=1e-9)
    assert heights[0, 0] == pytest.approx(height, rel=1e-6)
    assert abs(initials[0, 0]) < 1e-6
    assert losses[0, 1] > 1e-6 * var and losses[1, 0] > 1e-6 * var  # wrong rate, wrong network
    # Away from the neutral start the state is nonlinear in u0: the screen's first-order
    # estimate of it is close, not exact (a start for LM).
    var, (losses, ks, heights, initials) = screen(-0.4)
    assert initials[0, 0] == pytest.approx(-0.4, abs=0.05)
    assert heights[0, 0] == pytest.approx(height, rel=0.02)
    assert losses[0, 0] < 1e-3 * var


def test_resonance_starts_find_a_known_mode_and_network():
    """A mode on the screen's grid, after a design point's network, is found at that point, f and ζ.

    The recording is made with scipy (`lsim`: the mode's state space, input linear
    between samples), independently of `hybrid.discovery._effects.Resonance`.
    """
    import jax.numpy as jnp
    import scipy.signal

    from hybrid.core._screen import N_SCREEN, design_raws
    from hybrid.data._recording import Recording
    from hybrid.discovery._starts import (
        MODE_DAMPINGS,
        N_JOINT_SCREEN,
        mode_frequencies,
        mode_screen,
        resonance_starts,
    )

    settings = DiagnoseSettings()
    rate = 30.0
    drive = discrepancy_drive(60.0, rate, seed=2)
    simulation = RCNetwork(method="zoh")
    design = start_design(simulation, N_SCREEN, settings.frozen_for(simulation))[:N_JOINT_SCREEN]
    point = design[37]
    s = np.asarray(simulation.replace(**point).simulate(jnp.asarray(drive.v), 1 / rate))
    f, zeta = float(mode_frequencies(rate)[9]), MODE_DAMPINGS[1]
    omega = 2 * np.pi * f
    mode = scipy.signal.StateSpace(
        [[0.0, 1.0], [-(omega**2), -2 * zeta * omega]], [[0.0], [omega**2]], [[1.0, 0.0]], [[0.0]]
    )
    t = np.arange(len(s)) / rate
    _, y, _ = scipy.signal.lsim(mode, s, t, X0=[s[0], 0.0])
    w = 1.7 * y + 0.2
    recording = Recording(t=t, v_in=np.asarray(drive.v), w=w)
    series = [series_from_recording(recording, settings.split, SPLIT_ORDER, settings.blocks)]
    problem = Problem(
        Model(simulation, LinearReadout(), "physics"), series, frozenset(settings.frozen_for(simulation))
    )

    _, raws = design_raws(simulation, [point, design[5]])
    losses = np.asarray(
        mode_screen(problem, simulation, raws, np.array([f, 1.3 * f, f]), np.array([zeta, zeta, 0.3]))
    )
    assert losses[0, 0] < 1e-12 * np.var(w)  # exact up to lsim's quadrature
    assert min(losses[0, 1], losses[0, 2], losses[1, 0]) > 1e-4 * np.var(w)  # wrong f, wrong ζ, wrong network
    # Where the fit is not exact, each loss is the least-squares residual of that network's output
    # through that mode (scipy's lsim) with a gain and an offset (numpy's lstsq) on the training part:
    # the screen's summed normal equations against a direct solve.
    (segments,) = [s.segments_of("train") for s in problem.series]
    train_w = np.concatenate([w[a:b] for a, b in segments])
    for row, other in ((0, point), (1, design[5])):
        x = np.asarray(simulation.replace(**other).simulate(jnp.asarray(drive.v), 1 / rate))
        for column, (fj, zj) in enumerate(((f, zeta), (1.3 * f, zeta), (f, 0.3))):
            om = 2 * np.pi * fj
            sys_j = scipy.signal.StateSpace(
                [[0.0, 1.0], [-(om**2), -2 * zj * om]], [[0.0], [om**2]], [[1.0, 0.0]], [[0.0]]
            )
            _, yj, _ = scipy.signal.lsim(sys_j, x, t, X0=[x[0], 0.0])
            design_j = np.stack(
                [np.concatenate([yj[a:b] for a, b in segments]), np.ones(len(train_w))], axis=1
            )
            coef, *_ = np.linalg.lstsq(design_j, train_w, rcond=None)
            reference = np.mean((train_w - design_j @ coef) ** 2)
            if reference > 1e-6 * np.var(w):
                assert losses[row, column] == pytest.approx(reference, rel=1e-6), (row, column)

    (start,) = resonance_starts(problem, simulation, rate, n_starts=1, frozen=settings.frozen_for(simulation))
    assert start["resonance_frequency_hz"] == pytest.approx(f) and start["resonance_damping"] == zeta
    assert all(start[k] == pytest.approx(v) for k, v in point.items())


def test_the_baselines_starts_do_not_depend_on_the_effects_searched(monkeypatch):
    """One effect or every built-in: the same `N_LANES` baseline starts, the lanes padded beyond them.

    The diagnosis is stopped at its first LM call (the baseline's lanes), whose
    starts are compared: a larger effect set runs more lanes per stage, and
    those must not change the baseline its candidates are measured against.
    """
    import jax.numpy as jnp

    import hybrid
    from hybrid.discovery import _diagnose
    from hybrid.discovery._search import N_LANES

    class Stop(Exception):
        pass

    seen = []

    def first_lanes(problem, actives, tangents, thetas, settings, patience):
        thetas = np.asarray(thetas)
        finite = np.all(np.isfinite(thetas), axis=1)
        _, readout = problem.split_theta(jnp.asarray(thetas[finite][0]))
        stack = problem.model(jnp.asarray(thetas[finite][0])).simulation
        seen.append((thetas.shape[0], int(finite.sum()), stack.inner.parameters(), np.asarray(readout)))
        raise Stop

    monkeypatch.setattr(_diagnose, "fit_lanes", first_lanes)
    recording = synthetic_recording(
        discrepancy_drive(20.0, 30.0, seed=3), SLOW, "none", {}, noise_fraction=0.01, seed=3
    )
    for effects in (["drift"], None):
        with pytest.raises(Stop):
            hybrid.diagnose(recording, simulation=hybrid.LTI(1), effects=effects)
    (lanes_one, starts_one, inner_one, readout_one), (lanes_all, starts_all, inner_all, readout_all) = seen
    assert lanes_one == N_LANES < lanes_all  # the built-ins' first step has more lanes than one effect's
    assert starts_one == starts_all == N_LANES
    assert inner_one.keys() == inner_all.keys()
    for name in inner_one:
        np.testing.assert_array_equal(np.asarray(inner_one[name]), np.asarray(inner_all[name]))
    np.testing.assert_array_equal(readout_one, readout_all)


def _mode(rate: float = 30.0, n: int = 3600, f: float = 1.5, zeta: float = 0.3):
    """A 1.5 Hz mode, ζ = 0.3, gain 2, under a multilevel PRBS held 3–15 samples: scipy's exact ZOH
    response (`cont2discrete`), with 0.01 noise."""
    import scipy.signal

    from hybrid import Recording

    rng = np.random.default_rng(0)
    v, k = np.zeros(n), 0
    while k < n:
        hold = int(rng.integers(3, 16))
        v[k : k + hold] = rng.choice([-2.0, -1.0, 0.0, 1.0, 2.0])
        k += hold
    w0 = 2 * np.pi * f
    a = np.array([[0.0, 1.0], [-(w0**2), -2 * zeta * w0]])
    b, c = np.array([[0.0], [2 * w0**2]]), np.array([[1.0, 0.0]])
    system = scipy.signal.cont2discrete((a, b, c, np.zeros((1, 1))), 1 / rate, method="zoh")
    y = scipy.signal.dlsim((*system[:4], 1 / rate), v)[1][:, 0]
    return Recording.from_arrays(v_in=v, w=y + 0.01 * rng.normal(size=n), rate=rate)


def test_no_start_is_taken_above_nyquist():
    """Sampled at 30 Hz, a mode above 15 Hz is an alias of one below: `in_band` refuses those points of
    the design (the screens set their losses to inf), the simulation as given always passes."""
    from hybrid import LTI
    from hybrid.core._screen import in_band, least_finite

    design = start_design(LTI(2), 512)
    ok = in_band(design, LTI(2).units, 30.0)
    assert np.array_equal(ok[1:], np.array([p["f_1"] <= 0.9 * 15.0 for p in design[1:]]))
    assert 100 < np.count_nonzero(~ok) < 400 and ok[0]  # the typical range reaches 1 kHz
    # the least finite losses, fewer where fewer are finite; inf and NaN never chosen
    losses = np.array([3.0, np.inf, 1.0, np.nan, 2.0])
    assert least_finite(losses, 2).tolist() == [2, 4] and least_finite(losses, 9).tolist() == [2, 4, 0]


def test_diagnose_fits_a_sampled_mode_below_nyquist_not_its_alias():
    """`lti:2` on a 1.5 Hz mode sampled at 30 Hz: the baseline is the mode, not an 88.6 Hz alias.

    With the design spread up to 1 kHz, the resonance's joint screen started a lane at an alias
    that the ZOH samples alike (88.57 Hz, ζ = 0.005: the same discrete poles), the baseline refitted
    from that lane's end point kept it, and the report's table read so.
    """
    from hybrid import diagnose, resolve_physics

    recording = _mode()
    found = diagnose(recording, simulation=resolve_physics("lti:2", [recording]), effects=["resonance"])
    assert found.cause == "none"
    fitted = {k: v["value"] for k, v in found.to_dict()["parameters"].items()}  # the baseline's: no cause
    assert fitted["f_1"] == pytest.approx(1.5, rel=0.01) and fitted["zeta_1"] == pytest.approx(0.3, rel=0.03)
