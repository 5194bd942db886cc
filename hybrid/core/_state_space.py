"""Simulations in state-space form: ẋ = f(x, u), y = g(x); `simulate` follows by fixed-step RK4.

A physics plug-in that states its dynamics as rates of named states (rather
than a whole `simulate`) gets three things: `simulate` for free; effects that act
*inside* the dynamics (`diagnose` can then name a nonlinearity fed back into the
drive, such as a cubic spring, or a limit on a state, such as an overflowing
tank); and its states by name for inspection (`AbstractStateSpace.trajectory`).

    class Lag(hybrid.AbstractStateSpace):
        states: ClassVar = ("level",)
        ...
        def rates(self, x, u, p):
            return ((u - x[0]) / p["tau"],)

A simulation whose rates are linear may also give its matrices
(`linear_matrices`): it is then stepped exactly (the matrix exponential of a
substep), however stiff, and only a force fed back from an effect is
approximated (held over a substep at the mean of its end values). `LTI` does.
A linear simulation whose `simulate` is a particular discretisation (a
bilinear/Tustin filter) gives that one (`discrete_matrices`), so that its
state-space form and its `simulate` are one model: the RC network does.

Integration: `substeps` classical RK4 steps per sample in one `lax.scan`, the
drive held over each sample (``drive_between_samples = "hold"``: a
zero-order-hold DAC, a pump switched per sample) or moving linearly to the next
sample (``"linear"``: a measured, band-limited drive). Fixed steps, not an
adaptive diffrax solver, for the reasons `examples/two_tank.py` gives: forward-
and reverse-mode autodiff both work (LM linearises the simulation; diffrax's
default adjoint refuses `jax.linearize`), and a fit sees a smooth function of
its parameters. RK4 is stable while a step is shorter than ~2.8 of the fastest
time constant: raise `substeps` for stiff physics.

Sample k's output is read from the state at the sample's time, before the step
to the next sample: y[k] = g(x(t_k)), with x(t_0) = `initial_state`. After each
RK4 step the simulation's own `walls` (a rim it models, say) and then the
effects' limits act on the state (`integrate`'s `bound`).
"""

from __future__ import annotations

import abc
from collections.abc import Callable
from typing import ClassVar, TypeGuard

import jax
import jax.numpy as jnp
from jax import lax
from jaxtyping import Array, Float

from ..data._header_units import speed_unit
from ..util._errors import InputError
from ._arguments import check_drive, run_compiled
from ._loop_safe_linalg import zoh_discretise
from ._simulation import AbstractSimulation

#: How the drive moves between two samples.
DRIVE_FORMS = ("hold", "linear")


