"""Constrained, named physical parameters.

Physical parameters are stored unconstrained ("raw") so that any optimiser can
move them freely, and mapped to their physical range on use:

- `Positive`: value = exp(raw) — resistances ratios, capacitances, rates.
- `UnitInterval`: value = sigmoid(raw) — the attenuation coefficients α ∈ (0, 1).
- `Real`: value = raw — gains and offsets.

A module holding parameters keeps them in a dict ``raw: dict[str, Array]``
(names are the keys, so fitted parameters are labelled by name for free) and a
static dict of constraints with the same keys.
"""

from __future__ import annotations

import abc
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..util._errors import InputError


class Constraint(eqx.Module):
    """Maps an unconstrained raw value to a physical value and back."""

    @abc.abstractmethod
    def to_physical(self, raw):
        """Physical value of an unconstrained raw value."""

    @abc.abstractmethod
    def to_raw(self, value):
        """Unconstrained raw value of a physical value (checks the range)."""

    @abc.abstractmethod
    def describe(self) -> str:
        """The allowed range in words."""

    @abc.abstractmethod
    def contains(self, value) -> bool:
        """Whether a physical value (or every element of an array of them) lies in the range."""

    @property
    def bounds(self) -> tuple[float, float]:
        """The open range (low, high) the physical value lies in (±inf where unbounded)."""
        return (-math.inf, math.inf)


class Positive(Constraint):
    """value = exp(raw) ∈ (0, ∞)."""

    def to_physical(self, raw):
        return jnp.exp(raw)

    def to_raw(self, value):
        return jnp.log(value)

    @property
    def bounds(self) -> tuple[float, float]:
        return (0.0, math.inf)

    def describe(self) -> str:
        return "positive"

    def contains(self, value) -> bool:
        return bool(np.all(np.asarray(value) > 0) and np.all(np.isfinite(value)))


class UnitInterval(Constraint):
    """value = sigmoid(raw) ∈ (0, 1)."""

    def to_physical(self, raw):
        return 1.0 / (1.0 + jnp.exp(-raw))

    def to_raw(self, value):
        return jnp.log(value) - jnp.log1p(-value)

    @property
    def bounds(self) -> tuple[float, float]:
        return (0.0, 1.0)

    def describe(self) -> str:
        return "strictly between 0 and 1"

    def contains(self, value) -> bool:
        v = np.asarray(value)
        return bool(np.all((v > 0) & (v < 1)))


class SignedUnitInterval(Constraint):
    """value = tanh(raw) ∈ (−1, 1)."""

    def to_physical(self, raw):
        return jnp.tanh(raw)

    def to_raw(self, value):
        return jnp.arctanh(value)

    @property
    def bounds(self) -> tuple[float, float]:
        return (-1.0, 1.0)

    def describe(self) -> str:
        return "strictly between −1 and 1"

    def contains(self, value) -> bool:
        v = np.asarray(value)
        return bool(np.all((v > -1) & (v < 1)))


class Real(Constraint):
    """value = raw ∈ ℝ."""

    def to_physical(self, raw):
        return raw

    def to_raw(self, value):
        return jnp.asarray(value)

    def describe(self) -> str:
        return "finite"

    def contains(self, value) -> bool:
        return bool(np.all(np.isfinite(np.asarray(value))))


#: A value within this fraction of its range of a bound of a two-sided range sits at that bound.
AT_BOUND = 1e-3


def bound_reached(value: float, constraint: Constraint | None) -> tuple[str, float] | None:
    """("upper" or "lower", the bound) where `value` sits at a bound of `constraint`'s two-sided range
    (within `AT_BOUND` of its width), else None.

    Only a range bounded on both sides has a scale to be near a bound on: a
    positive capacitance of 1e-4 F is not "at 0". A value there sits where its
    raw value's map is flat (a sigmoid's, a tanh's tail): the data cannot move it.
    """
    if constraint is None or not math.isfinite(value):
        return None
    low, high = constraint.bounds
    width = high - low
    if not math.isfinite(width):
        return None
    for bound, word in ((high, "upper"), (low, "lower")):
        if abs(value - bound) <= AT_BOUND * width:
            return word, bound
    return None


