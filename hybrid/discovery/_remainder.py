"""Where an unexplained remainder lives: cheap extensions fitted to the final residual.

When the final model's held-out error stays above the measurement-noise floor,
`describe_remainder` says what kind of thing the simulation still misses by
fitting simple extensions to the residual r = w − ŵ and reporting how much of
the held-out mean square of r each removes (1 − MSE(r − r̂)/MSE(r)):

- **offset**: the training mean of r (the baseline every map includes).
- **static, drive**: binned means of r on training quantile bins of the drive
  level v (every level its own bin for a multilevel drive), interpolated
  linearly. On a grid symmetric about v = 0 (both signs driven) the map's
  variance splits exactly into an even and an odd part; **one-sidedness** is the
  map's rms on positive vs negative drive; **flat near zero** compares the
  slope of w (recording) and of ŵ (model) on v for |v| < ¼ max|v| with their
  slope outside (a dead zone); **bend at the ends** is the change of the slope
  of r on v from the middle to the outer third of each side, relative to the
  model's gain (saturation, stiffening).
- **static, output**: a map of the simulation's output, w ≈ g(ŵ), fitted
  monotone (`scipy.optimize.isotonic_regression`, increasing or decreasing,
  whichever fits training better) and as free binned means of r on ŵ.
- **rate**: binned means of r on dv/dt (differences within a segment × rate).
- **time**: a cubic polynomial in absolute time (held-out blocks interleave
  with training blocks, so a trend fitted on one applies to the other; held
  out beyond the training span, it stays at its value at the end).
- **linear filter**: ridge least squares of r on the lags 0..L of v, and of ŵ
  (L ≈ rate × 1 s, at least 16 and at most 60), never across a segment change; its frequency
  response up to Nyquist for the figure.
- **power of the output, filtered**: the same filter of ŵ_c² and of ŵ_c³
  (ŵ centred and scaled on training), each with ŵ's own lags beside it (a
  refitted linear model leaves the power's part correlated with ŵ
  in the residual): a static nonlinearity *inside* the
  dynamics, e.g. an oscillator's cubic (odd) or quadratic (even) restoring
  force, whose effect on w is its force passed through the resonance. The
  first-order perturbation of a Duffing oscillator is exactly this.
- **periodic**: a sinusoid (amplitude and phase per recording) at the
  frequency of the training residual's largest spectral line, at least
  `residual_tests.MIN_CYCLES` cycles per recording (slower is a trend) and above every bin slower than
  that (a spectrum that rises into the trends' band is a trend's or a slow response's) — only where the drive
  carries no line there, nor at a harmonic, an alias or a sum or difference of
  its own lines (a periodic drive's response is the drive's, not a
  disturbance). Phase-locked over the recording, a vibration or an electrical
  pick-up predicts its held-out blocks; a lightly damped mode that random drive
  excites wanders in phase and does not.
- **repeats**: where two recordings share a drive (lengths within 1 %, drives
  correlating above `SAME_DRIVE` sample for sample), the mean product of their
  held-out residuals at the same places over their mean square above the floor:
  the share of the excess that repeats with the drive. An unstructured remainder
  is then read as a disturbance (it does not repeat) or a miss no map here
  represents (it does); with no such pair, the summary says that recording the
  drive again tells them apart.
- **states** (a simulation in state-space form with at most `MAX_STATES`
  states): a map of each state fed back into the drive, through the model's
  linearised response (`_state_feedback`), and the same map read on the
  output (`_state_output`: a readout that bends with a state, a static map).

Every extension is fitted on `train` and judged on `heldout`: a flexible fit
always explains some of its training noise, so only a held-out gain shows
structure. ``of_excess`` is a gain over the held-out MSE above the noise
floor; ``kind`` names the simplest family within 0.05 of the best (static,
time, dynamic), or "unstructured" below 20 % of the excess (2 % of the MSE).
"""

from __future__ import annotations

import textwrap
from typing import Any

import numpy as np

from . import residual_tests as rt
from ._verdict import FOLLOWS_DRIVE_P, drive_test_words

MIN_SAMPLES = 50  # fewer held-out (or training) samples: no description
MIN_BIN = 5  # samples a bin needs to be kept
UNSTRUCTURED_EXCESS = 0.2  # below this fraction of the excess recovered: "unstructured"
UNSTRUCTURED_MSE = 0.02  # ... or below this fraction of the held-out MSE
MARGIN = 0.05  # a more complex family must beat a simpler one by this much
SIGNIFICANT = 3.0  # standard errors the held-out MSE must exceed the floor by to have an excess
KEYS = ("t", "v_in", "w", "w_hat", "segment")
#: Each extension's family, in order of preference within its family (the first within MARGIN of the best).
FAMILY = {
    "static_drive": "static",
    "static_output_monotone": "static",
    "static_output_free": "static",
    "state_output": "static",
    "filter_drive": "dynamic",
    "rate": "dynamic",
    "filter_output": "dynamic",
    "time": "time",
    "periodic": "periodic",
    "state_linear": "dynamic",
    "filter_output_cube": "nonlinear_dynamic",
    "filter_output_square": "nonlinear_dynamic",
    "state_map": "nonlinear_dynamic",
    "drive_map": "drive_static",
}
#: A map of the drive through the dynamics (`_drive_map`) comes last, and `_verdict` weighs it only where
#: it recovers clearly more (`MARGIN`) than every other reading: it spans a linear filter of the drive and,
#: through a nonlinear simulation, more.
ORDER = ("static", "time", "periodic", "dynamic", "nonlinear_dynamic", "drive_static")
#: The linear filters' lags: a second's worth of samples, at least `MIN_LAGS` (at 1 Hz a second is one
#: lag, blind to a thermocouple's 8 s lag: a new user's chamber read "no simple structure … the best
#: linear filter 0 %") and at most `MAX_LAGS`.
MIN_LAGS, MAX_LAGS = 16, 60
#: A bin of the drive's periodogram this many times the median of its neighbours (`LINE_WINDOW` bins of
#: the unpadded spectrum each side) is a line of the drive: a random drive's bins are exponential, above
#: 30× their median about once in 10⁹.
LINE_PEAK, LINE_WINDOW = 30.0, 25
#: ... and at least this fraction of the strongest line's power (−40 dB: below it, a taper's leakage).
LINE_RANGE = 1e-4
#: Harmonics of a drive's line that count as the drive's (folded by the sampling), and the lines whose
#: sums and differences do (the strongest).
HARMONICS, INTERMODULATED = 10, 10
#: Bins of the unpadded spectrum within which a residual's line coincides with one the drive causes.
COINCIDE_BINS = 3
#: Two recordings' drives correlating above this, sample for sample, are one drive played twice.
SAME_DRIVE = 0.98
#: Share of the excess two recordings under one drive have in common up to which a remainder does not
#: repeat (a disturbance), and from which it does (a miss of the response); between, part of each.
NOT_REPEATED, REPEATED = 0.2, 0.6
#: A held-out stretch (a block's held-out part) holding at least this share of the held-out error above
#: the floor, and at least `CONCENTRATED_RATIO` times its share of the held-out samples, is where the
#: remainder lives: the summary names it, with what sets it apart from the training part where that shows.
CONCENTRATED = 0.5
CONCENTRATED_RATIO = 2.0
#: ... among at least this many held-out stretches (with fewer, a share says little of where).
CONCENTRATED_STRETCHES = 3
#: Mains frequencies (Hz) and the harmonics of them a line is read against.
MAINS, MAINS_HARMONICS = (50.0, 60.0), 3
#: The state feedback's maps are fitted for a simulation with at most this many states (the RC network's
#: 45 are stages of one diffusion, not quantities a user would name a force of).
MAX_STATES = 8
#: Knots of a state's map: hat functions on the training values' quantiles (a continuous, piecewise
#: linear map), and a step at zero where the state takes both signs (a Coulomb friction's).
KNOTS = 7


def _num(x, digits: int = 4):
    """A JSON float of `digits` significant digits (None for a non-finite value)."""
    return float(f"{float(x):.{digits}g}") if np.isfinite(x) else None


def _list(a) -> list:
    return [_num(x) for x in np.asarray(a, float).ravel()]


def _prepare(part: dict) -> dict:
    """Arrays of finite samples, with a run id that changes at every segment change or dropped sample."""
    a = {k: np.asarray(part[k], float).ravel() for k in KEYS}
    n = len(a["t"])
    if any(len(a[k]) != n for k in KEYS):
        raise ValueError("t, v_in, w, w_hat and segment must have equal lengths")
    ok = np.isfinite(np.column_stack([a[k] for k in KEYS])).all(axis=1) if n else np.zeros(0, bool)
    brk = np.r_[True, (a["segment"][1:] != a["segment"][:-1]) | ~ok[:-1]][:n]
    run = np.cumsum(brk)[ok]
    out = {k: a[k][ok] for k in KEYS}
    recording = part.get("recording")  # which recording each sample is from (one, when not given)
    out["recording"] = (np.zeros(n) if recording is None else np.asarray(recording, float).ravel())[ok]
    out["r"] = out["w"] - out["w_hat"]
    out["ok"] = ok  # which samples were kept: a state feedback's responses are filtered alike
    if part.get("spike") is not None:  # the noise floor's spikes and glitches (`_concentrated`)
        out["spike"] = np.asarray(part["spike"], bool).ravel()[ok]
    starts = np.flatnonzero(np.r_[True, run[1:] != run[:-1]]) if len(run) else np.zeros(0, int)
    out["pos"] = np.arange(len(run)) - np.repeat(starts, np.diff(np.r_[starts, len(run)]))
    return out


def _binned(x, y, max_bins: int):
    """Bin centres (mean x) and mean y: each distinct level its own bin when few, else quantile bins."""
    levels = np.unique(x)
    if len(levels) <= max_bins:
        b = np.searchsorted(levels, x)
    else:
        edges = np.unique(np.quantile(x, np.linspace(0, 1, max_bins + 1)[1:-1]))
        b = np.searchsorted(edges, x, side="right")
    count = np.bincount(b)
    keep = count >= MIN_BIN
    sx, sy = np.bincount(b, x)[keep], np.bincount(b, y)[keep]
    return sx / count[keep], sy / count[keep], count[keep].astype(float)


def _interp(x, centres, values):
    return np.interp(x, centres, values) if len(centres) else np.zeros_like(x)


def _lags(x, pos, lags: int):
    """Rows (indices) with a full window of `lags` past samples inside their own run, and the lag matrix."""
    rows = np.flatnonzero(pos >= lags)
    return rows, x[rows[:, None] - np.arange(lags + 1)[None, :]]


def _slope(x, y, extra=None):
    """Least-squares slope of y on x (with an intercept and optional extra columns); None when x is constant."""
    if len(x) < 20 or len(np.unique(x)) < 2:
        return None
    cols = [x, np.ones_like(x)] + ([] if extra is None else [extra])
    coef = np.linalg.lstsq(np.column_stack(cols), y, rcond=None)[0]
    return float(coef[0])


