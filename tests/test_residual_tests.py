"""Residual analysis (hybrid.discovery.residual_tests) on signals with known statistics."""

import numpy as np
import pytest
import scipy.signal

from hybrid.discovery import residual_tests as rt


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
