"""`hybrid.joint_starts`: a plug-in effect's starts with the simulation screened jointly.

A sensor that cannot see sign reads |y| of an oscillator. The effect-free fit of |y| is no oscillator
at all, and from it a rectifier switched on stays in that fit's basin (issue 31 names this sensor as
an effect a user adds). With `screened_starts` built on `joint_starts`, the search starts the
rectifier's lanes from the oscillator's design points too. The recording is made with scipy's exact
ZOH discretisation, never by the library's simulations.
"""

from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp
import numpy as np
import pytest
import scipy.signal

import hybrid
from hybrid import AbstractEffect, InputError, Positive, UnitInterval, encode, joint_starts

RATE, F0, ZETA, SECONDS = 25.0, 0.8, 0.5, 60.0
SCREENED: list[list[dict]] = []  # what each screened_starts call returned, for the test to read


class Rectifier(AbstractEffect):
    """On the output: y ↦ (1 − m)·y + m·(√(y² + e²) − e); m = 1 reads |y|, smoothed over e."""

    raw: dict
    name: ClassVar[str] = "rectifier"
    constraints: ClassVar = {"mix": UnitInterval(), "smooth": Positive()}
    units: ClassVar = {"mix": "1", "smooth": "{signal}"}
    defaults: ClassVar = {"mix": 0.01, "smooth": 0.01}
    n_screened: ClassVar[int] = 2

    def __init__(self, **values):
        self.raw = encode({**self.defaults, **values}, self.constraints, self.name)

    def apply(self, y, dt):
        p = self.parameters()
        e = p["smooth"]
        return (1 - p["mix"]) * y + p["mix"] * (jnp.sqrt(y * y + e * e) - e)

    def starts(self, context):
        span = float(np.ptp(np.asarray(context.signal))) or 1.0
        return [{"mix": 0.5, "smooth": 0.01 * span}, {"mix": 0.9, "smooth": 0.01 * span}]

    def screened_starts(self, context):
        found = joint_starts(context, self, self.starts(context), self.n_screened)
        SCREENED.append(found)
        return found

    def material(self, derived, parameters, thresholds):
        return float(parameters["mix"]) >= 0.1, f"mix {float(parameters['mix']):.2f} (needs ≥ 0.1)"


class UnscreenedRectifier(Rectifier):
    name: ClassVar[str] = "unscreened_rectifier"
    n_screened: ClassVar[int] = 0


def _abs_oscillator(seed: int) -> hybrid.Recording:
    rng = np.random.default_rng(seed)
    levels, holds = [], []
    while sum(holds) < SECONDS * RATE:
        levels.append(rng.uniform(-3.0, 3.0))
        holds.append(int(rng.integers(int(0.3 * RATE), int(1.5 * RATE))))
    u = np.repeat(levels, holds)[: int(SECONDS * RATE)]
    wn = 2 * np.pi * F0
    a, b = np.array([[0.0, 1.0], [-(wn**2), -2 * ZETA * wn]]), np.array([[0.0], [1.5 * wn**2]])
    ad, bd, c, d, _ = scipy.signal.cont2discrete((a, b, np.array([[1.0, 0.0]]), np.zeros((1, 1))), 1 / RATE)
    x, y = np.zeros(2), np.empty_like(u)
    for k, value in enumerate(u):  # the drive held over each sample: exact
        y[k] = x[0]
        x = ad @ x + bd[:, 0] * value
    w = np.abs(y) + rng.normal(0.0, 0.01 * np.ptp(np.abs(y)), y.size)
    return hybrid.Recording.from_arrays(v_in=u, w=w, rate=RATE, name=f"abs oscillator {seed}")


@pytest.fixture(scope="module")
def recording():
    return _abs_oscillator(0)


def test_screened_starts_find_the_sign_blind_sensor_that_plain_starts_miss(recording):
    """Named, its remainder at the noise floor, only where its lanes start from the joint screen."""
    simulation = hybrid.resolve_physics("lti:2", recording)
    plain = hybrid.diagnose(recording, simulation=simulation, effects=[UnscreenedRectifier])
    SCREENED.clear()
    screened = hybrid.diagnose(recording, simulation=simulation, effects=[Rectifier])
    # The premise: from the effect-free fit alone the rectifier's lanes stay in its basin.
    assert plain.cause == "none", (plain.cause, plain.gain)
    assert screened.cause == "rectifier" and screened.unexplained is None
    assert screened.causes[0]["parameters"]["mix"]["value"] == pytest.approx(1.0, abs=0.01)
    held = screened.heldout
    assert screened.noise_floor is not None
    mse = float(np.mean((held.w - held.extended) ** 2))
    assert mse < 1.5 * screened.noise_floor.variance  # to the noise floor: the true model's error
    # One call per diagnosis (the first step screens); each start holds the simulation's parameters
    # and the effect's, at the values it was given.
    assert len(SCREENED) == 1 and 1 <= len(SCREENED[0]) <= Rectifier.n_screened
    for start in SCREENED[0]:
        assert set(simulation.parameter_names()) <= set(start) and start["mix"] in (0.5, 0.9)


class _Misnamed(Rectifier):
    name: ClassVar[str] = "misnamed"

    def screened_starts(self, context):
        return joint_starts(context, self, [{"mixx": 0.5}], self.n_screened)


def test_joint_starts_refuses_a_context_without_a_screen_and_values_it_cannot_set(recording):
    context = hybrid.StartContext(signal=recording.w, rate=RATE, duration=SECONDS)
    with pytest.raises(InputError, match=r"call it from screened_starts\(context\)"):
        joint_starts(context, Rectifier(), [{"mix": 0.5}], 1)
    with pytest.raises(InputError, match=r"name mixx, which are not its parameters \(mix, smooth\)"):
        hybrid.diagnose(recording, simulation=hybrid.resolve_physics("lti:2", recording), effects=[_Misnamed])
