"""Which effects `diagnose` searches: the built-ins, a plug-in's checks, the set for a simulation.

[`EFFECTS`][] names the built-in effect classes; [`resolve_effects`][] turns
what a user passes (names, classes, instances, or None for the built-ins) into
checked instances, and for a simulation in state-space form adds the effects
inside its dynamics (a limit on each of its states).
"""

from __future__ import annotations

import difflib
import re

import jax
import jax.numpy as jnp
import numpy as np

from ..core._parameters import Constraint, constraint_problem
from ..core._state_space import check_state_space, dynamics_of, velocities
from ..util._errors import InputError, PluginError
from ._effects import (
    PLACES,
    ROLES,
    AbstractEffect,
    Backlash,
    BackRelaxation,
    BaselineDrift,
    Clip,
    Creep,
    DeadBand,
    Delay,
    Drift,
    DriveClip,
    DriveDeadZone,
    DriveEven,
    DriveSaturation,
    EvenResponse,
    FrameTiming,
    Hysteresis,
    Lag,
    Line,
    Resonance,
    Saturation,
    StartContext,
)
from ._inside_effects import Friction, PolynomialStiffness, StateLimit, StateWindow

#: The built-in effects, by name, in the order they act on their signal (each added later
#: goes last, which keeps the others' places in the stack and so their fits' layout).
EFFECTS: dict[str, type[AbstractEffect]] = {
    cls.name: cls
    for cls in (
        Delay,
        BackRelaxation,
        Saturation,
        Hysteresis,
        Drift,
        Resonance,
        EvenResponse,
        BaselineDrift,
        DriveDeadZone,
        PolynomialStiffness,
        DriveSaturation,
        DriveEven,
        Backlash,
        Lag,
    )
}
#: Built-in effects searched only when named (``--effects builtins,creep``): physics that a lab meets
#: (a piezo's creep, an amplifier's hard clip) but that the default set's lanes would pay for on every
#: recording, or whose extra freedom would stand in for other effects there (a clip's free knee, soft,
#: took a drift under a rising level).
NAMED_ONLY: dict[str, type[AbstractEffect]] = {
    cls.name: cls for cls in (Creep, Clip, DriveClip, Line, DeadBand)
}
#: Names an effect may not take: the search's words for "no effect", the always-on frame timing and
#: `EffectStack.signals_into`'s key for the drive that reaches the simulation.
RESERVED = ("none", "frame_timing", "drive")


def _probe_context() -> StartContext:
    signal = np.sin(np.linspace(0.0, 6.0, 64)) * 2.0
    return StartContext(
        signal=signal,
        rate=30.0,
        duration=60.0,
        drive=signal,
        measured=signal,
        lag_samples=1,
        residual_peak_hz=None,
    )


def force_percent_of_drive(force, drive, on: float = 1.0) -> float:
    """An inside feedback's size: its largest |force| (switch `on` applied) as a percentage of the largest |drive|."""
    top = float(np.max(np.abs(drive))) if len(drive) else 0.0
    return 100.0 * on * float(np.max(np.abs(force))) / top if top > 0 else 0.0


def _near_misses(cls: type) -> list[tuple[str, str]]:
    """(name, the AbstractEffect member it resembles) for each of `cls`'s own names one letter or so off."""
    known = {n for n in dir(AbstractEffect) if not n.startswith("_")}
    own = [
        n
        for klass in cls.__mro__
        if klass not in AbstractEffect.__mro__ and klass is not object
        for n in vars(klass)
        if not n.startswith("_") and n not in known
    ]
    out = []
    for name in dict.fromkeys(own):
        close = difflib.get_close_matches(name, known, n=1, cutoff=0.85)
        if close:
            out.append((name, close[0]))
    return out


