"""Physical effects a simulation leaves out, as extensions of any simulation; effects are plug-ins.

An output-side effect maps the signal s(t) a simulation returns (V_o of the RC
network, volts) to a modified signal y(t) before the readout's gain and
offset; a drive-side effect maps the drive u(t) before the simulation
(``place = "drive"``). Each has a few interpretable parameters whose units
follow the signal it acts on (``{signal}`` in `units`; below for the RC
network, whose output is in V). The built-ins:

=================  =====================================  =====================================
name               y(t)                                   parameters
=================  =====================================  =====================================
``delay``          s(t − d)  (linear interpolation)       ``delay_s`` d (s)
``back_relaxation`` s − β·x,  τ ẋ = s − x                 ``relaxation_time_s`` τ (s),
                                                          ``relaxation_fraction`` β
``saturation``     tanh(κ± s)/κ±  (κ₊ for s ≥ 0)          ``saturation_pos_curvature``, ``saturation_neg_curvature`` (1/V)
``hysteresis``     s + W·u,  du/ds = k(1 − u|u| sgn(ds))  ``hysteresis_height`` W (V),
                   (Bouc–Wen, n = 2, γ = 0)               ``hysteresis_rate`` k (1/V),
                                                          ``hysteresis_initial_state`` u₀
``drift``          s · exp(κ t)                           ``drift_rate_per_s`` κ (1/s)
``resonance``      ω²/(s² + 2ζωs + ω²) applied to s       ``resonance_frequency_hz`` f = ω/2π,
                   (exact first-order-hold discretisation) ``resonance_damping`` ζ
``even_response``  s + c s²                               ``even_coefficient`` c (1/V)
``baseline_drift`` s + a·t + b·t² + c·t³ (t in minutes)    ``baseline_slope_per_min`` a (V/min),
                                                          ``baseline_curvature_per_min2`` b (V/min²),
                                                          ``baseline_cubic_per_min3`` c (V/min³)
``lag``            1/(τs + 1) applied to s                ``lag_time_s`` τ (s)
                   (exact first-order-hold discretisation)
``drive_dead_zone`` S(u − clip(u, −d, d))  (on the drive)  ``drive_dead_zone_width`` d (unit of u)
``drive_saturation`` S(tanh(κ± u)/κ±)  (on the drive)      ``drive_saturation_pos_curvature``,
                                                          ``drive_saturation_neg_curvature`` (1/unit of u)
``drive_even``     S(u + c u²)  (on the drive)             ``drive_even_coefficient`` c (1/unit of u)
``backlash``       S(play_h(u))  (on the drive)            ``backlash_half_width`` h (unit of u)
=================  =====================================  =====================================

A delay of the drive is the output's ``delay``: a dead time commutes with
time-invariant dynamics, S(u(· − d)) = S(u)(· − d) from rest, so one effect
stands for both places.

Searched only when named (``NAMED_ONLY`` of `hybrid.discovery._effect_set`):
``creep`` (`Creep`), ``clip`` and ``drive_clip`` (`Clip`, `DriveClip`: the
saturations with the knee's sharpness n fitted, sgn(s)·tanh(|κs|ⁿ)^(1/n)/|κ|,
a hard clip at ±1/|κ| as n grows; parameters ``<name>_pos_curvature``,
``<name>_neg_curvature``, ``<name>_sharpness``), ``line`` (`Line`: a
sinusoid added to the output, ``line_frequency_hz``, ``line_cos``,
``line_sin``), and ``dead_band`` (`DeadBand`: s − clip(s, −d, d) on the
output, ``dead_band_width`` d in V).

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
- Baseline drift: the output's zero creeps (a sensor warming): additive,
  where `drift` is a gain that changes.
- Lag: the sensor follows the output with a time constant (a thermocouple
  in its sheath, a filter) or the simulation lacks a pole; with linear
  dynamics it cannot be told from the same pole at the drive, and where the
  simulation has a pole of its own as free, the two time constants may
  trade places (which one is the sensor's, the data do not say).
- Drive dead zone: the drive must pass ±d before anything moves (static
  friction at the input, an amplifier's threshold).
- Drive saturation: an amplifier, a DAC stage or a pump that clips before the
  dynamics (the dynamics then smooth the clipped drive).
- Drive even: a force ∝ u², as an electrostatic actuator's ∝ V².
- Backlash: gears or a slack linkage; after a reversal the drive travels 2h
  before the dynamics see it move (`play`).

Everything `diagnose` needs to search an effect is the effect's own
(`starts`, `screened_starts`, `thresholds`, `material`, `unpinned_reason`): a
user's effect is a subclass in one file (docs/effects.md), passed to
``diagnose(effects=...)`` or ``hybrid diagnose --effects``.

Each effect is an [`AbstractEffect`][]; [`EffectStack`][]
(`hybrid.discovery._effect_stack`) applies them to a simulation. The Bouc–Wen
state of the hysteresis is solved in `hybrid.discovery._hysteresis`.
"""

from __future__ import annotations

import abc
import dataclasses
import math
from typing import Any, ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array, Float

from ..core._lifted import lifted_blocks, lifted_response
from ..core._loop_safe_linalg import expm
from ..core._parameters import Constraint, Positive, Real, SignedUnitInterval, UnitInterval, decode, encode
from ..core._simulation import substitute_unit, unit_in
from . import residual_tests as rt
from ._hysteresis import bouc_wen_state

#: Where an effect acts: on the drive before the simulation, y = S(φ(u)); inside the dynamics
#: (a simulation in state-space form: a force fed back into the drive, or a limit on a state);
#: or on its output, y = φ(S(u)).
PLACES = ("drive", "inside", "output")
#: What an effect inside the dynamics does: "feedback", ẋ = f(x, u − φ(z)), z the output or a
#: named state; or "limit", a state z replaced by φ(z) after every integration step.
ROLES = ("feedback", "limit")
#: The placeholder an effect's `units` use for the unit of the signal it acts on.
SIGNAL = "{signal}"


@dataclasses.dataclass(frozen=True)
class StartContext:
    """What an effect's starting values may depend on; `diagnose`'s search builds one per step.

    - `signal`: the signal entering the effect on the training part under the
      current model: the simulation's output for an output-side effect, the
      drive for a drive-side one, the output or the named state for one inside
      the dynamics (`acts_on`), in its own unit.
    - `drive`: the drive on the same samples (its unit is the drive's).
    - `measured`: the recorded output on the same samples, brought into the
      simulation's output unit by the current readout ((w − offset)/gain):
      where the simulation's output would have to be (a level the record sits
      flat at is a limit's natural start).
    - `rate`: samples per second; `duration`: the first recording's length (s).
    - `lag_samples`: the whole-sample lag that best aligns the current model with the recording.
    - `residual_peak_hz`: the training residual's spectral peak at 0.5 Hz or above, or None.
    - `dead_times`: whole-sample shifts around where the recorded output starts to follow the drive,
      where that lies beyond a few samples, read from the training part alone
      (`hybrid.discovery._starts.dead_times`); () where none is clear.
    - `problem`, `simulation`, `frozen`: for a screen (`AbstractEffect.screened_starts`):
      the search's least-squares problem, the simulation being diagnosed and
      the names of its parameters that are not fitted. For a drive- or
      output-side effect's screen, `simulation` is an `EffectStack` of it: at the
      first step with every effect off (its output is the inner simulation's,
      exactly), from the second on the model extended so far (the named effects
      on, at their fitted values); its `parameters()` and `typical_ranges()`
      include the inner simulation's. One structure at every step: a screen's
      program compiles once per diagnosis. An effect inside the dynamics screens
      the simulation itself, at the first step only. A screen designs the
      simulation jointly with the effect.
    """

    signal: np.ndarray
    rate: float
    duration: float
    drive: np.ndarray | None = None
    measured: np.ndarray | None = None
    lag_samples: int = 0
    residual_peak_hz: float | None = None
    dead_times: tuple[int, ...] = ()
    problem: Any = None
    simulation: Any = None
    frozen: frozenset = frozenset()


def _filled(templates: dict[str, str], signal_unit: str, drive_unit: str) -> dict[str, str]:
    """`templates` with ``{signal}`` replaced by `signal_unit` and ``{drive}`` by `drive_unit`."""
    unit, drive = signal_unit or "(unit of S)", drive_unit or "(unit of the drive)"
    return {k: unit_in(substitute_unit(v, SIGNAL, unit), drive) for k, v in templates.items()}


