"""A named effect's refinement tried in its place (`hybrid.discovery._refine`).

The command-line test's recording is made here with scipy: a heater that stops at 13 W, driven in
random steps over 0–20 W, into a first-order block. Without the refinement the default set named
`drive_even` (a concave quadratic of the drive) with `drive_saturation` its rival and 91 % of the
held-out error left unexplained; the remainder pointed at the named-only `drive_clip`.
"""

from __future__ import annotations

import json
import types

import helpers as h
import numpy as np
import pytest
import scipy.signal

from hybrid.discovery._effect_set import EFFECTS, NAMED_ONLY
from hybrid.discovery._refine import refinable, refined, refined_effects, refinement_reason

TOP = 13.0  # W: where the heater stops


def _heater(path, seed: int = 1) -> None:
    """60 s at 30 Hz: random steps of 0–20 W held 1–5 s, clipped at `TOP`, into 1.5 °C/W with τ = 2 s."""
    rng = np.random.default_rng(seed)
    rate, n = 30.0, 1800
    t = np.arange(n) / rate
    v = h.held_levels(rng, t, 0.0, 20.0, 1.0, 5.0)
    _, y, _ = scipy.signal.lsim(scipy.signal.lti([1.5], [2.0, 1.0]), np.minimum(v, TOP), t)
    w = 22.0 + y + 0.01 * np.ptp(y) * rng.normal(size=n)
    np.savetxt(path, np.c_[t, v, w], delimiter=",", header="t,v_in,w\ns,W,degC", comments="")


def test_a_heater_that_stops_sharply_is_named_drive_clip_by_the_default_set(tmp_path):
    _heater(tmp_path / "heat.csv")
    run = h.run_hybrid(tmp_path, "diagnose", "heat.csv", "--physics", "lti:1", "--out", "d", "--quiet")
    assert run.returncode == 0, run.stderr[-2000:]
    report = json.loads((tmp_path / "d" / "report.json").read_text())
    refined_ = report["evidence"]["refined"]
    assert refined_["swaps"] == {
        "saturation": "clip",
        "drive_dead_zone": "dead_band",
        "drive_saturation": "drive_clip",
    }, refined_
    assert refined_["kept"], refined_
    assert refined_["gain_over_first"] >= 1.5
    assert [c["name"] for c in report["causes"]] == ["drive_clip"], report["verdict"]
    assert report["unexplained"] is None, report["verdict"]
    level = 1 / report["parameters"]["drive_clip_pos_curvature"]["value"]
    assert level == pytest.approx(TOP, rel=0.01)
    assert report["settings"]["refine"] is True
    tried = (
        "diagnosed again with clip in place of saturation, dead_band in place of drive_dead_zone and drive_clip "
        "in place of drive_saturation"
    )
    assert f"refined: {tried}" in run.stdout
    assert f"**Refined.** D{tried[1:]}" in (tmp_path / "d" / "report.md").read_text()

    # the default set's own answer did not name the clip (and left the remainder that pointed at it)
    assert refined_["first_causes"] and "drive_clip" not in refined_["first_causes"]


def _effects(*names):
    return [({**EFFECTS, **NAMED_ONLY}[n])() for n in names]


BUILTINS = _effects(*EFFECTS)
LEFT = {"description": {"summary": "…"}}


