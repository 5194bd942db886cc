"""Which physics: the command line's `--physics SPEC` turned into a simulation.

- ``rc``: the paper's distributed RC network ([`RCNetwork`][hybrid.RCNetwork], defaults: Tustin
  sections, Table 1's strip), the physics of `hybrid fit` and `hybrid sensitivity` by default;
- ``rc:zoh``: the same network discretised exactly for a drive held between samples, C_clamp at
  `ZOH_C_CLAMP` (``RCNetwork(method="zoh", C_clamp=0.03)``), the physics of `hybrid diagnose` by default;
- ``lti:N``: a stable linear system of order N ([`LTI`][hybrid.LTI], 1 ≤ N ≤ 20);
- ``path/to/file.py:ClassName``: a class defined in a Python file (imported
  under a module name made from the file's absolute path, kept in
  `sys.modules` so that `load_model` finds the class again: resolve the same
  spec before loading a model saved with it);
- ``package.module:ClassName``: a class in an importable module.

The class must subclass [`AbstractSimulation`][hybrid.AbstractSimulation] and
build with no arguments (its defaults are the starting values). Every failure
is one [`InputError`][hybrid.InputError] that says what is wrong and how to fix it.

A plug-in is checked once, eagerly, before anything is compiled: its
``simulate`` runs on a short probe drive (the first samples of the recording,
or a step) and must return one finite floating-point value per sample, and it
must trace under `jax.jit` to the same shape (`PluginError` names the
class, the method and what was wrong). The compiled hot path is left as it is:
a failure that only shows later (at run time, under `jit`, `vmap` or autodiff)
is attributed by `describe_failure` from the exception's traceback, which
runs through the plug-in's own code, so the command line still names the
plug-in and its method in one line (exit status 2).

A plug-in is code that runs with the user's rights: ``sys.exit`` and
``KeyboardInterrupt`` raised by it are caught and reported, and
`exit_guard` turns ``os._exit`` in the main thread into an exception while
a command runs; an exit that bypasses Python (``posix._exit``, a signal)
cannot be caught in-process.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib
import importlib.util
import inspect
import os
import re
import sys
import threading
import traceback
from pathlib import Path

import numpy as np

from ..core._arguments import as_recordings
from ..core._parameters import constraint_problem
from ..core._simulation import AbstractSimulation
from ..core._state_space import check_state_space, has_states
from ..util._errors import InputError, PluginError
from ._lti import LTI, MAX_ORDER
from ._lti_start import lti_for_recordings
from ._rc_network import RCNetwork

__all__ = ["HardExit", "PluginError", "describe_failure", "exit_guard", "probe_simulation", "resolve_physics"]

FORMS = "rc, rc:zoh, lti:N, path/to/file.py:ClassName or package.module:ClassName"
#: C_clamp (F) of ``rc:zoh``: 30 mF, the virtual IPMC's total double-layer capacitance, the first point of
#: diagnose's screened design and its centre since the discrepancy experiments were run.
ZOH_C_CLAMP = 0.03
#: Samples of the probe drive a plug-in's `simulate` is checked on before any compilation.
PROBE_SAMPLES = 32
#: Where the user is sent for the whole story of a failure.
TRACEBACK_HINT = "add -v to see the traceback"

# Module name -> (the --physics spec, the parameter names) of every plug-in resolved in this process:
# a traceback through one of these modules' code is that plug-in's failure (describe_failure).
_SOURCES: dict[str, tuple[str, tuple[str, ...]]] = {}


class HardExit(BaseException):
    """``os._exit(status)`` called in the main thread while `exit_guard` is active."""

    def __init__(self, status):
        super().__init__(status)
        self.status = status

    def __str__(self) -> str:
        return f"os._exit({self.status!r})"


@contextlib.contextmanager
def exit_guard():
    """While active, ``os._exit`` called in this process's main thread raises `HardExit` instead.

    Nothing of this package calls ``os._exit`` in the main thread (the
    watchdog calls it from its own thread, and a forked child has another
    pid: both still exit), so a plug-in that does is caught and reported
    instead of ending the command with its status, in silence. Code that
    bypasses ``os._exit`` (``posix._exit``, ``os.kill``) cannot be caught.
    """
    real = os._exit
    pid, main = os.getpid(), threading.main_thread()

    def guarded(status):
        if os.getpid() == pid and threading.current_thread() is main:
            raise HardExit(status)
        real(status)

    os._exit = guarded
    try:
        yield
    finally:
        os._exit = real


def _first_line(error: BaseException) -> str:
    text = next((line.strip() for line in str(error).splitlines() if line.strip()), "")
    return text if len(text) <= 300 else text[:297] + "..."


def _what(error: BaseException) -> str:
    """What the plug-in did: 'raised KeyError: 'gain'', 'called sys.exit(0)', ..."""
    if isinstance(error, SystemExit):
        return f"called sys.exit({error.code!r})"
    if isinstance(error, HardExit):
        return f"called os._exit({error.status!r})"
    if isinstance(error, KeyboardInterrupt):
        return "raised KeyboardInterrupt (not a Ctrl-C)"
    text = _first_line(error)
    return f"raised {type(error).__name__}" + (f": {text}" if text else "")


_OWN_PACKAGE = __name__.split(".")[0]


def register(module_name: str, text: str, names=(), flag: str = "--physics") -> None:
    """Count `module_name`'s code as the plug-in `flag` `text`'s (this package's own modules never count)."""
    if module_name.split(".")[0] != _OWN_PACKAGE:
        _SOURCES[module_name] = (f"{flag} {text}", tuple(names))


def _plugin_frames(error: BaseException):
    """(frame summary, module name) of the plug-in code the traceback of `error` runs through, outermost first."""
    frames = []
    for frame, line in traceback.walk_tb(error.__traceback__):
        module = frame.f_globals.get("__name__")
        if module in _SOURCES:
            frames.append((frame, line, module))
    return frames


def _chain(error: BaseException):
    seen: list[BaseException] = []
    todo: list[BaseException | None] = [error]
    while todo and len(seen) < 20:
        current = todo.pop(0)
        if current is None or any(current is s for s in seen):
            continue
        seen.append(current)
        todo += [current.__cause__, current.__context__]
    return seen


def describe_failure(error: BaseException) -> str | None:
    """One line naming the plug-in, its method and what went wrong, if `error` came from a plug-in's code.

    `error` is any exception that ended a command. It counts as the plug-in's
    when its traceback (or that of an exception it was raised from) runs
    through the code of a plug-in resolved in this process: the line names
    the ``--physics`` spec, the method ``hybrid`` called (the outermost
    plug-in frame), the exception or exit, and where in the plug-in's file it
    happened. None otherwise (and for a `PluginError`, already one line).
    """
    if isinstance(error, PluginError):
        source = _SOURCES.get(getattr(error.plugin, "__module__", None) or "")
        return f"{source[0]}: {error}" if source is not None else None
    for current in _chain(error):
        frames = _plugin_frames(current)
        if frames:
            label = _SOURCES[frames[0][2]][0]
            return f"{label}: {_failed_in(current, '')}; fix the plug-in ({TRACEBACK_HINT})"
    return None


def _method_name(code) -> str:
    name = getattr(code, "co_qualname", code.co_name)
    return "importing the module" if name == "<module>" else name


def resolve_physics(spec: str, recordings=None, *, rate: float | None = None) -> AbstractSimulation:
    """The simulation named by `spec` (``rc``, ``lti:N``, ``file.py:Class``, ``module:Class``).

    **Arguments:**

    - `spec`: as given to ``--physics`` (see the module docstring).
    - `recordings`: the recordings it will be fitted to (one `Recording` or
      path, or a list of them), or None. An ``lti:N``
      then starts with its time scales centred on theirs
      (`hybrid.physics._lti_start`); every other physics ignores them.
    - `rate`: samples per second of the drives it will run on, where there are
      no recordings yet (``hybrid design``'s rig): a plug-in is probed on a
      step at that rate (30 Hz if None) rather than the recordings' first samples.

    **Returns:** an instance with the class's default parameters.

    **Raises:** [`InputError`][hybrid.InputError] naming the problem and the fix.
    """
    if not isinstance(spec, str) or not spec.strip():
        raise InputError(f"--physics needs one of {FORMS}, got {spec!r}")
    if isinstance(recordings, (list, tuple)) and not recordings:
        recordings = None
    elif recordings is not None:  # one Recording or path, or several, as `fit` and `diagnose` take them
        recordings = as_recordings(recordings, "resolve_physics")
    text = spec.strip()
    lowered = text.lower()
    if lowered == "rc":
        return RCNetwork()
    if lowered == "rc:zoh":
        return RCNetwork(method="zoh", C_clamp=ZOH_C_CLAMP)
    if lowered.startswith("lti:") or lowered == "lti":
        lti = _lti(text)
        return lti if not recordings else lti_for_recordings(lti.order, recordings)
    module, label, name = plugin_module(
        text, "--physics", f"not a physics I know; give {FORMS} (e.g. --physics examples/two_tank.py:TwoTank)"
    )
    simulation = _instantiate(text, module, label, name)
    probe_simulation(simulation, recordings, label=f"--physics {text}", rate=rate)
    return simulation


def _lti(text: str) -> LTI:
    order = text.partition(":")[2].strip()
    if not re.fullmatch(r"\d+", order) or not 1 <= int(order) <= MAX_ORDER:
        raise InputError(
            f"--physics {text}: the order N of lti:N must be a whole number from 1 to {MAX_ORDER} "
            "(the number of states), e.g. --physics lti:2"
        )
    return LTI(int(order))


def plugin_module(text: str, flag: str, unknown: str):
    """(module, label, class name) of a plug-in given as ``file.py:Class`` or ``module:Class``.

    `flag` TEXT names it in every message; `unknown` is what to say when
    `text` has no ``where:Class`` shape.
    """
    where, sep, name = text.rpartition(":")
    if not sep or not where:
        raise InputError(f"{flag} {text}: {unknown}")
    if not name.isidentifier():
        raise InputError(
            f"{flag} {text}: {name!r} is not a Python class name; write the class after the "
            f"last colon, e.g. {flag} mine.py:ClassName"
        )
    if where.endswith(".py") or "/" in where or "\\" in where:
        return module_from_file(text, where, flag), Path(where).name, name
    return module_from_name(text, where, flag), f"module {where}", name


def module_from_file(text: str, where: str, flag: str = "--physics"):
    """The module of a plug-in file (`flag` TEXT names it in every message); the same file gives the same module."""
    path = Path(where).expanduser()
    if not path.is_file():
        hint = (
            "it is a folder; name the .py file in it"
            if path.is_dir()
            else "check the path (relative to the current folder)"
        )
        raise InputError(f"{flag} {text}: no file {where} (looked at {path.resolve()}): {hint}")
    if path.suffix != ".py":
        raise InputError(f"{flag} {text}: {where} is not a Python file (.py): write the class in a .py file")
    resolved = path.resolve()
    # The same file gets the same module name in every process (so a saved model's module matches),
    # and a name no installed package has.
    digest = hashlib.sha1(str(resolved).encode()).hexdigest()[:10]
    stem = re.sub(r"\W", "_", resolved.stem)
    name = f"hybrid_plugin_{stem}_{digest}"
    stamp = resolved.stat().st_mtime_ns
    loaded = sys.modules.get(name)
    if loaded is not None and getattr(loaded, "__hybrid_plugin_mtime__", None) == stamp:
        return loaded  # the same, unchanged file: the same classes (a model built from them stays loadable)
    spec = importlib.util.spec_from_file_location(name, resolved)
    if spec is None or spec.loader is None:
        raise InputError(f"{flag} {text}: {where} cannot be imported as a Python module: check its name")
    module = importlib.util.module_from_spec(spec)
    module.__dict__["__hybrid_plugin_mtime__"] = stamp
    sys.modules[name] = module
    register(name, text, flag=flag)
    # Its folder on the import path, as `python file.py` would put it: a plug-in may import a module beside
    # it (its physics, a shared helper). Last, so that it shadows no installed package; kept, for imports
    # made later, inside its methods.
    if str(resolved.parent) not in sys.path:
        sys.path.append(str(resolved.parent))
    try:
        spec.loader.exec_module(module)
    except SyntaxError as error:
        sys.modules.pop(name, None)
        raise InputError(
            f"{flag} {text}: {where} has a syntax error at line {error.lineno}: {error.msg}; "
            "fix the file (python -m py_compile shows it too)"
        ) from None
    except BaseException as error:  # the file's own code failed (sys.exit too): say so, in one line
        sys.modules.pop(name, None)
        if isinstance(error, KeyboardInterrupt):
            raise  # a Ctrl-C, or the plug-in's own: the command line tells them apart
        raise PluginError(
            f"{flag} {text}: importing {where} {_what(error)}; "
            f"fix the file or install what it imports ({TRACEBACK_HINT})",
            error,
        ) from None
    return module


def module_from_name(text: str, where: str, flag: str = "--physics"):
    """The module of a plug-in given as an importable name (`flag` TEXT names it in every message)."""
    if where not in sys.modules:
        register(where, text, flag=flag)  # its module-level code is the plug-in's
    try:
        return importlib.import_module(where)
    except ModuleNotFoundError as error:
        if error.name and (where == error.name or where.startswith(error.name + ".")):
            raise InputError(
                f"{flag} {text}: no module named {where}: install the package or add its folder "
                "to PYTHONPATH, or give a file as path/to/file.py:ClassName"
            ) from None
        raise InputError(
            f"{flag} {text}: importing module {where} raised ModuleNotFoundError: {error}; "
            "install what it imports"
        ) from None
    except KeyboardInterrupt:
        raise
    except BaseException as error:  # sys.exit in the module's code too
        raise PluginError(
            f"{flag} {text}: importing module {where} {_what(error)}; fix the module ({TRACEBACK_HINT})",
            error,
        ) from None


def _instantiate(text: str, module, label: str, name: str) -> AbstractSimulation:
    cls = getattr(module, name, None)
    if cls is None:
        mine = [
            k
            for k, v in vars(module).items()
            if inspect.isclass(v)
            and issubclass(v, AbstractSimulation)
            and v.__module__ == module.__name__
            and not inspect.isabstract(v)
        ]
        defines = (
            f"it defines: {', '.join(sorted(mine))}" if mine else "it defines no AbstractSimulation subclass"
        )
        raise InputError(f"--physics {text}: {label} has no class {name}; {defines}")
    if not inspect.isclass(cls) or not issubclass(cls, AbstractSimulation):
        what = (
            "a class but not an AbstractSimulation subclass"
            if inspect.isclass(cls)
            else f"a {type(cls).__name__}, not a class"
        )
        raise InputError(
            f"--physics {text}: {name} in {label} is {what}; "
            "derive it from hybrid.AbstractSimulation (raw, constraints, units, simulate(v_in, dt)): "
            "see docs/plugins.md"
        )
    if inspect.isabstract(cls):
        missing = ", ".join(sorted(getattr(cls, "__abstractmethods__", ())))
        raise InputError(
            f"--physics {text}: {name} in {label} is abstract (it does not define {missing}); "
            "define simulate(self, v_in, dt) returning the signal for each sample"
        )
    problem = constraint_problem(inspect.getattr_static(cls, "constraints", None))
    if problem:
        raise InputError(f"--physics {text}: {name}: {problem}")
    register(cls.__module__, text)
    if module.__name__ != cls.__module__:
        register(module.__name__, text)
    try:
        simulation = cls()  # type: ignore[call-arg]  # eqx AbstractVar `raw`: no init arg
    except KeyboardInterrupt:
        raise
    except BaseException as error:
        raise PluginError(
            f"--physics {text}: {name}() {_what(error)}; the class must build "
            "with no arguments, its defaults being the starting values",
            error,
        ) from None
    _check(text, name, simulation)
    names = tuple(simulation.raw)
    for key in {cls.__module__, module.__name__}:
        register(key, text, names)
    return simulation


def _check(text: str, name: str, simulation: AbstractSimulation) -> None:
    """Parameters decode, and each has a constraint and a unit: what fit, save and diagnose rely on."""
    try:
        raw = simulation.raw
        names = list(raw) if isinstance(raw, dict) else None
    except Exception:
        names = None
    if names is None:
        raise InputError(
            f"--physics {text}: {name}() has no dict raw of parameters; set self.raw = "
            "encode(values, self.constraints, name) in __init__ (see docs/plugins.md)"
        )
    constraints, units = _fact(simulation, "constraints"), _fact(simulation, "units")
    if not isinstance(constraints, dict) or any(k not in constraints for k in names):
        raise InputError(
            f"--physics {text}: {name} needs a class-level dict constraints with an entry "
            f"(Positive(), Real(), UnitInterval(), ...) for each parameter {names}"
        )
    if not isinstance(units, dict):
        raise InputError(
            f"--physics {text}: {name} needs a class-level dict units with an entry "
            f'(e.g. "s", "cm^2", "1" for dimensionless) for each parameter {names}'
        )
    missing = [k for k in names if k not in units]
    if missing:
        raise InputError(
            f"--physics {text}: {name}.units has no unit for {missing}; add them "
            '(e.g. "s", "cm^2", "1" for dimensionless)'
        )
    for fact in ("typical", "plausible", "frozen_by_default"):
        # A misspelt key would be ignored: its parameter left out of the start design, the warning or the
        # frozen set without a word (and frozen_by_default's refusal would name a --freeze never given).
        stated = _fact(simulation, fact)
        if not isinstance(stated, dict):
            raise InputError(
                f"--physics {text}: {name}.{fact} must be a dict by parameter name, got {stated!r:.80}"
            )
        unknown = sorted(k for k in stated if k not in names)
        if unknown:
            raise InputError(
                f"--physics {text}: {name}.{fact} names {unknown}, which are not its parameters "
                f"({', '.join(names)}): a misspelling?"
            )
        if fact == "frozen_by_default":
            continue
        for key, bounds in stated.items():
            if not _is_range(bounds):
                raise InputError(
                    f"--physics {text}: {name}.{fact}[{key!r}] must be (low, high), two finite numbers with "
                    f"low < high in the parameter's unit, got {bounds!r:.60}"
                )
    span = _fact(simulation, "drive_range")
    if span is not None and not _is_range(span):
        raise InputError(
            f"--physics {text}: {name}.drive_range must be None or (low, high), two finite numbers with "
            f"low < high in the drive unit its numbers are written for, got {span!r:.60}"
        )


def _is_range(bounds) -> bool:
    """Whether `bounds` is (low, high): two finite numbers, low < high."""
    try:
        low, high = (float(b) for b in bounds)
    except (TypeError, ValueError):
        return False
    return bool(np.isfinite(low) and np.isfinite(high) and low < high)


def _fact(simulation: AbstractSimulation, name: str) -> object:
    """The fact `name` (`constraints`, `units`) as the simulation states it, or None if it does not."""
    try:
        return getattr(simulation, name)
    except Exception:  # the base class's one-line refusal, or a plug-in's property that fails
        return None


def _probe_drive(recordings, rate: float | None = None):
    """A short drive, its step and its words: the first recording's first samples, or a step at `rate` Hz.

    Without recordings the step is sampled at `rate` (the rig's, where a
    command knows it; 30 Hz, a camera's, where it does not): a plug-in that is
    stable only at its own rate must not be refused at another.
    """
    for recording in recordings or ():
        v_in = np.asarray(getattr(recording, "v_in", ()), dtype=float)[:PROBE_SAMPLES]
        dt = float(getattr(recording, "dt", 0.0) or 0.0)
        if v_in.size >= 2 and dt > 0 and np.all(np.isfinite(v_in)):
            return v_in, dt, f"the first {v_in.size} samples of the recording's drive"
    rate = 30.0 if rate is None else float(rate)
    v_in = np.r_[np.zeros(PROBE_SAMPLES // 4), np.ones(PROBE_SAMPLES - PROBE_SAMPLES // 4)]
    return v_in, 1 / rate, f"a {PROBE_SAMPLES}-sample step from 0 to 1 V at {rate:g} Hz"


def _check_result(out, n: int) -> str | None:
    """What is wrong with `out` as simulate's result for an n-sample drive, or None."""
    import jax

    if not isinstance(out, (jax.Array, np.ndarray, jax.ShapeDtypeStruct)):
        return f"returned a {type(out).__name__}, not an array"
    shape = tuple(out.shape)
    if shape != (n,):
        what = "a scalar (shape ())" if shape == () else f"shape {shape}"
        return (
            f"returned {what} for a drive of shape ({n},): it must return one value per sample, shape ({n},)"
        )
    if not np.issubdtype(np.dtype(out.dtype), np.floating):
        return f"returned dtype {np.dtype(out.dtype)}: it must return real floating-point values"
    return None


#: What a plug-in that JAX could not trace is told.
TRACEABLE = (
    "its methods must be traceable (no float(), int() or Python if on values: use jnp.where, lax.cond)"
)


def probe_simulation(
    simulation: AbstractSimulation, recordings=None, label: str | None = None, rate: float | None = None
) -> None:
    """Check a simulation's `simulate` once, eagerly, before anything is compiled.

    It runs on a short drive (the first samples of `recordings`, or a step at `rate` Hz)
    and must return one finite floating-point value per sample; it is then
    traced under `jax.jit` (``eqx.filter_eval_shape``: no compilation), which
    must succeed with the same shape. What `fit`, `diagnose` and
    `sensitivity` would otherwise find later, deep in a compiled program.

    **Raises:** `PluginError` naming `label` (default: the class), the method and what was wrong.
    """
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    cls = type(simulation).__name__
    label = label or cls
    if has_states(simulation):  # what diagnose's effects inside the dynamics need, checked for every command
        check_state_space(simulation, label)
        _probe_linear(simulation, label)
    v_in, dt, drive = _probe_drive(recordings, rate)
    n = v_in.size
    try:
        out = simulation.simulate(jnp.asarray(v_in), dt)
        problem = _check_result(out, n)
        if problem is None:
            values = np.asarray(out)
            bad = int(np.sum(~np.isfinite(values)))
            if bad:
                problem = (
                    f"returned {bad} non-finite values (NaN or inf) of {n} at its default parameters on "
                    f"{drive}: check its formulas and defaults"
                )
    except KeyboardInterrupt:
        raise
    except PluginError:
        raise
    except BaseException as error:
        # a state-space plug-in's simulate is a scan: traced even when called eagerly (a Python if on a state)
        untraceable = (
            jax.errors.ConcretizationTypeError,  # TracerBoolConversionError's too
            jax.errors.TracerIntegerConversionError,
            jax.errors.TracerArrayConversionError,
        )
        fix = TRACEABLE if isinstance(error, untraceable) else "fix the plug-in"
        raise PluginError(
            f"{label}: {_failed_in(error, cls, 'on ' + drive)}; {fix} ({TRACEBACK_HINT})", error
        ) from None
    if problem is not None:
        raise PluginError(f"{label}: {cls}.simulate(v_in, dt) {problem}")
    try:
        traced = eqx.filter_eval_shape(lambda s, v: s.simulate(v, dt), simulation, jnp.asarray(v_in))
    except KeyboardInterrupt:
        raise
    except BaseException as error:
        raise PluginError(
            f"{label}: {_failed_in(error, cls, 'under jax.jit; it runs eagerly')}: {TRACEABLE} ({TRACEBACK_HINT})",
            error,
        ) from None
    problem = _check_result(traced, n)
    if problem is not None:
        raise PluginError(f"{label}: {cls}.simulate(v_in, dt) under jax.jit {problem}")


#: Relative disagreement between `rates` and A x + B u that `_probe_linear` refuses.
LINEAR_RTOL = 1e-6


def _probe_linear(simulation, label: str) -> None:
    """A state-space plug-in's `rates` give one rate per state, and A x + B u where it gives `linear_matrices`.

    Where the matrices are given they step the simulation and `rates` is used
    only by effects inside the dynamics: a typo in one of them would go unseen
    by every command but diagnose, which would search another model than the one fitted.
    Checked at three random states and drives, at the default parameters.
    """
    import jax.numpy as jnp

    cls = type(simulation).__name__
    k = len(simulation.states)

    def rates(x, u) -> np.ndarray:
        got = simulation.rates(tuple(jnp.asarray(v, float) for v in x), jnp.asarray(u, float), p)
        if not isinstance(got, (tuple, list)) or len(got) != k:
            said = f"{len(got)}" if isinstance(got, (tuple, list)) else f"a {type(got).__name__}"
            raise PluginError(
                f"{label}: {cls}.rates must return a tuple of {k} rate(s), one per state "
                f"{simulation.states}, got {said}"
            )
        return np.asarray([float(np.asarray(g)) for g in got])

    doing = "calling prepare, initial_state and rates at the default parameters"
    try:
        p = simulation.prepare(simulation.parameters())
        x0 = simulation.initial_state(jnp.asarray(0.0), p)
        rates(x0, 0.0)  # its shape, at the initial state
        doing = "calling observe at the initial state"
        shape = np.shape(simulation.observe(x0, p))
        if shape != ():  # simulate, made of it, would blame itself for a shape the author never wrote
            raise PluginError(
                f"{label}: {cls}.observe must return the output at a state, one value (shape ()), got shape "
                f"{shape}: return one quantity, e.g. x[0], or a combination of the states"
            )
        doing = "calling linear_matrices"
        linear = simulation.linear_matrices(p)
        if linear is None:
            return
        doing = "checking rates against linear_matrices"
        a, b = (np.asarray(m, float) for m in linear)
        if a.shape != (k, k) or b.reshape(-1).shape != (k,):
            raise PluginError(
                f"{label}: {cls}.linear_matrices must return (A, B) of shapes ({k}, {k}) and ({k},) for its "
                f"{k} state(s) {simulation.states}, got {a.shape} and {b.shape}"
            )
        rng = np.random.default_rng(0)
        for _ in range(3):
            x, u = rng.normal(size=k), float(rng.normal())
            got = rates(x, u)
            want = a @ x + b.reshape(-1) * u
            if not np.allclose(
                got, want, rtol=LINEAR_RTOL, atol=LINEAR_RTOL * (np.max(np.abs(want)) + 1e-300)
            ):
                raise PluginError(
                    f"{label}: {cls}.rates and linear_matrices disagree at the default parameters: at the state "
                    f"{np.round(x, 3).tolist()} and drive {u:.3g}, rates gives {got.tolist()} but A x + B u "
                    f"gives {want.tolist()}; make them one model (or return None from linear_matrices)"
                )
    except (KeyboardInterrupt, PluginError):
        raise
    except BaseException as error:
        raise PluginError(
            f"{label}: {_failed_in(error, cls, doing)}; fix the plug-in ({TRACEBACK_HINT})",
            error,
        ) from None


def _failed_in(error: BaseException, cls: str, context: str = "") -> str:
    """'Cls.simulate raised X: msg (at file:line, context)', from the plug-in's own frames when there are any."""
    frames = [
        (f, line)
        for f, line in traceback.walk_tb(error.__traceback__)
        if f.f_globals.get("__name__") in _SOURCES
    ]
    method = _method_name(frames[0][0].f_code) if frames else f"{cls}.simulate"
    where = [f"at {Path(frames[-1][0].f_code.co_filename).name}:{frames[-1][1]}"] if frames else []
    names = _SOURCES[frames[0][0].f_globals["__name__"]][1] if frames else ()
    hint = (
        f"; its parameters are {', '.join(names)}: a name not in raw?"
        if isinstance(error, KeyError) and names
        else ""
    )
    detail = ", ".join(where + ([context] if context else []))
    return f"{method} {_what(error)}{hint}" + (f" ({detail})" if detail else "")
