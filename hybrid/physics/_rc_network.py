"""The distributed RC network of the paper (Eqs 4–14), discretised for sampled drives.

The strip is divided into compartments k = 0..N (N = 45 by default, so 46
sections). Each compartment has an electrode resistance RE_k, an interface
resistance RI_k in series with a double-layer capacitance C_k, and the membrane
resistance R_M; RE_k, RI_k and C_k grow linearly from clamp to tip
(Eqs 4–9, attenuation coefficients α_E, α_I, α_C ∈ (0, 1)). Each compartment is a
first-order section (Eq 10)

    H_k(s) = G_k (s + Z_k) / (s + P_k),
    G_k = (1 + RE_k/R_M + RE_k/RI_k)^-1                 (Eq 11)
    Z_k = 1 / (RI_k C_k)                                (Eq 12)
    P_k = 1 / (C_k (RI_k + RE_k R_M / (RE_k + R_M)))    (Eq 13)

and the network is their product H(s) = Π_k H_k(s) (Eq 14), from the drive
V_i to the tip voltage V_o.

Discretisation (`method`):

- ``"tustin"`` (default): each section by the bilinear transform of its
  zero-pole-gain form, s → (2/Δt)(1 − z⁻¹)/(1 + z⁻¹), in direct form II
  transposed (the recursion of `scipy.signal.sosfilt`). The cascade is run in
  blocks of L samples (see [`cascade_filter`][]): a few small matrix products
  and a scan over T/L block states, ~0.4× the time of `sosfilt` for 10⁴ samples
  and ~10× faster than one `lax.scan` per stage (`benchmarks/simulate.py`).
- ``"zoh"``: the exact response of the continuous network to a zero-order-hold
  drive, by the matrix exponential of the cascade's state-space realisation (the generic
  ZOH numerics of `_zoh.py`, which `LTI` shares).

The network starts at rest (all states zero) before the first sample.

State-space form (where `diagnose` runs an effect *inside* the dynamics: a
force fed back into the drive, a limit on a compartment's voltage). The
network is also an [`AbstractLinearStateSpace`][] with one state per section,
``vc_k``: the voltage across compartment k's double-layer capacitance C_k
(the interface branch RI_k + C_k sees the section's output y_k, so
v_C = y_k Z_k/(s + Z_k) = G_k Z_k/(s + P_k) u_k), so a limit on a state is a limit
on a physical voltage (the electrolysis window of the electrolyte, say). `simulate` stays the block-lifted cascade; the state-space form
is stepped once per sample by `discrete_matrices`, which give *the same
discretisation* as `simulate`:

- ``"tustin"``: the trapezoidal rule on the sections, x_{k+1} = Φ x_k +
  Γ (u_k + u_{k+1}). The bilinear transform of each section and the
  trapezoidal rule on the whole realisation have one transfer function (the
  substitution s → (2/Δt)(z − 1)/(z + 1) commutes with the product of
  sections), and from rest before the record (x_0 = Γ u_0) the two agree
  sample by sample to rounding;
- ``"zoh"``: e^{AΔt} and its integral, the exact response to a held drive.

Stepping 46 states one sample after another costs far more than the
block-lifted cascade, so `diagnose` leaves the inside effects out of its
default set for the network (`not_searched_inside` says so in the report) and
searches them when asked (``--effects builtins,stiffness,limit_vc_0,window_vc``: ``window_vc``, one
window ±L on every compartment's double-layer voltage, `StateWindow`).
"""

from __future__ import annotations

import numbers
from typing import ClassVar, Literal

import equinox as eqx
import jax.numpy as jnp
from jax import lax
from jaxtyping import Array, Complex, Float

from ..core._arguments import check_drive, run_compiled
from ..core._lifted import lifted_response
from ..core._loop_safe_linalg import zoh_discretise
from ..core._parameters import Constraint, Positive, UnitInterval, encode
from ..core._state_space import AbstractLinearStateSpace
from ..util._errors import InputError
from ._strip import Strip
from ._zoh import BLOCK, zoh_response

Method = Literal["tustin", "zoh"]
METHODS = ("tustin", "zoh")


