"""hybrid.sensitivity against independent references.

- local sensitivities against central finite differences of the simulation;
- the covariance after a fit against `scipy.optimize.curve_fit` on the same
  data, with a model written independently (tests/helpers.py Eqs 4–13 +
  scipy bilinear_zpk + sosfilt), finite-difference Jacobian;
- the SVD finding the ξρ/ξh null direction by itself;
- Sobol indices against the closed form of an additive model;
- the frequency sensitivities against finite differences of Eq 14;
- the `hybrid sensitivity` command (JSON content, exit 2 on bad input).
"""

import json
from typing import ClassVar

import helpers as h
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.optimize
import scipy.signal

from hybrid import (
    AbstractSimulation,
    InputError,
    LinearReadout,
    Model,
    RCNetwork,
    Real,
    Recording,
    UnitInterval,
    encode,
    make_drive,
    sensitivity as S,
)
from hybrid.cli import main

DT = 1.0 / h.RATE


@pytest.fixture(scope="module")
def prbs():
    return make_drive("prbs", 60.0, seed=0, min_hold=0.2, max_hold=4.0).v


@pytest.fixture(scope="module")
def rc_sensitivity(prbs):
    return S.local_sensitivities(RCNetwork(n_stages=45), prbs, DT)


# --------------------------------------------------------------------------- local sensitivities
def test_sensitivities_match_central_differences(rc_sensitivity, prbs):
    net = RCNetwork(n_stages=45)
    sens = rc_sensitivity
    assert sens.names == ("xi_rho", "xi_h", "alpha_E", "alpha_I", "alpha_C", "C_clamp")
    assert sens.jacobian.shape == (prbs.size, 6)
    for j, name in enumerate(sens.names):
        value = sens.values[name]
        step = 1e-6 * value
        hi = np.asarray(net.replace(**{name: value + step}).simulate(prbs, DT))
        lo = np.asarray(net.replace(**{name: value - step}).simulate(prbs, DT))
        fd = (hi - lo) / (2 * step)
        # forward mode vs central differences: ≤ 1e-6 of max |∂V_o/∂θ| (FD error ~1e-8 measured)
        assert h.relative_error(sens.jacobian[:, j], fd) < 1e-6, name
    # normalised = θ ∂y/∂θ / rms(y)
    rms = np.sqrt(np.mean(sens.output**2))
    np.testing.assert_allclose(sens.normalised()[:, 0], sens.jacobian[:, 0] * sens.values["xi_rho"] / rms)


def test_model_sensitivities_include_readout_parameters(prbs):
    model = Model(RCNetwork(n_stages=5), LinearReadout(2.0, 0.5), "physics")
    sens = S.local_sensitivities(model, prbs, DT, frozen={"xi_h"})
    assert sens.names == ("xi_rho", "alpha_E", "alpha_I", "alpha_C", "C_clamp", "gain", "offset")
    v_o = np.asarray(RCNetwork(n_stages=5).simulate(prbs, DT))
    # ∂ŵ/∂gain = V_o, ∂ŵ/∂offset = 1 (1e-12)
    np.testing.assert_allclose(sens.jacobian[:, 5], v_o, rtol=0, atol=1e-12)
    np.testing.assert_allclose(sens.jacobian[:, 6], 1.0, rtol=1e-12)
    assert sens.output_unit == "mm"