class AbstractEffect(eqx.Module):
    """One physical effect: y = effect(s) with named, constrained parameters.

    A plug-in subclass states its facts as class variables and owns everything
    `diagnose` needs to search for it; nothing else in the library names it.

    - `name`, `constraints`, `units`, `defaults` (required): as for a simulation.
      A unit may contain ``{signal}``, the unit of the signal the effect acts on
      (``"1/{signal}"`` for a curvature): `units_for` fills it in.
    - `place`: ``"output"`` (default; it acts on the simulation's output),
      ``"drive"`` (it acts on the drive before the simulation) or ``"inside"``
      (inside the dynamics of a simulation in state-space form,
      [`AbstractStateSpace`][]). An inside effect states its `role`:
      ``"feedback"``, `apply` maps the signal it `acts_on` (``"output"`` or a
      state's name) to a force in the drive's unit (``{drive}``) that is
      subtracted from the drive wherever the rates are evaluated (a cubic
      spring: φ(y) = k·y³); or ``"limit"``, `apply` maps a state to its limited
      value after every integration step (an overflow: min(h, L)). `apply` of an
      inside effect works sample by sample (it gets a scalar inside the loop).
    - A limit's `bounded_states` (default: `acts_on` alone) are the states it
      holds, each after every step (`StateWindow`: every state of a group);
      `cut(unlimited, limited)` says how far it pulls its state in (default:
      both ends), which the stack turns into ``cut_percent_of_range`` for
      `material`; with `from_rest`, `apply` and `derived` (and `spilled`,
      `stopped`, where `into` or `velocity` name a state) get ``origin=``, where
      the state rests under no drive (`StateLimit`'s rim is measured from there).
    - `thresholds`: the smallest size that counts as a cause, by name (see
      `material`); `DiagnoseSettings.materiality` overrides them by name.
    - `of_time`: whether the effect is a function of time itself (a drift of
      the gain or of the baseline; default False): a drive whose level rises
      with time confounds it with an effect of the level, and the report says
      so only for such a pair of rivals.
    - `starts(context)`: starting values for the search's lanes (default: the
      defaults); `screened_starts(context)`: at most `n_screened` more, from a
      screen of the simulation's design jointly with the effect (every step; an
      inside effect's in the first step only).
    - `n_kept`: how many of its lanes (starts and screened starts) go on past
      the race's first `DiagnoseSettings.start_steps` LM steps: those with the
      least validation loss there (0, the default: every lane runs). For starts
      that differ in one size only (a dead zone's width, a play's), where a
      few steps show which basin the data favour.
    - `material(derived, parameters, thresholds)`: whether a fit of the effect is
      large enough to count, and the sentence that says why (default: always).
    - `derived(s, dt)`: quantities an experimenter reads more easily than the
      raw parameters (they are `material`'s `derived`); `derived_units` their
      units by name, as `units` (``{signal}`` allowed: a saturation's level is in
      the unit of the signal it acts on). A name ending ``_percent``, ``_s``,
      ``_hz`` or ``_samples`` says its unit already.
    - `levels`: those derived quantities that are values of the signal the
      effect acts on, by name, with their sign: +1 for a value, −1 for the size
      of a negative one (a saturation's ``level_neg``). On the output, where
      the readout (w = gain·y + offset) still stands between the effect and
      the recording, the report gives each as recorded too, in w's unit.
    - `reading(parameters, output_unit)`: what the fit means physically, where the
      name alone could mislead (default: nothing).
    - `refinement`: the name of an effect searched only when named that a fit
      of this one can stand in for: one whose form contains this one's and one
      more freedom (a saturation's knee of any sharpness, `Clip`), or the same
      form in another place (the drive's dead zone for the output's,
      `DeadBand`). Where this effect is named and something is left
      unexplained, `diagnose` tries the refinement in its place
      (`DiagnoseSettings.refine`). None (the default): none.
    - `points_at(parameters)`: the effect searched only when named that a fit
      of this one stands in for (an even part whose map turns down near the end
      of the signal's range: a clip), or None (the default); where a named
      cause points at a searched effect's `refinement`, `diagnose` tries it too.
    """

    raw: eqx.AbstractVar[dict[str, Array]]
    name: ClassVar[str]
    constraints: ClassVar[dict[str, Constraint]]
    units: ClassVar[dict[str, str]]
    defaults: ClassVar[dict[str, float]]
    place: ClassVar[str] = "output"
    role: ClassVar[str] = "feedback"
    acts_on: ClassVar[str] = "output"
    thresholds: ClassVar[dict[str, float]] = {}
    derived_units: ClassVar[dict[str, str]] = {}
    levels: ClassVar[dict[str, int]] = {}
    n_screened: ClassVar[int] = 0
    n_kept: ClassVar[int] = 0
    of_time: ClassVar[bool] = False
    refinement: ClassVar[str | None] = None
    from_rest: ClassVar[bool] = False

    @property
    def bounded_states(self) -> tuple[str, ...]:
        """The states a limit (``role = "limit"``) holds after every step: `acts_on` alone by default."""
        return (self.acts_on,)

    def cut(self, unlimited, limited) -> float:
        """How far a limit pulls its state in, in the state's unit: the fall of its top plus the rise of its bottom.

        `unlimited`, `limited`: the state of `acts_on` over the record without
        the limit and with it. Both ends by default, so that a floor counts as
        a ceiling does; an upper limit alone (`StateLimit`) counts its top.
        """
        top = float(np.max(unlimited) - np.max(limited))
        bottom = float(np.min(limited) - np.min(unlimited))
        return max(top, 0.0) + max(bottom, 0.0)

    @abc.abstractmethod
    def apply(self, s: Float[Array, " time"], dt: float) -> Float[Array, " time"]:
        """The modified signal for the signal `s` sampled every `dt` seconds."""

    def starts(self, context: StartContext) -> list[dict[str, float]]:
        """Starting values for the search's lanes, a few; how many must not depend on the data."""
        return [dict(self.defaults)]

    def screened_starts(self, context: StartContext) -> list[dict[str, float]]:
        """At most `n_screened` starts from a screen (the simulation's parameters may be among them)."""
        return []

    def material(self, derived: dict, parameters: dict, thresholds: dict) -> tuple[bool, str]:
        """(whether the fit is large enough to be a cause, the sentence that says why).

        `derived`: this effect's `derived` quantities; `parameters`: every
        fitted parameter by name (the simulation's too); `thresholds`: this
        class's `thresholds` with the settings' overrides.
        """
        return True, ""

    def reading(self, parameters: dict[str, float], output_unit: str) -> str:
        """What a fit of this effect means for the system, in one sentence ('' by default: the name says it).

        `parameters`: its fitted values by name, and its derived quantities on
        the recording (`derived`) beside them; `output_unit`: the unit of the
        recording's output (`unit_kind` of `hybrid.data._header_units` tells a speed's ``mm/s`` from a
        position's ``mm``): one form can mean different physics on different
        signals, as a force of the output is a spring on a position and a damping
        on a speed. The report prints it beside the cause.
        """
        return ""

    def points_at(self, parameters: dict[str, float]) -> str | None:
        """The name of an effect searched only when named that a fit at `parameters` stands in for, or None.

        `parameters`: as `reading`'s. Where it names a searched effect's
        `refinement`, `diagnose` tries the refinements in their parents' place
        (`DiagnoseSettings.refine`): a heater clipped at 6 V of a 0–10 V drive
        read `drive_even` (its map turning down over the last 16 %), and the
        clip was not tried.
        """
        return None

    def unlike(self, parameters: dict) -> str | None:
        """Why a fit at `parameters` is not this effect at all, whatever its size, or None (the default).

        `parameters`: the fit's values by name, with its `derived` quantities on the recording beside them.

        A candidate refused for its size alone is reported as "too small to count", with the thresholds
        that would admit it; a fit that took another form (a resonance of ζ 1, two real poles: a lag) is
        not offered so.
        """
        return None

    def unpinned_reason(self, name: str, signal: np.ndarray) -> str | None:
        """Why a recording whose signal entering this effect is `signal` cannot pin parameter `name`.

        None (the default) where the effect does not know; `diagnose` then says
        what the numbers show.
        """
        return None

    def units_for(self, signal_unit: str, drive_unit: str = "") -> dict[str, str]:
        """`units` with ``{signal}`` replaced by `signal_unit` and ``{drive}`` by `drive_unit`.

        A simulation that does not state its `output_unit` gives
        ``"(unit of S)"``: the unit of its output, whatever that is.
        """
        return _filled(self.units, signal_unit, drive_unit)

    def derived_units_for(self, signal_unit: str, drive_unit: str = "") -> dict[str, str]:
        """`derived_units` filled in as `units_for` fills `units`."""
        return _filled(self.derived_units, signal_unit, drive_unit)

    def config(self) -> dict:
        """The JSON-able settings that rebuild this effect's skeleton (`from_config`); default none."""
        return {}

    @classmethod
    def from_config(cls, config: dict) -> AbstractEffect:
        """The effect `config()` describes, with its default values."""
        return cls(**config)

    def parameters(self) -> dict[str, Array]:
        return decode(self.raw, self.constraints)

    def with_values(self, **values) -> AbstractEffect:
        current = {k: float(v) for k, v in self.parameters().items()}
        current.update(values)
        return eqx.tree_at(lambda e: e.raw, self, encode(current, self.constraints, self.name))

    def derived(self, s, dt: float) -> dict[str, float]:
        """Quantities an experimenter reads more easily than the raw parameters."""
        return {}


def thresholds_of(effect, materiality: dict) -> dict:
    """`effect`'s materiality thresholds, each overridden by `materiality`'s value of that name."""
    return {k: materiality.get(k, v) for k, v in effect.thresholds.items()}


def init_values(effect, values):
    """Set `effect.raw` from its defaults updated by `values` (what a built-in effect's __init__ does)."""
    merged = {**effect.defaults, **(values or {})}
    effect.raw = encode(merged, effect.constraints, effect.name)


def signal_span(signal) -> float:
    """The range of a signal (at least 1e-9: a flat signal still gets finite starts)."""
    return max(float(np.ptp(signal)), 1e-9)


def signal_top(signal) -> float:
    """The largest |value| of a signal (at least 1e-9)."""
    return max(float(np.max(np.abs(signal))), 1e-9)


def shown(size: float, need: float, digits: int = 1, kind: str = "f") -> str:
    """`size` to `digits` decimals (`kind` "f"; "g": significant digits), or to as many more as show it
    below `need` where it is (up to 12).

    A materiality line read "gain change 5.0 % (needs ≥ 5.0 %)" for a size of 4.97 % refused (a probe's).
    """
    text = f"{size:.{digits}{kind}}"
    while size < need and float(text) >= need and digits < 12:
        digits += 1
        text = f"{size:.{digits}{kind}}"
    return text