def check_effect(effect: AbstractEffect, label: str) -> None:
    """Refuse, in one line that says the fix, an effect that `diagnose` could not search.

    Checks its facts (name, place, constraints, units, defaults, thresholds)
    and runs `apply` and `starts` once on a short probe signal.
    """
    cls = type(effect).__name__
    name = getattr(effect, "name", None)
    if not isinstance(name, str) or not name.isidentifier() or name in RESERVED:
        raise InputError(
            f"{label}: {cls}.name must be an identifier other than {', '.join(RESERVED)}, got {name!r}; "
            "set name: ClassVar[str] = 'my_effect'"
        )
    if effect.place not in PLACES:
        raise InputError(f"{label}: {cls}.place must be one of {', '.join(PLACES)}, got {effect.place!r}")
    misspelt = _near_misses(type(effect))
    if misspelt:
        typo, meant = misspelt[0]
        raise InputError(
            f"{label}: {cls} defines {typo!r}, which diagnose never reads (did you mean {meant!r}?); "
            "rename it, or the default is used in its place"
        )
    if effect.place == "inside" and effect.role not in ROLES:
        raise InputError(f"{label}: {cls}.role must be one of {', '.join(ROLES)}, got {effect.role!r}")
    constraints = getattr(effect, "constraints", None)
    if not isinstance(constraints, dict) or not all(isinstance(c, Constraint) for c in constraints.values()):
        raise InputError(
            f"{label}: {cls}.constraints must be a dict of hybrid constraints by parameter name "
            "(e.g. {'friction_force': hybrid.Positive()})"
        )
    for fact in ("units", "defaults"):
        given = getattr(effect, fact, None)
        missing = sorted(set(constraints) - set(given or {}))
        if not isinstance(given, dict) or missing:
            stray = sorted(set(given or {}) - set(constraints)) if isinstance(given, dict) else []
            raise InputError(
                f"{label}: {cls}.{fact} has no entry for {missing or 'any parameter'}; add them"
                + (f" ({fact} names {stray}, which is not a parameter: misspelt?)" if stray else "")
            )
    for parameter, unit in effect.units.items():
        unknown = sorted(set(re.findall(r"\{([^{}]*)\}", str(unit))) - {"signal", "drive"})
        if unknown:
            raise InputError(
                f"{label}: {cls}.units[{parameter!r}] = {unit!r} has the placeholder {{{unknown[0]}}}: write "
                "{signal} (the unit of the signal the effect acts on) or {drive} (the drive's)"
            )
    if not isinstance(effect.thresholds, dict) or not all(
        isinstance(v, (int, float)) for v in effect.thresholds.values()
    ):
        raise InputError(f"{label}: {cls}.thresholds must be a dict of numbers by name")
    if not isinstance(effect.n_screened, int) or effect.n_screened < 0:
        raise InputError(f"{label}: {cls}.n_screened must be a whole number ≥ 0, got {effect.n_screened!r}")
    if not isinstance(effect.n_kept, int) or isinstance(effect.n_kept, bool) or effect.n_kept < 0:
        raise InputError(
            f"{label}: {cls}.n_kept must be a whole number ≥ 0 (0: every lane runs), got {effect.n_kept!r}"
        )
    context = _probe_context()
    try:
        if effect.place == "inside":  # evaluated sample by sample inside the integration loop
            dt = 1.0 / context.rate
            out = np.array([float(effect.apply(jnp.asarray(z), dt)) for z in context.signal])
        else:
            out = np.asarray(effect.apply(jnp.asarray(context.signal), 1.0 / context.rate))
        starts = effect.starts(context)
    except KeyboardInterrupt:
        raise
    except Exception as error:
        raise PluginError(
            f"{label}: {cls} failed on a probe signal ({type(error).__name__}: {error}); fix apply or starts",
            error,
        ) from None
    traced = context.signal[0] if effect.place == "inside" else context.signal  # a sample, or the signal
    try:  # as the search runs it: traced under jit (numpy or float() on a traced value fails here)
        jax.eval_shape(lambda z: effect.apply(z, 1.0 / context.rate), jnp.asarray(traced))
    except KeyboardInterrupt:
        raise
    except Exception as error:
        raise PluginError(
            f"{label}: {cls}.apply(s, dt) runs on numbers but not under jax.jit ({type(error).__name__}); "
            "write it with jax.numpy (jnp) and jax.lax (lax.scan for a state carried from sample to sample, "
            "jnp.where for a branch), not numpy, math, float() or a Python if on values",
            error,
        ) from None
    if out.shape != context.signal.shape:
        raise InputError(
            f"{label}: {cls}.apply(s, dt) must return one finite value per sample of s; on a "
            f"{context.signal.shape[0]}-sample probe it returned shape {out.shape}"
        )
    if not np.issubdtype(out.dtype, np.floating):
        raise InputError(
            f"{label}: {cls}.apply(s, dt) returned {out.dtype} values: return floating point, as s is "
            "(an integer output has no gradient to fit)"
        )
    if not np.all(np.isfinite(out)):
        raise InputError(
            f"{label}: {cls}.apply(s, dt) returned {int(np.sum(~np.isfinite(out)))} non-finite values of "
            f"{out.shape[0]} on a probe signal at its default parameters: fix apply"
        )
    try:  # what the report asks of every effect it weighs: its size, and whether that is a cause
        derived = effect.derived(context.signal, 1.0 / context.rate)
        given = dict(derived) if isinstance(derived, dict) else {}
        if effect.place == "inside" and effect.role == "feedback":  # what `EffectStack.derived` adds
            given["force_percent_of_drive"] = force_percent_of_drive(out, context.signal)
        elif effect.place == "inside":  # a limit's cut needs the simulation without it: none on a probe
            given["cut_percent_of_range"] = 0.0
        verdict = effect.material(given, effect.parameters(), dict(effect.thresholds))
    except KeyboardInterrupt:
        raise
    except Exception as error:
        raise PluginError(
            f"{label}: {cls} failed on a probe signal ({type(error).__name__}: {error}); fix derived or material",
            error,
        ) from None

    def finite_number(v) -> bool:  # a Python, numpy or jax scalar
        a = np.asarray(v)
        return a.shape == () and a.dtype.kind in "iuf" and bool(np.isfinite(a))

    if not isinstance(derived, dict) or not all(
        isinstance(k, str) and finite_number(v) for k, v in derived.items()
    ):
        raise InputError(
            f"{label}: {cls}.derived(s, dt) must return a dict of finite numbers by name; on a probe signal at "
            f"its default parameters it returned {derived!r}"
        )
    if not (
        isinstance(verdict, tuple)
        and len(verdict) == 2
        and np.asarray(verdict[0]).shape == ()  # a bool, numpy's or a traced comparison's
        and np.asarray(verdict[0]).dtype == np.bool_
        and isinstance(verdict[1], str)
    ):
        raise InputError(
            f"{label}: {cls}.material(derived, parameters, thresholds) must return (bool, str): whether the "
            f"effect is large enough to be a cause, and why; it returned {verdict!r}"
        )
    if not isinstance(starts, list) or not starts or not all(isinstance(x, dict) for x in starts):
        raise InputError(
            f"{label}: {cls}.starts(context) must return a non-empty list of dicts of its parameters "
            f"({', '.join(constraints)})"
        )
    strangers = sorted({key for start in starts for key in start} - set(constraints))
    if strangers:
        raise InputError(
            f"{label}: {cls}.starts(context) gave {', '.join(map(repr, strangers))}, not a parameter of it "
            f"({', '.join(constraints)}): a start sets some of those (the others keep their defaults)"
        )