class _Judge:
    """Held-out gain of a prediction of r: fraction of the MSE removed, and of the excess over the floor."""

    def __init__(self, r, floor):
        self.r, self.mse = r, float(np.mean(r * r))
        self.floor = float(floor) if floor is not None and np.isfinite(floor) and floor > 0 else None
        self.excess, self.reason = None, None
        if self.floor is not None:
            excess = self.mse - self.floor
            if excess <= SIGNIFICANT * self.mse * np.sqrt(2.0 / len(r)):  # sd of a mean square of white noise
                self.reason = "the held-out MSE is within sampling error of the noise floor"
            else:
                self.excess = excess

    def __call__(self, pred) -> dict:
        removed = self.mse - float(np.mean((self.r - pred) ** 2))
        of_excess = None if self.excess is None else _num(min(max(removed / self.excess, 0.0), 1.0))
        return {"fraction": _num(removed / self.mse), "of_excess": of_excess}

    def score(self, part: dict) -> float:
        """What `part` (a `__call__`'s result) recovers: of the excess, or of the MSE where there is none."""
        return part["of_excess"] if self.excess is not None else max(part["fraction"] or 0.0, 0.0)


def _even_odd(fp, fn) -> dict | None:
    """The shares of a map's variance in its even and odd parts, from its values at +g and −g (None: constant)."""
    even, odd = np.var((fp + fn) / 2), np.mean(((fp - fn) / 2) ** 2)
    total = even + odd
    return {"even": _num(even / total), "odd": _num(odd / total)} if total > 0 else None


def _drive_shape(tr, centres, values) -> dict:
    """Even/odd split, one-sidedness, flat near zero and bend at the ends of the drive map."""
    v = tr["v_in"]
    out: dict[str, Any] = {}
    vmax = float(np.max(np.abs(v)))
    a = min(float(v.max()), float(-v.min()))
    if a <= 0.1 * vmax:
        why = "the drive never takes both signs" if a <= 0 else "the drive barely takes one of its signs"
        out["symmetry"] = out["one_sided"] = {"reason": why}
    else:
        g = np.linspace(0.0, a, 51)
        fp, fn = _interp(g, centres, values), _interp(-g, centres, values)
        out["symmetry"] = _even_odd(fp, fn) or {"reason": "the map of the drive is constant"}
        pos, neg = np.sqrt(np.mean((fp - fp[0]) ** 2)), np.sqrt(np.mean((fn - fn[0]) ** 2))
        ratio = max(pos, neg) / min(pos, neg) if min(pos, neg) > 0 else (np.inf if max(pos, neg) > 0 else 1.0)
        out["one_sided"] = {
            "positive": _num(pos),
            "negative": _num(neg),
            "ratio": _num(min(ratio, 1e6)),
            "side": ("positive" if pos > neg else "negative") if ratio >= 3 else None,
            "flag": bool(ratio >= 3),
        }
    near = np.abs(v) <= 0.25 * vmax
    ratios: dict[str, float | None] = {}
    for name, y in (("recording", tr["w"]), ("model", tr["w_hat"])):
        inner = _slope(v[near], y[near])
        outer = _slope(v[~near], y[~near], (v[~near] > 0).astype(float))
        ratios[name] = inner / outer if inner is not None and outer not in (None, 0.0) else None
    rec, mod = ratios["recording"], ratios["model"]
    if rec is None or mod is None or np.std(v[near]) < 0.05 * 0.25 * vmax:
        out["flat_near_zero"] = {"reason": "too few distinct drive levels near zero"}
    else:
        which = "recording" if rec < 0.4 and mod > 0.6 else "model" if mod < 0.4 and rec > 0.6 else None
        out["flat_near_zero"] = {
            "recording": _num(rec),
            "model": _num(mod),
            "which": which,
            "flag": which is not None,
        }
    gain = _slope(v, tr["w_hat"])
    bend: dict[str, float | None] = {}
    for side, s in (("positive", 1.0), ("negative", -1.0)):
        x = s * v
        top = float(x.max()) if len(x) else 0.0
        mid, end = (x > top / 3) & (x <= 2 * top / 3), x > 2 * top / 3
        sm, se = _slope(v[mid], tr["r"][mid]), _slope(v[end], tr["r"][end])
        bend[side] = _num((se - sm) / gain) if top > 0 and None not in (sm, se) and gain else None
    found = [b for b in bend.values() if b is not None]
    out["bend_at_ends"] = (
        {**bend, "flag": bool(max(abs(b) for b in found) > 0.25)}
        if found
        else {"reason": "too few distinct drive levels at the ends"}
    )
    return out


#: A step in time (`_time_step`) is sought at this many times spread over the training span, none
#: within `STEP_EDGE` of its ends. It stands for the time reading where it recovers `MARGIN` more than the
#: cubic and than its own trends without the change, and at least `STEP_SHARE` of what it is judged on: a
#: slow coloured disturbance wanders in steps too (tests/test_remainder.py's, 3× the floor's σ: a "change"
#: recovering 24 %), a sensor re-zeroed or a gain that changed recovers 89-100 % (`-k one_time`).
STEP_TIMES, STEP_EDGE, STEP_SHARE = 60, 0.1, 0.5


def _gain_trend(tr, ho, judge, scaled) -> dict:
    """A gain that moves over the record: a cubic in time of w's offset beside one of the model's gain
    (its change alone: x, x², x³ times ŵ; a constant gain is a static map), fitted on the training
    residual and judged on the held-out part (an amplifier or a sensor warming, a strip that dries).

    With the offset's cubic alone, a gain 1 + 0.3 sin(2πt/T) over 0.8 of a period of the record read
    "no simple structure … not predictable from … time" (`tests/test_remainder.py -k gain_that`).
    """

    def basis(part):
        x = scaled(part["t"])
        powers = np.column_stack([x**k for k in range(4)])
        return np.column_stack([powers, powers[:, 1:] * part["w_hat"][:, None]])

    coef = np.linalg.lstsq(basis(tr), tr["r"], rcond=None)[0]
    return {**judge(basis(ho) @ coef), "form": "gain", "degree": 3}


def _time_step(tr, ho, judge, scaled) -> dict | None:
    """A change at one time T beside a smooth trend: from T on, w offset by a, the model's output scaled by 1 + b.

    Least squares of the training residual on a cubic in time, ŵ and ŵ·t (smooth
    trends of the offset and the gain) and [1(t > T), 1(t > T)·ŵ] at each candidate T,
    the T of the least training error kept and judged on the held-out part (a sensor
    re-zeroed or bumped, a clamp that slipped, a gain that changed during the record).
    The trends take what a smooth drift, or an effect fitted to the step (a baseline
    drift, a drift of the gain), leaves; ``without`` is the same fit without the change.
    `scaled`: time onto [−1, 1] over the training span, constant beyond it (the cubic's).
    """

    def smooth(part):  # a trend, and a gain's
        x = scaled(part["t"])
        return np.column_stack([x**0, x, x**2, x**3, part["w_hat"], x * part["w_hat"]])

    def with_change(trends, part, at):
        after = (part["t"] > at).astype(float)
        return np.column_stack([trends, after, after * part["w_hat"]])

    trends_tr, trends_ho = smooth(tr), smooth(ho)
    t0, t1 = float(tr["t"].min()), float(tr["t"].max())
    best = None
    for at in np.linspace(t0 + STEP_EDGE * (t1 - t0), t1 - STEP_EDGE * (t1 - t0), STEP_TIMES):
        after = int(np.sum(tr["t"] > at))
        if min(after, len(tr["t"]) - after) < MIN_SAMPLES:
            continue
        x = with_change(trends_tr, tr, at)
        coef = np.linalg.lstsq(x, tr["r"], rcond=None)[0]
        sse = float(np.sum((tr["r"] - x @ coef) ** 2))
        if best is None or sse < best[0]:
            best = (sse, float(at), coef)
    if best is None:
        return None
    _, at, coef = best
    # Every time between the training samples either side fits them alike: the change is put midway
    # (a held-out block often spans it).
    at = 0.5 * (float(tr["t"][tr["t"] <= at].max()) + float(tr["t"][tr["t"] > at].min()))
    offset, gain = coef[-2], coef[-1]
    scaled_ms = float(np.mean((gain * tr["w_hat"][tr["t"] > at]) ** 2))
    return {
        **judge(with_change(trends_ho, ho, at) @ coef),
        "form": "step",
        "at_s": _num(at),
        "offset": _num(offset),
        "gain_change": _num(gain),
        # the offset's share of the change's mean square after T (the rest is the scaling's)
        "offset_share": _num(offset**2 / (offset**2 + scaled_ms)) if offset**2 + scaled_ms > 0 else None,
        # the same trends without the change: what the change itself adds
        "without": judge(trends_ho @ np.linalg.lstsq(trends_tr, tr["r"], rcond=None)[0]),
    }


#: Pieces of the wander (`_time_wander`) that a change at one time must beat: a random walk of w's
#: baseline is followed by a change at one time too (a probe's thermal record, a walk over 1.2 °C: "from
#: t = 21.67 s on, w offset by −3.9 °C", 83 %), but by straight pieces between several times better.
WANDER_PIECES = 8


def _time_wander(tr, ho, judge, scaled, offset: bool = True) -> dict:
    """A wander in time: a trend of w's offset made of `WANDER_PIECES` straight pieces over the training
    span (continuous, constant beyond it), beside ŵ and ŵ·t (`_time_step`'s gain trends), fitted on the
    training residual and judged on the held-out part. `offset` False: a trend of the model's gain made
    of such pieces instead (a gain that wanders, which an additive disturbance, not scaling with the
    model's output, does not follow)."""
    knots = np.linspace(-1.0, 1.0, WANDER_PIECES + 1)
    spacing = knots[1] - knots[0]

    def basis(part):
        x = scaled(part["t"])
        hats = np.clip(1.0 - np.abs(x[:, None] - knots[None, :]) / spacing, 0.0, None)
        if offset:  # beside the gain's trend (`_time_step`'s)
            return np.column_stack([hats, part["w_hat"], x * part["w_hat"]])
        return hats * part["w_hat"][:, None]

    coef = np.linalg.lstsq(basis(tr), tr["r"], rcond=None)[0]
    return {
        **judge(basis(ho) @ coef),
        "form": "wander",
        "pieces": WANDER_PIECES,
        **({} if offset else {"gain_only": True}),
    }


#: A slope of w on ŵ below this fraction of the slope beside it reads as flat (`_output_shape`).
FLAT_SLOPE = 0.4


def _output_shape(w_hat, w) -> dict:
    """Where the recording's w rises with the model's output ŵ, and where it stays flat.

    ``flat_middle``: w's slope on ŵ within a quarter of ŵ's half-range of its middle,
    against its slope beyond (a side's offset apart), below `FLAT_SLOPE`: a dead band
    (a sensor's, or play). ``levels_off``: each side's slope over the outer third of
    ŵ's half-range against the third before it, below `FLAT_SLOPE`: w stops at a level
    there (a sensor's full scale, an ADC's range). Slopes of the samples themselves,
    as `_drive_shape`'s.
    """
    lo, hi = float(np.min(w_hat)), float(np.max(w_hat))
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    if not half > 0:
        return {"reason": "the model's output is constant"}
    x = w_hat - mid
    near = np.abs(x) <= 0.25 * half
    inner = _slope(x[near], w[near])
    outer = _slope(x[~near], w[~near], (x[~near] > 0).astype(float))
    ratio = inner / outer if inner is not None and outer else None
    out: dict[str, Any] = {
        "flat_middle": {
            "ratio": None if ratio is None else _num(ratio),  # None: too few samples in the middle or beyond
            "flag": bool(ratio is not None and ratio < FLAT_SLOPE),
        }
    }
    ends: dict[str, Any] = {}
    for side, sign in (("top", 1.0), ("bottom", -1.0)):
        y = sign * x
        band, end = (y > half / 3) & (y <= 2 * half / 3), y > 2 * half / 3
        before, last = _slope(x[band], w[band]), _slope(x[end], w[end])
        ends[side] = _num(last / before) if before and last is not None else None
    off = [side for side, r in ends.items() if r is not None and r < FLAT_SLOPE]
    out["levels_off"] = {**ends, "sides": off, "flag": bool(off)}
    return out


