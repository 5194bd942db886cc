"""`fit(screen=N)` / `hybrid fit --screen N`: starts screened over the physics' typical ranges.

The recording is `experiments/discrepancy.py`'s hysteresis + drift draw, seed 3 (60 s at 30 Hz, a
random strip), fitted as the physics alone with 60 % for training: from the RC network's default
values LM stops where it starts (every physical parameter unmoved). Measured (NMSE, MSE/variance):
train 0.76 and test 4.0 from the defaults, 0.88 and 3.9 with 16 perturbed starts, 0.375 and 0.185
from 4 starts screened out of 512 points (the rest is the hysteresis and drift the physics lacks).
"""

from __future__ import annotations

import helpers as h
import pytest

from hybrid import InputError, LevenbergMarquardt, RCNetwork, fit, make_model

SPLIT = (0.6, 0.3, 0.1)


@pytest.fixture(scope="module")
def recording():
    return h.hidden_recording("hysteresis+drift", 3)


def _fit(recording, **kwargs):
    model = make_model("physics", simulation=RCNetwork())
    return fit(model, recording, split=SPLIT, progress=False, **kwargs)


def test_screened_starts_leave_the_plateau_that_the_default_values_stop_on(recording):
    stuck = _fit(recording)
    assert stuck.metrics["train"]["nmse_variance"] > 0.5 and stuck.metrics["test"]["nmse_variance"] > 1.0
    assert any("plateau" in w and "--screen" in w for w in stuck.warnings), stuck.warnings
    screened = _fit(recording, screen=512, starts=4)
    assert screened.metrics["train"]["nmse_variance"] < 0.5
    assert screened.metrics["test"]["nmse_variance"] < stuck.metrics["test"]["nmse_variance"] / 5
    assert screened.settings["screen"] == 512
    assert not any("plateau" in w for w in screened.warnings), screened.warnings
    # more screened points than starts: each start is a design point, none the defaults perturbed
    moved = [k for k, v in screened.parameters.items() if k in RCNetwork().constraints and k != "xi_h"]
    assert any(abs(screened.parameters[k] - float(RCNetwork().parameters()[k])) > 1e-3 for k in moved)


def test_screen_takes_a_whole_number_and_the_cli_refuses_it_where_there_is_nothing_to_screen(
    recording, tmp_path
):
    with pytest.raises(InputError, match="screen must be 0 or a positive number"):
        _fit(recording, screen=-1, solver=LevenbergMarquardt(max_steps=1))
    recording.save(tmp_path / "rec.csv")
    for flags, words in (
        (["--model", "normal"], "the normal model has none"),
        (["--model", "physics", "--start-from", "saved.eqx"], "saved model's"),
    ):
        run = h.run_hybrid(tmp_path, "fit", "rec.csv", "--screen", "64", *flags, "--out", "x.eqx")
        assert run.returncode == 2 and words in run.stderr and "Traceback" not in run.stderr, run.stderr
        assert not (tmp_path / "x.eqx").exists()
