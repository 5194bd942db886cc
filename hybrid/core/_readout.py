"""Readouts: map a window of the mediatory signal to the tip displacement w (mm).

- [`LinearReadout`][]: w = gain · s(t) + offset — the physics-only simulation's
  linear electromechanical coupling (gain in mm/V, offset in mm).
- [`WindowedMLP`][]: the paper's D-MLP (Sec. II-B, Fig. 8): an MLP on the τ most
  recent samples, 11 hidden layers × 10 tanh neurons by default.

Every readout is per-sample: `predict_window(window) -> scalar`. The fitter
relies on this to build the network part of the Jacobian as per-sample
gradients (one `vmap`), instead of differentiating through the whole series.
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from ..util._errors import InputError
from ._loop_safe_linalg import lstsq
from ._parameters import Constraint, Real, decode, encode
from ._simulation import as_factor
from ._windows import segment_windows


class AbstractReadout(eqx.Module):
    """Per-sample map from a window of the mediatory signal to w (mm)."""

    window: eqx.AbstractVar[int]

    @abc.abstractmethod
    def predict_window(self, window: Float[Array, " window"]) -> Float[Array, ""]:
        """w at the newest sample of `window`."""

    @abc.abstractmethod
    def trainable(self, frozen: frozenset[str]) -> AbstractReadout:
        """Filter spec (bools) of the free leaves."""

    @abc.abstractmethod
    def parameters(self) -> dict[str, Array]:
        """Interpretable parameters by name (empty for a black box)."""

    @abc.abstractmethod
    def initialise(self, signal, w) -> AbstractReadout:
        """A copy whose fixed scalings / initial values suit the training data."""

    def units_for(self, signal_unit: str, w_unit: str) -> dict[str, str]:
        """Each named parameter's unit when the mediatory signal is in `signal_unit` and w in `w_unit`.

        Default: none (a black box has no named parameters).
        """
        return {}

    def rescaled(self, input_scale, output_scale) -> AbstractReadout:
        """The same map in other units: R'(input_scale · x) = output_scale · R(x).

        [`hybrid.fit`][] fits on data scaled to unit size and maps the readout
        back with this, so that fitted physical parameters do not depend on the
        units of w or v_in. A readout without it is fitted in the data's units.
        """
        raise NotImplementedError(f"{type(self).__name__} cannot be rescaled")

    def windows(self, signal, segments):
        return segment_windows(signal, self.window, segments)

    def __call__(self, signal: Float[Array, " time"], segments) -> Float[Array, " samples"]:
        """w for every sample of each `(start, stop)` segment of `signal`."""
        return jax.vmap(self.predict_window)(self.windows(signal, segments))


class LinearReadout(AbstractReadout):
    """w = gain · s + offset: linear electromechanical coupling (gain mm/V, offset mm, for the RC network).

    The gain's unit is w's over the simulation's output's (`units_for`): mm/V
    for the RC network's tip voltage read as a displacement, V/cm for a tank's
    level read by a sensor in volts.
    """

    raw: dict[str, Array]
    window: int = eqx.field(static=True)
    constraints: ClassVar[dict[str, Constraint]] = {"gain": Real(), "offset": Real()}

    def __init__(self, gain: float = 1.0, offset: float = 0.0):
        self.raw = encode({"gain": gain, "offset": offset}, self.constraints, "LinearReadout")
        self.window = 1

    def predict_window(self, window):
        p = self.parameters()
        return p["gain"] * window[-1] + p["offset"]

    def units_for(self, signal_unit: str, w_unit: str) -> dict[str, str]:
        """gain in w's unit per the signal's ("(unit of S)" where the simulation does not say), offset in w's."""
        signal = signal_unit or "(unit of S)"
        gain = "1" if signal == w_unit else f"{as_factor(w_unit)}/{as_factor(signal)}"
        return {"gain": gain, "offset": w_unit}

    def parameters(self):
        return decode(self.raw, self.constraints)

    def trainable(self, frozen):
        spec = jax.tree_util.tree_map(lambda _: False, self)
        return eqx.tree_at(lambda r: r.raw, spec, {k: k not in frozen for k in self.raw})

    def rescaled(self, input_scale, output_scale):
        raw = {
            "gain": self.raw["gain"] * (output_scale / input_scale),
            "offset": self.raw["offset"] * output_scale,
        }
        return eqx.tree_at(lambda r: r.raw, self, raw)

    def initialise(self, signal, w):
        # Least-squares gain and offset for the current signal: a good LM start.
        s = jnp.asarray(signal)
        design = jnp.stack([s, jnp.ones_like(s)], axis=1)
        (gain, offset), _ = lstsq(design, jnp.asarray(w))  # no LAPACK: runs in diagnose's batched screens
        raw = {"gain": jnp.asarray(gain), "offset": jnp.asarray(offset)}
        return eqx.tree_at(lambda r: r.raw, self, raw)


