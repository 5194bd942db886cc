"""The noise floor says what it was estimated from, and warns where it cannot be the measurement noise.

On smoothed or oversampled data the model-free estimators read what the processing
left of w's sample-to-sample variation (often only the rounding of the stored
values), not the measurement error. The floor then warns; on ordinary data (white
noise on a slow signal, stored with a few decimals) it does not. The data are built
here with numpy and scipy, the rounding with numpy.round, so the quantisation step
and the true noise are known independently of the code under test.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.signal

from hybrid import LTI, Recording, diagnose
from hybrid.discovery._noise_floor import noise_floor, quantisation_step
from hybrid.discovery._report import noise_section
from hybrid.discovery._unexplained import FAR_ABOVE_FLOOR, floor_caveat


def _slow_signal(n, rate, seed, cutoff_hz=2.0, hold=15):
    rng = np.random.default_rng(seed)
    v = np.repeat(rng.choice([-2.0, -1.0, 0.0, 1.0, 2.0], size=n // hold + 1), hold)[:n]
    b, a = scipy.signal.butter(2, cutoff_hz / (rate / 2))
    return v, scipy.signal.lfilter(b, a, v)


def test_the_quantisation_step_is_the_grid_the_values_were_rounded_to():
    rng = np.random.default_rng(0)
    x = rng.uniform(-2.0, 2.0, 3000)
    assert quantisation_step(np.round(x, 3)) == pytest.approx(1e-3, rel=1e-6)
    assert quantisation_step(np.round(x * 4096) / 4096) == pytest.approx(1 / 4096, rel=1e-6)  # a 12-bit ADC
    assert quantisation_step(np.round(x * 1000)) == 1.0  # counts
    assert quantisation_step(0.001 * np.array([0, 2, 5, 7, 9])) == pytest.approx(
        1e-3
    )  # no two values 1 step apart
    assert math.isnan(quantisation_step(x))  # continuous values are on no grid
    assert math.isnan(quantisation_step(np.ones(10)))


def test_smoothed_oversampled_data_warn_and_say_what_the_floor_read():
    """A 1 kHz record of a 2 Hz strip in mm, noise 5 µm, smoothed over 20 samples, stored to 1 µm."""
    rate, sigma = 1000.0, 0.005
    v, clean = _slow_signal(30_000, rate, 0, hold=500)
    noisy = 0.5 * clean + np.random.default_rng(1).normal(0.0, sigma, clean.size)
    w = np.round(np.convolve(noisy, np.ones(20) / 20, mode="same"), 3)
    floor = noise_floor(w, v, rate)
    # what makes the warning necessary: the floor reads the rounding (1 µm / √12), far below the true 5 µm
    assert floor.std < sigma / 3
    assert floor.quantum == pytest.approx(1e-3, rel=1e-6)
    assert len(floor.warnings) == 1 and "below the data's quantisation step (0.001" in floor.warnings[0]
    assert "smoothed or oversampled" in floor.warnings[0]
    assert floor.source and str(w.size) in floor.source
    # a model as close as the true noise allows (5 µm RMS) is far above this floor: the caveat says so
    caveat = floor_caveat(sigma**2, floor)
    assert caveat is not None and f"{sigma / floor.std:.3g}× the floor's σ" in caveat
    assert "if w was smoothed" in caveat  # nothing says whose the excess is: the floor is doubted
    # the excess is the smoothed noise, which no map of the drive predicts; one that a map recovers held
    # out is the model's miss, and the caveat says so rather than doubting the floor
    assert "if w was smoothed" in floor_caveat(sigma**2, floor, recovered=0.3)
    missed = floor_caveat(sigma**2, floor, recovered=0.8)
    assert missed is not None and "recovers 80% of that excess" in missed and "smoothed," not in missed
    # nor where most of the excess lies in one held-out stretch (a probe's 20 min drift that did not carry on
    # into the last one), which noise spread over the record does not; one stretch holding its share
    # of the samples' excess says nothing
    late = {"share": 0.91, "samples_fraction": 1 / 3, "t": [1080.0, 1199.98]}
    there = floor_caveat(sigma**2, floor, recovered=0.0, concentrated=late)
    assert (
        "91% of that excess lies in one held-out stretch, t = 1080–1200 s" in there
        and "smoothed," not in there
    )
    even = {**late, "share": 0.4}
    assert "if w was smoothed" in floor_caveat(sigma**2, floor, recovered=0.0, concentrated=even)
    report = "\n".join(
        noise_section(
            {
                "noise_floor": floor.to_dict(),
                "settings": {"unexplained_ratio": 2.0},
                "unexplained": None,
                "units": {"w": "mm", "v_in": "V"},
            }
        )
    )
    assert "Estimated from " + floor.source in report and "**Warning:** the floor σ" in report
    assert f"σ = {floor.std:.3g} mm" in report  # the floor is in the recording's unit


def test_a_coarse_sensors_rounding_is_the_floor_and_its_right_model_is_at_it():
    """A first-order plant read through a quantiser of a tenth of its range (noise 1 % before it).

    A probe's plant so read gave a floor of σ = 0.125 from w's own variation, below the rounding's own
    0.205 (a slow signal stays on a level for samples on end), and its right model was "64 % unexplained".
    The floor is now the rounding's, step/√12, and the right model sits at it.
    """
    rate, n = 50.0, 5000
    rng = np.random.default_rng(4)
    v = np.repeat(rng.uniform(-2.0, 2.0, n // 40 + 1), 40)[:n]
    a = np.exp(-1.0 / (rate * 0.4))
    clean = scipy.signal.lfilter([1 - a], [1, -a], v)
    step = 0.1 * np.ptp(clean)
    w = step * np.round((clean + 0.01 * np.ptp(clean) * rng.normal(size=n)) / step)
    floor = noise_floor(w, v, rate)
    assert floor.quantum == pytest.approx(step, rel=1e-6)
    assert floor.method == "rounding" and floor.variance == pytest.approx(step**2 / 12, rel=1e-9)
    assert len(floor.warnings) == 1 and "the floor is the rounding's" in floor.warnings[0]
    # the right model's error is the rounding's and the noise's, where w's own estimate is far below
    assert np.mean((w - clean) ** 2) == pytest.approx(step**2 / 12 + (0.01 * np.ptp(clean)) ** 2, rel=0.1)
    assert min(v for k, v in floor.estimates.items() if k != "rounding") < 0.8 * step**2 / 12
    found = diagnose(Recording.from_arrays(v_in=v, w=w, rate=rate), simulation=LTI(1), effects=["saturation"])
    assert found.unexplained is None and found.cause == "none", found.verdict
    # a grid the signal spans in 3 steps (an on/off sensor's few levels) is not read as spread rounding
    coarse = np.ptp(clean) / 3
    assert noise_floor(coarse * np.round(clean / coarse), v, rate).method != "rounding"


@pytest.mark.parametrize("seed", [0, 1])
def test_ordinary_data_give_no_warning(seed):
    """White noise (2 % of the range) on a slow strip at 30 Hz, stored with 4 decimals: the floor is the noise."""
    v, clean = _slow_signal(3600, 30.0, seed)
    sigma = 0.02 * np.ptp(clean)
    w = np.round(clean + np.random.default_rng(100 + seed).normal(0.0, sigma, clean.size), 4)
    floor = noise_floor(w, v, 30.0)
    assert floor.variance == pytest.approx(sigma**2, rel=0.25)  # as tests/test_noise_floor.py
    assert floor.quantum == pytest.approx(1e-4, rel=1e-6) and floor.warnings == ()
    assert floor.method in floor.source or "differences" in floor.source or "spectrum" in floor.source
    for ratio in (1.0, 3.0, 0.9 * FAR_ABOVE_FLOOR):  # a model at, near or well above the floor
        assert floor_caveat(ratio * floor.variance, floor) is None
    report = "\n".join(
        noise_section(
            {
                "noise_floor": floor.to_dict(),
                "settings": {"unexplained_ratio": 2.0},
                "unexplained": None,
                "units": {"w": "mm", "v_in": "V"},
            }
        )
    )
    assert "Warning" not in report and "Estimated from " in report