# --------------------------------------------------------------------------- identifiability
def test_svd_names_the_xi_rho_xi_h_null_direction(rc_sensitivity):
    ident = rc_sensitivity.identifiability()
    ratio = ident.singular_values / ident.singular_values[0]
    # exactly one null direction (float64 rounding: measured 3.5e-18), the rest ≥ 1e-5
    assert ratio[-1] < 1e-12
    assert ratio[-2] > 1e-5
    assert len(ident.null_directions) == 1
    null = ident.null_directions[0]
    # R_I ∝ ξρ/ξh: scaling both by the same factor leaves V_o unchanged, so the
    # null direction in (log ξρ, log ξh) is (1, 1)/√2; the identifiable
    # combination, log(ξρ/ξh), is orthogonal to it.
    assert set(null) == {"xi_rho", "xi_h"}
    assert null["xi_rho"] == pytest.approx(2**-0.5, abs=1e-8)
    assert null["xi_h"] == pytest.approx(2**-0.5, abs=1e-8)
    pairs = {frozenset(p[:2]): p[2] for p in ident.collinear_pairs}
    assert pairs[frozenset({"xi_rho", "xi_h"})] == pytest.approx(-1.0, abs=1e-12)
    # the near-collinear pairs the issue measured, flagged at |cos| ≥ 0.99
    assert abs(pairs[frozenset({"xi_rho", "alpha_I"})]) > 0.99
    assert abs(pairs[frozenset({"alpha_C", "C_clamp"})]) > 0.99
    assert frozenset({"alpha_E", "C_clamp"}) not in pairs


def test_identifiability_of_a_constructed_matrix():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(2, 200))
    matrix = np.stack([a, b, a - 2 * b, a + 1e-4 * rng.normal(size=200)], axis=1)
    ident = S.identifiability(matrix, ["p", "q", "r", "s"])
    # null: r = p − 2q  →  direction (1, −2, −1, 0)/√6
    (null,) = ident.null_directions
    np.testing.assert_allclose([null["p"], null["q"], null["r"]], np.array([1, -2, -1]) / 6**0.5, atol=1e-8)
    # near null: s ≈ p
    assert len(ident.near_null_directions) == 1
    assert ident.collinear_pairs[0][:2] == ("p", "s")
    with pytest.raises(InputError):
        S.identifiability(matrix, ["p", "q"])


# --------------------------------------------------------------------------- covariance vs curve_fit
TRUE = RCNetwork(xi_rho=6.0, xi_h=1.0, alpha_E=0.3, alpha_I=0.6, alpha_C=0.4, C_clamp=0.02, n_stages=10)
FREE = ("xi_rho", "alpha_C", "C_clamp", "gain", "offset")
FROZEN = {"xi_h", "alpha_E", "alpha_I"}


@pytest.fixture(scope="module")
def curve_fit_reference():
    recording = h.planted_physics_recording(TRUE, 1.7, 0.3, 0.02, seed=3)
    (a, b), _, _ = h.split_bounds(recording.n)
    v = recording.v_in

    def model(_, xi_rho, alpha_C, C_clamp, gain, offset):  # numpy + scipy only
        G, Z, P = h.stage_zpk_np(xi_rho, 1.0, 0.3, 0.6, alpha_C, C_clamp, 10)
        sos = [
            scipy.signal.zpk2sos(*scipy.signal.bilinear_zpk([-z], [-p], g, fs=h.RATE))[0]
            for g, z, p in zip(G, Z, P)
        ]
        return gain * scipy.signal.sosfilt(np.array(sos), v)[a:b] + offset

    popt, pcov = scipy.optimize.curve_fit(
        model,
        None,
        recording.w[a:b],
        p0=[5.0, 0.5, 0.03, 1.5, 0.2],
        method="trf",
        jac="3-point",
        x_scale="jac",
        ftol=1e-15,
        xtol=1e-15,
        gtol=1e-15,
    )
    return recording, popt, pcov


def test_covariance_matches_curve_fit(curve_fit_reference):
    recording, popt, pcov = curve_fit_reference
    fitted = Model(
        TRUE.replace(xi_rho=popt[0], alpha_C=popt[1], C_clamp=popt[2]),
        LinearReadout(popt[3], popt[4]),
        "physics",
    )
    cov = S.parameter_covariance(fitted, recording, frozen=FROZEN)
    assert set(cov.names) == set(FREE)
    idx = [cov.names.index(n) for n in FREE]
    ours = cov.matrix[np.ix_(idx, idx)]
    se_ref = np.sqrt(np.diag(pcov))
    # standard errors in physical units (Positive, UnitInterval and Real parameters,
    # mapped by the delta method) within 1e-4 relative of curve_fit's (measured 1.1e-6;
    # curve_fit's 3-point finite-difference Jacobian limits the agreement)
    np.testing.assert_allclose(np.sqrt(np.diag(ours)), se_ref, rtol=1e-4)
    np.testing.assert_allclose(ours / np.outer(se_ref, se_ref), pcov / np.outer(se_ref, se_ref), atol=1e-4)
    assert [cov.std_errors[n] for n in FREE] == pytest.approx(list(se_ref), rel=1e-4)
    # degrees of freedom and s² as curve_fit: m − 5, ‖r‖²/(m − 5)
    assert cov.dof == cov.n_residuals - 5
    # the Fisher information is the inverse covariance here (all identifiable)
    np.testing.assert_allclose(cov.fisher @ cov.matrix, np.eye(5), atol=1e-8)
    # and the planted truth lies within 3 standard errors of the optimum
    truth = np.array([6.0, 0.4, 0.02, 1.7, 0.3])
    assert np.all(np.abs(popt - truth) < 3 * se_ref)


