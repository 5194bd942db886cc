"""Synthetic strips with a hidden effect: the data the discrepancy search must see through.

A recording is made the way a lab would see a strip, independently of the
models fitted to it:

1. the drive (camera rate, held by the DAC) on a fine grid `oversample` times
   the camera rate; a dead time shifts it there (``delay``);
2. the paper's RC cascade (Eqs 4–14; continuous matrices from
   ``RCNetwork.state_space``) discretised *exactly* (zero-order hold, matrix
   exponential in scipy) on the fine grid and run in numpy — not the Tustin
   scan the fitter uses;
3. the hidden effect, in a functional form *different* from the extension in
   [`hybrid.discovery._effects`][] that is meant to find it:

   ==================  ==================================================  ==========================
   effect              here                                                extension that finds it
   ==================  ==================================================  ==========================
   ``back_relaxation``  two exponentials, τ/2 and 2τ, equal weights          one exponential
   ``hysteresis``       Preisach model: 12 play operators, widths up to     Bouc–Wen
                        30 % of the range
   ``saturation``       algebraic s/√(1 + (s/σ±)²), asymmetric              tanh, asymmetric
   ``delay``            dead time on the drive, whole fine-grid samples     interpolated delay of V_o
   ``drift``            gain 1 ± δ·smoothstep(t/T) or 1 ± δ t/T             exponential gain
   ``resonance``        mode discretised by ZOH on the fine grid            first-order hold at camera rate
   ==================  ==================================================  ==========================

4. gain (mm/V) and offset; a camera that integrates over its exposure and
   samples at the recording rate; Gaussian noise.

Some forms take a scale from the signal they act on (a saturation's σ± from
the drive-side signal's peaks, a Preisach loop's widths from its span; the
noise std from the displacement's range): the recording keeps them
(``metadata["hidden"]["derived"]``, ``["noise_std"]``), and
`hybrid.ipmc.rerecord` records the same strip under another drive with them,
as a second run on one rig would be.

Several hidden effects at once (``"back_relaxation+saturation"``) and effects
outside the library (``electrostatic``, ``dead_zone``, ``rate_dependent``,
``self_heating``: `hybrid.ipmc._outside_effects`) are made by
`hybrid.ipmc._hidden_pairs` with the same steps, the effects in physical order;
`synthetic_recording` and `random_effect` send such specs there.

Parameters are drawn from the ranges of the discrepancy issue: ξρ/ξh 1–100,
α 0.1–0.9, C_clamp 1 mF–1 F, gain 0.3–5 mm/V; back-relaxation τ 3–60 s,
20–100 %; hysteresis 5–30 % of the range; saturation 10–50 % below linear at
the largest drive; delay 1–15 samples; drift 15–60 %; resonance 1–10 Hz,
ζ 0.02–0.3.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

HIDDEN_EFFECTS = ("none", "back_relaxation", "hysteresis", "saturation", "delay", "drift", "resonance")


@dataclasses.dataclass(frozen=True)
class SyntheticStrip:
    """A strip: RC parameters (Table 1 geometry), electromechanical gain and offset."""

    xi_rho: float = 10.0
    xi_h: float = 1.0
    alpha_E: float = 0.5
    alpha_I: float = 0.5
    alpha_C: float = 0.5
    C_clamp: float = 0.05
    gain_mm_per_v: float = 2.0
    offset_mm: float = 0.0


def discrepancy_drive(duration: float = 60.0, rate: float = 30.0, seed: int = 0, amplitude: float = 2.0):
    """The drive of the discrepancy tests and experiment: multilevel PRBS, holds 0.5–10 s.

    Steps reveal a dead time and excite a mode, holds show a relaxation, and
    random levels reached from above and from below separate saturation from
    hysteresis.
    """
    from ..data._paper_drives import prbs

    return prbs(
        duration, rate=rate, amplitude=amplitude, min_hold=0.5, max_hold=10.0, levels="multilevel", seed=seed
    )


def random_strip(rng: np.random.Generator) -> SyntheticStrip:
    """A strip from the issue's ranges (log-uniform where the range spans decades)."""
    ratio = math.exp(rng.uniform(math.log(1.0), math.log(100.0)))
    xi_h = math.exp(rng.uniform(math.log(0.5), math.log(5.0)))
    return SyntheticStrip(
        xi_rho=ratio * xi_h,
        xi_h=xi_h,
        alpha_E=rng.uniform(0.1, 0.9),
        alpha_I=rng.uniform(0.1, 0.9),
        alpha_C=rng.uniform(0.1, 0.9),
        C_clamp=math.exp(rng.uniform(math.log(1e-3), math.log(1.0))),
        gain_mm_per_v=rng.uniform(0.3, 5.0) * rng.choice([-1.0, 1.0]),
        offset_mm=rng.uniform(-0.5, 0.5),
    )


