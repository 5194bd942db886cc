"""Performance measures of the paper, Eqs 18-20, and two honest variants.

The paper defines (Section IV.B)

* Eq 18-19: ``NMSE(w, w_hat) = MSE(w_n, w_hat_n) = (1/M) sum (w_n - w_hat_n)^2``
* Eq 20: ``Fitting = 100 (1 - ||w_n - w_hat_n|| / ||w_n - mean(w_n)||)`` (%)

where ``w_n`` and ``w_hat_n`` are "calculated by dividing each value of w(t)
and w_hat(t) by the maximum values observed". That sentence is ambiguous; we
read it as each signal divided by *its own* maximum absolute value,
``w_n = w / max|w|`` and ``w_hat_n = w_hat / max|w_hat|`` ([`nmse`][hybrid.nmse],
[`fitting`][hybrid.fitting]). Under that reading NMSE ignores the scale of the prediction:
``w_hat`` and ``10 * w_hat`` score the same. [`nmse_target`][hybrid.nmse_target] divides both
by ``max|w|`` instead, so a wrong gain is penalised, and
[`nmse_variance`][hybrid.nmse_variance] is the system-identification convention
``MSE(w, w_hat) / var(w)``.

All functions take numpy or JAX arrays of equal shape (the mean runs over
every element), follow the input's floating dtype, return 0-d JAX arrays and
can be jitted and differentiated. Shape checks always run; checks on values
(non-finite input, a target that cannot be normalised) run only on concrete
arrays, as under ``jit`` they would need Python control flow on traced values.
There a zero or constant target gives inf or nan.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike
from jaxtyping import Array, Float

from ..util._errors import InputError

__all__ = ["METRICS", "fitting", "metrics", "nmse", "nmse_target", "nmse_variance"]

#: Keys of [`metrics`][hybrid.metrics].
METRICS: tuple[str, ...] = ("nmse", "nmse_target", "nmse_variance", "fitting")


def _pair(w: ArrayLike, w_hat: ArrayLike, xp=jnp) -> tuple[Array, Array]:
    """Both signals as floating arrays of `xp` (JAX's, or numpy's for concrete values), after checks."""
    a, b = xp.asarray(w), xp.asarray(w_hat)
    if a.shape != b.shape:
        raise InputError(
            f"target w has shape {a.shape} but prediction w_hat has shape "
            f"{b.shape}: compare signals of the same length"
        )
    if a.size == 0:
        raise InputError("target w and prediction w_hat are empty: compare non-empty signals")
    dtype = xp.result_type(a, b)
    if not xp.issubdtype(dtype, xp.inexact):
        dtype = xp.result_type(float)
    a, b = a.astype(dtype), b.astype(dtype)
    for label, x in (("target w", a), ("prediction w_hat", b)):
        value = _concrete(x)
        if value is not None and not np.all(np.isfinite(value)):
            bad = np.flatnonzero(~np.isfinite(value.reshape(-1)))
            raise InputError(
                f"{label} has non-finite values at index {', '.join(map(str, bad[:5]))}"
                f"{', ...' if bad.size > 5 else ''} ({bad.size} in all): remove "
                "or interpolate them"
            )
    return a, b


def _concrete(x: Array) -> np.ndarray | None:
    """``x`` as numpy when it has a value now, None when it is traced."""
    if isinstance(x, jax.core.Tracer):
        return None
    return np.asarray(x)


def _require_concrete(ok: bool | None, message: str) -> None:
    if ok is False:
        raise InputError(message)


def _peak(x: Array, xp=jnp) -> Array:
    """``max|x|``, replaced by 1 when x is all zero so that zero stays zero."""
    peak = xp.max(xp.abs(x))
    return xp.where(peak > 0, peak, xp.ones_like(peak))


def _safe_norm(x: Array, xp=jnp) -> Array:
    """Euclidean norm whose gradient is 0, not nan, at x = 0."""
    squares = xp.sum(x**2)
    positive = squares > 0
    return xp.where(positive, xp.sqrt(xp.where(positive, squares, 1.0)), 0.0)


def _nonzero(w: Array) -> bool | None:
    value = _concrete(w)
    return None if value is None else bool(np.any(value != 0))


def _nonconstant(w: Array) -> bool | None:
    value = _concrete(w)
    return None if value is None else bool(np.ptp(value) > 0)


def _normalised(w: Array, w_hat: Array, xp=jnp) -> tuple[Array, Array]:
    """Eq 18's ``w_n, w_hat_n``: each signal over its own ``max|.|``."""
    _require_concrete(
        _nonzero(w),
        "target w is zero everywhere, so it cannot be normalised by its maximum: "
        "check that the displacement channel was recorded",
    )
    return w / _peak(w, xp), w_hat / _peak(w_hat, xp)


