"""The remainder's map of the drive before the dynamics: where the missing physics sits on the drive.

A static map of the drive level (a heater's or a pump's limit, an amplifier's curve) acts before the
dynamics; the remainder's maps of the drive level and of the model's output read it on the output,
where a slow plant smears it over its time constant (a heater clipped at 70 % of a 0–100 % drive into
a 300 s lag: "no simple structure … 0 %"). The model's own response to each map of the drive, linearised
along the recording, reads it where it acts. The recordings are made here with numpy (an exact ZOH
first-order lag), never with the library's simulations.
"""

from __future__ import annotations

import helpers as h
import jax.numpy as jnp
import numpy as np
import pytest

import hybrid
from hybrid.discovery._effect_stack import EffectStack, drive_responses

RATE, TAU, N = 1.0, 60.0, 2400


def _lag(u: np.ndarray) -> np.ndarray:
    """The exact ZOH lag of time constant TAU from rest (`helpers.zoh_lag`)."""
    return h.zoh_lag(u, 1.0 / RATE, TAU)


def _drive(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    levels, holds = [], []
    while sum(holds) < N:
        levels.append(rng.uniform(0.0, 100.0))
        holds.append(int(rng.integers(30, 150)))
    return np.repeat(levels, holds)[:N]


def _recording(y: np.ndarray, u: np.ndarray, seed: int) -> hybrid.Recording:
    w = y + np.random.default_rng(seed).normal(0.0, 0.005 * np.ptp(y), y.size)
    return hybrid.Recording.from_arrays(v_in=u, w=w, rate=RATE, name=f"heater {seed}")


def test_the_drive_responses_are_the_models_derivatives_along_the_drive_and_its_parameters():
    """Against central differences of the whole stack's output (a drive effect on, through lti:2)."""
    u = jnp.asarray(np.sin(np.arange(300) / 7.0) + 0.3 * np.cos(np.arange(300) / 3.1))
    stack = EffectStack(hybrid.LTI(2), ["drive_saturation"])
    stack = stack.replace(drive_saturation_pos_curvature=0.8, drive_saturation_neg_curvature=0.3)
    directions = jnp.asarray(np.stack([np.cos(np.arange(300) / 5.0), (np.arange(300) > 150) * 1.0]))
    names = ("f_1", "drive_saturation_pos_curvature")
    got, by_parameter = (np.asarray(x) for x in drive_responses(stack, u, 0.05, directions, names))
    eps = 1e-6
    for k in range(2):
        up = np.asarray(stack.simulate(u + eps * directions[k], 0.05))
        down = np.asarray(stack.simulate(u - eps * directions[k], 0.05))
        np.testing.assert_allclose(got[k], (up - down) / (2 * eps), rtol=1e-6, atol=1e-9)
    for k, name in enumerate(names):  # in the raw (unconstrained) value
        raw = float(stack.raw[name])
        up = np.asarray(stack.with_raw({name: jnp.asarray(raw + eps)}).simulate(u, 0.05))
        down = np.asarray(stack.with_raw({name: jnp.asarray(raw - eps)}).simulate(u, 0.05))
        np.testing.assert_allclose(by_parameter[k], (up - down) / (2 * eps), rtol=1e-5, atol=1e-8)


@pytest.fixture(scope="module")
def clipped():
    """A heater driven over 0–100 % that delivers no more than 70 %, through a 60 s lag."""
    u = _drive(4)
    return hybrid.diagnose(
        _recording(0.5 * _lag(np.minimum(u, 70.0)), u, 4), simulation="lti:1", effects=["delay"]
    )


def test_a_drive_that_stops_at_a_level_is_read_before_the_dynamics(clipped):
    assert clipped.unexplained is not None  # nothing searched can take it
    description = clipped.unexplained["description"]
    assert description["kind"] == "drive_static", description["summary"]
    assert "static in the drive, before the dynamics" in description["summary"]
    through = description["drive_map"]
    # read as a clip at the top, its level a quantile of the drive near the true 70 % (to first order about a
    # lag that bent its gain to the clip, the level trades with that gain: 80 % here)
    assert through["levels_off"] == ["top"] and list(through["clip"]["levels"]) == ["top"]
    assert 60.0 <= through["clip"]["levels"]["top"] <= 85.0
    assert through["of_excess"] > 0.8
    # the free map it reports flattens above the clip (a fit to first order softens the knee)
    v, mapped = (np.asarray(through["curve"][k]) for k in ("v", "mapped"))
    below, above = v < 60.0, v > 80.0
    rise_below = np.polyfit(v[below], mapped[below], 1)[0]
    rise_above = np.polyfit(v[above], mapped[above], 1)[0]
    assert rise_above < 0.5 * rise_below
    assert "a clip of the drive near" in description["summary"]
    assert "--effects builtins,drive_clip" in description["summary"]


def test_a_limit_on_the_output_is_not_read_on_the_drive():
    """The same lag with its output clipped (a sensor's full scale): the output's maps read it."""
    u = _drive(5)
    y = np.minimum(0.5 * _lag(u), 35.0)
    found = hybrid.diagnose(_recording(y, u, 5), simulation="lti:1", effects=["delay"])
    assert found.unexplained is not None
    description = found.unexplained["description"]
    assert description["kind"] != "drive_static", description["summary"]
