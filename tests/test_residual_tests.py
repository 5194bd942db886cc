"""Residual analysis (hybrid.discovery.residual_tests) on signals with known statistics."""

import numpy as np
import pytest
import scipy.signal
import scipy.stats

from hybrid.discovery import residual_tests as rt
from hybrid.discovery._evidence import heldout_evidence


def _ar1(rho, n, seed=0):
    e = np.random.default_rng(seed).standard_normal(n)
    return scipy.signal.lfilter([1.0], [1.0, -rho], e)


def test_the_written_out_99_percent_quantile_is_scipys():
    import scipy.stats

    assert rt.Z99 == float(scipy.stats.norm.ppf(0.995))


def test_white_noise_stays_inside_the_99_percent_band():
    e = np.random.default_rng(1).standard_normal(20000)
    acf = rt.autocorrelation(e, 100)
    assert acf[0] == pytest.approx(1.0)
    outside = np.mean(np.abs(acf[1:]) > rt.confidence_bound(len(e)))
    assert outside <= 0.04  # 1 % expected; 4 % leaves room for chance over 100 lags
    assert rt.ljung_box(e)["p_value"] > 0.001


def test_ar1_autocorrelation_is_geometric_and_not_white():
    x = _ar1(0.8, 50000)
    acf = rt.autocorrelation(x, 5)
    np.testing.assert_allclose(acf, 0.8 ** np.arange(6), atol=0.03)
    assert rt.ljung_box(x)["p_value"] < 1e-10
    # Effective sample factor of an AR(1): 1 + 2 Σ ρ^k = (1 + ρ)/(1 − ρ) = 9.
    assert rt.effective_sample_factor(x, 200) == pytest.approx(9.0, rel=0.15)


def test_cross_correlation_finds_the_lag():
    u = np.random.default_rng(2).standard_normal(5000)
    e = np.concatenate([np.zeros(3), u[:-3]]) + 0.1 * np.random.default_rng(3).standard_normal(5000)
    lags, ccf = rt.cross_correlation(e, u, 10)
    assert lags[np.argmax(ccf)] == 3
    assert ccf.max() > 0.9


def test_travel_direction_holds_through_flat_parts():
    drive = np.array([0, 1, 1, 1, 0.5, 0.5, 2, 2])
    np.testing.assert_array_equal(rt.travel_direction(drive), [0, 1, 1, 1, -1, -1, 1, 1])


def test_loops_separate_a_direction_dependent_residual():
    t = np.linspace(0, 20, 4000)
    drive = np.sin(2 * np.pi * 0.5 * t)
    direction = rt.travel_direction(drive)
    residual = 0.3 * direction  # +0.3 rising, −0.3 falling
    out = rt.loops(residual, drive)
    assert out["separation"] == pytest.approx(0.6, rel=1e-6)
    assert rt.loops(np.zeros_like(drive), drive)["separation"] == 0.0


def test_segment_errors_show_a_growing_error():
    w = np.ones(800)
    w_hat = 1 - np.linspace(0, 0.4, 800)
    errors = rt.segment_errors(w, w_hat, 4)
    assert np.all(np.diff(errors) > 0)
    assert errors[0] == pytest.approx(np.mean((w[:200] - w_hat[:200]) ** 2))


def test_spectrum_peaks_at_a_hidden_tone():
    rate = 30.0
    t = np.arange(6000) / rate
    e = np.sin(2 * np.pi * 4.0 * t) + np.random.default_rng(4).standard_normal(6000)
    f, p = rt.spectrum(e, rate)
    assert f[np.argmax(p)] == pytest.approx(4.0, abs=rate / 256)


def test_ljung_box_q_ignores_scale_and_reports_the_variance():
    """Q compares correlations only; its variance puts two residuals' correlated parts in one unit."""
    rng = np.random.default_rng(3)
    x = scipy.signal.lfilter([1.0], [1.0, -0.8], rng.normal(size=2000))
    big, small = rt.ljung_box(x), rt.ljung_box(0.25 * x)
    assert small["Q"] == pytest.approx(big["Q"], rel=1e-12)
    assert small["variance"] == pytest.approx(np.var(x) / 16, rel=1e-12)
    # the quarter-size residual's autocovariances, in the big one's units: 1/16² of Q
    assert small["Q"] * (small["variance"] / big["variance"]) ** 2 == pytest.approx(big["Q"] / 256, rel=1e-12)


