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
from jax.custom_derivatives import SymbolicZero
from jax.flatten_util import ravel_pytree
from jaxtyping import Array

from ..core._arguments import check_drive, run_compiled
from ..core._devices import map_rows
from ..core._parameters import Constraint
from ..core._serialise import imported_class
from ..core._simulation import AbstractSimulation, AbstractWrapper, perturb_raw, unit_in
from ..core._state_space import dynamics_of, integrate, own_forces
from ..util._errors import InputError
from ._effect_set import force_percent_of_drive, resolve_effects
from ._effects import AbstractEffect, StartContext


class EffectStack(AbstractWrapper):
    """A simulation with physical effects on its drive, inside it and on its output.

    y = φ_out(S_inside(φ_drive(v_in))), where S_inside is `inner` with the
    inside effects in its dynamics.

    **Arguments:**

    - `inner`: the simulation being extended (e.g. [`RCNetwork`][]).
    - `effects`: effect instances or names (see [`EFFECTS`][]). Those whose
      `place` is ``"drive"`` act on the drive, in their order, before `inner`;
      those ``"inside"`` act in `inner`'s dynamics (it must be in state-space
      form, [`AbstractStateSpace`][]: feedback forces add up, limits act in
      their order after every step); the others act on its output, in their order.
    - `active`: per-effect switch, 1 on and 0 off (default all on): an effect
      contributes ``active·(effect(s) − s)``.
    - `drive_unit`: the drive's unit, which a drive-side effect's parameter
      units follow (an output-side effect's follow `inner.output_unit`).

    Its parameters are the inner simulation's plus every effect's (names are
    unique); freeze, replace and fit them like any simulation's.
    """

    inner: AbstractSimulation
    effects: tuple[AbstractEffect, ...]
    active: Array
    drive_unit: str = eqx.field(static=True)

    def __init__(self, inner: AbstractSimulation, effects=(), active=None, drive_unit: str = "V"):
        built = []
        for effect in effects:
            if isinstance(effect, str):  # a built-in, or limit_<state> etc. of a state-space inner
                (effect,) = resolve_effects([effect], inner)
            if not isinstance(effect, AbstractEffect):
                raise InputError(f"effects must be effect names or AbstractEffect instances, got {effect!r}")
            built.append(effect)
        inside = [e for e in built if e.place == "inside"]
        if inside:
            dynamics = dynamics_of(inner)
            if dynamics is None:
                raise InputError(
                    f"{', '.join(e.name for e in inside)} act inside the dynamics, but {type(inner).__name__} "
                    "has no state-space form: derive it from hybrid.AbstractStateSpace, or drop them"
                )
            states = dynamics[0].states
            missing = [
                e.name
                for e in inside
                if e.acts_on != "output"
                and any(s not in states for s in (e.bounded_states if e.role == "limit" else (e.acts_on,)))
            ]
            if missing:
                raise InputError(
                    f"{', '.join(missing)} act on states {type(inner).__name__} does not have "
                    f"(its states: {', '.join(states)})"
                )
        names = [n for e in built for n in e.constraints] + list(inner.parameter_names())
        if len(set(names)) != len(names):
            raise InputError(f"parameter names collide in {names}: use each effect once")
        self.inner = inner
        self.effects = tuple(built)
        self.drive_unit = drive_unit
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
        v_in, dt = check_drive(v_in, dt, "EffectStack.simulate")
        return run_compiled(_output, self, v_in, dt)

    def signal_unit(self, effect: AbstractEffect) -> str:
        """The unit of the signal `effect` acts on: the drive's, the inner output's or a state's."""
        if effect.place == "drive":
            return self.drive_unit
        if effect.place == "inside" and effect.acts_on != "output":
            dynamics = dynamics_of(self.inner)
            unit = dynamics[0].state_units.get(effect.acts_on) if dynamics else None
            # A state in the drive's unit (an oscillator's position, in volts of drive) says "{drive}".
            return unit_in(unit, self.drive_unit) if unit else f"(unit of {effect.acts_on})"
        return unit_in(self.inner.output_unit, self.drive_unit)

    def parameters(self):
        out = dict(self.inner.parameters())
        for effect in self.effects:
            out.update(effect.parameters())
        return out

    def parameter_names(self):
        return tuple(self.inner.parameter_names()) + tuple(n for e in self.effects for n in e.constraints)

    @property
    def force_unit(self) -> str:
        """The unit of a force fed back inside the dynamics: the drive's, or the simulation's `force_unit`."""
        dynamics = dynamics_of(self.inner)
        return unit_in(dynamics[0].force_unit, self.drive_unit) if dynamics else self.drive_unit

    def _fills(self, effect: AbstractEffect) -> tuple[str, str]:
        """(``{signal}``, ``{drive}``) of `effect`'s units: an inside feedback's ``{drive}`` is its force's
        unit (the drive's, unless the simulation puts it elsewhere)."""
        return self.signal_unit(effect), self.force_unit if effect.place == "inside" else self.drive_unit

    @property
    def units(self) -> dict[str, str]:
        out = dict(self.inner.units)
        for effect in self.effects:
            out.update(effect.units_for(*self._fills(effect)))
        return out

    def units_in(self, drive_unit: str) -> dict[str, str]:
        """`units` with the drive in `drive_unit`, the effects' ``{signal}`` and ``{drive}`` filled in with it."""
        return AbstractWrapper.units_in(
            EffectStack(self.inner, self.effects, self.active, drive_unit), drive_unit
        )

    @property
    def derived_units(self) -> dict[str, dict[str, str]]:
        """Each effect's `derived_units`, filled in as `units` fills its parameters', by effect name."""
        return {effect.name: effect.derived_units_for(*self._fills(effect)) for effect in self.effects}

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
        return EffectStack(inner, effects, self.active, self.drive_unit)

    def with_raw(self, raw):
        names = set(self.inner.parameter_names())
        inner = {k: v for k, v in raw.items() if k in names}
        effects = tuple(
            eqx.tree_at(lambda e: e.raw, e, {**e.raw, **{k: raw[k] for k in e.raw if k in raw}})
            for e in self.effects
        )
        return EffectStack(
            self.inner.with_raw(inner) if inner else self.inner, effects, self.active, self.drive_unit
        )

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
        return EffectStack(inner, effects, self.active, self.drive_unit)

    def trainable(self, frozen):
        # One pass over the stack's leaves, by path: the inner simulation's own spec (a plug-in may
        # define it), each effect's `raw` values free unless frozen, everything else fixed: a diagnosis asks
        # a few hundred times, and a tree_at per effect rebuilt the whole stack for each.
        inner = iter(jax.tree_util.tree_leaves(self.inner.trainable(frozen)))
        leaves, treedef = jax.tree_util.tree_flatten_with_path(self)

        def free(path) -> bool:
            field = path[0].name
            if field == "inner":
                return next(inner)
            raw = field == "effects" and len(path) == 4 and getattr(path[2], "name", None) == "raw"
            return raw and path[3].key not in frozen

        return jax.tree_util.tree_unflatten(treedef, [free(path) for path, _ in leaves])

    def config(self) -> dict:
        """The skeleton a saved model rebuilds: the inner simulation's, each effect's class, the switches."""
        from ..core._serialise import describe_simulation

        return {
            "inner": describe_simulation(self.inner),
            "effects": [
                {"type": type(e).__qualname__, "module": type(e).__module__, "config": e.config()}
                for e in self.effects
            ],
            "active": [float(a) for a in np.asarray(self.active)],
            "drive_unit": self.drive_unit,
        }

    @classmethod
    def from_config(cls, config: dict) -> EffectStack:
        """The stack `config()` describes, with default values (a saved model's leaves fill them in)."""
        from ..core._serialise import build_simulation

        effects = tuple(
            effect_class(d["type"], d.get("module")).from_config(d.get("config", {}))
            for d in config["effects"]
        )
        return cls(
            build_simulation(config["inner"]), effects, config.get("active"), config.get("drive_unit", "V")
        )

    def signals_into(self, v_in, dt, n: int | None = None) -> dict[str, np.ndarray]:
        """The signal entering each effect on this drive (its first `n` samples), by effect name.

        Under ``"drive"``: the drive that reaches the inner simulation.
        """
        n = int(v_in.shape[0]) if n is None else int(n)
        signals = np.asarray(_signals_into_effects(self, v_in, dt))
        out = {effect.name: s[:n] for effect, s in zip(self.effects, signals)}
        return {**out, "drive": signals[-1][:n]}

    def derived(self, v_in, dt, n: int | None = None) -> dict[str, dict[str, float]]:
        """Each active effect's derived quantities (see `AbstractEffect.derived`), on this drive.

        `n`: the samples of `v_in` that were recorded (a padded drive's first
        `n`); each effect's quantities are taken over those alone. An inside
        feedback's include ``force_percent_of_drive``: its largest |force| as
        a percentage of the largest |drive| that reaches the simulation; an
        inside limit's ``cut_percent_of_range``: how far it pulls the state's
        peak down, as a percentage of the state's range without it.
        """
        signals = self.signals_into(v_in, dt, n)
        out = {}
        for i, (on, e) in enumerate(zip(self.active, self.effects)):
            if not float(on):  # a switched-off effect leaves its signal unchanged: nothing to derive
                continue
            at = {}
            if e.place == "inside" and e.role == "limit" and e.from_rest:  # measured from the state's rest
                core = dynamics_of(self.inner)
                assert core is not None  # an inside effect needs the state-space form
                at = {"origin": float(rest_state(core[0], jnp.float64)[core[0].states.index(e.acts_on)])}
            out[e.name] = e.derived(signals[e.name], dt, **at)
            if e.place == "inside" and e.role == "feedback":
                force = np.asarray(jax.vmap(lambda z, e=e: e.apply(z, dt))(jnp.asarray(signals[e.name])))
                size = force_percent_of_drive(force, drive_forces(self, signals["drive"]), float(on))
                out[e.name] = {**out[e.name], "force_percent_of_drive": size}
            if e.place == "inside" and e.role == "limit":
                free = self.with_active(np.where(np.arange(len(self.effects)) == i, 0.0, self.active))
                unlimited = free.signals_into(v_in, dt, n)[e.name]
                span = float(np.ptp(unlimited)) if len(unlimited) else 0.0
                cut = e.cut(unlimited, signals[e.name]) if span > 0 else 0.0
                out[e.name] = {
                    **out[e.name],
                    "cut_percent_of_range": 100.0 * max(cut, 0.0) / span if span else 0.0,
                }
        return out


