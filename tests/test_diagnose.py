"""`diagnose` names the effect hidden in a recording, or none, from held-out evidence.

The recordings come from `hybrid._synthetic`: the paper's cascade by exact ZOH
on an 8× finer grid (scipy), the effect in a different functional form from the
extension that finds it (two-exponential relaxation against one, a Preisach
model of play operators against Bouc–Wen, algebraic against tanh saturation, a
dead time on the drive against one on V_o, linear/smoothstep against
exponential drift, a ZOH mode against a first-order-hold one), then camera
exposure and 1 % noise. Strips and effects are drawn from the issue's ranges.

Every draw here is 60 s at 30 Hz with the same drive shape, so the search is
compiled once for the module. Draws of a hidden effect are those whose effect is
*visible* (`experiments/discrepancy.py`: the best effect-free fit leaves ≥ 3×
the noise variance; below that the cascade absorbs the effect and no extension
can gain 2×); the experiment runs every draw.
"""

import numpy as np
import pytest

from hybrid._diagnose import diagnose
from hybrid._synthetic import discrepancy_drive, random_effect, random_strip, synthetic_recording

DURATION, RATE, NOISE = 60.0, 30.0, 0.01

#: (hidden effect, seed): effect-free on five seeds, every effect on draws whose effect is visible.
CASES = [("none", seed) for seed in range(5)] + [
    ("back_relaxation", 1), ("hysteresis", 0), ("saturation", 0), ("drift", 0),
    ("delay", 2), ("resonance", 1),
]


def hidden_effect_recording(effect: str, seed: int):
    rng = np.random.default_rng([seed, len(effect), sum(map(ord, effect))])
    strip, params = random_strip(rng), random_effect(effect, rng, RATE)
    drive = discrepancy_drive(DURATION, RATE, seed)
    return synthetic_recording(drive, strip, effect, params, noise_fraction=NOISE, seed=seed)


@pytest.mark.parametrize("effect,seed", CASES)
def test_diagnose_names_the_hidden_effect(effect, seed):
    recording = hidden_effect_recording(effect, seed)
    found = diagnose(recording)
    named = {c.name: f"gain {c.gain:.2f}, ΔBIC {c.delta_bic:.0f}, {c.reasons}" for c in found.candidates}
    assert found.cause == effect, f"hidden {effect} {recording.metadata['hidden']['effect_params']}, named {found.cause}: {named}"
    if effect == "none":
        assert found.gain == 1.0 and found.extended is found.baseline
        return
    assert found.gain >= 2.0, named
    # The named extension's held-out residual is closer to white than the baseline's.
    assert found.extended.ljung_box["Q"] < found.baseline.ljung_box["Q"]
    truth = recording.metadata["hidden"]["effect_params"]
    derived = found.extended.derived
    if effect == "delay":  # the fitted dead time (plus frame lag) within a sample of the truth
        total = derived["delay_samples"] + found.extended.parameters["frame_lag"]
        assert abs(total - (truth["delay_samples"] + 0.25)) < 1.0, (total, truth)
    if effect == "resonance":
        assert found.extended.parameters["resonance_frequency_hz"] == pytest.approx(truth["frequency_hz"], rel=0.1)
    if effect == "drift":
        assert np.sign(derived["gain_change_percent"]) == np.sign(truth["change"])