class RCNetwork(AbstractLinearStateSpace):
    """The paper's RC network (Eqs 4–14) as a differentiable simulation.

    **Arguments:**

    - `xi_rho`: ξρ, interface/metal resistivity ratio (IMRR), dimensionless, > 0.
    - `xi_h`: ξh, interface/metal thickness ratio (IMTR), dimensionless, > 0.
      Only ξρ/ξh enters the network (through RI_clamp): fix one of the two.
    - `alpha_E`, `alpha_I`, `alpha_C`: attenuation coefficients of electrode
      resistance, interface resistance and capacitance, clamp/tip, in (0, 1).
    - `C_clamp`: double-layer capacitance at the clamp (F); not given by the paper.
    - `strip`: geometry and materials ([`hybrid.Strip`][], Table 1 by default).
    - `n_stages`: N; the network has N + 1 compartments k = 0..N.
    - `method`: ``"tustin"`` or ``"zoh"`` (see the module docstring).

    Its state-space form has the states ``vc_0`` (the clamp compartment's
    double-layer voltage) to ``vc_N`` (the tip's), each in the drive's unit; a
    limit is searched on the clamp's and the tip's (`limited_states`), and a window on all of
    them (``window_vc``, `state_groups`) where asked.
    """

    raw: dict[str, Array]
    strip: Strip = eqx.field(static=True)
    n_stages: int = eqx.field(static=True)
    method: str = eqx.field(static=True)

    constraints: ClassVar[dict[str, Constraint]] = {
        "xi_rho": Positive(),
        "xi_h": Positive(),
        "alpha_E": UnitInterval(),
        "alpha_I": UnitInterval(),
        "alpha_C": UnitInterval(),
        "C_clamp": Positive(),
    }
    output_unit: ClassVar[str] = "{drive}"  # V_o is in the drive's volts (a divider of V_i)
    units: ClassVar[dict[str, str]] = {
        "xi_rho": "1",
        "xi_h": "1",
        "alpha_E": "1",
        "alpha_I": "1",
        "alpha_C": "1",
        "C_clamp": "F",
    }
    # Plausible for an IPMC strip (a fitted value outside is warned about, not refused):
    # an interface 0.1-1000x as resistive and 0.01-100x as thick as the electrode; a tip
    # that keeps 1-99 % of the clamp's conductance or capacitance (0 and 1 are the edges
    # the sigmoid never reaches); 0.1 mF to 10 F of double-layer capacitance at the clamp
    # (a few cm² of Pt-Nafion at 0.1-10 mF/cm², with room either way).
    plausible: ClassVar[dict[str, tuple[float, float]]] = {
        "xi_rho": (0.1, 1e3),
        "xi_h": (0.01, 1e2),
        "alpha_E": (0.01, 0.99),
        "alpha_I": (0.01, 0.99),
        "alpha_C": (0.01, 0.99),
        "C_clamp": (1e-4, 10.0),
    }
    # Where diagnose's screened start design spreads (log for the positive ones), in this
    # order: the strips of the discrepancy experiments, 1 mF-1 F at the clamp, an interface
    # 1-100x as resistive as the electrode, each alpha 0.1-0.9.
    typical: ClassVar[dict[str, tuple[float, float]]] = {
        "C_clamp": (1e-3, 1.0),
        "xi_rho": (1.0, 1e2),
        "alpha_E": (0.1, 0.9),
        "alpha_I": (0.1, 0.9),
        "alpha_C": (0.1, 0.9),
    }
    frozen_by_default: ClassVar[dict[str, str]] = {
        "xi_h": "only xi_rho/xi_h enters the network (RI_clamp = xi_rho rho_E L / (W xi_h h_E)): "
        "xi_h stays fixed and xi_rho carries the ratio",
    }
    linear_in_drive: ClassVar[bool] = True  # zero initial state: V_o is linear in V_i
    not_searched_inside: ClassVar[str | None] = (
        "its state-space form steps one state per section, sample after sample, far dearer than its "
        "block-lifted cascade: ask for them by name (--effects builtins,stiffness,limit_vc_0,window_vc)"
    )

    def __init__(
        self,
        xi_rho: float = 10.0,
        xi_h: float = 1.0,
        alpha_E: float = 0.5,
        alpha_I: float = 0.5,
        alpha_C: float = 0.5,
        C_clamp: float = 0.05,
        *,
        strip: Strip = Strip(),
        n_stages: int = 45,
        method: Method = "tustin",
    ):
        if isinstance(n_stages, bool) or not isinstance(n_stages, numbers.Integral) or n_stages < 1:
            raise InputError(f"n_stages (N) must be a positive integer, got {n_stages!r}")
        if method not in METHODS:
            raise InputError(f"discretisation method must be one of {METHODS}, got {method!r}")
        if not isinstance(strip, Strip):
            raise InputError(
                f"strip must be a hybrid.Strip (geometry and materials), got {type(strip).__name__}"
            )
        values = dict(
            xi_rho=xi_rho,
            xi_h=xi_h,
            alpha_E=alpha_E,
            alpha_I=alpha_I,
            alpha_C=alpha_C,
            C_clamp=C_clamp,
        )
        self.raw = encode(values, self.constraints, "RCNetwork")
        self.strip = strip
        self.n_stages = int(n_stages)
        self.method = method

    def config(self) -> dict:
        """The strip (Table 1), N and the discretisation: what rebuilds this network."""
        return {"n_stages": self.n_stages, "method": self.method, "strip": self.strip.to_dict()}

    @classmethod
    def from_config(cls, config: dict) -> RCNetwork:
        return cls(
            strip=Strip.from_dict(config["strip"]), n_stages=config["n_stages"], method=config["method"]
        )

    # --- Eqs 4–9 -------------------------------------------------------------
    def stage_elements(self, p: dict | None = None) -> dict[str, Float[Array, " stages"]]:
        """RE_k, RI_k, C_k (Ω, Ω, F) for k = 0..N and R_M (Ω), Eqs 4–9 and Table 1.

        `p`: decoded parameters (default: this network's own).
        """
        p = self.parameters() if p is None else p
        k = jnp.arange(self.n_stages + 1, dtype=p["C_clamp"].dtype)
        frac = k / self.n_stages
        RE_clamp = self.strip.RE_clamp
        RI_clamp = self.strip.RI_clamp(p["xi_rho"], p["xi_h"])
        RE = (RE_clamp / p["alpha_E"] - RE_clamp) * frac + RE_clamp
        RI = (RI_clamp / p["alpha_I"] - RI_clamp) * frac + RI_clamp
        C = (p["C_clamp"] / p["alpha_C"] - p["C_clamp"]) * frac + p["C_clamp"]
        return {"RE": RE, "RI": RI, "C": C, "RM": jnp.asarray(self.strip.R_M, RE.dtype)}

    # --- Eqs 10–13 -----------------------------------------------------------
    def stage_zpk(
        self, p: dict | None = None
    ) -> tuple[Float[Array, " stages"], Float[Array, " stages"], Float[Array, " stages"]]:
        """Gain G_k (1), zero Z_k (rad/s) and pole P_k (rad/s) of each section, Eqs 11–13.

        Each section is H_k(s) = G_k (s + Z_k)/(s + P_k): its zero is at s = −Z_k
        and its pole at s = −P_k. `p`: decoded parameters (default: this network's own).
        """
        e = self.stage_elements(p)
        RE, RI, C, RM = e["RE"], e["RI"], e["C"], e["RM"]
        G = 1.0 / (1.0 + RE / RM + RE / RI)
        Z = 1.0 / (RI * C)
        P = 1.0 / (C * (RI + RE * RM / (RE + RM)))
        return G, Z, P

    # --- Eq 14 -----------------------------------------------------------------
    def frequency_response(self, frequency: Float[Array, " freq"]) -> Complex[Array, " freq"]:
        """H(j2πf) = Π_k G_k (j2πf + Z_k)/(j2πf + P_k) (Eq 14), `frequency` in Hz."""
        G, Z, P = self.stage_zpk()
        s = 2j * jnp.pi * jnp.asarray(frequency)[..., None]
        return jnp.prod(G * (s + Z) / (s + P), axis=-1)

    def realisation(self, p: dict) -> tuple[Array, Array, Array, Array]:
        """Continuous realisation (A, B, C, D) of the cascade, one state per section (volts).

        Section k's state is its double-layer voltage x_k = v_C,k:
        ẋ_k = G_k Z_k u_k − P_k x_k, and its output y_k = G_k u_k + (1 − P_k/Z_k) x_k
        is the next section's input, u_{k+1} = y_k. A is lower triangular;
        V_o = C x + D V_i. `state_space()` gives it at the network's own parameters.
        """
        return _realisation(*self.stage_zpk(p))

    # --- the state-space form (effects inside the dynamics act on it) ---------------------
    @property
    def states(self) -> tuple[str, ...]:  # type: ignore[override]  # per N, not per class
        """``vc_0`` (the clamp compartment's double-layer voltage) … ``vc_N`` (the tip's)."""
        return tuple(f"vc_{k}" for k in range(self.n_stages + 1))

    @property
    def limited_states(self) -> tuple[str, ...]:  # type: ignore[override]
        """The clamp's double-layer voltage, the largest, and the tip's."""
        return ("vc_0", f"vc_{self.n_stages}")

    @property
    def state_groups(self) -> dict[str, tuple[str, ...]]:  # type: ignore[override]
        """``vc``: every compartment's double-layer voltage, which one electrolyte's window bounds alike."""
        return {"vc": self.states}

    @property
    def state_units(self) -> dict[str, str]:
        return dict.fromkeys(self.states, "{drive}")  # each a voltage, a fraction of the drive at DC

    def prepare(self, p: dict) -> dict:
        G, Z, P = self.stage_zpk(p)  # the sections' too: `discrete_matrices` reads them
        return {**dict(zip("ABCD", _realisation(G, Z, P))), "G": G, "Z": Z, "P": P}

    def discrete_matrices(self, p: dict, dt):
        """(Φ, Γ₀, Γ₁) of `simulate`'s own discretisation (see the module docstring)."""
        if self.method == "zoh":
            phi, gamma = zoh_discretise(p["A"], p["B"], dt)
            return phi, gamma, jnp.zeros_like(gamma)
        return trapezoid_matrices(p["G"], p["Z"], p["P"], dt)

    # --- time domain -------------------------------------------------------------
    def simulate(self, v_in: Float[Array, " time"], dt: float) -> Float[Array, " time"]:
        """Tip voltage V_o (V) for the drive `v_in` (V) sampled every `dt` s, from rest.

        Concrete arguments are checked (InputError for dt ≤ 0, NaN, a non-finite
        or non-vector drive); inside jit/vmap/grad they are not (`hybrid.core._arguments`).
        """
        v_in, dt = check_drive(v_in, dt, "RCNetwork.simulate")
        return run_compiled(_simulate, self, v_in, dt)