def at_first_starts(stack: EffectStack, recording) -> EffectStack:
    """`stack` with each effect at its first start (`AbstractEffect.starts`) on `recording`, its defaults otherwise.

    A fit from an effect's defaults can sit where its gradient is zero: a
    saturation's curvature 0 is the linear response, and tanh(κs)/κ is even in
    κ, so LM never moves it (`hybrid fit --effects saturation` kept the line on a
    clipped record). Each start is taken with the other effects as they are; an
    effect whose `starts` fails here keeps its defaults.

    An effect's `StartContext.measured` is the recorded w brought into the
    simulation's output unit by the least-squares line through the inner
    simulation's output (w ≈ g·y + c), as `diagnose` brings it by the fitted
    readout: a line added to the output (`Line`) starts at the residual's
    strongest line (`hybrid fit --effects line` from its 1 Hz default found a
    7.3 Hz pick-up nowhere).
    """
    v_in = jnp.asarray(recording.v_in)
    signals = stack.signals_into(v_in, recording.dt)
    measured = _in_output_unit(
        np.asarray(recording.w, float), np.asarray(stack.inner.simulate(v_in, recording.dt))
    )
    values: dict[str, float] = {}
    for effect in stack.effects:
        context = StartContext(
            signal=np.asarray(signals[effect.name]),
            rate=recording.rate,
            duration=float(recording.n * recording.dt),
            drive=np.asarray(signals["drive"]),
            measured=measured,
        )
        try:
            first = (effect.starts(context) or [{}])[0]
        except Exception:  # a plug-in's starts that need what only diagnose gives: its defaults
            continue
        values.update({k: float(v) for k, v in first.items() if k in effect.constraints})
    return stack.replace(**values) if values else stack