class AbstractStateSpace(AbstractSimulation):
    """A simulation stated as rates of named states: ẋ = `rates`(x, u), y = `observe`(x).

    A subclass states, besides a simulation's facts (constraints, units, …):

    - `states` (required): the states' names, in the order of x;
    - `state_units`: each state's unit, ``{drive}`` standing for the drive's
      (default: none stated);
    - `limited_states`: the states a wall could limit (a level that can
      overflow, a position with an end stop), where `diagnose` searches a limit
      by default (None, the default: every state);
    - `velocity_states`: the states that are velocities (a mass's, a shaft's
      speed), where `diagnose` searches a dry friction by default
      (``friction_<state>``; default: the states whose `state_units` are a
      speed, m/s or rad/s, `velocities`);
    - `state_groups`: states alike enough that one limit of either sign bounds them
      all, by the group's name (the RC network's ``{"vc": ("vc_0", …, "vc_45")}``:
      every compartment's double-layer voltage, under one electrolyte's
      window); ``window_<group>`` names that limit (`StateWindow`), as
      ``window_<state>`` names one on a single state (default: none);
    - `spills_into`: where what a limit cuts off a state would go, by state
      (``{"h1": "h2"}``: water over the upper tank's rim falls into the lower
      tank); `diagnose`'s limit on such a state moves a fitted share of the
      cut there (default: none, the cut is lost);
    - `rates(x, u, p)` (required): dx/dt, a tuple of scalars in the order of
      `states`, for the state x (a tuple of scalars, one per state), the drive
      u (a scalar) and the decoded parameters p;
    - `prepare(p)`: what the rates read, computed once per run from the
      decoded parameters (default: the parameters themselves);
    - `observe(x, p)`: the output (default: the first state);
    - `initial_state(u0, p)`: x at the first sample (a tuple), given the first
      drive value (default: all zero, at rest);
    - `walls(x, p)`: the state (a tuple) after the simulation's own walls act
      on it after each step (default: unchanged);

    The state is a tuple of scalars, not an array: inside the integration loop
    of a few thousand samples, XLA on a CPU runs scalar arithmetic far faster
    than the stacking and slicing of small arrays (a 2-state oscillator: 20×).
    - `substeps` (default 4) and `drive_between_samples` (``"hold"`` or ``"linear"``).
    """

    states: ClassVar[tuple[str, ...]]
    limited_states: ClassVar[tuple[str, ...] | None] = None
    velocity_states: ClassVar[tuple[str, ...]] = ()
    spills_into: ClassVar[dict[str, str]] = {}
    state_groups: ClassVar[dict[str, tuple[str, ...]]] = {}
    #: Why `diagnose`'s default set leaves out the effects inside these dynamics (None: it searches them);
    #: they are searched when named (``effects=``, ``--effects``).
    not_searched_inside: ClassVar[str | None] = None
    substeps: ClassVar[int] = 4
    drive_between_samples: ClassVar[str] = "hold"
    #: The unit of a force fed back from an effect inside the dynamics (`forced_rates`): ``"{drive}"``
    #: (default) where it is taken off the drive; a plug-in that puts it elsewhere says its unit (``"W"``).
    force_unit: ClassVar[str] = "{drive}"

    @property
    def state_units(self) -> dict[str, str]:
        """Unit of each state, by name; ``"{drive}"`` stands for the drive's unit (default: none stated)."""
        return {}

    @abc.abstractmethod
    def rates(self, x: tuple, u, p: dict) -> tuple:
        """dx/dt (a tuple of scalars) at the state `x` under the drive `u` (scalar), with the parameters `p`."""

    def forced_rates(self, x: tuple, u, force, p: dict) -> tuple:
        """dx/dt with a force fed back from an effect inside the dynamics (default: taken off the drive).

        ``rates(x, u − force, p)``: a cubic spring, a friction, a loss acts
        where the drive does, in the drive's unit. Where the drive enters
        nonlinearly (a heater's power u²/R, a valve's flow), a loss cannot be
        taken off it (at u = 0, (u − φ)²/R heats): override this to put the
        force where one acts (``((u**2 / p["r"] - force - p["h"] * (x[0] - p["ambient"])) / p["c"],)``),
        and say its unit (`force_unit`) and the force the drive itself exerts
        (`drive_force`, which a force's size is measured against). With it
        overridden, a force is integrated by RK4 (`linear_matrices` and
        `discrete_matrices` carry forces through the drive).
        """
        return self.rates(x, u - force, p)

    def drive_force(self, u, p: dict):
        """The force the drive `u` exerts, in `force_unit` (default: `u`): the scale a fed-back force is sized against."""
        return u

    def prepare(self, p: dict) -> dict:
        """What `rates` reads, from the decoded parameters, computed once per run (default: `p`).

        Coefficients derived from the parameters (ω², 2ζω) computed here are not
        recomputed at every RK4 stage of every sample.
        """
        return p

    def observe(self, x: tuple, p: dict):
        """The output at the state `x` (default: the first state)."""
        return x[0]

    def initial_state(self, u0, p: dict) -> tuple:
        """The state at the first sample, given the first drive value `u0` (default: zero)."""
        return tuple(jnp.zeros((), jnp.result_type(u0, float)) for _ in self.states)

    def walls(self, x: tuple, p: dict) -> tuple:
        """The state after the simulation's own walls act on it (default: unchanged)."""
        return x

    def linear_matrices(self, p: dict) -> tuple[Array, Array] | None:
        """(A, B) where the rates are linear, ẋ = A x + B u (default None: they are not).

        `p` is what `prepare` returned. A linear simulation that gives them is
        integrated exactly between force updates (a zero-order hold of the drive
        over each substep, e^{Ah}), so stiff linear dynamics (time constants far
        below the sample interval) need no small steps; a force fed back from
        an effect is held over a substep at the mean of its values at the
        substep's two ends (Heun's rule: second order in the substep).
        """
        return None

    def discrete_matrices(self, p: dict, dt) -> tuple[Array, Array, Array] | None:
        """(Φ, Γ₀, Γ₁) of a linear simulation stepped once per sample (default None: not given).

        x_{k+1} = Φ x_k + Γ₀ v_k + Γ₁ v_{k+1}, y_k = observe(x_k) + D v_k, with v
        the drive less a fed-back force: Γ₁ = 0 for a zero-order hold, Γ₀ = Γ₁
        for the trapezoidal rule (a bilinear, Tustin, filter). Given, it
        replaces the substeps (`linear_matrices`, RK4); the state before the
        first sample is at rest with no drive, so x_0 = Γ₁ v_0 (a digital
        filter's start; `initial_state` is not used). A fed-back force at the
        next sample is predicted at the state the step reaches with the
        current force held (Heun's rule). `p` is what `prepare` returned.
        """
        return None

    def feedthrough(self, p: dict):
        """D where the output has a direct part, y = observe(x) + D·(drive − force) (default 0).

        A force fed back from the output reads observe(x), the state's part: the
        direct part would make the loop algebraic.
        """
        return 0.0

    def simulate(self, v_in: Float[Array, " time"], dt: float) -> Float[Array, " time"]:
        """The output at each sample time for the drive `v_in` sampled every `dt` seconds."""
        v_in, dt = check_drive(v_in, dt, f"{type(self).__name__}.simulate")
        return run_compiled(_output, self, v_in, dt)

    def trajectory(self, v_in: Float[Array, " time"], dt: float) -> dict[str, Float[Array, " time"]]:
        """Every state at each sample time, by name."""
        v_in, dt = check_drive(v_in, dt, f"{type(self).__name__}.trajectory")
        xs = run_compiled(_states, self, v_in, dt)
        return {name: xs[:, i] for i, name in enumerate(self.states)}