def test_to_optimum_is_the_step_to_curve_fit_s_optimum(curve_fit_reference):
    """`Covariance.to_optimum`: ~0 at curve_fit's optimum; from a point a few standard errors off,
    the way back to it (damped Gauss–Newton: within 0.01 standard errors)."""
    recording, popt, pcov = curve_fit_reference
    se = np.sqrt(np.diag(pcov))

    def model_at(values):
        xi_rho, alpha_C, C_clamp, gain, offset = values
        return Model(
            TRUE.replace(xi_rho=xi_rho, alpha_C=alpha_C, C_clamp=C_clamp),
            LinearReadout(gain, offset),
            "physics",
        )

    at = S.parameter_covariance(model_at(popt), recording, frozen=FROZEN)
    assert all(abs(at.to_optimum[n]) < 1e-3 * s for n, s in zip(FREE, se))
    off = popt + np.array([2.0, -3.0, 1.5, 2.5, -2.0]) * se
    away = S.parameter_covariance(model_at(off), recording, frozen=FROZEN)
    step = np.array([away.to_optimum[n] for n in FREE])
    np.testing.assert_allclose(step / se, (popt - off) / se, atol=0.01)
    assert away.to_dict()["to_optimum"]["gain"] == pytest.approx(step[FREE.index("gain")])


def test_standard_errors_of_a_fit_use_its_frozen_set_split_and_blocks(curve_fit_reference):
    """standard_errors(result) is parameter_covariance with the settings the fit recorded."""
    from hybrid import LevenbergMarquardt, fit, make_model

    recording = curve_fit_reference[0]
    split, order = (0.6, 0.1, 0.3), ("train", "validation", "test")
    result = fit(
        make_model("physics", simulation=TRUE),
        [recording],
        solver=LevenbergMarquardt(max_steps=5),
        frozen=FROZEN,
        split=split,
        split_order=order,
        blocks=3,
        progress=False,
    )
    ours = S.standard_errors(result, recording).matrix
    reference = S.parameter_covariance(
        result.model, recording, frozen=FROZEN, split=split, split_order=order, blocks=3
    ).matrix
    np.testing.assert_array_equal(ours, reference)
    # the blocks matter: the contiguous split's covariance is another matrix
    contiguous = S.parameter_covariance(
        result.model, recording, frozen=FROZEN, split=split, split_order=order
    ).matrix
    assert not np.allclose(ours, contiguous, rtol=1e-3)