def resolve_effects(effects=None, simulation=None) -> tuple[AbstractEffect, ...]:
    """The effects `diagnose` searches: None gives every built-in ([`EFFECTS`][]) `simulation` can take.

    Each item is a built-in's name, ``limit_<state>`` (a limit on a state of
    `simulation`), ``floor_<state>`` (a limit below one), ``friction_<state>`` (a Coulomb friction on one),
    ``window_<state>`` or ``window_<group>`` (a limit of either sign on a state, or
    one on every state of a group of its `state_groups`: `StateWindow`; searched
    when named), an
    [`AbstractEffect`][] subclass (built with no arguments:
    its defaults) or an instance. Every one is checked (`check_effect`); names
    and parameter names must be unique. Effects inside the dynamics need
    `simulation` in state-space form ([`AbstractStateSpace`][]): for None, the
    built-ins are the drive's and the output's effects, plus, for a
    simulation with states, the stiffness, a limit on each state (each
    of its `limited_states`), a floor under each of those that one of its
    velocities moves (an end stop below a position) and a friction on each of its velocities (`velocities`),
    unless it says why not (`not_searched_inside`: the RC network, whose
    stepped form is far dearer than its `simulate`).
    """
    states = _states_of(simulation)
    if effects is None:
        core = None if simulation is None else dynamics_of(simulation)
        if core is not None and core[0].not_searched_inside:
            states = ()  # its inside effects are searched when named (see AbstractStateSpace)
        built = [cls() for cls in EFFECTS.values() if states or cls.place != "inside"]  # type: ignore[call-arg]
        if not states or core is None:
            return tuple(built)
        limited = states if core[0].limited_states is None else core[0].limited_states
        ceilings = tuple(state_limit(core[0], state) for state in limited if state in states)
        # an end stop may sit on either side of a position; a level fed by a flow has no floor to meet
        stops = tuple(state_limit(core[0], e.state, below=True) for e in ceilings if e.velocity is not None)
        moving = tuple(Friction(state) for state in velocities(core[0]) if state in states)
        return tuple(built) + ceilings + stops + moving
    if isinstance(effects, (str, AbstractEffect)) or isinstance(effects, type):
        effects = [effects]
    items: list = []
    for item in effects:  # "builtins" stands for every built-in, as on the command line
        items += (
            list(resolve_effects(None, simulation))
            if isinstance(item, str) and item == "builtins"
            else [item]
        )
    out = []
    for item in items:
        label = (
            f"effect {item!r}"
            if isinstance(item, str)
            else f"effect {getattr(item, '__name__', type(item).__name__)}"
        )
        if isinstance(item, str) and ":" in item:
            raise InputError(
                f"{label}: a spec file.py:Class is read by the command line's --effects; in Python, import "
                "the class (from the file's module) and pass it, e.g. effects=['builtins', MyEffect]"
            )
        if isinstance(item, str):
            limits = {f"limit_{state}": state for state in states}
            floors = {f"floor_{state}": state for state in states}
            frictions = {f"friction_{state}": state for state in states}
            groups = _groups_of(simulation)
            windows = {f"window_{state}": (state, (state,)) for state in states} | {
                f"window_{group}": (group, tuple(members)) for group, members in groups.items()
            }
            if item in limits:
                item = state_limit(dynamics_of(simulation)[0], limits[item])  # type: ignore[index]
            elif item in floors:
                item = state_limit(dynamics_of(simulation)[0], floors[item], below=True)  # type: ignore[index]
            elif item in frictions:
                item = Friction(frictions[item])
            elif item in windows:
                item = StateWindow(windows[item][0], windows[item][1])
            elif item not in EFFECTS and item not in NAMED_ONLY:
                # one per state: the RC network's 46 of each would bury the line
                names = list(limits) + list(floors) + list(frictions) + list(windows)
                if len(limits) > 3:
                    first, last = states[0], states[-1]
                    names = [
                        f"limit_<state> (limit_{first} … limit_{last})",
                        f"floor_<state> (floor_{first} … floor_{last})",
                        f"friction_<state> (friction_{first} … friction_{last})",
                        f"window_<state> (window_{states[0]} … window_{states[-1]})"
                        + "".join(
                            f", window_{group} (a window on every state of {group})" for group in groups
                        ),
                    ]
                close = difflib.get_close_matches(
                    item, [*EFFECTS, *NAMED_ONLY, *limits, *floors, *frictions, *windows], n=1
                )
                raise InputError(
                    f"unknown effect {item!r}"
                    + (f" (did you mean {close[0]!r}?)" if close else "")
                    + f": the built-ins are {', '.join([*EFFECTS, *NAMED_ONLY, *names])}; "
                    "a plug-in is an AbstractEffect subclass (see docs/effects.md)"
                )
            else:
                item = {**EFFECTS, **NAMED_ONLY}[item]()  # type: ignore[call-arg]  # eqx AbstractVar `raw`
        elif isinstance(item, type):
            if not issubclass(item, AbstractEffect):
                raise InputError(
                    f"{label}: not an AbstractEffect subclass; derive it from hybrid.AbstractEffect"
                )
            if getattr(item, "__abstractmethods__", None):
                missing = ", ".join(sorted(item.__abstractmethods__))
                raise InputError(
                    f"{label}: abstract (it does not define {missing}); define apply(self, s, dt)"
                )
            declared, defaults = getattr(item, "constraints", None), getattr(item, "defaults", None)
            problem = constraint_problem(declared)
            if problem:
                raise InputError(f"{label}: {problem}")
            if isinstance(declared, dict) and isinstance(defaults, dict) and set(declared) - set(defaults):
                # building would fail inside encode, with a message about raw values
                raise InputError(
                    f"{label}: {item.__name__}.defaults has no entry for {sorted(set(declared) - set(defaults))}; "
                    "add them (the start values)"
                )
            if isinstance(declared, dict) and isinstance(defaults, dict) and set(defaults) - set(declared):
                # encode would say the effect 'has no parameter' the author meant to give it
                raise InputError(
                    f"{label}: {item.__name__}.defaults names {sorted(set(defaults) - set(declared))}, which "
                    f"{item.__name__}.constraints lacks; add each parameter to constraints (e.g. "
                    "{'slew_rate': hybrid.Positive()}) or drop it from defaults"
                )
            try:
                item = item()  # type: ignore[call-arg]  # eqx AbstractVar `raw`: no init arg
            except KeyboardInterrupt:
                raise
            except Exception as error:
                raise PluginError(
                    f"{label}: building it with no arguments raised {type(error).__name__}: {error}; "
                    "its defaults are the starting values",
                    error,
                ) from None
        elif not isinstance(item, AbstractEffect):
            raise InputError(f"{label}: give an effect's name, an AbstractEffect subclass or an instance")
        # built-ins are tested
        if type(item) not in (*EFFECTS.values(), *NAMED_ONLY.values(), StateLimit, StateWindow, Friction):
            check_effect(item, label)
        if item.place == "inside":
            _check_inside(item, label, simulation, states)
        out.append(item)
    if not out:
        raise InputError("effects is empty: give at least one effect, or None for the built-ins")
    names = [e.name for e in out]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        plugin = [
            n for n in twice if n in EFFECTS and any(type(e) is not EFFECTS[n] for e in out if e.name == n)
        ]
        raise InputError(
            f"effects named twice: {twice}; give each effect once"
            + (
                f" (a plug-in named like the built-in {plugin[0]!r}: give it a name of its own)"
                if plugin
                else ""
            )
        )
    parameters = [p for e in out for p in e.constraints] + list(FrameTiming.constraints)
    shared = sorted({p for p in parameters if parameters.count(p) > 1})
    if shared:
        raise InputError(
            f"effects share parameter names {shared}: give each effect's parameters their own names"
        )
    return tuple(out)


