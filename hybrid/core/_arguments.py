"""Checks on the library's arguments: a wrong type is an InputError that says what to pass.

The public entry points (`fit`, `fit_batch`, `diagnose`, `simulate`, …) call
these first, so that a path where a Recording belongs, a string where a set of
names belongs, or a negative time step ends in one
[`InputError`][hybrid.InputError] line instead of a raw TypeError or
AttributeError deep inside, or a silently wrong answer.

Checks on values (finite drive, positive dt) run only on concrete values:
inside `jax.jit`, `jax.vmap` or `jax.grad` the arguments are tracers whose
values are unknown, and they are passed through untouched.
"""

from __future__ import annotations

import math
import numbers
import os
from collections.abc import Iterable

import equinox as eqx
import jax
import numpy as np

from ..util._errors import InputError

__all__ = [
    "as_names",
    "as_recordings",
    "check_drive",
    "check_model",
    "check_seed",
    "is_tracer",
    "require_float64",
    "run_compiled",
]

#: What a script that left jax's float64 off is told to do (the library never changes `jax.config`).
FLOAT64_FIX = (
    "call jax.config.update('jax_enable_x64', True) at the start of your script, before any JAX array "
    "is made (the command line does)"
)


def require_float64(where: str, why: str) -> None:
    """An InputError unless jax's float64 is on (``jax_enable_x64``); `why`: what needs it."""
    if not jax.config.read("jax_enable_x64"):
        raise InputError(f"{where} needs float64 ({why}), and jax's float64 is off: {FLOAT64_FIX}")


def is_tracer(x) -> bool:
    """True inside `jit`/`vmap`/`grad`, where `x`'s value is not known."""
    return isinstance(x, jax.core.Tracer)


def run_compiled(function, *args):
    """`function(*args)`, compiled once per structure and shapes when called op by op.

    Called outside `jit`, a `lax.scan` or `lax.cond` compiles its body afresh
    at every call (its closure is new each time): ~0.03–0.3 s each, and a
    simulation's `simulate`, called op by op on a recording, compiled a dozen
    such programs every time (a whole test suite spent ~300 s of its 870 s of
    compiling on them). Here it is one program, cached by the arguments'
    structure (`function` a module-level function, floats and other non-arrays
    static, arrays by shape and dtype). Inside a trace (`jit`, `vmap`, `grad`)
    `function` is called as it is: the enclosing program compiles it. A
    function that cannot be traced (a plug-in's Python `if` on a value) runs op
    by op, as it would without this.
    """
    if any(is_tracer(leaf) for leaf in jax.tree_util.tree_leaves(args)):
        return function(*args)
    try:
        return _compiled_call(function, *args)
    except jax.errors.JAXTypeError:  # not traceable: op by op (where its own error, if any, shows)
        return function(*args)


@eqx.filter_jit
def _compiled_call(function, *args):
    return function(*args)


def simulated(simulation, v_in, dt):
    """`simulation.simulate(v_in, dt)` through `run_compiled`: once per structure and length op by op.

    The library's simulations compile their own; a plug-in's `simulate` that
    scans a step defined inside it compiled that scan afresh at every call from
    `fit`'s predictions and a model's `predict` (a probe's loop of fits of one
    length: 14 programs and 20 MB a fit).
    """
    return run_compiled(_simulate, simulation, v_in, dt)


def _simulate(simulation, v_in, dt):
    return simulation.simulate(v_in, dt)


def check_model(model, where: str):
    """`model` must be a [`hybrid.Model`][] (from `make_model`, `load_model` or a fit)."""
    from ._models import Model

    if not isinstance(model, Model):
        raise InputError(
            f"{where} needs a hybrid.Model as its model, got {type(model).__name__} {model!r:.60}: "
            "build one with hybrid.make_model(...) or hybrid.load_model(path)"
        )
    return model


def check_simulation(simulation, where: str, allow_none: bool = True):
    """`simulation` must be an `AbstractSimulation` (e.g. `RCNetwork()`), or None where a default exists.

    (`hybrid.diagnose` and `hybrid.make_model` resolve a ``--physics`` spec string before this check.)
    """
    from ._simulation import AbstractSimulation

    if simulation is None and allow_none:
        return None
    if not isinstance(simulation, AbstractSimulation):
        raise InputError(
            f"{where} needs a simulation such as hybrid.RCNetwork(), or a --physics spec such as 'lti:2' "
            f"or 'file.py:Class', got {type(simulation).__name__} {simulation!r:.60}"
        )
    return simulation


