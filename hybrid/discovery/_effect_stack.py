"""A simulation followed by physical effects: `EffectStack` and `extend`.

[`EffectStack`][] wraps a simulation with effects and is itself a
[`AbstractSimulation`][]: the fitter fits it like the RC network. Each effect
has a switch in ``active`` (1 on, 0 off; an array, not a static flag), so that
the discrepancy search fits every candidate with one compiled program, `vmap`-ed
over the switches: with a switch at 0 the effect's parameters have exactly zero
Jacobian columns and Levenberg–Marquardt (λI damping) leaves them in place.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ..core._parameters import Constraint
from ..core._simulation import AbstractSimulation, AbstractWrapper, perturb_raw
from ..util._errors import InputError
from ._effects import EFFECTS, AbstractEffect


class EffectStack(AbstractWrapper):
    """A simulation followed by physical effects: y = e_K(…e_1(inner(v_in))…).

    **Arguments:**

    - `inner`: the simulation being extended (e.g. [`RCNetwork`][]).
    - `effects`: effect instances or names (see [`EFFECTS`][]), applied in that order.
    - `active`: per-effect switch, 1 on and 0 off (default all on): an effect
      contributes ``active·(effect(s) − s)``.

    Its parameters are the inner simulation's plus every effect's (names are
    unique); freeze, replace and fit them like any simulation's.
    """

    inner: AbstractSimulation
    effects: tuple[AbstractEffect, ...]
    active: Array

    def __init__(self, inner: AbstractSimulation, effects=(), active=None):
        built = []
        for effect in effects:
            if isinstance(effect, str):
                if effect not in EFFECTS:
                    raise InputError(f"unknown effect {effect!r}: choose from {', '.join(EFFECTS)}")
                effect = EFFECTS[effect]()  # type: ignore[call-arg]  # eqx AbstractVar `raw`: no init arg
            if not isinstance(effect, AbstractEffect):
                raise InputError(f"effects must be effect names or AbstractEffect instances, got {effect!r}")
            built.append(effect)
        names = [n for e in built for n in e.constraints] + list(inner.parameter_names())
        if len(set(names)) != len(names):
            raise InputError(f"parameter names collide in {names}: use each effect once")
        self.inner = inner
        self.effects = tuple(built)
        if active is None:
            active = jnp.ones(len(built))
        self.active = jnp.asarray(active, dtype=float)
        if self.active.shape != (len(built),):
            raise InputError(
                f"active needs one switch per effect ({len(built)}), got shape {self.active.shape}"
            )

    @property  # type: ignore[misc]  # equinox: AbstractVar `raw` may be implemented by a property
    def raw(self) -> dict[str, Array]:  # type: ignore[override]  # (mypy sees a plain field)
        """Every unconstrained value, inner and effects (read-only view)."""
        out = dict(self.inner.raw)
        for effect in self.effects:
            out.update(effect.raw)
        return out

    @property
    def effect_names(self) -> tuple[str, ...]:
        return tuple(e.name for e in self.effects)

    def simulate(self, v_in, dt):
        s = self.inner.simulate(v_in, dt)
        for on, effect in zip(self.active, self.effects):
            s = switched(on, effect, s, dt)
        return s

    def parameters(self):
        out = dict(self.inner.parameters())
        for effect in self.effects:
            out.update(effect.parameters())
        return out

    def parameter_names(self):
        return tuple(self.inner.parameter_names()) + tuple(n for e in self.effects for n in e.constraints)

    @property
    def units(self) -> dict[str, str]:
        out = dict(self.inner.units)
        for effect in self.effects:
            out.update(effect.units)
        return out

    @property
    def constraints(self) -> dict[str, Constraint]:
        out = dict(self.inner.constraints)
        for effect in self.effects:
            out.update(effect.constraints)
        return out

    def replace(self, **values):
        own = {e.name: {k: v for k, v in values.items() if k in e.constraints} for e in self.effects}
        rest = {k: v for k, v in values.items() if not any(k in e.constraints for e in self.effects)}
        inner = self.inner.replace(**rest) if rest else self.inner
        effects = tuple(e.with_values(**own[e.name]) if own[e.name] else e for e in self.effects)
        return EffectStack(inner, effects, self.active)

    def with_raw(self, raw):
        names = set(self.inner.parameter_names())
        inner = {k: v for k, v in raw.items() if k in names}
        effects = tuple(
            eqx.tree_at(lambda e: e.raw, e, {**e.raw, **{k: raw[k] for k in e.raw if k in raw}})
            for e in self.effects
        )
        return EffectStack(self.inner.with_raw(inner) if inner else self.inner, effects, self.active)

    def with_active(self, active) -> EffectStack:
        """The same stack with other switches (an array of 0/1 per effect)."""
        return eqx.tree_at(lambda s: s.active, self, jnp.asarray(active, dtype=float))

    def perturbed(self, key, scale, frozen=frozenset()):
        keys = jax.random.split(key, len(self.effects) + 1)
        inner = self.inner.perturbed(keys[0], scale, frozen)
        effects = tuple(
            eqx.tree_at(lambda e: e.raw, effect, perturb_raw(effect.raw, k, scale, frozen))
            for k, effect in zip(keys[1:], self.effects)
        )
        return EffectStack(inner, effects, self.active)

    def trainable(self, frozen):
        spec = jax.tree_util.tree_map(lambda _: False, self)
        spec = eqx.tree_at(lambda s: s.inner, spec, self.inner.trainable(frozen))
        effects = tuple(
            eqx.tree_at(
                lambda e: e.raw,
                jax.tree_util.tree_map(lambda _: False, e),
                {k: k not in frozen for k in e.raw},
            )
            for e in self.effects
        )
        return eqx.tree_at(lambda s: s.effects, spec, effects)

    def derived(self, v_in, dt, n: int | None = None) -> dict[str, dict[str, float]]:
        """Each active effect's derived quantities (see `AbstractEffect.derived`), on this drive.

        `n`: the samples of `v_in` that were recorded (a padded drive's first
        `n`); each effect's quantities are taken over those alone.
        """
        n = int(v_in.shape[0]) if n is None else int(n)
        signals = np.asarray(_signals_into_effects(self, v_in, dt))
        out = {}
        for on, effect, s in zip(self.active, self.effects, signals):
            if float(on):  # a switched-off effect leaves s unchanged
                out[effect.name] = effect.derived(s[:n], dt)
        return out


def switched(on, effect: AbstractEffect, s, dt):
    """``s + on·(effect(s) − s)``; an effect switched off is not evaluated at all.

    A search lane runs every effect of its stack on every LM step, under every
    Jacobian direction: a `lax.cond` on the switch skips the effects a lane has
    off (under `vmap` it becomes a select, and both sides run as before). It
    also keeps a switched-off effect's NaN or inf out of ``0·(effect(s) − s)``.
    """
    return jax.lax.cond(on != 0, lambda x: x + on * (effect.apply(x, dt) - x), lambda x: x, s)


@eqx.filter_jit
def _signals_into_effects(stack, v_in, dt):
    """The signal entering each effect of `stack` (rows in its order), in one compiled program.

    The switches are data: every stack of one structure, whichever effects are
    on, shares the program.
    """
    s = stack.inner.simulate(v_in, dt)
    into = []
    for on, effect in zip(stack.active, stack.effects):
        into.append(s)
        s = switched(on, effect, s, dt)
    return jnp.stack(into)


def extend(simulation: AbstractSimulation, *effects, **values) -> EffectStack:
    """`simulation` followed by the named effects, with optional starting values.

    >>> extend(RCNetwork(), "delay", "back_relaxation", relaxation_time_s=20.0)
    """
    stack = EffectStack(simulation, effects)
    return stack.replace(**values) if values else stack
