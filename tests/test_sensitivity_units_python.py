"""The covariance's units are the recording's, as the fit's are: `hybrid.sensitivity` in Python.

A recording of w in micrometres gives a gain in um/V and an offset in um, both in `FitResult.units`
and in `standard_errors(result, recording).units`; one that declares no unit of w (a lab's file read
without `units`) gives `a.u.`. The covariance's values are in the recording's units either way; its
labels used to say mm whatever the recording said.
"""

from __future__ import annotations

import helpers as h
import numpy as np
import pytest

import hybrid as hy
from hybrid import sensitivity as S

DT, N = 0.05, 240
TRUE = {"f_1": 1.5, "zeta_1": 0.3, "bandpass_1": 0.2, "direct": 0.05}


@pytest.fixture(scope="module")
def lab_csv(tmp_path_factory):
    """A lab's file: drive 'u' (V), output 'y' = 2·LTI(2) + 0.1 with a little noise, time 't' (s)."""
    u = h.step_drive(N, seed=5, low=4, high=30)
    y = 2.0 * h.lti2_zoh_response(TRUE, u, DT) + 0.1 + 0.01 * np.random.default_rng(1).normal(size=N)
    path = tmp_path_factory.mktemp("units") / "lab.csv"
    rows = [f"{i * DT:.12g},{a:.12g},{b:.12g}" for i, (a, b) in enumerate(zip(u, y))]
    path.write_text("t,u,y\n" + "\n".join(rows) + "\n")
    return path


def _load(path, units=None):
    return hy.load_mapped(str(path), input="u", output="y", time="t", units=units)


def test_standard_errors_are_labelled_in_the_recording_s_units_as_the_fit_is(lab_csv):
    recording = _load(lab_csv, {"w": "um"})
    model = hy.make_model("physics", simulation=hy.LTI(2, **TRUE))
    result = hy.fit(model, recording, solver=hy.LevenbergMarquardt(max_steps=2), progress=False)
    assert result.units["gain"] == "um/V" and result.units["offset"] == "um"
    cov = S.standard_errors(result, recording)
    assert cov.units == {name: result.units[name] for name in cov.names}  # used to say mm/V and mm
    assert S.parameter_covariance(result.model, recording).units == cov.units


def test_a_recording_without_units_labels_the_covariance_as_the_fit_does(lab_csv):
    recording = _load(lab_csv)  # no units given: w in arbitrary units, the drive in V
    model = hy.Model(hy.LTI(2, **TRUE), hy.LinearReadout(2.0, 0.1), "physics")
    cov = S.parameter_covariance(model, recording)
    assert cov.units["gain"] == "a.u./V" and cov.units["offset"] == "a.u."  # used to say mm/V and mm
    assert cov.units["f_1"] == "Hz" and cov.units["direct"] == "1"
    assert np.all(np.isfinite(list(cov.std_errors.values())))
