"""The solvers of [`hybrid.fit`][] and [`hybrid.fit_batch`][]: strategy objects, options as fields.

As in optimistix (``optx.least_squares(fn, optx.LevenbergMarquardt(rtol=…), y0)``),
switching solver swaps one object, and an option that belongs to one solver
(`patience` to Levenberg–Marquardt, `learning_rate` to Adam) is a field of that
solver, not a keyword of `fit`:

```python
hybrid.fit(model, recording, solver=hybrid.LevenbergMarquardt(max_steps=200, patience=30))
hybrid.fit(model, recording, solver=hybrid.Adam(max_steps=2_000, learning_rate=1e-3))
```

Every solver minimises the same objective (``Problem.objective_residuals``: the
training residuals and the weight-decay rows) from the same starts, and the
validation split picks the best iterate of each start and the best start.
The options are checked when the object is built: a bad one is one
[`hybrid.InputError`][] line.

The strings ``"lm"``, ``"optimistix"`` and ``"adam"`` (`SOLVERS`) and the flat
keywords ``max_steps``, ``patience`` and ``learning_rate`` of `fit` still work for
one release, with a `DeprecationWarning` that gives the new spelling
(`resolve_solver`).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from typing import ClassVar

import equinox as eqx

from ..util._errors import InputError
from ._levenberg_marquardt import LMSettings

#: The deprecated string names of `fit(solver=...)`, in the order of the classes below.
SOLVERS = ("lm", "optimistix", "adam")


def _positive_int(owner: str, name: str, value, low: int = 1) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        what = "a positive integer" if low == 1 else f"an integer ≥ {low}"
        raise InputError(f"{owner}: {name} must be {what}, got {value!r}")


def _positive_float(owner: str, name: str, value, zero_ok: bool = False) -> None:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if not ok or value < 0 or (value == 0 and not zero_ok):
        what = "a finite number ≥ 0" if zero_ok else "a finite positive number"
        raise InputError(f"{owner}: {name} must be {what}, got {value!r}")


class AbstractSolver(eqx.Module):
    """What every solver of `fit` has: `max_steps`, and a name for `FitResult.settings`."""

    max_steps: eqx.AbstractVar[int]

    #: the name recorded in `FitResult.settings["solver"]` (the deprecated string spelling)
    name: eqx.AbstractClassVar[str]

    def record(self) -> dict:
        """The solver's options for `FitResult.settings` (JSON-able): its name and fields."""
        fields = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        return {"solver": self.name, **fields}


class LevenbergMarquardt(AbstractSolver):
    """Levenberg–Marquardt on the structured Jacobian, the default solver of `fit` and `fit_batch`.

    Several starts run `vmap`-ed in one compiled program (see
    `hybrid.core._levenberg_marquardt`: Nielsen's damping rule, JᵀJ formed once
    per accepted point, the best iterate on the validation split kept).

    **Fields:**

    - `max_steps`: most LM iterations per start, accepted or rejected.
    - `patience`: stop a start after this many accepted steps without a better
      validation loss (0: never stop on validation).
    - `ftol`: stop when an accepted step lowers the cost by less than this, relative.
    - `gtol`: stop when max |Jᵀr| is below this.
    - `lambda0`: the initial damping λ (relative to max diag(JᵀJ) for ``"identity"``).
    - `scaling`: the damping matrix D: ``"identity"`` (Levenberg) or ``"marquardt"``
      (diag(JᵀJ)).
    """

    max_steps: int = 300
    patience: int = 40
    ftol: float = 1e-10
    gtol: float = 1e-12
    lambda0: float = 1e-3
    scaling: str = "identity"

    name: ClassVar[str] = "lm"

    def __check_init__(self):
        owner = "LevenbergMarquardt"
        _positive_int(owner, "max_steps", self.max_steps)
        _positive_int(owner, "patience", self.patience, low=0)
        _positive_float(owner, "ftol", self.ftol, zero_ok=True)
        _positive_float(owner, "gtol", self.gtol, zero_ok=True)
        _positive_float(owner, "lambda0", self.lambda0)
        if self.scaling not in ("identity", "marquardt"):
            raise InputError(f"{owner}: scaling must be 'identity' or 'marquardt', got {self.scaling!r}")

    def lm_settings(self) -> LMSettings:
        """These options as the compiled loop's static `hybrid.core.LMSettings`."""
        return LMSettings(
            max_steps=self.max_steps,
            ftol=self.ftol,
            gtol=self.gtol,
            patience=self.patience,
            lambda0=self.lambda0,
            scaling=self.scaling,
        )