class AbstractLinearStateSpace(AbstractStateSpace):
    """A state-space form with linear rates, ẋ = A x + B u, y = C x + D u, from its matrices.

    A subclass gives `realisation(p)`, (A, B, C, D) from the decoded
    parameters; `prepare` computes it once per run, and the rates, the output,
    `linear_matrices` and `feedthrough` follow, so the form is stepped exactly
    (or by the subclass's own `discrete_matrices`). `LTI` and the RC network are.
    """

    @abc.abstractmethod
    def realisation(self, p: dict) -> tuple[Array, Array, Array, Array]:
        """(A, B, C, D) for the decoded parameters `p`."""

    def prepare(self, p: dict) -> dict:
        return dict(zip("ABCD", self.realisation(p)))

    def state_space(self) -> tuple[Array, Array, Array, Array]:
        """The continuous realisation (A, B, C, D) at this simulation's own parameters."""
        return self.realisation(self.parameters())

    def rates(self, x: tuple, u, p: dict) -> tuple:
        return tuple(p["A"] @ jnp.stack(x) + p["B"] * u)

    def observe(self, x: tuple, p: dict):
        return p["C"] @ jnp.stack(x)

    def linear_matrices(self, p: dict):
        return p["A"], p["B"]

    def feedthrough(self, p: dict):
        return p["D"]


def has_states(simulation) -> TypeGuard[AbstractStateSpace]:
    """Whether `simulation` is in the state-space form that effects inside the dynamics need."""
    return isinstance(simulation, AbstractStateSpace)


def dynamics_of(simulation) -> tuple[AbstractStateSpace, Callable, int] | None:
    """(the state-space simulation that runs, the drive it runs on, the samples to drop), or None.

    `simulation` itself where it is in state-space form; the inner simulation of
    a `HeldStart` (a record that starts where a held drive left the system) with
    its held drive before the record and those samples dropped after, so that an
    effect inside the dynamics (an overflow) acts while the system settles too.
    None where there is no state-space form underneath.
    """
    from ._held_start import HeldStart

    if has_states(simulation):
        return simulation, lambda u: u, 0
    if isinstance(simulation, HeldStart) and has_states(simulation.inner):
        return simulation.inner, simulation.held_drive, simulation.settle_samples
    return None


def velocities(simulation: AbstractStateSpace) -> tuple[str, ...]:
    """The states that are velocities: its `velocity_states`, or where it names none, those whose
    `state_units` are a speed (m/s, rad/s, °/s, rpm).

    A probe's cart (one state, speed in m/s) declared no `velocity_states`: its Coulomb friction, not
    searched, was named a drive-side dead zone and a nonlinear damping; the built-in friction on the
    speed, named, gained 37×.
    """
    if simulation.velocity_states:
        return tuple(simulation.velocity_states)
    try:
        units = dict(simulation.state_units)
    except Exception:  # a plug-in's property that fails: no unit stated
        return ()
    return tuple(state for state in simulation.states if speed_unit(str(units.get(state) or "")))


