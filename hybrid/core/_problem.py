"""A least-squares problem: a model, the data it is fitted to, and which leaves are free.

The residuals of a split are r = (w − ŵ)/σ_w over every recording's segments of
that split, with σ_w the standard deviation of the training displacement, so
that costs are dimensionless. The parameters being fitted are flattened into one
vector θ = [θ_sim, θ_readout].

The Jacobian is built from the model's structure instead of differentiating
the whole pytree:

- J_sim (m × k, k ≈ 6): forward mode through the simulation's `lax.scan`, one
  tangent per free physical parameter, pushed through the readout;
- J_readout (m × n): the readout is per-sample, so its Jacobian rows are the
  gradients of ŵ_i with respect to the readout's weights, one `vmap` over the
  m input windows.

For 3,000 residuals × 1,727 parameters a whole LM step built on it is ~18×
faster and takes ~10× less peak memory than a step of
`optimistix.LevenbergMarquardt` on the same residuals (`benchmarks/lm_step.py`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from ..util._errors import InputError
from ._arguments import simulated
from ._models import Model
from ._parameters import Real
from ._simulation import DRIVE, drive_power

#: Above this many bytes, J's readout columns are built a chunk of rows at a time (`normal_equations`).
JACOBIAN_CHUNK_BYTES = 2**27
MIN_CHUNK_ROWS = 64
#: At or above this many multiply-adds (rows × n²), a chunk's JᵀJ is BLAS's symmetric rank-k update
#: on the host (`gram`); below it, XLA's product (a program with a host call is never cached on disk).
HOST_GRAM_MACS = 2**33


class Series(eqx.Module):
    """One recording prepared for fitting: drive, displacement, and its split segments.

    `weights` (optional): per split, a 0/1 array over every sample. A series
    padded to a bucket's length ([`bucketed_series`][]) has one segment per split,
    the whole padded series, and the weights say which samples belong to the
    split: residuals outside it are exactly zero. Its static layout then depends
    only on the bucket's length, so one compiled program serves every recording
    that falls in the bucket.
    """

    v_in: jax.Array
    w: jax.Array
    dt: float = eqx.field(static=True)
    segments: tuple[tuple[str, tuple[tuple[int, int], ...]], ...] = eqx.field(static=True)
    weights: tuple[tuple[str, jax.Array], ...] | None = None
    spans: tuple[tuple[str, np.ndarray | jax.Array], ...] | None = None

    def segments_of(self, split: str) -> tuple[tuple[int, int], ...]:
        return dict(self.segments)[split]

    def recorded_segments_of(self, split: str) -> tuple[tuple[int, int], ...]:
        """The split's (start, stop) samples of the recording itself, padding excluded (host side)."""
        if self.spans is None:
            return self.segments_of(split)
        return tuple((int(a), int(b)) for a, b in np.asarray(dict(self.spans)[split]) if b > a)

    @property
    def n_recorded(self) -> int:
        """Samples of the recording itself (host side): the padded length less the padding."""
        if self.spans is None:
            return int(self.v_in.shape[0])
        return max(int(np.max(np.asarray(spans)[:, 1])) for _, spans in self.spans if len(spans))

    def target(self, split: str) -> jax.Array:
        return jnp.concatenate([self.w[a:b] for a, b in self.segments_of(split)])

    def weight(self, split: str) -> jax.Array | None:
        """The split's 0/1 weights over `target(split)`, or None when every sample counts."""
        return None if self.weights is None else dict(self.weights)[split]


def segment_ids(series: Sequence[Series], split: str) -> np.ndarray:
    """An id per sample of `split` (every series' segments in turn, as `target(split)` lays them out)."""
    lengths = [b - a for s in series for a, b in s.segments_of(split)]
    return np.repeat(np.arange(len(lengths)), lengths)


def _weight_of(series: Series, split: str) -> jax.Array:
    weight = series.weight(split)
    return jnp.ones(series.target(split).shape[0], series.w.dtype) if weight is None else weight


