"""The same recording in another unit of w gets the same diagnosis.

A lab records a displacement in µm, mm or m; what `diagnose` names must not
depend on which. The search's least-squares problem holds a grey-box readout's
gain and offset (w's unit) in units of w's own scale (`hybrid.core.Problem`),
so that Levenberg's damping λI and their Jacobian columns read the same in any
unit. Before, hysteresis seed 1 of `experiments/discrepancy.py` (60 s) was
named in µm and not in mm, and drift seed 0 named `saturation` in m.
"""

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest
from helpers import hidden_recording

from hybrid import LinearReadout, Model, RCNetwork, diagnose
from hybrid.core import Problem, series_from_recording

MICRONS = 1000.0  # mm → µm
INCHES = 1.0 / 25.4  # mm → in: a factor that is not a power of ten


def _in_unit(recording, factor):
    return dataclasses.replace(recording, w=np.asarray(recording.w) * factor)


@pytest.mark.parametrize("factor", [MICRONS, INCHES])
def test_the_least_squares_problem_reads_the_same_in_any_unit_of_w(factor):
    """θ, the cost and the normal equations of a model and recording are those of both in another unit (to rounding)."""
    recording = hidden_recording("none", 0, duration=20.0)
    model = Model(RCNetwork(), LinearReadout(gain=3.0, offset=0.05), "physics")
    other = Model(model.simulation, LinearReadout(gain=3.0 * factor, offset=0.05 * factor), "physics")
    problems = [
        Problem(m, [series_from_recording(r)])
        for m, r in ((model, recording), (other, _in_unit(recording, factor)))
    ]
    thetas = [p.flatten(m) for p, m in zip(problems, (model, other))]
    np.testing.assert_allclose(thetas[1], thetas[0], rtol=1e-12, atol=1e-15)
    theta = thetas[0] * (1.0 + 0.01 * jnp.sin(jnp.arange(thetas[0].size)))  # away from the start
    (a, g), (a_um, g_um) = (p.normal_equations(theta) for p in problems)
    np.testing.assert_allclose(a_um, a, rtol=1e-9, atol=1e-12 * float(jnp.max(jnp.abs(a))))
    np.testing.assert_allclose(g_um, g, rtol=1e-9, atol=1e-12 * float(jnp.max(jnp.abs(g))))
    # and the model it stands for is in each recording's own unit
    gains = [float(p.model(theta).readout.parameters()["gain"]) for p in problems]
    np.testing.assert_allclose(gains[1], gains[0] * factor, rtol=1e-12)


def test_a_strip_recorded_in_microns_gets_the_diagnosis_it_gets_in_millimetres():
    # Three effects, not the default thirteen, to keep the two diagnoses cheap: at fd47900 this draw named
    # nothing in mm and hysteresis in µm with these three too (baseline held-out NMSE 0.0064 and 0.0084).
    recording = hidden_recording("hysteresis", 1)
    found = [
        diagnose(r, simulation=RCNetwork(), effects=["hysteresis", "saturation", "drift"])
        for r in (recording, _in_unit(recording, MICRONS))
    ]
    mm, um = found
    assert [c["name"] for c in um.causes] == [c["name"] for c in mm.causes] != []
    for a, b in zip(um.causes, mm.causes):  # the same fit, to rounding
        np.testing.assert_allclose(a["incremental_gain"], b["incremental_gain"], rtol=1e-6)
    assert (um.unexplained is None) == (mm.unexplained is None)
    base_mm, base_um = (d.steps[0].current for d in found)
    np.testing.assert_allclose(base_um.heldout.nmse, base_mm.heldout.nmse, rtol=1e-6)
    np.testing.assert_allclose(base_um.validation_loss, base_mm.validation_loss, rtol=1e-6)
