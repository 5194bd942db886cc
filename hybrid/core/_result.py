"""The typed result of a fit."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Collection
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ._arguments import FLOAT64_FIX
from ._models import Model
from ._simulation import AbstractSimulation, AbstractWrapper, from_library, unit_suffix
from ._state_space import has_states


@dataclasses.dataclass(frozen=True)
class FitResult:
    """What [`hybrid.fit`][] returns.

    **Fields:**

    - `model`: the fitted model (best start, best iterate by validation loss).
    - `parameters`: fitted interpretable parameters by name, physical units.
    - `units`: unit of each parameter.
    - `metrics`: per split (``"train"``, ``"validation"``, ``"test"``), a dict of
      ``nmse`` (Eq 18, each signal by its own max |·|), ``nmse_target`` (both by
      max |w|), ``nmse_variance`` (MSE / var w) and ``fitting`` (Eq 20, %).
    - `history`: one dict per progress report: step, train cost and validation
      loss of each start.
    - `starts`: per start: best validation loss, steps, accepted steps, best step.
    - `best_start`: index of the start that was kept.
    - `settings`: solver, starts, frozen parameters, split, seed, … (JSON-able).
    - `seconds`: wall time of the fit, compile time included.
    - `warnings`: sentences about results not to take at face value: a physical
      parameter outside its plausible range (`AbstractSimulation.plausible`) or
      still at its start value, a fit that made no accepted step, a recording
      whose time base was rebuilt (`hybrid.core._result.fit_warnings`); a
      held-out part predicted no better than by its mean; an effect of time
      fitted with the recording in one block.
    - `stopped`: true when the fit was stopped before it ended (its `stop`
      function said so: ``hybrid fit`` on SIGINT, SIGTERM or ``--time-limit``);
      `model` is then the best iterate found so far.
    """

    model: Model
    parameters: dict[str, float]
    units: dict[str, str]
    metrics: dict[str, dict[str, float]]
    history: list[dict[str, Any]]
    starts: list[dict[str, Any]]
    best_start: int
    settings: dict[str, Any]
    seconds: float
    warnings: list[str] = dataclasses.field(default_factory=list)
    stopped: bool = False

    def summary(self, said: Collection[str] = ()) -> str:
        """A few readable lines: metrics per split, the fitted parameters and the warnings (less those `said`
        already: the command line prints what reading each recording did as it reads it)."""
        lines = [
            f"{self.model.kind} model, {self.settings.get('solver')} "
            f"({len(self.starts)} start(s), kept #{self.best_start}), {self.seconds:.1f} s"
            + (", stopped early: the best model so far" if self.stopped else "")
        ]
        for split, m in self.metrics.items():
            lines.append(
                f"  {split:<10} NMSE {m['nmse']:.3e}  NMSE(target) {m['nmse_target']:.3e}  "
                f"Fitting {m['fitting']:6.2f} %"
            )
        for name, value in self.parameters.items():
            lines.append(f"  {name:<8} = {value:.6g}{unit_suffix(self.units.get(name))}")
        lines += [f"  warning: {text}" for text in self.warnings if text not in said]
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able record of the fit (without the weights)."""
        return {
            "kind": self.model.kind,
            "parameters": self.parameters,
            "units": self.units,
            "metrics": self.metrics,
            "starts": self.starts,
            "best_start": self.best_start,
            "settings": self.settings,
            "seconds": self.seconds,
            "warnings": list(self.warnings),
            "stopped": self.stopped,
            "history": self.history,
        }


#: A fitted value whose relative change from its start is below this "did not move".
UNMOVED_RTOL = 1e-6
#: A fit that leaves at least this share of the training part's variance (NMSE) may be on a plateau.
POOR_TRAIN_NMSE = 0.5
#: A physics fit with fewer training samples than this many per fitted parameter is warned about.
SAMPLES_PER_PARAMETER = 10