def robust_std(x):
    """std(x), without overflow or underflow at any magnitude (w in m, mm or µm, ×1e±300).

    x is divided by the power of two just above max |x| first: that division and
    the multiplication back are exact, so for ordinary magnitudes the result is
    bit for bit `jnp.std(x)`.
    """
    x, p = _binary_scaled(x)
    return jnp.std(x) * p


def robust_rms(x):
    """rms(x) without overflow or underflow (see `robust_std`)."""
    x, p = _binary_scaled(x)
    return jnp.sqrt(jnp.mean(x**2)) * p


def _binary_scaled(x):
    """(x / p, p) with p the power of two just above max |x| (exact in floating point)."""
    x = jnp.asarray(x)
    _, exponent = jnp.frexp(jnp.max(jnp.abs(x)))
    p = jnp.ldexp(jnp.ones((), x.dtype), exponent)
    return x / p, p


def series_from_recording(
    recording,
    fractions=(0.3, 0.5, 0.2),
    order=("train", "test", "validation"),
    blocks: int = 1,
    *,
    measured_only: bool = True,
):
    """A [`Series`][] from a Recording, split in time (paper: 30/50/20 %, contiguous).

    With `blocks` > 1 the recording is cut into that many equal chunks and each
    chunk is split by `fractions` in `order`: every part then spans the whole
    recording. The simulation still runs over every sample (it never sees the
    measured displacement), so a held-out block is predicted from the drive
    alone, with the state the earlier samples left; it interpolates in time
    instead of extrapolating past the training data.

    With `measured_only` (the default) the samples a ``quality`` column marks 0
    (rig's: w held or interpolated there, not measured; `unmeasured_runs`) are
    in no part: no fit weighs them and no score counts them
    (`without_unmeasured`). `diagnose` passes False and leaves them out of its
    padded series itself.
    """
    segments = split_segments(recording, fractions, order, blocks)
    if measured_only:
        quality = getattr(recording, "extra", {}).get("quality")
        segments = without_unmeasured(segments, unmeasured_runs(quality), recording.name)
    # device_put, not jnp.asarray: no compiled program per recording length
    return Series(
        jax.device_put(np.asarray(recording.v_in)),
        jax.device_put(np.asarray(recording.w)),
        float(recording.dt),
        segments,
    )


def unmeasured_runs(quality) -> list[tuple[int, int]]:
    """Runs (first, last) of a 0/1 ``quality`` column's 0s (w not measured there); [] without such a column."""
    if quality is None:
        return []
    q = np.asarray(quality, float)
    if not np.isin(q, (0.0, 1.0)).all():
        return []
    edges = np.diff(np.r_[1.0, q, 1.0])  # −1 where a run of 0s begins, +1 after it ends
    starts, stops = np.flatnonzero(edges < 0), np.flatnonzero(edges > 0) - 1
    return [(int(a), int(b)) for a, b in zip(starts, stops)]


def unmeasured_mask(runs, n: int) -> np.ndarray:
    """True at the `n` samples that `runs` ((first, last), `unmeasured_runs`) cover: w not measured there."""
    mask = np.zeros(int(n), bool)
    for a, b in runs:
        mask[a : b + 1] = True
    return mask


def unmeasured_of(recording) -> np.ndarray:
    """True at the samples of `recording` whose ``quality`` column (rig's) is 0: w not measured there."""
    return unmeasured_mask(unmeasured_runs(recording.extra.get("quality")), recording.n)


def without_unmeasured(parts, runs, name: str = "") -> tuple[tuple[str, tuple[tuple[int, int], ...]], ...]:
    """`parts` ((part, ((start, stop), ...)), ...) with the samples of `runs` ((first, last)) left out.

    Each (start, stop) is cut into the pieces between the runs. A part that had
    samples and is left with none is refused (nothing to fit or to score
    there), with how to go on; `name` is the recording's, for that line.
    """
    if not runs:
        return tuple((part, tuple((int(a), int(b)) for a, b in rows)) for part, rows in parts)
    end = max([int(b) + 1 for _, b in runs] + [int(b) for _, rows in parts for _, b in rows])
    measured = ~unmeasured_mask(runs, end)
    out = []
    for part, rows in parts:
        pieces = []
        for a, b in rows:
            edges = np.diff(np.r_[0, measured[a:b].astype(int), 0])
            pieces += [
                (int(a + p), int(a + q)) for p, q in zip(np.flatnonzero(edges > 0), np.flatnonzero(edges < 0))
            ]
        if not pieces and any(b > a for a, b in rows):
            raise InputError(
                f"recording '{name}': every sample of its {part} part has quality 0 (w not measured there): "
                "leave the unmeasured stretch out with --range, or track the video again"
            )
        out.append((part, tuple(pieces)))
    return tuple(out)