def _in_output_unit(w: np.ndarray, y: np.ndarray) -> np.ndarray | None:
    """`w` mapped onto `y`'s unit by the least-squares line w ≈ g·y + c, or None where y carries no such line."""
    if w.shape != y.shape or not (np.all(np.isfinite(w)) and np.all(np.isfinite(y))) or np.ptp(y) == 0:
        return None
    g, c = np.polyfit(y, w, 1)
    return (w - c) / g if g != 0 and np.isfinite(g) else None


def effect_class(name: str, module: str | None = None) -> type[AbstractEffect]:
    """The imported `AbstractEffect` subclass a saved model names (a plug-in's module imported first)."""
    return imported_class(AbstractEffect, name, module, "effect")


def switched(on, effect: AbstractEffect, s, dt):
    """``s + on·(effect(s) − s)``; an effect switched off is not evaluated at all.

    A search lane runs every effect of its stack on every LM step, under every
    Jacobian direction: a `lax.cond` on the switch skips the effects a lane has
    off (under `vmap` it becomes a select, and both sides run as before). It
    also keeps a switched-off effect's NaN or inf out of ``0·(effect(s) − s)``.
    Both sides keep ``s``'s dtype: a plug-in's apply that returns float32 (said in
    the report, `narrowed`) would otherwise stop the cond with a TypeError.
    """
    return jax.lax.cond(
        on != 0, lambda x: (x + on * (effect.apply(x, dt) - x)).astype(x.dtype), lambda x: x, s
    )


