"""The physics-simulation interface: anything that turns a drive into a mediatory signal.

A simulation is an `eqx.Module` with named, constrained parameters (see
`hybrid.core._parameters`) and `simulate(v_in, dt) -> signal`. It also says
what the generic rooms need to know about its physics, so that none of them
names a particular one: each parameter's unit, its plausible range (a fitted
value outside is warned about), its typical range (where `diagnose`'s screened
start design spreads), which parameters a fit keeps fixed by default and why,
and how to rebuild it when a saved model is loaded (`config`/`from_config`).
The fitter, the models, `diagnose` and the CLI only use this interface, so the
paper's RC network is one implementation among others (an effect stack that
wraps a simulation is itself one).
"""

from __future__ import annotations

import abc
import dataclasses
import re
import warnings
from typing import ClassVar, Self

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ..util._errors import InputError
from ._arguments import check_drive
from ._parameters import Constraint, decode, encode


class AbstractSimulation(eqx.Module):
    """A physics simulation with named, constrained parameters.

    Subclasses hold the unconstrained values in `raw` and state the facts below.
    Each fact is read in one way, as the attribute of an instance
    (`simulation.units`, `simulation.frozen_by_default`, …). A subclass states it
    as a class-level constant (``units: ClassVar[dict] = {...}``), or, where it
    depends on a field (as `LTI`'s parameters depend on its order, or a wrapper's
    on what it wraps), as a property computed from its fields.
    """

    raw: eqx.AbstractVar[dict[str, Array]]

    # --- the facts the generic rooms read (required: constraints, units) ------------------
    @property
    def constraints(self) -> dict[str, Constraint]:
        """Constraint of each parameter, by name (e.g. `Positive`: optimised in log). Required."""
        raise InputError(
            f"{type(self).__name__} states no constraints: give it a class-level dict constraints "
            "(name -> Positive(), Real(), UnitInterval(), ...) for each parameter (see docs/plugins.md)"
        )

    @property
    def units(self) -> dict[str, str]:
        """Unit of each parameter, by name ("1" for dimensionless). Required."""
        raise InputError(
            f"{type(self).__name__} states no units: give it a class-level dict units "
            '(name -> "s", "cm^2", "1", ...) for each parameter (see docs/plugins.md)'
        )

    @property
    def plausible(self) -> dict[str, tuple[float, float]]:
        """Physically plausible range (low, high) of a parameter, in its unit (default: none).

        A fitted value outside it is warned about (`FitResult.warnings`), not refused.
        """
        return {}

    @property
    def typical(self) -> dict[str, tuple[float, float]]:
        """Where most real systems lie (low, high), per parameter, in its unit (default: none).

        diagnose's screened start design spreads over these ranges, in this order
        (log-spaced for a `Positive` parameter); `typical_ranges()` completes them
        from `plausible`.
        """
        return {}

    @property
    def frozen_by_default(self) -> dict[str, str]:
        """Parameters that `fit` (from the CLI) and `diagnose` keep fixed unless freed, with the reason.

        E.g. one of two parameters that enter only as a ratio (default: none).
        """
        return {}

    @property
    def drive_range(self) -> tuple[float, float] | None:
        """The drive levels (low, high) the simulation's numbers are written for, in that drive unit (default: none).

        Its defaults, frozen values, `typical` and `plausible` ranges hold for
        drives like these: a pump's 0–10 V. `fit` and `diagnose` warn where a
        recording's drive peaks `DRIVE_RANGE_FACTOR` times above its largest
        |level| or as far below it (a drive in mV, or in DAC counts, read as
        volts), not refused: say it only where a drive far outside is an error.
        """
        return None

    @property
    def linear_in_drive(self) -> bool:
        """True when the output is linear in the drive (zero initial state) (default False).

        A drive in mV then gives the same parameters as one in V: `fit` scales v_in.
        """
        return False

    @property
    def output_unit(self) -> str:
        """The unit of the mediatory signal `simulate` returns ("{drive}" for the RC network's V_o).

        ``"{drive}"`` stands for the drive's unit (a voltage divider's output is
        in the volts or millivolts it is driven with; see `unit_in`); "" (the
        default) where the simulation does not say.
        """
        return ""

    def units_in(self, drive_unit: str) -> dict[str, str]:
        """`units` with the drive in `drive_unit` (``"{drive}"`` keeps the placeholder: `drive_power`).

        A wrapper that fills ``{drive}`` in itself (`EffectStack`) overrides this.
        """
        return {name: unit_in(unit, drive_unit) for name, unit in self.units.items()}

    @abc.abstractmethod
    def simulate(self, v_in: Float[Array, " time"], dt: float) -> Float[Array, " time"]:
        """Mediatory signal for the drive `v_in` (V) sampled every `dt` seconds."""

    def parameters(self) -> dict[str, Array]:
        """Physical values of the parameters, by name (units in `units`)."""
        return decode(self.raw, self.constraints)

    def replace(self, **values) -> Self:
        """A copy with some parameters set to new physical values."""
        current = dict(self.parameters())
        unknown = set(values) - set(current)
        if unknown:
            raise InputError(
                f"{type(self).__name__} has no parameter(s) {sorted(unknown)}: "
                f"its parameters are {sorted(current)}"
            )
        current.update(values)
        raw = encode(current, self.constraints, type(self).__name__)
        return eqx.tree_at(lambda s: s.raw, self, raw)

    def with_raw(self, raw: dict[str, Array]) -> AbstractSimulation:
        """A copy with some unconstrained values replaced (traceable: no decoding, no checks).

        What a compiled screen uses to rebuild the simulation at each row of a
        design; a wrapper routes each value to the part that holds it.
        """
        return eqx.tree_at(lambda s: s.raw, self, {**self.raw, **raw})

    def parameter_names(self) -> tuple[str, ...]:
        """Names of the parameters (what `frozen` and `replace` accept)."""
        return tuple(self.raw)

    def typical_ranges(self) -> dict[str, tuple[float, float]]:
        """Typical (low, high) of each parameter: `typical`, then `plausible` for the rest.

        What a start design spreads over (`typical` alone may name only some parameters).
        """
        own = dict(self.typical)
        return {**own, **{k: v for k, v in self.plausible.items() if k not in own}}

    # --- the getters of release 0.x: each re-reads one fact; kept for one release ----------
    def parameter_units(self) -> dict[str, str]:
        """Deprecated: read `units`."""
        _deprecated("parameter_units()", "units")
        return dict(self.units)

    def parameter_constraints(self) -> dict[str, Constraint]:
        """Deprecated: read `constraints`."""
        _deprecated("parameter_constraints()", "constraints")
        return dict(self.constraints)

    def plausible_ranges(self) -> dict[str, tuple[float, float]]:
        """Deprecated: read `plausible`."""
        _deprecated("plausible_ranges()", "plausible")
        return dict(self.plausible)

    def default_frozen(self) -> dict[str, str]:
        """Deprecated: read `frozen_by_default`."""
        _deprecated("default_frozen()", "frozen_by_default")
        return dict(self.frozen_by_default)

    def config(self) -> dict:
        """The JSON-able settings that rebuild this simulation's skeleton (`from_config`).

        The default serves a simulation whose only field is `raw`; one with more
        fields (a strip, a number of stages) overrides this and `from_config`.
        """
        extra = [f.name for f in dataclasses.fields(self) if f.name != "raw"]
        if extra:
            raise InputError(
                f"{type(self).__name__} cannot be saved: it has fields {extra} besides raw; define "
                "config() (its settings as a JSON-able dict) and the classmethod from_config(config)"
            )
        return {}

    @classmethod
    def from_config(cls, config: dict) -> AbstractSimulation:
        """A simulation with default parameter values built from `config()`'s settings."""
        return cls(**config)

    def perturbed(self, key, scale: float, frozen=frozenset()) -> AbstractSimulation:
        """A copy whose free raw (unconstrained) values get N(0, scale²) noise: a new start."""
        return eqx.tree_at(lambda s: s.raw, self, perturb_raw(self.raw, key, scale, frozen))

    def free_parameter_order(self, frozen=frozenset()) -> list[str]:
        """The free parameters' names in the order their values take in a flattened θ.

        `Problem` ravels `eqx.filter(simulation, simulation.trainable(frozen))`:
        this tags every raw value with its index (`with_raw`) and reads the tags
        back in that order, so a wrapper's layout (inner first or last, sorted
        keys or not) is never assumed.
        """
        names = list(self.parameter_names())
        tagged = self.with_raw({n: jnp.asarray(float(i)) for i, n in enumerate(names)})
        leaves = jax.tree_util.tree_leaves(eqx.filter(tagged, tagged.trainable(frozenset(frozen))))
        return [names[int(leaf)] for leaf in leaves]

    def trainable(self, frozen: frozenset[str]) -> AbstractSimulation:
        """Filter spec (same structure, bools) marking the free parameters."""
        spec = {name: name not in frozen for name in self.raw}
        return eqx.tree_at(
            lambda s: s.raw,
            _all(self, False),
            spec,
        )


