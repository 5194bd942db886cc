"""A simulation that starts where a constant drive has left it: `HeldStart`.

A recording of a slow system rarely begins at rest: the tanks of Cascaded Tanks
hold water when the pump's record starts, and an IPMC strip may still carry the
charge of a previous drive. A simulation that starts at rest (or in equilibrium
with the first sample) then spends its first time constants on a transient the
system never had. `HeldStart` gives any simulation one more parameter, the
constant drive ``initial_drive`` (in the drive's unit) that held the system
before the record began: it simulates ``settle_samples`` samples of it, then
the record, and returns the record's part only.

Why a held drive and not the state itself: the state's size and meaning differ
between simulations (two tank levels, 46 RC charges, the modal states of
`LTI`), a held drive is one number with the drive's unit for all of them, and
for a system that was resting at a steady input it is exact. For a record that
begins mid-transient it is a one-parameter approximation of the initial state.

A record scored on its own (a benchmark's validation record, which starts from
another level than the estimation record) needs its own ``initial_drive``:
re-fit that parameter alone on the record's first samples, every other one
fixed, and say how many samples were used (``experiments/measured.py`` does).
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ..util._errors import InputError
from ._parameters import Constraint, Real, encode
from ._simulation import DRIVE, AbstractSimulation, AbstractWrapper

#: The name of the added parameter.
INITIAL_DRIVE = "initial_drive"
OWN_CONSTRAINTS: dict[str, Constraint] = {INITIAL_DRIVE: Real()}
OWN_UNITS = {INITIAL_DRIVE: DRIVE}  # a level of the drive, in its unit


class HeldStart(AbstractWrapper):
    """`inner` run after `settle_samples` samples of the constant drive ``initial_drive``.

    **Arguments:**

    - `inner`: any simulation.
    - `settle_samples`: how many samples of the held drive precede the record:
      several of the slowest time constant (in samples) lets the state settle.
    - `initial_drive`: its starting value, in the drive's unit (default 0).

    The parameters are the inner simulation's plus ``initial_drive``.
    """

    inner: AbstractSimulation
    settle_samples: int = eqx.field(static=True)
    own: dict[str, Array]
    # The held drive is a parameter of the drive's own scale: rescaling the drive (what
    # `fit` does for a simulation linear in it) would silently change its meaning.
    linear_in_drive: ClassVar[bool] = False

    def __init__(self, inner: AbstractSimulation, settle_samples: int, initial_drive: float = 0.0):
        if not isinstance(inner, AbstractSimulation):
            raise InputError(
                f"HeldStart wraps a simulation (an AbstractSimulation), got {type(inner).__name__}"
            )
        if isinstance(settle_samples, bool) or not isinstance(settle_samples, int) or settle_samples < 1:
            raise InputError(
                f"settle_samples must be a positive whole number of samples, got {settle_samples!r}: "
                "take several of the slowest time constant, in samples"
            )
        if INITIAL_DRIVE in inner.parameter_names():
            raise InputError(f"{type(inner).__name__} already has a parameter {INITIAL_DRIVE!r}")
        self.inner = inner
        self.settle_samples = settle_samples
        self.own = encode({INITIAL_DRIVE: initial_drive}, OWN_CONSTRAINTS, "HeldStart")

    @property  # type: ignore[misc]  # equinox: AbstractVar `raw` may be implemented by a property
    def raw(self) -> dict[str, Array]:  # type: ignore[override]  # (mypy sees a plain field)
        return {**self.inner.raw, **self.own}

    def with_raw(self, raw):
        inner = {k: v for k, v in raw.items() if k != INITIAL_DRIVE}
        own = {INITIAL_DRIVE: raw.get(INITIAL_DRIVE, self.own[INITIAL_DRIVE])}
        return eqx.tree_at(
            lambda s: (s.inner, s.own), self, (self.inner.with_raw(inner) if inner else self.inner, own)
        )

    def held_drive(self, v_in):
        """The drive the inner simulation runs on: `settle_samples` of ``initial_drive``, then `v_in`."""
        v_in = jnp.asarray(v_in)
        held = self.parameters()[INITIAL_DRIVE]
        prefix = jnp.full((self.settle_samples,), held, dtype=jnp.result_type(v_in.dtype, held.dtype))
        return jnp.concatenate([prefix, v_in.astype(prefix.dtype)])

    def simulate(self, v_in, dt):
        return self.inner.simulate(self.held_drive(v_in), dt)[self.settle_samples :]

    def parameters(self):
        return {**self.inner.parameters(), INITIAL_DRIVE: self.own[INITIAL_DRIVE]}

    def parameter_names(self):
        return tuple(self.inner.parameter_names()) + (INITIAL_DRIVE,)

    @property
    def constraints(self) -> dict[str, Constraint]:
        return {**self.inner.constraints, **OWN_CONSTRAINTS}

    @property
    def units(self) -> dict[str, str]:
        return {**self.inner.units, **OWN_UNITS}

    def replace(self, **values):
        rest = {k: v for k, v in values.items() if k != INITIAL_DRIVE}
        inner = self.inner.replace(**rest) if rest else self.inner
        own = encode(
            {INITIAL_DRIVE: values.get(INITIAL_DRIVE, self.parameters()[INITIAL_DRIVE])},
            OWN_CONSTRAINTS,
            "HeldStart",
        )
        return eqx.tree_at(lambda s: (s.inner, s.own), self, (inner, own))

    def perturbed(self, key, scale, frozen=frozenset()):
        return eqx.tree_at(lambda s: s.inner, self, self.inner.perturbed(key, scale, frozen))

    def trainable(self, frozen):
        spec = jax.tree_util.tree_map(lambda _: False, self)
        spec = eqx.tree_at(lambda s: s.inner, spec, self.inner.trainable(frozen))
        return eqx.tree_at(lambda s: s.own, spec, {INITIAL_DRIVE: INITIAL_DRIVE not in frozen})

    def config(self) -> dict:
        """The inner simulation's skeleton and `settle_samples` (what `load_model` rebuilds)."""
        from ._serialise import describe_simulation

        return {"inner": describe_simulation(self.inner), "settle_samples": self.settle_samples}

    @classmethod
    def from_config(cls, config: dict) -> HeldStart:
        from ._serialise import build_simulation

        return cls(build_simulation(config["inner"]), int(config["settle_samples"]))