def _simulate(network: RCNetwork, v_in, dt):
    if network.method == "tustin":
        b0, b1, a1 = tustin_sections(*network.stage_zpk(), dt)
        return cascade_filter(b0, b1, a1, v_in)
    return zoh_response(*network.state_space(), v_in, dt)


def _realisation(G, Z, P) -> tuple[Array, Array, Array, Array]:
    """(A, B, C, D) of the cascade with each state a double-layer voltage (see `state_space`)."""
    n = G.shape[0]

    def section(carry, k):
        c_in, d_in = carry  # u_k = c_in · x + d_in · V_i
        row = (G[k] * Z[k] * c_in).at[k].add(-P[k])
        c_out = (G[k] * c_in).at[k].add(1.0 - P[k] / Z[k])
        return (c_out, G[k] * d_in), (row, G[k] * Z[k] * d_in)

    zero = jnp.zeros(n, G.dtype)
    (C, D), (A, B) = lax.scan(section, (zero, jnp.ones((), G.dtype)), jnp.arange(n))
    return A, B, C, D


def trapezoid_matrices(G, Z, P, dt) -> tuple[Array, Array, Array]:
    """(Φ, Γ, Γ) of x_{k+1} = Φ x_k + Γ (u_k + u_{k+1}): the trapezoidal rule on `state_space`'s form.

    Section by section, clamp to tip: x'_k = a_k x_k + b_k (u_k + u'_k) with
    a = (1 − PΔt/2)/(1 + PΔt/2) and b = G Z (Δt/2)/(1 + PΔt/2), where the
    section's next input u'_k is the previous section's next output, itself
    a combination of x, u and u' found one section earlier: the implicit rule
    solved exactly by forward substitution (A is lower triangular), no
    inverse. Its transfer function is the Tustin cascade's (`tustin_sections`).
    """
    n = G.shape[0]
    half = 0.5 * dt * P
    a, b = (1.0 - half) / (1.0 + half), G * Z * (0.5 * dt) / (1.0 + half)
    zero = jnp.zeros(n, G.dtype)

    def section(carry, k):
        # u_k = c·x + d·u (now) and u'_k = e·x + f·u + g·u' (next sample), for the whole drive u, u'
        c, d, e, f, g = carry
        row = b[k] * (c + e) + a[k] * (jnp.arange(n) == k)
        by_now, by_next = b[k] * (d + f), b[k] * g  # x'_k's weights on u and u'
        w = 1.0 - P[k] / Z[k]  # y = G u + w x
        out = (
            (G[k] * c).at[k].add(w),
            G[k] * d,
            G[k] * e + w * row,
            G[k] * f + w * by_now,
            G[k] * g + w * by_next,
        )
        return out, (row, by_now, by_next)

    one = jnp.ones((), G.dtype)
    _, (phi, gamma_now, gamma_next) = lax.scan(
        section, (zero, one, zero, jnp.zeros((), G.dtype), one), jnp.arange(n)
    )
    return phi, gamma_now, gamma_next


