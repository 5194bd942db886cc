"""A fit whose parameters the recording cannot pin apart says so (`hybrid.core._fit.unpinned_warnings`).

A probe's heated block, C dT/dt = k u − T/R read through the readout's gain: only R·C (the time constant)
and k·R·gain (the static gain) reach the output, so `hybrid fit` returned one point of a surface of
equal fits and printed C, R, k and gain as if each were determined, without a word (`hybrid
sensitivity` found the two null directions). The data here are scipy's exact response of the block
(`scipy.signal.lsim`, the drive held over each sample), not the plug-in's.
"""

from __future__ import annotations

from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.signal

import hybrid as hy

TAU, STATIC = 4.0, 2.5  # the block's R·C (s) and k·R (K per V): all a recording can tell
RATE, N = 10.0, 1500


class HeatedBlock(hy.AbstractSimulation):
    """C dT/dt = k u − T/R, from rest: the output in K."""

    raw: dict
    constraints: ClassVar[dict] = {"R": hy.Positive(), "C": hy.Positive(), "k": hy.Positive()}
    units: ClassVar[dict] = {"R": "K/W", "C": "J/K", "k": "W/{drive}"}
    typical: ClassVar[dict] = {"R": (0.1, 10.0), "C": (1.0, 100.0), "k": (0.1, 10.0)}
    linear_in_drive: ClassVar[bool] = True
    output_unit: ClassVar[str] = "K"

    def __init__(self, R=1.0, C=3.0, k=1.0):
        self.raw = hy.encode({"R": R, "C": C, "k": k}, self.constraints, "HeatedBlock")

    def simulate(self, v_in, dt):
        v_in, dt = hy.check_drive(v_in, dt, "HeatedBlock.simulate")
        p = self.parameters()
        a = jnp.exp(-dt / (p["R"] * p["C"]))

        def step(T, u):  # T at the sample, then held u over the step (zero-order hold, as lsim's)
            return a * T + (1 - a) * p["k"] * p["R"] * u, T

        return jax.lax.scan(step, jnp.zeros((), v_in.dtype), v_in)[1]


@pytest.fixture(scope="module")
def block():
    rng = np.random.default_rng(7)
    t = np.arange(N) / RATE
    u = np.repeat(rng.uniform(0.0, 2.0, N // 40 + 1), 40)[:N]
    _, T, _ = scipy.signal.lsim(scipy.signal.lti([STATIC / TAU], [1.0, 1.0 / TAU]), u, t, interp=False)
    T = T + 0.005 * np.ptp(T) * rng.standard_normal(N)
    return hy.Recording(t=t, v_in=u, w=T, metadata={"units": {"v_in": "V", "w": "K"}}, name="block")


def test_a_fit_of_parameters_seen_only_as_products_says_they_are_not_pinned(block):
    result = hy.fit(hy.make_model("physics", simulation=HeatedBlock()), block, progress=False)
    p = result.parameters
    # the fit itself is right where the data can tell: the time constant and the static gain
    assert p["R"] * p["C"] == pytest.approx(TAU, rel=0.02)
    assert p["k"] * p["R"] * p["gain"] == pytest.approx(STATIC, rel=0.02)
    (said,) = [w for w in result.warnings if "does not pin" in w]
    assert "does not pin C, R, k and gain apart: 2 combinations" in said
    assert said.count("--freeze ") == 2  # one parameter per blind direction


def test_parameters_the_recording_pins_get_no_such_warning(block):
    # R and k frozen: R·C pins C, k·R·gain pins gain
    model = hy.make_model("physics", simulation=HeatedBlock())
    result = hy.fit(model, block, frozen={"R", "k"}, progress=False)
    assert result.parameters["C"] == pytest.approx(TAU, rel=0.02)
    assert not [w for w in result.warnings if "does not pin" in w], result.warnings


class _Unused(HeatedBlock):
    """The block with a parameter its simulate never reads (a plug-in author's leftover)."""

    constraints: ClassVar[dict] = {**HeatedBlock.constraints, "spare": hy.Positive()}
    units: ClassVar[dict] = {**HeatedBlock.units, "spare": "1"}
    typical: ClassVar[dict] = {**HeatedBlock.typical, "spare": (0.1, 10.0)}

    def __init__(self, R=1.0, C=3.0, k=1.0, spare=1.0):
        self.raw = hy.encode({"R": R, "C": C, "k": k, "spare": spare}, self.constraints, "_Unused")


def test_a_parameter_the_prediction_does_not_depend_on_is_said_to_sit_at_its_start(block):
    model = hy.make_model("physics", simulation=_Unused())
    result = hy.fit(model, block, frozen={"R", "k"}, progress=False)
    assert result.parameters["spare"] == 1.0 and result.parameters["C"] == pytest.approx(TAU, rel=0.02)
    (said,) = [w for w in result.warnings if "does not depend on" in w]
    assert said.startswith("the prediction does not depend on spare on this recording")
    assert "--freeze spare" in said and "never uses" in said
    assert not [w for w in result.warnings if "does not pin" in w]
    assert not [w for w in result.warnings if "did not move" in w]  # said once, not twice (a verifier's)


class _Leaky(HeatedBlock):
    """The block with a share of the drive that leaks straight to the output, ``leak`` in [0, 1]."""

    constraints: ClassVar[dict] = {**HeatedBlock.constraints, "leak": hy.UnitInterval()}
    units: ClassVar[dict] = {**HeatedBlock.units, "leak": "K/{drive}"}
    typical: ClassVar[dict] = {**HeatedBlock.typical, "leak": (0.0, 1.0)}

    def __init__(self, R=1.0, C=3.0, k=1.0, leak=0.3):
        self.raw = hy.encode({"R": R, "C": C, "k": k, "leak": leak}, self.constraints, "_Leaky")

    def simulate(self, v_in, dt):
        return super().simulate(v_in, dt) + self.parameters()["leak"] * jnp.asarray(v_in)


def test_a_parameter_pushed_to_its_bound_is_said_to_sit_there_not_to_be_idle(block):
    """The block has no leak (its true value 0, the range's lower bound): the fit pushes ``leak`` onto 0,
    where its raw value's map is flat and the Jacobian's column vanishes, though the prediction depends on
    it with a slope of the drive. A probe's refit of a diagnosis's frame lag at 0 samples read "the
    prediction does not depend on frame_lag"."""
    model = hy.make_model("physics", simulation=_Leaky())
    result = hy.fit(model, block, frozen={"R", "k"}, progress=False)
    assert result.parameters["leak"] < 1e-3 and result.parameters["C"] == pytest.approx(TAU, rel=0.02)
    (said,) = [w for w in result.warnings if "leak" in w]
    assert said.startswith("leak sits at its lower bound (0 K/V)"), said
    assert "--freeze leak" in said and "does not depend on" not in said
