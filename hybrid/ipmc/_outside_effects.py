"""Effects outside the library: physics that no extension of `hybrid.discovery` describes.

An open-world discrepancy search must say "unexplained" when a recording holds
an effect it has no extension for, rather than force it into a known name. These
forms are that test: each is physically motivated, has interpretable parameters,
and is written here on numpy arrays, independently of the extensions (nothing of
`hybrid.discovery` is imported). Each acts on ``s``, the drive-side signal of the
generator (the cascade's V_o in volts, at rest 0, on the fine grid), like the
library's hidden effects in `hybrid.ipmc._synthetic`:

==================  ===========================================================  ==============================
name                form                                                          parameters (drawn range)
==================  ===========================================================  ==============================
``electrostatic``   s + κ s²/S, S = max|s|: a Maxwell stress ∝ charge² beside     ``quadratic_fraction`` κ
                    the linear one; even in s, so no gain or offset absorbs it    (0.15–0.5: the square part at
                                                                                  the peak over the linear part)
``dead_zone``       sign(s)·max(|s| − δ, 0), δ = f·range(s): stiction at the      ``threshold_fraction`` f
                    clamp, no response until the drive-side signal passes δ       (0.03–0.20 of the range)
``rate_dependent``  s / (1 + β r/R), r = |ds/dt| low-passed with time constant    ``stiffening`` β (0.3–1.0),
                    τ_m, R = 95th percentile of r: a polymer that stiffens while  ``memory_s`` τ_m (0.1–1 s,
                    it is strained fast (viscoelastic); neither a linear filter   log-uniform)
                    nor a static map
``self_heating``    s·(1 + γ h/H), h = s² low-passed with time constant τ_th,     ``gain_change`` γ (±0.25–0.6),
                    H = max h: Joule heating by the drive changes the strip's     ``thermal_time_s`` τ_th (3–30 s,
                    coupling; a gain that follows the drive's recent power         log-uniform)
==================  ===========================================================  ==============================

Each form returns the signal and the values it derived from the data (S, δ, R,
H), which the recording's metadata keeps beside the drawn parameters: the ground
truth in the signal's own units. Given those values (``derived=``, from an earlier
recording of the strip), a form uses them instead: another drive then meets the
same physical strip (`hybrid.ipmc.rerecord`), not one rescaled to its own range.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np


def lowpass(u: np.ndarray, tau: float, dt: float) -> np.ndarray:
    """x[n] = a x[n−1] + (1 − a) u[n], a = exp(−dt/τ), from rest: a first-order memory of `u`."""
    import scipy.signal

    a = math.exp(-dt / tau)
    return scipy.signal.lfilter([1.0 - a], [1.0, -a], u)


def _log_uniform(rng, low, high):
    return math.exp(rng.uniform(math.log(low), math.log(high)))


def _electrostatic(p, s, dt, t, d):
    peak = float(np.max(np.abs(s))) if d is None else d["peak_v"]
    if peak == 0.0:
        return s.copy(), {"peak_v": 0.0, "quadratic_per_v": 0.0}
    k = p["quadratic_fraction"] / peak
    return s + k * s * s, {"peak_v": peak, "quadratic_per_v": k}


def _dead_zone(p, s, dt, t, d):
    delta = p["threshold_fraction"] * float(np.ptp(s)) if d is None else d["threshold_v"]
    return np.sign(s) * np.maximum(np.abs(s) - delta, 0.0), {"threshold_v": delta}


def _rate_dependent(p, s, dt, t, d):
    rate = np.abs(np.diff(s, prepend=s[0])) / dt
    r = lowpass(rate, p["memory_s"], dt)
    # a rate the strip often reaches: β is the stiffening there
    top = float(np.quantile(r, 0.95)) if d is None else d["reference_rate_v_per_s"]
    if top == 0.0:
        return s.copy(), {"reference_rate_v_per_s": 0.0}
    return s / (1.0 + p["stiffening"] * r / top), {"reference_rate_v_per_s": top}


def _self_heating(p, s, dt, t, d):
    h = lowpass(s * s, p["thermal_time_s"], dt)
    top = float(np.max(h)) if d is None else d["reference_heat_v2"]
    if top == 0.0:
        return s.copy(), {"reference_heat_v2": 0.0}
    return s * (1.0 + p["gain_change"] * h / top), {"reference_heat_v2": top}


@dataclasses.dataclass(frozen=True)
class OutsideForm:
    """An effect outside the library: its draw from the stated ranges and its form."""

    name: str
    summary: str
    draw: Callable[[np.random.Generator, float], dict]
    form: Callable[[dict, np.ndarray, float, np.ndarray, dict | None], tuple[np.ndarray, dict]]

    def apply(
        self, params: dict, s: np.ndarray, dt: float, t: np.ndarray, derived: dict | None = None
    ) -> tuple[np.ndarray, dict]:
        """(the signal after the effect, the values derived from the data) for `s` on a grid of step `dt`.

        `derived`: the values as an earlier recording derived them (the same
        strip under another drive); None derives them from `s`.
        """
        return self.form(params, np.asarray(s, dtype=float), float(dt), t, derived)


#: The effects outside the library, by name.
OUTSIDE_EFFECTS: dict[str, OutsideForm] = {
    f.name: f
    for f in (
        OutsideForm(
            "electrostatic",
            "w ∝ s + κ s²/max|s|: a part even in the drive (Maxwell stress ∝ charge²)",
            lambda rng, rate: {"quadratic_fraction": rng.uniform(0.15, 0.5)},
            _electrostatic,
        ),
        OutsideForm(
            "dead_zone",
            "no response while |s| < δ = f·range(s) (stiction), s ∓ δ beyond",
            lambda rng, rate: {"threshold_fraction": rng.uniform(0.03, 0.20)},
            _dead_zone,
        ),
        OutsideForm(
            "rate_dependent",
            "stiffness 1 + β·(recent |ds/dt|)/R, R its 95th percentile: the faster the strain, the smaller w",
            lambda rng, rate: {"stiffening": rng.uniform(0.3, 1.0), "memory_s": _log_uniform(rng, 0.1, 1.0)},
            _rate_dependent,
        ),
        OutsideForm(
            "self_heating",
            "gain 1 + γ·(recent s²)/max: Joule heating by the drive changes the coupling",
            lambda rng, rate: {
                "gain_change": float(rng.uniform(0.25, 0.6) * rng.choice([-1.0, 1.0])),
                "thermal_time_s": _log_uniform(rng, 3.0, 30.0),
            },
            _self_heating,
        ),
    )
}
