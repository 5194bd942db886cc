r"""A virtual IPMC strip: the simulated "ground truth" that the project's models are fitted to.

The virtual strip is deliberately *richer* than the paper's hybrid model (an
unloaded cascade of first-order RC sections, Eq 14, feeding a D-MLP with a 2 s
window) and is implemented *independently* of it (numpy/scipy only; the
Table 1 constants are written out here again). It is still a plausible IPMC, so
the hybrid model can fit it, while a model that only sees the last 2 s of the
drive cannot (the back-relaxation below is slower than 2 s).

Signal chain (all units SI unless the name says otherwise)::

    v_drive ─DAC+amp→ u(t) ─loaded RC line→ v_k(t) ─back-diffusion→ p_k(t)
            ─tanh→ κ_k(t) ─cantilever→ w_qs(t) ─first mode→ w(t) ─camera→ w_j + noise

1. Actuation (12-bit DAC + amplifier, as in the paper's rig). A command v (V)
   becomes the DAC code c = clip(round((v/V_fs + 1)(2^b − 1)/2), 0, 2^b − 1)
   (codes 0..4095 over 0..V_ref = 0..5 V), and the shifted/amplified output is
   u = V_fs (2c/(2^b − 1) − 1) ∈ [−V_fs, +V_fs] (V_fs = 3 V): quantisation step
   2V_fs/(2^b − 1) = 1.465 mV, clipping at the rails, and a zero-order hold
   between drive samples (the DAC updates at the drive's sample times).

2. Loaded RC transmission line (not the paper's unloaded cascade). The strip
   is cut into N+1 compartments k = 0..N of length Δx = L/(N+1), centred at
   x_k = (k + ½)Δx. The paper's linear profiles (Eqs 4–9) give the clamp→tip
   values, with Table 1's constants::

       RE_clamp = ρ_E L / (W h_E)            = 0.424 Ω
       RI_clamp = (ξρ/ξh) ρ_E L / (W h_E)    = 8.48 Ω     (ξρ/ξh = 20)
       R_M      = L / (σ_M W h_M)            = 2130 Ω
       X(k)     = X_clamp + (X_clamp/α_X − X_clamp) k/N,  X ∈ {RE, RI, C}   (Eqs 4–9)

   **Choice: the Table 1 quantities are whole-strip values, split per
   compartment.** RE(k), RI(k), C(k), R_M are what the whole strip would have
   with the local properties of compartment k; compartment k covers Δx/L of the
   strip, so its series electrode resistance is RE_k = RE(k)/(N+1), its
   interface resistance (across the thickness, over Δx·W) RI_k = RI(k)(N+1),
   its double-layer capacitance C_k = C(k)/(N+1) and its membrane shunt
   R_M,k = R_M (N+1). The network's totals
   and time constants are then independent of N (it converges to the
   continuous line). (The paper's cascade instead uses the unsplit values in
   every stage.) Each branch's time constant RI_k C_k = RI(k) C(k) is unchanged
   by the split.

   Circuit: the amplifier (through R_s, output + clamp-contact resistance) and
   RE_0 feed node 0; RE_k joins node k−1 to node k; node k is shunted to the
   return electrode by R_M,k and by RI_k in series with C_k; the tip (node N)
   is open. With node voltages V_k and capacitor voltages v_k (the states)::

       KCL at node k:  (V_{k−1} − V_k)/RE_k − (V_k − V_{k+1})/RE_{k+1}
                        − V_k/R_M,k − (V_k − v_k)/RI_k = 0,
                        V_{−1} ≡ u, RE_0 → R_s + RE_0, no RE_{N+1} term
       capacitor k:    C_k dv_k/dt = (V_k − v_k)/RI_k

   i.e. G V = D v + b u with G tridiagonal (conductances), D = diag(1/RI_k),
   b = e_0/(R_s + RE_0), so V = G⁻¹(D v + b u) and

       dv/dt = A_e v + B_e u,   A_e = C⁻¹(D G⁻¹ D − D),   B_e = C⁻¹ D G⁻¹ b.

   A_e is similar to a symmetric negative-definite matrix, so its modes are
   real decays with time constants between min and max of RI_k C_k (plus the
   loading by R_s and the RE_k). Default C_clamp = 20 mF (16.5 mF/cm² at the
   clamp end, 33 mF/cm² at the tip, 30 mF in total: large but plausible for a
   Pt–Nafion double layer; chosen for the time constants) gives RI_k C_k from
   0.17 s (clamp) to 0.57 s (tip) and electrical time constants (eigenvalues
   of A_e) from 0.17 s to 0.57 s.
   The stored charge is q_k = C_k v_k (C).

3. Slow charge dynamics (back-diffusion), one state ρ_k (V) per compartment::

       τ_b dρ_k/dt = v_k − ρ_k,      p_k = C_k (v_k − β ρ_k)        (C)

   p_k is the charge that bends the strip: under a held voltage it relaxes
   from q_k to (1 − β) q_k with time constant τ_b (default τ_b = 6 s, β = 0.25).
   The full linear system, x = [v_0..v_N, ρ_0..ρ_N] (V), is
   dx/dt = A x + B u, A = [[A_e, 0], [I/τ_b, −I/τ_b]], B = [B_e; 0].

4. Electromechanical coupling (nonlinear, static). With the bending charge
   density σ_k = p_k/(W Δx) (C/m²)::

       κ_k  = K σ_sat tanh(σ_k/σ_sat)                 curvature, 1/m
       w_qs = Σ_k κ_k (L − x_k) Δx                    quasi-static tip displacement, m

   (small-deflection cantilever kinematics). K (m/C) and σ_sat (C/m²) are
   derived from two user-facing numbers: `gain_mm_per_v`, the small-signal
   static (DC, fully relaxed) tip displacement per volt (default 2 mm/V; the
   small-signal step response peaks at 2.5 mm/V after ≈ 1.5 s, then relaxes to
   2 mm/V), and `compression`, the static shortfall at ±V_fs relative to that
   small-signal slope, 1 − w_qs(V_fs)/(V_fs · gain) (default 0.15 at 3 V;
   0.075 at 2 V). At the peak of a step the shortfall is larger: 0.21 at 3 V,
   0.11 at 2 V. A ±2 V PRBS-like drive spans about ±4.9 mm: reversals
   overshoot the single-step peak of 4.5 mm because the slow state still holds
   the previous polarity.

5. Mechanics: the tip follows w_qs through a well-damped first mode::

       ẅ + 2ζω_n ẇ + ω_n² w = ω_n² w_qs,   ω_n = 2π · 12 Hz, ζ = 0.6.

6. Simulation and camera. Time advances on an internal grid of step
   h = Δt_drive / oversample (default 16 × 30 Hz = 480 Hz). The linear part is
   exact: x(t_n + m h) = Φ(mh) x(t_n) + Γ(mh) u_n from the matrix exponential
   of the augmented [[A, B], [0, 0]] (exact ZOH for the DAC's piecewise-constant
   u); the nonlinearity is applied pointwise on the grid and the mechanical mode
   is discretised exactly for a w_qs that is piecewise linear between grid
   points (first-order hold). The camera frame j (default: at every drive
   sample, 30 fps; or at `camera_fps`) integrates the displacement over its
   exposure [t_j, t_j + T_exp] (default T_exp = 1/60 s; w taken piecewise linear
   between grid points) and reports the mean.

7. Measurement noise: w_j = w_true,j + ε_j, ε_j ~ N(0, s²), s = 0.02 mm
   (≈ 0.2 % of the ≈ 10 mm range of a ±2 V drive), seeded; optional rounding
   to the camera's pixel scale (`pixel_mm`, default off).

The strip starts at rest (all states zero) at the first drive sample.

The parameters, with their defaults, are `VirtualIPMCParameters`
(`hybrid.ipmc._virtual_parameters`).
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..util._errors import InputError
from ._virtual_elements import build_model, dac_output, mechanics, quasi_static_tip
from ._virtual_parameters import VirtualIPMCParameters

__all__ = ["VirtualRecording", "simulate_virtual_ipmc"]

_CHUNK_INTERVALS = 1024  # drive intervals per block of the fine-grid output map


@dataclass(frozen=True)
class VirtualRecording:
    """One recording of the virtual strip, sampled by the camera.

    **Arguments:**

    - `t`: frame times (s), shape (frames,).
    - `v_in`: the voltage actually applied at each frame time, after DAC
      quantisation and clipping (V), shape (frames,).
    - `w`: measured tip displacement, with noise (mm), shape (frames,).
    - `w_true`: noise-free, exposure-averaged tip displacement (mm).
    - `metadata`: parameters, seed, rates and derived quantities (JSON-able).
    """

    t: np.ndarray
    v_in: np.ndarray
    w: np.ndarray
    w_true: np.ndarray
    metadata: dict


def simulate_virtual_ipmc(
    t_drive, v_drive, params: VirtualIPMCParameters = VirtualIPMCParameters(), seed: int = 0
) -> VirtualRecording:
    """Record the virtual strip's tip displacement under a commanded drive.

    **Arguments:**

    - `t_drive`: uniform, increasing sample times of the drive (s), ≥ 2 samples.
      The DAC updates at these times and holds each value for one interval
      (the last one too).
    - `v_drive`: commanded voltage at each sample (V); values beyond
      ±`params.full_scale_v` are clipped by the amplifier rails.
    - `params`: a `VirtualIPMCParameters`.
    - `seed`: seed of the measurement noise (int ≥ 0).

    **Returns:**

    A `VirtualRecording`; with the default `camera_fps=None` it has one frame
    per drive sample and `t` equals `t_drive`.
    """
    if not isinstance(params, VirtualIPMCParameters):
        raise InputError(
            f"params must be a VirtualIPMCParameters, not {type(params).__name__}; "
            "build one with VirtualIPMCParameters(...)."
        )
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or seed < 0:
        raise InputError(f"seed must be a non-negative integer, not {seed!r}; pass e.g. seed=0.")
    t, v, dt = _check_drive(t_drive, v_drive)
    frame_period = dt if params.camera_fps is None else 1.0 / params.camera_fps
    if params.exposure_s > frame_period * (1 + 1e-9):
        raise InputError(
            f"exposure_s = {params.exposure_s} s is longer than the frame period "
            f"{frame_period:.4g} s of this drive's rate; use an exposure no longer than one frame "
            f"(exposure_s=..., on the command line --param exposure_s={frame_period:.4g})"
        )

    u = dac_output(v, params)
    model = build_model(params)
    os_ = params.oversample
    h = dt / os_
    reduce = quasi_static_tip(params, model)
    w_qs = fine_outputs(model.a, model.b, model.c_out, u, h, os_, reduce)  # mm
    w_fine = mechanics(params, h, w_qs)

    # Frames: exposure windows [t_j, t_j + T_exp] in units of the fine step.
    m = len(t)
    horizon = m * os_
    period_steps = frame_period / h
    expo_steps = params.exposure_s / h
    if params.camera_fps is None:
        n_frames = m
        t_frames = t.copy()
    else:
        n_frames = int(math.floor((horizon - expo_steps) / period_steps + 1e-9)) + 1
        t_frames = t[0] + np.arange(n_frames) / params.camera_fps
    start = np.arange(n_frames) * period_steps
    w_true = _expose(w_fine, start, expo_steps)
    dac_index = np.minimum(np.floor(start / os_ + 1e-9).astype(int), m - 1)
    v_in = u[dac_index]

    rng = np.random.default_rng(int(seed))
    w = w_true + params.noise_std_mm * rng.standard_normal(n_frames)
    if params.pixel_mm is not None:
        w = np.round(w / params.pixel_mm) * params.pixel_mm

    metadata = {
        "model": "hybrid.ipmc._virtual_ipmc",
        "parameters": {
            k: (v.item() if isinstance(v, np.generic) else v) for k, v in dataclasses.asdict(params).items()
        },
        "seed": int(seed),
        "drive_rate_hz": 1.0 / dt,
        "camera_fps": 1.0 / frame_period,
        "internal_rate_hz": 1.0 / h,
        "n_frames": int(n_frames),
        "t0_s": float(t[0]),
        "derived": model.derived | reduce.derived,
    }
    return VirtualRecording(t=t_frames, v_in=v_in, w=w, w_true=w_true, metadata=metadata)


# ----------------------------------------------------------------------------------------
# Time stepping and camera (private; the tests check each against an independent reference).


def _zoh(a: np.ndarray, b: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact ZOH step: expm([[A, B], [0, 0]] h) = [[Φ, Γ], [0, 1]]."""
    import scipy.linalg

    n = len(b)
    aug = np.zeros((n + 1, n + 1))
    aug[:n, :n] = a * h
    aug[:n, n] = b * h
    e = scipy.linalg.expm(aug)
    return e[:n, :n], e[:n, n]


