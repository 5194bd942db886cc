"""Physical effects the paper's RC network leaves out, as extensions of any simulation.

An effect maps the mediatory signal s(t) of a simulation (V_o of the RC
network, volts) to a modified signal y(t) before the readout's gain and
offset. Each has a few interpretable parameters in physical units:

=================  =====================================  =====================================
name               y(t)                                   parameters
=================  =====================================  =====================================
``delay``          s(t − d)  (linear interpolation)       ``delay_s`` d (s)
``back_relaxation`` s − β·x,  τ ẋ = s − x                 ``relaxation_time_s`` τ (s),
                                                          ``relaxation_fraction`` β
``saturation``     tanh(κ± s)/κ±  (κ₊ for s ≥ 0)          ``saturation_pos_per_v``, ``saturation_neg_per_v`` (1/V)
``hysteresis``     s + W·u,  du/ds = k(1 − u|u| sgn(ds))  ``hysteresis_height_v`` W (V),
                   (Bouc–Wen, n = 2, γ = 0)               ``hysteresis_rate_per_v`` k (1/V),
                                                          ``hysteresis_initial_state`` u₀
``drift``          s · exp(κ t)                           ``drift_rate_per_s`` κ (1/s)
``resonance``      ω²/(s² + 2ζωs + ω²) applied to s       ``resonance_frequency_hz`` f = ω/2π,
                   (exact first-order-hold discretisation) ``resonance_damping`` ζ
``even_response``  s + c s²                               ``even_per_v`` c (1/V)
=================  =====================================  =====================================

- Back-relaxation: under a held voltage the bending charge diffuses back; the
  step response peaks, then relaxes by the fraction β with time constant τ.
- Hysteresis: the Bouc–Wen state u is rate-independent (it moves with ds, not
  dt) and solved exactly per sample (tanh/tan branches, see `bouc_wen_state`),
  so the loop's half-height is W once |Δs| ≫ 1/k. Where on the loop the strip
  starts (u₀ at the first sample) is left by its history before the recording and is
  fitted: on a slow strip that never sweeps its whole range, the first branch can
  last most of a recording (hysteresis seed 10 of `experiments/discrepancy.py`,
  C_clamp 0.83 F: measured with the n = 1 element, the held-out gain was 6.7
  with the initial state fitted and 1.6 with the strip assumed to start at rest).
- Drift: the actuation gain changes monotonically over a recording
  (dehydration, temperature); t counts from the recording's first sample.
- Resonance: a mechanical mode of the cantilever (unity DC gain).
- Even response: a displacement that follows the square of the drive, the
  same for ±V, as an electrostatic actuator's does (an IPMC's is odd).

Each effect is an [`AbstractEffect`][]; [`EffectStack`][]
(`hybrid.discovery._effect_stack`) applies them to a simulation. The Bouc–Wen
state of the hysteresis is solved in `hybrid.discovery._hysteresis`.
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array, Float

from ..core._loop_safe_linalg import expm
from ..core._parameters import Constraint, Positive, Real, SignedUnitInterval, UnitInterval, decode, encode
from ._hysteresis import bouc_wen_state


class AbstractEffect(eqx.Module):
    """One physical effect: y = effect(s) with named, constrained parameters."""

    raw: eqx.AbstractVar[dict[str, Array]]
    name: ClassVar[str]
    constraints: ClassVar[dict[str, Constraint]]
    units: ClassVar[dict[str, str]]
    defaults: ClassVar[dict[str, float]]

    @abc.abstractmethod
    def apply(self, s: Float[Array, " time"], dt: float) -> Float[Array, " time"]:
        """The modified signal for the signal `s` sampled every `dt` seconds."""

    def parameters(self) -> dict[str, Array]:
        return decode(self.raw, self.constraints)

    def with_values(self, **values) -> AbstractEffect:
        current = {k: float(v) for k, v in self.parameters().items()}
        current.update(values)
        return eqx.tree_at(lambda e: e.raw, self, encode(current, self.constraints, self.name))

    def derived(self, s, dt: float) -> dict[str, float]:
        """Quantities an experimenter reads more easily than the raw parameters."""
        return {}


def _init(effect, values):
    merged = {**effect.defaults, **(values or {})}
    effect.raw = encode(merged, effect.constraints, effect.name)


class Delay(AbstractEffect):
    """Dead time d: y(t) = s(t − d), linearly interpolated; s = 0 before the recording (rest)."""

    raw: dict[str, Array]
    name: ClassVar[str] = "delay"
    constraints: ClassVar = {"delay_s": Positive()}
    units: ClassVar = {"delay_s": "s"}
    defaults: ClassVar = {"delay_s": 0.05}

    def __init__(self, **values):
        _init(self, values)

    def apply(self, s, dt):
        d = self.parameters()["delay_s"]
        n = jnp.arange(-1, s.shape[0], dtype=s.dtype)
        return jnp.interp(n[1:] - d / dt, n, jnp.concatenate([jnp.zeros(1, s.dtype), s]), left=0.0)

    def derived(self, s, dt):
        return {"delay_samples": float(self.parameters()["delay_s"] / dt)}


def affine_recurrence(a, b, x0=0.0):
    """x[n] = a[n] x[n−1] + b[n] for n = 0..T−1 from x[−1] = x0, as a parallel scan.

    The composition of affine maps is associative, so `lax.associative_scan`
    evaluates the recurrence in O(log T) vectorised passes instead of T
    dependent scalar steps (which cost ~1 µs each on a CPU).
    """

    def compose(first, second):
        a1, b1 = first
        a2, b2 = second
        return a2 * a1, a2 * b1 + b2

    a = jnp.broadcast_to(a, b.shape)
    b = b.at[0].add(a[0] * x0)
    return lax.associative_scan(compose, (a, b))[1]


def _first_order_lowpass(s, a):
    """x[n] = a x[n−1] + (1 − a) s[n], x[−1] = 0 (the discrete low-pass 1/(τs + 1))."""
    return affine_recurrence(a, (1 - a) * s)


class BackRelaxation(AbstractEffect):
    """y = s − β x with τ ẋ = s − x: a held drive relaxes by the fraction β with time constant τ.

    Discretised exactly for a signal held over each sample (a = e^{−dt/τ}).
    """

    raw: dict[str, Array]
    name: ClassVar[str] = "back_relaxation"
    constraints: ClassVar = {"relaxation_time_s": Positive(), "relaxation_fraction": UnitInterval()}
    units: ClassVar = {"relaxation_time_s": "s", "relaxation_fraction": "1"}
    defaults: ClassVar = {"relaxation_time_s": 10.0, "relaxation_fraction": 0.3}

    def __init__(self, **values):
        _init(self, values)

    def apply(self, s, dt):
        p = self.parameters()
        a = jnp.exp(-dt / p["relaxation_time_s"])
        x = jnp.concatenate([jnp.zeros(1, s.dtype), _first_order_lowpass(s, a)[:-1]])
        return s - p["relaxation_fraction"] * x

    def derived(self, s, dt):
        return {"relaxation_percent": 100.0 * float(self.parameters()["relaxation_fraction"])}


def _soft_clip(s, k):
    """tanh(k s)/k, even in k and equal to s at k = 0 (finite gradients there too)."""
    x = k * s
    small = jnp.abs(x) < 1e-4
    k_safe = jnp.where(jnp.abs(k) < 1e-300, 1.0, k)
    x_safe = jnp.where(small, 1.0, x)
    return jnp.where(small, s * (1.0 - x * x / 3.0), jnp.tanh(x_safe) / k_safe)


class Saturation(AbstractEffect):
    """y = tanh(κ₊ s)/κ₊ for s ≥ 0 and tanh(κ₋ s)/κ₋ for s < 0: slope 1 at s = 0.

    κ± (1/V) is the curvature of each side; κ = 0 is the linear response, so
    the effect-free simulation lies inside the family (at a finite parameter,
    where a saturation level σ = 1/κ would need σ → ∞). The response levels
    off at ±1/|κ±| (V of s): ``derived`` reports those levels and the shortfall
    below the linear extrapolation at the largest |s| of each sign.
    """

    raw: dict[str, Array]
    name: ClassVar[str] = "saturation"
    constraints: ClassVar = {"saturation_pos_per_v": Real(), "saturation_neg_per_v": Real()}
    units: ClassVar = {"saturation_pos_per_v": "1/V", "saturation_neg_per_v": "1/V"}
    defaults: ClassVar = {"saturation_pos_per_v": 0.0, "saturation_neg_per_v": 0.0}

    def __init__(self, **values):
        _init(self, values)

    def apply(self, s, dt):
        p = self.parameters()
        k = jnp.where(s >= 0, p["saturation_pos_per_v"], p["saturation_neg_per_v"])
        return _soft_clip(s, k)

    def derived(self, s, dt):
        """Level 1/|κ| (V) and shortfall below the linear extrapolation at the largest |s|, %."""
        p = self.parameters()
        out = {}
        for side, peak, k in (
            ("pos", np.max(s), p["saturation_pos_per_v"]),
            ("neg", -np.min(s), p["saturation_neg_per_v"]),
        ):
            peak, k = float(peak), abs(float(k))
            out[f"level_{side}_v"] = 1.0 / k if k > 0 else float("inf")
            if peak > 0:
                out[f"shortfall_{side}_percent"] = 100.0 * (
                    1.0 - float(_soft_clip(jnp.asarray(peak), k)) / peak
                )
        return out


class Hysteresis(AbstractEffect):
    """y = s + W u, u the Bouc–Wen state (n = 2, γ = 0) of s, solved exactly per sample.

    Rate-independent: u depends on the path of s, not on time. Its loop is
    2|W| high (in units of s) once the excursions exceed a few 1/k; with W > 0 the
    rising branch lies above the falling one, with W < 0 below. The loop state
    at the first sample, u₀ ∈ (−1, 1), is a parameter (see
    [`bouc_wen_state`][]); recordings fitted together share it, as recordings of
    one strip that each start from the same rest do.
    """

    raw: dict[str, Array]
    name: ClassVar[str] = "hysteresis"
    constraints: ClassVar = {
        "hysteresis_height_v": Real(),
        "hysteresis_rate_per_v": Positive(),
        "hysteresis_initial_state": SignedUnitInterval(),
    }
    units: ClassVar = {
        "hysteresis_height_v": "V",
        "hysteresis_rate_per_v": "1/V",
        "hysteresis_initial_state": "1",
    }
    defaults: ClassVar = {
        "hysteresis_height_v": 0.01,
        "hysteresis_rate_per_v": 10.0,
        "hysteresis_initial_state": 0.0,
    }

    def __init__(self, **values):
        _init(self, values)

    def apply(self, s, dt):
        p = self.parameters()
        u = bouc_wen_state(s, p["hysteresis_rate_per_v"], p["hysteresis_initial_state"])
        return s + p["hysteresis_height_v"] * u

    def derived(self, s, dt):
        """Loop height 2|W| as a percentage of the signal's range."""
        span = float(np.ptp(s))
        height = 2.0 * abs(float(self.parameters()["hysteresis_height_v"]))
        return {"loop_height_percent_of_range": 100.0 * height / span if span > 0 else 0.0}


