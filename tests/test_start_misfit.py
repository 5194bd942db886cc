"""A record that does not start where the simulation does: `diagnose` says so and names `--settle`.

The records are a first-order system's response (exact ZOH by numpy, τ = 6
samples) to a staircase, one started at rest, the other from a drive of 1.5
held before the record (the state at 1.5, where `lti:1` starts at 0). Through
the real command line: the second record is diagnosed again from a held start
(``evidence.start.settled``), which then fits; with ``--no-auto-settle`` its
report has ``evidence.start.off`` and a ``start:`` line naming ``--settle``; the same record diagnosed with
``--settle 60``, the record started at rest, and one whose baseline wanders
as far at its end as at its start (a trend, not a start) have neither. The
statistic itself is checked against numpy on the saved final model's free run.
`hybrid fit --model physics` says it too.
"""

from __future__ import annotations

import json
import os
import signal
from pathlib import Path

import numpy as np
import pytest
from helpers import held_lag_csv

import hybrid
from hybrid.cli import main
from hybrid.discovery._start import (
    MIN_START,
    ONE_SIGN,
    RATIO,
    SETTLE_SHARE,
    START_SHARE,
    covered_try,
    misfit_at_start,
    settle_samples,
    settled_try,
)

TAU, DT, NOISE, N = 3.0, 0.5, 0.002, 480
#: Two effects, not the default set: the start check reads the final model whatever the effects, and
#: two effects' lanes cost a fraction of the default set's.
EFFECTS = ("--effects", "saturation,delay")