def random_effect(name: str, rng: np.random.Generator, rate: float) -> dict:
    """Parameters of a hidden effect drawn from the issue's ranges (outside names and "a+b": `random_hidden`)."""
    if name == "none":
        return {}
    if name == "back_relaxation":
        return {
            "tau_s": math.exp(rng.uniform(math.log(3.0), math.log(60.0))),
            "fraction": rng.uniform(0.2, 1.0),
        }
    if name == "hysteresis":
        return {"height_fraction": rng.uniform(0.05, 0.30)}
    if name == "saturation":
        strong = rng.uniform(0.10, 0.50)
        weak = strong * rng.uniform(0.3, 1.0)
        pos, neg = (strong, weak) if rng.random() < 0.5 else (weak, strong)
        return {"shortfall_pos": pos, "shortfall_neg": neg}
    if name == "delay":
        return {"delay_samples": int(rng.integers(1, 16))}
    if name == "drift":
        return {
            "change": rng.uniform(0.15, 0.60) * rng.choice([-1.0, 1.0]),
            "shape": str(rng.choice(["linear", "smoothstep"])),
        }
    if name == "resonance":
        top = min(10.0, 0.35 * rate)
        return {
            "frequency_hz": math.exp(rng.uniform(math.log(1.0), math.log(top))),
            "damping": rng.uniform(0.02, 0.3),
        }
    # An effect outside the library or several at once ("a+b"): see `hybrid.ipmc._hidden_pairs`.
    from ._hidden_pairs import random_hidden

    return random_hidden(name, rng, rate)


# --------------------------------------------------------------------------- #
# Building blocks (numpy / scipy, independent of the JAX models)
# --------------------------------------------------------------------------- #


def _zoh(a, b, dt):
    import scipy.linalg

    n = a.shape[0]
    m = np.zeros((n + 1, n + 1))
    m[:n, :n], m[:n, n] = a, b
    e = scipy.linalg.expm(m * dt)
    return e[:n, :n], e[:n, n]


@functools.lru_cache(maxsize=64)
def _state_space(strip: SyntheticStrip):
    """The cascade's continuous (A, B, C, D) for `strip`, read-only numpy (cached: one strip, many effects)."""
    from ..physics._rc_network import RCNetwork

    network = RCNetwork(strip.xi_rho, strip.xi_h, strip.alpha_E, strip.alpha_I, strip.alpha_C, strip.C_clamp)
    matrices = tuple(np.asarray(x, dtype=float) for x in network.state_space())
    for x in matrices:
        x.flags.writeable = False
    return matrices


def rc_cascade_exact(strip: SyntheticStrip, v_fine: np.ndarray, dt_fine: float) -> np.ndarray:
    """V_o of the paper's cascade on the fine grid, exact for a drive held per fine sample."""
    import scipy.signal

    a, b, c, d = _state_space(strip)
    phi, gamma = _zoh(a, b, dt_fine)
    # x[n+1] = Φ x[n] + Γ u[n] over the fine grid, outputs y[n] = C x[n] + D u[n].
    _, y, _ = scipy.signal.dlsim((phi, gamma[:, None], c[None, :], np.atleast_2d(d), dt_fine), v_fine)
    return y[:, 0]


def _lowpass_exact(s, tau, dt):
    import scipy.signal

    a = math.exp(-dt / tau)
    x = scipy.signal.lfilter([0.0, 1.0 - a], [1.0, -a], s)
    return x


def _play(s, r):
    out = np.empty_like(s)
    p = s[0]
    for i, x in enumerate(s):
        p = min(max(p, x - r), x + r)
        out[i] = p
    return out


def hidden_derived(name: str, p: dict, s: np.ndarray) -> dict:
    """The values a hidden effect's form takes from the signal it acts on, in the signal's units.

    A saturation's σ± (V: the shortfall is drawn at this signal's peaks) and a
    Preisach loop's span (V: its play widths are fractions of it); {} for the
    forms that take nothing from the signal. A second recording of the same strip
    reuses the first's (`apply_hidden`'s `derived`), so the physics stays put
    when the drive changes.
    """
    s = np.asarray(s, dtype=float)
    if name == "hysteresis":
        return {"span_v": float(np.ptp(s))}
    if name == "saturation":
        sigma = {}
        for side, sign in (("pos", 1.0), ("neg", -1.0)):
            peak = float(np.max(sign * s))
            # shortfall f at the peak: 1 − 1/√(1 + x²) = f  →  x = √(1/(1 − f)² − 1), σ = peak / x
            x = math.sqrt(1.0 / (1.0 - p[f"shortfall_{side}"]) ** 2 - 1.0)
            sigma[f"sigma_{side}_v"] = peak / x if peak > 0 else None  # this side never driven
        return sigma
    return {}


