"""The noise floor of w, from the recording alone, against noise of known variance.

The signals are built here with scipy (a low-passed random drive: a slow
strip's displacement) and the noise is drawn with a known σ, so each estimator
is checked against the truth, not against itself.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.signal

from hybrid.discovery._noise_floor import difference_variance, noise_floor, repeat_variance, spectral_variance

RATE = 30.0


def _slow_signal(n, seed, cutoff_hz=2.0):
    rng = np.random.default_rng(seed)
    v = np.repeat(rng.choice([-2.0, -1.0, 0.0, 1.0, 2.0], size=n // 15 + 1), 15)[:n]
    b, a = scipy.signal.butter(2, cutoff_hz / (RATE / 2))
    return v, scipy.signal.lfilter(b, a, v)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_white_noise_on_a_slow_signal_is_recovered(seed):
    v, clean = _slow_signal(3600, seed)
    sigma = 0.02 * np.ptp(clean)
    w = clean + np.random.default_rng(100 + seed).normal(0.0, sigma, clean.size)
    floor = noise_floor(w, v, RATE)
    # Upper bounds that the signal can only raise: within 25 % of σ² (a 2-Hz signal leaves
    # little power above 12 Hz or in 4th differences), and within 4 standard errors.
    assert floor.variance == pytest.approx(sigma**2, rel=0.25)
    assert abs(floor.variance - sigma**2) <= 4 * floor.std_error + 0.05 * sigma**2
    assert floor.fraction_of_variance == pytest.approx(floor.variance / np.var(w))
    assert floor.method in floor.estimates


def test_differences_are_exact_for_white_noise_and_blind_to_a_constant():
    """E[(Δᵏ e)²] = C(2k, k) σ²: with 200,000 samples each order is within 2 % of σ²."""
    e = np.random.default_rng(7).normal(0.0, 0.3, 200_000) + 5.0
    for k in (1, 2, 3, 4):
        assert difference_variance(e, k) == pytest.approx(0.09, rel=0.02)


def test_the_spectral_level_reads_the_white_floor():
    e = np.random.default_rng(8).normal(0.0, 0.5, 60_000)
    assert spectral_variance(e, RATE) == pytest.approx(0.25, rel=0.05)


def test_a_repeated_drive_gives_the_noise_without_the_signal():
    """However fast the signal, repetitions of the same drive differ only by the noise."""
    rng = np.random.default_rng(3)
    period = rng.normal(size=300)  # a fast, rough response that differences would take for noise
    v = np.tile(rng.normal(size=300), 8)
    w = np.tile(period, 8) + rng.normal(0.0, 0.05, 2400)
    variance, found = repeat_variance(w, v)
    assert found == 300
    assert variance == pytest.approx(0.0025, rel=0.1)
    floor = noise_floor(w, v, RATE)
    assert floor.method == "repeats" and floor.variance == pytest.approx(0.0025, rel=0.1)
    assert difference_variance(w, 2) > 10 * 0.0025  # the other estimators see the signal


def test_a_drive_that_never_repeats_has_no_repeat_estimate():
    v, clean = _slow_signal(900, 4)
    v = v + np.random.default_rng(5).normal(0.0, 1e-3, v.size)
    assert math.isnan(repeat_variance(clean, v)[0])
    assert "repeats" not in noise_floor(clean + 0.01, v, RATE).estimates