def fit_warnings(
    start: Model,
    fitted: Model,
    frozen,
    start_record: dict[str, Any],
    train_nmse: float | None = None,
    n_train: int | None = None,
    rate: float | None = None,
    idle=(),
) -> list[str]:
    """What about a fit should not be taken at face value (see `FitResult.warnings`).

    **Arguments:**

    - `start`: the model the kept start began from.
    - `fitted`: the fitted model.
    - `frozen`: names kept fixed (never warned about as unmoved).
    - `start_record`: the kept start's entry of `FitResult.starts`.
    - `train_nmse`: the fit's NMSE on the training part (MSE / variance), if known.
    - `n_train`: the training samples, if known: a physics fit with fewer than
      `SAMPLES_PER_PARAMETER` per fitted parameter is warned about (a Hybrid's
      network is held by weight decay and validation instead).
    - `rate`: the recordings' (least) sampling rate, Hz, if known: a fitted
      frequency at or above its Nyquist frequency is warned about ([`aliased`][]).
    - `idle`: names the prediction does not depend on, said so elsewhere
      (`hybrid.core._fit.unpinned_warnings`): not warned about as unmoved.
    """
    warnings = []
    units = fitted.units
    before = {k: float(v) for k, v in start.simulation.parameters().items()}
    after = {k: float(v) for k, v in fitted.simulation.parameters().items()}
    free = [k for k in after if k not in frozen]
    no_step = start_record.get("accepted_steps", start_record.get("steps")) == 0
    if no_step and free:
        warnings.append(
            "the fit made no accepted step: every parameter is still at its start value (the "
            "data may not constrain the model, or the fit failed: check the recording's columns "
            "and units, or try other starts)"
        )
    # Steps were accepted (the training cost fell) but the validation loss was least at the start:
    # the kept iterate is the start (`best_theta`), and every parameter "did not move".
    kept_start = not no_step and start_record.get("best_step") == 0
    if kept_start and free:
        warnings.append(
            f"the fit kept its start: its {start_record.get('accepted_steps')} accepted steps lowered the "
            "training cost but never the loss on the validation part, so the simulation's parameters are at "
            "their start values (early stopping; the readout's gain and offset are set afresh). Where the "
            "start is a fit of this record already (--start-from), that is expected; else the validation "
            "part behaves otherwise than the training part: a drift, or an effect the model lacks (hybrid "
            "diagnose names it), or conditions only one part holds (move the parts: --split, or "
            "fit(..., blocks=3))"
        )
    for name in [n for n in free if n not in idle]:
        value, initial = after[name], before[name]
        unit = unit_suffix(units.get(name))
        if not no_step and not kept_start and abs(value - initial) <= UNMOVED_RTOL * abs(initial):
            warnings.append(
                f"{name} = {value:.6g}{unit} did not move from its start value: the data may not "
                "constrain it, or the fit failed"
            )
    n_fitted = len(free) + len([k for k in fitted.readout.parameters() if k not in frozen])
    if n_train is not None and fitted.kind == "physics" and n_train < SAMPLES_PER_PARAMETER * n_fitted:
        warnings.append(
            f"only {n_train} training samples for {n_fitted} fitted parameters: the fit can follow the "
            f"noise and its test score says little; record longer (at least {SAMPLES_PER_PARAMETER} "
            f"training samples per parameter: {SAMPLES_PER_PARAMETER * n_fitted} here)"
        )
    if train_nmse is not None and train_nmse >= POOR_TRAIN_NMSE and fitted.simulation.typical_ranges():
        warnings.append(
            f"the fit leaves {100 * min(train_nmse, 9.99):.0f} % of the training part's variance: LM may have "
            "stopped on a plateau far from the system's values; start from points screened over the "
            "physics' typical ranges (hybrid fit --screen 512 --starts 4; fit(..., screen=512, starts=4))"
        )
    warnings += implausible(fitted, frozen)
    warnings += aliased(fitted, frozen, rate) + sub_sample(fitted, frozen, rate)
    warnings += narrowed(user_methods(fitted.simulation), rate)
    if not jax.config.read("jax_enable_x64"):
        warnings.append(
            "fitted in float32, as jax's float64 is off: sums over the record (and the RC network's product "
            "of 46 sections) round at 1e-7 of their size, which moves the parameters the data pin weakly; "
            + FLOAT64_FIX
        )
    return warnings


#: A recording's drive that peaks this many times above (or below) the largest |level| of its
#: simulation's `drive_range` is warned about: 20 keeps a drive a few times the written-for levels
#: quiet and catches a unit's step of 1000 (mV read as V) or a DAC's counts (0–4095 for 0–5 V).
DRIVE_RANGE_FACTOR = 20.0