def _sides(signal) -> tuple[float, float]:
    """The largest positive and negative excursions, each at least 5 % of the largest |value|."""
    top = signal_top(signal)
    return max(float(np.max(signal)), 0.05 * top), max(float(-np.min(signal)), 0.05 * top)


class Delay(AbstractEffect):
    """Dead time d: y(t) = s(t − d), linearly interpolated; s = 0 before the recording (rest)."""

    raw: dict[str, Array]
    name: ClassVar[str] = "delay"
    constraints: ClassVar = {"delay_s": Positive()}
    units: ClassVar = {"delay_s": "s"}
    defaults: ClassVar = {"delay_s": 0.05}
    thresholds: ClassVar = {"delay_samples": 1.0}
    n_screened: ClassVar[int] = 3

    def __init__(self, **values):
        init_values(self, values)

    def apply(self, s, dt):
        d = self.parameters()["delay_s"]
        n = jnp.arange(-1, s.shape[0], dtype=s.dtype)
        return jnp.interp(n[1:] - d / dt, n, jnp.concatenate([jnp.zeros(1, s.dtype), s]), left=0.0)

    def derived(self, s, dt):
        return {"delay_samples": float(self.parameters()["delay_s"] / dt)}

    def starts(self, context):
        # The objective is multimodal in the dead time (one basin per few samples):
        # the lag that best aligns the current model; `screened_starts` adds screened ones.
        return [{"delay_s": max(context.lag_samples - 0.25, 0.75) / context.rate}]

    def screened_starts(self, context):
        from ._starts import delay_starts

        return delay_starts(
            context.problem,
            context.simulation,
            context.rate,
            self.n_screened,
            context.frozen,
            context.dead_times,
        )

    def reading(self, parameters, output_unit):
        # The frame timing (≤ 1 sample, always fitted) adds to the dead time, and the two trade: a user read
        # delay_s alone, 0.27 s for a 0.30 s delay whose last sample the frame lag had taken.
        delay, lag = parameters.get("delay_samples"), parameters.get("frame_lag")
        if delay is None or lag is None or not delay > 0:
            return ""
        dt = parameters.get("delay_s", 0.0) / delay
        return (
            f"a dead time of {delay + lag:.3g} samples ({(delay + lag) * dt:.3g} s) in all with the frame timing's "
            f"{lag:.2g}; the two trade places within a sample, so read their sum"
        )

    def material(self, derived, parameters, thresholds):
        # The dead time beyond the frame timing (≤ 1 sample, fitted in the baseline too).
        delay, lag = derived.get("delay_samples", 0.0), parameters.get("frame_lag", 0.0)
        need = thresholds["delay_samples"]
        return delay + lag >= need, (
            f"delay {delay:.2f} + frame lag {lag:.2f} = {shown(delay + lag, need, 2)} samples (needs ≥ {need} in all)"
        )


def affine_recurrence(a, b, x0=0.0):
    """x[n] = a[n] x[n−1] + b[n] for n = 0..T−1 from x[−1] = x0, as a sequential `lax.scan`.

    The composition of affine maps is associative, so a parallel
    `lax.associative_scan` would do too, but under `diagnose`'s batched
    forward-mode Jacobians it compiles 4–12× slower and runs 0.7–1.6× as long
    on a CPU (`benchmarks/scan_forms.py`, 9,000 and 36,000 samples).
    """
    a = jnp.broadcast_to(a, b.shape)

    def step(x, ab):
        x = ab[0] * x + ab[1]
        return x, x

    return lax.scan(step, jnp.asarray(x0, b.dtype), (a, b))[1]


def _first_order_lowpass(s, a):
    """x[n] = a x[n−1] + (1 − a) s[n], x[−1] = 0 (the discrete low-pass 1/(τs + 1))."""
    return affine_recurrence(a, (1 - a) * s)


def _lagged_lowpass(s, dt, tau):
    """x with τẋ = s − x from rest, exact for s held over each sample, read one sample late (x[0] = 0)."""
    x = _first_order_lowpass(s, jnp.exp(-dt / tau))
    return jnp.concatenate([jnp.zeros(1, s.dtype), x[:-1]])


class _SlowResponse(AbstractEffect):
    """y = s + σ·β·x with τẋ = s − x (x from rest, read one sample late), σ = `sign`: a held drive's response
    changes slowly by the fraction β with time constant τ.

    Discretised exactly for a signal held over each sample (a = e^{−dt/τ}). The
    parameters are ``<key>_time_s`` and ``<key>_fraction``; ``derived`` gives
    ``<key>_percent`` (100 β), and `material` compares it with that threshold.
    """

    key: ClassVar[str]
    sign: ClassVar[float]

    def __init__(self, **values):
        init_values(self, values)

    def apply(self, s, dt):
        p = self.parameters()
        return s + self.sign * p[f"{self.key}_fraction"] * _lagged_lowpass(s, dt, p[f"{self.key}_time_s"])

    def derived(self, s, dt):
        return {f"{self.key}_percent": 100.0 * float(self.parameters()[f"{self.key}_fraction"])}

    def material(self, derived, parameters, thresholds):
        size, need = derived.get(f"{self.key}_percent", 0.0), thresholds[f"{self.key}_percent"]
        return size >= need, f"{self.key} {shown(size, need)} % (needs ≥ {need} %)"


class BackRelaxation(_SlowResponse):
    """y = s − β x with τ ẋ = s − x: a held drive relaxes by the fraction β with time constant τ.

    Discretised exactly for a signal held over each sample (a = e^{−dt/τ}).
    """

    raw: dict[str, Array]
    name: ClassVar[str] = "back_relaxation"
    key: ClassVar[str] = "relaxation"
    sign: ClassVar[float] = -1.0
    constraints: ClassVar = {"relaxation_time_s": Positive(), "relaxation_fraction": UnitInterval()}
    units: ClassVar = {"relaxation_time_s": "s", "relaxation_fraction": "1"}
    defaults: ClassVar = {"relaxation_time_s": 10.0, "relaxation_fraction": 0.3}
    thresholds: ClassVar = {"relaxation_percent": 10.0}

    def starts(self, context):
        return [
            {"relaxation_time_s": 5.0, "relaxation_fraction": 0.3},
            {"relaxation_time_s": min(30.0, context.duration / 3), "relaxation_fraction": 0.5},
            {"relaxation_time_s": 3.0, "relaxation_fraction": 0.8},
        ]


class Creep(_SlowResponse):
    """y = s + β x with τ ẋ = s − x: a held drive's response creeps on by the fraction β with time constant τ.

    The mirror of `BackRelaxation` (which gives some of the response back): a
    piezo stack's or a polymer's creep, a viscoelastic flexure, a battery's slow
    diffusion beside its fast RC pair. One exponential, as back-relaxation's;
    a creep spread over decades of time (logarithmic) is fitted by the τ the
    recording weighs most. Discretised exactly for a signal held over each
    sample (a = e^{−dt/τ}), starting at rest. Searched only when named
    (``--effects builtins,creep``; `NAMED_ONLY`): the default set keeps its
    lanes, and a remainder that a linear filter of the drive recovers points
    here.
    """

    raw: dict[str, Array]
    name: ClassVar[str] = "creep"
    key: ClassVar[str] = "creep"
    sign: ClassVar[float] = 1.0
    constraints: ClassVar = {"creep_time_s": Positive(), "creep_fraction": Positive()}
    units: ClassVar = {"creep_time_s": "s", "creep_fraction": "1"}
    defaults: ClassVar = {"creep_time_s": 5.0, "creep_fraction": 0.1}
    thresholds: ClassVar = {"creep_percent": 3.0}

    def starts(self, context):
        return [
            {"creep_time_s": 1.0, "creep_fraction": 0.05},
            {"creep_time_s": 5.0, "creep_fraction": 0.1},
            {"creep_time_s": min(30.0, context.duration / 3), "creep_fraction": 0.1},
        ]


#: Sharpness from which a saturation's knee reads as a hard clip: at its level the response
#: reaches 0.966 of the level, tanh(1)^(1/8) (a tanh's reaches 0.762, ``tanh(1)``).
SHARP_KNEE = 8.0
#: A saturation's shortfall at the signal's peak (%) below which its level on that side is not reported:
#: the signal stays on the straight part (a tanh's level then lies 5.7 times beyond the peak or more).
REACHED_PERCENT = 1.0
#: Sharpness below which the knee reads as soft: the response approaches its levels slowly.
SOFT_KNEE = 0.7


def _log_tanh_exp(z):
    """log tanh(eᶻ), accurate at both ends (its series below e⁻¹⁵, 0 above e³ where tanh is 1 − 2e⁻⁴⁰)."""
    low, high = z < -15.0, z >= 3.0
    mid = jnp.clip(z, -15.0, 3.0)
    return jnp.where(
        low,
        z - jnp.exp(2.0 * jnp.minimum(z, -15.0)) / 3.0,
        jnp.where(high, 0.0, jnp.log(jnp.tanh(jnp.exp(mid)))),
    )


