"""Open-world diagnosis: both effects of a pair are named, stepwise, each on its own evidence.

Split from tests/test_open_world.py so that the two slow files can run on
different workers. The draws are those of `experiments/discrepancy.py`.
"""

from __future__ import annotations

import numpy as np
import pytest
from helpers import hidden_recording

from hybrid import diagnose
from hybrid.discovery._verdict import FOLLOWS_DRIVE_P
from hybrid.ipmc._hidden_pairs import true_noise_variance


# One pair here (hysteresis + drift, seed 2, ran here too until the suite neared its 10-minute budget);
# `experiments/discrepancy.py` runs every pair on many draws.
@pytest.mark.parametrize("spec,seed", [("back_relaxation+saturation", 0)])
def test_both_effects_of_a_pair_are_named(spec, seed):
    recording = hidden_recording(spec, seed)
    found = diagnose(recording)
    names = [c["name"] for c in found.causes]
    assert sorted(names) == sorted(spec.split("+")), found.verdict
    for cause in found.causes:  # each passed the rules against the model before it
        assert cause["incremental_gain"] >= 1.5 and cause["delta_bic"] <= -10.0
    assert found.cause == names[0]
    # Each cause's derived quantities are the final model's, as its parameters are (the first cause's
    # own step fitted it alone): those of the saved model, on the recording, computed apart.
    saved = found.models["extended"].simulation.derived(
        recording.v_in, float(recording.t[1] - recording.t[0])
    )
    for cause in found.causes:
        assert cause["derived"].keys() == saved[cause["name"]].keys()
        for key, value in saved[cause["name"]].items():
            assert cause["derived"][key] == pytest.approx(value, rel=1e-6), (cause["name"], key)
    # Both together come down to the measurement noise: nothing is left unexplained. Against the
    # true noise variance (which diagnose never sees): within 2.5x, where the baseline was far above.
    assert found.unexplained is None, found.verdict
    var_w = np.var(found.heldout.w)
    assert found.extended.heldout.nmse * var_w <= 2.5 * true_noise_variance(recording)
    assert found.baseline.heldout.nmse * var_w >= 10 * true_noise_variance(recording)
    # The baseline, missing both, leaves a residual that follows the drive (the held-out blocks' test of
    # independence, `residual_tests.drive_independence`); the verdict says so of the final model exactly
    # where its own test says so.
    tests = {k: found.evidence[k]["drive_independence"] for k in ("baseline", "extended")}
    assert tests["baseline"]["p_value"] < 1e-6 and tests["baseline"]["lags"] == 31, tests
    assert ("still follows the drive" in found.verdict) == (tests["extended"]["p_value"] < FOLLOWS_DRIVE_P)