def apply_hidden(name, p, s, dt, t, derived: dict | None = None):
    """The signal `s` (fine grid, step `dt`, times `t`) after the hidden effect `name` with parameters `p`.

    `derived`: the values the form takes from the signal (`hidden_derived`), as an
    earlier recording of the strip derived them; None derives them from `s`.
    """
    import scipy.signal

    d = hidden_derived(name, p, s) if derived is None else derived
    if name == "back_relaxation":
        slow = 0.5 * _lowpass_exact(s, p["tau_s"] / 2, dt) + 0.5 * _lowpass_exact(s, 2 * p["tau_s"], dt)
        return s - p["fraction"] * slow
    if name == "hysteresis":
        span = d["span_v"]
        widths = np.linspace(1, 12, 12) / 12 * 0.3 * span
        plays = np.stack([_play(s, r) for r in widths])
        c = p["height_fraction"] * span / (2 * widths.mean())
        return s + c * np.mean(plays - s, axis=0)
    if name == "saturation":
        out = s.copy()
        for side, sign in (("pos", 1.0), ("neg", -1.0)):
            sigma = d[f"sigma_{side}_v"]
            mask = sign * s > 0
            if sigma is not None:
                out[mask] = s[mask] / np.sqrt(1.0 + (s[mask] / sigma) ** 2)
        return out
    if name == "drift":
        u = (t - t[0]) / (t[-1] - t[0])
        shape = u if p["shape"] == "linear" else u * u * (3 - 2 * u)
        return s * (1.0 + p["change"] * shape)
    if name == "resonance":
        w, z = 2 * math.pi * p["frequency_hz"], p["damping"]
        a = np.array([[0.0, 1.0], [-w * w, -2 * z * w]])
        b = np.array([0.0, w * w])
        phi, gamma = _zoh(a, b, dt)
        _, y, _ = scipy.signal.dlsim(
            (phi, gamma[:, None], np.array([[1.0, 0.0]]), np.zeros((1, 1)), dt), s, x0=np.array([s[0], 0.0])
        )
        return y[:, 0]
    return s


def fine_drive(v: np.ndarray, oversample: int, delay_samples: int = 0) -> np.ndarray:
    """The drive held on the fine grid, shifted by a dead time of `delay_samples` camera samples."""
    v_fine = np.repeat(v, oversample)
    shift = int(delay_samples) * oversample
    if shift:
        v_fine = np.concatenate([np.zeros(shift), v_fine[:-shift]])  # at rest before the drive
    return v_fine


def camera(
    w_fine,
    oversample: int,
    exposure_fraction: float,
    noise_fraction: float,
    seed: int,
    noise_std: float | None = None,
):
    """(w_true, noise, its std): what the camera sees of the fine-grid displacement, and its Gaussian noise.

    Sample n (time n/rate) averages the fine grid over the exposure ending at it.
    The noise std is `noise_std` (mm) where given (an earlier recording's: the
    camera does not change with the drive), else `noise_fraction` × the range of w_true.
    """
    m = int(oversample)
    k = max(1, int(round(exposure_fraction * m)))
    padded = np.concatenate([np.full(k - 1, w_fine[0]), w_fine])
    averaged = np.convolve(padded, np.ones(k) / k, mode="valid")
    w_true = averaged[::m]
    rng = np.random.default_rng(seed)
    std = float(noise_fraction * np.ptp(w_true) if noise_std is None else noise_std)
    return w_true, std * rng.standard_normal(len(w_true)), std


def synthetic_recording(
    drive,
    strip: SyntheticStrip = SyntheticStrip(),
    effect: str = "none",
    effect_params: dict | None = None,
    *,
    noise_fraction: float = 0.01,
    oversample: int = 8,
    exposure_fraction: float = 0.5,
    seed: int = 0,
):
    """A Recording of `strip` under `drive` with a hidden `effect`.

    **Arguments:**

    - `drive`: a [`hybrid.Drive`][] (its rate is the camera's).
    - `strip`: RC parameters, gain and offset.
    - `effect`: one of `HIDDEN_EFFECTS`, an effect outside the library
      (``electrostatic``, …) or several at once (``"back_relaxation+saturation"``);
      `effect_params` as from [`random_effect`][]. Made by
      `hybrid.ipmc._hidden_pairs.compound_recording`.
    - `noise_fraction`: noise std as a fraction of the displacement's range.
    - `oversample`: fine-grid points per camera sample.
    - `exposure_fraction`: exposure time as a fraction of the frame interval; each
      sample averages the displacement over the exposure ending at its time stamp.
    - `seed`: seeds the noise.

    The truth (effect, its parameters, the values its form derived from the
    signal, the strip, the noise std, the noise-free w) is in ``metadata["hidden"]``
    and ``extra["w_true"]``; [`rerecord`][] records the same strip under another drive.
    """
    from ._hidden_pairs import compound_recording  # one recipe for one effect, several, or none

    return compound_recording(
        drive,
        strip,
        effect,
        effect_params,
        noise_fraction=noise_fraction,
        oversample=oversample,
        exposure_fraction=exposure_fraction,
        seed=seed,
    )