def test_the_periodogram_of_recordings_on_their_grids_is_the_sum_of_each_ones():
    # Against numpy's FFT written out: a row's missing samples (NaN) are zeros after its mean (over the
    # samples it has) is taken out, each row padded to n_fft, the rows' |FFT|² summed; and the strongest
    # line of two sinusoids sampled with gaps is the stronger one's frequency, to a padded bin.
    rate, n = 50.0, 1000
    t = np.arange(n) / rate
    rows = np.vstack([2.0 * np.sin(2 * np.pi * 7.3 * t), 0.5 * np.sin(2 * np.pi * 3.1 * t + 1.0)])
    rows[:, 200:300] = np.nan
    freq, power = rt.periodogram(rows, rate, 4 * n)
    expected = sum(np.abs(np.fft.rfft(np.nan_to_num(row - np.nanmean(row)), n=4 * n)) ** 2 for row in rows)
    np.testing.assert_allclose(power, expected, rtol=1e-12)
    np.testing.assert_allclose(freq, np.fft.rfftfreq(4 * n, 1 / rate))
    assert rt.strongest_line(freq, power, 1.0, rate / 2) == pytest.approx(7.3, abs=rate / (4 * n))
    assert rt.strongest_line(freq, power, 1.0, 5.0) == pytest.approx(3.1, abs=rate / (4 * n))
    assert rt.strongest_line(freq, power, 30.0, 40.0) is None


def _held_steps(n, rng, rate=30.0, hold=(0.5, 3.0)):
    """A drive held at random levels for `hold` s each: far from white (the discrepancy drive's kind)."""
    holds, levels = rng.uniform(*hold, 2000), rng.uniform(-1.0, 1.0, 2000)
    return levels[np.searchsorted(np.cumsum(holds), np.arange(n) / rate, side="right")]


def test_drive_independence_holds_its_level_for_a_stepped_drive_where_the_plain_band_does_not():
    """300 independent pairs (a stepped drive, an AR(1) residual of ρ 0.9, three held-out blocks of 200):
    the prewhitened test rejects at 5 % at most 5 % of them (1–3 % seen: the AR fits make it a little
    conservative); without prewhitening (order 0, the ±z/√N band's assumption of a white drive) most.
    Bound: binomial(300, 0.05) exceeds 27 with probability < 0.001."""
    rng = np.random.default_rng(0)
    blocks = np.repeat(np.arange(3), 200)
    p = {0: [], rt.WHITENING_ORDER: []}
    for _ in range(300):
        u = _held_steps(600, rng)
        e = scipy.signal.lfilter([1.0], [1.0, -0.9], rng.standard_normal(600))
        for order in p:
            p[order].append(rt.drive_independence(e, u, blocks, order=order)["p_value"])
    rejected = {order: int(np.sum(np.asarray(v) < 0.05)) for order, v in p.items()}
    print("rejected at 5 % of 300, by whitening order:", rejected)  # docs/diagnose.md quotes them (pytest -s)
    assert rejected[rt.WHITENING_ORDER] <= 27, rejected
    assert rejected[0] > 150, rejected  # the plain band's test on a stepped drive: no level at all


def test_drive_independence_finds_a_small_part_of_the_drive_left_in_the_residual():
    """A residual that is noise plus a lagged, smoothed copy of the drive half the noise's size (a
    remainder 1.25× the noise floor in variance, under the 2× that `diagnose` calls unexplained) is
    found, on each of five drives; the same noise alone is not. The power grows with the drive's steps:
    here holds of 0.1–0.6 s, about 165 steps in the 60 s (`pytest -s` prints the p-values); with the
    33 steps of holds of 0.5–3 s the same part is harder to see."""
    blocks = np.repeat(np.arange(6), 300)
    found = []
    for seed in range(5):
        rng = np.random.default_rng(seed)
        u = _held_steps(1800, rng, hold=(0.1, 0.6))
        noise = rng.standard_normal(1800)
        # the drive, 5 samples late, smoothed
        left = scipy.signal.lfilter([0.2], [1.0, -0.8], np.r_[np.zeros(5), u[:-5]])
        left *= 0.5 / np.std(left)
        found.append(rt.drive_independence(noise + left, u, blocks))
        assert rt.drive_independence(noise, u, blocks)["p_value"] > 1e-3
    print("p of a part half the noise's size, seeds 0-4:", [f"{f['p_value']:.1e}" for f in found])
    assert all(f["p_value"] < 1e-8 and f["lags"] == rt.INDEPENDENCE_LAGS + 1 for f in found)
    # and the statistic is Σ_k c_k²/Var c_k of the filtered pair: at order 0 on one block, of the series
    # themselves, with Var c_k = Σε²·Σu²/m over the m samples each lag overlaps
    e, d = noise + left - np.mean(noise + left), u - np.mean(u)
    pairs = [(e[k:], d[: len(d) - k]) for k in range(rt.INDEPENDENCE_LAGS + 1)]
    expected = sum((a @ b) ** 2 / (a @ a * (b @ b) / len(b)) for a, b in pairs)
    assert rt.drive_independence(noise + left, u, order=0)["statistic"] == pytest.approx(expected, rel=1e-12)