class Drift(AbstractEffect):
    """y = s · exp(κ t): the actuation gain changes monotonically, t from the first sample."""

    raw: dict[str, Array]
    name: ClassVar[str] = "drift"
    constraints: ClassVar = {"drift_rate_per_s": Real()}
    units: ClassVar = {"drift_rate_per_s": "1/s"}
    defaults: ClassVar = {"drift_rate_per_s": 0.0}

    def __init__(self, **values):
        _init(self, values)

    def apply(self, s, dt):
        t = dt * jnp.arange(s.shape[0], dtype=s.dtype)
        return s * jnp.exp(self.parameters()["drift_rate_per_s"] * t)

    def derived(self, s, dt):
        duration = dt * (s.shape[0] - 1)
        change = float(jnp.expm1(self.parameters()["drift_rate_per_s"] * duration))
        return {"gain_change_percent": 100.0 * change, "over_s": float(duration)}


def foh_matrices(a, b, dt):
    """Exact first-order-hold discretisation of ẋ = A x + B u (u linear between samples).

    Returns (Φ, Γ₀, Γ₁) with x[n+1] = Φ x[n] + Γ₀ u[n] + Γ₁ (u[n+1] − u[n]), from
    the exponential of the augmented matrix [[A, B, 0], [0, 0, 1], [0, 0, 0]]·dt.
    """
    n = a.shape[0]
    m = jnp.zeros((n + 2, n + 2), a.dtype)
    m = m.at[:n, :n].set(a).at[:n, n].set(b).at[n, n + 1].set(1.0)
    e = expm(m * dt)  # matmul-only: safe in batched loops (see _loop_safe_linalg)
    return e[:n, :n], e[:n, n], e[:n, n + 1] / dt