def _output(stack, v_in, dt):
    return _signals_through(stack, v_in, dt, states=False)[1]


def _signals_through(stack, v_in, dt, states: bool = True):
    """(the signal entering each effect, rows in the stack's order; the stack's output; the drive into `inner`).

    `states=False` (the output alone, as `simulate` wants it): while every
    inside effect is off, the inner simulation runs as its own `simulate` (the
    RC network's block-lifted cascade, not its state-space form stepped sample
    by sample), and neither the signals entering the effects nor the drive into
    `inner` are computed (None).
    """
    into: list = [None] * len(stack.effects)
    inside = [(i, e) for i, e in enumerate(stack.effects) if e.place == "inside"]
    # The drive into `inner` for the signals' record and the inside dynamics; the inner
    # simulation's own response takes the drive's effects into its derivative (`inner_response`).
    u = _through(stack, "drive", v_in, dt, into) if states or inside else None
    if inside:
        # A lane with every inside effect off (the baseline's, an outside candidate's) runs the
        # plain simulation: the effects' forces and limits cost as much as the dynamics.
        any_on = jnp.any(jnp.stack([stack.active[i] != 0 for i, _ in inside]))
        dynamics = dynamics_of(stack.inner)
        assert dynamics is not None  # checked when the stack was built
        core, held, skip = dynamics
        driven = held(u)
        n_states = len(core.states)

        def plain(x):
            if states:
                return integrate(core, x, dt)
            out = inner_response(stack, v_in, dt)  # the record's part; held samples as 0
            out = jnp.concatenate([jnp.zeros(skip, out.dtype), out])
            return out.astype(jnp.result_type(x, out)), jnp.zeros((x.shape[0], n_states), out.dtype)

        s, trajectory = jax.lax.cond(
            any_on, lambda x: _inside_dynamics(stack, core, inside, x, dt), plain, driven
        )
        s, trajectory = s[skip:], trajectory[skip:]
        for i, effect in inside:
            into[i] = s if effect.acts_on == "output" else trajectory[:, core.states.index(effect.acts_on)]
    else:
        s = inner_response(stack, v_in, dt)
    return into, _through(stack, "output", s, dt, into if states else None), u


def _through(stack, place: str, signal, dt, into: list | None = None):
    """`signal` through `stack`'s effects of `place` ("drive" or "output"), in their order.

    `into`: where to record the signal entering each (by the effect's index).
    """
    for i, effect in enumerate(stack.effects):
        if effect.place == place:
            if into is not None:
                into[i] = signal
            signal = switched(stack.active[i], effect, signal, dt)
    return signal


