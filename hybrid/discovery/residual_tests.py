"""Residual analysis of system identification: is what the model leaves out noise?

For held-out residuals ε(t) = w − ŵ and the drive u(t):

- `autocorrelation`: ρ_εε(k), k = 0..K. A model that captures the dynamics
  leaves white residuals: |ρ_εε(k)| < z/√N for k ≥ 1 with z = 2.576 (99 %).
- `cross_correlation`: ρ_εu(k), k = −K..K; residuals independent of the input
  stay within the same ±z/√N band (Ljung, *System Identification*, §16.6).
- `drive_independence`: one test of that independence that holds for a drive
  that is not white: the drive and the residual each prewhitened by an AR model
  of its own (Haugh's double prewhitening; the band above assumes a white
  drive, and a drive held in steps is far from one), then each lag's
  cross-product sum over its standard error under independence (the sizes
  taken recording by recording), squared and summed over k = 0..K, against χ²_{K+1}.
- `ljung_box`: the portmanteau statistic Q = N(N+2) Σ_{k=1}^{K} ρ_k²/(N−k)
  and its χ²_K p-value: one number for "how far from white"; with the
  residual's variance γ_0, so that Q·(γ_0/γ_0')² compares the correlated part
  of two residuals in the units of the second (ρ_k = γ_k/γ_0).
- `spectrum`: Welch power spectral density (scipy).
- `periodogram`, `strongest_line`, `zero_padding`: the periodogram of recordings laid on their
  own sample grids (a part of the split, its other samples missing), summed
  over the recordings, and its largest bin in a band: a line's frequency to a
  fraction of a bin of the whole record, where Welch's segments give a few bins.
- `loops`: mean residual against drive level, separately for a rising and a
  falling drive (direction of the last change), the signature of hysteresis
  and saturation.
- `segment_errors`: NMSE per consecutive segment, the signature of drift.
"""

from __future__ import annotations

import numpy as np

#: Two-sided 99 % normal quantile used for the confidence bounds: scipy.stats.norm.ppf(0.995), written out
#: so that importing hybrid does not import scipy.stats (tests/test_residual_tests.py checks the digits).
Z99 = 2.5758293035489004


def _standardise(x):
    x = np.asarray(x, dtype=float)
    x = x - x.mean()
    scale = np.sqrt(np.mean(x * x))
    return x / scale if scale > 0 else x


def autocorrelation(residual, max_lag: int = 50) -> np.ndarray:
    """ρ(k) for k = 0..max_lag (biased estimator, ρ(0) = 1)."""
    e = _standardise(residual)
    n = len(e)
    max_lag = min(max_lag, n - 1)
    return np.array([np.dot(e[: n - k], e[k:]) / n for k in range(max_lag + 1)])


def cross_correlation(residual, drive, max_lag: int = 50) -> tuple[np.ndarray, np.ndarray]:
    """(lags, ρ_εu(k)) for k = −max_lag..max_lag; k > 0: the drive leads the residual."""
    e, u = _standardise(residual), _standardise(drive)
    n = len(e)
    max_lag = min(max_lag, n - 1)
    lags = np.arange(-max_lag, max_lag + 1)
    values = np.array(
        [np.dot(e[k:], u[: n - k]) / n if k >= 0 else np.dot(e[: n + k], u[-k:]) / n for k in lags]
    )
    return lags, values


#: `drive_independence`'s defaults: the AR order that whitens the drive and the residual, and the lags tested (the drive
#: leading the residual by 0..`INDEPENDENCE_LAGS` samples).
WHITENING_ORDER = 10
INDEPENDENCE_LAGS = 30
#: The least share of the drive's variance its AR filter must leave for `drive_independence` to test.
MIN_INNOVATION = 1e-4