@pytest.fixture(scope="module")
def records(tmp_path_factory):
    folder = tmp_path_factory.mktemp("start")
    u = np.repeat(np.random.default_rng(3).uniform(-1.0, 1.0, N // 15), 15)
    noise = NOISE * np.random.default_rng(5).normal(size=N)
    paths = {}
    # a slow wander of the baseline, as large at the end as at the start (no effect searched here has it)
    wander = 0.5 * np.linspace(-1.0, 1.0, N) ** 8
    cases = (("at_rest", 0.0, 0.0), ("moving", 1.5, 0.0), ("wander", 0.0, wander), ("settled", u[0], 0.0))
    for name, held, extra in cases:
        paths[name] = held_lag_csv(folder / f"{name}.csv", u, held, DT, TAU, noise + extra)
    return paths


def diagnose(path, out, capsys, *extra):
    argv = [
        "diagnose",
        path,
        *f"--columns input=u,output=y --rate {1 / DT} --physics lti:1".split(),
        *EFFECTS,
    ]
    code = main([str(a) for a in [*argv, *extra, "--quiet", "--out", out]])
    stdout, err = capsys.readouterr()
    assert code == 0, err
    return stdout, json.loads((out / "report.json").read_text())


def test_a_record_that_starts_moving_is_diagnosed_again_from_a_held_start(records, tmp_path, capsys):
    """By default diagnose tries the remedy itself: held at a fitted drive, the start fits, and that is kept."""
    out, report = diagnose(records["moving"], tmp_path / "d", capsys)
    start = report["evidence"]["start"]
    held = settle_samples(N)
    assert held == round(SETTLE_SHARE * N)
    assert start["off"] is False and start["settled"]["automatically"] and start["settled"]["samples"] == held
    assert start["settled"]["without"]["ratio"] >= RATIO > start["recordings"][0]["ratio"]
    assert f"as --settle {held} would" in out and "--no-auto-settle" in out
    assert "**Start.**" in (tmp_path / "d" / "report.md").read_text()
    # the saved models start from the held drive: the fitted initial_drive is the one held before the record
    model = hybrid.load_model(tmp_path / "d" / "extended.eqx")
    assert isinstance(model.simulation.inner, hybrid.HeldStart) or isinstance(
        model.simulation, hybrid.HeldStart
    )
    assert float(model.parameters()["initial_drive"]) == pytest.approx(1.5, abs=0.1)
    data = np.loadtxt(records["moving"], delimiter=",", skiprows=1)
    head = (data[:, 1] - np.asarray(model.predict(data[:, 0], DT)))[: start["recordings"][0]["first_samples"]]
    assert np.sqrt(np.mean(head**2)) == pytest.approx(start["recordings"][0]["rms_first"], rel=1e-6)


def test_a_lag_that_stands_in_for_a_settled_start_gives_way_to_the_held_start(records, tmp_path, capsys):
    """A record that starts settled at its first drive, where `lti:1` starts at rest: from its own start a
    lag (on a direct feedthrough, settled at its first value) meets the start and is named (16× on this
    record); the effect-free model's start is missed, so the held start is tried, needs no effect, and
    is kept, with the time constant the record was made with (exact ZOH by numpy)."""
    own, report = diagnose(
        records["settled"], tmp_path / "own", capsys, "--effects", "lag", "--no-auto-settle"
    )
    assert report["cause"] == "lag"  # the answer this guards against
    out, report = diagnose(records["settled"], tmp_path / "d", capsys, "--effects", "lag")
    start = report["evidence"]["start"]
    assert report["cause"] == "none" and report["unexplained"] is None, report["verdict"]
    assert (
        start["off"] is False and start["settled"]["kept"] and start["settled"]["effect_free_ratio"] >= RATIO
    )
    assert start["settled"]["without"]["causes"] == ["lag"]
    assert "and lag met them" in out and "stood in for the record's initial state" in out
    model = hybrid.load_model(tmp_path / "d" / "extended.eqx")
    assert float(model.parameters()["tau_1"]) == pytest.approx(TAU, rel=0.02)
    u0 = np.loadtxt(records["settled"], delimiter=",", skiprows=1)[0, 0]
    assert float(model.parameters()["initial_drive"]) == pytest.approx(u0, abs=0.05)


def test_the_covered_start_keeps_the_held_run_only_where_the_causes_do_not_earn_their_place():
    """`covered_try` on checks made by hand: the held run is kept where it meets the start clearly (within
    MET), from a held drive near the record's, names other causes and the own-start causes gain under
    min_gain over it; not where it names the same, where they gain more, where it still misses the start,
    where it meets it only loosely, or from a drive far outside the record's."""
    from types import SimpleNamespace

    from hybrid.discovery._start import MET

    noise = 0.01 * np.random.default_rng(1).normal(size=1000)
    moving = noise + 0.5 * np.exp(-np.arange(1000) / 8.0)
    loosely = noise + 0.04 * np.exp(-np.arange(1000) / 8.0)  # under RATIO, over MET
    effect_free = misfit_at_start([moving], ["a"], settled=False)
    final = misfit_at_start([noise], ["a"], settled=False)
    extended = SimpleNamespace(heldout=SimpleNamespace(nmse=0.1))
    drive = np.array([0.0, 2.0])

    def again(nmse, causes, residual, held=0.5):
        return SimpleNamespace(
            evidence={"start": misfit_at_start([residual], ["a"], settled=True)},
            extended=SimpleNamespace(heldout=SimpleNamespace(nmse=nmse), parameters={"initial_drive": held}),
            causes=[{"name": c} for c in causes],
        )

    kept = covered_try(effect_free, final, again(0.12, [], noise), 250, ["lag"], extended, 1.5, drive)
    assert kept["settled"]["kept"] and kept["settled"]["without"]["gain_over_held"] == pytest.approx(1.2)
    assert "needs no effect, and lag gains only 1.20×" in kept["sentence"]
    assert MET < misfit_at_start([loosely], ["a"], settled=True)["recordings"][0]["ratio"] < RATIO
    for case, why in (
        (again(0.12, ["lag"], noise), "the simulation names lag too"),
        (again(0.2, [], noise), "yet lag gains 2.00× over that held out"),
        (again(0.12, [], moving), "the model still misses the start"),
        (again(0.12, [], loosely), "the model still misses the start"),
        (again(0.12, [], noise, held=9.8), "only from a drive of 9.8 held, outside the record's 0 to 2"),
    ):
        stands = covered_try(effect_free, final, case, 250, ["lag"], extended, 1.5, drive)
        assert not stands["settled"]["kept"] and stands["off"] is False
        assert why in stands["sentence"] and "from the simulation's own start" in stands["sentence"]


def test_a_held_start_that_cannot_be_tried_leaves_the_first_diagnosis_saying_why(
    records, tmp_path, capsys, monkeypatch
):
    """A retry that fails (here HeldStart refuses) does not lose the diagnosis: it stands, with the reason."""

    def refuse(self, *args, **kwargs):
        raise hybrid.InputError("HeldStart: refused for this test")

    monkeypatch.setattr(hybrid.HeldStart, "__init__", refuse)
    out, report = diagnose(records["moving"], tmp_path / "d", capsys)
    start = report["evidence"]["start"]
    assert start["off"] is True and start["settled"]["error"] == "HeldStart: refused for this test"
    assert "could not be tried: HeldStart: refused for this test" in out and "--settle N" in out


def test_a_record_that_starts_moving_is_flagged_with_the_remedy(records, tmp_path, capsys):
    out, report = diagnose(records["moving"], tmp_path / "d", capsys, "--no-auto-settle", "--no-refine")
    assert report["settings"]["settle_when_off"] is False and report["settings"]["refine"] is False
    start = report["evidence"]["start"]
    assert start["off"] is True and "settled" not in start
    assert "start: " in out and "--settle N" in out and "HeldStart" in out
    assert "**Start.**" in (tmp_path / "d" / "report.md").read_text()
    row = start["recordings"][0]
    assert row["checked"] and row["first_samples"] == max(MIN_START, round(START_SHARE * N))
    assert row["ratio"] >= RATIO and row["ratio_to_last"] >= RATIO and row["mean_over_rms_first"] >= ONE_SIGN
    # the statistic from the saved final model's free run over the record (numpy), to 1e-6
    data = np.loadtxt(records["moving"], delimiter=",", skiprows=1)
    model = hybrid.load_model(tmp_path / "d" / "extended.eqx")
    head = (data[:, 1] - np.asarray(model.predict(data[:, 0], DT)))[: row["first_samples"]]
    assert np.sqrt(np.mean(head**2)) == pytest.approx(row["rms_first"], rel=1e-6)
    assert abs(head.mean()) / np.sqrt(np.mean(head**2)) == pytest.approx(row["mean_over_rms_first"], rel=1e-6)


@pytest.mark.parametrize("case", ["at_rest", "settled", "wander"])
def test_a_record_that_starts_where_the_simulation_does_is_not(records, tmp_path, capsys, case):
    extra = ("--settle", 60) if case == "settled" else ()
    path = records["moving" if case == "settled" else case]
    out, report = diagnose(path, tmp_path / "d", capsys, *extra)
    start = report["evidence"]["start"]
    assert start["off"] is False and start["sentence"] is None
    assert "start: " not in out
    row = start["recordings"][0]
    assert row["checked"]
    if case == "wander":  # the start is missed, one-signed, but the end as much: a trend, not a start
        assert (
            row["ratio"] >= RATIO and row["mean_over_rms_first"] >= ONE_SIGN and row["ratio_to_last"] < RATIO
        )
    else:
        assert row["ratio"] < RATIO


def test_fit_says_it_too_for_a_physics_model(records, tmp_path, capsys):
    """`hybrid fit --model physics` on the record that starts moving: the same check on its free run."""
    argv = ["fit", records["moving"], *f"--columns input=u,output=y --rate {1 / DT} --physics lti:1".split()]
    argv += ["--model", "physics", "--quiet", "--out", tmp_path / "m.eqx", "--json", tmp_path / "f.json"]
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert code == 0, err
    start = json.loads((tmp_path / "f.json").read_text())["start"]
    assert start["off"] is True and "start: " in out and "--settle N" in out


def _slow_record(tmp_path, held: bool = True) -> Path:
    """A slow plant (τ 20 s over 240 s, a heater's power in 0–2), started settled at its first drive or at rest."""
    u = np.repeat(np.random.default_rng(3).uniform(0.0, 2.0, N // 15), 15)
    noise = NOISE * np.random.default_rng(5).normal(size=N)
    return held_lag_csv(tmp_path / "slow.csv", u, u[0] if held else 0.0, DT, 20.0, noise)


@pytest.mark.parametrize("held", [True, False], ids=["settled", "at_rest"])
def test_fit_points_at_a_held_start_where_the_physics_bent_to_meet_a_settled_one(tmp_path, capsys, held):
    """A slow plant (τ 20 s over 240 s, a heater's power in 0–2) whose record starts settled at its first
    drive: `lti:1` from rest meets the start by bending (τ 18 s, a direct term; its start check passes), so
    `fit` fits the held simulation too and points at --settle where that fits the held-out parts 1.5×
    better; the same record started at rest gets no such line."""
    path = _slow_record(tmp_path, held)
    argv = ["fit", path, *f"--columns input=u,output=y --rate {1 / DT} --physics lti:1".split()]
    argv += ["--model", "physics", "--quiet", "--out", tmp_path / "m.eqx", "--json", tmp_path / "f.json"]
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert code == 0, err
    start = json.loads((tmp_path / "f.json").read_text())["start"]
    if held:
        assert start["off"] is False
        assert f"fit again with --settle {settle_samples(N)}" in out and "tau_1" in start["held_hint"]
    else:
        assert "held at a fitted drive" not in out and "held_hint" not in start


@pytest.mark.parametrize("stopped_by", [None, "sigint", "time_limit"])
def test_the_held_start_s_second_fit_keeps_the_time_limit_and_a_signal_keeps_the_saved_model(
    tmp_path, capsys, monkeypatch, stopped_by
):
    """The held simulation's fit runs after the model is saved (the test above): it gets what
    `--time-limit` leaves (before, it was fitted with no limit at all), and a SIGINT
    during it (sent here as it starts, in this process: no race) ends the command as the physics-alone fit's
    does, in one line, exit 130, the saved model kept and no --json written. A limit that runs out in it
    (set here as it starts) leaves the model and the --json, and says the check was not done."""
    import hybrid.cli as cli

    calls: list[dict] = []
    fit_as_asked = cli._fit_as_asked

    def watched(args, model, recordings, frozen, **more):
        calls.append(more)
        if len(calls) == 2 and stopped_by == "sigint":  # the second fit: the held simulation's
            os.kill(os.getpid(), signal.SIGINT)
        if len(calls) == 2 and stopped_by == "time_limit":
            more["stop"].timed_out = True  # as the deadline would at its next look
        return fit_as_asked(args, model, recordings, frozen, **more)

    monkeypatch.setattr(cli, "_fit_as_asked", watched)
    path = _slow_record(tmp_path)
    argv = ["fit", path, *f"--columns input=u,output=y --rate {1 / DT} --physics lti:1".split()]
    argv += ["--model", "physics", "--quiet", "--out", tmp_path / "m.eqx", "--json", tmp_path / "f.json"]
    try:
        code = main([str(a) for a in argv + ["--time-limit", "600"]])
    except SystemExit as stopped:  # as the `hybrid` console script ends on it
        code = stopped.code
    out, err = capsys.readouterr()
    assert len(calls) == 2, (out, err)
    stop = calls[1].get("stop")
    assert stop is not None and 0 < stop.time_limit <= 600
    assert (tmp_path / "m.eqx").is_file()
    if stopped_by == "sigint":
        assert code == 130, err
        (line,) = err.strip().splitlines()
        assert "stopped by SIGINT while fitting the physics held at a drive" in line and "is saved" in line
        assert "--json not written" in line and not (tmp_path / "f.json").exists()
    elif stopped_by == "time_limit":
        assert code == 0, err
        (line,) = err.strip().splitlines()
        assert line.startswith("hybrid: warning: --time-limit 600 s ran out while fitting the physics held")
        assert "not checked" in line and "fit again with --settle" not in out
        assert "held_hint" not in json.loads((tmp_path / "f.json").read_text())["start"]
    else:
        assert code == 0, err
        assert "fit again with --settle" in out  # the hint still comes, within the limit


@pytest.mark.parametrize("test_record", ["moving", "at_rest"])
def test_a_test_record_that_starts_away_from_the_model_is_said_to(records, tmp_path, capsys, test_record):
    """`fit --test VAL --initial-samples 4` of a model with no held start: the 4 samples are only left out
    of the score (nothing sets the record's state from them), so a validation record that starts moving
    gets a `start:` line naming --settle (a probe's slow plant: RMSE 0.254 mm, 0.062 with --settle); one
    that starts where the model does gets none."""
    argv = ["fit", records["at_rest"], *f"--columns input=u,output=y --rate {1 / DT} --physics lti:1".split()]
    argv += ["--model", "physics", "--quiet", "--out", tmp_path / "m.eqx", "--json", tmp_path / "f.json"]
    if test_record == "moving":
        path = records["moving"]
    else:  # another record started at rest: another drive
        u = np.repeat(np.random.default_rng(4).uniform(-1.0, 1.0, N // 15), 15)
        path = held_lag_csv(
            tmp_path / "rest.csv", u, 0.0, DT, TAU, NOISE * np.random.default_rng(6).normal(size=N)
        )
    argv += ["--test", f"{path}", "--initial-samples", "4"]
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert code == 0, err
    (score,) = json.loads((tmp_path / "f.json").read_text())["test"]
    if test_record == "moving":
        assert score["start"]["off"] and score["start"]["ratio"] >= RATIO
        assert "start: test record" in out and "--initial-samples 4" in out and "--settle N" in out
    else:
        assert "start" not in score and "start: test record" not in out


def test_the_rule_and_its_sentences_on_residuals_made_by_hand():
    """`misfit_at_start` on numpy residuals: each condition of the rule, and the sentence for each case."""
    noise = 0.01 * np.random.default_rng(0).normal(size=1000)
    decay = 0.5 * np.exp(-np.arange(1000) / 8.0)  # an initial-state error dying away over ~20 samples
    moving, quiet = noise + decay, noise
    swings = np.where(np.arange(1000) % 2, 1.0, -1.0)
    # as large, but swinging at a size that does not die away (0.5, then 0.3 until sample 80): neither one
    # sign nor a free oscillation's fall, though its start is missed 6.7× the rest's RMS and more the end's
    two_signed = noise + swings * np.where(
        np.arange(1000) < 20, 0.5, np.where(np.arange(1000) < 80, 0.3, 0.0)
    )
    ends = noise + decay + decay[::-1]  # the end missed as much as the start
    # an underdamped plant that starts moving: its free oscillation changes sign as it dies away (a probe's
    # validation record: |mean| 0.53 of the start's RMS, no start line)
    ringing = noise + 0.5 * np.exp(-np.arange(1000) / 15.0) * np.cos(2 * np.pi * np.arange(1000) / 12.0)
    found = misfit_at_start([moving, quiet, two_signed, ends, ringing], [*"abcde"], settled=False)
    rows = found["recordings"]
    assert [row["off"] for row in rows] == [True, False, False, False, True]
    assert rows[2]["ratio"] >= RATIO and rows[2]["ratio_to_last"] >= RATIO and not rows[2]["dies_away"]
    assert rows[4]["mean_over_rms_first"] < ONE_SIGN and rows[4]["dies_away"]
    ring = misfit_at_start([ringing], ["e"], settled=False)["sentence"]
    assert "its RMS on the rest, dying away: " in ring and "all one sign" not in ring
    assert rows[0]["first_samples"] == 20  # 2 % of 1000
    assert "each record alone with --settle N" in found["sentence"]  # several records: one hold each
    alone = misfit_at_start([moving], ["a"], settled=False)["sentence"]
    assert alone.startswith("the model misses the first 20 samples of a by") and "--settle N" in alone
    assert "its RMS on the rest, all one sign: " in alone
    assert "larger --settle N" in misfit_at_start([moving], ["a"], settled=True)["sentence"]
    unpredicted = np.r_[np.full(5, np.nan), moving[5:]]  # a start no part predicts is not judged
    assert misfit_at_start([unpredicted], ["a"], settled=False)["recordings"][0]["checked"] is False


def test_the_retry_sentence_keeps_the_held_run_only_when_its_start_fits():
    """`settled_try` on checks made by hand: a held start that fits is kept; one that still misses is not."""
    from types import SimpleNamespace

    noise = 0.01 * np.random.default_rng(1).normal(size=1000)
    moving = noise + 0.5 * np.exp(-np.arange(1000) / 8.0)
    before = misfit_at_start([moving], ["a"], settled=False)
    fitted = misfit_at_start([noise], ["a"], settled=True)
    missed = misfit_at_start([moving], ["a"], settled=True)
    model = SimpleNamespace(heldout=SimpleNamespace(nmse=0.2))
    better = SimpleNamespace(heldout=SimpleNamespace(nmse=0.1))
    kept = settled_try(before, fitted, 250, "drift", ["drift"], model, better)
    assert kept["off"] is False and kept["settled"]["without"] == {
        "cause": "drift",
        "causes": ["drift"],
        "gain": pytest.approx(2.0),
        "ratio": before["recordings"][0]["ratio"],
    }
    assert "as --settle 250 would" in kept["sentence"] and "it names drift (gain 2.00×)" in kept["sentence"]
    stands = settled_try(before, missed, 250, "none", [], model, model)
    assert stands["off"] is True and stands["settled"]["off"] is True
    assert stands["sentence"].startswith(before["sentence"]) and "not the initial state" in stands["sentence"]