def split_segments(
    recording, fractions=(0.3, 0.5, 0.2), order=("train", "test", "validation"), blocks: int = 1
) -> tuple[tuple[str, tuple[tuple[int, int], ...]], ...]:
    """The (part, ((start, stop), ...)) of each part of `series_from_recording`'s split, in `order`."""
    if int(blocks) != blocks or blocks < 1:
        raise InputError(f"blocks must be a whole number ≥ 1, got {blocks!r}")
    edges = [round(k * recording.n / blocks) for k in range(int(blocks) + 1)]
    parts: dict[str, list[tuple[int, int]]] = {name: [] for name in order}
    for lo, hi in zip(edges[:-1], edges[1:]):
        chunk = recording if (lo, hi) == (0, recording.n) else recording.segment(slice(lo, hi))
        for name, s in chunk.split(fractions=fractions, order=order).slices.items():
            parts[name].append((lo + s.start, lo + s.stop))
    return tuple((name, tuple(parts[name])) for name in order)


#: Recordings are padded to the next of these multiples of a power of two (`bucket_length`).
BUCKET_STEPS = (1.0, 1.25, 1.5, 1.75)
#: The shortest bucket (samples).
MIN_BUCKET = 256


def bucket_length(n: int) -> int:
    """The padded length of an `n`-sample series: the next m·2ᵏ with m in `BUCKET_STEPS`, at least `MIN_BUCKET`.

    Consecutive buckets are at most 25 % apart, so padding costs at most a
    quarter more samples, and recordings of a few minutes to a few hours fall
    in a few dozen buckets.
    """
    n = max(int(n), MIN_BUCKET)
    k = max(int(np.floor(np.log2(n))), 0)
    for power in (k, k + 1):
        for m in BUCKET_STEPS:
            length = int(round(m * 2**power))
            if length >= n:
                return length
    raise AssertionError(n)  # unreachable: 2^(k+1) > n


def bucketed_series(series: Series, length: int) -> Series:
    """`series` padded to `length` samples, its segments as per-split weights (see [`Series`][]).

    The drive is padded with its last value (the simulation is causal: the
    padding never changes a real sample's output), w with zeros; every split's
    weight is 1 on its own samples and 0 elsewhere, the padding included.
    """
    n = int(series.v_in.shape[0])
    if length < n:
        raise ValueError(f"cannot pad {n} samples to {length}")
    v_in, w = np.asarray(series.v_in), np.asarray(series.w)  # padded on the host: no program per length
    v_in = jax.device_put(np.concatenate([v_in, np.full(length - n, v_in[-1], v_in.dtype)]))
    w = jax.device_put(np.concatenate([w, np.zeros(length - n, w.dtype)]))
    weights = []
    for name, spans in series.segments:
        mask = np.zeros(length, w.dtype)
        for a, b in spans:
            mask[a:b] = 1.0
        weights.append((name, jax.device_put(mask)))
    segments = tuple((name, ((0, length),)) for name, _ in series.segments)
    recorded = tuple((name, span_rows(s)) for name, s in series.segments)
    return Series(v_in, w, series.dt, segments, tuple(weights), recorded)


def _target_scale(series) -> jax.Array:
    """w's robust std on the training part of `series` (1 where w is constant: refused by fit)."""
    if any(s.weights is not None for s in series):  # padded series: the training samples alone, on the host
        train = np.concatenate(
            [np.asarray(s.target("train"))[np.asarray(_weight_of(s, "train")) > 0] for s in series]
        )
        top = float(np.max(np.abs(train)))
        power = np.ldexp(1.0, int(np.frexp(top)[1])) if np.isfinite(top) and top > 0 else 1.0
        std = jax.device_put(np.asarray(np.std(train / power) * power))  # `robust_std` in numpy
    else:
        std = robust_std(jnp.concatenate([s.target("train") for s in series]))
    return jnp.where(std > 0, std, jnp.ones_like(std))