def test_unidentifiable_parameters_get_infinite_variance(curve_fit_reference):
    recording, popt, _ = curve_fit_reference
    fitted = Model(
        TRUE.replace(xi_rho=popt[0], alpha_C=popt[1], C_clamp=popt[2]),
        LinearReadout(popt[3], popt[4]),
        "physics",
    )
    frozen_xi = S.parameter_covariance(fitted, recording, frozen=FROZEN)
    free_xi = S.parameter_covariance(fitted, recording, frozen=FROZEN - {"xi_h"})
    assert set(free_xi.unidentifiable) == {"xi_rho", "xi_h"}
    assert free_xi.std_errors["xi_rho"] == np.inf and free_xi.std_errors["xi_h"] == np.inf
    # the other parameters are orthogonal to the null direction, and J's rank (the
    # degrees of freedom used) is unchanged: the same standard errors (1e-6)
    assert free_xi.dof == frozen_xi.dof
    for name in ("alpha_C", "C_clamp", "gain", "offset"):
        assert free_xi.std_errors[name] == pytest.approx(frozen_xi.std_errors[name], rel=1e-6), name
    # the Fisher information stays finite and is singular along (1/ξρ, 1/ξh)·(ξρ, ξh) scaling
    i, j = free_xi.names.index("xi_rho"), free_xi.names.index("xi_h")
    direction = np.zeros(len(free_xi.names))
    direction[i], direction[j] = free_xi.values["xi_rho"], free_xi.values["xi_h"]
    F = free_xi.fisher
    assert np.all(np.isfinite(F))
    assert direction @ F @ direction < 1e-8 * np.max(np.abs(np.diag(F))) * direction @ direction


class _Shared(AbstractSimulation):
    """y = (g + s)·v + c·v², s a share in (0, 1): g and s trade off exactly wherever s is free."""

    raw: dict
    constraints: ClassVar = {"g": Real(), "s": UnitInterval(), "c": Real()}
    units: ClassVar = {"g": "1", "s": "1", "c": "1"}

    def __init__(self, s=0.5):
        self.raw = encode({"g": 1.2, "s": s, "c": 0.3}, self.constraints, "Shared")

    def simulate(self, v_in, dt):
        p = self.parameters()
        return (p["g"] + p["s"]) * v_in + p["c"] * v_in**2


def test_a_parameter_at_a_bound_is_held_there_not_spread_over_what_trades_off_with_it():
    """A share the fit pushed to its bound (0.99995 of (0, 1)) is held at it: the others' errors are those
    with it frozen (1e-9), where left free its exact trade-off with g made g unidentifiable too (a
    probe's frame lag at 1 sample, beside a delay: the friction and the inertia beside them lost theirs)."""
    v = np.asarray(make_drive("prbs", 30.0, seed=2).v)
    w = 2.2 * v + 0.3 * v**2 + 0.01 * np.random.default_rng(0).normal(size=v.size)
    recording = Recording.from_arrays(v_in=v, w=w, rate=h.RATE)
    fixed = {"gain", "offset"}
    at_bound = Model(_Shared(s=0.99995), LinearReadout(1.0, 0.0), "physics")
    held = S.parameter_covariance(at_bound, recording, frozen=fixed)
    frozen = S.parameter_covariance(at_bound, recording, frozen=fixed | {"s"})
    assert held.unidentifiable == ("s",) and held.std_errors["s"] == np.inf
    for name in ("g", "c"):
        assert np.isfinite(held.std_errors[name]), name
        assert held.std_errors[name] == pytest.approx(frozen.std_errors[name], rel=1e-9), name
    inside = S.parameter_covariance(
        Model(_Shared(s=0.5), LinearReadout(1.0, 0.0), "physics"), recording, frozen=fixed
    )
    assert set(inside.unidentifiable) == {"g", "s"}  # off the bound, the trade-off stands


def test_covariance_rejects_bad_input(curve_fit_reference):
    recording, _, _ = curve_fit_reference
    model = Model(TRUE, LinearReadout(), "physics")
    with pytest.raises(InputError):
        S.parameter_covariance(model, [])
    with pytest.raises(InputError):
        S.parameter_covariance(TRUE, recording)
    with pytest.raises(InputError):
        S.parameter_covariance(model, recording, noise_std=-1.0)
    with pytest.raises(InputError):
        S.local_sensitivities(model, np.array([1.0, np.nan, 2.0]), DT)
    with pytest.raises(InputError):
        S.local_sensitivities("not a model", np.ones(10), DT)


# --------------------------------------------------------------------------- Sobol
class _Additive(AbstractSimulation):
    """y = a·v + 2b·v with a, b real: first-order = total Sobol indices 1/5 and 4/5."""

    raw: dict
    constraints: ClassVar = {"a": Real(), "b": Real()}
    units: ClassVar = {"a": "1", "b": "1"}

    def __init__(self):
        self.raw = encode({"a": 1.0, "b": 1.0}, self.constraints, "Additive")

    def simulate(self, v_in, dt):
        p = self.parameters()
        return p["a"] * v_in + 2.0 * p["b"] * v_in