def _ridge(xc, yc):
    """Ridge least squares of centred `yc` on the centred columns `xc`, the ridge 1e-3 of the mean diagonal.

    einsum, not BLAS: a multi-threaded BLAS is many times slower on a busy machine.
    """
    gram = np.einsum("ni,nj->ij", xc, xc)
    ridge = 1e-3 * np.trace(gram) / max(gram.shape[0], 1) + 1e-300
    return np.linalg.solve(gram + ridge * np.eye(gram.shape[0]), np.einsum("ni,n->i", xc, yc))


def _difference_basis(width: int, blocks: int) -> np.ndarray:
    """T with x·T = [level, first differences] of each block of `width` lags: x_0, x_0 − x_1, x_1 − x_2, …"""
    one = np.eye(width, k=1) - np.eye(width)  # column j ≥ 1: x_{j−1} − x_j
    one[0, 0] = 1.0  # column 0: x_0, the level
    return np.kron(np.eye(blocks), one)


def _filter(tr, ho, key, lags, rate, judge) -> dict:
    """Ridge FIR of r on lags 0..`lags` of `key` (or of several keys together), within runs.

    Held-out gain and the frequency response of the first key's filter.
    """
    keys = (key,) if isinstance(key, str) else tuple(key)
    lagged = [_lags(tr[k], tr["pos"], lags) for k in keys]
    rows, x = lagged[0][0], np.hstack([m for _, m in lagged])
    hlagged = [_lags(ho[k], ho["pos"], lags) for k in keys]
    hrows, hx = hlagged[0][0], np.hstack([m for _, m in hlagged])
    if len(rows) < 4 * x.shape[1] or len(hrows) < MIN_SAMPLES:
        return {"reason": f"too few samples with {lags} past samples inside a segment"}
    # The ridge acts on each key's level and its successive differences, each scaled to unit spread,
    # not on its raw lags: the lags of a smooth signal (a slow plant's ŵ, 200 samples to settle) are
    # near copies of one another, and a ridge on them keeps their sum and drops their differences,
    # where a lag or a rate lives (an 8 s sensor lag at 1 Hz: r = −0.58·corr with dŵ/dt, and the
    # filter of the raw lags recovered −5 % held out). The same span: h = T·g, the lags' filter.
    to_lags = _difference_basis(lags + 1, len(keys))
    xm, ym = x.mean(axis=0), tr["r"][rows].mean()
    d = (x - xm) @ to_lags
    scale = d.std(axis=0)
    scale[scale == 0] = 1.0
    g = _ridge(d / scale, tr["r"][rows] - ym)
    h = to_lags @ (g / scale)
    pred = np.zeros_like(ho["r"])
    pred[hrows] = np.einsum("ni,i->n", hx - xm, h) + ym
    f = np.linspace(0.0, rate / 2, 100)
    resp = np.exp(-2j * np.pi * np.outer(f / rate, np.arange(lags + 1))) @ h[: lags + 1]
    db = 20 * np.log10(np.abs(resp) + 1e-300)
    return dict(
        judge(pred),
        lags=int(lags),
        fit_rows=int(len(rows)),
        response={
            "f_hz": _list(f),
            "magnitude_db": _list(np.maximum(db, db.max() - 120.0)),
            "phase_deg": _list(np.degrees(np.unwrap(np.angle(resp)))),
        },
    )


def _places(tr: dict, ho: dict, rate: float) -> dict[int, tuple[float, int]]:
    """Each recording's (first time, length in samples), over both parts: where its samples sit."""
    t, rec = np.concatenate([tr["t"], ho["t"]]), np.concatenate([tr["recording"], ho["recording"]])
    out = {}
    for i in np.unique(rec):
        ti = t[rec == i]
        out[int(i)] = (float(ti.min()), int(round((ti.max() - ti.min()) * rate)) + 1)
    return out


def _grids(parts, key: str, places: dict, rate: float, n: int) -> np.ndarray:
    """`key` of `parts` laid on each recording's sample grid (rows, in `places`' order; length `n`, NaN
    where no part has a sample)."""
    out = np.full((len(places), n), np.nan)
    for row, (i, (start, _)) in enumerate(places.items()):
        for part in parts:
            m = part["recording"] == i
            k = np.round((part["t"][m] - start) * rate).astype(int)
            keep = (k >= 0) & (k < n)
            out[row, k[keep]] = part[key][m][keep]
    return out


def _sinusoid_columns(part: dict, m, f: float) -> np.ndarray:
    phase = 2 * np.pi * f * part["t"][m]
    return np.column_stack([np.ones(len(phase)), np.cos(phase), np.sin(phase)])


def _sinusoid_fit(part: dict, f: float) -> dict:
    """Per recording, the least-squares mean, cosine and sine at `f` of `part`'s r."""
    return {
        i: np.linalg.lstsq(_sinusoid_columns(part, m, f), part["r"][m], rcond=None)[0]
        for i in np.unique(part["recording"])
        for m in [part["recording"] == i]
    }


def _sinusoid_at(part: dict, f: float, coef: dict) -> np.ndarray:
    """`_sinusoid_fit`'s prediction on `part`: zero in a recording it had no samples of (no phase to carry)."""
    out = np.zeros(len(part["r"]))
    for i, c in coef.items():
        m = part["recording"] == i
        out[m] = _sinusoid_columns(part, m, f) @ c
    return out


def _drive_lines(drive: np.ndarray, rate: float, n_fft: int, pad: int, near: float) -> np.ndarray:
    """Frequencies (Hz) of the drive's lines, strongest first.

    `drive`: each recording's drive on its sample grid (`_grids`), held out or
    not: its periodogram is taken over each whole recording, Hann-tapered. A
    line is a local maximum `LINE_PEAK` times the median of its neighbours
    (`LINE_WINDOW` bins of the unpadded spectrum each side: `pad` of the grid's
    to one) and within `LINE_RANGE` of the strongest; a maximum within `near`
    (Hz) of a stronger line is that line's leakage.
    """
    import scipy.ndimage

    _, power = rt.periodogram(drive, rate, n_fft, hann=True)
    local = scipy.ndimage.median_filter(power, size=2 * LINE_WINDOW * pad + 1, mode="nearest")
    inner = power[1:-1]
    peak = 1 + np.flatnonzero(
        (inner >= power[:-2])
        & (inner >= power[2:])
        & (inner > LINE_PEAK * local[1:-1])
        & (inner > LINE_RANGE * power.max())
    )
    kept: list[float] = []
    for f in peak[np.argsort(power[peak])[::-1]] * rate / n_fft:
        if all(abs(f - g) > near for g in kept):
            kept.append(float(f))
    return np.asarray(kept)


def _fundamental(lines: np.ndarray, near: float) -> float | None:
    """The period's frequency of a drive whose lines all sit on one grid (a multisine, a square wave):
    the lowest line or its half, third or quarter, where every line lies within `near` of a multiple."""
    top = lines[: INTERMODULATED * 2]
    if len(top) < 2:
        return None
    for j in range(1, 5):
        f0 = float(top.min()) / j
        order = np.round(top / f0)
        if np.all(np.abs(top - order * f0) <= near):
            return float(np.median(top / order))
    return None


def _drive_made(f: float, lines: np.ndarray, rate: float, near: float) -> str | None:
    """Why a residual's line at `f` is the drive's response, or None: it is one of the drive's lines, on
    the grid of a periodic drive's harmonics, a harmonic of a strong line, or a sum or difference of two."""
    if not len(lines):
        return None
    hit = lambda g: bool(np.any(np.abs(_folded(g, rate) - f) <= near))
    if hit(lines):
        return f"the drive has a line there ({lines[np.argmin(np.abs(_folded(lines, rate) - f))]:.4g} Hz)"
    f0 = _fundamental(lines, near)
    if f0 is not None and hit(f0 * np.arange(1, int(np.ceil(rate / f0)) * 2 + 2)):
        return f"the drive is periodic ({f0:.4g} Hz, its lines on that grid) and the line is one of its harmonics"
    strong = lines[:INTERMODULATED]
    for fl in strong:
        for k in range(2, HARMONICS + 1):
            if hit(k * fl):
                return f"the drive has a line at {fl:.4g} Hz, whose harmonic {k} lies there"
    for i, a in enumerate(strong):
        for b in strong[i + 1 :]:
            if hit(a + b) or hit(a - b):
                return f"the drive's lines at {a:.4g} and {b:.4g} Hz mix there"
    return None


def _folded(f, rate: float):
    """Frequencies as sampling at `rate` reads them, in [0, rate/2]."""
    return np.abs((np.asarray(f, float) + rate / 2) % rate - rate / 2)


def _periodic(tr, ho, places: dict, rate: float, judge) -> dict:
    """A sinusoid at the training residual's strongest line, judged held out (module docstring: periodic)."""
    n = max(length for _, length in places.values())  # the longest recording's samples
    span = (n - 1) / rate
    if span <= 0 or rt.MIN_CYCLES / span >= rate / 2:
        return {
            "reason": f"the recordings are too short for {rt.MIN_CYCLES} cycles of a line below the Nyquist frequency"
        }
    pad = rt.zero_padding(n)
    n_fft = pad * n
    freq, power = rt.periodogram(_grids([tr], "r", places, rate, n), rate, n_fft)
    low = rt.MIN_CYCLES / span
    peak = rt.strongest_line(freq, power, low, rate / 2 * (1 - 1.0 / n))
    if peak is None:
        return {"reason": "no frequency between the trends and the Nyquist frequency"}
    if np.max(power[freq < low], initial=0.0) >= power[np.searchsorted(freq, peak)]:
        # The band's largest bin is a line only where it stands above the trends' band below it: a spectrum
        # that keeps rising there is a trend's or a slow response's (a creep of τ = 3 s under a 1 s PRBS
        # read as a 0.086 Hz "line" with 3.4 cycles in 40 s, `tests/test_creep.py`).
        return {
            "reason": f"the residual's power rises below {low:.3g} Hz (fewer than {rt.MIN_CYCLES} cycles per "
            "recording): a trend or a slow response, not a line"
        }
    step = rate / n_fft
    fine = np.linspace(peak - step, peak + step, 21)
    # the frequency that the sinusoid fits best on training, near the padded spectrum's peak
    rss = [float(np.sum((tr["r"] - _sinusoid_at(tr, f, _sinusoid_fit(tr, f))) ** 2)) for f in fine]
    f = float(fine[int(np.argmin(rss))])
    coef = _sinusoid_fit(tr, f)
    amplitude = float(np.sqrt(np.mean([c[1] ** 2 + c[2] ** 2 for c in coef.values()]) / 2.0))
    out: dict[str, Any] = {"frequency_hz": _num(f), "amplitude_rms": _num(amplitude)}
    near = COINCIDE_BINS * rate / n
    why = _drive_made(
        f, _drive_lines(_grids([tr, ho], "v_in", places, rate, n), rate, n_fft, pad, near), rate, near
    )
    if why:
        return dict(out, reason=f"the residual's line at {f:.4g} Hz is the drive's response: {why}")
    out.update(judge(_sinusoid_at(ho, f, coef)))
    mains = [
        (m, k) for m in MAINS for k in range(1, MAINS_HARMONICS + 1) if abs(_folded(k * m, rate) - f) <= near
    ]
    if mains:
        m, k = mains[0]
        what = f"{m:g} Hz mains" if k == 1 else f"harmonic {k} of {m:g} Hz mains ({k * m:g} Hz)"
        out["mains"] = f"{what}, which sampling at {rate:g} Hz reads at {f:.4g} Hz"
    return out