def tustin_sections(G, Z, P, dt):
    """Bilinear transform of G (s + Z)/(s + P) → (b0, b1, a1) of (b0 + b1 z⁻¹)/(1 + a1 z⁻¹).

    With c = 2/Δt: b0 = G (c + Z)/(c + P), b1 = G (Z − c)/(c + P), a1 = (P − c)/(c + P).
    The discrete zero and pole are (1 − ZΔt/2)/(1 + ZΔt/2) and (1 − PΔt/2)/(1 + PΔt/2),
    as `scipy.signal.bilinear_zpk` gives.
    """
    c = 2.0 / dt
    den = c + P
    return G * (c + Z) / den, G * (Z - c) / den, (P - c) / den


def cascade_filter(b0, b1, a1, x: Float[Array, " time"], block: int = BLOCK) -> Float[Array, " time"]:
    """Run first-order sections (b0 + b1 z⁻¹)/(1 + a1 z⁻¹) in series over `x`, from rest.

    The same numbers as running the sections one after the other (DF-II
    transposed, as `scipy.signal.sosfilt`), to rounding (~1e-14 relative against
    `sosfilt` for 10⁴ samples; `tests/test_rc_network.py` asserts ≤ 1e-10), but computed by *lifting* the cascade to blocks
    of L = `block` samples. With the K section states x_j at the start of block j
    and the block's inputs u_j ∈ ℝ^L, the cascade is exactly

        y_j = O x_j + H u_j,      x_{j+1} = A^L x_j + C u_j,

    where H (L × L) is the lower-triangular Toeplitz matrix of the first L
    samples of the impulse response, O (L × K) the free response of each unit
    state, C = [A^{L−1}B … AB B] (K × L) and A^L (K × K) the state map of one
    block. All four come from running the sections themselves for L samples on
    K + 1 unit excitations (no matrix powers, no eigen-decomposition: the
    sections' close poles would make a modal form ill-conditioned). The series
    then costs two matrix products over all blocks, a `lax.scan` of T/L steps of
    a K × K product, and one more matrix product: ~L + 2K + K²/L multiply-adds
    per sample, as dense, vectorisable work instead of T·K dependent scalar steps.
    """
    dtype = jnp.result_type(x, b0)
    H, O, A_L, C = block_matrices(b0.astype(dtype), b1.astype(dtype), a1.astype(dtype), block)
    return lifted_response(H, O, A_L, C, x.astype(dtype))