class WindowedMLP(AbstractReadout):
    """The paper's D-MLP on a sliding window (Sec. II-B, Fig. 8).

    w(t) = σ_w · MLP((x[t−τ+1..t] − μ_x)/σ_x) + μ_w, where μ, σ are fixed
    scalings taken from the training data (not fitted), so that the network
    works on O(1) numbers whatever the units.

    **Arguments:**

    - `window`: τ, samples per input window (paper: 60 = 2 s at 30 fps).
    - `depth`: number of hidden layers (paper: 11).
    - `width`: neurons per hidden layer (paper: 10).
    - `activation`: hidden activation (paper: tanh).
    - `key`: PRNG key for the initial weights.

    Its parameter group is named ``"network"`` (to freeze all weights at once).
    """

    mlp: eqx.nn.MLP
    scales: Float[Array, 4]  # μ_x, σ_x, μ_w, σ_w — fixed, never fitted
    window: int = eqx.field(static=True)

    def __init__(
        self,
        window: int = 60,
        depth: int = 11,
        width: int = 10,
        activation=jnp.tanh,
        *,
        key: PRNGKeyArray,
    ):
        for name, value, low in (("window", window, 1), ("depth", depth, 0), ("width", width, 1)):
            if not isinstance(value, int) or value < low:
                raise InputError(f"D-MLP {name} must be an integer ≥ {low}, got {value!r}")
        mlp_key, init_key = jax.random.split(key)
        mlp = eqx.nn.MLP(
            window,
            "scalar",
            width,
            depth,
            activation=activation,
            key=mlp_key,
            dtype=jnp.zeros(()).dtype,
        )
        self.mlp = _tanh_gain_init(mlp, init_key)
        self.scales = jnp.array([0.0, 1.0, 0.0, 1.0])
        self.window = window

    def predict_window(self, window):
        mu_x, sigma_x, mu_w, sigma_w = self.scales
        return sigma_w * self.mlp((window - mu_x) / sigma_x) + mu_w

    def parameters(self):
        return {}

    def trainable(self, frozen):
        spec = jax.tree_util.tree_map(lambda _: False, self)
        if "network" in frozen:
            return spec
        return eqx.tree_at(lambda r: r.mlp, spec, jax.tree_util.tree_map(eqx.is_inexact_array, self.mlp))

    def rescaled(self, input_scale, output_scale):
        factors = jnp.array([input_scale, input_scale, output_scale, output_scale], self.scales.dtype)
        return eqx.tree_at(lambda r: r.scales, self, self.scales * factors)

    def initialise(self, signal, w):
        s, w = jnp.asarray(signal), jnp.asarray(w)
        scales = jnp.stack(
            [
                jnp.mean(s),
                jnp.maximum(jnp.std(s), 1e-12),
                jnp.mean(w),
                jnp.maximum(jnp.std(w), 1e-12),
            ]
        ).astype(self.scales.dtype)
        return eqx.tree_at(lambda r: r.scales, self, scales)

    @property
    def n_weights(self) -> int:
        leaves = jax.tree_util.tree_leaves(eqx.filter(self.mlp, eqx.is_inexact_array))
        return sum(int(leaf.size) for leaf in leaves)


def _tanh_gain_init(mlp: eqx.nn.MLP, key) -> eqx.nn.MLP:
    """Weights N(0, (5/3)²/fan_in), biases 0: keeps tanh activations O(1) through depth.

    Equinox's default U(±1/√fan_in) shrinks the signal by ~0.58 per tanh layer:
    after the paper's 11 layers the output barely depends on the input and
    Gauss–Newton starts from a flat model.
    """
    keys = jax.random.split(key, len(mlp.layers))
    layers = []
    for layer, k in zip(mlp.layers, keys):
        fan_in = layer.weight.shape[1]
        gain = 5.0 / 3.0 if layer is not mlp.layers[-1] else 1.0
        weight = gain / jnp.sqrt(fan_in) * jax.random.normal(k, layer.weight.shape, layer.weight.dtype)
        layer = eqx.tree_at(lambda l: l.weight, layer, weight)
        if layer.bias is not None:
            layer = eqx.tree_at(lambda l: l.bias, layer, jnp.zeros_like(layer.bias))
        layers.append(layer)
    return eqx.tree_at(lambda m: m.layers, mlp, tuple(layers))