#: The drive's largest |value| in the middle of the span that θ holds as given (`_drive_decade`).
DRIVE_MIDDLE = 2.0


def _drive_decade(series) -> int:
    """k of the SI prefix 1000ᵏ the drive's largest |value| is held in: 0 for 0.063 to 63 units.

    The span is centred on `DRIVE_MIDDLE` units, a few volts: every drive of
    the repo's data and tests lies in it (Silverbox's 0.092 V, ±2 V strips, a
    0–10 V pump, a 50 W heater), so each is fitted as before this scaling, to
    the last bit. A drive in the next prefix (the same in mV, or kV) gets k ± 1:
    a unit change moves k and nothing else. Read on the whole drive (an
    input, known on every split; padding repeats its last value). Traced
    drives (a problem built under `jit`) get 0.
    """
    if any(isinstance(s.v_in, jax.core.Tracer) for s in series):
        return 0
    top = max(float(np.max(np.abs(np.asarray(s.v_in)))) if np.size(s.v_in) else 0.0 for s in series)
    if not (np.isfinite(top) and top > 0):
        return 0
    return int(np.round(np.log10(top / DRIVE_MIDDLE) / 3.0))


def _theta_units(simulation, frozen, decade: int, n_sim: int) -> np.ndarray:
    """Each θ_sim entry's unit: 1000^(decade · p), p the drive's power in its parameter's unit.

    Only `Real` parameters: a `Positive` one is optimised in log, where a unit
    is a shift, which LM's steps do not see. 1 wherever the simulation's units
    or layout cannot be read (a plug-in without `units`, a parameter that is
    not a scalar): θ as given, as before this scaling.
    """
    ones = np.ones(n_sim)
    if decade == 0 or n_sim == 0:
        return ones
    try:
        order = simulation.free_parameter_order(frozen)
        units = simulation.units_in(DRIVE)
        constraints = simulation.constraints
    except (InputError, TypeError, ValueError):
        return ones
    if len(order) != n_sim:
        return ones
    return np.array(
        [
            _in_prefix(units.get(name, ""), decade) if isinstance(constraints.get(name), Real) else 1.0
            for name in order
        ]
    )


def _in_prefix(unit: str, decade: int) -> float:
    """1000^(decade · p), p the drive's power in `unit` (`drive_power`; 0 where `unit` does not parse)."""
    return 1000.0 ** (decade * (drive_power(unit) or 0.0))


def _rescalable(readout) -> bool:
    """Whether `readout` is a grey-box readout that `rescaled` converts (its θ then in units of w's scale)."""
    if not readout.parameters():  # a black box (the D-MLP): its weights, penalised, stay as they are
        return False
    try:
        readout.rescaled(1.0, 1.0)
    except NotImplementedError:
        return False
    return True


#: Rows of a padded series' spans per split, empty (0, 0) rows filling the rest (more rows only for
#: more segments): one array shape whatever the blocks, so recordings of one bucket split into
#: different numbers of blocks share its compiled programs (the spans are read on the host only).
SPAN_ROWS = 16


def span_rows(spans) -> np.ndarray:
    rows = np.asarray(spans, np.int64).reshape(-1, 2)
    return np.concatenate([rows, np.zeros((max(SPAN_ROWS - len(rows), 0), 2), np.int64)])


