"""Models saved by an earlier release load and predict as they did when saved.

tests/data/model_v1_*.eqx were written by `hybrid.save_model` in format "hybrid-model/1" (the paper's RC
network with a linear readout; LTI(2) with the D-MLP), with their predictions on a fixed drive in
model_v1_predictions.npz. A change to the model classes or to the file format that loses them fails
here: bump `FORMAT` and keep loading (or refuse with one line saying how to convert) the old files.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import hybrid

DATA = Path(__file__).parent / "data"


@pytest.mark.parametrize("name", ["rc_physics", "lti2_hybrid"])
def test_a_model_saved_in_format_1_loads_and_predicts_as_saved(name):
    expected = np.load(DATA / "model_v1_predictions.npz")
    model = hybrid.load_model(DATA / f"model_v1_{name}.eqx")
    predicted = np.asarray(model.predict(expected["drive"], float(expected["dt"])))
    np.testing.assert_allclose(predicted, expected[name], rtol=1e-10, atol=1e-12)