def check_state_space(simulation: AbstractStateSpace, label: str) -> None:
    """Refuse, in one line that says the fix, a state-space form `integrate` cannot run."""
    cls = type(simulation).__name__
    states = getattr(simulation, "states", None)
    if (
        not isinstance(states, tuple)
        or not states
        or not all(isinstance(s, str) and s.isidentifier() for s in states)
    ):
        raise InputError(
            f"{label}: {cls}.states must be a non-empty tuple of state names (identifiers), got {states!r}; "
            "e.g. states: ClassVar = ('position', 'velocity')"
        )
    if len(set(states)) != len(states):
        raise InputError(f"{label}: {cls}.states names a state twice: {states}")
    limited = simulation.limited_states
    if limited is not None and (not isinstance(limited, tuple) or not set(limited) <= set(states)):
        raise InputError(
            f"{label}: {cls}.limited_states must be None or a tuple of its states ({', '.join(states)}), "
            f"got {limited!r}"
        )
    moving = simulation.velocity_states
    if not isinstance(moving, tuple) or not set(moving) <= set(states):
        raise InputError(
            f"{label}: {cls}.velocity_states must be a tuple of its states ({', '.join(states)}), got {moving!r}"
        )
    spills = simulation.spills_into
    if not isinstance(spills, dict) or any(
        a not in states or b not in states or a == b for a, b in spills.items()
    ):
        raise InputError(
            f"{label}: {cls}.spills_into must map a state to another of its states ({', '.join(states)}), "
            f"got {spills!r}; e.g. {{'h1': 'h2'}}"
        )
    if not isinstance(simulation.substeps, int) or simulation.substeps < 1:
        raise InputError(f"{label}: {cls}.substeps must be a whole number ≥ 1, got {simulation.substeps!r}")
    if simulation.drive_between_samples not in DRIVE_FORMS:
        raise InputError(
            f"{label}: {cls}.drive_between_samples must be one of {', '.join(DRIVE_FORMS)}, "
            f"got {simulation.drive_between_samples!r}"
        )


def _output(simulation, v_in, dt):
    return integrate(simulation, v_in, dt)[0]


def _states(simulation, v_in, dt):
    return integrate(simulation, v_in, dt)[1]


def own_forces(simulation) -> bool:
    """Whether `simulation` puts a fed-back force where it acts itself (`AbstractStateSpace.forced_rates`)."""
    return type(simulation).forced_rates is not AbstractStateSpace.forced_rates