def block_matrices(b0, b1, a1, block):
    """H, O, A^L, C of `cascade_filter` by running the sections on unit excitations.

    Columns 0..L−1 are unit impulses at the input at samples 0..L−1 with every
    state at rest: their outputs are the columns of H and their final states the
    columns of C. Column L + k starts with section k's state at 1 and no input:
    its output is column k of O and its final state column k of A^L. Sections run
    one after the other, each a `lax.scan` over the L samples of all L + K columns.
    """
    n_sections = b0.shape[0]
    eye = jnp.eye(block + n_sections, dtype=b0.dtype)
    impulses = eye[:block]  # (L samples, L + K columns)
    initial = eye[block:]  # (K sections, L + K columns)

    def section(x, coefficients):
        c0, c1, d1, s0 = coefficients

        def step(state, xn):
            y = c0 * xn + state
            return c1 * xn - d1 * y, y

        final, y = lax.scan(step, s0, x)
        return y, final

    y, final = lax.scan(section, impulses, (b0, b1, a1, initial))
    return y[:, :block], y[:, block:], final[:, block:], final[:, :block]


def cascade_filter_stage_major(b0, b1, a1, x: Float[Array, " time"]) -> Float[Array, " time"]:
    """The plain recursion: one `lax.scan` over time per section, section after section.

    Kept as the straightforward reference for [`cascade_filter`][] (tests, benchmarks).
    """
    dtype = jnp.result_type(x, b0)
    y, _ = lax.scan(_first_order_section, x.astype(dtype), (b0, b1, a1))
    return y


def _first_order_section(x, coefficients):
    """One section y[n] = b0 x[n] + s[n−1], s[n] = b1 x[n] − a1 y[n] (DF-II transposed)."""
    b0, b1, a1 = coefficients

    def step(state, xn):
        y = b0 * xn + state
        return b1 * xn - a1 * y, y

    _, y = lax.scan(step, jnp.zeros((), x.dtype), x)
    return y, None
