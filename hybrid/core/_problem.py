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

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.flatten_util import ravel_pytree

from ..util._errors import InputError
from ._models import Model

#: Above this many bytes, J's readout columns are built a chunk of rows at a time (`normal_equations`).
JACOBIAN_CHUNK_BYTES = 2**27
MIN_CHUNK_ROWS = 64


class Series(eqx.Module):
    """One recording prepared for fitting: drive, displacement, and its split segments."""

    v_in: jax.Array
    w: jax.Array
    dt: float = eqx.field(static=True)
    segments: tuple[tuple[str, tuple[tuple[int, int], ...]], ...] = eqx.field(static=True)

    def segments_of(self, split: str) -> tuple[tuple[int, int], ...]:
        return dict(self.segments)[split]

    def target(self, split: str) -> jax.Array:
        return jnp.concatenate([self.w[a:b] for a, b in self.segments_of(split)])


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
    return jnp.sqrt(jnp.mean(x ** 2)) * p


def _binary_scaled(x):
    """(x / p, p) with p the power of two just above max |x| (exact in floating point)."""
    x = jnp.asarray(x)
    _, exponent = jnp.frexp(jnp.max(jnp.abs(x)))
    p = jnp.ldexp(jnp.ones((), x.dtype), exponent)
    return x / p, p