def drive_independence(
    residual,
    drive,
    segments=None,
    lags: int = INDEPENDENCE_LAGS,
    order: int = WHITENING_ORDER,
    recordings=None,
) -> dict | None:
    """Whether the residual is independent of the drive: a portmanteau test on the prewhitened pair.

    The drive and the residual are each filtered by an AR(`order`) model of
    its own, fitted by least squares over every segment (never across one's
    edge): both are then close to white (Haugh, 1976). Filtering the residual
    by the drive's model instead (Box and Jenkins) nearly differences a slow
    remainder away when the drive is held in steps, and the test lost it.
    Each lag's cross-product sum c_k = Σ_t ε′_t u′_{t−k} of the filtered pair,
    summed over the segments, is then standardised by its variance under
    independence, Σ_recordings (Σ ε′²)(Σ u′²)/m over each recording's m
    samples that the lag overlaps, and the statistic S = Σ_{k=0}^{lags}
    c_k²/Var c_k is χ² with lags + 1 degrees of freedom for an independent
    pair. On one recording that is N Σ ρ̂_εu(k)² up to the lags' overlap; taken
    recording by recording, the sizes of the residual and of the drive may
    differ between recordings diagnosed together (a second, 10× larger drive
    and noise), where one N Σ ρ̂² over them all rejected 130 of 300 independent
    pairs at 10⁻³ (`tests/test_residual_tests.py`). Within a recording the
    sizes are taken as one: a noise that grows with the drive can still read as
    a dependence. Not per held-out block, nor per sample (White's variance from
    each lag's own products): a drive that moves in one block and rests in the
    others leaves the residual larger in the first where the model misses its
    response, and either form counts that size as noise (run at 9fe3bf2 over
    `experiments/drive_independence.py`'s draws, the per-sample form no longer
    told a baseline that misses two effects from noise). Only lags where the
    drive leads count: a causal model's missing part follows the drive that
    came before.

    `segments`: one label per sample (the held-out blocks: samples with the same
    label are contiguous in time), or None for one record.
    `recordings`: one label per sample, the recording it comes from (each
    segment lies within one), or None for one.

    Returns ``{"statistic", "lags", "order", "p_value"}``, or None where there is
    too little to test: a drive or residual without variation, fewer than 4 ×
    (order + lags) samples after the filter's start, or a drive its own AR model
    predicts (what the filter leaves of it under `MIN_INNOVATION` of its variance:
    a sine, a chirp, a drive held at one level in each block), whose filtered
    remains are not the white signal the test's χ² assumes: on such drives it
    rejected independent pairs far more often than its level. A drive of held
    steps keeps far more than that share (`tests/test_residual_tests.py`).
    """
    import scipy.stats

    e = np.asarray(residual, dtype=float)
    u = np.asarray(drive, dtype=float)
    labels = np.zeros(len(e), int) if segments is None else np.asarray(segments)
    sources = np.zeros(len(e), int) if recordings is None else np.asarray(recordings)
    if (
        e.shape != u.shape
        or labels.shape != e.shape
        or sources.shape != e.shape
        or not (np.all(np.isfinite(e)) and np.all(np.isfinite(u)))
    ):
        return None
    e, u = e - e.mean(), u - u.mean()
    parts = [np.flatnonzero(labels == label) for label in dict.fromkeys(labels.tolist())]
    parts = [i for i in parts if len(i) > order + lags]

    def lagged(x, idx):  # rows [x_{i-1}, ..., x_{i-order}] for i = order.. of one segment
        x = x[idx]
        return np.stack([x[order - j : len(x) - j] for j in range(1, order + 1)], axis=1), x[order:]

    if not parts or np.ptp(u) == 0 or np.ptp(e) == 0:
        return None

    def whitened(x):  # each segment of x filtered by x's own AR(order) model, fitted over them all
        if not order:
            return [x[idx] for idx in parts]
        rows, targets = zip(*(lagged(x, idx) for idx in parts))
        a = np.linalg.lstsq(np.concatenate(rows), np.concatenate(targets), rcond=None)[0]
        return [y - r @ a for r, y in (lagged(x, idx) for idx in parts)]

    pairs = list(zip(whitened(e), whitened(u)))
    n = sum(len(fu) for _, fu in pairs)
    if n < 4 * (order + lags):
        return None
    su = np.sqrt(sum(float(fu @ fu) for _, fu in pairs) / n)
    kept = np.concatenate([u[idx][order:] for idx in parts])
    if not su**2 >= MIN_INNOVATION * float(np.mean((kept - kept.mean()) ** 2)):
        return None
    sums = np.zeros(lags + 1)
    sizes: dict = {}  # recording -> (Σε′², Σu′², m) over the samples each lag overlaps
    for (fe, fu), idx in zip(pairs, parts):  # every segment is longer than the lags (`parts`)
        own = sizes.setdefault(sources[idx[0]], np.zeros((3, lags + 1)))
        for k in range(lags + 1):
            ek, uk = fe[k:], fu[: len(fu) - k]
            sums[k] += float(ek @ uk)
            own[:, k] += (float(ek @ ek), float(uk @ uk), len(uk))
    variances = sum(ee * uu / m for ee, uu, m in sizes.values())
    if not np.all(variances > 0):
        return None
    statistic = float(np.sum(sums**2 / variances))
    return {
        "statistic": statistic,
        "lags": lags + 1,
        "order": order,
        "p_value": float(scipy.stats.chi2.sf(statistic, lags + 1)),
    }