def drive_outside_range(simulation, drives, drive_unit: str = "") -> list[str]:
    """One sentence where the drives' largest |level| lies `DRIVE_RANGE_FACTOR`× outside `simulation.drive_range`.

    `drives`: the recordings' drives, in the unit `drive_unit` labels (a file
    without units: the simulation's own). Nothing where the simulation states no
    range, or the drives are all zero.
    """
    span = simulation.drive_range
    peak = max((float(np.max(np.abs(np.asarray(d, float)))) for d in drives if len(d)), default=0.0)
    if span is None or not (math.isfinite(peak) and peak > 0):
        return []
    top = max(abs(float(span[0])), abs(float(span[1])))
    if top <= 0 or 1.0 / DRIVE_RANGE_FACTOR <= peak / top <= DRIVE_RANGE_FACTOR:
        return []
    ratio, unit = peak / top, unit_suffix(drive_unit)
    own = simulation
    while isinstance(getattr(own, "inner", None), AbstractSimulation):  # a wrapper's range is its inner's
        own = own.inner
    size = f"{ratio:.3g}× the largest" if ratio > 1 else f"1/{1 / ratio:.3g} of the largest"
    said = (
        f"the drive reaches {peak:.4g}{unit}, {size} level {type(own).__name__} is written for "
        f"({span[0]:g} to {span[1]:g} in its own drive unit, its drive_range): its numbers (defaults, frozen "
        "values, typical ranges) hold for drives like those"
    )
    power = round(math.log10(ratio) / 3) * 3
    if power and abs(math.log10(ratio) - power) < 0.5:
        said += f"; {ratio:.3g} is near 10^{power}, the step between units ({_prefix_pair(drive_unit)})"
    return [
        said + ": check the drive's unit, then rescale the drive to the simulation's or restate the "
        "simulation's numbers in the drive's unit (docs/plugins.md)"
    ]


def _prefix_pair(unit: str) -> str:
    """A unit and its base a factor 1000 apart, in the drive's own unit: "mW and W", "mV and V" without one.

    A probe's drive in mW was told "the step between units (mV and V)".
    """
    unit = (unit or "").strip()
    if len(unit) > 1 and unit[0] in "mµuknMG" and unit[1:].isalpha():
        return f"{unit} and {unit[1:]}"
    if unit.isalpha():
        return f"m{unit} and {unit}"
    return "mV and V"


#: The share of a drive's power (mean removed) within `LINE_BINS` bins of its strongest frequency from which
#: the drive is one sinusoid (`one_frequency_drive`): a sine's Hann-windowed lobe holds all of it, a square
#: wave's fundamental 81 % (8/π²), a PRBS's or a chirp's strongest few bins a small share. A second tone of
#: 0.15 of the first's amplitude (2 % of the power) pins a second-order plant (a probe's fit: f and ζ within
#: 1 %), so 95 % was too low; and one of 0.1 (1 % of the power) made a study's bounds on an `lti:2`'s gain
#: and ζ 7× and 3× tighter than a pure sine's (the verification probe of 2026-12-06), so 99 % was too.
ONE_LINE_SHARE = 0.995
LINE_BINS = 3


def one_frequency_drive(drives, *, bounds: bool = False) -> list[str]:
    """One sentence where every drive is one sinusoid, at one frequency, else none.

    `drives`: (u, rate in Hz) of each recording. `bounds`: the sentence is about standard errors
    computed before any fit (`hybrid.sensitivity.simulation_study`'s Cramér–Rao bounds), not a fit's.

    A linear system under a sine shows one gain and one phase: two numbers. A probe's `lti:2` fitted to
    a 0.5 Hz sine read f 1.02 ± 0.0047 Hz, ζ 0.338 ± 0.006 and a gain 9 standard errors from the truth,
    every parameter "pinned", and nothing said that the drive could not tell them: what pinned them was
    the record's start and the model's form taken as exact.
    """
    found = []
    for drive, rate in drives:
        u = np.asarray(drive, float)
        if u.size < 8 * LINE_BINS or not np.ptp(u) > 0:
            return []
        power = np.abs(np.fft.rfft((u - u.mean()) * np.hanning(u.size))) ** 2
        power[0] = 0.0  # what the window leaves of the mean
        k = int(np.argmax(power))
        share = float(np.sum(power[max(k - LINE_BINS, 0) : k + LINE_BINS + 1]) / np.sum(power))
        if not share >= ONE_LINE_SHARE:
            return []
        found.append((_peak_bin(power, k) * rate / u.size, share, rate / u.size))
    if not found or max(f for f, _, _ in found) - min(f for f, _, _ in found) > LINE_BINS * max(
        b for *_, b in found
    ):
        return []
    frequency, share = found[0][0], min(s for _, s, _ in found)
    return [
        f"the drive is one sinusoid ({frequency:.3g} Hz holds {share:.1%} of its power"
        + (" in every recording" if len(found) > 1 else "")
        + "): a linear system shows one gain and one phase under it, so "
        + (
            "the standard errors of parameters beyond those rest on the simulation's start from rest and on "
            "the model's form being exact, not on the drive"
            if bounds
            else "parameters beyond those rest on the record's start and on the model's form being exact, and "
            "so do their standard errors"
        )
        + "; a drive of many frequencies (steps, a PRBS, a chirp) pins them"
    ]