#: A drive-side effect with at most this many parameters is differentiated in each of them once
#: (`inner_response`); one with more (a plug-in's table), along each direction asked, as plainly.
DRIVE_JACOBIAN_MAX = 8


def _split(tree, spec):
    """(the parameters `spec` marks as one flat vector, a function back to them, the other arrays, the rest)."""
    params, rest = eqx.partition(tree, spec)
    arrays, static = eqx.partition(rest, eqx.is_inexact_array)
    flat, unravel = ravel_pytree(params)
    return flat, unravel, arrays, static


def inner_response(stack: EffectStack, v_in, dt):
    """`stack.inner.simulate(u, dt)`, u = `v_in` through the drive's effects, at the cost of few directions.

    A search lane's Jacobian takes one direction per free parameter of the
    whole stack (the inner simulation's, the frame timing's, its effects'),
    all at once under `vmap`; run plainly, the inner simulation — by far the
    dearest part — would be differentiated along every one of them, though
    only its own parameters' and the drive's effects' directions move it. Here
    its derivative is computed once per parameter that moves it, outside the
    batch of directions, and multiplied by each direction:

    - its Jacobian in its own parameters (`jax.jacfwd`);
    - for each drive-side effect that is on, the Jacobian of the response in
      that effect's parameters: the drive's derivative in them (the drive
      effects alone), then the simulation's along each such column (one or two
      directions, where the batch has ~13), one traced copy of the
      simulation's derivative for every drive effect (`_drive_directions`); an
      effect that is off moves nothing and costs nothing (`lax.cond` on its
      switch); one with more than `DRIVE_JACOBIAN_MAX` parameters is
      differentiated along each direction instead;
    - along the drive `v_in` itself, plainly, when the caller differentiates
      it (a sensitivity to the drive, a drive's design); never where its
      derivative is known to be zero (not differentiated).

    Only parameters (`raw`) go through `jax.jacfwd`: a plug-in may hold other
    arrays (a calibration table, a fixed matrix), whose derivative, if
    anything asks for it, is taken plainly along the directions given, as is
    one along the switches.
    """
    spec = stack.trainable(frozenset())  # the inner simulation's spec, and each effect's `raw`
    flat, unravel, arrays, static = _split(stack.inner, spec.inner)
    drives = [(i, _split(e, spec.effects[i])) for i, e in enumerate(stack.effects) if e.place == "drive"]
    effect_flats = tuple(d[0] for _, d in drives)
    effect_arrays = tuple(d[2] for _, d in drives)
    switches = jnp.stack([stack.active[i] for i, _ in drives]) if drives else jnp.zeros(0)

    def drive_of(p_effects, e_arrays, on, source):
        u = source
        for k, (_, (_, back, _, e_static)) in enumerate(drives):
            u = switched(on[k], eqx.combine(back(p_effects[k]), e_arrays[k], e_static), u, dt)
        return u

    def run(theta, p_effects, others, e_arrays, on, source):
        drive = drive_of(p_effects, e_arrays, on, source)
        return _in_drive_dtype(eqx.combine(unravel(theta), others, static), drive, dt)

    @jax.custom_jvp
    def response(theta, p_effects, others, e_arrays, on, source):
        return run(theta, p_effects, others, e_arrays, on, source)

    def _derivative(primals, tangents):
        theta, p_effects, others, e_arrays, on, source = primals
        d_theta, d_effects, *d_rest = tangents
        rest = primals[2:]
        u = drive_of(p_effects, e_arrays, on, source)  # the drive into the simulation, once

        def simulate(drive, t=theta):
            return _in_drive_dtype(eqx.combine(unravel(t), others, static), drive, dt)

        if isinstance(d_theta, SymbolicZero):  # no parameter differentiated: the value alone
            y = simulate(u)
            dy = jnp.zeros_like(y)
        else:
            J, y = jax.jacfwd(lambda t: (simulate(u, t),) * 2, has_aux=True)(theta)
            dy = J @ d_theta
        # what is taken plainly below, along each direction: the tangents of the switches, the drive
        # and the arrays when given, and of a drive effect with many parameters (zero where done here)
        plainly = [not all(isinstance(t, SymbolicZero) for t in jax.tree_util.tree_leaves(d)) for d in d_rest]
        plain_effects, once = [], []
        for k, (p, d) in enumerate(zip(p_effects, d_effects)):
            many = not isinstance(d, SymbolicZero) and p.size > DRIVE_JACOBIAN_MAX
            plainly.append(many)
            plain_effects.append(d if many else jnp.zeros_like(p))
            if not (isinstance(d, SymbolicZero) or many):
                once.append(k)
        if once:
            dy = dy + _drive_directions(
                lambda pe: drive_of(pe, e_arrays, on, source),
                simulate,
                u,
                p_effects,
                on,
                [(k, d_effects[k]) for k in once],
                y,
            )
        if any(plainly):
            zeroed = [
                jax.tree_util.tree_map(
                    lambda t, a: jnp.zeros_like(a) if isinstance(t, SymbolicZero) else t, d, r
                )
                for r, d in zip(rest, d_rest)
            ]
            along_each = jax.jvp(
                lambda pe, *r: run(theta, pe, *r), (p_effects, *rest), (tuple(plain_effects), *zeroed)
            )[1]
            dy = dy + along_each
        return y, dy

    response.defjvp(_derivative, symbolic_zeros=True)
    return response(flat, effect_flats, arrays, effect_arrays, switches, v_in)