def state_basis(x) -> dict:
    """The functions a state's map is made of, from its training values `x`: knots and whether to step at zero.

    Hat functions on `KNOTS` quantiles of `x` (a continuous, piecewise linear
    map, held flat beyond the training range) and, where the state takes both
    signs on at least 5 % of the samples each, a step at zero (the inner knot
    nearest zero moved there, so that no hat makes a jump of its own near it).
    Also the centre (the mean) its linear column is taken about.
    """
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    if not len(x):
        return {"knots": np.zeros(0), "step": False, "centre": 0.0}
    knots = np.quantile(x, np.linspace(0.0, 1.0, KNOTS))
    both = bool(min(np.mean(x > 0), np.mean(x < 0)) >= 0.05)
    if both:  # a knot at zero: the hats bend there, and only the step jumps
        knots[1 + np.argmin(np.abs(knots[1:-1]))] = 0.0
    return {"knots": np.unique(knots), "step": both, "centre": float(np.mean(x))}


#: The columns of each state's map, in `basis_forces`' order: as many whatever the state's values, so
#: that the responses' program (`force_responses`) has one shape for every recording of a length.
ROLES = ("linear", *(f"hat_{j}" for j in range(KNOTS)), "step", "bend", "cube")


def basis_forces(basis: dict, x) -> np.ndarray:
    """The columns of a state's map on its values `x`, one row each, in the order of `ROLES`.

    ``linear`` (x less its training centre), ``hat_j`` (piecewise linear, 1 at
    knot j, 0 at its neighbours), ``step`` (1 where x > 0): the free map; and
    the forms it is read against (`FORMS`): ``bend`` (x·|x|) and ``cube`` (x³),
    x scaled by its largest training |x|. Rows of zeros where a column has
    nothing to say: hats beyond the distinct knots (a state of few values),
    the step of a state that keeps its sign, all but the linear column of a
    state whose training values are constant.
    """
    x = np.asarray(x, float)
    knots = basis["knots"]
    rows = np.zeros((len(ROLES), x.size))
    rows[0] = x - basis["centre"]
    if len(knots) >= 2:
        eye = np.eye(len(knots))
        for j in range(len(knots)):
            rows[1 + j] = np.interp(x, knots, eye[j])
        if basis["step"]:
            rows[1 + KNOTS] = x > 0
        z = x / max(abs(knots[0]), abs(knots[-1]))
        rows[2 + KNOTS], rows[3 + KNOTS] = z * np.abs(z), z**3
    return rows


def _least_squares(train_cols, y, held_cols):
    """Ridge least squares of `y` on the training columns (and an intercept); (held-out prediction, coefficients).

    The columns are scaled to unit variance first; the ridge (`_ridge`, as
    `_filter`'s) keeps collinear columns (a map's hats span
    its linear column; the response to a constant force is nearly the
    readout's offset) from cancelling on training data and blowing up held
    out (1e-9 took a map of the oscillator's position to a held-out fraction of
    −10 where 1e-3 gives +0.03). The coefficients are of the columns as given.
    """
    x = np.column_stack(train_cols)
    mean = x.mean(axis=0)
    scale = x.std(axis=0)
    scale[scale == 0] = 1.0
    coef = _ridge((x - mean) / scale, y - y.mean()) / scale
    intercept = y.mean() - mean @ coef
    return np.column_stack(held_cols) @ coef + intercept, coef


def _map_shape(grid, force) -> dict:
    """The odd and even parts of a state's map, on a grid symmetric about zero (none where it barely crosses it)."""
    lo, hi = float(grid[0]), float(grid[-1])
    a = min(hi, -lo)
    if a <= 0.1 * max(abs(lo), abs(hi)):
        return {}
    g = np.linspace(0.0, a, 51)
    split = _even_odd(np.interp(g, grid, force), np.interp(-g, grid, force))
    return {"symmetry": split} if split else {}


#: A form names a map when it adds, held out, this share of what the free map adds to the linear
#: feedback of the states: a fit linearised along the recording leaves the free map a little more to
#: take up (a 0.12 V Coulomb friction on an oscillator: the linear feedback 4 % of the excess, the step
#: 74 %, the free map 82 %).
FORM_SHARE = 0.85
#: ... and this much more of it than each other form, where the free map recovers at least this much
#: of the excess (or of the held-out error, with no floor).
FORM_LEAD = MARGIN
FORM_MIN = 0.5
#: Forms named only where they oppose the drive: a friction or a drag is taken off the drive with the
#: sign of the state it acts on (a state the drive pushes up). A step or a bend of the other sign is the
#: fitted model's own damping having overshot (a pendulum's Coulomb friction, its damping fitted at twice
#: the truth: the map falls away from zero as −x·|x| does), not a drag.
OPPOSING = ("step", "bend")
#: The simple forms a state's map is read against (each its own column beside the linear ones), and
#: how the report words a map that one of them explains.
FORMS = {
    "step": "a step of {size} at zero (±{half}), as a Coulomb friction has",
    "bend": "growing as x·|x| away from zero ({size} at the largest |x|), as a quadratic drag does",
    "cube": "growing as x³ ({size} at the largest |x|), as a cubic spring does",
    "grow": "growing faster than linearly away from zero ({size} at the largest |x|), as a drag or a "
    "stiffening spring does",
}


def _read_form(forms: dict) -> str | None:
    """The form (`FORMS`) a state's map reads as, from each form's ``share``, or None.

    One form leads: at least `FORM_SHARE`, `FORM_LEAD` more than each other,
    and (`OPPOSING`) of the sign that opposes the drive. A bend and a cube
    alike (neither leads the other, both lead the step, both positive): a map
    that grows faster than linearly (``grow``), which a recording of one state
    rarely tells apart.
    """

    def share(k):
        return forms[k]["share"] or 0.0 if k in forms else -np.inf

    def leads(k, others):
        return share(k) >= FORM_SHARE and all(share(k) >= share(o) + FORM_LEAD for o in others)

    def opposes(k):  # (and has a size to give: a non-finite one is no reading)
        size = forms[k]["size"]
        return size is not None and (k not in OPPOSING or size > 0)

    for k in forms:
        if leads(k, [o for o in forms if o != k]):
            return k if opposes(k) else None
    if "bend" in forms and "cube" in forms and leads("bend", ["step"]) and leads("cube", ["step"]):
        positive = (forms["bend"]["size"] or 0.0) > 0 and (forms["cube"]["size"] or 0.0) > 0
        return "grow" if positive else None
    return None


#: Another state whose training trajectory correlates with the named one's this closely is named beside it.
ALIKE = 0.9


def _alike(values: dict, best: str) -> dict:
    """The states whose training values correlate with `best`'s by |r| ≥ `ALIKE`: {name: r}.

    Two states that move together (a motor's and its load's speeds on a stiff
    shaft) give maps that fit alike: the best of them is not the answer alone.
    """
    if best not in values:
        return {}
    x = np.asarray(values[best], float)
    out = {}
    for name, other in values.items():
        y = np.asarray(other, float)
        if name == best or y.shape != x.shape or np.std(x) == 0 or np.std(y) == 0:
            continue
        r = float(np.corrcoef(x, y)[0, 1])
        if abs(r) >= ALIKE:
            out[name] = _num(r, 3)
    return out


def _maps(feedback: dict):
    """(state, its basis, its columns' indices by role) of each state that varies on the training part."""
    cols = feedback["columns"]
    for name in feedback["states"]:
        basis = feedback["bases"][name]
        if len(basis["knots"]) < 2:  # constant on the training part: no map to fit
            continue
        yield name, basis, {cols[j][1]: j for j in range(len(cols)) if cols[j][0] == name}


def _drive_map(tr, ho, drive_map: dict, judge) -> dict:
    """A static map of the drive level before the dynamics, through the final model linearised along the recording.

    `drive_map` (from `hybrid.discovery._unexplained.drive_map_signals`): the model's response to each
    column of a map of the drive (its hats and, for a two-signed drive, a step at zero), on the training
    and held-out samples. With the output's derivatives in the simulation's parameters (the simulation
    retuned, to first order) the columns are fitted to the residual: a clip, a dead zone or a pump's
    curve on the drive, whatever the dynamics after it; the hats span a change of the drive's gain. The
    map u ↦ u + Δ(u) is reported on a grid over the drive's training range, in the drive's unit
    (Δ scaled by the readout's gain). ``clip`` (`_drive_clip`): a clip of the drive read into the map,
    its ends also in ``levels_off``.
    """
    r_tr, r_ho = drive_map["train"][:, tr["ok"]], drive_map["heldout"][:, ho["ok"]]
    retune_tr, retune_ho = drive_map["retune_train"][:, tr["ok"]], drive_map["retune_heldout"][:, ho["ok"]]
    if not all(np.all(np.isfinite(x)) for x in (r_tr, r_ho, retune_tr, retune_ho)):
        return {"reason": "the model's response to a change of its drive is not finite on this recording"}
    basis = drive_map["basis"]
    knots = basis["knots"]
    if len(knots) < 2:
        return {"reason": "the drive is constant on the training part"}
    # No column of ŵ (the readout's gain): the hats span a gain of the drive, and with one beside them
    # the map would be known only up to a tilt, a level it stops at not told from a slope.
    pred, coef = _least_squares([*r_tr, *retune_tr], tr["r"], [*r_ho, *retune_ho])
    gain = drive_map.get("gain")
    scale = 1.0 / gain if gain else 1.0
    grid = np.linspace(knots[0], knots[-1], 101)
    rows = basis_forces(basis, grid)
    change = scale * sum(b * rows[ROLES.index(role)] for role, b in zip(drive_map["roles"], coef))
    mapped = grid + change - (np.interp(0.0, grid, change) if knots[0] < 0 < knots[-1] else change[0])
    result = judge(pred)
    clip = _drive_clip(tr, ho, drive_map, judge, result, scale)
    levels_off = clip["ends"] if clip else []
    if clip and judge.score(clip["recovered"]) > judge.score(result):
        result = clip["recovered"]  # a sharp level the hats, 7 quantiles apart, blur: the map is the clip
    return dict(
        result,
        unit=drive_map.get("drive_unit", ""),
        curve={"v": _list(grid), "mapped": _list(mapped)},
        clip=clip,
        levels_off=levels_off,
    )


#: A clip of the drive is the drive map's form where it takes this share of what the free map adds to the
#: simulation retuned (as `FORM_SHARE` for a state's map), with the sign of a clip.
CLIP_SHARE = 0.85