def _soft_clip(s, k, n=None):
    """s's saturation of curvature k and sharpness n: sign(s)·tanh(|ks|ⁿ)^(1/n)/|k|.

    Even in k and equal to s at k = 0 (finite gradients there too); slope 1 at
    s = 0, levels ±1/|k|. n = None is the tanh, tanh(ks)/k (the saturations',
    computed directly); as n grows the knee sharpens towards the hard clip
    clip(s, −1/|k|, 1/|k|) (n = 8: 0.966 of the level at the level; n → ∞: the
    clip itself). Computed as s·g with log g = (log tanh(xⁿ) − n log x)/n,
    x = |ks|, which stays finite for x → 0 (g → exp(−x²ⁿ/3n)) and for large x or n.
    """
    if n is None:
        x = k * s
        small = jnp.abs(x) < 1e-4
        k_safe = jnp.where(jnp.abs(k) < 1e-300, 1.0, k)
        x_safe = jnp.where(small, 1.0, x)
        return jnp.where(small, s * (1.0 - x * x / 3.0), jnp.tanh(x_safe) / k_safe)
    x = jnp.abs(k * s)
    tiny = x < 1e-12
    log_x = jnp.log(jnp.where(tiny, 1.0, x))
    log_g = (_log_tanh_exp(n * log_x) - n * log_x) / n
    return jnp.where(tiny, s, s * jnp.exp(jnp.where(tiny, 0.0, log_g)))


class _SidedSaturation(AbstractEffect):
    """sign(x)·tanh(|κ± x|ⁿ)^(1/n)/|κ±| (κ₊ for x ≥ 0), slope 1 at x = 0, on whichever signal.

    κ± is the curvature of each side (1/unit of the signal); κ = 0 is the
    linear response, so the effect-free simulation lies inside the family (at a
    finite parameter, where a saturation level σ = 1/κ would need σ → ∞). The
    response levels off at ±1/|κ±|: ``derived`` reports those levels and the
    shortfall below the linear extrapolation at the largest |x| of each sign.
    The sharpness n (one for both sides) shapes the knee: 1, a tanh's, in
    `Saturation` and `DriveSaturation`; fitted in `Clip` and `DriveClip`, where
    an amplifier's rail, a DAC's range or a sensor's full scale clips hard
    (n ≥ `SHARP_KNEE`: the level is reached almost at once) and a soft
    material bends over slowly (n < 1). The parameters are
    ``<name>_pos_curvature``, ``<name>_neg_curvature`` (and ``<name>_sharpness``).
    """

    thresholds: ClassVar = {"shortfall_percent": 5.0}
    derived_units: ClassVar = {"level_pos": SIGNAL, "level_neg": SIGNAL}
    levels: ClassVar = {"level_pos": 1, "level_neg": -1}

    def __init__(self, **values):
        init_values(self, values)

    def _curvature(self, side: str):
        return self.parameters()[f"{self.name}_{side}_curvature"]

    def _sharpness(self):
        """The knee's sharpness n: fitted by `Clip` and `DriveClip`; None (a tanh's) for the saturations."""
        return self.parameters().get(f"{self.name}_sharpness")

    def apply(self, s, dt):
        k = jnp.where(s >= 0, self._curvature("pos"), self._curvature("neg"))
        return _soft_clip(s, k, self._sharpness())

    @staticmethod
    def _peaks(signal) -> tuple[tuple[str, float], ...]:
        return ("pos", float(np.max(signal))), ("neg", float(-np.min(signal)))

    def derived(self, s, dt):
        """Each side's shortfall below the linear extrapolation at the largest |s| of its sign, %, and its
        level 1/|κ| where `s` reaches it (a shortfall ≥ `REACHED_PERCENT`): a level far beyond the data's
        peak is not measured, and a one-sided clip fitted its other side anywhere out there."""
        out = {}
        n = self._sharpness()
        n = None if n is None else float(n)
        for side, peak in self._peaks(s):
            if peak <= 0:
                continue
            k = abs(float(self._curvature(side)))
            shortfall = 100.0 * (1.0 - float(_soft_clip(jnp.asarray(peak), k, n)) / peak)
            if shortfall >= REACHED_PERCENT:
                out[f"level_{side}"] = 1.0 / k
            out[f"shortfall_{side}_percent"] = shortfall
        return out

    def starts(self, context):
        # Curvatures whose shortfall at the largest |s| is about 3 % (next to the
        # current model, so LM can only improve on it), 13 % and 35 %, on a tanh's knee.
        pos, neg = _sides(context.signal)
        keys = f"{self.name}_pos_curvature", f"{self.name}_neg_curvature"
        return [dict(zip(keys, (c / pos, c / neg))) for c in (0.3, 1 / 1.5, 1 / 0.8)]

    def unpinned_reason(self, name, signal):
        if name == f"{self.name}_neg_curvature" and np.min(signal) >= 0:
            return "the signal it acts on never goes negative"
        if name == f"{self.name}_pos_curvature" and np.max(signal) <= 0:
            return "the signal it acts on never goes positive"
        if name == f"{self.name}_sharpness":
            reach = max(abs(float(self._curvature(side))) * peak for side, peak in self._peaks(signal))
            if reach < 0.5:
                return (
                    f"the signal it acts on stays below the knee (at most {reach:.2g} of a level), "
                    "where every sharpness bends alike"
                )
        return None

    def reading(self, parameters, output_unit):
        n = parameters.get(f"{self.name}_sharpness", 1.0)
        if n >= SHARP_KNEE:
            return (
                f"a sharp knee (sharpness {n:.3g}; a tanh's is 1): close to a hard clip at its levels, as an "
                "amplifier's rail, a DAC's range or a sensor's range gives"
            )
        if n <= SOFT_KNEE:
            return f"a soft knee (sharpness {n:.3g}; a tanh's is 1): it approaches its levels slowly"
        return ""

    def material(self, derived, parameters, thresholds):
        worst = max([v for k, v in derived.items() if k.startswith("shortfall")] or [0.0])
        need = thresholds["shortfall_percent"]
        return worst >= need, f"shortfall {shown(worst, need)} % (needs ≥ {need} %)"


def _sided_facts(name: str, sharp: bool = False) -> tuple[dict, dict, dict]:
    """(constraints, units, defaults) of a sided saturation: its two curvatures, and its sharpness where `sharp`."""
    keys = (f"{name}_pos_curvature", f"{name}_neg_curvature")
    constraints: dict[str, Constraint] = {k: Real() for k in keys}
    units = dict.fromkeys(keys, "1/{signal}")
    defaults = dict.fromkeys(keys, 0.0)
    if sharp:
        sharpness = f"{name}_sharpness"
        constraints[sharpness], units[sharpness], defaults[sharpness] = Positive(), "1", 1.0
    return constraints, units, defaults


class Saturation(_SidedSaturation):
    """On the output: y = tanh(κ₊ s)/κ₊ for s ≥ 0 and tanh(κ₋ s)/κ₋ for s < 0 (κ± in 1/unit of s).

    A strip, a sensor or a camera's field that cannot follow the simulation
    beyond a level, each side its own (see `_SidedSaturation` for the form;
    `Clip` for a knee of any sharpness).
    """

    raw: dict[str, Array]
    name: ClassVar[str] = "saturation"
    refinement: ClassVar[str | None] = "clip"
    constraints, units, defaults = _sided_facts("saturation")


class DriveSaturation(_SidedSaturation):
    """On the drive: u ↦ tanh(κ± u)/κ± (κ± in 1/unit of the drive), each side its own.

    An amplifier or a DAC stage that clips, a pump or valve at its limit: the
    drive that reaches the dynamics levels off at ±1/|κ±|. Unlike the output's
    saturation it is filtered by the dynamics, so a fast drive's clipped peaks
    are smoothed, and a slow one's flattened (`DriveClip` for a hard clip).
    """

    raw: dict[str, Array]
    name: ClassVar[str] = "drive_saturation"
    place: ClassVar[str] = "drive"
    refinement: ClassVar[str | None] = "drive_clip"
    n_kept: ClassVar[int] = 1  # its starts are sizes of one form: a few steps tell them apart
    constraints, units, defaults = _sided_facts("drive_saturation")


class _SharpKnee(_SidedSaturation):
    """A sided saturation whose knee's sharpness is fitted: starts at a tanh's knee and at a hard clip's."""

    def starts(self, context):
        # the saturation's three starts (n = 1), and a hard clip (n = SHARP_KNEE) at 0.8 of the peaks
        pos, neg = _sides(context.signal)
        sharp = {
            f"{self.name}_pos_curvature": 1 / (0.8 * pos),
            f"{self.name}_neg_curvature": 1 / (0.8 * neg),
            f"{self.name}_sharpness": SHARP_KNEE,
        }
        return [*super().starts(context), sharp]


class Clip(_SharpKnee):
    """On the output: a saturation whose knee's sharpness n is fitted (n = 1: `Saturation`; n → ∞: a hard clip).

    A sensor's full scale, a camera's field, an ADC's range: the output stops
    at a level, sharply, where a tanh bends over the whole range. Searched
    when named (``--effects builtins,clip``; `NAMED_ONLY`): its third
    parameter would let it stand in for effects of other shapes in the
    default search (a drift under a rising level).
    """

    raw: dict[str, Array]
    name: ClassVar[str] = "clip"
    constraints, units, defaults = _sided_facts("clip", sharp=True)