def state_limit(dynamics, state: str, below: bool = False) -> StateLimit:
    """The built-in limit on `state` of `dynamics` (a state-space form), spilling where it says.

    Where one of its `velocity_states` moves `state` (`_velocity_of`), the limit
    stops it too: an end stop on a position. `below`: a floor (`StateLimit`'s
    `below`), which spills nothing.
    """
    into = None if below else dynamics.spills_into.get(state)
    spill = {} if into is None else {"into": into, "into_unit": dynamics.state_units.get(into, "")}
    return StateLimit(state, velocity=_velocity_of(dynamics, state), below=below, **spill)


def _velocity_of(dynamics, state: str) -> str | None:
    """The state of `velocity_states` that moves `state` (a position's velocity), or None.

    The first whose value the rate of `state` grows with, at rest with the
    simulation's own parameters (∂ẋ/∂v > 0): a mass's velocity for its
    position, `LTI(N)`'s band-pass state for its low-pass (ṗ = ω·q). A level
    fed by a flow has none.
    """
    moving = [v for v in velocities(dynamics) if v != state and v in dynamics.states]
    if not moving:
        return None
    p = dynamics.prepare(dynamics.parameters())
    dtype = jnp.result_type(*jax.tree_util.tree_leaves(dynamics.raw))
    rest = tuple(jnp.zeros((), dtype) for _ in dynamics.states)
    k = dynamics.states.index(state)
    slopes = jax.grad(lambda x: dynamics.rates(x, jnp.zeros((), dtype), p)[k])(rest)
    for v in moving:
        if float(slopes[dynamics.states.index(v)]) > 0.0:
            return v
    return None