def held_at_start(simulation, settle_samples: int, recording) -> HeldStart:
    """`simulation` held for `settle_samples` samples at `recording`'s first drive level (its first 10 samples' mean)."""
    first = float(np.mean(np.asarray(recording.v_in)[:10]))
    return HeldStart(simulation, settle_samples, initial_drive=first)


def has_held_start(simulation) -> bool:
    """Whether `simulation` starts from a held drive: a `HeldStart`, or a wrapper with one inside."""
    return isinstance(simulation, AbstractSimulation) and INITIAL_DRIVE in simulation.parameter_names()


def refit_initial_drive(model, recording, samples: int, bounds: tuple[float, float] | None = None):
    """(model, value): `model` with ``initial_drive`` re-fitted alone on the first `samples` of `recording`.

    A record scored on its own (a benchmark's validation record) starts from its
    own state, which the fitted ``initial_drive`` of another record does not
    know. Every other parameter stays fixed; a bounded scalar search
    (`scipy.optimize.minimize_scalar`) over `bounds` (in the drive's unit;
    default: the record's drive range) minimises the RMSE of the model's
    free-run prediction over those samples. Say how many were used when
    quoting a score over the whole record.
    """
    import scipy.optimize

    simulation = getattr(model, "simulation", None)
    if not has_held_start(simulation):
        raise InputError(
            "refit_initial_drive needs a model whose simulation is a HeldStart (or wraps one, as "
            "diagnose's extended model of a --settle record does)"
        )
    v, w = np.asarray(recording.v_in, float), np.asarray(recording.w, float)
    if isinstance(samples, bool) or not isinstance(samples, int) or not 1 <= samples <= len(v):
        raise InputError(f"samples must be a whole number from 1 to the record's {len(v)}, got {samples!r}")
    low, high = bounds if bounds is not None else (float(v.min()), float(v.max()))
    if not (np.isfinite(low) and np.isfinite(high) and low < high):
        low, high = low - 1.0, high + 1.0  # a constant drive: search around it

    def with_drive(u0):
        return eqx.tree_at(lambda m: m.simulation, model, simulation.replace(initial_drive=float(u0)))

    def rmse(u0):  # the model is causal: the first samples' prediction needs only the first samples' drive
        predicted = np.asarray(with_drive(u0).predict(v[:samples], recording.dt))
        return float(np.sqrt(np.mean((predicted - w[:samples]) ** 2)))

    found = scipy.optimize.minimize_scalar(rmse, bounds=(low, high), method="bounded")
    return with_drive(found.x), float(found.x)