def test_refinable_takes_a_named_cause_s_refinement_and_the_one_the_remainder_points_at():
    def swaps(effects, kept, left=LEFT, room=3.0):
        return refinable(effects, kept, left, BUILTINS, room, 1.5)

    # every refinement at once, the other place's too: a drive's clip read through the dynamics as a tanh
    # on the output, and the output's clip was all the second run could name
    both = {"drive_saturation": "drive_clip", "saturation": "clip", "drive_dead_zone": "dead_band"}
    # a named dead zone of the drive is tried as the output's dead band too (a probe's sensor dead band)
    assert swaps(BUILTINS, ["drive_dead_zone"]) == both
    assert swaps(BUILTINS, ["drive_saturation"]) == both
    assert swaps(BUILTINS, ["saturation", "delay"]) == both
    # nothing unexplained, but 1.8× the floor left: a clip may still gain the 1.5× asked (a sensor's clip)
    assert swaps(BUILTINS, ["saturation"], left=None, room=1.8) == both
    # under 1.5× the floor not even a perfect clip could gain 1.5×: not tried
    assert swaps(BUILTINS, ["saturation"], left=None, room=1.4) == {}
    # but beside two other causes, at the floor, a clip and one other may explain as much (a probe's drive
    # clip beside a friction read as drive_saturation, the friction and a dead zone never hidden)
    crowded = ["drive_saturation", "friction_velocity", "drive_dead_zone"]
    assert swaps(BUILTINS, crowded, left=None, room=1.1) == both
    assert swaps(BUILTINS, ["delay", "lag", "drift"], left=None, room=1.1) == {}  # no saturation among them
    assert refinement_reason(crowded, 1.1, 1.5, None, swaps=swaps(BUILTINS, crowded, None, 1.1)) == (
        "drive_saturation was named beside 2 other causes, which drive_clip in its place may stand for"
    )
    assert refinement_reason(crowded, 1.8, 1.5, None) == "something was left above the noise"
    # the remainder's pointer is followed whatever is named
    pointed = {"description": {"named_only": "drive_clip"}}
    assert swaps(BUILTINS, ["drive_even"], left=pointed) == both
    # the remainder's creep is no refinement of a searched effect: not tried
    assert swaps(BUILTINS, ["drive_even"], left={"description": {"named_only": "creep"}}) == {}
    # a refinement searched already, or a set without the built-ins: nothing
    assert swaps([*BUILTINS, *_effects("drive_clip")], ["drive_saturation"]) == {}
    assert swaps([*BUILTINS, *_effects("drive_clip")], ["saturation"]) == {
        "saturation": "clip",
        "drive_dead_zone": "dead_band",
    }
    assert swaps(_effects("drive_saturation", "delay"), ["drive_saturation"]) == {}
    swapped = [getattr(e, "name", e) for e in refined_effects(BUILTINS, {"drive_saturation": "drive_clip"})]
    assert "drive_clip" in swapped and "drive_saturation" not in swapped
    assert set(swapped) == (set(EFFECTS) - {"drive_saturation"}) | {"drive_clip"}


def test_a_named_even_part_that_turns_down_near_the_end_of_the_range_points_at_the_clip():
    """A probe's heater clipped at 6 V of a 0–10 V drive (its own plug-in, a sensor lag beside): the default
    set named drive_even, whose reading said the map "turns down over the last 16 %", and the clip was never
    tried; with --effects builtins,drive_clip it named drive_clip at 6.0 V and gained 169×."""
    from hybrid.discovery._effects import TURNS_NEAR_END

    even = EFFECTS["drive_even"]()
    assert even.points_at({"rising_percent_of_range": 84.0}) == "drive_clip"
    assert EFFECTS["even_response"]().points_at({"rising_percent_of_range": 84.0}) == "clip"
    assert even.points_at({"rising_percent_of_range": 100.0}) is None  # monotone over the range: an even part
    assert even.points_at({"rising_percent_of_range": TURNS_NEAR_END - 1}) is None  # a turn mid-range: V²
    assert EFFECTS["delay"]().points_at({"rising_percent_of_range": 84.0}) is None  # the default: none
    # a turn just beyond the range (a verifier's heater clipped at 70 %: 104 %) is as flat as a level
    assert even.points_at({"rising_percent_of_range": 100.0, "turn_percent_of_range": 104.0}) == "drive_clip"
    assert even.points_at({"rising_percent_of_range": 100.0, "turn_percent_of_range": 130.0}) is None
    # the pointer alone (nothing left above the noise, no saturation named) tries the clip in each place
    pointed = refinable(BUILTINS, ["drive_even"], None, BUILTINS, 1.0, 1.5, {"drive_even": "drive_clip"})
    assert pointed == {"drive_saturation": "drive_clip", "saturation": "clip", "drive_dead_zone": "dead_band"}
    assert refinable(BUILTINS, ["drive_even"], None, BUILTINS, 1.0, 1.5) == {}
    assert refinement_reason(["drive_even"], 1.0, 1.5, None, {"drive_even": "drive_clip"}) == (
        "drive_even's fit reads as drive_clip"
    )


