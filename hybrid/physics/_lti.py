"""A generic continuous-time linear system of order N, stable for every parameter value.

`LTI(order=N)` is a grey box for "some linear dynamics between the drive and the
sensor" when no physical model is at hand (`--physics lti:N` on the command
line). It is a sum of sections in parallel (modal form), one state per real
pole and two per pair of poles, plus a direct feedthrough:

    H(s) = Σ_k H_k(s) + direct

- N odd: section 1 is first order, H_1(s) = lowpass_1 / (1 + s·tau_1),
  and the other (N − 1)/2 sections are second order;
- N even: all N/2 sections are second order,

      H_k(s) = (lowpass_k · ω_k² + bandpass_k · ω_k s) / (s² + 2 zeta_k ω_k s + ω_k²),
      ω_k = 2π f_k.

Why this parameterisation:

- *Stable by construction.* tau_k, f_k and zeta_k are `Positive` (optimised as
  logarithms), so every pole has a negative real part for every raw value, and
  every discrete pole lies inside the unit circle. zeta_k is positive, not in
  (0, 1): a second-order section covers a resonant pair (zeta < 1) and two real
  poles (zeta ≥ 1) alike, so N = 2 includes the overdamped systems (two tanks,
  two RC stages) and every stable denominator of degree N is reachable.
- *Well conditioned.* Each second-order section is realised as
  ṗ = ω q, q̇ = ω (u − p − 2 zeta q): p is its unit-DC-gain low-pass response and
  q its band-pass response (peak gain 1/(2 zeta)), both O(1), so the residues
  lowpass_k and bandpass_k are dimensionless weights of comparable size. Nothing
  is diagonalised: no eigenvectors that blow up where two poles meet, and the
  gradient stays finite at zeta = 1.
- *Not redundant with the readout.* The physics model's readout multiplies the
  output by a gain. Scaling every residue and `direct` by the same factor would
  do the same, so section 1's low-pass weight is fixed at 1 and is not a
  parameter: lowpass_1 = 1. (The one system left out is one whose first section
  has no low-pass part; relabel or pick another order.) The remaining 2N
  parameters (N for the denominator, N − 1 residues, `direct`) are the
  2N + 1 numbers of a general proper order-N transfer function less its scale.

The sections are discretised exactly for a drive held between samples (zero-order
hold) with the matrix exponential of [`hybrid.core._loop_safe_linalg.expm`][]
(matrix products only, safe inside `diagnose`'s batched compiled loops), and run
lifted to blocks of samples by the generic ZOH code of `_zoh.py`, which the RC
network's ``method="zoh"`` shares. The system starts at
rest. It is also an `AbstractStateSpace` (states ``lag_1``, ``low_k``,
``band_k``; `linear_matrices` gives A and B, so the form is stepped exactly),
which is where `diagnose` runs an effect inside its dynamics (a cubic fed
back, a limit on a low-pass state); `simulate` stays the block-lifted ZOH.
Section k = 1 holds the fastest default time scale; the defaults spread the
sections half a decade apart around 1 s so that no two start on the same pole.
"""

from __future__ import annotations

import math
import numbers
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from ..core._arguments import check_drive, run_compiled
from ..core._loop_safe_linalg import zoh_discretise
from ..core._parameters import Constraint, Positive, Real, encode
from ..core._state_space import AbstractLinearStateSpace
from ..util._errors import InputError
from ._zoh import zoh_response

#: The largest order `LTI` accepts (10 second-order sections).
MAX_ORDER = 20
_MAX_SECTIONS = MAX_ORDER // 2


