"""A fit does not depend on the units of w or v_in (issue 20, "never answer wrong in silence").

Before, the same recording gave ξρ = 0.027 with w in mm, 2.8e7 with w in µm, and with w × 1e300
or × 1e-100 the fit never left its start values yet reported them as fitted: LM's damping λI
saw the gain's Jacobian column in the recording's units, std(w) overflowed, and σ_w had an
absolute floor of 1e-12. `fit` now works on w / std(w_train) and v_in / rms(v_in) and maps the
readout back, so the physical parameters are the same whatever the units, and the gain is in
the recording's units.

The recording and model are those of `test_fit.py`'s planted physics fit (N = 10, 1,200
samples, default LM settings), so in one pytest process they share its compiled LM program.
"""

import json
import re

import helpers as h
import jax.numpy as jnp
import numpy as np
import pytest

from hybrid import LTI, LevenbergMarquardt, RCNetwork, Recording, fit, make_model
from hybrid.core._problem import robust_rms, robust_std

TRUE_NETWORK = RCNetwork(
    xi_rho=6.0, xi_h=1.0, alpha_E=0.3, alpha_I=0.6, alpha_C=0.4, C_clamp=0.02, n_stages=10
)
PHYSICAL = ("xi_rho", "alpha_E", "alpha_I", "alpha_C", "C_clamp")
# The scaled recordings differ from the reference by the rounding of w · factor (one ulp,
# ~1e-16 relative), and the fit divides by std(w), so it sees the same numbers up to a few ulp.
# Measured spread of the physical parameters: ≤ 1e-9 relative (virtual IPMC PRBS, all five
# free); 1e-6 leaves three orders of magnitude for other machines and BLAS. Before the fix the
# spread was O(1) (or the start values, for 1e300 and 1e-100).
RTOL = 1e-6


@pytest.fixture(scope="module")
def recording():
    return h.planted_physics_recording(TRUE_NETWORK, 1.7, 0.3, 0.005, seed=0)


def _fit(recording):
    start = make_model("physics", simulation=RCNetwork(n_stages=10))
    return fit(start, recording, frozen={"xi_h"}, progress=False)


@pytest.fixture(scope="module")
def reference(recording):
    return _fit(recording)


@pytest.mark.parametrize(
    "w_factor, v_factor",
    [
        (1e-3, 1.0),  # w in m
        (1e3, 1.0),  # w in µm
        (1e-100, 1.0),
        (1e300, 1.0),  # std(w) overflowed: every residual was 0
        (1.0, 1e3),  # v_in in mV
    ],
)
def test_physical_parameters_do_not_depend_on_units(recording, reference, w_factor, v_factor):
    scaled = Recording(recording.t, recording.v_in * v_factor, recording.w * w_factor)
    result = _fit(scaled)
    assert result.starts[0]["accepted_steps"] > 0
    for name in PHYSICAL:
        assert result.parameters[name] == pytest.approx(reference.parameters[name], rel=RTOL), name
    # the gain (mm/V) and offset (mm) come back in the recording's own units
    assert result.parameters["gain"] == pytest.approx(
        reference.parameters["gain"] * w_factor / v_factor, rel=RTOL
    )
    assert result.parameters["offset"] == pytest.approx(reference.parameters["offset"] * w_factor, rel=RTOL)
    for split, metrics in reference.metrics.items():
        assert result.metrics[split]["fitting"] == pytest.approx(metrics["fitting"], abs=1e-6)
    # and the returned model predicts in those units
    w_hat = np.asarray(result.model.predict(scaled.v_in, scaled.dt))
    w_ref = np.asarray(reference.model.predict(recording.v_in, recording.dt))
    np.testing.assert_allclose(w_hat / w_factor, w_ref, rtol=1e-6, atol=1e-6 * np.max(np.abs(w_ref)))


def test_the_reference_fit_recovers_the_planted_gain(reference):
    assert reference.parameters["gain"] == pytest.approx(1.7, rel=0.01)
    assert reference.metrics["test"]["fitting"] > 95.0


@pytest.mark.parametrize("factor", [1.0, 1e-3, 1e300, 1e-100, 1e-300])
def test_robust_std_and_rms_at_any_magnitude(factor):
    x = np.random.default_rng(0).normal(size=1000) + 0.5
    assert float(robust_std(x * factor)) == pytest.approx(np.std(x) * factor, rel=1e-12)
    assert float(robust_rms(x * factor)) == pytest.approx(np.sqrt(np.mean(x**2)) * factor, rel=1e-12)
    # ordinary magnitudes: bit for bit jnp.std (the power-of-two prescaling is exact), so
    # every other user of Problem.scale (diagnose, fit_batch, sensitivity) is unchanged
    if factor in (1.0, 1e-3):
        assert float(robust_std(x * factor)) == float(jnp.std(x * factor))