def _peak_bin(power: np.ndarray, k: int) -> float:
    """The strongest bin `k` of a Hann-windowed `power` spectrum refined between bins by a parabola through
    the log powers of it and its neighbours (a 0.7123 Hz sine over 60 s read "0.717 Hz", its bin)."""
    if not 0 < k < power.size - 1 or not np.all(power[k - 1 : k + 2] > 0):
        return float(k)
    a, b, c = np.log(power[k - 1 : k + 2])
    bend = a - 2 * b + c
    return float(k + 0.5 * (a - c) / bend) if bend < 0 else float(k)


def aliased(
    fitted: Model,
    frozen,
    rate: float | None,
    advice: str = "read it as that, or fit again from a start below the Nyquist frequency",
) -> list[str]:
    """One sentence per fitted frequency (unit Hz) of `fitted`'s simulation at or above the Nyquist frequency.

    Sampled at `rate`, a frequency f is seen near its alias |f − k·rate| (the k
    that puts it below rate/2; a damped mode's equivalent keeps its decay per
    sample, so its natural frequency and damping differ somewhat): a fit can land on
    either (`lti:2` with a sensor's lag: a 1.2 Hz, ζ 0.4 plant fitted as
    28.9 Hz, ζ 0.017 at 30 Hz, the same discrete poles). The value is then not
    the system's frequency. `frozen` names and a missing `rate` give nothing. `advice` ends each
    sentence (a sensitivity study, which fits nothing, says what to study instead).
    """
    if not rate or not math.isfinite(rate) or rate <= 0:
        return []
    nyquist = 0.5 * rate
    out = []
    for name, value in fitted.simulation.parameters().items():
        f = float(value)
        if fitted.units.get(name) != "Hz" or name in frozen or not (math.isfinite(f) and f >= nyquist):
            continue
        alias = abs(f - round(f / rate) * rate)
        out.append(
            f"{name} = {f:.6g} Hz is at or above the Nyquist frequency ({nyquist:g} Hz of samples at {rate:g} Hz): "
            f"the samples cannot tell it from its alias near {alias:.4g} Hz, which is what the recording shows; "
            + advice
        )
    return out


#: The samples of the float64 signal `narrowed` traces a plug-in's method on (shapes only: nothing runs).
NARROW_PROBE = 64


def _unwrapped(simulation: AbstractSimulation) -> tuple[AbstractSimulation, tuple]:
    """(the simulation inside every wrapper `simulation` is: a `HeldStart`, an effect stack; the effects of
    those wrappers)."""
    effects: tuple = ()
    while isinstance(simulation, AbstractWrapper):
        effects += tuple(getattr(simulation, "effects", ()))
        simulation = simulation.inner
    return simulation, effects


def user_simulation(simulation: AbstractSimulation) -> AbstractSimulation | None:
    """The plug-in `simulation` runs (itself, or inside its wrappers: held at a fitted drive, extended by
    effects), or None where that is the library's own (which computes in its signal's dtype)."""
    inner = _unwrapped(simulation)[0]
    return None if from_library(inner) else inner


def user_methods(simulation: AbstractSimulation, effects=()) -> list[tuple[str, Any]]:
    """(who, f(signal, dt)) for each method of a user's code that `simulation` runs: the plug-in's
    `simulate` and, in state-space form, its `rates` (at a state and a drive read off the signal), and each
    user effect's `apply`, of its wrappers' and of `effects`; for `narrowed`."""
    inner, wrapped = _unwrapped(simulation)
    out: list[tuple[str, Any]] = []
    if not from_library(inner):
        name = type(inner).__name__
        out.append((f"{name}.simulate", inner.simulate))
        if has_states(inner):
            n = len(inner.states)

            def rates(v, dt, inner=inner, n=n):
                state = tuple(v[k % v.shape[0]] for k in range(n))
                return jnp.stack(inner.rates(state, v[0], inner.prepare(inner.parameters())))

            out.append((f"{name}.rates", rates))
    seen = set()
    for effect in (*wrapped, *effects):
        if not from_library(effect) and id(effect) not in seen:
            seen.add(id(effect))
            out.append((f"{type(effect).__name__}.apply", effect.apply))
    return out