#: The placeholder a unit uses for the drive's unit (`AbstractSimulation.output_unit`, effects' `units`).
DRIVE = "{drive}"


def as_factor(unit: str) -> str:
    """`unit` as one factor of a larger unit: in parentheses where it is compound (``rad/s`` → ``(rad/s)``).

    So that a gain of rad/s per V reads ``(rad/s)/V``, not ``rad/s/V``; a unit
    already in parentheses (``(unit of S)``) or a single symbol stays as it is.
    """
    bracketed = unit.startswith("(") and unit.endswith(")")
    return f"({unit})" if not bracketed and any(c in unit for c in "/·* ") else unit


def substitute_unit(template: str, placeholder: str, unit: str) -> str:
    """`template` with `placeholder` replaced by `unit`, as a factor (`as_factor`) unless it stands alone.

    A placeholder the template already brackets takes the unit as it comes: ``{drive}/({signal})^2`` reads
    ``V/(rad/s)^2``, not ``V/((rad/s))^2`` (a probe's effect plug-in).
    """
    if template == placeholder:
        return unit
    return template.replace(f"({placeholder})", as_factor(unit)).replace(placeholder, as_factor(unit))


def unit_in(unit: str, drive_unit: str = "V") -> str:
    """`unit` (an `output_unit`, a state's unit) with ``"{drive}"`` replaced by `drive_unit`, then `cancelled`."""
    return cancelled(substitute_unit(unit, DRIVE, drive_unit))