def _states_of(simulation) -> tuple[str, ...]:
    """The states of `simulation` (a state-space form, checked), or () where it has none."""
    dynamics = None if simulation is None else dynamics_of(simulation)
    if dynamics is None:
        return ()
    check_state_space(dynamics[0], f"simulation {type(dynamics[0]).__name__}")
    return tuple(dynamics[0].states)


def _groups_of(simulation) -> dict[str, tuple[str, ...]]:
    """The state groups of `simulation`'s state-space form (`AbstractStateSpace.state_groups`), or {}."""
    dynamics = None if simulation is None else dynamics_of(simulation)
    return {} if dynamics is None else dict(dynamics[0].state_groups)


def _check_inside(effect: AbstractEffect, label: str, simulation, states) -> None:
    """An inside effect needs a simulation with states, and a state (or the output) it can act on."""
    if simulation is None:
        return  # checked again when diagnose resolves the effects with its simulation
    if not states:
        raise InputError(
            f"{label} acts inside the dynamics, but {type(simulation).__name__} has no state-space form: "
            "derive the simulation from hybrid.AbstractStateSpace (see docs/plugins.md), or drop the effect"
        )
    for what, state in (
        ("acts on", effect.acts_on),
        *(("acts on", s) for s in (effect.bounded_states[1:] if effect.role == "limit" else ())),
        ("spills into", getattr(effect, "into", None)),
        ("stops the velocity", getattr(effect, "velocity", None)),
    ):
        if state not in (None, "output") and state not in states:
            raise InputError(
                f"{label} {what} the state {state!r}, which {type(simulation).__name__} does not have: "
                f"its states are {', '.join(states)}"
            )


def searched_places(effects, simulation) -> dict[str, dict]:
    """Each place (`PLACES`): the effects searched there, and why none was where that is known."""
    dynamics = dynamics_of(simulation)
    out = {}
    for place in PLACES:
        names = [e.name for e in effects if e.place == place]
        why = None
        if not names and place == "inside" and dynamics is None:
            core = getattr(simulation, "inner", simulation)  # a HeldStart's simulation, not the wrapper
            why = (
                f"{type(core).__name__} has no state-space form (hybrid.AbstractStateSpace), "
                "so no effect inside its dynamics was searched"
            )
        elif not names and place == "inside" and dynamics is not None and dynamics[0].not_searched_inside:
            why = f"not by default for {type(dynamics[0]).__name__}: {dynamics[0].not_searched_inside}"
        elif not names:
            why = "no effect given acts here"
        out[place] = {"effects": names, "not_searched": why}
        groups = _groups_of(simulation) if place == "inside" else {}
        if groups:  # the windows on its groups of states not searched, which a remainder's hint may name
            out[place]["windows"] = [f"window_{g}" for g in groups if f"window_{g}" not in names]
    return out