def confidence_bound(n: int) -> float:
    """Half-width of the 99 % band of a correlation estimate from n white samples."""
    return Z99 / np.sqrt(n)


def ljung_box(residual, lags: int = 30) -> dict:
    """Portmanteau whiteness test: Q, degrees of freedom, p-value and the variance γ_0 that normalises ρ_k."""
    import scipy.stats

    rho = autocorrelation(residual, lags)[1:]
    n = len(residual)
    k = np.arange(1, len(rho) + 1)
    q = float(n * (n + 2) * np.sum(rho**2 / (n - k)))
    return {
        "Q": q,
        "lags": int(len(rho)),
        "p_value": float(scipy.stats.chi2.sf(q, len(rho))),
        "variance": float(np.var(residual)),
    }


def white_limit(lags: int = 30, level: float = 0.99) -> float:
    """The Ljung–Box Q below which a residual passes as white at `level` (χ² quantile)."""
    import scipy.stats

    return float(scipy.stats.chi2.ppf(level, lags))


def spectrum(residual, rate: float) -> tuple[np.ndarray, np.ndarray]:
    """(frequencies in Hz, power spectral density in unit²/Hz), Welch's method."""
    import scipy.signal

    residual = np.asarray(residual, dtype=float)
    nperseg = int(min(len(residual), max(64, 2 ** int(np.log2(max(len(residual) // 8, 1))))))
    return scipy.signal.welch(residual - residual.mean(), fs=rate, nperseg=nperseg)


#: A line is read from this many cycles per recording (slower: a trend in time), by the remainder and `line`.
MIN_CYCLES = 3
#: Zero padding of a periodogram (`zero_padding`: its grid this many times finer than the record's) ...
PAD = 4
#: ... as long as the padded grid stays within this many points (a long record is padded less).
MAX_FFT = 2**22


def zero_padding(n: int) -> int:
    """How many times a record of `n` samples is zero-padded for `periodogram`: `PAD`, less past `MAX_FFT`."""
    return max(min(PAD, MAX_FFT // max(n, 1)), 1)


def periodogram(grids, rate: float, n_fft: int, hann: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(frequencies in Hz, power) of signals on their sample grids, summed over them.

    `grids`: one row per recording, each sample at its place from the
    recording's start, NaN where the row has no sample (another part of the
    split; read as 0 once the row's mean is taken out). Each row is
    zero-padded to `n_fft` points (`n_fft` at least the rows' length); `hann`
    tapers each over its span (to its last sample), so that a line's leakage
    falls off within a few bins.
    """
    grids = np.atleast_2d(np.asarray(grids, float))
    power = np.zeros(n_fft // 2 + 1)
    for row in grids:
        have = np.isfinite(row)
        if not have.any():
            continue
        x = np.where(have, row - row[have].mean(), 0.0)
        if hann:
            end = int(np.flatnonzero(have)[-1]) + 1
            x[:end] *= np.hanning(end)
        power += np.abs(np.fft.rfft(x, n=n_fft)) ** 2
    return np.fft.rfftfreq(n_fft, 1.0 / rate), power


def strongest_line(freq, power, low: float, high: float) -> float | None:
    """The frequency of `power`'s largest bin with `low` ≤ f < `high`, or None when no bin lies there."""
    band = (freq >= low) & (freq < high)
    return float(freq[band][np.argmax(power[band])]) if band.any() else None


def travel_direction(drive) -> np.ndarray:
    """+1 where the drive last changed upwards, −1 downwards (0 before any change)."""
    drive = np.asarray(drive, dtype=float)
    step = np.sign(np.diff(drive, prepend=drive[0]))
    step[np.abs(np.diff(drive, prepend=drive[0])) < 1e-9 * max(np.ptp(drive), 1e-300)] = 0.0
    direction = np.zeros_like(step)
    last = 0.0
    for i, s in enumerate(step):
        if s != 0:
            last = s
        direction[i] = last
    return direction


def loops(residual, drive, bins: int = 12) -> dict:
    """Mean residual by drive level, rising and falling separately.

    Returns ``{"centres": (bins,), "rising": (bins,), "falling": (bins,),
    "separation": float}`` where separation is the rms difference between the
    rising and falling means over levels that have both (NaN where a bin is empty).
    """
    residual, drive = np.asarray(residual, dtype=float), np.asarray(drive, dtype=float)
    direction = travel_direction(drive)
    edges = np.linspace(drive.min(), drive.max() + 1e-12, bins + 1)
    which = np.clip(np.digitize(drive, edges) - 1, 0, bins - 1)
    out: dict[str, np.ndarray | float] = {"centres": 0.5 * (edges[1:] + edges[:-1])}
    by_way: dict[str, np.ndarray] = {}
    for name, sign in (("rising", 1.0), ("falling", -1.0)):
        means = np.full(bins, np.nan)
        for b in range(bins):
            sel = (which == b) & (direction == sign)
            if sel.sum() >= 3:
                means[b] = residual[sel].mean()
        out[name] = by_way[name] = means
    rising, falling = by_way["rising"], by_way["falling"]
    both = np.isfinite(rising) & np.isfinite(falling)
    out["separation"] = float(np.sqrt(np.mean((rising[both] - falling[both]) ** 2))) if both.any() else 0.0
    return out


def segment_errors(w, w_hat, segments: int = 8) -> np.ndarray:
    """Mean squared error per consecutive segment, divided by the mean square of w overall."""
    w, w_hat = np.asarray(w, dtype=float), np.asarray(w_hat, dtype=float)
    scale = np.mean(w * w)
    parts = np.array_split(np.arange(len(w)), segments)
    return np.array([np.mean((w[p] - w_hat[p]) ** 2) / scale for p in parts])


def effective_sample_factor(residual, max_lag: int = 50) -> float:
    """1 + 2 Σ ρ(k) over the lags before ρ first drops below zero (≥ 1).

    Correlated residuals carry less information than white ones: standard
    errors from (JᵀJ)⁻¹ are scaled by the square root of this factor.
    """
    rho = autocorrelation(residual, max_lag)[1:]
    positive = np.cumprod(rho > 0).astype(bool)
    return float(max(1.0, 1.0 + 2.0 * np.sum(rho[positive])))