class OptimistixLM(AbstractSolver):
    """`optimistix.LevenbergMarquardt` on the flattened parameters, one start after the other.

    Its Jacobian is autodiff of the whole model: fine for a physics-only model (a
    handful of parameters), slow for a D-MLP. It returns its final iterate; the
    validation split only picks among the starts. A reference for
    [`LevenbergMarquardt`][hybrid.LevenbergMarquardt], which it agrees with on
    physics-only models (`tests/test_fit.py`).

    **Fields:**

    - `max_steps`: most iterations per start.
    - `rtol`, `atol`: optimistix's relative and absolute tolerances.
    """

    max_steps: int = 300
    rtol: float = 1e-10
    atol: float = 1e-12

    name: ClassVar[str] = "optimistix"

    def __check_init__(self):
        _positive_int("OptimistixLM", "max_steps", self.max_steps)
        _positive_float("OptimistixLM", "rtol", self.rtol)
        _positive_float("OptimistixLM", "atol", self.atol)


class Adam(AbstractSolver):
    """`optax.adam` on ½‖r‖² / n (n training residuals), all starts `vmap`-ed.

    It runs all `max_steps` steps; after each one the validation loss is
    evaluated and each start keeps its best iterate.

    **Fields:**

    - `max_steps`: the number of Adam steps per start.
    - `learning_rate`: Adam's step size.
    """

    max_steps: int = 300
    learning_rate: float = 3e-3

    name: ClassVar[str] = "adam"

    def __check_init__(self):
        _positive_int("Adam", "max_steps", self.max_steps)
        _positive_float("Adam", "learning_rate", self.learning_rate)


#: each deprecated name's solver, with its default options
_BY_NAME: dict[str, AbstractSolver] = {
    "lm": LevenbergMarquardt(),
    "optimistix": OptimistixLM(),
    "adam": Adam(),
}


def solver_named(name: str, **options) -> AbstractSolver:
    """The solver of a deprecated string name (``"lm"``, ``"optimistix"``, ``"adam"``) with `options`.

    For the command line's ``--solver NAME``; in Python, build the object.
    """
    if name not in _BY_NAME:
        raise InputError(f"solver must be one of {', '.join(SOLVERS)}, got {name!r}")
    return dataclasses.replace(_BY_NAME[name], **options)


def resolve_solver(solver, where: str, stacklevel: int = 3, **old) -> AbstractSolver:
    """The solver object of `fit(solver=...)`, turning the deprecated spellings into it.

    `solver` is a solver object or a deprecated string name; `old` holds the
    deprecated flat keywords (``max_steps``, ``patience``, ``learning_rate``), None
    where not given. Each given keyword replaces that field of the solver; one the
    solver has no field for is ignored, as it always was (``patience`` for Adam).
    Any deprecated spelling gives one `DeprecationWarning` that shows the new one.
    """
    given = {k: v for k, v in old.items() if v is not None}
    named = isinstance(solver, str)
    if named and solver in _BY_NAME:
        base = _BY_NAME[solver]
    elif isinstance(solver, AbstractSolver):
        base = solver
    else:
        got = repr(solver) if named else type(solver).__name__
        raise InputError(
            f"{where}: solver must be a solver object such as hybrid.LevenbergMarquardt(), "
            f"hybrid.Adam() or hybrid.OptimistixLM(), got {got}"
        )
    if not named and not given:
        return solver
    cls = type(base)
    defaults = {f.name: f.default for f in dataclasses.fields(base)}
    names = list(defaults)
    used = {k: v for k, v in given.items() if k in names}
    ignored = sorted(set(given) - set(names))
    result = dataclasses.replace(base, **used) if used else base  # checks the new values
    old_spelling = ", ".join([f"solver={solver!r}"] * named + [f"{k}=..." for k in given])
    kept = {k: getattr(result, k) for k in names if getattr(result, k) != defaults[k]}
    new = f"solver=hybrid.{cls.__name__}({', '.join(f'{k}={v!r}' for k, v in kept.items())})"
    note = f" ({', '.join(ignored)} does nothing for {cls.__name__} and is ignored)" if ignored else ""
    warnings.warn(
        f"{where}({old_spelling}) is deprecated and will be removed: pass {new}{note}",
        DeprecationWarning,
        stacklevel=stacklevel,
    )
    return result
