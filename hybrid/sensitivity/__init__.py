"""Gradient-based sensitivity, identifiability and parameter uncertainty.

Everything here works on the interfaces, not on the RC network by name: a
target is an [`AbstractSimulation`][] (output: its mediatory signal, V_o for
the RC network of Eqs 4–14) or a [`Model`][] (output: the prediction ŵ, in w's unit).
Its named parameters are whatever `target.parameters()` returns; derivatives
are taken with respect to the unconstrained values the fitter moves and mapped
to physical units by the chain rule (the delta method), so any reparameterisation
([`hybrid.Positive`][], [`hybrid.UnitInterval`][], …) is handled.

- [`local_sensitivities`][]: ∂y(t)/∂θ_j by forward mode (`jax.jacfwd`)
  through the simulation's scan; `normalised()` gives s_j ∂y/∂θ_j / rms(y), with
  s_j = |θ_j| or, for a parameter at 0, a typical magnitude ([`parameter_scales`][]).
- [`identifiability`][]: the SVD of the normalised sensitivity matrix. Its
  (near-)zero singular values name the parameter combinations the output
  cannot fix; the cosine between two columns flags near-collinear pairs.
- [`parameter_covariance`][] / [`standard_errors`][]: after a fit, the Fisher
  information, the covariance and the standard errors of the named parameters
  in physical units (network weights, if any, are nuisance parameters and are
  marginalised out), as `scipy.optimize.curve_fit` computes them.
- [`frequency_sensitivity`][]: ∂ log|H(j2πf)|/∂ log θ and ∂∠H/∂ log θ for
  simulations with a `frequency_response` (Eq 14).
- [`sobol_indices`][]: variance-based (Sobol) first-order and total indices of
  the whole output series, by `vmap`-ed sampling.

Float64 is needed for meaningful small singular values: call
``jax.config.update("jax_enable_x64", True)`` in your entry point.
"""

from __future__ import annotations

from ._covariance import Covariance, parameter_covariance, problem_covariance, standard_errors
from ._identifiability import Identifiability, identifiability
from ._local import Sensitivity, frequency_sensitivity, local_sensitivities, parameter_scales
from ._sobol import SobolIndices, sobol_indices

__all__ = [
    "Covariance",
    "Identifiability",
    "Sensitivity",
    "SobolIndices",
    "frequency_sensitivity",
    "identifiability",
    "local_sensitivities",
    "parameter_covariance",
    "parameter_scales",
    "problem_covariance",
    "sobol_indices",
    "standard_errors",
]