class Resonance(AbstractEffect):
    """A mechanical mode, unity DC gain: ω²/(s² + 2ζωs + ω²), f = ω/2π in Hz.

    Discretised exactly for a signal linear between samples (first-order hold),
    so it holds up to and beyond the Nyquist frequency without warping.
    """

    raw: dict[str, Array]
    name: ClassVar[str] = "resonance"
    constraints: ClassVar = {"resonance_frequency_hz": Positive(), "resonance_damping": UnitInterval()}
    units: ClassVar = {"resonance_frequency_hz": "Hz", "resonance_damping": "1"}
    defaults: ClassVar = {"resonance_frequency_hz": 5.0, "resonance_damping": 0.1}

    def __init__(self, **values):
        _init(self, values)

    def apply(self, s, dt):
        p = self.parameters()
        w = 2 * jnp.pi * p["resonance_frequency_hz"]
        z = p["resonance_damping"]
        a = jnp.array([[0.0, 1.0], [-w * w, -2 * z * w]], s.dtype)
        b = jnp.array([0.0, 1.0], s.dtype) * w * w
        phi, g0, g1 = foh_matrices(a, b, dt)
        du = jnp.diff(s, append=s[-1:])
        # x[n+1] = Φ x[n] + Γ₀ u[n] + Γ₁ Δu[n], from rest at the first value (unity DC gain):
        # a linear recurrence, evaluated as a parallel scan of affine maps.
        forcing = g0[None, :] * s[:, None] + g1[None, :] * du[:, None]
        x0 = jnp.array([1.0, 0.0], s.dtype) * s[0]
        forcing = forcing.at[0].add(phi @ x0)
        phis = jnp.broadcast_to(phi, (s.shape[0], 2, 2))

        def compose(first, second):
            a1, b1 = first
            a2, b2 = second
            return a2 @ a1, jnp.einsum("...ij,...j->...i", a2, b1) + b2

        states = lax.associative_scan(compose, (phis, forcing))[1]  # x[1..T]
        return jnp.concatenate([x0[None, 0], states[:-1, 0]])


