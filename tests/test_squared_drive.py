"""A drive squared before the RC network (an electrostatic force ∝ V²) is named `drive_even`.

A squared drive gives the effect-free fit nothing odd to follow: the network's
fit lands far from the plant's dynamics (held-out NMSE above 1), and
`drive_even` switched on from there stays in that basin. Its screened start
(the network's design screened jointly with the mostly and the purely even map)
is what finds it. The draw is `experiments/inside_effects.py` rc_square seed 1,
which named nothing before the screen; the plant is the paper's network written
here as a linear ODE from Eqs 4–13 and discretised exactly by scipy's ZOH, never
by the library's simulations (it matches the experiment's `solve_ivp` plant to
4e-8 of the range).
"""

from __future__ import annotations

import numpy as np
import scipy.signal

import hybrid

RATE, SECONDS, STAGES = 30.0, 60.0, 45


def network(c_clamp: float, xi_rho: float, alphas) -> tuple:
    """(A, B, C, D) of the network from the drive to the tip voltage, its 46 double-layer voltages the states."""
    strip = hybrid.Strip()  # Table 1's strip: its resistances only
    a_e, a_i, a_c = alphas
    frac = np.arange(STAGES + 1) / STAGES
    re = strip.RE_clamp * (1 + (1 / a_e - 1) * frac)
    ri = float(strip.RI_clamp(xi_rho, 1.0)) * (1 + (1 / a_i - 1) * frac)
    cap = c_clamp * (1 + (1 / a_c - 1) * frac)
    gain = 1 / (1 + re / strip.R_M + re / ri)
    zero, pole = 1 / (ri * cap), 1 / (cap * (ri + re * strip.R_M / (re + strip.R_M)))

    def rates(x, v):  # each section's node voltage feeds the next; the last is the tip's
        dx = np.empty(STAGES + 1)
        for k in range(STAGES + 1):
            dx[k] = gain[k] * zero[k] * v - pole[k] * x[k]
            v = gain[k] * v + (1 - pole[k] / zero[k]) * x[k]
        return dx, v

    columns = [rates(e, 0.0) for e in np.eye(STAGES + 1)]  # linear: its matrices column by column
    b, d = rates(np.zeros(STAGES + 1), 1.0)
    a = np.stack([c[0] for c in columns], axis=1)
    return a, b[:, None], np.array([[c[1] for c in columns]]), np.array([[d]])


def test_a_squared_drive_through_the_rc_network_is_named_drive_even():
    rng = np.random.default_rng(2001)  # experiments/inside_effects.py's draw for rc_square seed 1
    c_clamp = float(np.exp(rng.uniform(np.log(0.01), np.log(0.06))))
    xi_rho = rng.uniform(5.0, 30.0)
    alphas = rng.uniform(0.3, 0.7, 3)
    n = int(SECONDS * RATE)
    levels, holds = [], []
    while sum(holds) < n:  # random levels in [−2, 2] V held 0.1–1 s
        levels.append(rng.uniform(-2.0, 2.0))
        holds.append(int(rng.integers(3, 31)))
    u = np.repeat(levels, holds)[:n]
    plant = scipy.signal.cont2discrete(network(c_clamp, xi_rho, alphas), 1 / RATE, "zoh")
    clean = scipy.signal.dlsim(plant, u * u)[1][:, 0]
    noise = 0.005 * 0.5 * float(np.ptp(clean))  # 0.5 % of w's range
    w = 0.5 * clean + 0.2 + noise * np.random.default_rng(7).normal(size=n)
    recording = hybrid.Recording.from_arrays(v_in=u, w=w, rate=RATE)

    found = hybrid.diagnose(
        recording, simulation=hybrid.resolve_physics("rc:zoh", [recording]), effects=["drive_even"]
    )

    assert [c["name"] for c in found.causes] == ["drive_even"]
    # the map found is the square's: its even part at the largest |u| many times its odd part
    c = found.extended.parameters["drive_even_coefficient"]
    assert abs(c) * float(np.max(np.abs(u))) > 10.0
    # and the model then reaches the noise: nothing left unexplained
    assert found.unexplained is None
    assert found.gain > 100.0