def _in_drive_dtype(simulation, drive, dt):
    """`simulation.simulate(drive, dt)` in the drive's dtype where it returns fewer bits: a plug-in's float32
    (said in the report, `narrowed`) stopped the response's derivative on its primal's dtype."""
    out = simulation.simulate(drive, dt)
    return out.astype(jnp.promote_types(out.dtype, drive.dtype))


def _drive_directions(drive, simulate, u, p_effects, on, asked, y):
    """The response's derivative along the asked drive effects' directions: Σ_k J_k·d_k for (k, d_k) in `asked`.

    J_k = ∂simulate(drive(p))/∂p_k: the drive's derivative in effect k's
    parameters (the drive effects alone; zero while k is off), then the
    simulation's derivative along each of those columns that an effect switched
    on moves, one column after another under one `lax.map`. The simulation's
    derivative is traced and compiled once for every drive effect, not once per
    effect: with the four drive-side built-ins the lanes' program traced it four
    times (`benchmarks/diagnose_effect_set.py`). The live columns come first
    (`slots`), the rest are zero rows; each direction's weights are gathered
    into that order (a few numbers), not the responses scattered back into the
    parameters' order (rows as long as the record). While every asked effect
    is off — most lanes of a search: each fits one effect or two — no column
    is computed at all (one `lax.cond`), nor any derivative of the simulation
    along the drive. The columns are computed once, outside the batch of
    directions (`d_k`). `u`: `drive(p_effects)`, the drive the caller simulated.
    """
    n_cols = sum(p_effects[k].size for k, _ in asked)
    live = jnp.concatenate([jnp.full(p_effects[k].size, on[k] != 0) for k, _ in asked])
    n_live = jnp.sum(live)
    slots = jnp.nonzero(live, size=n_cols, fill_value=0)[0]  # the live columns first, then filler

    def responses():
        columns = []
        for k, _ in asked:
            p = p_effects[k]

            def along(q, k=k):
                return drive(p_effects[:k] + (q,) + p_effects[k + 1 :])

            columns.append(
                jax.lax.cond(  # an effect switched off moves nothing
                    on[k] != 0,
                    lambda along=along, p=p: jax.jacfwd(along)(p).reshape(u.shape[0], -1),
                    lambda p=p: jnp.zeros((u.shape[0], p.size), u.dtype),
                )
            )
        U = jnp.concatenate(columns, axis=1)  # the drive's derivative, one column per parameter

        def response_along(j):
            return jax.lax.cond(
                j < n_live,
                lambda: jax.jvp(simulate, (u,), (U[:, slots[j]],))[1].astype(y.dtype),
                lambda: jnp.zeros_like(y),
            )

        return jax.lax.map(response_along, jnp.arange(n_cols))

    J = jax.lax.cond(n_live > 0, responses, lambda: jnp.zeros((n_cols,) + y.shape, y.dtype))
    d = jnp.concatenate([d.reshape(-1) for _, d in asked])
    weights = jnp.where(jnp.arange(n_cols) < n_live, d[slots], 0)  # the filler's rows are zero
    return jnp.tensordot(weights.astype(y.dtype), J, axes=1)


