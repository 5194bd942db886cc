"""The noise floor of w, from the recording alone, against noise of known variance.

The signals are built here with scipy (a low-passed random drive: a slow
strip's displacement) and the noise is drawn with a known σ, so each estimator
is checked against the truth, not against itself.
"""

from __future__ import annotations

import math
import pathlib

import numpy as np
import pytest
import scipy.signal

from hybrid.discovery._noise_floor import (
    difference_variance,
    glitch_runs,
    noise_floor,
    repeat_variance,
    spectral_variance,
)

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


def test_isolated_spikes_are_found_and_left_out_of_the_floor():
    # A tracker that lost its marker for one frame, 12 times in 2 minutes: each spike 30–60 % of the
    # range (15–30 σ of the noise). Counted, they raise every estimator over twice σ² (the floor said
    # "within the noise" beside a model that missed); left out, the floor is the noise's again (the
    # test above's bounds), and the warning says how many, and that every fit still counts them.
    # The drive steps every 15 samples; a spike in the first 3 samples after a step is not told from a
    # fast response there (`SPIKE_AFTER`), so the spikes are placed where the drive has held 4 or more.
    v, clean = _slow_signal(3600, 5)
    sigma = 0.02 * np.ptp(clean)
    rng = np.random.default_rng(105)
    w = clean + rng.normal(0.0, sigma, clean.size)
    jumps = np.flatnonzero(np.diff(v) != 0) + 1
    held = np.setdiff1d(np.arange(10, clean.size - 10), np.concatenate([jumps + k for k in range(-1, 4)]))
    at = np.sort(rng.choice(held, 12, replace=False))
    w[at] += rng.choice([-1.0, 1.0], 12) * rng.uniform(0.3, 0.6, 12) * np.ptp(clean)
    floor = noise_floor(w, v, RATE)
    assert list(floor.spikes) == list(at)
    assert floor.variance == pytest.approx(sigma**2, rel=0.25)
    assert min(difference_variance(w, k) for k in (1, 2, 3, 4)) > 2 * sigma**2  # what counting them gives
    assert floor.spike_note in floor.warnings and "12 isolated spike(s)" in floor.spike_note
    # a spike right after a step is left alone (the floor then reads it, as before)
    w[jumps[5] + 1] += 0.5 * np.ptp(clean)
    assert jumps[5] + 1 not in noise_floor(w, v, RATE).spikes


@pytest.mark.parametrize("hz", [5.0, 10.0, 15.0, 24.0])
@pytest.mark.parametrize("shape", ["linear", "saturating", "rectified"])
def test_a_fast_response_to_steps_is_no_spike(hz, shape):
    # A mode up to the Nyquist frequency (50 Hz sampling) under random steps, read linearly, through a
    # saturating sensor or rectified: its first samples after each step leave their neighbours as a
    # spike would (flagged at 8 robust σ alone), but they come at the drive's steps and are no larger
    # than the response's own largest steps.
    v, mode = _fast_mode(3000, 0, hz=hz, zeta=0.4 if hz < 20 else 0.05)
    clean = {"linear": mode, "saturating": 30.0 * np.tanh(mode / 30.0), "rectified": np.abs(mode)}[shape]
    w = clean + np.random.default_rng(2).normal(0.0, 0.03, clean.size)
    assert noise_floor(w, v, 50.0).spikes == ()