def nmse(w: ArrayLike, w_hat: ArrayLike) -> Float[Array, ""]:
    """Normalised mean squared error as written in the paper, Eqs 18-19.

    ``mean((w / max|w| - w_hat / max|w_hat|)**2)``: each signal divided by its
    own peak magnitude (our reading of "dividing each value of w and w_hat by
    the maximum values observed"). Invariant to rescaling ``w_hat``; an
    all-zero ``w_hat`` is left at zero.

    Arguments:
        w: measured tip displacement (any unit, e.g. mm).
        w_hat: predicted tip displacement, same shape.

    Returns:
        The NMSE, dimensionless, 0 for a perfect prediction.
    """
    return _nmse(*_pair(w, w_hat))


def _nmse(w, w_hat, xp=jnp):
    w_n, w_hat_n = _normalised(w, w_hat, xp)
    return xp.mean((w_n - w_hat_n) ** 2)


def nmse_target(w: ArrayLike, w_hat: ArrayLike) -> Float[Array, ""]:
    """NMSE with both signals divided by the target's peak, ``max|w|``.

    ``mean((w - w_hat)**2) / max|w|**2``: unlike [`nmse`][hybrid.nmse], a prediction
    with the right shape but the wrong gain is penalised.

    Arguments:
        w: measured tip displacement.
        w_hat: predicted tip displacement, same shape and unit.

    Returns:
        The NMSE on the target's scale, dimensionless.
    """
    return _nmse_target(*_pair(w, w_hat))


def _nmse_target(w, w_hat, xp=jnp):
    _require_concrete(
        _nonzero(w),
        "target w is zero everywhere, so it cannot scale the error: check that "
        "the displacement channel was recorded",
    )
    scale = _peak(w, xp)
    return xp.mean(((w - w_hat) / scale) ** 2)


def nmse_variance(w: ArrayLike, w_hat: ArrayLike) -> Float[Array, ""]:
    """NMSE as in system identification, ``mean((w - w_hat)**2) / var(w)``.

    1 means no better than predicting the mean of the target.

    Arguments:
        w: measured tip displacement.
        w_hat: predicted tip displacement, same shape and unit.

    Returns:
        The variance-normalised MSE, dimensionless.
    """
    return _nmse_variance(*_pair(w, w_hat))


def _nmse_variance(w, w_hat, xp=jnp):
    _require_concrete(
        _nonconstant(w),
        "target w is constant, so its variance cannot scale the error: evaluate "
        "on a segment where the strip moves",
    )
    return xp.mean((w - w_hat) ** 2) / xp.var(w)


def fitting(w: ArrayLike, w_hat: ArrayLike) -> Float[Array, ""]:
    """Fitting in percent, Eq 20, on the signals normalised as in [`nmse`][hybrid.nmse].

    ``100 (1 - ||w_n - w_hat_n|| / ||w_n - mean(w_n)||)``: 100 for a perfect
    prediction, 0 for one no better than the target's mean, negative when
    worse. The gradient is finite even at a perfect fit.

    Arguments:
        w: measured tip displacement.
        w_hat: predicted tip displacement, same shape.

    Returns:
        The fitting, %.
    """
    return _fitting(*_pair(w, w_hat))


def _fitting(w, w_hat, xp=jnp):
    _require_concrete(
        _nonconstant(w),
        "target w is constant, so the fitting of Eq 20 is undefined: evaluate "
        "on a segment where the strip moves",
    )
    w_n, w_hat_n = _normalised(w, w_hat, xp)
    return 100 * (1 - _safe_norm(w_n - w_hat_n, xp) / _safe_norm(w_n - xp.mean(w_n), xp))


def metrics(w: ArrayLike, w_hat: ArrayLike) -> dict[str, float]:
    """All measures at once, as Python floats (concrete arrays only).

    Arguments:
        w: measured tip displacement.
        w_hat: predicted tip displacement, same shape and unit.

    Returns:
        ``{"nmse", "nmse_target", "nmse_variance", "fitting"}``; see the
        functions of the same names.
    """
    functions = {
        "nmse": _nmse,
        "nmse_target": _nmse_target,
        "nmse_variance": _nmse_variance,
        "fitting": _fitting,
    }
    # The same formulas in numpy: floats of concrete arrays need no compiled program (one per length).
    w, w_hat = (np.asarray(x) for x in _pair(w, w_hat, np))
    return {key: float(functions[key](w, w_hat, np)) for key in METRICS}
