"""Which physics: the command line's `--physics SPEC` turned into a simulation.

- ``rc``: the paper's distributed RC network ([`RCNetwork`][hybrid.RCNetwork], defaults);
- ``lti:N``: a stable linear system of order N ([`LTI`][hybrid.LTI], 1 ≤ N ≤ 20);
- ``path/to/file.py:ClassName``: a class defined in a Python file (imported
  under a module name made from the file's absolute path, kept in
  `sys.modules` so that `load_model` finds the class again: resolve the same
  spec before loading a model saved with it);
- ``package.module:ClassName``: a class in an importable module.

The class must subclass [`AbstractSimulation`][hybrid.AbstractSimulation] and
build with no arguments (its defaults are the starting values). Every failure
is one [`InputError`][hybrid.InputError] that says what is wrong and how to fix it.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import inspect
import re
import sys
from pathlib import Path

from ..core._simulation import AbstractSimulation
from ..util._errors import InputError
from ._lti_start import lti_for_recordings
from ._lti import MAX_ORDER, LTI
from ._rc_network import RCNetwork

FORMS = "rc, lti:N, path/to/file.py:ClassName or package.module:ClassName"


def resolve_physics(spec: str, recordings=None) -> AbstractSimulation:
    """The simulation named by `spec` (``rc``, ``lti:N``, ``file.py:Class``, ``module:Class``).

    **Arguments:**

    - `spec`: as given to ``--physics`` (see the module docstring).
    - `recordings`: the recordings it will be fitted to, or None. An ``lti:N``
      then starts with its time scales centred on theirs
      (`hybrid.physics._lti_start`); every other physics ignores them.

    **Returns:** an instance with the class's default parameters.

    **Raises:** [`InputError`][hybrid.InputError] naming the problem and the fix.
    """
    if not isinstance(spec, str) or not spec.strip():
        raise InputError(f"--physics needs one of {FORMS}, got {spec!r}")
    text = spec.strip()
    lowered = text.lower()
    if lowered == "rc":
        return RCNetwork()
    if lowered.startswith("lti:") or lowered == "lti":
        lti = _lti(text)
        return lti if not recordings else lti_for_recordings(lti.order, recordings)
    where, sep, name = text.rpartition(":")
    if not sep or not where:
        raise InputError(f"--physics {text}: not a physics I know; give {FORMS} "
                         "(e.g. --physics examples/two_tank.py:TwoTank)")
    if not name.isidentifier():
        raise InputError(f"--physics {text}: {name!r} is not a Python class name; write the class after the "
                         "last colon, e.g. --physics tanks.py:TwoTank")
    if where.endswith(".py") or "/" in where or "\\" in where:
        module, label = _module_from_file(text, where), Path(where).name
    else:
        module, label = _module_from_name(text, where), f"module {where}"
    return _instantiate(text, module, label, name)


def _lti(text: str) -> LTI:
    order = text.partition(":")[2].strip()
    if not re.fullmatch(r"\d+", order) or not 1 <= int(order) <= MAX_ORDER:
        raise InputError(f"--physics {text}: the order N of lti:N must be a whole number from 1 to {MAX_ORDER} "
                         "(the number of states), e.g. --physics lti:2")
    return LTI(int(order))


def _module_from_file(text: str, where: str):
    path = Path(where).expanduser()
    if not path.is_file():
        hint = ("it is a folder; name the .py file in it" if path.is_dir()
                else "check the path (relative to the current folder)")
        raise InputError(f"--physics {text}: no file {where} (looked at {path.resolve()}): {hint}")
    if path.suffix != ".py":
        raise InputError(f"--physics {text}: {where} is not a Python file (.py): write the class in a .py file")
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
        raise InputError(f"--physics {text}: {where} cannot be imported as a Python module: check its name")
    module = importlib.util.module_from_spec(spec)
    module.__hybrid_plugin_mtime__ = stamp
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except SyntaxError as error:
        sys.modules.pop(name, None)
        raise InputError(f"--physics {text}: {where} has a syntax error at line {error.lineno}: {error.msg}; "
                         "fix the file (python -m py_compile shows it too)") from None
    except BaseException as error:  # the file's own code failed: say so, in one line
        sys.modules.pop(name, None)
        if isinstance(error, KeyboardInterrupt):
            raise
        raise InputError(f"--physics {text}: importing {where} raised {type(error).__name__}: {error}; "
                         "fix the file or install what it imports") from None
    return module


def _module_from_name(text: str, where: str):
    try:
        return importlib.import_module(where)
    except ModuleNotFoundError as error:
        if error.name and (where == error.name or where.startswith(error.name + ".")):
            raise InputError(f"--physics {text}: no module named {where}: install the package or add its folder "
                             "to PYTHONPATH, or give a file as path/to/file.py:ClassName") from None
        raise InputError(f"--physics {text}: importing module {where} raised ModuleNotFoundError: {error}; "
                         "install what it imports") from None
    except Exception as error:
        raise InputError(f"--physics {text}: importing module {where} raised {type(error).__name__}: {error}; "
                         "fix the module") from None


def _instantiate(text: str, module, label: str, name: str) -> AbstractSimulation:
    cls = getattr(module, name, None)
    if cls is None:
        mine = [k for k, v in vars(module).items() if inspect.isclass(v) and issubclass(v, AbstractSimulation)
                and v.__module__ == module.__name__ and not inspect.isabstract(v)]
        defines = f"it defines: {', '.join(sorted(mine))}" if mine else "it defines no AbstractSimulation subclass"
        raise InputError(f"--physics {text}: {label} has no class {name}; {defines}")
    if not inspect.isclass(cls) or not issubclass(cls, AbstractSimulation):
        what = "a class but not an AbstractSimulation subclass" if inspect.isclass(cls) else \
            f"a {type(cls).__name__}, not a class"
        raise InputError(f"--physics {text}: {name} in {label} is {what}; "
                         "derive it from hybrid.AbstractSimulation (raw, constraints, units, simulate(v_in, dt)): "
                         "see docs/plugins.md")
    if inspect.isabstract(cls):
        missing = ", ".join(sorted(getattr(cls, "__abstractmethods__", ())))
        raise InputError(f"--physics {text}: {name} in {label} is abstract (it does not define {missing}); "
                         "define simulate(self, v_in, dt) returning the signal for each sample")
    try:
        simulation = cls()
    except Exception as error:
        raise InputError(f"--physics {text}: {name}() raised {type(error).__name__}: {error}; the class must build "
                         "with no arguments, its defaults being the starting values") from None
    _check(text, name, simulation)
    return simulation


def _check(text: str, name: str, simulation: AbstractSimulation) -> None:
    """Parameters decode, and each has a constraint and a unit: what fit, save and diagnose rely on."""
    try:
        raw = simulation.raw
        names = list(raw) if isinstance(raw, dict) else None
    except Exception:
        names = None
    if names is None:
        raise InputError(f"--physics {text}: {name}() has no dict raw of parameters; set self.raw = "
                         "encode(values, self.constraints, name) in __init__ (see docs/plugins.md)")
    constraints = getattr(type(simulation), "constraints", None)
    units = simulation.parameter_units() if isinstance(constraints, dict) else None
    if not isinstance(constraints, dict) or any(k not in simulation.constraints for k in names):
        raise InputError(f"--physics {text}: {name} needs a class-level dict constraints with an entry "
                         f"(Positive(), Real(), UnitInterval(), ...) for each parameter {names}")
    missing = [k for k in names if k not in units]
    if missing:
        raise InputError(f"--physics {text}: {name}.units has no unit for {missing}; add them "
                         '(e.g. "s", "cm^2", "1" for dimensionless)')
