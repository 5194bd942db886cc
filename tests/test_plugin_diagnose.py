"""`diagnose` on a physics written by a user: a small ODE plug-in, started where a held drive left it.

The plug-in (a first-order lag, τ ẏ = u − y, written here) is wrapped in
`HeldStart`: the recordings start with the lag charged by a constant drive, as a
lab's slow system does. The truth is computed by numpy alone (exact ZOH
discretisation from the held steady state), and the hidden effect has another
functional form than the library's extension (an algebraic one-sided
saturation, y/√(1 + (y/σ)²) on the positive side, against tanh). `diagnose`
must name it, and name nothing on the effect-free recording; both runs share
one compiled search.
"""

from __future__ import annotations

import json
import re
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest
from jax import lax
from jax.flatten_util import ravel_pytree

import hybrid
from hybrid import AbstractSimulation, HeldStart, Positive, encode
from hybrid.discovery import RENAMED_IN_SCHEMA_4
from hybrid.discovery._search import simulation_labels

RATE, SECONDS, TAU, HELD, SETTLE, NOISE = 10.0, 60.0, 2.5, 1.2, 200, 0.01


class Lag(AbstractSimulation):
    """y of τ ẏ = u − y (u held over each sample), from rest."""

    raw: dict
    constraints: ClassVar[dict] = {"tau_s": Positive()}
    units: ClassVar[dict] = {"tau_s": "s"}
    typical: ClassVar[dict] = {"tau_s": (0.5, 20.0)}
    linear_in_drive: ClassVar[bool] = False  # HeldStart's initial_drive lives on the drive's scale

    def __init__(self, tau_s=1.0):
        self.raw = encode({"tau_s": tau_s}, self.constraints, "Lag")

    def simulate(self, v_in, dt):
        a = jnp.exp(-dt / self.parameters()["tau_s"])
        return lax.scan(lambda y, u: ((a * y + (1 - a) * u),) * 2, jnp.zeros(()), jnp.asarray(v_in))[1]


def recording(saturate: bool, seed: int = 0) -> hybrid.Recording:
    rng = np.random.default_rng(seed)
    n = int(SECONDS * RATE)
    u = np.repeat(rng.uniform(-2.0, 2.0, n // 25 + 1), 25)[:n]
    a = np.exp(-1.0 / (RATE * TAU))
    y, state = np.empty(n), HELD  # the lag settled at the held drive before the record
    for k in range(n):
        y[k] = state
        state = a * state + (1 - a) * u[k]
    if saturate:  # one-sided: the positive side levels off at 1 (the lag reaches ±2)
        y = np.where(y > 0, y / np.sqrt(1.0 + y * y), y)
    w = 3.0 * y + 0.5
    w = w + NOISE * np.ptp(w) * rng.normal(size=n)
    # a force sensor (N): the readout's units follow it, not the IPMC's mm
    return hybrid.Recording(
        t=np.arange(n) / RATE, v_in=u, w=w, metadata={"units": {"t": "s", "v_in": "V", "w": "N"}}
    )


def _keys(tree) -> set[str]:
    if isinstance(tree, dict):
        return set(tree) | {k for v in tree.values() for k in _keys(v)}
    if isinstance(tree, list):
        return {k for v in tree for k in _keys(v)}
    return set()


@pytest.mark.parametrize("saturate, cause", [(True, "saturation"), (False, "none")])
def test_diagnose_names_a_hidden_effect_on_a_plugin_that_starts_away_from_rest(saturate, cause, tmp_path):
    found = hybrid.diagnose(recording(saturate), simulation=HeldStart(Lag(), SETTLE))
    # the recorded signals' units travel to the report: its labels and sentences, never the IPMC's mm
    assert found.signal_units == {"w": "N", "v_in": "V"}
    if not saturate:
        paths = hybrid.write_report(found, tmp_path)
        data = json.loads(paths["report.json"].read_text())
        assert data["units"] == {"w": "N", "v_in": "V"}
        assert not [k for k in _keys(data) if k.endswith(("_mm", "_v"))]
        assert set(RENAMED_IN_SCHEMA_4.values()) <= set(data["evidence"]["baseline"])  # renamed, not dropped
        text = paths["report.md"].read_text()
        assert "loop separation (N)" in text and f"σ = {found.noise_floor.std:.3g} N" in text
        assert not re.search(r"\bmm\b", text), re.search(r".{40}\bmm\b.{20}", text)
    assert found.cause == cause, found.verdict
    held = float(found.extended.parameters["initial_drive"])
    assert abs(held - HELD) < 0.15, held  # the held drive is recovered with the rest
    assert abs(float(found.extended.parameters["tau_s"]) - TAU) < 0.1 * TAU
    report = found.to_dict()["parameters"]
    # the uncertainties carry the recordings' units too (they said mm, which the report then overrode)
    assert {k: found.uncertainties[k].unit for k in ("gain", "offset")} == {
        k: report[k]["unit"] for k in ("gain", "offset")
    }
    assert {k: report[k]["unit"] for k in ("gain", "offset", "tau_s", "initial_drive")} == {
        "gain": "N/(unit of S)",  # w's unit per the simulation's output's (Lag does not name it)
        "offset": "N",
        "tau_s": "s",
        "initial_drive": "V",  # the drive's
    }
    if saturate:
        assert found.gain >= 2.0
        assert report["saturation_pos_curvature"]["unit"] == "1/(unit of S)"
    else:
        assert found.unexplained is None, found.verdict


def test_free_parameter_order_is_the_order_of_theta():
    """A wrapper's layout is read, not assumed: HeldStart keeps its own parameter after its inner's."""
    inner = HeldStart(hybrid.LTI(2), 10)
    stack = hybrid.EffectStack(inner, ["delay", "saturation"])
    for frozen in (frozenset(), frozenset({"f_1", "initial_drive"}), frozenset({"saturation_neg_curvature"})):
        names = inner.free_parameter_order(frozen)
        assert sorted(names) == sorted(set(inner.parameter_names()) - frozen)
        labels = simulation_labels(stack, frozen)  # the inner's names, then each effect's
        marks = {n: 100.0 + i for i, n in enumerate(labels)}
        marked = stack.with_raw({n: jnp.asarray(v) for n, v in marks.items()})
        theta, _ = ravel_pytree(eqx.filter(marked, marked.trainable(frozen)))
        assert [float(x) for x in theta] == [marks[n] for n in labels]