def _drive_clip(tr, ho, drive_map: dict, judge, free: dict, scale: float) -> dict | None:
    """A clip of the drive at one end, or both, read into the drive map where it takes most of what it adds.

    Each clip column of `drive_map` (``clips``: a level at a quantile of the drive, top or bottom) is
    fitted alone beside ŵ and the simulation's retuned parameters; the best of each end, then both
    together. Of (top, bottom, both) those that take `CLIP_SHARE` of what the free map adds over those
    columns alone, each with a clip's sign (the drive cut, not stretched, beyond its level), the
    simplest within `MARGIN` of the best is returned: its ends, levels (drive's unit), share and what it
    recovers (``recovered``: the drive map's score where it beats the free map's); None where none does.
    """
    ok_tr, ok_ho = tr["ok"], ho["ok"]
    base_tr = [tr["w_hat"], *drive_map["retune_train"][:, ok_tr]]
    base_ho = [ho["w_hat"], *drive_map["retune_heldout"][:, ok_ho]]
    c_tr, c_ho = drive_map["clip_train"][:, ok_tr], drive_map["clip_heldout"][:, ok_ho]
    if not (np.all(np.isfinite(c_tr)) and np.all(np.isfinite(c_ho))):
        return None
    score = judge.score

    def fitted(columns):  # (what it recovers, its score, each clip's size: > 0 where it cuts)
        pred, coef = _least_squares(
            base_tr + [c_tr[j] for j in columns], tr["r"], base_ho + [c_ho[j] for j in columns]
        )
        part = judge(pred)
        return part, score(part), coef[len(base_tr) :] * scale

    floor = fitted([])[1]
    room = score(free) - floor
    if room < MARGIN:
        return None
    clips = drive_map["clips"]
    best = {}
    for end in ("top", "bottom"):
        tried = [(fitted([j]), j) for j, (e, _) in enumerate(clips) if e == end]
        tried = [(got, j) for (_, got, size), j in tried if size[0] > 0]  # cut, not stretched
        if tried:
            best[end] = max(tried)[1]
    passing = []
    for ends in (("top",), ("bottom",), ("top", "bottom")):
        if all(end in best for end in ends):
            part, got, sizes = fitted([best[end] for end in ends])
            if (got - floor) / room >= CLIP_SHARE and np.all(sizes > 0):
                passing.append((got, ends, part))
    if not passing:
        return None
    top = max(got for got, *_ in passing)
    got, ends, part = next(item for item in passing if item[0] >= top - MARGIN)  # the simplest near the best
    return {
        "ends": list(ends),
        "levels": {end: _num(clips[best[end]][1]) for end in ends},
        "share": _num((got - floor) / room),
        "recovered": part,
    }


def _state_feedback(tr, ho, feedback: dict, judge) -> dict:
    """A static map of each state fed back into the dynamics' drive, through their linearised response.

    `feedback` (from `hybrid.discovery._unexplained.feedback_signals`): per
    column (``columns``: (state, role)) its response on the training and the
    held-out samples (``train``, ``heldout``: rows), the states' bases, units,
    the drive's unit and the readout's gain. A force φ(x) taken off the drive
    moves the output by the response to φ: r ≈ gain · Σ βⱼ Rⱼ with φ = Σ βⱼ·bⱼ.
    ``linear``: the linear columns of every state and ŵ (a force proportional
    to the states, and the readout's gain retuned); each state's free map adds
    its hats and step to those, and each of its `FORMS` adds that one column
    alone. Where the free map carries `FORM_MIN` of the excess, a form that
    adds `FORM_SHARE` of what the free map adds to the linear feedback held
    out (its ``share``), `FORM_LEAD` more than each other form, and of the
    sign that opposes the drive (`OPPOSING`), is the map's ``form`` (its size
    in the drive's unit: a step's jump, a bend's or cube's value at the
    largest |x|): a recording
    rarely pins where a velocity's map rises between the knots next to zero
    (it crosses zero quickly), but a step's column fitted alone can be judged.
    The free map is reported in the drive's unit on a grid over the state's
    training range, as the force that would be taken off the drive.
    """
    cols = feedback["columns"]
    r_tr, r_ho = feedback["train"][:, tr["ok"]], feedback["heldout"][:, ho["ok"]]
    if not np.all(np.isfinite(r_tr)) or not np.all(np.isfinite(r_ho)):
        return {"reason": "the dynamics' response to a force on a state is not finite on this recording"}
    linear = [j for j, (_, role) in enumerate(cols) if role == "linear"]
    base_tr, base_ho = [tr["w_hat"]] + [r_tr[j] for j in linear], [ho["w_hat"]] + [r_ho[j] for j in linear]
    pred, _ = _least_squares(base_tr, tr["r"], base_ho)
    out: dict[str, Any] = {"linear": judge(pred), "states": {}, "into": feedback.get("into", "its drive")}
    gain = feedback.get("gain")
    scale = 1.0 / gain if gain else 1.0

    score = judge.score

    def fitted(columns):
        pred, coef = _least_squares(
            base_tr + [r_tr[j] for j in columns], tr["r"], base_ho + [r_ho[j] for j in columns]
        )
        return judge(pred), coef[len(base_tr) :]

    for name, basis, own in _maps(feedback):
        knots = basis["knots"]
        hats = [own[f"hat_{k}"] for k in range(len(knots))]
        free = hats + ([own["step"]] if basis["step"] else [])
        result, coef = fitted(free)
        grid = np.linspace(knots[0], knots[-1], 101)
        rows = basis_forces(basis, grid)
        beta = {cols[j][1]: b for j, b in zip(free, coef)}
        smooth = scale * sum(
            beta[role] * row for role, row in zip(ROLES, rows) if role.startswith("hat_") and role in beta
        )
        step = scale * beta.get("step", 0.0)
        # A constant force moves the output as the readout's offset does: the map is fixed at zero
        # midway through its step there (a Coulomb friction's ±F), or at its lowest value.
        if knots[0] < 0 < knots[-1]:
            force = smooth + step * (grid > 0) - np.interp(0.0, grid, smooth) - step / 2
        else:
            force = smooth - smooth[0]
        forms = {}
        for role in ("step", "bend", "cube") if basis["step"] else ("bend", "cube"):
            part, (size,) = fitted([own[role]])
            forms[role] = dict(part, size=_num(scale * size))
        # What each form adds to the linear feedback, as a share of what the free map adds.
        room = score(result) - score(out["linear"])
        for part in forms.values():
            part["share"] = _num((score(part) - score(out["linear"])) / room) if room > 0 else None
        # A form is read into a map that carries most of the remainder, never into a partial account (a
        # sensor's play on the output dwells at each reversal as a friction does: a velocity's step takes
        # up part of an effect that is not inside at all).
        carries = score(result) >= FORM_MIN
        chosen = _read_form(forms) if room >= MARGIN and carries else None
        out["states"][name] = dict(
            result,
            unit=feedback["units"].get(name, ""),
            curve={"x": _list(grid), "force": _list(force)},
            force_unit=feedback.get("force_unit", feedback["drive_unit"]) if gain else "",
            forms=forms,
            carries=bool(carries),  # most of the excess: its state may be named as the rest's place
            form=chosen,
            form_size=None if chosen is None else forms["bend" if chosen == "grow" else chosen]["size"],
            **_map_shape(grid, force),
        )
    return out


#: A state's map read on the output counts as where the rest lives only where its bend carries this share
#: of what it recovers: what the state's linear column recovers is a linear readout of the states, a
#: linear filter of the drive (an output lag), not a static function of a state.
BEND_SHARE = 0.5


def _state_output(tr, ho, feedback: dict, judge) -> dict:
    """A static map of each state added to the output: a readout that is a nonlinear function of a state.

    A battery's open-circuit voltage is a function of its charge, a state the
    model has, added to the terminal voltage: no map of the drive, the output
    or a force fed back finds it (a new user's cell read "a trend in time").
    Per state, ŵ and the map's hats are fitted on the training
    part and judged held out, as is ŵ beside the state's linear column alone;
    the map counts (``bends``) where what it recovers beyond that linear
    column is at least `BEND_SHARE` of what it recovers. Its curve is in w's
    unit over the state's training range.
    """
    cols = feedback["columns"]
    d_tr, d_ho = feedback["direct_train"][:, tr["ok"]], feedback["direct_heldout"][:, ho["ok"]]
    if not np.all(np.isfinite(d_tr)) or not np.all(np.isfinite(d_ho)):
        return {"reason": "the simulation's states are not finite on this recording"}
    score = judge.score
    out: dict[str, Any] = {"states": {}}
    for name, basis, own in _maps(feedback):
        knots = basis["knots"]
        # hats alone: the step at zero is a friction's, and zero is no mark on a state read out (a charge)
        free = [own[f"hat_{k}"] for k in range(len(knots))]
        pred, coef = _least_squares(
            [tr["w_hat"]] + [d_tr[j] for j in free], tr["r"], [ho["w_hat"]] + [d_ho[j] for j in free]
        )
        result = judge(pred)
        straight, _ = _least_squares(
            [tr["w_hat"], d_tr[own["linear"]]], tr["r"], [ho["w_hat"], d_ho[own["linear"]]]
        )
        linear = judge(straight)
        grid = np.linspace(knots[0], knots[-1], 101)
        rows = basis_forces(basis, grid)
        curve = np.sum([c * rows[ROLES.index(cols[j][1])] for c, j in zip(coef[1:], free)], axis=0)
        gained = score(result) - score(linear)
        out["states"][name] = dict(
            result,
            unit=feedback["units"].get(name, ""),
            linear=linear,
            bends=bool(score(result) > 0 and gained >= BEND_SHARE * score(result)),
            curve={"x": _list(grid), "r": _list(curve - np.min(curve))},
        )
    bent = {k: v for k, v in out["states"].items() if v["bends"]}
    if bent:
        out["best"] = max(bent, key=lambda k: bent[k]["fraction"] or -np.inf)
    return out


def _unavailable(why: str, n_tr: int, n_ho: int) -> dict:
    """The description when there is nothing to judge: every part a reason."""
    return {
        "n_train": n_tr,
        "n_heldout": n_ho,
        "reason": why,
        "recovered": {"reason": why},
        "kind": "unstructured",
        "summary": f"no description of the remainder: {why}",
    }