def _diagnosis(causes, nmse):
    return types.SimpleNamespace(
        causes=[{"name": c} for c in causes],
        extended=types.SimpleNamespace(heldout=types.SimpleNamespace(nmse=nmse)),
    )


def test_the_second_diagnosis_is_kept_only_where_it_names_the_refinement_and_gains_min_gain():
    first = _diagnosis(["drive_saturation"], 0.03)
    swaps = {"drive_saturation": "drive_clip"}
    better = _diagnosis(["drive_clip"], 0.01)
    kept, evidence = refined(first, better, swaps, 1.5)
    assert kept is better and evidence["kept"] and evidence["gain_over_first"] == pytest.approx(3.0)
    close = _diagnosis(["drive_clip"], 0.025)  # 1.2× lower: the first stands
    kept, evidence = refined(first, close, swaps, 1.5)
    assert kept is first and not evidence["kept"] and "only 1.20× lower" in evidence["sentence"]
    other = _diagnosis(["drive_even"], 0.001)  # far lower, but without the refinement: the first stands
    kept, evidence = refined(first, other, swaps, 1.5)
    assert kept is first and "does not name drive_clip" in evidence["sentence"]
    worse = _diagnosis(["drive_clip"], 0.06)  # higher: said as higher, not "0.50× lower"
    kept, evidence = refined(first, worse, swaps, 1.5)
    assert kept is first and "is 2.00× higher" in evidence["sentence"], evidence["sentence"]
    broken = _diagnosis(["drive_clip"], float("nan"))
    kept, evidence = refined(first, broken, swaps, 1.5)
    assert kept is first and "is not finite" in evidence["sentence"] and evidence["gain_over_first"] == 0.0


def test_a_first_diagnosis_that_stands_no_longer_asks_for_the_refinement_just_tried():
    """A verifier's asymmetric output dead band: dead_band was tried in drive_dead_zone's place and not kept,
    and the report then advised "the built-in dead_band is searched when named (--effects builtins,dead_band)"."""
    from hybrid.discovery._unexplained import named_only_hint

    description = {"summary": "static on the model's output", "named_only": "dead_band"}
    hint = named_only_hint(
        {"recovered": {"named": "static_output_monotone"}, "static": _band_shape()},
        {"output": {"effects": ()}},
    )
    description["summary"] += f"; {hint}"
    first = _diagnosis([], 0.03)
    first.unexplained = {"description": description}
    swaps = {"drive_dead_zone": "dead_band"}
    kept, _ = refined(first, _diagnosis(["dead_band"], 0.025), swaps, 1.5)  # 1.2× lower: the first stands
    assert kept is first
    summary = first.unexplained["description"]["summary"]
    assert "--effects builtins,dead_band" not in summary and "dead_band was tried in its place" in summary
    # a pointer at an effect that was not tried keeps asking for it
    other = {"summary": f"x; {hint}", "named_only": "dead_band"}
    first.unexplained = {"description": other}
    refined(first, _diagnosis(["clip"], 0.025), {"saturation": "clip"}, 1.5)
    assert "--effects builtins,dead_band" in other["summary"]


def _band_shape():
    """A remainder's static readings whose monotone map of the output is flat in the middle (a dead band)."""
    shape = {"flat_middle": {"flag": True}, "levels_off": {"flag": False}}
    return {"output_monotone": {"shape": shape}}


def test_a_refinement_with_fewer_causes_as_good_held_out_is_kept():
    """A probe's drive clip beside a Coulomb friction: the default set named drive_saturation, the friction
    and a dead zone never hidden; refined, drive_clip and the friction alone, 2.38e-3 against 2.67e-3 held
    out (1.12×), and the three-cause diagnosis stood because 1.12 < 1.5."""
    swaps = {"drive_saturation": "drive_clip", "saturation": "clip"}
    first = _diagnosis(["drive_saturation", "friction_band_1", "drive_dead_zone"], 2.67e-3)
    simpler = _diagnosis(["drive_clip", "friction_band_1"], 2.38e-3)
    kept, evidence = refined(first, simpler, swaps, 1.5)
    assert kept is simpler and evidence["kept"]
    assert "fewer causes than drive_saturation, friction_band_1, drive_dead_zone" in evidence["sentence"]
    # as many causes, or fewer but worse held out: the min_gain rule decides, and the first stands
    same = _diagnosis(["drive_clip", "friction_band_1", "drive_dead_zone"], 2.38e-3)
    assert refined(first, same, swaps, 1.5)[0] is first
    worse = _diagnosis(["drive_clip", "friction_band_1"], 2.9e-3)
    assert refined(first, worse, swaps, 1.5)[0] is first
    # fewer causes, but not the refinement: the first stands
    other = _diagnosis(["friction_band_1"], 2.0e-3)
    assert refined(first, other, swaps, 1.5)[0] is first