def drive_forces(stack: EffectStack, drive) -> np.ndarray:
    """The force each value of `drive` exerts, in the unit of a force fed back inside `stack`'s dynamics.

    The drive itself where a force is taken off it; the simulation's
    `drive_force` where it puts forces elsewhere (a heater's power u²/R).
    """
    dynamics = dynamics_of(stack.inner)
    if dynamics is None or not own_forces(dynamics[0]):
        return np.asarray(drive)
    core = dynamics[0]
    p = core.prepare(core.parameters())
    return np.asarray(jax.vmap(lambda u: core.drive_force(u, p))(jnp.asarray(drive)))


def _named_state(effect, field: str, states) -> int | None:
    """The index in `states` of the state a limit's `field` names (`StateLimit.into`, `.velocity`), or None."""
    name = getattr(effect, field, None)
    return None if name is None else states.index(name)


def rest_state(inner, dtype) -> tuple:
    """The state-space simulation's initial state under no drive: where each state rests (a tank empty,
    a block at ambient), the origin of a limit's rim (`StateLimit._rim`)."""
    return tuple(inner.initial_state(jnp.zeros((), dtype), inner.prepare(inner.parameters())))


def _inside_dynamics(stack, inner, inside, u, dt, external=None):
    """(output, states) of the inner state-space simulation with the inside effects in its loop.

    A switched-off effect adds no force and leaves its state alone (`jnp.where`,
    so that its NaN cannot leak in either).
    """
    feedback = [(stack.active[i], e) for i, e in inside if e.role == "feedback"]
    limits = [
        (
            stack.active[i],
            e,
            [inner.states.index(s) for s in e.bounded_states],
            _named_state(e, "into", inner.states),
            _named_state(e, "velocity", inner.states),
        )
        for i, e in inside
        if e.role == "limit"
    ]

    def force(x, y):
        total = jnp.zeros((), y.dtype)
        for on, effect in feedback:
            z = y if effect.acts_on == "output" else x[inner.states.index(effect.acts_on)]
            total = total + jnp.where(on != 0, on * effect.apply(z, dt), 0.0)
        return total

    # A limit `from_rest` measures from its state's rest under no drive (`StateLimit._rim`): the
    # same whatever the zero of the state's unit.
    rest = rest_state(inner, jnp.asarray(u).dtype) if limits else ()

    def bound(x):
        x = list(x)
        for on, effect, ks, j, m in limits:
            for k in ks:  # each state it holds (a window's group: every one)
                z = x[k]
                at = {"origin": rest[k]} if effect.from_rest else {}
                x[k] = jnp.where(on != 0, z + on * (effect.apply(z, dt, **at) - z), z)
                if j is not None:  # a share of the cut lands in another state (a tank's spill below)
                    x[j] = jnp.where(on != 0, x[j] + on * effect.spilled(z, dt, **at), x[j])
                if m is not None:  # an end stop also stops the velocity that drove the state into it
                    x[m] = jnp.where(on != 0, x[m] + on * (effect.stopped(z, x[m], **at) - x[m]), x[m])
        return tuple(x)

    return integrate(inner, u, dt, force if feedback else None, bound if limits else None, external)


@eqx.filter_jit
def _signals_into_effects(stack, v_in, dt):
    """The signal entering each effect of `stack` (rows in its order), in one compiled program.

    The switches are data: every stack of one structure, whichever effects are
    on, shares the program.
    """
    into, _, u = _signals_through(stack, v_in, dt)
    return jnp.stack([*into, u])