def fine_outputs(a, b, c_out, u, h, oversample, reduce: Callable | None = None):
    """y = reduce(C x) on the fine grid t_0 + i h, i = 0..M·oversample, exact ZOH.

    The input u[n] (M values) is held over [t_n, t_n + oversample·h). States
    at the drive samples come from an M-step recursion with Φ(Δt); the
    `oversample` points inside each interval from one matrix product per block
    of intervals: y[n, m] = C Φ(mh) x_n + C Γ(mh) u_n.
    """
    nx = len(b)
    phi_h, gam_h = _zoh(a, b, h)
    phis = [np.eye(nx)]
    gams = [np.zeros(nx)]
    for _ in range(oversample):
        phis.append(phi_h @ phis[-1])
        gams.append(phi_h @ gams[-1] + gam_h)
    phi_dt, gam_dt = phis[-1], gams[-1]
    m = len(u)
    x = np.empty((m + 1, nx))
    x[0] = 0.0
    phi_t = phi_dt.T.copy()
    for n in range(m):  # M small matvecs: a few ms for M = 9000
        x[n + 1] = x[n] @ phi_t + gam_dt * u[n]
    ny = c_out.shape[0]
    out_x = np.concatenate([c_out @ phis[j] for j in range(oversample)], axis=0).T  # (nx, os·ny)
    out_u = np.concatenate([c_out @ gams[j] for j in range(oversample)])  # (os·ny,)
    parts = []
    for s in range(0, m, _CHUNK_INTERVALS):
        e = min(s + _CHUNK_INTERVALS, m)
        y = (x[s:e] @ out_x + u[s:e, None] * out_u).reshape(-1, ny)
        parts.append(y if reduce is None else reduce(y))
    last = (c_out @ x[m])[None, :]
    parts.append(last if reduce is None else reduce(last))
    return np.concatenate(parts, axis=0)