def narrowed(parts, rate: float | None) -> list[str]:
    """One sentence per plug-in method that returns fewer bits than the float64 signal it is given.

    `parts`: (who, f) pairs, `who` the method's name for the sentence (``"Motor.simulate"``) and f(signal,
    dt) the method. Read by tracing (`jax.eval_shape`: nothing compiled or run), and only where float64 is
    on (off, `fit_warnings` says it of the whole fit). A probe's plug-ins returned float32 from `simulate`,
    `rates` and an effect's `apply` (a float32 constant, a cast) and nothing was said: the output, and the
    derivatives the fit and the standard errors take through it, keep about 7 significant digits.
    """
    if not jax.config.read("jax_enable_x64") or not rate or not math.isfinite(rate) or rate <= 0:
        return []
    signal = jax.ShapeDtypeStruct((NARROW_PROBE,), np.float64)
    out = []
    for who, method in parts:
        try:
            dtype = np.dtype(jax.eval_shape(lambda v, method=method: method(v, 1.0 / rate), signal).dtype)
        except Exception:  # what a plug-in's method does wrong is said where it runs, not here
            continue
        if np.issubdtype(dtype, np.floating) and dtype.itemsize < 8:
            out.append(
                f"{who} returns {dtype} for a float64 signal: its output, and the derivatives the fit and the "
                "standard errors take through it, keep about 7 significant digits, so what the data pin "
                "weakly rounds away; compute in the signal's own dtype (no float32 casts or arrays: "
                "jnp.asarray(x, v.dtype))"
            )
    return out


#: A fitted time (unit s) below this share of the sample step is read as within one sample (`sub_sample`).
SUB_SAMPLE_SHARE = 0.1


def sub_sample(fitted: Model, frozen, rate: float | None) -> list[str]:
    """One sentence per fitted time (unit s) of `fitted`'s simulation under `SUB_SAMPLE_SHARE` of a sample step.

    What such a time sets (a lag's time constant, a delay) is over within one
    sample: the samples cannot pin it, and any value well below the step fits
    alike (`lti:1` on a camera's 30 Hz record of a fast strip: τ = 2.3 ms, the
    section a gain). `frozen` names and a missing `rate` give nothing.
    """
    if not rate or not math.isfinite(rate) or rate <= 0:
        return []
    step = 1.0 / rate
    out = []
    for name, value in fitted.simulation.parameters().items():
        t = float(value)
        if (
            fitted.units.get(name) != "s"
            or name in frozen
            or not (math.isfinite(t) and 0 < t < SUB_SAMPLE_SHARE * step)
        ):
            continue
        out.append(
            f"{name} = {t:.3g} s is under a tenth of the sample step ({step:.3g} s at {rate:g} Hz): what it times is "
            "over within one sample, so the samples cannot pin it and any value well below the step fits alike; "
            "read it as faster than the samples (record faster to measure it)"
        )
    return out


def implausible(fitted: Model, frozen, why: str = "") -> list[str]:
    """One sentence per fitted parameter of `fitted`'s simulation outside its plausible range.

    `AbstractSimulation.plausible`; `frozen` names are left out. `why`: what
    else may have put it there, after the checks every fit is told (units,
    columns, identifiability).
    """
    out = []
    plausible = fitted.simulation.plausible
    for name, value in outside_plausible(fitted.simulation, frozen).items():
        (low, high), unit = plausible[name], unit_suffix(fitted.units.get(name))
        out.append(
            f"{name} = {value:.6g}{unit} is outside its plausible range {low:g} to "
            f"{high:g}{unit}: check the recording's units and columns, or the value is not "
            f"identifiable from this data{why}"
        )
    return out


def outside_plausible(simulation, frozen) -> dict[str, float]:
    """The value of each parameter of `simulation` not in `frozen` that lies outside its plausible range."""
    values = {k: float(v) for k, v in simulation.parameters().items()}
    return {
        name: values[name]
        for name, (low, high) in simulation.plausible.items()
        if name in values and name not in frozen and not (low <= values[name] <= high)
    }