def as_recordings(recordings, where: str) -> list:
    """One or several recordings as a list; a file path is loaded with `Recording.load`.

    Anything else (a number, a dict, an array) is an InputError that says to pass
    Recording objects.
    """
    from ..data._recording import Recording

    items = list(recordings) if isinstance(recordings, (list, tuple)) else [recordings]
    out = []
    for i, item in enumerate(items):
        if isinstance(item, Recording):
            out.append(item)
        elif isinstance(item, (str, os.PathLike)):
            out.append(Recording.load(item))
        else:
            which = "" if len(items) == 1 else f" (item {i})"
            raise InputError(
                f"{where} needs Recording objects or file paths, got {type(item).__name__}{which}: "
                "load files with hybrid.Recording.load(path) or build one with Recording.from_arrays(...)"
            )
    if not out:
        raise InputError(f"{where} got no recordings: pass at least one Recording")
    return out


def as_names(names, where: str, what: str = "frozen", valid: Iterable[str] | None = None) -> frozenset[str]:
    """Parameter names as a frozenset: one string is one name (not its letters).

    `valid`, when given, are the names allowed: any other is an InputError that lists them.
    """
    if isinstance(names, str):
        names = (names,)
    elif names is None:
        names = ()
    elif not isinstance(names, Iterable) or isinstance(names, (bytes, dict)):
        raise InputError(
            f"{where}: {what} must be a parameter name or a set of names such as {{'xi_h'}}, "
            f"got {type(names).__name__} {names!r:.60}"
        )
    names = tuple(names)
    bad = [n for n in names if not isinstance(n, str)]
    if bad:
        raise InputError(f"{where}: {what} must hold parameter names (strings), got {bad[0]!r}")
    if valid is not None:
        valid = list(valid)
        unknown = sorted(set(names) - set(valid))
        if unknown:
            raise InputError(f"{where}: unknown {what} name(s) {unknown}: valid names are {valid}")
    return frozenset(names)


def check_seed(seed, where: str) -> int:
    """A seed is a non-negative integer."""
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or seed < 0:
        raise InputError(f"{where}: seed must be a non-negative integer, got {seed!r}")
    return int(seed)


def check_dt(dt, where: str):
    """The sample interval as a float: a finite positive number of seconds (a tracer passes unchecked)."""
    if is_tracer(dt):
        return dt
    if isinstance(dt, (bool, str, bytes)) or dt is None:
        raise InputError(f"{where}: dt must be the sample interval in seconds (a number), got {dt!r}")
    try:
        value = float(dt)
    except (TypeError, ValueError):
        raise InputError(
            f"{where}: dt must be one number (seconds), got {type(dt).__name__} {dt!r:.60}"
        ) from None
    if not (math.isfinite(value) and value > 0):
        raise InputError(f"{where}: dt must be a finite positive number of seconds, got {value!r}")
    return value


def check_drive(v_in, dt, where: str):
    """`v_in` (V, shape (T,)) and `dt` (s) of a simulation; returns them (v_in as a JAX array).

    Concrete values must be real, finite and one-dimensional, and dt positive:
    an error names the first bad sample. Tracers pass through unchecked.
    """
    import jax.numpy as jnp

    dt = check_dt(dt, where)
    if is_tracer(v_in):
        return v_in, dt
    if isinstance(v_in, (str, bytes)) or v_in is None:
        raise InputError(f"{where}: v_in must be the drive voltage as an array of numbers, got {v_in!r:.60}")
    try:
        array = np.asarray(v_in)
    except (TypeError, ValueError) as error:
        raise InputError(f"{where}: v_in must be an array of numbers ({error})") from None
    if array.dtype.kind not in "biuf":
        raise InputError(f"{where}: v_in must hold real numbers, got dtype {array.dtype}")
    if array.ndim != 1:
        raise InputError(f"{where}: v_in must have shape (T,), one value per sample, got {array.shape}")
    bad = np.flatnonzero(~np.isfinite(array))
    if bad.size:
        raise InputError(
            f"{where}: v_in has {bad.size} non-finite value(s), the first at sample {int(bad[0])}: "
            "remove or interpolate them"
        )
    return jnp.asarray(v_in), dt


def check_key(key, where: str):
    """A JAX PRNG key (``jax.random.key(0)``, or a legacy ``jax.random.PRNGKey(0)``), or None."""
    if key is None or is_tracer(key):
        return key
    import jax.numpy as jnp

    if isinstance(key, jax.Array):
        if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
            return key
        if key.dtype == jnp.uint32 and key.shape == (2,):
            return key
    raise InputError(
        f"{where}: key must be a JAX PRNG key such as jax.random.key(0), got {type(key).__name__} {key!r:.60}"
    )