class Problem(eqx.Module):
    """Residuals and their structured Jacobian for fitting `model` to `series`.

    **Arguments:**

    - `model`: the model at its starting point (its fixed leaves stay as they are).
    - `series`: the recordings, as [`Series`][].
    - `frozen`: names of parameters to keep fixed (see `Model.parameter_names`).
    - `weight_decay`: μ ≥ 0, adds ½ μ ‖θ_network‖² to the cost (only the weights of a
      black-box readout such as the D-MLP; physical parameters and linear gains are
      never penalised). It is the residual block √μ θ_network appended to r, i.e.
      ridge regularisation as in MATLAB's Bayesian-regularised LM (`trainbr`).
    - `sim_tangents`: optional (k × n_sim) array of orthonormal directions in θ_sim:
      the forward-mode Jacobian is built along these k directions only (zero rows
      allowed as padding) and the rest of θ_sim gets zero Jacobian columns, so
      Levenberg–Marquardt leaves it in place. An array, not a static option: lanes
      of a batched fit can differ in it without recompiling.

    A grey-box readout (one with named parameters that can be `rescaled`, as
    `LinearReadout`) sits in θ in units of `scale` (w's robust std on the
    training part): its gain and offset are w's unit, and in θ as given LM's
    damping λI and their Jacobian columns would make the end point depend on
    the unit w was recorded in (the same strip in µm and in mm named different
    causes). The drive's unit likewise: θ holds every `Real` parameter whose
    unit has the drive's in it (a loop's height in V, an even part's
    coefficient in 1/V, a gain in mm/V) in the SI prefix that the drive's
    size falls in (`_drive_decade`: 1000ᵏ, k = 0 for a drive of 0.063 to 63
    units), so the same recording in mV, V or kV takes the same LM steps
    (before, a draw of `experiments/discrepancy.py` in mV fitted a baseline up
    to 6× worse than in V: `experiments/results/drive_units.md`). A prefix,
    not the drive's own size: a prefix is what a unit changes, and θ stays as
    before for every drive of ordinary size. `model(θ)` and `flatten` convert,
    so no caller sees the difference.
    """

    sim_static: eqx.Module
    readout_static: eqx.Module
    unravel_sim: Callable = eqx.field(static=True)
    unravel_readout: Callable = eqx.field(static=True)
    series: tuple[Series, ...]
    scale: jax.Array
    kind: str = eqx.field(static=True)
    n_sim: int = eqx.field(static=True)
    n_readout: int = eqx.field(static=True)
    weight_decay: float = eqx.field(static=True)
    sim_tangents: jax.Array | None
    readout_in_scale: bool = eqx.field(static=True)
    sim_units: jax.Array
    output_units: jax.Array

    def __init__(
        self, model: Model, series, frozen=frozenset(), weight_decay: float = 0.0, sim_tangents=None
    ):
        series = tuple(series)
        if not series:
            raise InputError("no recordings to fit: pass at least one recording")
        self.series = series
        self.scale = _target_scale(series)
        self.readout_in_scale = _rescalable(model.readout)
        spec = model.trainable(frozen)
        sim_dyn, self.sim_static = eqx.partition(model.simulation, spec.simulation)
        theta_sim, self.unravel_sim = ravel_pytree(sim_dyn)
        decade = _drive_decade(series)
        self.sim_units = jnp.asarray(_theta_units(model.simulation, frozen, decade, int(theta_sim.size)))
        self.output_units = jnp.asarray(
            _in_prefix(str(getattr(model.simulation, "output_unit", "") or ""), decade)
        )
        readout_dyn, self.readout_static = eqx.partition(self._to_theta_units(model.readout), spec.readout)
        theta_readout, self.unravel_readout = ravel_pytree(readout_dyn)
        self.n_sim = int(theta_sim.size)
        self.n_readout = int(theta_readout.size)
        if self.n_sim + self.n_readout == 0:
            raise InputError("every parameter is frozen: free at least one to fit")
        if any(s.weights is not None for s in series) and getattr(model.readout, "window", 1) != 1:
            raise InputError(
                f"padded series need a per-sample readout: a window of {model.readout.window} samples "
                "would reach across a split's start (use series_from_recording's segments)"
            )
        self.kind = model.kind
        if not weight_decay >= 0:
            raise InputError(f"weight_decay must be ≥ 0, got {weight_decay!r}")
        penalised = not model.readout.parameters()  # black-box readouts only
        self.weight_decay = float(weight_decay) if penalised else 0.0
        self.sim_tangents = sim_tangents

    # --- θ ↔ model -------------------------------------------------------------
    def _to_theta_units(self, readout):
        if not self.readout_in_scale:
            return readout
        return readout.rescaled(1.0 / self.output_units, 1.0 / self.scale)

    def flatten(self, model: Model, frozen=frozenset()) -> jax.Array:
        spec = model.trainable(frozen)
        a, _ = ravel_pytree(eqx.filter(model.simulation, spec.simulation))
        b, _ = ravel_pytree(eqx.filter(self._to_theta_units(model.readout), spec.readout))
        return jnp.concatenate([a / self.sim_units, b])

    def split_theta(self, theta):
        return theta[: self.n_sim], theta[self.n_sim :]

    def simulation(self, theta_sim):
        return eqx.combine(self.unravel_sim(theta_sim * self.sim_units), self.sim_static)

    def readout(self, theta_readout):
        readout = eqx.combine(self.unravel_readout(theta_readout), self.readout_static)
        return readout.rescaled(self.output_units, self.scale) if self.readout_in_scale else readout

    def model(self, theta) -> Model:
        a, b = self.split_theta(theta)
        # the signals' units are not kept: a static field, they would compile a program per unit label
        return Model(self.simulation(a), self.readout(b), self.kind)

    # --- residuals -----------------------------------------------------------
    def _signals(self, theta_sim):
        simulation = self.simulation(theta_sim)
        return [simulated(simulation, s.v_in, s.dt) for s in self.series]

    def _windows(self, readout, signals, split):
        return jnp.concatenate(
            [readout.windows(x, s.segments_of(split)) for x, s in zip(signals, self.series)]
        )

    def target(self, split):
        return jnp.concatenate([s.target(split) for s in self.series])

    def recorded(self, values, split):
        """The entries of `values` (laid out as `target(split)`) that are recorded samples, on the host.

        For padded series ([`bucketed_series`][]) the padding and the other
        splits' samples are dropped; otherwise `values` is returned as it is.
        """
        values = np.asarray(values)
        if all(s.spans is None for s in self.series):
            return values
        parts, start = [], 0
        for s in self.series:
            n = int(s.target(split).shape[0])
            here = values[start : start + n]
            parts += [here[a:b] for a, b in s.recorded_segments_of(split)] if s.spans is not None else [here]
            start += n
        return np.concatenate(parts)

    def weights(self, split):
        """0/1 per entry of `target(split)` (padded series), or None when every entry counts."""
        if all(s.weights is None for s in self.series):
            return None
        return jnp.concatenate([_weight_of(s, split) for s in self.series])

    def _weighted(self, r, split):
        weights = self.weights(split)
        return r if weights is None else r * weights.astype(r.dtype)

    def prediction(self, theta, split):
        """ŵ (mm) on `split`, all recordings concatenated."""
        a, b = self.split_theta(theta)
        readout = self.readout(b)
        windows = self._windows(readout, self._signals(a), split)
        return jax.vmap(readout.predict_window)(windows)

    def residuals(self, theta, split="train"):
        return self._weighted((self.target(split) - self.prediction(theta, split)) / self.scale, split)

    def penalty_mask(self, theta):
        """1 for the penalised (network) entries of θ, 0 elsewhere."""
        return jnp.concatenate([jnp.zeros(self.n_sim, theta.dtype), jnp.ones(self.n_readout, theta.dtype)])

    def objective_residuals(self, theta):
        """[r_train, √μ θ_network]: the residuals every solver minimises the squares of."""
        return self._with_penalty(self.residuals(theta), theta)

    def _with_penalty(self, r, theta):
        """`r` followed by the weight decay's rows √μ θ_network (none without weight decay)."""
        if not self.weight_decay:
            return r
        return jnp.concatenate([r, jnp.sqrt(self.weight_decay) * self.penalty_mask(theta) * theta])

    def cost(self, theta):
        """½‖r_train‖² + ½ μ ‖θ_network‖², the objective every solver minimises."""
        r = self.objective_residuals(theta)
        return 0.5 * jnp.sum(r * r)

    def cost_and_validation_loss(self, theta):
        """(`cost`, `validation_loss`) from one simulation of the model."""
        a, b = self.split_theta(theta)
        readout = self.readout(b)
        signals = self._signals(a)
        split = "validation" if self.has_validation else "train"
        losses = {}
        # In this order, not a set's: a set of strings iterates in an order that changes with each
        # process's hash seed, and so would the traced program and its persistent-cache key.
        for name in dict.fromkeys(("train", split)):
            w_hat = jax.vmap(readout.predict_window)(self._windows(readout, signals, name))
            losses[name] = self._weighted((self.target(name) - w_hat) / self.scale, name)
        r = self._with_penalty(losses["train"], theta)
        weights = self.weights(split)
        count = losses[split].shape[0] if weights is None else jnp.maximum(jnp.sum(weights), 1.0)
        return 0.5 * jnp.sum(r * r), 0.5 * jnp.sum(losses[split] ** 2) / count

    @property
    def has_validation(self) -> bool:
        return all("validation" in dict(s.segments) for s in self.series)

    def validation_loss(self, theta):
        """½ mean r² on the validation split (the training split if there is none).

        Picks the best iterate and the best start, whatever the solver.
        """
        split = "validation" if self.has_validation else "train"
        r = self.residuals(theta, split)
        weights = self.weights(split)
        if weights is None:
            return 0.5 * jnp.mean(r**2)
        return 0.5 * jnp.sum(r**2) / jnp.maximum(jnp.sum(weights), 1.0)

    def _residuals_and_sim_jacobian(self, theta, split):
        """r (m,), J_sim (m × k) by forward mode through the simulation, and the readout's input windows."""
        a, b = self.split_theta(theta)
        target = self.target(split)

        def from_sim(theta_sim):
            readout = self.readout(b)
            windows = self._windows(readout, self._signals(theta_sim), split)
            return self._weighted(
                (target - jax.vmap(readout.predict_window)(windows)) / self.scale, split
            ), windows

        if self.n_sim:
            r, linear, windows = jax.linearize(from_sim, a, has_aux=True)
            if self.sim_tangents is None:
                J_sim = jax.vmap(linear, out_axes=1)(jnp.eye(self.n_sim, dtype=a.dtype))
            else:  # only these directions (rows); the others get zero columns
                basis = self.sim_tangents.astype(a.dtype)
                J_sim = jax.vmap(linear, out_axes=1)(basis) @ basis
        else:
            r, windows = from_sim(a)
            J_sim = jnp.zeros((r.shape[0], 0), r.dtype)
        return r, J_sim, windows

    def _readout_jacobian(self, theta, windows):
        """J_readout (rows × n): per window, the gradient of −ŵ/σ_w with respect to the readout's weights."""
        _, b = self.split_theta(theta)

        def predict_one(theta_readout, window):
            return self.readout(theta_readout).predict_window(window)

        return -jax.vmap(jax.grad(predict_one), (None, 0))(b, windows) / self.scale

    def residuals_and_jacobian(self, theta, split="train"):
        """r (m,) and J = ∂r/∂θ (m × n), built from the model's structure."""
        r, J_sim, windows = self._residuals_and_sim_jacobian(theta, split)
        J_r = self._weighted(self._readout_jacobian(theta, windows).T, split).T
        return r, jnp.concatenate([J_sim, J_r], axis=1)

    def normal_equations(self, theta, split="train"):
        """JᵀJ and Jᵀr, never holding J whole when it is large.

        J's readout columns (m × n, 1,726 for the paper's D-MLP) are what grows
        with the record: 10⁶ samples would need ~10 GB. Above `JACOBIAN_CHUNK_BYTES`
        they are built in equal chunks of rows (`chunk_rows`: no padding, a
        shorter last chunk if m does not divide) inside a `lax.scan`, each folded
        into JᵀJ's lower triangle (`gram_lower`: one symmetric rank-k update) and
        Jᵀ[J_sim r] (one product) at once; J_sim (m × k, k ≈ 6) is kept whole. Below it, the
        products of the whole J (the same numbers, summed in another order).
        """
        r, J_sim, windows = self._residuals_and_sim_jacobian(theta, split)
        m, n = r.shape[0], self.n_readout
        rows, full = chunk_rows(m, n, r.dtype.itemsize)
        if n == 0 or full == 0:
            J_r = self._weighted(self._readout_jacobian(theta, windows).T, split).T  # padding rows: zero
            J = jnp.concatenate([J_sim, J_r], axis=1)
            return gram(J), J.T @ r
        if self.weights(split) is not None:  # padded series: a chunk's rows weighted like its residuals
            weights = self.weights(split).astype(r.dtype)
            windows = (windows, weights)
            readout_jacobian = lambda th, x: self._readout_jacobian(th, x[0]) * x[1][:, None]
        else:
            readout_jacobian = self._readout_jacobian
        sim_r = jnp.concatenate([J_sim, r[:, None]], axis=1)  # one product folds Jᵀ J_sim and Jᵀ r

        def fold(acc, chunk):
            window, rhs = chunk
            J_r = readout_jacobian(theta, window)
            return (acc[0] + gram_lower(J_r), acc[1] + J_r.T @ rhs), None

        def whole_chunks(x):
            return jax.tree_util.tree_map(lambda y: y[: full * rows].reshape((full, rows) + y.shape[1:]), x)

        zeros = (jnp.zeros((n, n), r.dtype), jnp.zeros((n, sim_r.shape[1]), r.dtype))
        (A_rr, B), _ = jax.lax.scan(fold, zeros, (whole_chunks(windows), whole_chunks(sim_r)))
        if full * rows < m:  # the shorter last chunk
            rest = jax.tree_util.tree_map(lambda y: y[full * rows :], windows)
            (A_rr, B), _ = fold((A_rr, B), (rest, sim_r[full * rows :]))
        A_rs, g_r = B[:, :-1], B[:, -1]
        JtJ = jnp.block([[J_sim.T @ J_sim, A_rs.T], [A_rs, from_lower(A_rr)]])
        return JtJ, jnp.concatenate([J_sim.T @ r, g_r])