class DriveClip(_SharpKnee):
    """On the drive: a saturation whose knee's sharpness n is fitted (n = 1: `DriveSaturation`; n → ∞: a clip).

    An amplifier's rails, a DAC's range, a valve's stops: the drive that
    reaches the dynamics stops at a level, sharply. Searched when named
    (``--effects builtins,drive_clip``; `NAMED_ONLY`), as `Clip` is.
    """

    raw: dict[str, Array]
    name: ClassVar[str] = "drive_clip"
    place: ClassVar[str] = "drive"
    constraints, units, defaults = _sided_facts("drive_clip", sharp=True)


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
        "hysteresis_height": Real(),
        "hysteresis_rate": Positive(),
        "hysteresis_initial_state": SignedUnitInterval(),
    }
    units: ClassVar = {
        "hysteresis_height": "{signal}",
        "hysteresis_rate": "1/{signal}",
        "hysteresis_initial_state": "1",
    }
    defaults: ClassVar = {
        "hysteresis_height": 0.01,
        "hysteresis_rate": 10.0,
        "hysteresis_initial_state": 0.0,
    }
    #: A loop smaller than 3 % of the range is within modelling slack. A loop the recording never closes
    #: is no loop: where the rate times the signal's range k·ptp(s) is small, a sweep across the whole
    #: range moves the state by tanh(k·ptp(s)) at most, its branches never bend, and the state creeps
    #: with the distance the signal travels, standing in for something slow. In
    #: `experiments/discrepancy.py`'s single-effect draws the hidden loops were fitted at k·ptp(s) =
    #: 4.0–12.5; the one hysteresis named beside a hidden back-relaxation at 0.12, and on a plug-in
    #: plant's additive baseline wander a "loop" of 563 % of the range was named at 0.30 (`experiments/motor_wander.py`).
    #: A loop is seen only where the signal turns back: on a record whose signal only rises (a staircase
    #: of rising levels) the state runs along one branch, a static curve the data cannot tell from a
    #: saturation's, and its height is whatever fits that curve (a probe's output saturation under a
    #: rising staircase: "hysteresis" with a loop 838 % of the range, nothing ambiguous). The signal's
    #: largest turn back (`signal_turn`) must span a tenth of its range (`turn_percent_of_range`; with a
    #: turn of rate × turn ≥ 1 alone, the same staircase fitted a 10 % loop of rate 1.3e4/V that switched
    #: on a 0.4 % wiggle).
    thresholds: ClassVar = {
        "loop_height_percent_of_range": 3.0,
        "loop_rate_times_range": 1.0,
        "turn_percent_of_range": 10.0,
    }
    n_screened: ClassVar[int] = 1

    def __init__(self, **values):
        init_values(self, values)

    def apply(self, s, dt):
        p = self.parameters()
        u = bouc_wen_state(s, p["hysteresis_rate"], p["hysteresis_initial_state"])
        return s + p["hysteresis_height"] * u

    def derived(self, s, dt):
        """Loop height 2|W| as a percentage of the signal's range, the rate times that range, and the
        signal's largest turn back as a percentage of its range (`signal_turn`)."""
        span = float(np.ptp(s))
        p = self.parameters()
        height = 2.0 * abs(float(p["hysteresis_height"]))
        turn = signal_turn(s)
        return {
            "loop_height_percent_of_range": 100.0 * height / span if span > 0 else 0.0,
            "loop_rate_times_range": float(p["hysteresis_rate"]) * span,
            "turn_percent_of_range": 100.0 * turn / span if span > 0 else 0.0,
        }

    def starts(self, context):
        # Narrow and wide loops, and a wide, slow one (k·range 3: branches that bend over a third of
        # the range, as a Preisach loop's widest plays do). Without it, every lane of hysteresis seed 13
        # of `experiments/discrepancy.py` (a 9 % loop) ended on a 0.3 % loop, immaterial, and nothing was
        # named; from it the lane ends on a 10.5 % loop at a held-out gain of 2.5.
        span = signal_span(context.signal)
        return [
            {"hysteresis_height": 0.03 * span, "hysteresis_rate": 10.0 / span},
            {"hysteresis_height": 0.1 * span, "hysteresis_rate": 40.0 / span},
            {"hysteresis_height": 0.05 * span, "hysteresis_rate": 3.0 / span},
        ]

    def screened_starts(self, context):
        from ._starts import hysteresis_starts

        return hysteresis_starts(context.problem, context.simulation, self.n_screened, context.frozen)

    def unlike(self, parameters):
        # a signal that never turns back by 1 % of its range shows one branch: no loop at all, whatever
        # its size (a smaller turn than `turn_percent_of_range` asks is a matter of size, which a user may set)
        turn = parameters.get("turn_percent_of_range")
        if turn is not None and turn < 1.0:
            return f"the signal it acts on never turns back (its largest turn is {turn:.2g} % of its range): one branch, no loop"
        return None

    def material(self, derived, parameters, thresholds):
        size, need = (
            derived.get("loop_height_percent_of_range", 0.0),
            thresholds["loop_height_percent_of_range"],
        )
        closes, least = derived.get("loop_rate_times_range", np.inf), thresholds["loop_rate_times_range"]
        if closes < least:
            return False, (
                f"the loop never closes: rate × range {shown(closes, least, 2, 'g')} (needs ≥ {least:g}); its state creeps "
                "with the distance travelled, a slow trend rather than a loop"
            )
        turn, span = derived.get("turn_percent_of_range", 100.0), thresholds["turn_percent_of_range"]
        if turn < span:
            return False, (
                f"the signal it acts on never turns back far enough to show a loop: its largest turn is "
                f"{shown(turn, span, 2, 'g')} % of its range (needs ≥ {span:g} %); along one branch a loop is a static curve, "
                "which a saturation or an even response fits alike: a drive that goes up and down tells them "
                "apart"
            )
        return size >= need, f"loop {shown(size, need)} % of range (needs ≥ {need} %)"


def signal_turn(s) -> float:
    """How far `s` turns back: the smaller of its largest fall below its running maximum and its largest
    rise above its running minimum (0 for a signal that only rises or only falls; for a sweep up and
    back down, the way back)."""
    s = np.asarray(s, float)
    if not s.size:
        return 0.0
    fall = float(np.max(np.maximum.accumulate(s) - s))
    rise = float(np.max(s - np.minimum.accumulate(s)))
    return min(fall, rise)


#: The gain changes over the record that `Drift`'s lanes start from (none, a fall, a rise).
DRIFT_START_CHANGES = (0.0, -0.2, 0.25)


class Drift(AbstractEffect):
    """y = s · exp(κ t): the actuation gain changes monotonically, t from the first sample."""

    raw: dict[str, Array]
    name: ClassVar[str] = "drift"
    of_time: ClassVar[bool] = True
    constraints: ClassVar = {"drift_rate_per_s": Real()}
    units: ClassVar = {"drift_rate_per_s": "1/s"}
    defaults: ClassVar = {"drift_rate_per_s": 0.0}
    thresholds: ClassVar = {"gain_change_percent": 5.0}

    def __init__(self, **values):
        init_values(self, values)

    def apply(self, s, dt):
        t = dt * jnp.arange(s.shape[0], dtype=s.dtype)
        return s * jnp.exp(self.parameters()["drift_rate_per_s"] * t)

    def derived(self, s, dt):
        duration = dt * (s.shape[0] - 1)
        change = float(jnp.expm1(self.parameters()["drift_rate_per_s"] * duration))
        return {"gain_change_percent": 100.0 * change, "over_s": float(duration)}

    def starts(self, context):
        # From no drift alone, LM's first steps trade the drift against the simulation's slow poles and
        # the validation part keeps the start: a 24 % smoothstep change stayed at 0.0 % (drift seed 6 of
        # `experiments/discrepancy.py`, named backlash). A fall and a rise over the record start it too.
        duration = max(float(context.duration), 1e-12)
        return [{"drift_rate_per_s": math.log1p(change) / duration} for change in DRIFT_START_CHANGES]

    def material(self, derived, parameters, thresholds):
        size, need = abs(derived.get("gain_change_percent", 0.0)), thresholds["gain_change_percent"]
        return size >= need, f"gain change {shown(size, need)} % (needs ≥ {need} %)"


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


#: Below this h, `first_order_foh`'s Γ₁ = 1 − (1 − e^{−h})/h is summed as its series (through h⁶,
#: truncated at h⁶/20160 of it), where the difference would lose digits (eps/h).
FOH_SERIES_BELOW = 0.02


def first_order_foh(h):
    """`foh_matrices` of the unity-gain lag ẋ = (u − x)/τ, in closed form: (Φ, Γ₀, Γ₁) for h = dt/τ.

    Φ = e^{−h}, Γ₀ = 1 − e^{−h} (`expm1`: exact for a lag of many samples) and
    Γ₁ = 1 − (1 − e^{−h})/h: the numbers of `foh_matrices`' matrix exponential
    to rounding, without it. Under the search's batched Jacobians the 3×3
    `expm` took ~1–1.5 s of tracing and compiling in each of the lanes' and
    the covariance's programs (`benchmarks/diagnose_effect_set.py`).
    """
    gone = -jnp.expm1(-h)  # 1 − e^{−h}
    small = h < FOH_SERIES_BELOW
    hs = jnp.where(small, h, FOH_SERIES_BELOW)  # each branch finite, and its derivative, wherever h is
    series = hs * (1 / 2 - hs * (1 / 6 - hs * (1 / 24 - hs * (1 / 120 - hs * (1 / 720 - hs / 5040)))))
    return jnp.exp(-h), gone, jnp.where(small, series, 1.0 - gone / jnp.where(small, 1.0, h))


