"""What `diagnose` reports about the fit it names: the model, its standard errors, its residual statistics.

`fitted_model` (the fitted simulation with only the named effect),
`parameter_uncertainties` (standard errors in physical units, inflated for the
residual's autocorrelation) and `heldout_evidence` (held-out residual statistics of
the baseline and the extended model).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import jax.numpy as jnp
import numpy as np

from ..core._models import Model
from ..core._parameters import at_bound_said
from ..core._problem import Problem
from ..core._simulation import unit_suffix
from . import residual_tests as rt
from ._diagnosis import ParameterUncertainty
from ._effect_stack import EffectStack
from ._effects import FrameTiming


def fitted_model(problem: Problem, theta, causes) -> Model:
    """The fitted simulation with only the named effects (a name, a tuple, or none), frame timing, gain and offset."""
    causes = {causes} if isinstance(causes, str) else set(causes)
    model = problem.model(jnp.asarray(theta))
    stack = model.simulation
    assert isinstance(stack, EffectStack)  # a search fits an EffectStack
    effects = tuple(e for e in stack.effects if e.name in causes or e.name == FrameTiming.name)
    simulation = EffectStack(stack.inner, effects, drive_unit=stack.drive_unit)
    return Model(simulation, model.readout, "physics")


def parameter_uncertainties(
    problem: Problem, theta, residual_heldout, keep=None, units: dict[str, str] | None = None
) -> dict[str, ParameterUncertainty]:
    """Standard errors, in physical units, of `model`'s free parameters (those in `keep`, if given).

    `problem`: `diagnose` passes one of the fitted model's own structure (its
    causes alone, on the search's padded series): the same errors as on the
    search's problem with the other effects switched off (their Jacobian
    columns are zero), from a program that traces only the causes.

    ``std_error``: the Gauss–Newton covariance of
    [`hybrid.sensitivity.parameter_covariance`][] on the training part, inflated
    by the held-out residual's autocorrelation (`effective_sample_factor`:
    correlated residuals carry less information). The RC network's parameters
    are nearly collinear (ξρ, C_clamp and the α's trade off), and an effect
    whose parameter trades off with them inherits that spread.
    ``std_error_given_network`` (effect, frame timing, gain and offset only) is
    the standard error with the network's parameters held at their fitted
    values, from the Fisher information of the other parameters alone: how well
    the data fix the effect once the network is fixed — a lower bound on the
    marginal error. ``to_optimum``: the training part's optimum less the value,
    from Gauss–Newton steps (`hybrid.sensitivity.Covariance.to_optimum`).
    """
    from ..sensitivity import problem_covariance

    covariance = problem_covariance(problem, jnp.asarray(theta), units=units)
    model = problem.model(jnp.asarray(theta))
    inflation = rt.effective_sample_factor(residual_heldout)
    keep = set(covariance.names) if keep is None else set(keep)
    out = {
        name: ParameterUncertainty(
            std_error=std * math.sqrt(inflation),
            unit=covariance.units[name],
            inflation=inflation,
            to_optimum=covariance.to_optimum.get(name),
            diverged=covariance.diverged,
        )
        for name, std in covariance.std_errors.items()
        if name in keep
    }
    stack = model.simulation
    assert isinstance(stack, EffectStack)  # a search fits an EffectStack
    network = set(stack.inner.parameter_names())
    rest = [i for i, name in enumerate(covariance.names) if name not in network and name in keep]
    if rest:
        variance = inverse_diagonal(covariance.fisher[np.ix_(rest, rest)])
        for i, v in zip(rest, variance):
            se = math.sqrt(v * inflation) if np.isfinite(v) and v > 0 else float("inf")
            name = covariance.names[i]
            out[name] = dataclasses.replace(out[name], std_error_given_network=se)
    return out


def inverse_diagonal(fisher: np.ndarray) -> np.ndarray:
    """The diagonal of a Fisher matrix's pseudo-inverse, taken at unit scale (0 where a row is all 0).

    Parameters in mV beside others in m set the raw matrix's entries 1e6 or more apart, where pinv's
    rcond, relative to the largest singular value, cut a direction that the data pin: a probe's dead
    zone read ± 5.4e-13 mV with its simulation fixed, for ± 2.9 mV.
    """
    diagonal = np.sqrt(np.abs(np.diag(fisher)))
    scale = np.where(diagonal > 0, 1.0 / np.where(diagonal > 0, diagonal, 1.0), 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse = np.linalg.pinv(scale[:, None] * fisher * scale[None, :], rcond=1e-12, hermitian=True)
    return np.diag(inverse) * scale**2


#: What a model whose derivative diverged (`Covariance.diverged`) has: the reason its parameters are not
#: pinned (`not_pinned`) and the start of diagnose's warning (`diverged_warnings`).
DIVERGED_CAUSE = (
    "the model's derivative diverges at the fitted values while its output stays finite: its linearised "
    "step is unstable there (an integration step too long for the fastest dynamics the fit reached, a "
    "friction's sticking or a fast pole)"
)
DIVERGED = DIVERGED_CAUSE + ", so no error can be read"


def diverged_warnings(uncertainties: dict[str, ParameterUncertainty]) -> list[str]:
    """The warning a final model whose derivative diverged gets, or none.

    A probe's mass with a Coulomb friction in its own RK4 plug-in: a stick speed of 0.009 V/s made the
    friction's linearised stiffness too fast for the step, the sensitivities grew to 1e35 while the
    output stayed finite, and every parameter read "the output does not change with it".
    """
    if not any(u.diverged for u in uncertainties.values()):
        return []
    return [
        f"{DIVERGED_CAUSE}: the fit's steps, which follow that derivative, and every standard error are "
        "suspect; give the simulation a shorter step (more substeps) or bound the parameter that makes it stiff"
    ]


def not_pinned(uncertainties: dict[str, ParameterUncertainty], model: Model, series) -> dict[str, str]:
    """Why each parameter that the recording does not pin is not pinned, by name.

    A parameter is not pinned when its standard error is infinite (or not a
    number) or larger than its value. The reason is its effect's own where the
    effect knows it (`AbstractEffect.unpinned_reason`, from the signal entering
    it on the first recording: e.g. a branch for negative values that the
    signal never visits), else what the numbers say.
    """
    values = {k: float(v) for k, v in model.parameters().items()}
    stack = model.simulation
    assert isinstance(stack, EffectStack)  # a search fits an EffectStack
    owner = {p: e for e in stack.effects for p in e.constraints}
    constraints, units = stack.constraints, stack.units  # each built afresh when read
    signals: dict | None = None
    out = {}
    for name, u in uncertainties.items():
        se, value = u.std_error, abs(values.get(name, float("nan")))
        if math.isfinite(se) and se <= value:
            continue
        reason = (
            DIVERGED
            if u.diverged
            else _at_bound(name, values.get(name, float("nan")), constraints.get(name), units)
        )
        effect = owner.get(name)
        if reason is None and effect is not None:
            if signals is None:
                first = series[0]
                signals = stack.signals_into(first.v_in, first.dt, n=first.n_recorded)
            reason = effect.unpinned_reason(name, signals[effect.name])
        if reason is None:
            reason = (
                f"its standard error ({se:.2g}) is larger than its value"
                if math.isfinite(se)
                else "the output does not change with it, or it trades off exactly with other parameters"
            )
        out[name] = reason
    return out


def _at_bound(name: str, value: float, constraint, units: dict) -> str | None:
    """Why a value that sits at a bound of its two-sided range is not pinned (the bound sets it), or None."""
    said = at_bound_said(value, constraint, unit_suffix(units.get(name)))
    return None if said is None else f"it {said}"


def heldout_evidence(
    v, w, w_hat_base, w_hat_ext, rate, max_lag: int = 50, segments=None, recordings=None
) -> dict:
    """Residual statistics of the baseline and the extended model on held-out data.

    `segments`: the held-out block of each sample (`residual_tests.drive_independence`
    never filters across a block's edge); None: one block. `recordings`: the
    recording of each sample (the test takes the signals' sizes per recording);
    None: one.
    """
    out: dict[str, Any] = {
        "n_heldout": int(len(w)),
        "rate_hz": float(rate),
        "bound_99": rt.confidence_bound(len(w)),
    }
    for key, w_hat in (("baseline", w_hat_base), ("extended", w_hat_ext)):
        e = w - w_hat
        lags, ccf = rt.cross_correlation(e, v, max_lag)
        acf = rt.autocorrelation(e, max_lag)
        out[key] = {
            "ljung_box": rt.ljung_box(e),
            "drive_independence": rt.drive_independence(e, v, segments, recordings=recordings),
            "acf_outside_bound": int(np.sum(np.abs(acf[1:]) > out["bound_99"])),
            "ccf_outside_bound": int(np.sum(np.abs(ccf) > out["bound_99"])),
            "loop_separation": rt.loops(e, v)["separation"],  # in w's unit
            "segment_nmse": rt.segment_errors(w, w_hat).tolist(),
        }
    return out
