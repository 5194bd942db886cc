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


def _fast_mode(n, seed, rate=50.0, hz=15.0, zeta=0.4):
    """A 15-Hz mode sampled at 50 Hz driven by random steps (scipy ZOH): content up to the Nyquist frequency."""
    rng = np.random.default_rng(seed)
    v = np.repeat(rng.uniform(0.0, 100.0, n // 40 + 1), 40)[:n]
    w0 = 2 * math.pi * hz
    a = np.array([[0.0, 1.0], [-w0 * w0, -2 * zeta * w0]])
    b, c, d = np.array([[0.0], [w0 * w0]]), np.array([[1.0, 0.0]]), np.zeros((1, 1))
    system = scipy.signal.cont2discrete((a, b, c, d), 1 / rate, method="zoh")
    return v, scipy.signal.dlsim(system[:4] + (1 / rate,), v)[1][:, 0]


def test_a_fast_linear_response_is_taken_out_before_its_noise_is_read():
    """w of a fast mode varies from sample to sample far more than its noise: a linear fit's residual does not."""
    v, clean = _fast_mode(3000, 0)
    sigma = 0.03
    w = clean + np.random.default_rng(1).normal(0.0, sigma, clean.size)
    # Every estimator of w alone reads the mode (15 Hz with 25 Hz Nyquist).
    assert min(difference_variance(w, k) for k in (1, 2, 3, 4)) > 100 * sigma**2
    assert spectral_variance(w, 50.0) > 100 * sigma**2
    floor = noise_floor(w, v, 50.0)
    assert floor.method.startswith("linear_fit_differences_") and "linear fit" in floor.source
    assert floor.variance == pytest.approx(sigma**2, rel=0.15)
    assert abs(floor.variance - sigma**2) <= 4 * floor.std_error + 0.1 * sigma**2
    assert floor.fraction_of_variance == pytest.approx(floor.variance / np.var(w), rel=1e-9)


def test_a_fast_nonlinear_signals_floor_is_bounded_by_a_models_held_out_residual():
    """Where no linear fit takes the signal out, the fitted model's held-out residual bounds the noise."""
    from hybrid.discovery._noise_floor import RESIDUAL_SWITCH, bounded_by_residual

    v, mode = _fast_mode(3000, 0)
    clean = 30.0 * np.tanh(mode / 30.0)  # a sensor that saturates: no linear response of the drive
    sigma = 0.03
    rng = np.random.default_rng(1)
    noise = rng.normal(0.0, sigma, clean.size)
    floor = noise_floor(clean + noise, v, 50.0)
    assert floor.variance > 10 * sigma**2  # every model-free estimate reads the signal
    # Held out: three segments; the residual is the noise plus a slow miss (a creep, a low-pass of the
    # drive with τ = 3 s: the model lacks it) and a different offset per segment (a jump between them).
    creep = 0.05 * scipy.signal.lfilter([1 - math.exp(-1 / 150)], [1, -math.exp(-1 / 150)], v)
    segment = np.repeat([0, 1, 2], 300)
    residual = (noise + creep)[-900:] + np.array([0.0, 10.0, -10.0])[segment]
    bounded = bounded_by_residual(floor, residual, segment)
    assert bounded.variance == pytest.approx(sigma**2, rel=0.15)
    assert bounded.method.startswith("residual_differences_") and "held-out residual" in bounded.source
    assert abs(bounded.variance - sigma**2) <= 4 * bounded.std_error + 0.1 * sigma**2
    assert bounded.fraction_of_variance == pytest.approx(bounded.variance / np.var(clean + noise), rel=1e-9)
    assert np.mean(residual**2) > 100 * bounded.variance  # the creep stays far above it: not an all-clear
    # Differences across the segments' jumps would have read the offsets (±10) as noise.
    across = np.mean(np.diff(residual, n=4) ** 2) / math.comb(8, 4)
    assert across > 100 * sigma**2

    # A slow signal's model-free floor is sound: a residual that agrees with it leaves its value as it was.
    v, slow = _slow_signal(3600, 0)
    sigma = 0.02 * np.ptp(slow)
    noise = np.random.default_rng(2).normal(0.0, sigma, slow.size)
    floor = noise_floor(slow + noise, v, RATE)
    kept = bounded_by_residual(floor, noise[-900:], np.zeros(900, int))
    assert (kept.variance, kept.method) == (floor.variance, floor.method)
    assert RESIDUAL_SWITCH * floor.variance < sigma**2