_UNIT_TOKENS = re.compile(r"\(|\)|/|\^-?\d+(?:\.\d+)?|[·*\s]+|[^()/^·*\s]+")
_UNIT_PRODUCT = re.compile(r"[·*\s]+")


def drive_power(unit: str) -> float | None:
    """The power of the drive's unit (``"{drive}"``) in `unit`; None where `unit` does not parse.

    ``{drive}/s`` → 1, ``1/{drive}^2`` → −2, ``mm/({drive}/s)`` → −1, ``Hz`` → 0.
    Everything after a ``/`` in a group is in its denominator (``a/b·c`` is
    a/(b·c)). What a change of the drive's unit (mV for V) multiplies a value
    in `unit` by: 1000 to that power (`Problem`'s θ units).
    """
    tokens = _UNIT_TOKENS.findall(unit)
    if "".join(tokens) != unit:
        return None

    def group(i: int) -> tuple[float, int]:  # (power, index after the group)
        total, sign, expect_factor = 0.0, 1.0, True
        while i < len(tokens) and tokens[i] != ")":
            token = tokens[i]
            if token == "/":
                if expect_factor:
                    raise ValueError(unit)
                sign, expect_factor = -1.0, True
                i += 1
                continue
            if _UNIT_PRODUCT.fullmatch(token):
                i += 1
                continue
            if token.startswith("^"):
                raise ValueError(unit)
            if token == "(":
                power, i = group(i + 1)
                if i >= len(tokens) or tokens[i] != ")":
                    raise ValueError(unit)
            else:
                power = 1.0 if token == DRIVE else 0.0
            i += 1
            if i < len(tokens) and tokens[i].startswith("^"):
                power *= float(tokens[i][1:])
                i += 1
            total += sign * power
            expect_factor = False
        if sign < 0 and expect_factor:  # a slash with nothing below it
            raise ValueError(unit)
        return total, i

    try:
        power, end = group(0)
    except ValueError:
        return None
    return power if end == len(tokens) else None