@pytest.mark.parametrize(("size", "found"), [(14.0, 13), (6.0, 0)])
def test_spike_sensitivity_on_white_noise(size, found):
    # 13 spikes of `size` σ on white noise, mid-hold: 14 σ are all found (beyond 8 robust σ and 3× the
    # 99th percentile of the other excursions, ≈ 11.9 σ of the noise), 6 σ none (noise-like).
    rng = np.random.default_rng(3)
    w = rng.normal(size=5000)
    v = np.repeat(rng.uniform(-1, 1, 5000 // 20 + 1), 20)[:5000]
    at = np.arange(100, 5000, 400) + 7
    w[at] += size
    assert len(noise_floor(w, v, RATE).spikes) == found


@pytest.mark.parametrize("case", ["noise", "fast_steps", "impulses", "rounded"])
def test_what_is_not_a_spike_is_not_flagged(case):
    # White noise (3600 samples: 8 robust σ is out of reach), a first-order plant that follows each step
    # within a sample (it moves and stays), an impulse test's responses (the drive's own spikes), and
    # data rounded to a coarse grid (no robust spread): none is a spike, and the floor is what it was.
    rng = np.random.default_rng(7)
    v, clean = _slow_signal(3600, 7)
    if case == "fast_steps":
        clean = scipy.signal.lfilter([0.86], [1.0, -0.14], v)
    if case == "impulses":
        v = np.zeros(3600)
        v[::90] = 1.0
        clean = scipy.signal.lfilter([0.9], [1.0, -0.1], v)
    w = clean + rng.normal(0.0, 0.005 * np.ptp(clean), clean.size)
    if case == "rounded":
        w = np.round(w / (0.05 * np.ptp(clean))) * 0.05 * np.ptp(clean)
    floor = noise_floor(w, v, RATE)
    assert floor.spikes == () and floor.spike_note == ""
    assert floor.estimates["differences_1"] == difference_variance(w, 1)  # read from w as it is


def test_a_spike_at_either_end_of_the_record_is_found_without_an_index_error():
    # The first and last samples that have two neighbours (1 and n − 2), under a drive that holds
    # (w is read as it is): the rest of the excursions' tail is taken beside them, inside the record.
    w = np.random.default_rng(9).normal(0.0, 1.0, 2000)
    w[[1, 1998]] += 40.0
    assert noise_floor(w, np.zeros(2000), RATE).spikes == (1, 1998)


def test_a_pooled_floor_says_which_recording_has_the_spikes():
    # Two recordings of one drive, a spike in the second only: the pooled floor's warning names it
    # (counted from 1, as the remainder names recordings).
    import hybrid
    from hybrid.discovery._unexplained import pooled_noise_floor

    rng = np.random.default_rng(0)
    v = np.repeat(rng.uniform(-1, 1, 101), 20)[:2000]
    w = [rng.normal(size=2000), rng.normal(size=2000)]
    w[1][1007] += 40.0
    floor = pooled_noise_floor([hybrid.Recording.from_arrays(v_in=v, w=x, rate=RATE) for x in w])
    spiky = [line for line in floor.warnings if "isolated spike" in line]
    assert spiky == [floor.spike_note] and spiky[0].startswith("Recording 2: w has 1 isolated spike(s)")


def _glitched(seed, lengths, size=0.4, dropouts=True):
    """A slow strip under 40-sample holds at 50 Hz, σ = 1 % of its range, with glitches of these lengths.

    Every other one reads 0 where the strip is far from it (a logger's dropout; `dropouts`), the rest sit
    `size` of the range off (a tracker on a wrong blob); the k-th lies in hold 5 + 10k, entered at least
    5 samples after the drive's step and left at least 5 before the next.
    """
    rng = np.random.default_rng(seed)
    n = 6000
    v = np.repeat(rng.uniform(-2.0, 2.0, n // 40 + 1), 40)[:n]
    clean = scipy.signal.lfilter([0.04], [1.0, -0.96], v)  # a 25-sample lag
    span = np.ptp(clean)
    sigma = 0.01 * span
    w = clean + rng.normal(0.0, sigma, n)
    runs = []
    for k, length in enumerate(lengths):
        a = 40 * (5 + 10 * k) + 5 + int(rng.integers(0, 40 - 10 - length + 1))
        if dropouts and k % 2 and abs(clean[a]) > 0.3 * span:
            w[a : a + length] = 0.0
        else:
            w[a : a + length] += rng.choice([-1.0, 1.0]) * size * span
        runs.append((a, a + length - 1))
    return v, w, sigma, runs


def test_glitches_are_found_and_bridged_out_of_the_floor(monkeypatch):
    # A tracker that lost the tip for 2 to 10 frames, or a logger that read 0, 12 times in 2 minutes.
    # Not lone samples, so `spike_samples` misses them; counted, they raise the floor over 2× σ² (below);
    # bridged, it is the noise's.
    lengths = [2, 3, 4, 5, 6, 7, 8, 9, 10, 2, 3, 4]
    v, w, sigma, runs = _glitched(11, lengths)
    floor = noise_floor(w, v, 50.0)
    assert list(floor.glitches) == runs
    inside = sorted(k for a, b in runs for k in range(a, b + 1))
    assert list(floor.spikes) == inside
    assert floor.variance == pytest.approx(sigma**2, rel=0.25)
    assert floor.spike_note in floor.warnings and "12 glitch(es), runs of 2–10 samples" in floor.spike_note
    assert floor.spike_words == "glitches" and floor.to_dict()["glitches"] == [list(r) for r in runs]
    from hybrid.discovery import _noise_floor

    monkeypatch.setattr(_noise_floor, "glitch_runs", lambda w, v: [])
    assert noise_floor(w, v, 50.0).variance > 2 * sigma**2  # what counting them gives


@pytest.mark.parametrize(("size", "found"), [(0.3, 6), (0.04, 0)])
def test_glitch_sensitivity(size, found):
    # Plateaus 30 % of the range off (30 σ) are all found; 4 % (4 σ) none: within the noise's reach.
    v, w, sigma, runs = _glitched(12, [3, 4, 5, 6, 7, 8], size=size, dropouts=False)
    assert glitch_runs(w, v) == runs[:found]


@pytest.mark.parametrize("case", ["noise", "fast_steps", "pulses", "ringing", "step_stays", "rounded"])
def test_what_is_not_a_glitch_is_not_flagged(case):
    # Noise; a plant that follows each step within a sample; its response to drive pulses of 2–8
    # samples (w jumps in and out with the drive); a 15 Hz mode ringing after each step; an undriven
    # step of w that stays; data rounded to a coarse grid: none is a glitch.
    rng = np.random.default_rng(8)
    n = 4000
    v = np.repeat(rng.uniform(-2.0, 2.0, n // 40 + 1), 40)[:n]
    if case == "pulses":
        v = np.zeros(n)
        for a in range(50, n - 20, 97):
            v[a : a + 2 + a % 7] = 1.0
    clean = scipy.signal.lfilter([0.86], [1.0, -0.14], v)
    if case == "ringing":
        v, clean = _fast_mode(n, 1, hz=15.0, zeta=0.05)
    w = clean + rng.normal(0.0, 0.005 * np.ptp(clean), n)
    if case == "step_stays":
        w[2013:] += 0.5 * np.ptp(clean)
    if case == "rounded":
        w = np.round(w / (0.05 * np.ptp(clean))) * 0.05 * np.ptp(clean)
    assert glitch_runs(w, v) == []
    assert noise_floor(w, v, 50.0).glitches == ()


def test_recordings_without_glitches_have_none():
    # The discrepancy generator's strips (each hidden effect and pair of its open-world table, 3 seeds:
    # camera exposure, saturations, loops, resonances, delays) and the virtual strip under the four
    # paper drives: w moves with the drive, never jumps in and back out by itself.
    import hybrid as hy
    from hybrid.ipmc import virtual_recording
    from hybrid.ipmc._hidden_pairs import random_hidden
    from hybrid.ipmc._synthetic import HIDDEN_EFFECTS, discrepancy_drive, random_strip, synthetic_recording

    names = [*HIDDEN_EFFECTS, "dead_zone", "rate_dependent", "self_heating", "electrostatic"]
    names += [
        "back_relaxation+saturation",
        "hysteresis+drift",
        "delay+back_relaxation",
        "saturation+resonance",
    ]
    for seed in range(3):
        for name in names:
            rng = np.random.default_rng(seed)
            drive, strip = discrepancy_drive(60.0, 30.0, seed), random_strip(rng)
            params = None if name == "none" else random_hidden(name, rng, 30.0)
            recording = synthetic_recording(drive, strip, name, params, seed=seed)
            assert glitch_runs(recording.w, recording.v_in) == [], (seed, name)
    for kind in ("prbs", "sine", "chirp", "pulse"):
        recording = virtual_recording(hy.make_drive(kind, duration=60.0, rate=30.0), seed=0)
        assert glitch_runs(recording.w, recording.v_in) == [], kind


DATA = pathlib.Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.mark.skipif(not DATA.is_dir(), reason=f"the measured benchmarks are not in {DATA}")
def test_the_measured_benchmarks_have_no_glitches():
    tanks = np.genfromtxt(DATA / "cascaded-tanks" / "dataBenchmark.csv", delimiter=",", names=True)
    for u, y in (("uEst", "yEst"), ("uVal", "yVal")):
        assert glitch_runs(tanks[y], tanks[u]) == [], y
    snls = np.genfromtxt(DATA / "silverbox" / "SNLS80mV.csv", delimiter=",", names=True)
    for a, b in ((100, 40575), (40650, 127400)):  # the arrow, the estimation multisines
        assert glitch_runs(snls["V2"][a:b], snls["V1"][a:b]) == [], (a, b)