def sections(order: int) -> list[tuple[int, int]]:
    """(section number k, its number of states) for an order-N system: one first-order section if N is odd."""
    first = [(1, 1)] if order % 2 else []
    return first + [(k, 2) for k in range(len(first) + 1, len(first) + 1 + order // 2)]


def parameter_names_for(order: int) -> tuple[str, ...]:
    """Names of an order-N system's parameters: time scales, dampings, residues, direct."""
    names, residues = [], []
    for k, states in sections(order):
        names += [f"tau_{k}"] if states == 1 else [f"f_{k}", f"zeta_{k}"]
        if k > 1:
            residues.append(f"lowpass_{k}")
        if states == 2:
            residues.append(f"bandpass_{k}")
    return tuple(names + residues + ["direct"])


def _table(tau, f, zeta, residue, direct) -> dict:
    """One entry per possible parameter name (every order up to MAX_ORDER share these names)."""
    out = {"tau_1": tau}
    for k in range(1, _MAX_SECTIONS + 2):
        out.update({f"f_{k}": f, f"zeta_{k}": zeta, f"bandpass_{k}": residue})
        if k > 1:
            out[f"lowpass_{k}"] = residue
    out["direct"] = direct
    return out


#: Constraint, unit, plausible and typical range of every parameter name of every order up to
#: MAX_ORDER (an instance's `constraints`, … select its own).
CONSTRAINTS: dict[str, Constraint] = _table(Positive(), Positive(), Positive(), Real(), Real())
UNITS: dict[str, str] = _table("s", "Hz", "1", "1", "1")
# Plausible: any time scale from a microsecond to ten days, any damping that is not
# a numerical accident, residues within three decades of section 1's fixed 1.
PLAUSIBLE: dict[str, tuple[float, float]] = _table(
    (1e-6, 1e6), (1e-6, 1e6), (1e-3, 1e3), (-1e3, 1e3), (-1e3, 1e3)
)
# Where diagnose's screened start design spreads: time constants 1 ms-1000 s, natural
# frequencies 1 mHz-1 kHz (log), dampings 0.05-5 (resonant to overdamped), residues
# within ten times section 1's, a feedthrough of at most the drive itself.
TYPICAL: dict[str, tuple[float, float]] = _table(
    (1e-3, 1e3), (1e-3, 1e3), (0.05, 5.0), (-10.0, 10.0), (-1.0, 1.0)
)


class LTI(AbstractLinearStateSpace):
    """A stable continuous-time linear system of order N in modal form (see the module docstring).

    **Arguments:**

    - `order`: N, the number of states, 1 to 20.
    - `**values`: starting values of any parameters by name (the defaults spread
      the sections' time scales half a decade apart around 1 s, zeta = 0.7,
      low-pass weights 1, band-pass weights and `direct` 0).

    Parameters, for section k (units in `units`):

    - `tau_1` (s): time constant of the first-order section (N odd);
    - `f_k` (Hz), `zeta_k` (1): natural frequency and damping of a second-order section;
    - `lowpass_k`, `bandpass_k` (1): its residues (`lowpass_1` is fixed at 1);
    - `direct` (1): the feedthrough of the drive to the output.

    Its facts (`constraints`, `units`, `plausible`, `typical`) are properties of the
    order: each lists this system's parameters only, from tables that cover every order.
    """

    raw: dict[str, Array]
    order: int = eqx.field(static=True)

    linear_in_drive: ClassVar[bool] = True  # zero initial state: the output is linear in the drive
    # Every section has unit DC (or peak) gain and the residues and feedthrough are pure numbers: the
    # output is in the drive's unit, and so are the parameters of an output-side effect.
    output_unit: ClassVar[str] = "{drive}"
    # The state-space form is stepped exactly (`linear_matrices`); substeps only refine a fed-back force.
    substeps: ClassVar[int] = 2

    def __init__(self, order: int, **values):
        if isinstance(order, bool) or not isinstance(order, numbers.Integral) or not 1 <= order <= MAX_ORDER:
            raise InputError(
                f"LTI order must be a whole number of states from 1 to {MAX_ORDER}, got {order!r}: "
                "e.g. LTI(2) (or --physics lti:2) for two poles"
            )
        order = int(order)
        names = parameter_names_for(order)
        defaults = default_values(order)
        unknown = sorted(set(values) - set(names))
        if unknown:
            raise InputError(f"LTI({order}) has no parameter(s) {unknown}: its parameters are {list(names)}")
        self.raw = encode({**defaults, **values}, {k: CONSTRAINTS[k] for k in names}, f"LTI({order})")
        self.order = order

    # --- the facts, for this order ------------------------------------------------------
    @property
    def constraints(self) -> dict[str, Constraint]:
        return {k: CONSTRAINTS[k] for k in self.parameter_names()}

    @property
    def units(self) -> dict[str, str]:
        return {k: UNITS[k] for k in self.parameter_names()}

    @property
    def plausible(self) -> dict[str, tuple[float, float]]:
        return {k: PLAUSIBLE[k] for k in self.parameter_names()}

    @property
    def typical(self) -> dict[str, tuple[float, float]]:
        return {k: TYPICAL[k] for k in self.parameter_names()}  # time scales first, then residues

    def parameter_names(self) -> tuple[str, ...]:
        return parameter_names_for(self.order)  # in the sections' order (raw's keys may be sorted)

    def config(self) -> dict:
        """{"order": N}: what rebuilds this system's skeleton."""
        return {"order": self.order}

    @classmethod
    def from_config(cls, config: dict) -> LTI:
        return cls(order=config["order"])

    # --- the state-space form (effects inside the dynamics act on it) -----------------------
    @property
    def states(self) -> tuple[str, ...]:  # type: ignore[override]  # per order, not per class
        """One per pole: ``lag_1`` (a first-order section), ``low_k`` and ``band_k`` (section k's p, q)."""
        names: list[str] = []
        for k, states in sections(self.order):
            names += ["lag_1"] if states == 1 else [f"low_{k}", f"band_{k}"]
        return tuple(names)

    @property
    def limited_states(self) -> tuple[str, ...]:  # type: ignore[override]
        """The unit-DC-gain low-pass states (each follows a slow drive): where a level could hit a wall."""
        return tuple(s for s in self.states if not s.startswith("band_"))

    @property
    def velocity_states(self) -> tuple[str, ...]:  # type: ignore[override]
        """The band-pass states: q = ṗ/ω, the rate of the section's low-pass state (a mass's speed, scaled)."""
        return tuple(s for s in self.states if s.startswith("band_"))

    @property
    def state_units(self) -> dict[str, str]:
        return dict.fromkeys(self.states, "{drive}")  # each has unit DC (or peak) gain from the drive

    def realisation(self, p: dict) -> tuple[Array, Array, Array, Array]:
        """Continuous realisation (A, B, C, D): block diagonal A, one block per section."""
        return _realisation(self.order, p)

    # --- the system ---------------------------------------------------------------------
    def discrete(self, dt: float):
        """(A_d, B_d, C, D): the exact ZOH discretisation for a sample interval of `dt` s."""
        A, B, C, D = self.state_space()
        Ad, Bd = zoh_discretise(A, B, dt)
        return Ad, Bd, C, D

    def simulate(self, v_in: Float[Array, " time"], dt: float) -> Float[Array, " time"]:
        """Output (V) for the drive `v_in` (V) held over each interval of `dt` s, from rest."""
        v_in, dt = check_drive(v_in, dt, f"LTI({self.order}).simulate")
        return run_compiled(_simulate, self, v_in, dt)


def _simulate(system: LTI, v_in, dt):
    return zoh_response(*system.state_space(), v_in, dt)


def _realisation(order: int, p: dict) -> tuple[Array, Array, Array, Array]:
    """(A, B, C, D) of an order-N system from its decoded parameters `p`."""
    dtype = p["direct"].dtype
    n = order
    A = jnp.zeros((n, n), dtype)
    B = jnp.zeros(n, dtype)
    C = jnp.zeros(n, dtype)
    i = 0
    for k, states in sections(n):
        lowpass = p[f"lowpass_{k}"] if k > 1 else jnp.ones((), dtype)
        if states == 1:
            rate = 1.0 / p[f"tau_{k}"]
            A, B, C = A.at[i, i].set(-rate), B.at[i].set(rate), C.at[i].set(lowpass)
        else:
            w = 2.0 * jnp.pi * p[f"f_{k}"]
            A = A.at[i, i + 1].set(w).at[i + 1, i].set(-w).at[i + 1, i + 1].set(-2.0 * p[f"zeta_{k}"] * w)
            B = B.at[i + 1].set(w)
            C = C.at[i].set(lowpass).at[i + 1].set(p[f"bandpass_{k}"])
        i += states
    return A, B, C, p["direct"]


def default_values(order: int, centre_s: float = 1.0) -> dict[str, float]:
    """Starting values: time scales half a decade apart around `centre_s` seconds, fastest first."""
    layout = sections(order)
    out = {}
    for j, (k, states) in enumerate(layout):
        scale = centre_s * 10.0 ** (0.5 * (j - (len(layout) - 1) / 2))  # s
        if states == 1:
            out[f"tau_{k}"] = scale
        else:
            out.update({f"f_{k}": 1.0 / (2.0 * math.pi * scale), f"zeta_{k}": 0.7, f"bandpass_{k}": 0.0})
        if k > 1:
            out[f"lowpass_{k}"] = 1.0
    out["direct"] = 0.0
    return out