def test_a_second_diagnosis_that_fails_leaves_the_first_with_the_reason(tmp_path, monkeypatch):
    """A refinement whose diagnosis raises (a plug-in that refuses, a fit that is not finite) does not lose
    the first diagnosis: it stands, and ``evidence.refined`` says why there is no other."""
    import hybrid
    import hybrid.discovery._diagnose as d

    _heater(tmp_path / "heat.csv")
    recording = hybrid.load_mapped(tmp_path / "heat.csv")
    real = d.diagnose

    def refusing(*args, **kwargs):
        if not kwargs["settings"].refine:  # the second diagnosis
            raise hybrid.InputError("refused for this test")
        return real(*args, **kwargs)

    monkeypatch.setattr(d, "diagnose", refusing)
    found = refusing(recording, simulation=hybrid.LTI(1), settings=hybrid.DiagnoseSettings())
    refined_ = found.evidence["refined"]
    assert refined_["kept"] is False and refined_["error"] == "refused for this test"
    assert "could not be made (refused for this test): this one stands" in refined_["sentence"]
    assert "drive_clip" not in [c["name"] for c in found.causes]


def test_a_named_even_part_that_turns_near_the_end_carries_its_pointer_in_the_causes():
    """`Diagnosis.causes` gives a cause's `points_at` (what `diagnose` hands `refinable`): a first-order
    plant's drive_even at a coefficient whose map turns at 84 % of a 0–10 V drive points at drive_clip;
    at a V²-like coefficient turning below the drive's range it points at nothing."""
    import dataclasses

    from diagnosis_helpers import diagnosis_of, step

    import hybrid
    from hybrid.discovery._decision import evaluate_candidate
    from hybrid.discovery._diagnose import prepare_search
    from hybrid.discovery._search import initial_thetas

    rng = np.random.default_rng(3)
    u = np.repeat(rng.uniform(0.0, 10.0, 60), 30)
    w = scipy.signal.lfilter([0.1], [1.0, -0.9], u) + 0.01 * rng.normal(size=u.size)
    recording = hybrid.Recording.from_arrays(v_in=u, w=w, rate=30.0)
    search = prepare_search([recording], hybrid.LTI(1), hybrid.DiagnoseSettings(), ["drive_even"])
    problem, model = search.problem, search.model
    active = np.array([1.0, 1.0])  # drive_even and the frame timing

    def cause_at(coefficient):
        start = model.simulation.with_active(active).replace(drive_even_coefficient=coefficient)
        theta = initial_thetas(problem, [start], model.readout, search.frozen)[0]
        cand = evaluate_candidate(
            problem,
            theta,
            active,
            "drive_even",
            search.n_train,
            4,
            search.settings.materiality,
            search.frozen,
        )
        base = dataclasses.replace(cand, name="none")
        steps = [step(base, cand)]
        found = diagnosis_of(
            search, steps, cause="drive_even", baseline=base, extended=cand, candidates=[cand]
        )
        (cause,) = found.causes
        return cause

    turning = cause_at(-1.0 / (2 * 0.84 * 10.0))  # u − u²/16.8: turns at 8.4 V
    assert 75.0 <= turning["derived"]["turn_percent_of_range"] < 100.0  # of the drive's recorded range
    assert turning["points_at"] == "drive_clip" and "--effects builtins,drive_clip" in turning["reading"]
    assert "points_at" not in cause_at(0.05)  # convex on 0–10 V: rises over all of it