def describe_remainder(
    train: dict,
    heldout: dict,
    rate: float,
    floor_variance: float,
    feedback: dict | None = None,
    w_unit: str = "",
    spiky: str = "",
    v_unit: str = "",
    drive_map: dict | None = None,
) -> dict:
    """Where the residual r = w − ŵ lives: each measure fitted on `train`, judged on `heldout`.

    `train` and `heldout` hold 1-D arrays "t", "v_in", "w", "w_hat", "segment"
    (samples of a segment are contiguous; lags and differences stay inside
    one). `rate` is the sampling rate (Hz); `floor_variance` the measurement
    noise variance of w (None or ≤ 0: unknown). Returns a JSON-able dict:
    "offset", "static", "rate", "time", "linear_filter" (each with held-out
    "fraction" and "of_excess"), "recovered" (best gain; "named": the one the
    summary names), "kind" (the rate map and filters count as dynamic) and
    "summary"; a part that cannot be computed carries a "reason" instead.
    `feedback`: the responses of a simulation in state-space form to a force
    made of each state (`hybrid.discovery._unexplained.feedback_signals`);
    with it, "state_feedback" (`_state_feedback`). Either part may hold
    "recording", each sample's recording (a line's phase is its own in each);
    `w_unit` labels the amplitudes the summary quotes, `v_unit` the drive's levels. "concentrated"
    (`_concentrated`): the held-out stretch that holds most of the excess, when one does. `spiky`: what the
    noise floor found in w that leaves and comes back, in words (`NoiseFloor.spike_words`: isolated spikes,
    glitches; "" for none): the summary says they are part of the remainder, and an unstructured one is read
    as holding them rather than as a disturbance or a miss (unless two recordings under one drive tell).
    """
    import scipy.optimize

    tr, ho = _prepare(train), _prepare(heldout)
    n_tr, n_ho = len(tr["r"]), len(ho["r"])
    if n_ho < MIN_SAMPLES or n_tr < MIN_SAMPLES:
        return _unavailable(
            f"too few samples ({n_tr} training, {n_ho} held-out; {MIN_SAMPLES} needed)", n_tr, n_ho
        )
    rate = float(rate)
    if not np.isfinite(rate) or rate <= 0:
        raise ValueError(f"rate must be a positive number of samples per second, not {rate}")
    judge = _Judge(ho["r"], floor_variance)
    if judge.mse == 0.0:
        return _unavailable("the held-out residual is exactly zero", n_tr, n_ho)
    bins = int(np.clip(np.sqrt(n_tr) / 2, 4, 30))
    scores = {}

    # Static: the drive level.
    c, m, _ = _binned(tr["v_in"], tr["r"], bins)
    drive = judge(_interp(ho["v_in"], c, m))
    stride = -(-n_ho // 200)  # at most 200 points for the figure
    drive.update(
        curve={"v": _list(c), "r": _list(m)},
        points={"v": _list(ho["v_in"][::stride]), "r": _list(ho["r"][::stride])},
    )
    static = {"drive": drive, **_drive_shape(tr, c, m)}
    scores["static_drive"] = drive

    # Static: the simulation's output, monotone (w ≈ g(ŵ)) and free.
    xc, wy, wt = _binned(tr["w_hat"], tr["w"], 100)
    fits = [
        (float(np.sum(wt * (g - wy) ** 2)), name, g)
        for up, name in ((True, "increasing"), (False, "decreasing"))
        for g in [scipy.optimize.isotonic_regression(wy, weights=wt, increasing=up).x]
    ]
    _, direction, g = min(fits, key=lambda fit: fit[0])
    mono = judge(_interp(ho["w_hat"], xc, g - xc))  # r̂ = g(ŵ) − ŵ, constant beyond the training range
    static["output_monotone"] = dict(mono, direction=direction, shape=_output_shape(tr["w_hat"], tr["w"]))
    c2, m2, _ = _binned(tr["w_hat"], tr["r"], bins)
    static["output_free"] = judge(_interp(ho["w_hat"], c2, m2))
    scores["static_output_monotone"], scores["static_output_free"] = mono, static["output_free"]

    # Rate: dv/dt within segments (no prediction for the first sample of a run).
    ktr, kho = np.flatnonzero(tr["pos"] >= 1), np.flatnonzero(ho["pos"] >= 1)
    rate_part: dict[str, Any]
    if len(ktr) < MIN_SAMPLES or len(kho) < MIN_SAMPLES:
        rate_part = {"reason": "too few samples inside segments to take differences"}
    else:
        c3, m3, _ = _binned((tr["v_in"][ktr] - tr["v_in"][ktr - 1]) * rate, tr["r"][ktr], bins)
        pred = np.zeros(n_ho)
        pred[kho] = _interp((ho["v_in"][kho] - ho["v_in"][kho - 1]) * rate, c3, m3)
        rate_part = {**judge(pred), "curve": {"dv_dt": _list(c3), "r": _list(m3)}}
        scores["rate"] = rate_part

    # Time: a cubic in absolute time, scaled on the training span.
    t0, t1 = float(tr["t"].min()), float(tr["t"].max())
    time_part: dict[str, Any]
    if t1 <= t0:
        time_part = {"reason": "the training samples share one time stamp"}
    else:
        scaled = lambda t: np.clip((2.0 * t - t0 - t1) / (t1 - t0), -1.0, 1.0)  # constant beyond the span
        coef = np.polynomial.polynomial.polyfit(scaled(tr["t"]), tr["r"], 3)
        time_part = {**judge(np.polynomial.polynomial.polyval(scaled(ho["t"]), coef)), "degree": 3}
        step = _time_step(tr, ho, judge, scaled)
        # a gain that moves smoothly over the record, beyond what the offset's cubic follows
        gain = _gain_trend(tr, ho, judge, scaled)
        moves = judge.score(gain) >= STEP_SHARE and judge.score(gain) > judge.score(time_part) + MARGIN
        if (
            step is not None
            and judge.score(step) >= STEP_SHARE
            and judge.score(step) > max(judge.score(time_part), judge.score(step["without"])) + MARGIN
            and (not moves or judge.score(step) > judge.score(gain) + MARGIN)
        ):
            # a change at one time, which the cubic smooths over; unless straight pieces between several
            # times do better held out: a wander of the offset or of the gain (a true change they follow
            # only between two of them)
            wander = max(
                _time_wander(tr, ho, judge, scaled),
                _time_wander(tr, ho, judge, scaled, offset=False),
                key=judge.score,
            )
            if judge.score(wander) > judge.score(step):
                time_part = {**wander, "step": step, "cubic": time_part, "unit": w_unit}
            else:
                time_part = {**step, "wander": wander, "cubic": time_part, "unit": w_unit}
        elif moves:  # smoothly, or in straight pieces where they beat the cubic
            pieces = _time_wander(tr, ho, judge, scaled, offset=False)
            best = (
                {**pieces, "gain_cubic": gain} if judge.score(pieces) > judge.score(gain) + MARGIN else gain
            )
            time_part = {**best, "step": step, "cubic": time_part, "unit": w_unit}
        scores["time"] = time_part

    # Linear filter: lagged drive and lagged model output.
    lags = int(min(MAX_LAGS, max(MIN_LAGS, round(rate * 1.0))))
    filt = {
        "drive": _filter(tr, ho, "v_in", lags, rate, judge),
        "output": _filter(tr, ho, "w_hat", lags, rate, judge),
    }
    centre, spread = float(np.mean(tr["w_hat"])), float(np.std(tr["w_hat"])) or 1.0
    for part, power in ((tr, 2), (tr, 3), (ho, 2), (ho, 3)):
        part[f"w_hat_{power}"] = ((part["w_hat"] - centre) / spread) ** power
    # with the output's own lags: a refitted linear model leaves the power's part correlated with ŵ
    filt["output_square"] = _filter(tr, ho, ("w_hat_2", "w_hat"), lags, rate, judge)
    filt["output_cube"] = _filter(tr, ho, ("w_hat_3", "w_hat"), lags, rate, judge)
    scores.update({f"filter_{key}": part for key, part in filt.items() if "fraction" in part})

    fed: dict[str, Any] | None = None
    if feedback is not None:
        fed = _state_feedback(tr, ho, feedback, judge)
        if "linear" in fed:
            scores["state_linear"] = fed["linear"]
        if fed.get("states"):
            fed["best"] = max(fed["states"], key=lambda k: fed["states"][k]["fraction"] or -np.inf)
            scores["state_map"] = fed["states"][fed["best"]]
            fed["alike"] = _alike(feedback.get("values") or {}, fed["best"])

    through: dict[str, Any] | None = None
    if drive_map is not None:
        through = _drive_map(tr, ho, drive_map, judge)
        if "fraction" in through:
            scores["drive_map"] = through

    on_output: dict[str, Any] | None = None
    if feedback is not None and "direct_train" in feedback:
        on_output = _state_output(tr, ho, feedback, judge)
        if on_output.get("best"):
            scores["state_output"] = on_output["states"][on_output["best"]]

    places = _places(tr, ho, rate)
    periodic = dict(_periodic(tr, ho, places, rate, judge), unit=w_unit)
    if "fraction" in periodic:
        scores["periodic"] = periodic

    offset = judge(np.full(n_ho, tr["r"].mean()))
    out = {
        "n_train": n_tr,
        "n_heldout": n_ho,
        "heldout_mse": _num(judge.mse),
        "floor_variance": _num(judge.floor) if judge.floor is not None else None,
        "offset": offset,
        "static": static,
        "rate": rate_part,
        "time": time_part,
        "linear_filter": filt,
        "periodic": periodic,
    }
    if fed is not None:
        out["state_feedback"] = fed
    if on_output is not None:
        out["state_output"] = on_output
    if through is not None:
        out["drive_map"] = through
    repeats = _repeats(tr, ho, places, rate, judge)
    if repeats is not None:
        out["repeats"] = repeats
    out.update(_verdict(scores, judge, static, offset, fed, on_output, through))
    where = _concentrated(tr, ho, judge, places)
    if where is not None:
        out["concentrated"] = where
        out["summary"] += _concentrated_words(where, v_unit)
    # the held-out residual against the drive (each contiguous run a block): a disturbance leaves them
    # independent, a miss of the response the drive causes does not
    independence = rt.drive_independence(
        ho["r"], ho["v_in"], np.cumsum(ho["pos"] == 0), recordings=ho["recording"]
    )
    out["drive_independence"] = independence
    if out["kind"] == "unstructured" and judge.excess is not None and not (spiky and repeats is None):
        out["summary"] += _repeat_words(repeats, independence)
    if spiky:  # they count in every residual; the floor, read without them, does not
        out["summary"] += f"; w's {spiky} (the noise floor's warning) are part of it"
    return out


def _concentrated(tr, ho, judge, places: dict) -> dict | None:
    """The held-out stretch that holds most of the held-out error above the floor, or None.

    A stretch is a contiguous run of held-out samples of one recording (one
    block's held-out part). Its excess is its sum of r² less its samples times
    the floor; it is named when it holds at least `CONCENTRATED` of the whole
    excess and `CONCENTRATED_RATIO` times its share of the samples, among at
    least `CONCENTRATED_STRETCHES`, when the whole excess is beyond sampling
    error (`_Judge.excess`; half of it then is too, in fewer samples). Beside
    it: the drive's range there and on the training part of its recording,
    and whether it lies after (or before) every training sample of its
    recording — what the model had not seen there. Samples the noise floor read
    as spikes or glitches (``ho["spike"]``, where given) count for none: the
    summary says them already, and a few of them in one stretch are no change
    of the system there.
    """
    if judge.excess is None:  # no floor, or the held-out error is within sampling error of it
        return None
    over = ho["r"] ** 2 - judge.floor
    if "spike" in ho and ho["spike"].any():
        rest = ho["r"][~ho["spike"]]
        if rest.size < MIN_SAMPLES or not _Judge(rest, judge.floor).excess:  # the rest is at the floor
            return None
        over = np.where(ho["spike"], 0.0, over)
    stretch = np.cumsum(np.r_[0, (np.diff(ho["segment"]) != 0) | (np.diff(ho["recording"]) != 0)])
    if stretch[-1] + 1 < CONCENTRATED_STRETCHES:
        return None
    excess = np.bincount(stretch, weights=over)
    m = stretch == int(np.argmax(excess))
    # of the stretches' excesses above the floor (one below it, by sampling error, takes none away)
    share, samples = float(excess.max() / np.sum(np.maximum(excess, 0.0))), float(np.mean(m))
    if share < CONCENTRATED or share < CONCENTRATED_RATIO * samples:
        return None
    i = float(ho["recording"][m][0])
    trained = tr["recording"] == i
    t, v = ho["t"][m], ho["v_in"][m]
    out: dict[str, Any] = {
        "share": _num(share),
        "samples_fraction": _num(samples),
        "recording": int(i) if len(places) > 1 else None,
        "t": [_num(t.min(), 7), _num(t.max(), 7)],
        "drive": [_num(v.min()), _num(v.max())],
    }
    if trained.any():
        tv, tt = tr["v_in"][trained], tr["t"][trained]
        lo, hi = float(tv.min()), float(tv.max())
        margin = 0.02 * (hi - lo)
        out.update(
            train_drive=[_num(lo), _num(hi)],
            beyond_training_drive=bool(v.max() > hi + margin or v.min() < lo - margin),
            after_training=bool(t.min() > tt.max()),
            before_training=bool(t.max() < tt.min()),
        )
    return out


def _concentrated_words(where: dict, v_unit: str) -> str:
    """The clause that says where a concentrated remainder lives (`_concentrated`; its recording, among several)."""
    a, b = where["t"]
    of = f" of recording {where['recording'] + 1}" if where["recording"] is not None else ""
    unit = f" {v_unit}" if v_unit else ""
    said = (
        f"; {100 * where['share']:.0f} % of the held-out error above the floor lies in one held-out "
        f"stretch, t = {a:.4g}–{b:.4g} s{of} ({100 * where['samples_fraction']:.0f} % of the held-out samples)"
    )
    if where.get("beyond_training_drive"):
        lo, hi = where["drive"]
        tlo, thi = where["train_drive"]
        return (
            f"{said}, where the drive spans {lo:.3g} to {hi:.3g}{unit}, beyond the {tlo:.3g} to {thi:.3g}{unit} "
            "of the training part: the model extrapolates there, and a recording that trains on those levels "
            "tells what it misses"
        )
    if where.get("after_training"):
        return (
            f"{said}, after every training sample of the record: a change late in the record (warming, wear, "
            "a drift faster than the training part shows) or a response to a drive the training part lacks; a "
            "recording that repeats this stretch's drive earlier tells which"
        )
    if where.get("before_training"):
        return f"{said}, before every training sample: the record's start (an initial state the model misses)"
    return f"{said}: the training part does not show what happens there"


def _repeats(tr, ho, places: dict, rate: float, judge) -> dict | None:
    """Recordings under one drive: how much of the held-out residual they share (None: no two share one).

    Two recordings share a drive where their lengths agree within 1 % and
    their drives, sample for sample from each one's start, correlate above
    `SAME_DRIVE`. On the held-out samples both have at the same places, the
    mean of r_a·r_b is the part of the residual that repeats with the drive
    (a miss of the response), the rest does not (noise, a disturbance).
    `of_excess`: that mean over the pair's mean square above the floor.
    """
    if len(places) < 2:
        return None
    ids, lengths = list(places), [length for _, length in places.values()]
    n = max(lengths)
    drives, residuals = _grids([tr, ho], "v_in", places, rate, n), _grids([ho], "r", places, rate, n)
    pairs, shared, square, count = [], 0.0, 0.0, 0
    for a in range(len(ids)):
        for b in range(a + 1, len(ids)):
            if abs(lengths[a] - lengths[b]) > 0.01 * max(lengths[a], lengths[b]):
                continue
            va, vb = drives[a], drives[b]
            ok = np.isfinite(va) & np.isfinite(vb)
            if ok.sum() < MIN_SAMPLES or np.std(va[ok]) == 0 or np.std(vb[ok]) == 0:
                continue
            if np.corrcoef(va[ok], vb[ok])[0, 1] < SAME_DRIVE:
                continue
            ra, rb = residuals[a], residuals[b]
            ok = np.isfinite(ra) & np.isfinite(rb)
            if ok.sum() < MIN_SAMPLES:
                continue
            pairs.append([ids[a], ids[b]])
            shared += float(np.sum(ra[ok] * rb[ok]))
            square += float(np.sum((ra[ok] ** 2 + rb[ok] ** 2) / 2))
            count += int(ok.sum())
    if not pairs or square <= 0:
        return None
    above = None if judge.floor is None else square / count - judge.floor
    return {
        "pairs": pairs,
        "samples": count,
        "shared_fraction": _num(shared / square),
        "of_excess": _num(shared / count / above) if above is not None and above > 0 else None,
    }


#: The held-out residual's test against the drive finds no dependence at or above this p-value.
NO_DEPENDENCE_P = 0.05


def _repeat_words(repeats: dict | None, independence: dict | None = None) -> str:
    """The clause an unstructured remainder ends on: what repeating the drive tells, or would.

    With one recording under each drive, the held-out residual's test against the drive
    (`independence`) weighs the two readings: a remainder that follows the drive holds a
    miss of the response, not a disturbance alone.
    """
    if repeats is None or repeats.get("of_excess") is None:
        if independence is not None and independence["p_value"] < FOLLOWS_DRIVE_P:
            return (
                "; not predictable from the drive, the model's output or time by these maps, yet it follows the "
                f"drive ({drive_test_words(independence)}): "
                "part of it is a response to the drive that the simulation misses (too small beside the rest for "
                "these maps to count, or beyond them), not a disturbance alone"
            )
        tested = ""
        if independence is not None and independence["p_value"] >= NO_DEPENDENCE_P:
            tested = (
                f"; its test against the drive finds no dependence (p = {independence['p_value']:.2g}), as a "
                "disturbance's would be; the test reads a linear dependence alone, and a response the drive "
                "causes through a clip or a rate limit may pass it too"
            )
        elif independence is not None:
            tested = (
                f"; its test against the drive leans towards a dependence without settling it (p = "
                f"{independence['p_value']:.2g}, where {FOLLOWS_DRIVE_P:g} is asked)"
            )
        return (
            "; not predictable from the drive, the model's output or time by these maps: a disturbance the "
            "drive does not cause (a coloured noise, an unmeasured input) reads so, and so may a miss more "
            f"complex than they are{tested}; a second recording under the same drive, diagnosed with this one, "
            "tells them apart (a disturbance does not repeat)"
        )
    share = min(max(repeats["of_excess"], 0.0), 1.0)
    (a, b), others = repeats["pairs"][0], len(repeats["pairs"]) - 1
    more = f" (and {others} more pairs)" if others else ""
    said = f"recordings {a + 1} and {b + 1}{more}, under the same drive, share {100 * share:.0f} % of it held out"
    if share <= NOT_REPEATED:
        return (
            f"; {said}: it does not repeat with the drive, so it is a disturbance the drive does not cause "
            "(a coloured noise, an unmeasured input), not a part of the response the simulation misses — a "
            "floor read as white noise does not count it"
        )
    if share >= REPEATED:
        return f"; {said}: it repeats with the drive, a part of the response that these maps cannot represent"
    return f"; {said}: part of it repeats with the drive (a miss of the response), the rest is a disturbance"


def _map_words(part: dict) -> str:
    """What a state's map looks like, in a parenthesis: odd or even, and its simple form if one explains it."""
    sym = part.get("symmetry", {})
    words = ["odd" if (sym.get("odd") or 0) > 0.8 else "even" if (sym.get("even") or 0) > 0.8 else ""]
    form = part.get("form")
    if form is not None:
        size = part["form_size"]
        unit = f" {part['force_unit']}" if part.get("force_unit") else ""
        words.append(FORMS[form].format(size=f"{size:.3g}{unit}", half=f"{abs(size) / 2:.3g}{unit}"))
    words = [w for w in words if w]
    return f" ({'; '.join(words)})" if words else ""


def _verdict(
    scores: dict,
    judge: _Judge,
    static: dict,
    offset: dict,
    fed: dict | None = None,
    on_output: dict | None = None,
    through: dict | None = None,
) -> dict:
    """Best extension, kind (simplest family within MARGIN of the best) and the one-sentence summary."""

    score = judge.score
    # The map of the drive through the dynamics counts only where it recovers clearly more than every
    # other reading (`MARGIN`): it spans a linear filter of the drive, and through a nonlinear simulation
    # more; short of that the verdict is what it would be without it.
    others = max((score(p) for k, p in scores.items() if FAMILY[k] != "drive_static"), default=0.0)
    scores = {k: p for k, p in scores.items() if FAMILY[k] != "drive_static" or score(p) > others + MARGIN}
    best = max(scores, key=lambda k: scores[k]["fraction"] or -np.inf)
    rec = {
        "best": best,
        "fraction": scores[best]["fraction"],
        "of_excess": scores[best]["of_excess"],
        "named": None,
    }
    if judge.reason:
        rec["reason"] = judge.reason
    family = {f: max((score(p) for k, p in scores.items() if FAMILY[k] == f), default=0.0) for f in ORDER}
    top = max(family.values())
    where = (
        "of the held-out error above the noise floor" if judge.excess is not None else "of the held-out error"
    )
    frac = scores[best]["fraction"] or 0.0
    if top < UNSTRUCTURED_EXCESS or frac < UNSTRUCTURED_MSE:
        why = f" ({judge.reason})" if judge.reason else ""
        return {
            "recovered": rec,
            "kind": "unstructured",
            "summary": f"no simple structure: nothing recovers more than {100 * max(top, 0):.0f} % {where}{why}",
        }
    kind = next(f for f in ORDER if family[f] >= top - MARGIN)
    pct = lambda k: f"{100 * score(scores[k]):.0f} %"
    inkind = next(
        k for k in FAMILY if k in scores and FAMILY[k] == kind and score(scores[k]) >= family[kind] - MARGIN
    )
    rec["named"] = inkind
    best_static = max((k for k in scores if FAMILY[k] == "static"), key=lambda k: score(scores[k]))
    if kind == "static" and inkind == "static_drive":
        sym = static.get("symmetry", {})
        char = (
            " and even" if (sym.get("even") or 0) > 0.8 else " and odd" if (sym.get("odd") or 0) > 0.8 else ""
        )
        text = f"static{char} in the drive: a function of the drive level recovers {pct(inkind)} {where}"
        notes = [
            f"one-sided ({static['one_sided']['side']} drive)" if static["one_sided"].get("flag") else "",
            f"the {static['flat_near_zero']['which']} is flat near zero drive (dead zone)"
            if static["flat_near_zero"].get("flag")
            else "",
            "it bends at the largest drive levels" if static["bend_at_ends"].get("flag") else "",
        ]
        text += "".join(f"; {n}" for n in notes if n)
    elif kind == "static" and inkind == "state_output":
        assert on_output is not None  # scored only with it
        name = on_output["best"]
        part = on_output["states"][name]
        text = (
            f"static in the simulation's state {name}, on its output: a function of {name} added to the "
            f"output recovers {pct(inkind)} {where} (a readout that bends with a state, "
            f"such as a cell's open-circuit voltage with its charge: a physics plug-in's observe(x, p) can add it); "
            f"the best map of the drive {pct('static_drive')}, of the output {pct('static_output_free')}, {name}'s straight line "
            f"{100 * score(part['linear']):.0f} %"
        )
    elif kind == "static":
        how = "a monotone" if inkind == "static_output_monotone" else "a"
        text = f"static on the model's output: {how} map of the simulation's output recovers {pct(inkind)} {where}"
        shape = static["output_monotone"]["shape"]
        if (shape.get("flat_middle") or {}).get("flag"):
            text += (
                "; w stays flat in the middle of the output's range and rises beyond it (a dead band: a "
                "sensor's, or play between the actuator and what is measured)"
            )
        sides = (shape.get("levels_off") or {}).get("sides") or []
        if sides:
            text += f"; w levels off at the {' and '.join(sides)} of the output's range"
    elif kind == "dynamic":
        what = {
            "filter_drive": "a linear filter of the drive",
            "filter_output": "a linear filter of the model's output",
            "rate": "a function of the drive's rate dv/dt",
            "state_linear": "a force proportional to the simulation's states fed back into its drive (a "
            "spring or a damper on them)",
        }[inkind]
        weak = score(scores[best_static]) < 0.5 * family["dynamic"]
        text = f"dynamic: {what} recovers {pct(inkind)} {where}; " + (
            f"no static map does (best {pct(best_static)})"
            if weak
            else f"the best static map {pct(best_static)}"
        )
    elif kind == "nonlinear_dynamic" and inkind == "state_map":
        assert fed is not None  # scored only with it
        name = fed["best"]
        alike = fed.get("alike") or {}
        said = name  # a state that moves with it: which of them carries the force, this recording hardly says
        if alike:
            said += (
                " (or " + ", ".join(f"{k}, which moves with it: r = {r:.2f}" for k, r in alike.items()) + ")"
            )
        best_linear = max((k for k in scores if FAMILY[k] == "dynamic"), key=lambda k: score(scores[k]))
        text = (
            f"nonlinear inside the dynamics: a static function of the simulation's state {said} fed back into "
            f"{fed.get('into', 'its drive')} recovers {pct(inkind)} {where}{_map_words(fed['states'][name])}; the best linear filter "
            f"{pct(best_linear)}, the best static map {pct(best_static)}"
        )
    elif kind == "nonlinear_dynamic":
        odd = inkind == "filter_output_cube"
        best_linear = max((k for k in scores if FAMILY[k] == "dynamic"), key=lambda k: score(scores[k]))
        text = (
            f"nonlinear inside the dynamics: the {'cube' if odd else 'square'} of the model's output through a "
            f"linear filter recovers {pct(inkind)} {where} (an {'odd' if odd else 'even'} static nonlinearity "
            f"fed back through the dynamics, e.g. a {'cubic (stiffening or softening)' if odd else 'quadratic'} "
            f"restoring force, or a damping where the output is a speed); the best linear filter {pct(best_linear)}, the best static map "
            f"{pct(best_static)}"
        )
    elif kind == "drive_static":
        assert through is not None  # scored only with it
        linear = [k for k in scores if FAMILY[k] == "dynamic"]
        clip = through.get("clip") or {}
        text = (
            f"static in the drive, before the dynamics: a function of the drive level fed through the "
            f"simulation recovers {pct(inkind)} {where} (a drive that is not the one commanded: an amplifier's, "
            "a pump's or a valve's curve, a clip, a dead zone)"
        )
        if "static_drive" in scores:
            text += f"; the best map of the drive level on the output {pct('static_drive')}"
        if linear:
            text += f", the best linear filter {pct(max(linear, key=lambda k: score(scores[k])))}"
        if clip:
            unit = f" {through['unit']}" if through.get("unit") else ""
            levels = " and ".join(f"{level:.3g}{unit} ({end})" for end, level in clip["levels"].items())
            took = (
                "recovers as much or more"
                if clip["share"] >= 1.0
                else f"takes {100 * clip['share']:.0f} % of what that map adds"
            )
            text += (
                f"; a clip of the drive near {levels} {took}: a level the drive stops at (to first order: the "
                "level trades with the fitted gain)"
            )
    elif kind == "periodic":
        line = scores["periodic"]
        f = line["frequency_hz"]
        mains = f", e.g. {line['mains']}" if line.get("mains") else ""
        size = " ".join(x for x in (f"{line['amplitude_rms']:.3g}", line["unit"], "rms") if x)
        text = (
            f"periodic, not driven: a sinusoid at {f:.4g} Hz, where the drive has no line, recovers "
            f"{pct(inkind)} {where} (amplitude {size}): a disturbance added to the "
            f"measurement — a vibration or an electrical pick-up{mains} — rather than a part of the response "
            f"to the drive that the simulation misses; a notch at {f:.4g} Hz on w removes it"
        )
    elif scores[inkind].get("form") == "step":  # kind "time": the time reading, a change at one time
        step = scores[inkind]
        unit = f" {step['unit']}" if step.get("unit") else ""
        share = step.get("offset_share")
        changes = [
            f"w offset by {step['offset']:.3g}{unit}" if share is None or share >= 0.1 else "",
            f"the model's output scaled by {1.0 + step['gain_change']:.3g}"
            if share is None or share <= 0.9
            else "",
        ]
        text = (
            f"a change at one time: from t = {step['at_s']:.4g} s on, {' and '.join(c for c in changes if c)} "
            f"recovers {pct(inkind)} {where} (a sensor re-zeroed or bumped, a clamp that slipped, a part that "
            "changed during the record: neither an effect of the drive nor a smooth drift reads so)"
        )
    elif scores[inkind].get("gain_only"):  # kind "time": the gain's straight pieces, no change, no cubic
        wander = scores[inkind]
        text = (
            "a gain that wanders over the record: the model's output scaled by a trend of "
            f"{wander['pieces']} straight pieces in time recovers {pct(inkind)} {where}, the offset's cubic "
            f"{100 * score(wander['cubic']):.0f} % (an amplifier or a sensor warming and cooling, a part that "
            "dries or wears: not an effect of the drive; a record with the drive repeated at its start and its "
            "end measures it)"
        )
    elif scores[inkind].get("form") == "wander":  # kind "time": no single change, no cubic, follows it
        wander = scores[inkind]
        text = (
            "a wander in time: w's baseline (or the gain) moving over the record as no cubic and no single "
            f"change follow it: a trend of {wander['pieces']} straight pieces recovers "
            f"{pct(inkind)} {where}, a change at one time {100 * score(wander['step']):.0f} %, a cubic "
            f"{100 * score(wander['cubic']):.0f} % (a sensor's offset or the plant's surroundings wandering, "
            "a temperature: not an effect of the drive; a reference channel, or a record with the drive off "
            "before and after, measures it)"
        )
    elif scores[inkind].get("form") == "gain":  # kind "time": the gain's cubic, beyond the offset's
        text = (
            f"a gain that moves over the record: the model's output scaled by a cubic in time recovers "
            f"{pct(inkind)} {where}, the offset's cubic alone {100 * score(scores[inkind]['cubic']):.0f} % "
            "(an amplifier or a sensor warming, a part that dries or wears: not an effect of the drive; "
            "`drift` is its straight-line form, and a record with the drive repeated at its start and its "
            "end measures it)"
        )
    else:
        text = f"a trend in time (drift): a smooth function of time recovers {pct(inkind)} {where}"
    if score(offset) >= 0.8 * top:
        text += f"; mostly a constant offset (the training mean alone recovers {100 * score(offset):.0f} %)"
    return {"recovered": rec, "kind": kind, "summary": text}


def plot_remainder(description: dict, path, units: dict | None = None) -> None:
    """Two panels: the residual against drive level with the learned map, and the filters' gain.

    A third where the state feedback (`_state_feedback`) has a best state: its
    map, the force taken off the drive against the state; or, where the summary
    names a state's map on the output (`_state_output`), that map.

    `units`: the recorded signals' (``{"w": ..., "v_in": ...}``, `Diagnosis.signal_units`; default
    `PAPER_UNITS`) for the labels.
    """
    from ..core._fit import PAPER_UNITS

    units = units or PAPER_UNITS
    from ..util._figures import pyplot, save_png

    plt = pyplot()
    fed = description.get("state_feedback") or {}
    read = description.get("state_output") or {}
    on_output = (description.get("recovered") or {}).get("named") == "state_output"
    state = read.get("best") if on_output else fed.get("best")
    axes = plt.subplots(1, 3 if state else 2, figsize=(16.5 if state else 11, 4.2))[1]
    left, right = axes[0], axes[1]
    fig = left.figure
    if state and on_output:  # the map the summary names: a function of a state added to the output
        part, panel = read["states"][state], axes[2]
        panel.plot(part["curve"]["x"], part["curve"]["r"], "C3-", lw=1.8)
        panel.set(
            xlabel=f"state {state}" + (f" ({part['unit']})" if part.get("unit") else ""),
            ylabel=f"added to the output ({units['w']}, from its least)",
        )
        panel.set_title(f"Map of the state {state} on the output; recovers {_pct(part)}", fontsize=9)
        panel.grid(True, alpha=0.3)
    elif state:
        part, panel = fed["states"][state], axes[2]
        panel.plot(part["curve"]["x"], part["curve"]["force"], "C3-", lw=1.8)
        panel.axhline(0.0, color="0.5", lw=0.6)
        force_unit = f" ({part['force_unit']})" if part.get("force_unit") else " (scaled)"
        panel.set(
            xlabel=f"state {state}" + (f" ({part['unit']})" if part.get("unit") else ""),
            ylabel=f"force taken off the drive{force_unit}",
        )
        panel.set_title(
            f"Map of the state {state} fed back into the drive; recovers {_pct(part)}", fontsize=9
        )
        panel.grid(True, alpha=0.3)
    drive = description.get("static", {}).get("drive", {})
    if "curve" in drive:  # the held-out points and the map fitted on training
        left.scatter(
            drive["points"]["v"], drive["points"]["r"], s=5, color="0.6", alpha=0.6, label="held-out residual"
        )
        left.plot(
            drive["curve"]["v"], drive["curve"]["r"], "C3-o", ms=3, lw=1.8, label="map fitted on training"
        )
        sym = description["static"].get("symmetry", {})
        char = (
            f"even {100 * sym['even']:.0f} %, odd {100 * sym['odd']:.0f} %"
            if "even" in sym
            else sym.get("reason", "")
        )
        left.set_title(f"Residual against drive level ({char}); recovers {_pct(drive)}", fontsize=9)
        left.legend(fontsize=8)
    else:
        left.text(0.5, 0.5, description.get("reason", "no map"), ha="center", transform=left.transAxes)
    left.axhline(0.0, color="0.5", lw=0.6)
    left.set(xlabel=f"drive v_in ({units['v_in']})", ylabel=f"residual w − ŵ ({units['w']})")
    for key, label, colour in (
        ("drive", f"of the drive (per {units['v_in']})", "C0"),
        ("output", "of the model's output", "C2"),
    ):
        part = description.get("linear_filter", {}).get(key, {})
        if "response" in part:
            right.plot(
                part["response"]["f_hz"],
                part["response"]["magnitude_db"],
                color=colour,
                label=f"filter {label}: recovers {_pct(part)}",
            )
    if right.lines:
        right.legend(fontsize=8)
    right.set(xlabel="frequency (Hz)", ylabel="gain (dB)")
    right.set_title(
        "Linear filter of the residual fitted on training: frequency response\n(a constant offset alone "
        f"recovers {_pct(description.get('offset', {}))})",
        fontsize=9,
    )
    right.grid(True, alpha=0.3)
    width = 200 if state else 130  # characters of the summary per line of the title
    fig.suptitle(textwrap.fill(description.get("summary", ""), width), fontsize=9)
    fig.tight_layout()
    save_png(fig, path)


def _pct(part: dict) -> str:
    value = part.get("of_excess") if part.get("of_excess") is not None else part.get("fraction")
    return "—" if value is None else f"{100 * value:.0f} %"