# --------------------------------------------------------------------------- warnings (FitResult.warnings)
def test_warnings_name_implausible_unmoved_and_stuck_fits():
    from hybrid.core._result import fit_warnings

    start = make_model("physics", simulation=RCNetwork(n_stages=10))
    moved = start.simulation.replace(xi_rho=357.0, alpha_E=0.4, alpha_I=0.6, alpha_C=0.3, C_clamp=5e-11)
    fitted = make_model("physics", simulation=moved)
    record = {"accepted_steps": 12}
    warnings = fit_warnings(start, fitted, {"xi_h"}, record)
    assert len(warnings) == 1 and warnings[0].startswith(
        "C_clamp = 5e-11 F is outside its plausible range 0.0001 to 10 F"
    )
    # a parameter that did not move (relative change < 1e-6) is named; a frozen one is not
    fitted = make_model(
        "physics", simulation=start.simulation.replace(xi_rho=12.0, C_clamp=0.05 * (1 + 1e-9))
    )
    warnings = fit_warnings(start, fitted, {"xi_h"}, record)
    unmoved = sorted(w.split(" = ")[0] for w in warnings)
    assert unmoved == ["C_clamp", "alpha_C", "alpha_E", "alpha_I"]
    assert all(
        "did not move from its start value: the data may not constrain it, or the fit failed" in w
        for w in warnings
    )
    # no accepted step: one warning says so (not one per parameter); plausible ranges still apply
    stuck = make_model("physics", simulation=start.simulation.replace(alpha_E=0.999))
    warnings = fit_warnings(stuck, stuck, {"xi_h"}, {"accepted_steps": 0})
    assert "made no accepted step" in warnings[0] and len(warnings) == 2 and "alpha_E = 0.999" in warnings[1]
    # steps accepted but the validation loss least at the start (a drift on lti:2 of a user's data): one
    # warning that says the start was kept and why, not "the data may not constrain" each parameter
    warnings = fit_warnings(start, start, {"xi_h"}, {"accepted_steps": 6, "best_step": 0})
    assert len(warnings) == 1 and "the fit kept its start: its 6 accepted steps" in warnings[0]
    assert "validation part" in warnings[0] and "did not move" not in warnings[0]
    # a physics fit on too few training samples for its parameters (40 samples, 12 in training)
    few = fit_warnings(start, fitted, {"xi_h"}, record, n_train=12)
    assert "only 12 training samples for 7 fitted parameters" in few[-1] and "70 here" in few[-1]
    assert not any("training samples" in w for w in fit_warnings(start, fitted, {"xi_h"}, record, n_train=70))


def test_fit_reports_warnings_in_summary_and_json(recording):
    # a strip with an implausible double-layer capacitance (20 µF), camera timestamps in whole ms
    network = RCNetwork(xi_rho=6.0, alpha_E=0.3, alpha_I=0.6, alpha_C=0.4, C_clamp=2e-5, n_stages=10)
    planted = h.planted_physics_recording(network, 1.7, 0.3, 0.005, seed=0)
    t = np.round((planted.t + np.random.default_rng(0).uniform(-0.003, 0.003, planted.n)) * 1e3) / 1e3
    notes = Recording(t, planted.v_in, planted.w, name="camera.csv").notes  # t rebuilt: what it says
    # fitted on the planted time base (the rebuilt dt differs in its last digits, and dt is
    # compiled into the LM program: this keeps the program test_units and test_fit share)
    jittered = Recording(planted.t, planted.v_in, planted.w, name="camera.csv", notes=notes)
    result = fit(make_model("physics", simulation=network), jittered, frozen={"xi_h"}, progress=False)
    assert "t rebuilt as a uniform grid" in result.warnings[0] and "camera.csv" in result.warnings[0]
    assert any(w.startswith("C_clamp = ") and "outside its plausible range" in w for w in result.warnings)
    summary = result.summary()
    assert all(f"warning: {w}" in summary for w in result.warnings)
    # a dimensionless parameter prints bare (it read "alpha_E  = 0.3 1"), a dimensioned one with its unit
    assert re.search(r"^  alpha_E  = [-0-9.e+]+$", summary, re.M) and re.search(
        r"^  C_clamp  = \S+ F$", summary, re.M
    )
    record = json.loads(json.dumps(result.to_dict()))
    assert record["warnings"] == result.warnings


def test_a_unit_over_a_power_of_itself_is_cancelled():
    """`stiffness_cube` on a simulation that outputs volts read "V/V^3" (Duffing's cubic: 1/V^2)."""
    from hybrid.core._simulation import cancelled
    from hybrid.discovery._inside_effects import PolynomialStiffness as Stiffness

    assert Stiffness().units_for("V", "V")["stiffness_cube"] == "1/V^2"
    assert Stiffness().units_for("mm", "V")["stiffness_square"] == "V/mm^2"  # different units stay
    cases = {"V/V": "1", "V/V^2": "1/V", "(rad/s)/(rad/s)^3": "1/(rad/s)^2", "a.u./a.u.^3": "1/a.u.^2"}
    for unit, expected in {**cases, "mm/V": "mm/V", "cm^3/(s V)": "cm^3/(s V)", "V/mV": "V/mV"}.items():
        assert cancelled(unit) == expected, unit