def chunk_rows(m: int, n: int, itemsize: int) -> tuple[int, int]:
    """(rows, full): J's m × n readout block is folded as `full` chunks of `rows` rows, then the rest.

    A chunk holds at most `JACOBIAN_CHUNK_BYTES` (and at least `MIN_CHUNK_ROWS` rows);
    the chunks are as equal as that allows, so the last one is short by less than
    their number, and nothing is padded. ``full == 0``: J is small enough to build whole.
    """
    most = max(MIN_CHUNK_ROWS, JACOBIAN_CHUNK_BYTES // (itemsize * max(n, 1)))
    if n == 0 or m <= most:
        return m, 0
    chunks = -(-m // most)
    rows = -(-m // chunks)
    return rows, m // rows


def gram(J):
    """JᵀJ of a (rows × n) block, exactly symmetric (`gram_lower`, then `from_lower`)."""
    return from_lower(gram_lower(J))


def from_lower(A):
    """The symmetric matrix whose lower triangle (diagonal included) is A's."""
    return jnp.tril(A) + jnp.tril(A, -1).T


def gram_lower(J):
    """A matrix whose lower triangle (diagonal included) is that of JᵀJ; sums of them stay so.

    On the CPU, for a float32/float64 block of at least `HOST_GRAM_MACS`
    multiply-adds, it is BLAS's symmetric rank-k update (``?syrk``: half the
    multiply-adds of a general product, each at the rate of the host's optimised
    BLAS), through `jax.pure_callback`, and the strict upper triangle is 0.
    Otherwise it is XLA's whole ``J.T @ J``.
    """
    rows, n = J.shape
    if (
        J.dtype not in (jnp.float32, jnp.float64)
        or rows * n * n < HOST_GRAM_MACS
        or jax.default_backend() != "cpu"
    ):
        return J.T @ J
    return jax.pure_callback(
        _host_gram_lower, jax.ShapeDtypeStruct((n, n), J.dtype), J, vmap_method="sequential"
    )


def _host_gram_lower(J):
    from scipy.linalg import blas

    J = np.asarray(J)
    syrk = blas.dsyrk if J.dtype == np.float64 else blas.ssyrk
    # J.T is J's memory read column-major (no copy); the upper triangle of JᵀJ, column-major,
    # read row-major (.T, no copy) is its lower triangle.
    return syrk(1.0, J.T, trans=0, lower=0).T
