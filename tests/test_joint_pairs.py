"""Two effects that spoil each other's lone fit are named together (`hybrid.discovery._joint`).

Back-relaxation + saturation seed 3 of `experiments/discrepancy.py` (the
independent generator `hybrid.ipmc._hidden_pairs`): the relaxation fitted alone
loses on held-out data, the saturation alone gains 1.1, and a `drift` stood in
for both (gain 1.55) — a wrong cause, and the stepwise search could not reach
the pair from there.
"""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
from helpers import hidden_recording

from hybrid import diagnose
from hybrid.discovery._ambiguity import ambiguities
from hybrid.discovery._joint import JointPair, leaders, named_jointly
from hybrid.discovery._report import stepwise_section
from hybrid.ipmc._hidden_pairs import true_noise_variance


@dataclasses.dataclass
class _Candidate:  # the fields of `Candidate` that `leaders` and `named_jointly` read
    name: str
    delta_bic: float
    gain: float = 1.0
    eligible: bool = False
    validation_loss: float = float("nan")
    reasons: list = dataclasses.field(default_factory=list)


def _candidate(name, delta_bic, gain=1.0):
    return _Candidate(name, delta_bic, gain, reasons=[f"{name} failed"])


def test_the_leaders_are_the_largest_training_bic_drops_that_pass_the_bic_rule():
    cands = [
        _candidate(n, d)
        for n, d in [("a", -5.0), ("b", -900.0), ("c", 12.0), ("d", float("nan")), ("e", -40.0)]
    ]
    assert [c.name for c in leaders(cands, 10.0, n=2)] == ["b", "e"]
    # a BIC that rises, is unknown, or falls by less than the step's rule never leads
    assert [c.name for c in leaders(cands, 10.0)] == ["b", "e"]
    assert [c.name for c in leaders(cands, 1.0)] == ["b", "e", "a"]


def test_a_jointly_named_first_cause_reports_what_it_adds_beside_the_other_and_has_no_lone_rival():
    @dataclasses.dataclass(frozen=True)
    class FakeStep:  # the fields of `Step` that `named_jointly` and `ambiguities` read
        current: object
        candidates: list
        chosen: object
        chosen_val: float
        chosen_fits: list
        lanes: list
        joint_with: str | None = None

    a, b, drift = _candidate("a", -10.0, 0.5), _candidate("b", -20.0, 1.1), _candidate("drift", -3.0, 1.55)
    a.validation_loss = 0.25
    drift.eligible = True
    lanes = [SimpleNamespace(effect="a", theta=np.ones(3)), SimpleNamespace(effect="b", theta=np.zeros(3))]
    step = FakeStep(
        current=None, candidates=[a, b, drift], chosen=drift, chosen_val=0.3, chosen_fits=[], lanes=lanes
    )
    pair = JointPair(
        first="a",
        second="b",
        theta=np.arange(3.0),
        gain=7.8,
        gains_over_alone={"a": 9.0, "b": 6.4},
        delta_bics_over_alone={"a": -30.0, "b": -12.0},
    )
    named = named_jointly(step, pair)
    assert named.chosen.name == "a" and named.chosen.eligible and named.joint_with == "b"
    assert named.chosen.gain == 6.4 and named.chosen.delta_bic == -12.0  # over b alone: what a adds beside b
    assert named.chosen.reasons[0].startswith("named jointly with b: together they gain 7.80")
    assert named.chosen.reasons[1] == "alone: a failed"
    assert named.candidates[0] is named.chosen and named.candidates[2] is drift
    assert [t.tolist() for t in named.chosen_fits] == [[1.0, 1.0, 1.0]] and named.chosen_val == 0.25
    assert a.eligible is False  # the step's own candidate is left as it was
    # drift stays eligible in the step, but the pair beat it: no ambiguity is reported on the joint step
    assert ambiguities([named], np.ones(10), 0.01, [np.ones(10)], 30.0, []) == []


def test_a_pair_that_hides_each_other_is_named_and_the_stand_in_is_not():
    # The effects searched: the pair and the stand-in the full search named (fewer lanes than the
    # twelve built-ins; the same rules). Without the joint fits, this names `drift` (gain 1.55) or nothing.
    recording = hidden_recording("back_relaxation+saturation", 3)
    found = diagnose(recording, effects=["back_relaxation", "saturation", "drift"])
    names = sorted(c["name"] for c in found.causes)
    assert names == ["back_relaxation", "saturation"], found.verdict
    first, second = found.causes
    assert first["step"] == 1 and first["named_jointly_with"] == second["name"] == found.steps[0].joint_with
    assert first["joint"].startswith(f"named jointly with {second['name']}: together they gain")
    assert "named_jointly_with" not in second
    (named,) = [line for line in stepwise_section(found.to_dict()) if "**Named together.**" in line]
    assert f"{first['name']} was named jointly with {second['name']}" in named
    for cause in found.causes:
        assert cause["incremental_gain"] >= 1.5
    # Together they come down near the measurement noise (which diagnose never sees).
    var_w = np.var(found.heldout.w)
    assert found.extended.heldout.nmse * var_w <= 2.5 * true_noise_variance(recording)
    assert found.baseline.heldout.nmse * var_w >= 5 * true_noise_variance(recording)