def unit_suffix(unit: str | None) -> str:
    """`` unit`` to print after a value, or ``""`` for none and for a dimensionless ``"1"``."""
    return f" {unit}" if unit and unit != "1" else ""


def cancelled(unit: str) -> str:
    """`unit` with a factor over a power of itself cancelled: ``V/V^3`` → ``1/V^2``, ``mm/mm`` → ``1``.

    Only a unit made of one symbol (or one bracketed unit) over a power of the
    same: what an effect's ``{drive}/{signal}^3`` becomes when the drive and its
    signal share a unit (a stiffness fed back on a simulation that outputs volts).
    """
    match = re.fullmatch(r"([^\s/^()]+|\([^()]*\))/\1(?:\^(\d+))?", unit)
    if not match:
        return unit
    power = int(match.group(2) or 1) - 1
    symbol = match.group(1)
    return "1" if power == 0 else f"1/{symbol}" if power == 1 else f"1/{symbol}^{power}"


class AbstractWrapper(AbstractSimulation):
    """A simulation built around another (`inner`): its ranges and default freezes are the inner's.

    `HeldStart` and the discovery room's `EffectStack` are wrappers; each adds
    parameters of its own and says how they are stored.
    """

    inner: eqx.AbstractVar[AbstractSimulation]

    @property
    def plausible(self) -> dict[str, tuple[float, float]]:
        return self.inner.plausible

    @property
    def typical(self) -> dict[str, tuple[float, float]]:
        return self.inner.typical

    @property
    def frozen_by_default(self) -> dict[str, str]:
        return self.inner.frozen_by_default

    @property
    def drive_range(self) -> tuple[float, float] | None:
        return self.inner.drive_range

    @property
    def output_unit(self) -> str:
        return self.inner.output_unit

    def units_in(self, drive_unit: str) -> dict[str, str]:
        inner = self.inner.units_in(drive_unit)
        own = {name: unit_in(unit, drive_unit) for name, unit in self.units.items() if name not in inner}
        return {**inner, **own}


class Passthrough(AbstractSimulation):
    """No physics: the mediatory signal is the drive itself (the paper's Normal model)."""

    raw: dict[str, Array]
    constraints: ClassVar[dict[str, Constraint]] = {}
    units: ClassVar[dict[str, str]] = {}
    linear_in_drive: ClassVar[bool] = True

    def __init__(self):
        self.raw = {}

    def simulate(self, v_in, dt):
        return check_drive(v_in, dt, "Passthrough.simulate")[0]


def from_library(obj) -> bool:
    """Whether `obj`'s class is this package's own, not a user's plug-in (whose warnings tell its author
    what to fix: the library's own effects and simulations escape only where the search steps around)."""
    return type(obj).__module__.split(".")[0] == "hybrid"


def _deprecated(old: str, new: str) -> None:
    warnings.warn(
        f"AbstractSimulation.{old} is deprecated and goes in the next release: read the attribute "
        f"simulation.{new} instead",
        DeprecationWarning,
        stacklevel=3,
    )


def perturb_raw(raw: dict, key, scale: float, frozen=frozenset()) -> dict:
    """`raw` with N(0, scale²) noise added to every value not named in `frozen`."""
    import jax

    out = dict(raw)
    for j, name in enumerate(sorted(out)):
        if name not in frozen:
            out[name] = out[name] + scale * jax.random.normal(
                jax.random.fold_in(key, j), out[name].shape, out[name].dtype
            )
    return out


def _all(tree, value: bool):
    import jax

    return jax.tree_util.tree_map(lambda _: value, tree)
