"""The measurement noise of w, estimated from the recording alone (no model).

`diagnose` may say that nothing is missing only when the final model's
held-out error is consistent with how noisy the measurement is; this module
says how noisy it is without trusting any model. Every estimator below reads
the noise off a part of w where the signal is weak, so each is an upper bound
on the variance of white noise (signal leaking in only adds), and the floor is
the smallest of them:

- **differences** of order k = 1..4: for white noise of variance σ²,
  E[(Δᵏw)²] = C(2k, k) σ²; a slow signal's differences shrink like
  (2 sin πf/f_s)²ᵏ, so a higher order removes more of it (Rice 1984; Hall,
  Kay & Titterington 1990 use the same idea with optimal weights);
- **spectrum**: the Welch power spectral density of w in the top fifth of the
  band (0.8–1.0 × Nyquist), whose level for white noise is 2σ²/f_s (one-sided);
  the median over that band ignores a narrow line (an aliased mode, mains);
- **repeats** (only when the drive repeats itself exactly, e.g. a periodic
  drive or a repeated test sequence): the spread of w across the repetitions
  of each sample, which removes the signal however fast it is.

The standard error is the spread of the chosen estimator over `blocks`
contiguous blocks of the recording, divided by √blocks. Noise that is not
white (a slow drift of the tracker, vibration) is not seen by these
estimators and counts as something a model should explain.

**Where the signal itself is fast.** A plant whose response has content up to
the Nyquist frequency (a lightly damped mode near it, steps through a fast
mode) varies from sample to sample by far more than its noise, and every
estimator above reads that signal (a 15 Hz mode sampled at 50 Hz under steps:
more than a hundred times the noise variance, `tests/test_noise_floor.py`), and
a creep the model missed sat "within the floor". The fitted model's held-out residual is an upper bound
too (noise plus whatever the model misses, on samples it was not fitted to),
and its differences remove a slow miss as they remove a slow signal:
`bounded_by_residual` takes them where they lie below `RESIDUAL_SWITCH` of the
model-free floor, and says so (``source``, ``method`` ``residual_differences_k``).
A fitted model can be bent by what it lacks, though, and miss fast too; so
`noise_floor` itself also reads the differences of w's residual from a linear
fit to the drive's last `FIR_TAPS` samples (`linear_fit_residual`: fitted on the
first half, read on the second; ``linear_fit_differences_k``), which takes out
any response that settles within those samples, under the same rule. Where the
model-free floor is sound the estimates agree and it is kept.

**Spikes.** A lone sample far off both neighbours that comes back (a tracker
that jumped to a wrong blob for a frame, an electrical glitch) puts its energy
into every estimator above; `spike_samples` finds such samples (read on w less
its linear response to the drive, with rules that keep a fast response's first
samples after a step out), the estimators read w with each replaced by its
neighbours' mean, and `NoiseFloor.spikes` and a warning say so. A short run of
such samples (a tracker that lost the tip for a few frames, a logger that read
0 while its sensor dropped out) is a glitch: w jumps into it and back out
(`glitch_runs`), and the estimators read w with the run bridged by a straight
line; `NoiseFloor.glitches` holds the runs, `spikes` their samples too.

**What the floor can and cannot see.** Every estimator reads how much w varies
from one sample to the next beyond a smooth signal. Data that were smoothed,
low-pass filtered, interpolated or oversampled (a tracker's smoothing, a logger
at 1 kHz watching a 1 Hz strip) have had that variation removed, so the floor
then reads what is left (often the rounding of the stored values), not the
measurement error: from w alone such data cannot be told from a smooth signal
measured with little noise. So the floor says what it was estimated from
(`NoiseFloor.source`), and warns (`NoiseFloor.warnings`) when it is below the
data's quantisation step (`quantisation_step`: the values lie on a grid of that
step, whose rounding alone is step/√12); `hybrid.discovery._unexplained` adds a
warning when the model's held-out error is far above it.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np

#: Orders of the difference estimators.
DIFFERENCE_ORDERS = (1, 2, 3, 4)
#: The band the spectral estimator reads, as fractions of the Nyquist frequency.
SPECTRAL_BAND = (0.8, 1.0)
#: `bounded_by_residual` takes the residual's differences only below this share of the model-free floor's
#: variance: where the two agree within their spread (white noise, a slow signal) the model-free floor stays.
RESIDUAL_SWITCH = 0.5
#: Taps of `linear_fit_residual`'s response to the drive (samples).
FIR_TAPS = 32
#: The labels of the floors read from a fit's residual (`_leaked`): ``<label>_differences_k``.
FITTED_LABELS = ("residual", "linear_fit")
_ORDINALS = {1: "first", 2: "second", 3: "third", 4: "fourth"}
#: The floor's `method` where it is the rounding of w's values to their grid (`_at_least_rounding`).
ROUNDING = "rounding"
#: Grid steps a recording's range must span for its rounding error to be spread over a step (`_at_least_rounding`).
ROUNDING_LEVELS = 4
#: Largest number of grid steps a recording's range may span for `quantisation_step` to call it a grid.
MAX_GRID_STEPS = 10**7
#: Robust standard deviations of its neighbours' mean beyond which a lone sample is a spike (`spike_samples`).
SPIKE_SIGMAS = 8.0
#: ... and `SPIKE_OVER_TAIL` times the `SPIKE_QUANTILE` quantile of every other sample's excursion: a
#: response with content near the Nyquist frequency makes lone-looking samples at each step of its
#: drive (~1 in 40 samples of a 15 Hz mode sampled at 50 Hz under steps), a tail a glitch stands far
#: out of (on white noise, 3 × 2.58 robust σ). More candidates than `SPIKE_MAX_FRACTION` of the
#: samples are a feature of the signal, not glitches: none is counted.
SPIKE_QUANTILE, SPIKE_OVER_TAIL, SPIKE_MAX_FRACTION = 0.99, 3.0, 0.01
#: A spike's excursion is at least `SPIKE_ALONE` times those of the samples 2..`SPIKE_LOCAL` from it.
SPIKE_ALONE, SPIKE_LOCAL = 2.5, 5
#: Samples after a jump of the drive in which no spike is counted (a response's first samples).
SPIKE_AFTER = 3
#: The longest run of samples read as one glitch (`glitch_runs`): a third of a second at 30 frames/s.
GLITCH_RUN = 10
#: Glitches in more than this share of the samples are a feature of the signal, not glitches: none is counted.
GLITCH_MAX_FRACTION = 0.05


@dataclasses.dataclass(frozen=True)
class NoiseFloor:
    """The measurement noise of w, from the recording alone.

    **Fields:**

    - `variance`: σ², the noise variance (w's unit squared); `std` is its root.
    - `std_error`: standard error of `variance`, from its spread over blocks.
    - `method`: the estimator that gave the smallest value (see the module).
    - `estimates`: every estimator's variance, by name.
    - `fraction_of_variance`: σ² / var(w), the NMSE a perfect model would leave.
    - `source`: what the floor was estimated from, in words.
    - `quantum`: the step of the grid w's values lie on (`quantisation_step`), NaN when none.
    - `warnings`: sentences, when the floor may not be the measurement noise.
    - `spikes`: the samples of w read as isolated spikes (`spike_samples`) or inside a glitch
      (`glitch_runs`), left out of the estimators.
    - `glitches`: the glitches, each (first sample, last sample).
    - `spike_note`: the sentence about them (one of `warnings`), empty when there are none.
    """

    variance: float
    std_error: float
    method: str
    estimates: dict
    fraction_of_variance: float
    source: str = ""
    quantum: float = float("nan")
    warnings: tuple = ()
    spikes: tuple = ()
    glitches: tuple = ()
    spike_note: str = ""

    @property
    def std(self) -> float:
        return math.sqrt(self.variance)

    @property
    def spike_words(self) -> str:
        """What `spike_note` found, in a few words ("isolated spikes", "glitches", both); "" when nothing."""
        if not self.spike_note:
            return ""
        if not self.spikes:  # pooled over recordings: each says its own
            return "isolated spikes or glitches"
        inside = sum(b - a + 1 for a, b in self.glitches)
        if not self.glitches:
            return "isolated spikes"
        return "glitches" if inside == len(self.spikes) else "isolated spikes and glitches"

    @property
    def from_fit(self) -> bool:
        """Whether the floor was read from a fit's residual (`bounded_by_residual`, `linear_fit_residual`)."""
        return self.method.startswith(tuple(f"{label}_" for label in FITTED_LABELS))

    def to_dict(self) -> dict:
        return {
            "variance": self.variance,
            "std": self.std,
            "std_error": self.std_error,
            "method": self.method,
            "estimates": dict(self.estimates),
            "fraction_of_variance": self.fraction_of_variance,
            "source": self.source,
            "quantum": self.quantum,
            "warnings": list(self.warnings),
            "spikes": list(self.spikes),
            "glitches": [list(g) for g in self.glitches],
        }


def quantisation_step(w) -> float:
    """The step of the grid the values of `w` lie on (e.g. 0.001 for values stored with 3 decimals), or NaN.

    The candidates are the smallest non-zero difference between two sorted distinct values
    and its whole fractions down to a tenth (values 2 and 3 steps apart have a step finer
    than their smallest difference); the first that every value is a whole number of, from
    the smallest (to 1 % of a step), is the step, when the range spans at most
    `MAX_GRID_STEPS` steps. Values that vary continuously (floats from a model, a filter)
    give NaN.
    """
    w = np.asarray(w, float).reshape(-1)
    w = w[np.isfinite(w)]
    values = np.unique(w)
    if values.size < 3:
        return float("nan")
    smallest = float(np.min(np.diff(values)))
    span = float(values[-1] - values[0])
    for divisor in range(1, 11):
        step = smallest / divisor
        if not (step > 0 and span / step <= MAX_GRID_STEPS):
            break
        units = (values - values[0]) / step
        if bool(np.all(np.abs(units - np.round(units)) <= 0.01)):
            return step
    return float("nan")


def describe_source(method: str, n: int, rate: float, period: int = 0) -> str:
    """What the estimator `method` read, in words, for `n` samples at `rate` Hz."""
    if method.startswith("differences_"):
        k = int(method.rsplit("_", 1)[1])
        order = _ORDINALS.get(k, f"order-{k}")
        return (
            f"the {order} differences of w over {n} samples (how much w varies from one sample to the next "
            "beyond a smooth signal, white noise assumed)"
        )
    if method == "spectrum":
        nyquist = rate / 2
        return (
            f"w's spectrum at {SPECTRAL_BAND[0] * nyquist:.3g}–{SPECTRAL_BAND[1] * nyquist:.3g} Hz (the top "
            f"fifth of the band below the Nyquist frequency, {nyquist:.3g} Hz) over {n} samples, white noise "
            "assumed"
        )
    if method == "repeats":
        return f"the spread of w over the {n // period} repetitions of the drive (period {period} samples)"
    return method


def floor_warnings(std: float, quantum: float) -> tuple[str, ...]:
    """Sentences when a floor of σ = `std` cannot be the measurement noise of data on a grid of step `quantum`."""
    if not (np.isfinite(quantum) and std < quantum):
        return ()
    return (
        f"the floor σ = {std:.3g} is below the data's quantisation step ({quantum:.3g}; rounding alone "
        f"gives {quantum / math.sqrt(12):.3g}): the stored values do not resolve the noise, and smoothed or "
        "oversampled data look this way too; the floor then reads the rounding, not the measurement error",
    )


def _mad_spread(x: np.ndarray) -> float:
    """1.4826 × the median absolute deviation of x: its standard deviation, were it Gaussian, that outliers do not inflate."""
    return 1.4826 * float(np.median(np.abs(x - np.median(x)))) if x.size else 0.0


def _drive_jumps(v_in: np.ndarray) -> np.ndarray:
    """The first sample after each jump of the drive: a step beyond `SPIKE_SIGMAS` robust spreads of its steps."""
    dv = np.abs(np.diff(v_in))
    return np.flatnonzero(dv > SPIKE_SIGMAS * _mad_spread(dv)) + 1


def _excursion(x: np.ndarray) -> np.ndarray:
    """e_i = x_i − (x_{i−1} + x_{i+1})/2 for i = 1..n−2 (index i − 1): how far a sample leaves its neighbours."""
    return x[1:-1] - (x[:-2] + x[2:]) / 2


def _lone(x: np.ndarray, zero_spread: bool) -> np.ndarray:
    """Samples of x (indices) that leave both neighbours by over `SPIKE_SIGMAS` robust spreads and come back.

    `zero_spread`: where the robust spread is 0 (x flat but for a few samples),
    every such excursion counts (True) or none does (False).
    """
    e = _excursion(x)
    known = e[np.isfinite(e)]
    spread = _mad_spread(known)
    if not spread > 0:
        if not zero_spread:
            return np.zeros(0, int)
        big = np.abs(e) > 0
    else:
        big = np.abs(e) > SPIKE_SIGMAS * spread
    # alone: beyond its next neighbours' own excursions (a spike leaves them at noise, a ringing does not)
    padded = np.r_[np.zeros(SPIKE_LOCAL), np.nan_to_num(np.abs(e)), np.zeros(SPIKE_LOCAL)]
    around = np.max(
        [
            padded[SPIKE_LOCAL + k : SPIKE_LOCAL + k + e.size]
            for d in range(2, SPIKE_LOCAL + 1)
            for k in (d, -d)
        ],
        axis=0,
    )
    alone = np.abs(e) > SPIKE_ALONE * around
    return np.flatnonzero(big & alone & (np.abs(x[2:] - x[:-2]) < np.abs(e) / 2)) + 1


def _drive_lags(v_in: np.ndarray, taps: int) -> np.ndarray | None:
    """The columns of a linear response to the drive: 1 and its last `taps` samples (standardised), one row
    per sample from the `taps`-th on; None for fewer than 8 × `taps` samples or a drive that does not move."""
    n = v_in.size
    if n < 8 * taps or not np.ptp(v_in) > 0:
        return None
    u = (v_in - v_in.mean()) / np.std(v_in)
    return np.column_stack([np.ones(n - taps + 1)] + [u[taps - 1 - k : n - k] for k in range(taps)])


def _drive_free(w: np.ndarray, v_in: np.ndarray, taps: int = FIR_TAPS) -> np.ndarray:
    """w less its least-squares linear response to the drive's last `taps` samples (NaN before them).

    w itself where `_drive_lags` has none.
    """
    lags = _drive_lags(v_in, taps)
    if lags is None:
        return w
    coef = np.linalg.lstsq(lags, w[taps - 1 :], rcond=1e-8)[0]
    return np.r_[np.full(taps - 1, np.nan), w[taps - 1 :] - lags @ coef]


def spike_samples(w: np.ndarray, v_in: np.ndarray) -> np.ndarray:
    """Indices of isolated spikes in w: samples that leave both neighbours and come back, undriven.

    They are read on r, w less its linear response to the drive (`_drive_free`:
    a fast mode's ringing after a step, an impulse test's responses are the
    drive's). e_i = r_i − (r_{i−1} + r_{i+1})/2 is, for white noise of variance
    σ², of variance 1.5 σ²; a sample counts when |e_i| exceeds `SPIKE_SIGMAS`
    times e's robust spread (1.4826 × its median absolute deviation: the spikes
    do not inflate it) while its neighbours agree with each other to within half
    of it (|r_{i+1} − r_{i−1}| < |e_i|/2: a step moves and stays, and leaves its
    neighbours apart). Gaussian noise passes 8 robust σ about once in 10¹⁵
    samples. Not counted: samples within `SPIKE_AFTER` of a jump of the drive
    (beyond 8 robust spreads of its own differences: a step, not a sine's
    motion), within one of a lone sample of the drive, and any where most
    samples sit on one grid step (no robust spread).
    """
    w, v_in = np.asarray(w, float), np.asarray(v_in, float)
    if w.size < 5:
        return np.zeros(0, int)
    r = _drive_free(w, v_in)
    lone = _lone(r, zero_spread=False)
    if not len(lone) or len(lone) > SPIKE_MAX_FRACTION * w.size:  # so many: a feature of the signal
        return np.zeros(0, int)
    # beyond the tail of every other sample's excursion: a response with content near the Nyquist
    # frequency makes lone-looking samples at its drive's every step, which that tail holds
    e = np.abs(_excursion(r))
    rest = np.isfinite(e)
    near_lone = np.concatenate([lone - 2, lone - 1, lone])  # e's index is the sample's less one
    rest[near_lone[(near_lone >= 0) & (near_lone < e.size)]] = False
    tail = float(np.quantile(e[rest], SPIKE_QUANTILE)) if rest.any() else 0.0
    lone = lone[e[lone - 1] > SPIKE_OVER_TAIL * tail]
    jumps = _drive_jumps(v_in)
    driven = _lone(v_in, zero_spread=True)
    near = np.concatenate([jumps + k for k in range(-1, SPIKE_AFTER + 1)] + [driven - 1, driven, driven + 1])
    return lone[~np.isin(lone, near)]


def glitch_runs(w: np.ndarray, v_in: np.ndarray) -> list[tuple[int, int]]:
    """Glitches in w: runs (first, last) of 2 to `GLITCH_RUN` samples that w jumps into and back out of, undriven.

    Read on w itself, by its differences d_i = w_{i+1} − w_i: not on w less
    its linear response to the drive, as `spike_samples` reads, whose fit,
    cut at its last tap, steps where a jump of the drive leaves its window
    (a slow plant's pair of such steps 10 samples apart read as a glitch). A
    run a..b is entered by a jump d_{a−1} and left by one d_b of the other
    sign, each beyond `SPIKE_SIGMAS` robust spreads of d (1.4826 × its median
    absolute deviation); it comes back (w_{b+1} within the smaller jump of
    w_{a−1}: a step moves and stays; a response to a drive that moved
    meanwhile may leave it short of w_{a−1}); each of its samples stays off the
    level midway between w_{a−1} and w_{b+1} by over half the smaller jump (a
    plateau away, not a passing wiggle); and it is alone: no other difference
    within `SPIKE_LOCAL` samples either side of it reaches the smaller jump
    over `SPIKE_ALONE` (a ringing jumps at every sample). Not counted: a run
    that starts from the sample before a jump of the drive to `SPIKE_AFTER`
    samples after it (a response's first samples, a short pulse's response:
    a run that starts earlier is not the jump's doing), and every run when
    together they hold more than `GLITCH_MAX_FRACTION` of the samples (a
    feature of the signal). Single samples are `spike_samples`'s.
    """
    w, v_in = np.asarray(w, float), np.asarray(v_in, float)
    n = w.size
    if n < 2 * GLITCH_RUN:
        return []
    d = np.diff(w)
    spread = _mad_spread(d)
    if not spread > 0:
        return []
    big = np.flatnonzero(np.abs(d) > SPIKE_SIGMAS * spread)
    # a run that starts where a jump of the drive may move w (from the sample before it, a frame's
    # timing, to `SPIKE_AFTER` after) may be the response; one that starts before the jump cannot be
    at = np.concatenate([_drive_jumps(v_in) + k for k in range(-1, SPIKE_AFTER + 1)])
    driven = np.zeros(n, bool)
    driven[at[(at >= 0) & (at < n)]] = True
    runs: list[tuple[int, int]] = []
    taken = -1
    for i in big:  # the jump into a run a = i + 1 ...
        if i + 1 <= taken:
            continue
        for j in big[(big >= i + 2) & (big <= i + GLITCH_RUN)]:  # ... and out of it, b = j
            if np.sign(d[j]) == np.sign(d[i]):
                continue
            jump = min(abs(d[i]), abs(d[j]))
            level = (w[i] + w[j + 1]) / 2
            if abs(w[j + 1] - w[i]) >= jump or np.min(np.abs(w[i + 1 : j + 1] - level)) <= jump / 2:
                continue
            around = np.r_[d[max(i - SPIKE_LOCAL, 0) : i], d[j + 1 : j + 1 + SPIKE_LOCAL]]
            if around.size and np.max(np.abs(around)) >= jump / SPIKE_ALONE:
                continue
            if not driven[i + 1]:
                runs.append((int(i + 1), int(j)))
                taken = j
            break
    if sum(b - a + 1 for a, b in runs) > GLITCH_MAX_FRACTION * n:
        return []
    return runs


def bridged(w: np.ndarray, runs) -> np.ndarray:
    """A copy of w with each run (first, last) on the straight line between the samples either side of it."""
    original = np.asarray(w, float)
    out = original.copy()
    for a, b in runs:
        out[a : b + 1] = np.interp(np.arange(a, b + 1), [a - 1, b + 1], [original[a - 1], original[b + 1]])
    return out


def spike_sentence(w: np.ndarray, lone: np.ndarray, rate: float, glitches=()) -> str:
    """The warning about `lone` spikes and `glitches` (runs (first, last)) of w: how many, the largest, what to do."""
    runs = [(int(k), int(k)) for k in lone] + [(int(a), int(b)) for a, b in glitches]
    if not runs:
        return ""
    # how far a run's samples sit off the level around it (a lone spike's: its excursion)
    size, k = max((float(np.max(np.abs(w[a : b + 1] - (w[a - 1] + w[b + 1]) / 2))), a) for a, b in runs)
    what = (
        [f"{len(lone)} isolated spike(s), samples that leave both neighbours and come back"]
        if len(lone)
        else []
    )
    if glitches:
        lengths = sorted({b - a + 1 for a, b in glitches})
        spread = f"{lengths[0]}–{lengths[-1]}" if len(lengths) > 1 else f"{lengths[0]}"
        what.append(f"{len(glitches)} glitch(es), runs of {spread} samples that w jumps into and back out of")
    span = float(np.ptp(w)) or 1.0
    return (
        f"w has {' and '.join(what)} (the largest {100 * size / span:.0f} % of w's range, at t = {k / rate:.4g} s): "
        "a tracker that lost its marker, a sensor that dropped out or an electrical glitch reads so (as does a "
        "system that flips and flips back by itself: a relay, a contact that chatters); the floor is estimated "
        "without them, but every fit and score still counts them and they dilute every gain: remove or "
        "interpolate them and diagnose again"
    )


def difference_variance(w: np.ndarray, order: int) -> float:
    """σ² from the k-th differences: mean((Δᵏw)²) / C(2k, k)."""
    d = np.diff(np.asarray(w, float), n=order)
    return float(np.mean(d**2) / math.comb(2 * order, order)) if d.size else float("nan")


def spectral_variance(w: np.ndarray, rate: float, band=SPECTRAL_BAND) -> float:
    """σ² from the Welch PSD's median level in `band` (fractions of Nyquist): σ² = level · f_s / 2."""
    import scipy.signal

    w = np.asarray(w, float)
    nperseg = int(min(256, max(16, w.size // 8)))
    if w.size < 2 * nperseg:
        return float("nan")
    f, pxx = scipy.signal.welch(w - np.mean(w), fs=rate, nperseg=nperseg, detrend="linear")
    nyquist = rate / 2
    top = pxx[(f >= band[0] * nyquist) & (f < band[1] * nyquist)]
    if top.size == 0:
        return float("nan")
    # Each Welch bin is ~ level · χ²_ν/ν with ν ≈ 2 × segments (50 % overlap: fewer independent);
    # the median of χ²_ν/ν is ≈ (1 − 2/(9ν))³ (Wilson–Hilferty).
    segments = max(1, (w.size - nperseg) // (nperseg // 2) + 1)
    nu = 2.0 * segments * 0.7
    return float(np.median(top) / (1 - 2 / (9 * nu)) ** 3 * rate / 2)


def repeat_variance(w: np.ndarray, v_in: np.ndarray, min_period: int = 8) -> tuple[float, int]:
    """σ² from repetitions of the drive, and the period found (0 when the drive does not repeat exactly).

    The period is the shortest lag at which the drive equals itself (to 1e-9 of its
    range) for at least three whole periods; w's spread across the periods at each
    phase, with P/(P − 1) for the mean removed, is the noise.
    """
    v = np.asarray(v_in, float)
    w = np.asarray(w, float)
    n = v.size
    span = float(np.ptp(v)) or 1.0
    tol = 1e-9 * span
    head = min(64, n // 3)
    # Candidates: lags at which the drive's first samples come back (cheap), then the whole check.
    for lag in np.nonzero(np.abs(v[min_period : n // 3 + 1] - v[0]) <= tol)[0] + min_period:
        period = int(lag)
        if np.max(np.abs(v[period : period + head] - v[:head])) > tol:
            continue
        if np.max(np.abs(v[period:] - v[:-period])) <= tol:
            reps = n // period
            stack = w[: reps * period].reshape(reps, period)
            # The first period carries the start-up transient from rest: leave it out when there are enough.
            if reps >= 4:
                stack = stack[1:]
            p = stack.shape[0]
            return float(np.mean(np.var(stack, axis=0)) * p / (p - 1)), period
    return float("nan"), 0


def _estimators(rate: float) -> dict:
    """Each model-free estimator by name: (w, v_in) -> σ²."""
    Estimator = Callable[[np.ndarray, np.ndarray], float]

    def differences(order: int) -> Estimator:
        return lambda w, v: difference_variance(w, order)

    out: dict[str, Estimator] = {f"differences_{k}": differences(k) for k in DIFFERENCE_ORDERS}
    out["spectrum"] = lambda w, v: spectral_variance(w, rate)
    out["repeats"] = lambda w, v: repeat_variance(w, v)[0]
    return out


def noise_floor(w, v_in, rate: float, blocks: int = 8) -> NoiseFloor:
    """Estimate the measurement noise of `w` (sampled at `rate` Hz, driven by `v_in`) from the data alone."""
    w = np.asarray(w, float)
    v_in = np.asarray(v_in, float)
    quantum = quantisation_step(w)  # of the values as stored
    spread = float(np.var(w))
    lone, glitches = spike_samples(w, v_in), glitch_runs(w, v_in)
    note = spike_sentence(w, lone, rate, glitches)
    runs = [(int(k), int(k)) for k in lone] + glitches
    spikes = np.unique([k for a, b in runs for k in range(a, b + 1)]).astype(int)
    w = bridged(w, runs)  # for the estimators alone (a lone spike: its neighbours' mean)
    estimators = _estimators(rate)
    estimates = {name: f(w, v_in) for name, f in estimators.items()}
    if not np.isfinite(estimates["repeats"]):
        del estimates["repeats"]  # the drive does not repeat itself
    finite = {k: v for k, v in estimates.items() if np.isfinite(v)}
    method = min(finite, key=finite.__getitem__)
    variance = finite[method]
    # Spread over blocks: the chosen estimator on each contiguous block.
    on_blocks = [
        estimators[method](part_w, part_v)
        for part_w, part_v in zip(np.array_split(w, blocks), np.array_split(v_in, blocks))
    ]
    per_block = np.asarray([x for x in on_blocks if np.isfinite(x)])
    std_error = (
        float(np.std(per_block, ddof=1) / math.sqrt(per_block.size)) if per_block.size > 1 else float("nan")
    )
    period = repeat_variance(w, v_in)[1] if method == "repeats" else 0
    floor = NoiseFloor(
        variance=variance,
        std_error=std_error,
        method=method,
        estimates=estimates,
        fraction_of_variance=variance / spread if spread > 0 else float("nan"),
        source=describe_source(method, w.size, rate, period),
        quantum=quantum,
        warnings=floor_warnings(math.sqrt(variance), quantum) + ((note,) if note else ()),
        spikes=tuple(int(k) for k in spikes),
        glitches=tuple(glitches),
        spike_note=note,
    )
    levels = float(np.ptp(w)) / quantum if np.isfinite(quantum) and quantum > 0 else 0.0
    if method == "repeats":  # the repetitions already removed the signal, however fast
        return _at_least_rounding(floor, levels)
    linear = linear_fit_residual(w, v_in)
    if linear is None:
        return _at_least_rounding(floor, levels)
    what = (
        f"w's residual from a linear fit to the drive's last {FIR_TAPS} samples (fitted on its first half, "
        "read on its second)"
    )
    return _at_least_rounding(_leaked(floor, [linear], "linear_fit", what, blocks), levels)


def _at_least_rounding(floor: NoiseFloor, levels: float) -> NoiseFloor:
    """`floor`, or the rounding of w's values to their grid (σ² = step²/12) where that is larger.

    Values stored on a coarse grid (a sensor's or an ADC's steps) are the signal
    rounded: where the signal crosses `ROUNDING_LEVELS` steps or more, the
    rounding error is spread evenly over a step, and no model of the plant comes
    nearer the stored values than step/√12. The estimators read w's variation
    from one sample to the next, which a slow signal on a coarse grid hides (it
    stays on a level for samples on end): a probe's plant read by a quantiser of
    a tenth of its range gave σ = 0.125 against the rounding's 0.205, and its
    right model was called 64 % unexplained. Its `method` is then
    `ROUNDING`, and no residual lowers it (`bounded_by_residual`).
    """
    rounding = floor.quantum**2 / 12.0 if np.isfinite(floor.quantum) else 0.0
    if levels < ROUNDING_LEVELS or not floor.variance < rounding:
        return floor
    read = math.sqrt(floor.variance)
    return dataclasses.replace(
        floor,
        variance=rounding,
        std_error=float("nan"),
        method=ROUNDING,
        estimates={**floor.estimates, ROUNDING: rounding},
        fraction_of_variance=floor.fraction_of_variance * rounding / floor.variance
        if floor.variance > 0
        else float("nan"),
        source=(
            f"the rounding of w's values to their grid (step {floor.quantum:.3g}: σ = step/√12 = "
            f"{math.sqrt(rounding):.3g}), above the {read:.3g} that w's own variation gave ({floor.method}): "
            "no model of the plant comes nearer the stored values"
        ),
        warnings=(
            f"w's values lie on a grid of step {floor.quantum:.3g} ({levels:.0f} steps over its range: a "
            f"coarse sensor's or ADC's), whose rounding alone is σ = {math.sqrt(rounding):.3g}, more than "
            f"w's own variation gave ({read:.3g}): the floor is the rounding's",
        )
        + ((floor.spike_note,) if floor.spike_note else ()),
    )


def bounded_by_residual(floor: NoiseFloor, residual, segment, blocks: int = 8) -> NoiseFloor:
    """`floor`, or a tighter one from a fitted model's held-out `residual` where the signal leaked into `floor`.

    `residual`: w − ŵ on held-out samples (the model was not fitted to them, so
    its noise is the measurement's); `segment`: an id per sample, differences
    are taken within each contiguous segment only. See `_leaked`.
    """
    residual = np.asarray(residual, float)
    cuts = np.flatnonzero(np.diff(np.asarray(segment)) != 0) + 1
    parts = np.split(residual, cuts)
    return _leaked(
        floor, parts, "residual", f"the fitted model's held-out residual ({len(parts)} segment(s))", blocks
    )


def linear_fit_residual(w, v_in, taps: int = FIR_TAPS) -> np.ndarray | None:
    """w's residual on its second half from a linear fit to the drive's last `taps` samples on its first half.

    w[n] ≈ c + Σₖ hₖ u[n − k], k < `taps` (least squares): a response that settles
    within `taps` samples is taken out whatever its frequency, a slower one is
    left as a slow residual that differences remove. None when the recording
    has fewer than 8 × `taps` samples or a drive that does not move.
    """
    w, v_in = np.asarray(w, float), np.asarray(v_in, float)
    lags = _drive_lags(v_in, taps)
    if lags is None:
        return None
    y = w[taps - 1 :]
    half = y.size // 2
    coef = np.linalg.lstsq(lags[:half], y[:half], rcond=1e-8)[0]
    return y[half:] - lags[half:] @ coef


def _leaked(floor: NoiseFloor, parts, label: str, what: str, blocks: int = 8) -> NoiseFloor:
    """`floor`, or the differences of a residual where they lie below `RESIDUAL_SWITCH` × `floor.variance`.

    `parts`: contiguous pieces of a residual (noise plus what a fit misses, on
    samples it was not fitted to); for each order k = 1..4, σ²_k = mean((Δᵏr)²) /
    C(2k, k) over every piece's differences: noise plus the fast part of the
    miss, an upper bound on σ² as the model-free estimators are. The smallest
    replaces `floor` (method ``<label>_differences_k``, its standard error the
    spread over `blocks` blocks of the squared differences).
    """
    parts = [np.asarray(p, float) for p in parts if np.size(p) > 2 * max(DIFFERENCE_ORDERS)]
    if not parts or floor.method == ROUNDING:  # no fit comes nearer the stored values than their rounding
        return floor
    squares = {
        k: np.concatenate([np.diff(p, n=k) ** 2 for p in parts]) / math.comb(2 * k, k)
        for k in DIFFERENCE_ORDERS
    }
    estimates = {f"{label}_differences_{k}": float(np.mean(v)) for k, v in squares.items()}
    order = min(squares, key=lambda k: estimates[f"{label}_differences_{k}"])
    variance = estimates[f"{label}_differences_{order}"]
    if not (np.isfinite(variance) and variance < RESIDUAL_SWITCH * floor.variance):
        return dataclasses.replace(floor, estimates={**floor.estimates, **estimates})
    means = np.asarray([b.mean() for b in np.array_split(squares[order], blocks) if b.size])
    std_error = float(np.std(means, ddof=1) / math.sqrt(means.size)) if means.size > 1 else float("nan")
    n = sum(p.size for p in parts)
    name = _ORDINALS[order]
    source = (
        f"the {name} differences of {what} over {n} samples, white noise assumed (w's own estimate, "
        f"σ = {floor.std:.3g} from its {floor.method}, read a signal that is fast beside the noise)"
    )
    return dataclasses.replace(
        floor,
        variance=variance,
        std_error=std_error,
        method=f"{label}_differences_{order}",
        estimates={**floor.estimates, **estimates},
        fraction_of_variance=floor.fraction_of_variance * variance / floor.variance,
        source=source,
        warnings=floor_warnings(math.sqrt(variance), floor.quantum)
        + ((floor.spike_note,) if floor.spike_note else ()),
    )