def integrate(
    simulation: AbstractStateSpace,
    v_in: Float[Array, " time"],
    dt: float,
    force: Callable | None = None,
    bound: Callable | None = None,
    external: Float[Array, " time"] | None = None,
) -> tuple[Float[Array, " time"], Float[Array, "time states"]]:
    """(output, states) at each sample time: `simulation`'s rates integrated by RK4.

    - `force(x, y)`: a force fed back from the state (y = observe(x)), where
      the rates are evaluated: taken off the drive, or where the simulation's
      `forced_rates` puts it;
    - `bound(x)`: the state (a tuple) after a limit acts on it, after every
      step (and on the initial state);
    - `external`: a force signal beside it (held over each sample), as
      `force`'s (the remainder's force responses).

    The states come back as an array, one column per state.
    """
    if external is not None and not own_forces(simulation):  # taken off the drive: as it always was
        v_in, external = jnp.asarray(v_in) - external, None
    v_in, dt = check_drive(v_in, dt, f"{type(simulation).__name__}.simulate")
    p = simulation.prepare(simulation.parameters())
    dtype = jnp.result_type(v_in, *jax.tree_util.tree_leaves(p))
    u = jnp.asarray(v_in, dtype)
    ahead = jnp.concatenate([u[1:], u[-1:]])  # the next sample's drive (the last one repeated)
    u_next = ahead if simulation.drive_between_samples == "linear" else u
    n = simulation.substeps
    h = dt / n

    def pushed(x):
        return jnp.zeros((), dtype) if force is None else force(x, simulation.observe(x, p))

    own = own_forces(simulation) and (force is not None or external is not None)
    ext = jnp.zeros_like(u) if external is None else jnp.asarray(external, dtype)

    def rates(x, drive, e=0.0):
        if own:  # the simulation puts the force where it acts
            return tuple(simulation.forced_rates(x, drive, pushed(x) + e, p))
        return tuple(simulation.rates(x, drive - pushed(x), p))

    def settle(x):
        x = tuple(simulation.walls(x, p))
        return x if bound is None else tuple(bound(x))

    def axpy(x, a, k):
        return tuple(xi + a * ki for xi, ki in zip(x, k))

    def rk4(x, f0, fm, f1, e=0.0):
        k1 = rates(x, f0, e)
        k2 = rates(axpy(x, 0.5 * h, k1), fm, e)
        k3 = rates(axpy(x, 0.5 * h, k2), fm, e)
        k4 = rates(axpy(x, h, k3), f1, e)
        return tuple(
            xi + (h / 6.0) * (a1 + 2.0 * a2 + 2.0 * a3 + a4) for xi, a1, a2, a3, a4 in zip(x, k1, k2, k3, k4)
        )

    linear = None if own else simulation.linear_matrices(p)
    if linear is not None:
        phi, gamma = zoh_discretise(jnp.asarray(linear[0], dtype), jnp.asarray(linear[1], dtype), h)

        def exact(x, drive):
            return tuple(phi @ jnp.stack(x) + gamma * drive)

        def advance(x, f0, fm, f1, e=0.0):
            if force is None:
                return exact(x, fm)
            first = pushed(x)
            return exact(x, fm - 0.5 * (first + pushed(exact(x, fm - first))))
    else:
        advance = rk4

    direct = simulation.feedthrough(p)
    has_direct = not (isinstance(direct, float) and direct == 0.0)
    discrete = None if own else simulation.discrete_matrices(p, dt)
    if discrete is not None:
        phi, now, nxt = (jnp.asarray(m, dtype) for m in discrete)
        return _step_discrete(simulation, p, (phi, now, nxt, direct, has_direct), u, ahead, force, bound)

    def sample(x, pair):
        a, b, e = pair
        x_k = x
        y_k = simulation.observe(x_k, p)
        if has_direct:  # the direct part sees the drive less a force taken off it (not one put elsewhere)
            y_k = y_k + direct * (a if own else a - pushed(x_k))
        for j in range(n):  # unrolled: no loop nested in the scan
            f0, fm, f1 = (a + (b - a) * (t / n) for t in (j, j + 0.5, j + 1))
            x = settle(advance(x, f0, fm, f1, e))
        return x, (y_k, x_k)

    x0 = settle(tuple(jnp.asarray(xi, dtype) for xi in simulation.initial_state(u[0], p)))
    _, (y, xs) = lax.scan(sample, x0, (u, u_next, ext))
    return y, jnp.stack(xs, axis=1)


def _step_discrete(simulation, p, matrices, u, ahead, force, bound):
    """`integrate` for a simulation that gives its `discrete_matrices`: one step per sample.

    The state is carried as one array (one matrix-vector product a step: the
    RC network has 46 states), split into a tuple only where the simulation's
    or an effect's code reads it (`observe`, a force, a wall, a limit).
    """
    phi, now, nxt, direct, has_direct = matrices
    n = phi.shape[0]
    walls = type(simulation).walls is not AbstractStateSpace.walls

    def split(x):
        return tuple(x[i] for i in range(n))

    def pushed(x):
        return force(split(x), simulation.observe(split(x), p))

    def settle(x):
        if not walls and bound is None:
            return x
        x = tuple(simulation.walls(split(x), p))
        return jnp.stack(x if bound is None else tuple(bound(x)))

    def sample(x, pair):
        a, b = pair
        y_k = simulation.observe(split(x), p)
        f_k = jnp.zeros((), x.dtype) if force is None else force(split(x), y_k)
        if has_direct:
            y_k = y_k + direct * (a - f_k)
        base = phi @ x + now * (a - f_k)
        if force is None:
            x_next = base + nxt * b
        else:  # the next sample's force predicted at the state reached with this one held (Heun)
            x_next = base + nxt * (b - pushed(base + nxt * (b - f_k)))
        return settle(x_next), (y_k, x)

    # from rest before the record: x_0 = Γ₁ v_0, the force at sample 0 predicted as in a step
    first = nxt * u[0]
    x0 = settle(first if force is None else nxt * (u[0] - pushed(first)))
    _, (y, xs) = lax.scan(sample, x0, (u, ahead))
    return y, xs
