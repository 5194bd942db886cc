"""A drive that is one sinusoid is said: it shows a linear system's gain and phase at one frequency only.

A probe's `lti:2` fitted to a 0.5 Hz sine read f 1.02 ± 0.0047 Hz, ζ 0.338 ± 0.006 and a gain 9 standard errors
from the truth, all "pinned", with no word that the drive could not tell them.
"""

from __future__ import annotations

import helpers as h
import numpy as np

import hybrid
from hybrid.core._result import one_frequency_drive

RATE = 30.0


def _recording(u, seed=0):
    t = np.arange(u.size) / RATE
    y = h.zoh_lag(u, 1 / RATE, 0.5) + 0.01 * np.random.default_rng(seed).standard_normal(u.size)
    return hybrid.Recording(t, u, y)


def _said(*recordings):
    return one_frequency_drive([(r.v_in, r.rate) for r in recordings])


def _sine(frequency, n=1800, phase=0.3):
    return (
        1.5 * np.sin(2 * np.pi * frequency * np.arange(n) / RATE + phase) + 0.4
    )  # an offset is no frequency


def test_a_sine_is_said_and_drives_of_many_frequencies_are_not():
    (said,) = _said(_recording(_sine(0.5)))
    assert said.startswith("the drive is one sinusoid (0.5 Hz holds 100.0% of its power)")
    assert "a drive of many frequencies (steps, a PRBS, a chirp) pins them" in said
    # two recordings at one frequency: said for both; at two frequencies: two gains and phases, not said
    (both,) = _said(_recording(_sine(0.5)), _recording(_sine(0.5, n=900, phase=1.0), seed=1))
    assert "in every recording" in both
    assert _said(_recording(_sine(0.5)), _recording(_sine(2.0), seed=1)) == []
    # a square wave (its fundamental holds 8/π² = 81 %), random steps, a chirp, a sine under a
    # noise of a third of its size: many frequencies
    t = np.arange(1800) / RATE
    square = np.sign(np.sin(2 * np.pi * 0.2 * t))
    chirp = np.sin(2 * np.pi * (0.05 + 0.05 * t) * t)
    noisy = _sine(0.5) + 0.5 * np.random.default_rng(2).standard_normal(t.size)
    # and a sine with a second tone of 0.15 its amplitude (2 % of the power), which pins a second-order plant
    tones = _sine(0.5) + 0.15 * 1.5 * np.sin(2 * np.pi * 3.1 * t)
    # and one of 0.1 its amplitude (1 % of the power), which made a study's bounds 3-7x tighter (a probe)
    tenth = _sine(0.5) + 0.1 * 1.5 * np.sin(2 * np.pi * 2.3 * t)
    for u in (square, h.step_drive(1800), chirp, noisy, tones, tenth):
        assert _said(_recording(u)) == []


def test_the_frequency_said_lies_between_bins_where_the_sine_does():
    """A 0.7123 Hz sine over 60 s read "0.717 Hz", its bin (1/60 Hz wide)."""
    (said,) = _said(_recording(_sine(0.7123)))
    assert said.startswith("the drive is one sinusoid (0.712 Hz")


def test_fit_carries_the_warning():
    result = hybrid.fit(
        hybrid.make_model("physics", simulation=hybrid.LTI(order=1)),
        _recording(_sine(0.5)),
        solver=hybrid.LevenbergMarquardt(max_steps=5),
    )
    assert any(w.startswith("the drive is one sinusoid (0.5 Hz") for w in result.warnings), result.warnings
    steps = _recording(h.step_drive(1800))
    result = hybrid.fit(
        hybrid.make_model("physics", simulation=hybrid.LTI(order=1)),
        steps,
        solver=hybrid.LevenbergMarquardt(max_steps=5),
    )
    assert not any("one sinusoid" in w for w in result.warnings)