def series_from_recording(recording, fractions=(0.3, 0.5, 0.2), order=("train", "test", "validation"),
                          blocks: int = 1):
    """A [`Series`][] from a Recording, split in time (paper: 30/50/20 %, contiguous).

    With `blocks` > 1 the recording is cut into that many equal chunks and each
    chunk is split by `fractions` in `order`: every part then spans the whole
    recording. The simulation still runs over every sample (it never sees the
    measured displacement), so a held-out block is predicted from the drive
    alone, with the state the earlier samples left; it interpolates in time
    instead of extrapolating past the training data.
    """
    if int(blocks) != blocks or blocks < 1:
        raise InputError(f"blocks must be a whole number ≥ 1, got {blocks!r}")
    edges = [round(k * recording.n / blocks) for k in range(int(blocks) + 1)]
    parts = {name: [] for name in order}
    for lo, hi in zip(edges[:-1], edges[1:]):
        chunk = recording if (lo, hi) == (0, recording.n) else recording.segment(slice(lo, hi))
        for name, s in chunk.split(fractions=fractions, order=order).slices.items():
            parts[name].append((lo + s.start, lo + s.stop))
    segments = tuple((name, tuple(parts[name])) for name in order)
    return Series(
        jnp.asarray(recording.v_in), jnp.asarray(recording.w), float(recording.dt), segments
    )


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
    """

    sim_static: eqx.Module
    readout_static: eqx.Module
    unravel_sim: callable = eqx.field(static=True)
    unravel_readout: callable = eqx.field(static=True)
    series: tuple[Series, ...]
    scale: jax.Array
    kind: str = eqx.field(static=True)
    n_sim: int = eqx.field(static=True)
    n_readout: int = eqx.field(static=True)
    weight_decay: float = eqx.field(static=True)
    sim_tangents: jax.Array | None

    def __init__(self, model: Model, series, frozen=frozenset(), weight_decay: float = 0.0,
                 sim_tangents=None):
        series = tuple(series)
        if not series:
            raise InputError("no recordings to fit: pass at least one recording")
        spec = model.trainable(frozen)
        sim_dyn, self.sim_static = eqx.partition(model.simulation, spec.simulation)
        readout_dyn, self.readout_static = eqx.partition(model.readout, spec.readout)
        theta_sim, self.unravel_sim = ravel_pytree(sim_dyn)
        theta_readout, self.unravel_readout = ravel_pytree(readout_dyn)
        self.n_sim = int(theta_sim.size)
        self.n_readout = int(theta_readout.size)
        if self.n_sim + self.n_readout == 0:
            raise InputError("every parameter is frozen: free at least one to fit")
        self.series = series
        train = jnp.concatenate([s.target("train") for s in series])
        std = robust_std(train)
        self.scale = jnp.where(std > 0, std, jnp.ones_like(std))  # constant w: refused by fit
        self.kind = model.kind
        if not weight_decay >= 0:
            raise InputError(f"weight_decay must be ≥ 0, got {weight_decay!r}")
        penalised = not model.readout.parameters()  # black-box readouts only
        self.weight_decay = float(weight_decay) if penalised else 0.0
        self.sim_tangents = sim_tangents

    # --- θ ↔ model -------------------------------------------------------------
    def flatten(self, model: Model, frozen=frozenset()) -> jax.Array:
        spec = model.trainable(frozen)
        a, _ = ravel_pytree(eqx.filter(model.simulation, spec.simulation))
        b, _ = ravel_pytree(eqx.filter(model.readout, spec.readout))
        return jnp.concatenate([a, b])

    def split_theta(self, theta):
        return theta[: self.n_sim], theta[self.n_sim :]

    def simulation(self, theta_sim):
        return eqx.combine(self.unravel_sim(theta_sim), self.sim_static)

    def readout(self, theta_readout):
        return eqx.combine(self.unravel_readout(theta_readout), self.readout_static)

    def model(self, theta) -> Model:
        a, b = self.split_theta(theta)
        return Model(self.simulation(a), self.readout(b), self.kind)

    # --- residuals -----------------------------------------------------------
    def _signals(self, theta_sim):
        simulation = self.simulation(theta_sim)
        return [simulation.simulate(s.v_in, s.dt) for s in self.series]

    def _windows(self, readout, signals, split):
        return jnp.concatenate(
            [readout.windows(x, s.segments_of(split)) for x, s in zip(signals, self.series)]
        )

    def target(self, split):
        return jnp.concatenate([s.target(split) for s in self.series])

    def prediction(self, theta, split):
        """ŵ (mm) on `split`, all recordings concatenated."""
        a, b = self.split_theta(theta)
        readout = self.readout(b)
        windows = self._windows(readout, self._signals(a), split)
        return jax.vmap(readout.predict_window)(windows)

    def residuals(self, theta, split="train"):
        return (self.target(split) - self.prediction(theta, split)) / self.scale

    def penalty_mask(self, theta):
        """1 for the penalised (network) entries of θ, 0 elsewhere."""
        return jnp.concatenate([jnp.zeros(self.n_sim, theta.dtype), jnp.ones(self.n_readout, theta.dtype)])

    def objective_residuals(self, theta):
        """[r_train, √μ θ_network]: the residuals every solver minimises the squares of."""
        r = self.residuals(theta)
        if not self.weight_decay:
            return r
        return jnp.concatenate([r, jnp.sqrt(self.weight_decay) * self.penalty_mask(theta) * theta])

    def cost(self, theta):
        """½‖r_train‖² + ½ μ ‖θ_network‖², the objective every solver minimises."""
        r = self.objective_residuals(theta)
        return 0.5 * jnp.sum(r * r)

    @property
    def has_validation(self) -> bool:
        return all("validation" in dict(s.segments) for s in self.series)

    def validation_loss(self, theta):
        """½ mean r² on the validation split (the training split if there is none).

        Picks the best iterate and the best start, whatever the solver.
        """
        split = "validation" if self.has_validation else "train"
        return 0.5 * jnp.mean(self.residuals(theta, split) ** 2)

    def _residuals_and_sim_jacobian(self, theta, split):
        """r (m,), J_sim (m × k) by forward mode through the simulation, and the readout's input windows."""
        a, b = self.split_theta(theta)
        target = self.target(split)

        def from_sim(theta_sim):
            readout = self.readout(b)
            windows = self._windows(readout, self._signals(theta_sim), split)
            return (target - jax.vmap(readout.predict_window)(windows)) / self.scale, windows

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
        return r, jnp.concatenate([J_sim, self._readout_jacobian(theta, windows)], axis=1)

    def normal_equations(self, theta, split="train"):
        """JᵀJ and Jᵀr, never holding J whole when it is large.

        J's readout columns (m × n, 1,726 for the paper's D-MLP) are what grows
        with the record: 10⁶ samples would need ~10 GB. Above `JACOBIAN_CHUNK_BYTES`
        they are built `rows` windows at a time inside a `lax.scan` and folded
        into JᵀJ and Jᵀr at once; J_sim (m × k, k ≈ 6) is kept whole. Below it,
        the products of the whole J (the same numbers, summed in another order).
        """
        r, J_sim, windows = self._residuals_and_sim_jacobian(theta, split)
        m, n = r.shape[0], self.n_readout
        rows = max(MIN_CHUNK_ROWS, JACOBIAN_CHUNK_BYTES // (r.dtype.itemsize * max(n, 1)))
        if n == 0 or m <= rows:
            J = jnp.concatenate([J_sim, self._readout_jacobian(theta, windows)], axis=1)
            return J.T @ J, J.T @ r
        pad = (-m) % rows
        chunks = -(-m // rows)

        def padded(x):  # padding rows repeat the last window; their mask is 0
            return jnp.concatenate([x, jnp.repeat(x[-1:], pad, axis=0)]).reshape((chunks, rows) + x.shape[1:])

        mask = jnp.concatenate([jnp.ones(m, r.dtype), jnp.zeros(pad, r.dtype)]).reshape(chunks, rows)

        def fold(acc, chunk):
            window, j_sim, res, keep = chunk
            J_r = self._readout_jacobian(theta, window) * keep[:, None]
            return (acc[0] + J_r.T @ J_r, acc[1] + J_r.T @ j_sim, acc[2] + J_r.T @ res), None

        zeros = (jnp.zeros((n, n), r.dtype), jnp.zeros((n, J_sim.shape[1]), r.dtype), jnp.zeros(n, r.dtype))
        (A_rr, A_rs, g_r), _ = jax.lax.scan(fold, zeros, (padded(windows), padded(J_sim), padded(r), mask))
        JtJ = jnp.block([[J_sim.T @ J_sim, A_rs.T], [A_rs, A_rr]])
        return JtJ, jnp.concatenate([J_sim.T @ r, g_r])