def _expose(w: np.ndarray, start: np.ndarray, length: float) -> np.ndarray:
    """Mean of the piecewise-linear interpolant of w over [start, start + length].

    Positions are in units of the fine step (w[i] at position i).
    """
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]))])

    def integral(pos):
        i = np.clip(np.floor(pos).astype(int), 0, len(w) - 2)
        f = pos - i
        return cum[i] + w[i] * f + 0.5 * (w[i + 1] - w[i]) * f * f

    if length == 0.0:
        i = np.clip(np.floor(start).astype(int), 0, len(w) - 2)
        f = start - i
        return w[i] + (w[i + 1] - w[i]) * f
    return (integral(start + length) - integral(start)) / length


def _check_drive(t_drive, v_drive) -> tuple[np.ndarray, np.ndarray, float]:
    try:
        t = np.asarray(t_drive, dtype=float)
        v = np.asarray(v_drive, dtype=float)
    except (TypeError, ValueError):
        raise InputError(
            "t_drive and v_drive must be 1-D arrays of numbers; convert them "
            "with np.asarray(..., dtype=float)."
        ) from None
    if t.ndim != 1 or v.ndim != 1:
        raise InputError(
            f"t_drive and v_drive must be 1-D, got shapes {t.shape} and "
            f"{v.shape}; pass one drive as two 1-D arrays."
        )
    if t.shape != v.shape:
        raise InputError(
            f"t_drive has {t.size} samples but v_drive has {v.size}; give one voltage per sample time."
        )
    if t.size < 2:
        raise InputError(
            f"the drive has {t.size} sample(s); give at least 2 so that the sample interval is defined."
        )
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(v))):
        raise InputError(
            "t_drive and v_drive contain NaN or infinite values; remove or "
            "interpolate them before simulating."
        )
    step = np.diff(t)
    dt = (t[-1] - t[0]) / (t.size - 1)
    if dt <= 0 or np.max(np.abs(step - dt)) > 1e-6 * dt:
        raise InputError(
            "t_drive must be increasing with a uniform step; resample the drive onto a uniform time grid."
        )
    return t, v, float(dt)


def virtual_recording(drive, params: VirtualIPMCParameters = VirtualIPMCParameters(), seed: int = 0):
    """A [`hybrid.Recording`][] of the virtual strip driven by a [`hybrid.Drive`][].

    `v_in` is the voltage actually applied (after DAC quantisation and clipping),
    `w` the measured displacement; the noise-free displacement is kept as the
    extra channel ``w_true``.
    """
    from ..data._recording import Recording

    virtual = simulate_virtual_ipmc(drive.t, drive.v, params, seed=seed)
    metadata = {
        "source": f"virtual IPMC, {drive.name} drive, seed {seed}",
        "drive": {"name": drive.name, "params": drive.params},
        "virtual_ipmc": virtual.metadata,
    }
    return Recording(
        t=virtual.t,
        v_in=virtual.v_in,
        w=virtual.w,
        extra={"w_true": virtual.w_true},
        metadata=metadata,
    )