def extend(simulation: AbstractSimulation, *effects, **values) -> EffectStack:
    """`simulation` followed by the named effects, with optional starting values.

    >>> extend(RCNetwork(), "delay", "back_relaxation", relaxation_time_s=20.0)
    """
    stack = EffectStack(simulation, effects)
    return stack.replace(**values) if values else stack


def _dynamics_run(stack: EffectStack, v_in, dt, force):
    """(output, states) of `stack` on `v_in`, `force` (a signal in the force's unit) fed into its dynamics.

    The force enters where an inside feedback's does: taken off the drive (y =
    S(u − φ)) after the drive's effects, or where the simulation's
    `forced_rates` puts it, in every RK4 stage; the output's effects follow.
    Needs `stack.inner` in state-space form (`dynamics_of`).
    """
    u = _through(stack, "drive", v_in, dt)
    dynamics = dynamics_of(stack.inner)
    assert dynamics is not None  # the caller checks
    core, held, skip = dynamics
    inside = [(i, e) for i, e in enumerate(stack.effects) if e.place == "inside"]
    if own_forces(core):  # the simulation puts a force where it acts (a heater's loss off its power)
        driven, external = held(u), jnp.concatenate([jnp.zeros(skip, force.dtype), force])
    else:
        driven, external = held(u - force), None
    s, states = (
        _inside_dynamics(stack, core, inside, driven, dt, external)
        if inside
        else integrate(core, driven, dt, external=external)
    )
    return _through(stack, "output", s[skip:], dt), states[skip:]


@eqx.filter_jit
def state_trajectories(stack: EffectStack, v_in, dt):
    """The states of `stack`'s dynamics on `v_in`, one column per state (`stack.inner` in state-space form)."""
    return _dynamics_run(stack, v_in, dt, jnp.zeros_like(v_in))[1]


@eqx.filter_jit
def drive_responses(stack: EffectStack, v_in, dt, directions, names=()) -> tuple[jax.Array, jax.Array]:
    """How `stack`'s output moves, to first order, with its drive and with its parameters `names`.

    Row k of the first result is the derivative of the output along
    ``directions[k]`` (a signal in the drive's unit) added to the drive before
    every effect on it: the whole model linearised along this recording,
    whatever its form (no state-space form needed). Row j of the second is the
    derivative in parameter ``names[j]`` (its raw value). Forward mode, the
    directions a few rows at a time on each device (`map_rows`); one program.
    """
    v_in = jnp.asarray(v_in)
    raw = stack.raw

    def along(direction):
        return jax.jvp(lambda u: _output(stack, u, dt), (v_in,), (direction,))[1]

    def by(tangent):
        return jax.jvp(lambda r: _output(stack.with_raw(r), v_in, dt), (chosen,), (tangent,))[1]

    # Every parameter's direction through one traced copy of the model (vmapped over a one-hot
    # basis of `chosen`): a copy per name made the program several times longer to compile.
    chosen = {name: raw[name] for name in names}
    basis = {
        name: jnp.stack([jnp.full_like(value, float(k == j)) for k in range(len(names))])
        for j, (name, value) in enumerate(chosen.items())
    }
    parameters = jax.vmap(by)(basis) if names else jnp.zeros((0, v_in.shape[0]))
    return map_rows(along, directions, batch_size=8), parameters


@eqx.filter_jit
def force_responses(stack: EffectStack, v_in, dt, forces):
    """How `stack`'s output moves, to first order, with each row of `forces` fed into its dynamics.

    Row k of the result is the derivative of the output along a force
    ``forces[k]`` (a signal in the force's unit, `EffectStack.force_unit`,
    acting where an inside feedback's does: off the drive, or where the
    simulation's `forced_rates` puts it): the response of the dynamics,
    linearised along this recording, to that force. Forward mode, a few rows
    at a time on each device (`map_rows`).
    """
    zero = jnp.zeros_like(v_in)

    def one(direction):
        return jax.jvp(lambda f: _dynamics_run(stack, v_in, dt, f)[0], (zero,), (direction,))[1]

    return map_rows(one, forces, batch_size=8)