class FrameTiming(AbstractEffect):
    """The camera's sampling instant: y[n] = s(n − f) with 0 ≤ f ≤ 1 sample (linear interpolation).

    Not a cause but part of every measurement: a frame averages the
    displacement over its exposure, which ends at the frame's time stamp, so it
    reads the strip about half an exposure late (a 1/60 s exposure at 30 fps:
    f ≈ 0.25), and the drive's DAC updates need not line up with the frames.
    The discrepancy search fits f in its baseline, so that a sub-sample timing
    offset is not mistaken for a dead time.
    """

    raw: dict[str, Array]
    name: ClassVar[str] = "frame_timing"
    constraints: ClassVar = {"frame_lag": UnitInterval()}
    units: ClassVar = {"frame_lag": "samples"}
    defaults: ClassVar = {"frame_lag": 0.25}

    def __init__(self, **values):
        _init(self, values)

    def apply(self, s, dt):
        f = self.parameters()["frame_lag"]
        return s - f * (s - jnp.concatenate([s[:1], s[:-1]]))

    def derived(self, s, dt):
        return {"frame_lag_s": float(self.parameters()["frame_lag"]) * dt}


class EvenResponse(AbstractEffect):
    """y = s + c s²: a response with a part even in the signal, c in 1/V.

    An IPMC bends one way or the other with the sign of the drive (odd); an
    electrostatic actuator (a dielectric elastomer, an electrostatic zipper)
    is pulled by a force ∝ V², the same for +V and −V (even). c = 0 is the
    linear response; with the readout's gain the model spans everything from
    linear to purely quadratic (|c| large). ``derived`` reports the even part's
    size, |c|·max s², as a percentage of the signal's range.
    """

    raw: dict[str, Array]
    name: ClassVar[str] = "even_response"
    constraints: ClassVar = {"even_per_v": Real()}
    units: ClassVar = {"even_per_v": "1/V"}
    defaults: ClassVar = {"even_per_v": 0.0}

    def __init__(self, **values):
        _init(self, values)

    def apply(self, s, dt):
        return s + self.parameters()["even_per_v"] * s * s

    def derived(self, s, dt):
        """The even part's size, |c| max s², as a percentage of the range of s."""
        span = float(np.ptp(s))
        even = abs(float(self.parameters()["even_per_v"])) * float(np.max(np.square(s)))
        return {"even_percent_of_range": 100.0 * even / span if span > 0 else 0.0}


#: The effects, by name, in the order they act on the signal (the even response,
#: added last, keeps the others' places in the stack and so their fits' layout).
EFFECTS: dict[str, type[AbstractEffect]] = {
    cls.name: cls for cls in (Delay, BackRelaxation, Saturation, Hysteresis, Drift, Resonance, EvenResponse)
}