def test_the_drive_power_of_a_unit_is_read_off_its_symbols():
    """The power of ``{drive}`` in a unit (what a change of the drive's unit scales a value in it by)."""
    from hybrid import EffectStack
    from hybrid.core._simulation import DRIVE, drive_power

    cases = {
        "{drive}": 1,
        "1/{drive}": -1,
        "1/{drive}^2": -2,
        "{drive}/min": 1,
        "{drive}/{drive}^3": -2,
        "mm/({drive}/s)": -1,  # a bracketed factor's power
        "(rad/s)/{drive}": -1,
        "cm^3/(s {drive})": -1,  # a product in brackets
        "J/kg·{drive}": -1,  # everything after the slash is below it
        "{drive}^0.5": 0.5,
        "Hz": 0,
        "1": 0,
        "(unit of h1)": 0,
    }
    for unit, expected in cases.items():
        assert drive_power(unit) == expected, unit
    for broken in ("({drive}", "{drive})", "mm/", "/{drive}", "^2"):
        assert drive_power(broken) is None, broken
    # an effect stack fills its effects' units with the drive's unit as asked: the placeholder too
    units = EffectStack(RCNetwork(), ["drive_even", "hysteresis", "drive_dead_zone"]).units_in(DRIVE)
    powers = {
        k: drive_power(units[k]) for k in ("drive_even_coefficient", "hysteresis_height", "hysteresis_rate")
    }
    assert powers == {"drive_even_coefficient": -1, "hysteresis_height": 1, "hysteresis_rate": -1}
    assert drive_power(units["drive_dead_zone_width"]) == 1 and drive_power(units["xi_rho"]) == 0


def _lag_recording(clip: float | None):
    """A first-order lag (τ 0.5 s, exact for a drive held over each sample) under a multilevel drive, 60 s at
    30 Hz, 1 % noise; `clip`: the sensor's range, ± that many units (None: none)."""
    rng = np.random.default_rng(3)
    rate, n = 30.0, 1800
    u = np.repeat(rng.uniform(-1.0, 1.0, 90), 20)[:n]
    a, x, w = np.exp(-1.0 / (rate * 0.5)), 0.0, np.empty(n)
    for k in range(n):
        w[k], x = 3.0 * x, a * x + (1.0 - a) * u[k]
    w = w + 0.01 * np.ptp(w) * rng.normal(size=n)
    if clip is not None:
        w = np.clip(w, -clip, clip)
    return Recording.from_arrays(v_in=u, w=w, rate=rate, metadata={"units": {"w": "mm", "v_in": "V"}})


def test_a_fit_of_a_clipped_record_says_the_record_sits_flat_where_the_model_goes_beyond():
    """A sensor at the end of its range: the fit followed the flat runs in silence (lab-files user, a 2 mm
    clip of a 2.5 mm response: f 1.22 vs 1.2 Hz, ζ 0.31 vs 0.25, gain 1.88 vs 2, no word)."""
    model = make_model("physics", simulation=LTI(1))
    clipped = fit(model, [_lag_recording(2.0)], solver=LevenbergMarquardt(max_steps=60))
    flat = [w for w in clipped.warnings if "sits flat at its largest value (2 mm)" in w]
    assert len(flat) == 1, clipped.warnings
    assert "smallest value (-2 mm)" in flat[0] and "hybrid diagnose" in flat[0], flat
    whole = fit(model, [_lag_recording(None)], solver=LevenbergMarquardt(max_steps=60))
    assert not [w for w in whole.warnings if "sits flat" in w], whole.warnings


@pytest.mark.parametrize(
    "unit, kind",
    [
        ("mm/s", "rate"),
        ("rad/s", "rate"),
        ("deg/s", "rate"),
        ("L/min", "rate"),
        ("m s⁻¹", "rate"),
        ("rpm", "rate"),
        ("m/s^2", None),  # an acceleration is neither
        ("m/s²", None),
        ("µm", "position"),
        ("mm", "position"),
        ("rad", "position"),
        ("°", "position"),
        ("px", "position"),
        ("°C", "temperature"),
        ("K", "temperature"),
        ("degF", "temperature"),
        # spelled out, as a plug-in's state_units or a units row may write them
        ("degrees", "position"),
        ("rev", "position"),
        ("turns", "position"),
        ("inch", "position"),
        ("degrees/s", "rate"),
        ("kelvin", "temperature"),
        ("degrees C", "temperature"),
        ("min", None),  # a time, not a length
        ("kg", None),
        ("ms", None),  # a time, not a length
        ("mV", None),
        ("V", None),
        ("", None),
    ],
)
def test_a_units_kind_tells_a_rate_from_a_position(unit, kind):
    from hybrid.data._header_units import unit_kind

    assert unit_kind(unit) == kind