def test_sobol_indices_of_an_additive_model():
    v = jnp.linspace(-1.0, 1.0, 50)
    sobol = S.sobol_indices(_Additive(), v, DT, n_base=4096, spread=0.5, seed=1)
    # Var(a) = Var(b) (same uniform): S_a = 1/5, S_b = 4/5; Monte Carlo error ~1/√N
    assert sobol.first_order["a"] == pytest.approx(0.2, abs=0.04)
    assert sobol.first_order["b"] == pytest.approx(0.8, abs=0.04)
    assert sobol.total["a"] == pytest.approx(0.2, abs=0.04)
    assert sobol.total["b"] == pytest.approx(0.8, abs=0.04)
    assert sobol.n_evaluations == 4096 * 4


def test_sobol_indices_that_contradict_each_other_are_said_to_be_noisy_and_the_md_shows_them():
    """A probe's `--sobol 64` gave a total index below its first-order one (0.087 < 0.105), which exact
    indices never are, without a word, and sensitivity.md did not show the indices at all."""
    from hybrid.sensitivity._study import _markdown, simulation_study, sobol_warnings

    noisy = {"n_base": 64, "first_order": {"tau": 0.105, "k": 0.5}, "total": {"tau": 0.087, "k": 0.55}}
    (said,) = sobol_warnings(noisy)
    assert (
        "from 64 base samples are noisy: tau's total index 0.087 is below its first-order index 0.105" in said
    )
    assert sobol_warnings({**noisy, "total": {"tau": 0.1, "k": 0.55}}) == []  # within the slack: not said
    v = jnp.linspace(-1.0, 1.0, 50)
    result, _ = simulation_study(_Additive(), v, DT, sobol=256, seed=1)
    text = _markdown(result)
    assert "| parameter | S1 | ST |" in text and "Sobol indices (256 base samples" in text
    first = result["sobol"]["first_order"]["b"]
    assert f"| b | {first:.3g} |" in text


# --------------------------------------------------------------------------- frequency
def test_frequency_sensitivity_matches_finite_differences():
    net = RCNetwork(n_stages=10)
    f = np.logspace(-2, 1, 7)
    out = S.frequency_sensitivity(net, f)
    j = out["names"].index("C_clamp")
    c = 0.05
    eps = 1e-6
    hi = np.abs(np.asarray(net.replace(C_clamp=c * (1 + eps)).frequency_response(f)))
    lo = np.abs(np.asarray(net.replace(C_clamp=c * (1 - eps)).frequency_response(f)))
    fd = (np.log(hi) - np.log(lo)) / (np.log1p(eps) - np.log1p(-eps))
    np.testing.assert_allclose(out["magnitude"][:, j], fd, rtol=1e-6, atol=1e-9)


# --------------------------------------------------------------------------- CLI
def test_cli_sensitivity_writes_the_null_direction(tmp_path, capsys):
    out = tmp_path / "sens"
    assert main(["sensitivity", "--out", str(out), "--duration", "40", "--stages", "20"]) == 0
    result = json.loads((out / "sensitivity.json").read_text())
    assert len(result["singular_values"]) == 6
    assert result["null_directions"] == [
        {"xi_rho": pytest.approx(2**-0.5, abs=1e-8), "xi_h": pytest.approx(2**-0.5, abs=1e-8)}
    ]
    assert set(result["by_drive"]) == {"prbs", "sine", "chirp", "pulse"}
    for name in (
        "sensitivity_time.png",
        "sensitivity_frequency.png",
        "sensitivity_drives.png",
        "singular_values.png",
        "sensitivity.md",
    ):
        assert (out / name).stat().st_size > 1000
    assert "null direction" in capsys.readouterr().out