def at_bound_said(value: float, constraint: Constraint | None, unit_suffix: str = "") -> str | None:
    """ "sits at its lower bound (0 samples): the fit pushed it there, so the bound, not the recording, sets
    its value" where `value` sits at a bound of `constraint`'s two-sided range (`bound_reached`), else None.

    `unit_suffix`: the bound's unit as printed after a number (`hybrid.core._simulation.unit_suffix`).
    """
    reached = bound_reached(value, constraint)
    if reached is None:
        return None
    word, bound = reached
    return (
        f"sits at its {word} bound ({bound:g}{unit_suffix}): the fit pushed it there, so the bound, not the "
        "recording, sets its value"
    )


def encode(values: dict, constraints: dict, owner: str) -> dict:
    """Raw (unconstrained) arrays for physical `values`, checking names and ranges."""
    raw = {}
    for name, value in values.items():
        if name not in constraints:
            raise InputError(f"{owner} has no parameter {name!r}: its parameters are {sorted(constraints)}")
        constraint = constraints[name]
        if not isinstance(constraint, Constraint):
            raise InputError(f"{owner}: {constraint_problem({name: constraint})}")
        # A traced value (jax.grad, jax.vmap through `replace` or a constructor) cannot be checked here.
        if not isinstance(value, jax.core.Tracer):
            try:
                if value is None or isinstance(value, (str, bytes)):
                    raise TypeError(value)
                number = np.asarray(value, dtype=float)
            except (TypeError, ValueError):
                raise InputError(
                    f"{owner} parameter {name} must be a number, got {type(value).__name__} {value!r:.60}"
                ) from None
            if np.any(np.isnan(number)):
                raise InputError(f"{owner} parameter {name} must be a number, got {value!r} (NaN)")
            if not constraint.contains(value):
                raise InputError(f"{owner} parameter {name} must be {constraint.describe()}, got {value!r}")
        raw[name] = constraint.to_raw(jnp.asarray(value, dtype=float))
    missing = set(constraints) - set(raw)
    if missing:
        raise InputError(f"{owner} is missing parameter(s) {sorted(missing)}")
    return raw


def constraint_problem(constraints) -> str | None:
    """What is wrong with a class's declared `constraints` (name → `Constraint` instance), or None.

    Checked before a plug-in is built, so that the one line names the slip (the class
    `Positive` for its instance `Positive()`) rather than what it made `encode` raise.
    """
    if isinstance(constraints, property):
        return None  # a property (LTI's) is read from the instance, and checked there
    if not isinstance(constraints, dict):
        return (
            f"constraints is {constraints!r:.40}, not a dict: write constraints: ClassVar[dict] = "
            '{"tau": Positive()}, one entry per parameter'
        )
    for name, constraint in constraints.items():
        if isinstance(constraint, Constraint):
            continue
        if isinstance(constraint, type) and issubclass(constraint, Constraint):
            return (
                f"the constraint for {name} is the class {constraint.__name__}, not one of its instances: "
                f"write {constraint.__name__}() in constraints"
            )
        return (
            f"the constraint for {name} is {constraint!r:.60}, not a constraint: write Positive(), "
            "UnitInterval(), SignedUnitInterval() or Real() (hybrid's Constraint instances)"
        )
    return None


def decode(raw: dict, constraints: dict) -> dict:
    """Physical values of raw parameters (traceable)."""
    return {name: constraints[name].to_physical(value) for name, value in raw.items()}


def parse_assignment(text: str) -> tuple[str, float]:
    """Parse ``NAME=VALUE`` as given on the command line."""
    name, sep, value = text.partition("=")
    if not sep or not name.strip():
        raise InputError(f"parameter {text!r} must be written NAME=VALUE, e.g. xi_rho=12.5")
    try:
        number = float(value)
    except ValueError:
        raise InputError(
            f"parameter {name.strip()} must be a number, got {value!r} (write NAME=VALUE)"
        ) from None
    return name.strip(), number