class Lag(AbstractEffect):
    """A first-order lag, unity DC gain: 1/(τs + 1) applied to s, from rest at its first value.

    A sensor's time constant (a thermocouple in its sheath, a displacement
    sensor's or an amplifier's low-pass filter) or a pole the simulation lacks.
    Discretised exactly for a signal linear between samples (first-order hold,
    `foh_matrices`, as `Resonance`); x[0] = s[0] (the sensor settled where the
    record starts). Material from a time constant of one sample
    (`lag_samples`): a shorter one rounds a step within a frame, which the
    frame timing takes; and to a time constant of the record's length
    (`lag_records`): a longer one never settles within it, and fitted with the
    readout's gain it is an integral of the signal (a probe's 1953 s lag on a
    100 s record stood in for a baseline drift).
    """

    raw: dict[str, Array]
    name: ClassVar[str] = "lag"
    constraints: ClassVar = {"lag_time_s": Positive()}
    units: ClassVar = {"lag_time_s": "s"}
    defaults: ClassVar = {"lag_time_s": 0.1}
    thresholds: ClassVar = {"lag_samples": 1.0, "lag_records": 1.0}

    def __init__(self, **values):
        init_values(self, values)

    def apply(self, s, dt):
        phi, g0, g1 = first_order_foh(dt / self.parameters()["lag_time_s"])
        # From rest on d = s − s[0] (unity DC gain): with z = x − Γ₁ d, z[n+1] = Φ z[n] + (ΦΓ₁ + Γ₀ − Γ₁) d[n].
        first = s[0]
        d = s - first
        z = affine_recurrence(phi, (phi * g1 + g0 - g1) * d[:-1])
        return first + jnp.concatenate([jnp.zeros(1, s.dtype), z]) + g1 * d

    def derived(self, s, dt):
        tau = float(self.parameters()["lag_time_s"])
        return {"lag_samples": tau / dt, "lag_records": tau / (dt * max(len(s) - 1, 1))}

    def reading(self, parameters, output_unit):
        tau = parameters.get("lag_time_s", float("nan"))
        return (
            f"a time constant of {tau:.3g} s between the system and the record (a sensor's, a filter's) or a "
            "pole the simulation lacks; with linear dynamics the same lag at the drive acts alike, and where the "
            "simulation has a free time constant of its own the two may trade places: which is the sensor's, "
            "the data do not say"
        )

    def starts(self, context):
        # A lag of τ delays the slow part of a response by about τ: the lag that best aligns the current
        # model, a slow one (a thermocouple's seconds against a sample of a fraction of one) and one
        # between them on a log scale. All three run the whole race (no `n_kept`): kept after 6 steps,
        # the best lane on tests/test_sensor_lag.py's plant was not the one that ends on the sensor's
        # 0.5 s, and nothing was named.
        dt = 1.0 / context.rate
        fast = max(float(context.lag_samples), 2.0) * dt
        slow = max(context.duration / 30.0, 10.0 * fast)
        return [{"lag_time_s": tau} for tau in (fast, math.sqrt(fast * slow), slow)]

    def material(self, derived, parameters, thresholds):
        size, need = derived.get("lag_samples", 0.0), thresholds["lag_samples"]
        records, most = derived.get("lag_records", 0.0), thresholds["lag_records"]
        if size >= need and records > most:
            return False, (
                f"time constant {size:.4g} samples, {records:.3g} × the record (needs ≤ {most:g}): a lag the "
                "record never sees settle acts as an integral of the signal, not as a sensor's lag"
            )
        return size >= need, f"time constant {shown(size, need, 2)} samples (needs ≥ {need:g})"


#: Samples per block of `Resonance`'s recurrence (`lifted_response`).
MODE_BLOCK = 32


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
    thresholds: ClassVar = {"max_damping": 0.35, "min_frequency_hz": 0.5}
    n_screened: ClassVar[int] = 1

    def __init__(self, **values):
        init_values(self, values)

    def recurrence(self, dt, dtype):
        """(Φ, Γ₀, Γ₁) of the mode's state (position, velocity) from one sample to the next (`foh_matrices`)."""
        p = self.parameters()
        w = 2 * jnp.pi * p["resonance_frequency_hz"]
        z = p["resonance_damping"]
        a = jnp.array([[0.0, 1.0], [-w * w, -2 * z * w]], dtype)
        b = jnp.array([0.0, 1.0], dtype) * w * w
        return foh_matrices(a, b, dt)

    def apply(self, s, dt):
        phi, g0, g1 = self.recurrence(dt, s.dtype)
        # x[n+1] = Φ x[n] + Γ₀ s[n] + Γ₁ (s[n+1] − s[n]), from rest at the first value (unity DC gain:
        # x = (s[0], 0) is where a constant s[0] holds it), output x[n]₀. With z = x − Γ₁ s it is a
        # single-input system, z[n+1] = Φ z[n] + (ΦΓ₁ + Γ₀ − Γ₁) s[n], y = z₀ + Γ₁₀ s, run from rest on
        # s − s[0] in blocks (`lifted_response`) rather than one sample at a time.
        first = s[0]
        b = phi @ g1 + g0 - g1
        c = jnp.array([1.0, 0.0], s.dtype)
        return first + lifted_response(*lifted_blocks(phi, b, c, g1[0], MODE_BLOCK), s - first)

    def starts(self, context):
        # The residual's spectral peak; `screened_starts` adds a screened one.
        peak, nyquist = context.residual_peak_hz, 0.5 * context.rate
        guess = peak if peak and 0.5 <= peak < nyquist else 0.3 * context.rate
        return [{"resonance_frequency_hz": guess, "resonance_damping": 0.1}]

    def screened_starts(self, context):
        from ._starts import resonance_starts

        return resonance_starts(
            context.problem, context.simulation, context.rate, self.n_screened, context.frozen
        )

    def derived(self, s, dt):
        """The mode's frequency over the Nyquist frequency (1/(2 dt))."""
        return {"over_nyquist": float(self.parameters()["resonance_frequency_hz"] * 2.0 * dt)}

    def material(self, derived, parameters, thresholds):
        f, z = parameters["resonance_frequency_hz"], parameters["resonance_damping"]
        most, least = thresholds["max_damping"], thresholds["min_frequency_hz"]
        # at or above the Nyquist frequency a mode is aliased: the samples show another frequency, or none
        # (a chamber read at 1 Hz got a 0.98 Hz "mode")
        below = derived.get("over_nyquist", 0.0) < 1.0
        said = f"mode {f:.2f} Hz, ζ {z:.3f} (needs ζ ≤ {most}, f ≥ {least} Hz"
        said += ")" if below else f", below the Nyquist frequency {f / derived['over_nyquist']:.3g} Hz)"
        return z <= most and f >= least and below, said

    def unlike(self, parameters):
        # from ζ = 1/√2 on a second-order response has no peak: its poles act as lags, which `lag` names
        # (a probe's lag and dead time read as a 0.13 Hz mode of ζ 1.000, "too small" with max_damping to raise)
        z = parameters.get("resonance_damping")
        if z is None or not z >= 1 / math.sqrt(2):
            return None
        return f"a mode of ζ {z:.2f} has no resonant peak (from ζ 0.71 on): it acts as a lag, not a resonance"


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
        init_values(self, values)

    def apply(self, s, dt):
        f = self.parameters()["frame_lag"]
        return s - f * (s - jnp.concatenate([s[:1], s[:-1]]))

    def derived(self, s, dt):
        return {"frame_lag_s": float(self.parameters()["frame_lag"]) * dt}


#: The share of the signal's range (%) over which an even part's map rises, from which a turn inside the
#: range reads as a level the signal stops at (`_Even.reading`): a turn in the outer quarter.
TURNS_NEAR_END = 75.0
#: ... up to this share (%) beyond it: there the map's slope at the end is under 15 % of its slope where it
#: starts rising, as flat as a level.
TURNS_BEYOND_END = 115.0


class _Even(AbstractEffect):
    """x ↦ x + c x², on whichever signal: a part even in the signal (c in 1/unit of the signal).

    c = 0 is the linear response; with a gain after it the form spans
    everything from linear to purely quadratic (|c| large). ``derived`` reports
    the even part's size, |c|·max x², as a percentage of the signal's range.
    The parameter is named by the class's `coefficient`.
    """

    coefficient: ClassVar[str]
    #: The signal it acts on, in words, and the effect searched when named that stops it at a level.
    signal_words: ClassVar[str]
    level_words: ClassVar[str]
    clip: ClassVar[str]
    thresholds: ClassVar = {"even_percent_of_range": 5.0}

    def __init__(self, **values):
        init_values(self, values)

    def apply(self, s, dt):
        return s + self.parameters()[self.coefficient] * s * s

    def derived(self, s, dt):
        """The even part's size, |c| max s², as a percentage of the range of s; and the share of that
        range over which the map rises (100 where it is monotone there: it turns at s = −1/(2c))."""
        s = np.asarray(s, float)
        span, c = float(np.ptp(s)), float(self.parameters()[self.coefficient])
        even = abs(c) * float(np.max(np.square(s)))
        rising, out = 1.0, {}
        if c != 0.0 and span > 0:
            turn, low, high = -1.0 / (2.0 * c), float(np.min(s)), float(np.max(s))
            # where it turns, from the end it rises from, as a share of the range (beyond it: over 1)
            reach = (turn - low) / span if c < 0 else (high - turn) / span
            if 0.0 < reach < 1.0:  # rises below the turn where c < 0, above it where c > 0
                rising = reach
            if reach > 0.0:
                out["turn_percent_of_range"] = 100.0 * reach
        return {
            "even_percent_of_range": 100.0 * even / span if span > 0 else 0.0,
            "rising_percent_of_range": 100.0 * rising,
            **out,
        }

    def reading(self, parameters, output_unit):
        # A map that rises over most of the signal's range and turns down near one end is no even
        # response (whose turn lies near the middle of a two-signed signal, a V² force's at 0): it
        # stands in for a level the signal stops at, which this form cannot reach without turning.
        # A heater clipped at 70 % of a 0–100 % drive read drive_even (turning at 88 %) and a dead zone.
        if self.points_at(parameters) is None:
            return ""
        rising = parameters["rising_percent_of_range"]
        shape = (
            f"rises over {rising:.0f} % of the range of the {self.signal_words} and turns down over the last "
            f"{100.0 - rising:.0f} %"
            if rising < 100.0
            else f"flattens towards the end of the range of the {self.signal_words} (it would turn at "
            f"{parameters['turn_percent_of_range']:.0f} % of it)"
        )
        return (
            f"over this recording the map {shape}: {self.level_words} reads so more often than an even part; "
            f"--effects builtins,{self.clip} tests a clip"
        )

    def points_at(self, parameters):
        # a turn near the end of the range, or just beyond it (the slope there under ~15 % of where the map
        # starts rising: flat, a level): a verifier's heater clipped at 70 % of 0–20 W turned at 104 %
        rising = parameters.get("rising_percent_of_range", 100.0)
        turn = parameters.get("turn_percent_of_range", rising if rising < 100.0 else None)
        return self.clip if turn is not None and TURNS_NEAR_END <= turn < TURNS_BEYOND_END else None

    def starts(self, context):
        # An even part of 10 % of the range either way; with the gain after it, LM takes it to
        # a purely quadratic response if needed.
        span, top = signal_span(context.signal), signal_top(context.signal)
        return [{self.coefficient: 0.1 * span / top**2}, {self.coefficient: -0.1 * span / top**2}]

    def material(self, derived, parameters, thresholds):
        size, need = derived.get("even_percent_of_range", 0.0), thresholds["even_percent_of_range"]
        return size >= need, f"even part {shown(size, need)} % of range (needs ≥ {need} %)"


