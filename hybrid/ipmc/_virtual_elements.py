"""The virtual IPMC's elements, built from its parameters (steps 1–5 of the signal chain).

The DAC and amplifier (step 1), the loaded RC line with back-diffusion as one
linear state space (steps 2–3), the tanh electromechanical map to the
quasi-static tip (step 4) and the first bending mode (step 5). The equations are
in the docstring of `hybrid.ipmc._virtual_ipmc`; the tests check each block
against an independent reference.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ._virtual_parameters import VirtualIPMCParameters


@dataclass(frozen=True)
class _Ladder:
    """Per-compartment elements of the loaded line (Ω, F, m), index k = 0..N."""

    re: np.ndarray  # series electrode resistance of compartment k (node k−1 → k)
    ri: np.ndarray  # interface resistance of the shunt branch k
    c: np.ndarray  # double-layer capacitance of the shunt branch k
    rm: np.ndarray  # membrane shunt resistance of compartment k
    r_source: float  # series resistance before node 0
    dx: float  # compartment length
    x: np.ndarray  # compartment centres


def _table1(p: VirtualIPMCParameters) -> dict[str, float]:
    """Whole-strip clamp values of Table 1 (Ω, F)."""
    re = p.electrode_resistivity_ohm_m * p.length_m / (p.width_m * p.electrode_thickness_m)
    rm = p.length_m / (p.membrane_conductivity_s_per_m * p.width_m * p.membrane_thickness_m)
    return {
        "re_clamp_ohm": re,
        "ri_clamp_ohm": p.interface_ratio * re,
        "rm_ohm": rm,
        "c_clamp_f": p.clamp_capacitance_f,
    }


def build_ladder(p: VirtualIPMCParameters) -> _Ladder:
    """The line's elements: Eqs 4–9 profiles of whole-strip values, split over N+1."""
    n = p.n_compartments
    frac = np.arange(n) / (n - 1) if n > 1 else np.zeros(1)

    def profile(clamp, alpha):  # Eqs 4–9: X(k) = X_clamp + (X_clamp/α − X_clamp) k/N
        return clamp + (clamp / alpha - clamp) * frac

    t1 = _table1(p)
    dx = p.length_m / n
    return _Ladder(
        re=profile(t1["re_clamp_ohm"], p.alpha_e) / n,
        ri=profile(t1["ri_clamp_ohm"], p.alpha_i) * n,
        c=profile(t1["c_clamp_f"], p.alpha_c) / n,
        rm=np.full(n, t1["rm_ohm"] * n),
        r_source=float(p.source_resistance_ohm),
        dx=dx,
        x=(np.arange(n) + 0.5) * dx,
    )


def electrical(lad: _Ladder) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """State space of the loaded line: dv/dt = A_e v + B_e u, and the node map.

    **Returns:** `(a_e, b_e, nodes)`, where `nodes` (n, n+1) gives the node
    voltages V = nodes @ [v; u] from the tridiagonal KCL system G V = D v + b u.
    """
    import scipy.linalg

    n = len(lad.re)
    g_series = 1.0 / lad.re
    g_series[0] = 1.0 / (lad.r_source + lad.re[0])
    g_right = np.append(g_series[1:], 0.0)  # tip node is open
    diag = g_series + g_right + 1.0 / lad.rm + 1.0 / lad.ri
    # G in banded storage for solve_banded: super-, main, sub-diagonal.
    banded = np.zeros((3, n))
    banded[0, 1:] = -g_series[1:]
    banded[1] = diag
    banded[2, :-1] = -g_series[1:]
    rhs = np.zeros((n, n + 1))
    rhs[np.arange(n), np.arange(n)] = 1.0 / lad.ri
    rhs[0, n] = g_series[0]
    nodes = scipy.linalg.solve_banded((1, 1), banded, rhs)
    current = (nodes - np.eye(n, n + 1)) / lad.ri[:, None]  # branch currents per [v; u]
    a_e = current[:, :n] / lad.c[:, None]
    b_e = current[:, n] / lad.c
    return a_e, b_e, nodes


@dataclass(frozen=True)
class _Model:
    a: np.ndarray  # (2n, 2n) linear dynamics, states [v; ρ] (V)
    b: np.ndarray  # (2n,)
    c_out: np.ndarray  # (n, 2n): bending charge p_k = C_k (v_k − β ρ_k) (C)
    ladder: _Ladder
    derived: dict


