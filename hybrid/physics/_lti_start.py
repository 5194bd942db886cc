"""Where an `LTI` starts on a recording: its time scales centred on the data's own.

`LTI(N)`'s defaults centre its sections on 1 s. A lab's record may be sampled at
100 kHz (a mode at 800 Hz) or every 4 s (two water tanks): started three
decades away, Levenberg–Marquardt settles in a wrong basin (an lti:2 on a
100 kHz record of an 800 Hz mode stopped at f_1 = 0.48 Hz, zeta_1 = 638, train
NMSE 0.08: `benchmarks/long_record.py` before this module). `lti_for_recordings`
reads the time scale from the empirical transfer function H(f) = P_yu / P_uu
(Welch, pooled over the recordings) and centres the defaults there:

- a resonance (|H| peaks above twice its low-frequency level): its frequency;
- else the corner where |H| first falls below 1/√2 of its low-frequency level;
- else (flat to the top of the drive's band) a quarter of the sampling rate;

always within the resolved band [f of the first bin, rate/4], and only bins
where the drive has power (≥ 10⁻³ of its peak) count.
"""

from __future__ import annotations

import math

import numpy as np

from ..core._problem import unmeasured_of
from ._lti import LTI, default_values

RESONANCE = 2.0  # |H| above this many times its low-frequency level is a resonance
MIN_POWER = 1e-3  # bins where the drive's power is below this fraction of its peak are ignored


def response_frequency(v_in, w, rate: float) -> float:
    """The frequency (Hz) that sets the response's time scale: a resonance, else the −3 dB corner."""
    import scipy.signal

    v = np.asarray(v_in, float) - np.mean(v_in)
    y = np.asarray(w, float) - np.mean(w)
    n = len(v)
    top = rate / 4.0
    if n < 16 or not np.any(v):
        return top
    nperseg = int(min(n, max(16, n // 4), 8192))
    f, puu = scipy.signal.welch(v, fs=rate, nperseg=nperseg)
    _, pyu = scipy.signal.csd(v, y, fs=rate, nperseg=nperseg)
    keep = (f > 0) & (f <= top) & (puu >= MIN_POWER * puu.max())
    f, h = f[keep], np.abs(pyu[keep]) / puu[keep]
    if len(f) < 3:
        return top
    low = float(np.median(h[:3]))
    peak = int(np.argmax(h))
    if h[peak] > RESONANCE * low:
        return float(f[peak])
    below = np.flatnonzero(h < low / math.sqrt(2.0))
    return float(f[below[0]]) if len(below) else float(f[-1])


def _measured_w(recording) -> np.ndarray:
    """w with its samples of quality 0 (not measured: a tracker's held frames) read off a straight line
    between the measured samples beside them: the fits leave them out, and so does the start they begin
    from (wild values there moved the start: `tests/test_lti_start.py -k measured`)."""
    w = np.asarray(recording.w, float)
    unmeasured = unmeasured_of(recording)
    if not unmeasured.any() or unmeasured.all():
        return w
    n = np.arange(len(w))
    return np.interp(n, n[~unmeasured], w[~unmeasured])


def lti_for_recordings(order: int, recordings, **values) -> LTI:
    """`LTI(order)` with its default time scales centred on the recordings' (`values` override any)."""
    for r in recordings:  # what `fit` and `diagnose` check first: a corrupt cell is named, not transformed
        r.check_signals()
    freqs = [response_frequency(r.v_in, _measured_w(r), r.rate) for r in recordings]
    weights = [len(r.w) for r in recordings]
    centre_hz = float(np.exp(np.average(np.log(freqs), weights=weights)))
    return LTI(order, **{**default_values(order, 1.0 / (2.0 * math.pi * centre_hz)), **values})