class EvenResponse(_Even):
    """On the output: y = s + c s², a response with a part even in the signal.

    An IPMC bends one way or the other with the sign of the drive (odd); a
    sensor that cannot see sign, or a strip whose bending adds a quadratic
    part, reads the simulation's output with an even part.
    """

    raw: dict[str, Array]
    name: ClassVar[str] = "even_response"
    coefficient: ClassVar[str] = "even_coefficient"
    signal_words: ClassVar[str] = "simulation's output"
    level_words: ClassVar[str] = "an output that stops at a level (a sensor's full scale)"
    clip: ClassVar[str] = "clip"
    constraints: ClassVar = {"even_coefficient": Real()}
    units: ClassVar = {"even_coefficient": "1/{signal}"}
    defaults: ClassVar = {"even_coefficient": 0.0}


class DriveEven(_Even):
    """On the drive: u ↦ u + c u², a force even in the drive (|c| large: ∝ u², as V² is).

    An electrostatic actuator (a dielectric elastomer, an electrostatic zipper)
    is pulled by a force ∝ V², the same for +V and −V, and that force goes
    through the dynamics: the even part is in the drive, not in the output.
    """

    raw: dict[str, Array]
    name: ClassVar[str] = "drive_even"
    place: ClassVar[str] = "drive"
    n_kept: ClassVar[int] = 1  # its starts are sizes of one form: a few steps tell them apart
    n_screened: ClassVar[int] = 1
    coefficient: ClassVar[str] = "drive_even_coefficient"
    signal_words: ClassVar[str] = "drive"
    level_words: ClassVar[str] = (
        "a drive that stops at a level (a heater's, a pump's or an amplifier's limit)"
    )
    clip: ClassVar[str] = "drive_clip"
    constraints: ClassVar = {"drive_even_coefficient": Real()}
    units: ClassVar = {"drive_even_coefficient": "1/{signal}"}
    defaults: ClassVar = {"drive_even_coefficient": 0.0}

    def starts(self, context):
        # Besides an even part of ±10 %, one mostly even (3× the odd part at the largest |u|): a force
        # ∝ u² is the physical case, and from a linear fit of it LM may not get that far (lti:2 under
        # a squared drive, experiments/inside_effects.py lti_square seed 2: none named without it).
        return super().starts(context) + [{self.coefficient: 3.0 / signal_top(context.signal)}]

    def screened_starts(self, context):
        # A drive squared gives the effect-free fit nothing odd to follow, and its dynamics then land
        # anywhere: the RC network's fit of a squared drive reached held-out NMSE 1.16, and drive_even
        # from there stayed at 1.12 (a gain of 1.04) on experiments/inside_effects.py rc_square seeds 1
        # and 2, whose effect moves the output by 48 and 80 % of its range. Screened with the dynamics,
        # the mostly even and the purely even (30× the odd part at the largest |u|) forms, either sign.
        from ._starts import joint_starts

        top = signal_top(context.signal)
        values = [{self.coefficient: k / top} for k in (3.0, -3.0, 30.0)]
        return joint_starts(context, self, values, self.n_screened)


class BaselineDrift(AbstractEffect):
    """y = s + a·t + b·t² + c·t³, t in minutes from the recording's first sample: the output's zero wanders.

    The commonest drift of a real sensor or a warming plant is additive: the
    baseline creeps while the response stays the same (`Drift` is the other
    kind, a gain that changes). Zero at the first sample, so the readout's
    offset keeps its meaning; a, b and c are in the unit of the signal per
    minute (per minute², per minute³), which keeps their Jacobian columns of
    order one on recordings of minutes. The cubic term lets the trend turn
    twice, as a ramp with a slow swing does (a sine whose period is a few
    recordings long: a quadratic follows a quarter of its cycle, not two thirds).
    ``derived`` reports how far the trend moves over the recording (its lowest
    to its highest) as a percentage of the signal's range.
    """

    raw: dict[str, Array]
    name: ClassVar[str] = "baseline_drift"
    of_time: ClassVar[bool] = True
    constraints: ClassVar = {
        "baseline_slope_per_min": Real(),
        "baseline_curvature_per_min2": Real(),
        "baseline_cubic_per_min3": Real(),
    }
    units: ClassVar = {
        "baseline_slope_per_min": "{signal}/min",
        "baseline_curvature_per_min2": "{signal}/min²",
        "baseline_cubic_per_min3": "{signal}/min³",
    }
    defaults: ClassVar = {
        "baseline_slope_per_min": 0.0,
        "baseline_curvature_per_min2": 0.0,
        "baseline_cubic_per_min3": 0.0,
    }
    thresholds: ClassVar = {"baseline_percent_of_range": 5.0}

    def __init__(self, **values):
        init_values(self, values)

    def _trend(self, n: int, dt: float, xp=jnp):
        p = self.parameters()
        t = xp.arange(n) * (dt / 60.0)
        return t * (
            p["baseline_slope_per_min"]
            + t * (p["baseline_curvature_per_min2"] + t * p["baseline_cubic_per_min3"])
        )

    def apply(self, s, dt):
        return s + self._trend(s.shape[0], dt).astype(s.dtype)

    def derived(self, s, dt):
        span = float(np.ptp(s))
        trend = np.asarray(self._trend(len(s), dt), float)
        # how far it moves over the record, lowest to highest: the readout's offset takes its level, and a
        # baseline that falls by 3 % and comes back up by 5 % moves 5 %, not the 2 % it ends from its start
        # (a probe's sine-and-ramp drift, 6.8 % of the range, was read 4.1 % from its start and refused)
        size = float(np.ptp(trend)) if trend.size else 0.0
        return {
            "baseline_percent_of_range": 100.0 * size / span if span > 0 else 0.0,
            "over_s": float(dt * (len(s) - 1)),
        }

    def material(self, derived, parameters, thresholds):
        size, need = derived.get("baseline_percent_of_range", 0.0), thresholds["baseline_percent_of_range"]
        return size >= need, f"baseline moves {shown(size, need)} % of range (needs ≥ {need} %)"


class _DeadZone(AbstractEffect):
    """x ↦ x − clip(x, −d, d), nothing passed on while |x| ≤ d, on whichever signal.

    The half-width d (unit of the signal) is ``<name>_width``; ``derived``
    reports it as a percentage of the largest |x| (``<name>_percent``), and
    `material` asks 3 % of it. `DriveDeadZone` on the drive, `DeadBand` on the
    output; `noun` and `of` word the size's sentence.
    """

    noun: ClassVar[str]
    of: ClassVar[str]

    def __init__(self, **values):
        init_values(self, values)

    def apply(self, x, dt):
        d = self.parameters()[f"{self.name}_width"]
        return x - jnp.clip(x, -d, d)

    def derived(self, x, dt):
        top = float(np.max(np.abs(x))) if len(x) else 0.0
        d = float(self.parameters()[f"{self.name}_width"])
        return {f"{self.name}_percent": 100.0 * d / top if top > 0 else 0.0}

    def starts(self, context):
        top = signal_top(context.signal)
        return [{f"{self.name}_width": 0.05 * top}, {f"{self.name}_width": 0.2 * top}]

    def material(self, derived, parameters, thresholds):
        size, need = derived.get(f"{self.name}_percent", 0.0), thresholds[f"{self.name}_percent"]
        return size >= need, f"{self.noun} {shown(size, need)} % of the largest {self.of} (needs ≥ {need} %)"


def _dead_zone_facts(name: str) -> tuple[dict, dict, dict, dict]:
    """(constraints, units, defaults, thresholds) of a dead zone called `name`."""
    width = f"{name}_width"
    return {width: Positive()}, {width: "{signal}"}, {width: 0.01}, {f"{name}_percent": 3.0}