@pytest.mark.parametrize(
    "argv",
    [
        ["sensitivity"],  # --out missing
        ["sensitivity", "--out", "X", "--param", "xi_rho=-1"],
        ["sensitivity", "--out", "X", "--sobol", "-2"],
        ["sensitivity", "--out", "X", "--noise", "0"],
        ["sensitivity", "missing.csv", "--out", "X"],
    ],
)
def test_cli_sensitivity_bad_input_exits_2(argv, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("hybrid: error:") and err.count("\n") == 1
    assert not (tmp_path / "X").exists()


def test_the_errors_with_the_simulation_fixed_do_not_depend_on_the_parameters_scales():
    """`inverse_diagonal` of a Fisher matrix whose parameters are in units 1e9 apart (a drive in mV, an
    output in m): numpy's inverse of the same matrix, where pinv of the raw matrix cut a direction."""
    from hybrid.discovery._evidence import inverse_diagonal

    rng = np.random.default_rng(0)
    a = rng.normal(size=(40, 3))
    core = a.T @ a  # well conditioned at unit scale
    scales = np.array([1e-6, 1e3, 1.0])
    fisher = core / np.outer(scales, scales)
    exact = np.diag(np.linalg.inv(fisher))
    np.testing.assert_allclose(inverse_diagonal(fisher), exact, rtol=1e-9)
    raw = np.diag(np.linalg.pinv(fisher, rcond=1e-12, hermitian=True))
    assert not np.allclose(raw, exact, rtol=1e-3)  # what the raw matrix's pseudo-inverse gave
    padded = np.zeros((4, 4))
    padded[:3, :3] = fisher
    assert inverse_diagonal(padded)[3] == 0.0  # a row of zeros: no information, no variance read


def test_a_derivative_that_diverges_is_said_not_read_as_an_output_that_does_not_move():
    """A probe's mass with a Coulomb friction sticking below a small speed: the friction's linearised
    stiffness, ω²F/v_s, was too fast for the RK4 step, the sensitivities grew to 1e35 while the output
    stayed finite, and every parameter read "the output does not change with it, or it trades off
    exactly". Here a 1 Hz oscillator (30 Hz, 4 RK4 substeps) with a 1.2 V friction: sticking below
    0.5 V/s the covariance is read; below 0.01 V/s (ω²F/v_s·h ≈ 40) it is said to have diverged."""
    import dataclasses

    import hybrid
    from hybrid.discovery._diagnosis import ParameterUncertainty
    from hybrid.discovery._evidence import DIVERGED, diverged_warnings, not_pinned

    oscillator = hybrid.resolve_physics("examples/oscillator.py:MassSpringDamper").replace(
        frequency=1.0, zeta=0.2
    )
    u = h.step_drive(1200, seed=1, amplitude=2.0)
    rng = np.random.default_rng(0)
    covariances = {}
    for stick in (0.5, 0.01):
        stack = hybrid.extend(
            oscillator, hybrid.Friction("velocity"), velocity_friction=1.2, velocity_stick_speed=stick
        )
        model = hybrid.make_model("physics", simulation=stack)
        y = np.asarray(model.predict(u, 1 / 30.0))
        assert np.all(np.isfinite(y))  # the output itself stays finite
        recording = Recording(np.arange(u.size) / 30.0, u, y + 0.01 * rng.standard_normal(u.size))
        covariances[stick] = S.parameter_covariance(model, recording), model
    sane, _ = covariances[0.5]
    assert not sane.diverged and all(np.isfinite(list(sane.std_errors.values())))
    wild, model = covariances[0.01]
    assert wild.diverged and all(np.isinf(list(wild.std_errors.values())))
    assert all(np.isnan(list(wild.to_optimum.values())))  # no Gauss–Newton step follows such a J
    unsure = {
        name: ParameterUncertainty(std_error=float("inf"), unit="", inflation=1.0, diverged=True)
        for name in wild.names
    }
    assert set(not_pinned(unsure, model, []).values()) == {DIVERGED}
    (warned,) = diverged_warnings(unsure)
    assert (
        warned.startswith("the model's derivative diverges at the fitted values") and "shorter step" in warned
    )
    assert diverged_warnings({k: dataclasses.replace(u, diverged=False) for k, u in unsure.items()}) == []