def test_drive_independence_holds_its_level_on_recordings_of_different_sizes():
    """Two recordings diagnosed together, the second driven and disturbed 10× harder than the first (white
    drive and noise, independent): with each lag's variance summed recording by recording the test keeps its
    level (at most 2 of 300 rejected at 10⁻³ allowed: binomial(300, 10⁻³) exceeds 2 with probability
    0.0036), where the pooled N Σ ρ̂², which takes every ρ̂'s variance as 1/N, rejects most of them (its
    variance is about twice that here). 300 pairs of 1800 samples, six blocks."""
    rng = np.random.default_rng(4)
    blocks = np.repeat(np.arange(6), 300)
    scale = np.where(blocks < 3, 0.1, 1.0)
    lags = rt.INDEPENDENCE_LAGS
    p_blocks, p_pooled = [], []
    for _ in range(300):
        u, e = rng.standard_normal(1800) * scale, rng.standard_normal(1800) * scale
        p_blocks.append(rt.drive_independence(e, u, blocks, recordings=blocks >= 3)["p_value"])
        _, ccf = rt.cross_correlation(e, u, lags)
        p_pooled.append(scipy.stats.chi2.sf(1800 * np.sum(ccf[lags:] ** 2), lags + 1))
    rejected = {
        "by recording": int(np.sum(np.asarray(p_blocks) < 1e-3)),
        "pooled": int(np.sum(np.asarray(p_pooled) < 1e-3)),
    }
    print("rejected at 1e-3 of 300 independent pairs:", rejected)  # docs/diagnose.md quotes them (pytest -s)
    assert rejected["by recording"] <= 2, rejected
    assert rejected["pooled"] > 100, rejected
    # and diagnose's held-out evidence passes the recordings on (the last pair: as one, the pooled form)
    zero = np.zeros_like(e)
    evidence = heldout_evidence(u, e, zero, zero, 30.0, segments=blocks, recordings=blocks >= 3)
    assert evidence["extended"]["drive_independence"]["p_value"] == p_blocks[-1]
    pooled = rt.drive_independence(e, u, blocks)["statistic"]
    assert pooled != pytest.approx(evidence["extended"]["drive_independence"]["statistic"], rel=0.01)


def test_drive_independence_declines_what_it_cannot_test():
    u = _held_steps(600, np.random.default_rng(2))
    assert rt.drive_independence(np.ones(600), u) is None  # no variation in the residual
    assert rt.drive_independence(u, np.zeros(600)) is None  # nor in the drive
    assert rt.drive_independence(u[:100], u[:100]) is None  # too short for 10 + 30 lags, 4 times over
    assert rt.drive_independence(u, u[:-1]) is None  # not one pair


def test_drive_independence_is_not_taken_on_a_drive_its_own_ar_model_predicts():
    """A sine, a chirp and levels held one per block leave the filter nothing white to test against
    (the χ² would reject 1–14 % of independent pairs at 10⁻³); a stepped or square drive is tested."""
    rng = np.random.default_rng(3)
    t = np.arange(1800) / 30.0
    e = scipy.signal.lfilter([1.0], [1.0, -0.9], rng.standard_normal(1800))
    blocks = np.repeat(np.arange(6), 300)
    predictable = {
        "sine": np.sin(2 * np.pi * 0.7 * t),
        "chirp": scipy.signal.chirp(t, 0.1, 60.0, 3.0),
        "levels held per block": np.repeat(rng.uniform(-1.0, 1.0, 6), 300),
    }
    for name, u in predictable.items():
        assert rt.drive_independence(e, u, blocks) is None, name
    for u in (_held_steps(1800, rng, hold=(0.5, 10.0)), np.sign(np.sin(2 * np.pi * 0.25 * t + 0.3))):
        assert rt.drive_independence(e, u, blocks) is not None