class DriveDeadZone(_DeadZone):
    """On the drive: u ↦ u − clip(u, −d, d), no response while |u| ≤ d.

    Static friction at the input, a diode's or an amplifier's threshold, a
    valve's overlap: the drive must pass a width d (unit of the drive) before
    anything moves. ``derived`` reports d as a percentage of the largest |u|.
    """

    raw: dict[str, Array]
    name: ClassVar[str] = "drive_dead_zone"
    place: ClassVar[str] = "drive"
    refinement: ClassVar[str | None] = "dead_band"  # the same form on the output, which it can stand in for
    n_kept: ClassVar[int] = 1  # its starts are sizes of one form: a few steps tell them apart
    noun: ClassVar[str] = "dead zone"
    of: ClassVar[str] = "drive"
    constraints, units, defaults, thresholds = _dead_zone_facts("drive_dead_zone")


class DeadBand(_DeadZone):
    """On the output: s ↦ s − clip(s, −d, d), nothing recorded while |s| ≤ d.

    A sensor or a linkage to it that does not register until the output has
    moved a half-width d (unit of the signal) from rest: stiction between the
    strip and its clamp, a gauge's threshold, a digital filter's dead band. The
    drive's dead zone (`DriveDeadZone`) is filtered by the dynamics before
    anything is recorded; this one is not. Searched when named (``--effects
    builtins,dead_band``; `NAMED_ONLY`), and tried in the drive dead zone's place
    where that is named and leaves something unexplained (its `refinement`), or
    where the remainder's map of the output is flat in the middle: a probe's
    sensor dead band on a 1 Hz oscillator read `drive_dead_zone` (gain 3.2) with
    79 % of the rest "static on the model's output". ``derived`` reports d as a
    percentage of the largest |s|. The band is centred at the simulation's rest:
    a band off it, or wider on one side, is not this form (a centre fitted beside
    the readout's offset, which moves the output outside the band alike, lost
    the generator's dead zone of `experiments/discrepancy.py` seed 0 to a clip).
    """

    raw: dict[str, Array]
    name: ClassVar[str] = "dead_band"
    noun: ClassVar[str] = "dead band"
    of: ClassVar[str] = "output"
    constraints, units, defaults, thresholds = _dead_zone_facts("dead_band")


def play(u, half_width, initial=0.0):
    """The play (backlash) operator: y[n] = clip(y[n−1], u[n] − h, u[n] + h), y[−1] = `initial`.

    A sequential `lax.scan`. (A clamp of a clamp is a clamp, so this is also a
    parallel scan of (lower, upper) pairs; like the effects' other recurrences
    it stays sequential, which compiles far faster under `diagnose`'s batched
    Jacobians: see `affine_recurrence`.)
    """

    def step(y, value):
        y = jnp.clip(y, value - half_width, value + half_width)
        return y, y

    return lax.scan(step, jnp.asarray(initial, u.dtype), u)[1]


class Backlash(AbstractEffect):
    """On the drive: the play operator of half-width h, y[n] = clip(y[n−1], u[n] − h, u[n] + h).

    Gears, a loose linkage, a cable with slack: when the drive reverses it
    must travel 2h (unit of the drive) before what it drives moves again; the
    play starts centred on the first drive (y = u[0] before the first sample),
    as the simulation starts settled there or at rest: a linkage held at a
    drive of 6.67 N before the record would otherwise start 5.2 N into it (a
    probe's spring, whose start the report then blamed on something early in
    the record). ``derived`` reports the play 2h as a percentage of the drive's
    range.
    """

    raw: dict[str, Array]
    name: ClassVar[str] = "backlash"
    place: ClassVar[str] = "drive"
    n_kept: ClassVar[int] = 1  # its starts are sizes of one form: a few steps tell them apart
    constraints: ClassVar = {"backlash_half_width": Positive()}
    units: ClassVar = {"backlash_half_width": "{signal}"}
    defaults: ClassVar = {"backlash_half_width": 0.01}
    thresholds: ClassVar = {"play_percent_of_range": 3.0}

    def __init__(self, **values):
        init_values(self, values)

    def apply(self, u, dt):
        return play(u, self.parameters()["backlash_half_width"], u[0])

    def derived(self, u, dt):
        span = float(np.ptp(u)) if len(u) else 0.0
        play_width = 2.0 * float(self.parameters()["backlash_half_width"])
        return {"play_percent_of_range": 100.0 * play_width / span if span > 0 else 0.0}

    def starts(self, context):
        span = signal_span(context.signal)
        return [{"backlash_half_width": 0.03 * span}, {"backlash_half_width": 0.1 * span}]

    def material(self, derived, parameters, thresholds):
        size, need = derived.get("play_percent_of_range", 0.0), thresholds["play_percent_of_range"]
        return size >= need, f"play {shown(size, need)} % of the drive's range (needs ≥ {need} %)"


class Line(AbstractEffect):
    """y = s + a·cos 2πft + b·sin 2πft, t from the recording's first sample: a line added to the output.

    A disturbance the drive does not cause, at one frequency and phase-locked
    over the recording: a vibration of the sensor's mount, a motor's ripple at
    a constant speed, a mains pick-up (50 or 60 Hz, or a harmonic, as the
    sampling reads it). a and b are in the unit of the signal; one phase for
    every recording of a diagnosis (a line whose phase differs between them is
    not this). Its frequency's basin is about one bin of the recording's
    spectrum wide (1/T), so the starts read the training residual's strongest
    line (`line_peak_hz`) and a third of a bin either side, the amplitudes at 0
    (the first step solves them; then the frequency moves). Searched only when
    named (``--effects builtins,line``; `NAMED_ONLY`): an unexplained remainder
    that a sinusoid the drive does not carry recovers points here. ``derived``
    reports the line's rms as a percentage of the signal's range.
    """

    raw: dict[str, Array]
    name: ClassVar[str] = "line"
    of_time: ClassVar[bool] = True
    constraints: ClassVar = {"line_frequency_hz": Positive(), "line_cos": Real(), "line_sin": Real()}
    units: ClassVar = {"line_frequency_hz": "Hz", "line_cos": "{signal}", "line_sin": "{signal}"}
    defaults: ClassVar = {"line_frequency_hz": 1.0, "line_cos": 0.0, "line_sin": 0.0}
    thresholds: ClassVar = {"line_percent_of_range": 1.0}

    def __init__(self, **values):
        init_values(self, values)

    def apply(self, s, dt):
        p = self.parameters()
        phase = 2.0 * jnp.pi * p["line_frequency_hz"] * dt * jnp.arange(s.shape[0])
        return s + (p["line_cos"] * jnp.cos(phase) + p["line_sin"] * jnp.sin(phase)).astype(s.dtype)

    def derived(self, s, dt):
        p = self.parameters()
        span = float(np.ptp(s)) if len(s) else 0.0
        rms = math.sqrt((float(p["line_cos"]) ** 2 + float(p["line_sin"]) ** 2) / 2.0)
        return {"line_percent_of_range": 100.0 * rms / span if span > 0 else 0.0, "line_rms": rms}

    def starts(self, context):
        peak = line_peak_hz(context)
        if peak is None:  # no residual to read (the probe the lanes are counted on): three guesses
            return [{"line_frequency_hz": f, "line_cos": 0.0, "line_sin": 0.0} for f in (0.5, 2.0, 8.0)]
        third = 1.0 / (3.0 * max(context.duration, 1e-12))  # a third of a bin of the recording's spectrum
        return [
            {"line_frequency_hz": max(peak + k * third, third), "line_cos": 0.0, "line_sin": 0.0}
            for k in (0, -1, 1)
        ]

    def material(self, derived, parameters, thresholds):
        size, need = derived.get("line_percent_of_range", 0.0), thresholds["line_percent_of_range"]
        return size >= need, f"line {shown(size, need)} % of range rms (needs ≥ {need} %)"


def line_peak_hz(context: StartContext) -> float | None:
    """The training residual's strongest line (Hz), from 3 cycles per record up to the Nyquist frequency.

    The residual is `measured` − `signal` on the training samples. With the
    search's `problem`, each sample goes back to its place in its recording
    (the held-out blocks zero) and the recordings' periodograms are summed: laid
    end to end instead, a line's phase jumps at every block taken out, and
    blocks taken out at a regular spacing split its peak in two beside its
    frequency (a 7.3 Hz line of a 60 s record read 7.324 Hz, outside the fit's
    basin). The periodogram is zero-padded as the remainder's is (`zero_padding`). None without
    `measured` or with too few samples.
    """
    if context.measured is None or len(context.signal) < 16:
        return None
    r = np.asarray(context.measured, float) - np.asarray(context.signal, float)
    if not np.all(np.isfinite(r)):
        return None
    series = list(getattr(context.problem, "series", None) or ())
    spans = [(i, a, b) for i, one in enumerate(series) for a, b in one.recorded_segments_of("train")]
    if spans and sum(b - a for _, a, b in spans) == r.size:
        grids = np.full((len(series), max(b for _, _, b in spans)), np.nan)
        at = 0
        for i, a, b in spans:
            grids[i, a:b] = r[at : at + b - a]
            at += b - a
    else:  # no places to put them back: end to end
        grids = r[None, :]
    freq, power = rt.periodogram(grids, context.rate, rt.zero_padding(grids.shape[1]) * grids.shape[1])
    return rt.strongest_line(freq, power, rt.MIN_CYCLES / max(context.duration, 1e-12), context.rate / 2)