def build_model(p: VirtualIPMCParameters) -> _Model:
    lad = build_ladder(p)
    a_e, b_e, _ = electrical(lad)
    n = len(lad.re)
    eye = np.eye(n)
    a = np.block([[a_e, np.zeros((n, n))], [eye / p.relaxation_time_s, -eye / p.relaxation_time_s]])
    b = np.concatenate([b_e, np.zeros(n)])
    c_out = np.hstack([np.diag(lad.c), -p.relaxation_fraction * np.diag(lad.c)])
    tau = np.sort(-1.0 / np.linalg.eigvals(a_e).real)[::-1]
    t1 = _table1(p)
    derived = {
        "re_clamp_ohm": t1["re_clamp_ohm"],
        "ri_clamp_ohm": t1["ri_clamp_ohm"],
        "rm_ohm": t1["rm_ohm"],
        "c_total_f": float(lad.c.sum()),
        "branch_time_constants_s": [float(np.min(lad.ri * lad.c)), float(np.max(lad.ri * lad.c))],
        "electrical_time_constants_s": [float(x) for x in tau],
    }
    return _Model(a=a, b=b, c_out=c_out, ladder=lad, derived=derived)


class _TipMap:
    """w_qs (mm) from the bending charges p_k (C): tanh curvature, cantilever sum."""

    def __init__(self, weights: np.ndarray, p_sat: float, derived: dict):
        self.weights = weights  # 1e3 K (L − x_k) Δx / (W Δx): mm of tip per coulomb of p_k
        self.p_sat = p_sat  # σ_sat W Δx, saturation bending charge of one compartment (C)
        self.derived = derived

    def __call__(self, p_k: np.ndarray) -> np.ndarray:
        if math.isinf(self.p_sat):
            return p_k @ self.weights
        return np.tanh(p_k / self.p_sat) @ (self.weights * self.p_sat)


def quasi_static_tip(p: VirtualIPMCParameters, model: _Model) -> _TipMap:
    """Derive K and σ_sat from `gain_mm_per_v` and `compression` (static, relaxed)."""
    import scipy.optimize

    lad = model.ladder
    area = p.width_m * lad.dx
    arm = (p.length_m - lad.x) * lad.dx  # (L − x_k) Δx, m²
    p_static = model.c_out @ np.linalg.solve(model.a, -model.b)  # C per volt
    sigma_static = p_static / area  # C/m² per volt
    k_gain = p.gain_mm_per_v * 1e-3 / float(arm @ sigma_static)  # m/C
    weights = 1e3 * k_gain * arm / area  # mm per coulomb of p_k
    if p.compression == 0.0:
        sigma_sat = np.inf
    else:
        s_fs = sigma_static * p.full_scale_v
        r = s_fs / s_fs.max()
        share = arm * s_fs / float(arm @ s_fs)

        def shortfall(y):  # 1 − (static tip at V_fs)/(linear extrapolation), minus target
            return 1.0 - float(share @ (np.tanh(y * r) / (y * r))) - p.compression

        y = scipy.optimize.brentq(
            shortfall, 1e-9, 1.0 / ((1 - p.compression) * r.min()), xtol=1e-14, rtol=1e-14
        )
        sigma_sat = s_fs.max() / y  # C/m²
    derived = {
        "curvature_per_charge_density_m_per_c": k_gain,
        "saturation_charge_density_c_per_m2": float(sigma_sat) if np.isfinite(sigma_sat) else None,
        "static_gain_mm_per_v": p.gain_mm_per_v,
    }
    return _TipMap(weights, float(sigma_sat * area), derived)


def dac_output(v: np.ndarray, p: VirtualIPMCParameters) -> np.ndarray:
    """Applied voltage (V): 2^b-level DAC codes mapped onto ±V_fs, clipped at the rails."""
    top = 2**p.dac_bits - 1
    code = np.clip(np.round((np.asarray(v, float) / p.full_scale_v + 1.0) * top / 2.0), 0, top)
    return p.full_scale_v * (2.0 * code / top - 1.0)


def mechanics(p: VirtualIPMCParameters, h: float, w_qs: np.ndarray) -> np.ndarray:
    """First-mode response on the fine grid, exact for piecewise-linear w_qs (FOH)."""
    import scipy.signal

    wn = 2 * np.pi * p.mode_frequency_hz
    zeta = p.damping_ratio
    a = np.array([[0.0, 1.0], [-wn * wn, -2 * zeta * wn]])
    b = np.array([[0.0], [wn * wn]])
    ad, bd, cd, dd, _ = scipy.signal.cont2discrete(
        (a, b, np.array([[1.0, 0.0]]), np.zeros((1, 1))), h, method="foh"
    )
    num, den = scipy.signal.ss2tf(ad, bd, cd, dd)
    # At rest with w_qs(t_0) = 0: zero filter state is the exact initial condition.
    return scipy.signal.lfilter(num[0], den, w_qs)
