"""When a recording cannot tell two causes apart, the report says so (issue 35, item 2).

The test's statistics against an independent reference (scipy's exact
binomial test), `diagnose` on a constructed confound and `hybrid design` on
its rivals (every limit, and the criterion recomputed from the rivals'
predictions): a staircase drive
whose level rises with time hides a gain that drifts over time, which a
saturation (a gain that falls with level) explains as well; on random levels
the two are told apart. The plant (a first-order lag) is made here with
scipy's `lfilter`, not by the library.
"""

from __future__ import annotations

import inspect
import json
from types import SimpleNamespace

import equinox as eqx
import helpers as h
import numpy as np
import pytest
from scipy.signal import lfilter
from scipy.stats import binomtest, norm

import hybrid
from hybrid.cli import main
from hybrid.discovery._ambiguity import (
    ALPHA,
    HINT_GAIN,
    OPEN_RIVALS,
    _why,
    ambiguities,
    level_time_correlation,
    paired_difference,
    power_near,
    sentence,
)
from hybrid.discovery._diagnosis import Candidate

RATE, N = 30.0, 1800


def test_the_sign_test_over_decorrelated_chunks_is_scipys_binomial_test():
    rng = np.random.default_rng(0)
    named = rng.normal(size=3000)
    slow = np.repeat(rng.normal(size=300), 10)  # errors that stay alike for 10 samples
    for rival, worse in ((named + 0.05 * rng.normal(size=3000), False), (named * 1.3 + 0.1 * slow, True)):
        test = paired_difference(named, rival)
        d = rival**2 - named**2
        reference = binomtest(test["wins"], test["chunks"], 0.5, alternative="greater").pvalue
        assert test["p_value"] == pytest.approx(reference, rel=1e-9)
        assert (test["p_value"] <= ALPHA) == worse
        assert test["chunks"] <= 3000 and test["mean"] == pytest.approx(np.mean(d))
    # correlated differences are compared in chunks of their decorrelation length, not sample by sample
    correlated = paired_difference(named, named + slow)
    assert correlated["chunks"] < 3000 / 5


def test_level_time_and_frequency_evidence():
    t = np.arange(N) / RATE
    staircase = np.repeat(np.linspace(0.2, 2.0, 10), N // 10)
    assert level_time_correlation([staircase]) > 0.95
    random_levels = np.repeat(np.random.default_rng(1).uniform(0, 2, N // 15), 15)
    assert level_time_correlation([random_levels]) < 0.5
    slow = np.sin(2 * np.pi * 0.2 * t)
    assert power_near([slow], RATE, 0.2) > 0.9 and power_near([slow], RATE, 5.0) < 1e-3


def _recording(staircase: bool, seed: int = 0) -> hybrid.Recording:
    """A first-order lag (τ 0.5 s) whose gain decays by 1.2 %/s; the drive a staircase or random levels."""
    rng = np.random.default_rng(seed)
    if staircase:
        u = np.repeat(np.linspace(0.2, 2.0, 10), N // 10)
    else:
        u = np.repeat(rng.uniform(0.0, 2.2, N // 15), 15)
    a = np.exp(-1.0 / (RATE * 0.5))
    w = lfilter([1 - a], [1, -a], u) * np.exp(-0.012 * np.arange(N) / RATE)
    w = w + 0.005 * np.ptp(w) * rng.normal(size=N)
    return hybrid.Recording.from_arrays(v_in=u, w=w, rate=RATE)


@pytest.fixture(scope="module")
def confounded():
    """The staircase's diagnosis with the two rivals of the confound (the search's others: other tests)."""
    return hybrid.diagnose(
        _recording(staircase=True), simulation=hybrid.LTI(1), effects=["saturation", "drift"]
    )


def test_a_drift_hidden_by_a_rising_staircase_is_reported_ambiguous_and_random_levels_separate_it(
    confounded, tmp_path
):
    effects = {"saturation", "drift"}
    assert confounded.cause in effects
    (entry,) = confounded.to_dict()["ambiguous"]
    (rival,) = entry["rivals"]
    assert {entry["named"], rival["name"]} == effects
    assert rival["p_value"] > ALPHA and rival["named_wins"] <= rival["chunks"]
    assert any("level and time are correlated" in why for why in entry["why"])
    text = sentence(entry)
    assert "cannot tell" in text and rival["name"] in text and "\n" not in text
    paths = hybrid.write_report(confounded, tmp_path)  # report.md says it in one sentence
    assert f"**Ambiguous.** {text}" in paths["report.md"].read_text()
    assert json.loads(paths["report.json"].read_text())["ambiguous"][0]["rivals"][0]["name"] == rival["name"]
    # each side saved as a loadable model with its own effect
    for name, file in entry["models"].items():
        assert {e.name for e in hybrid.load_model(tmp_path / file).simulation.effects} == {
            "frame_timing",
            name,
        }

    separated = hybrid.diagnose(
        _recording(staircase=False), simulation=hybrid.LTI(1), effects=sorted(effects)
    )
    assert separated.cause == "drift" and separated.ambiguous == []


def _rivals(diagnosis):
    (entry,) = diagnosis.ambiguous
    return {name: diagnosis.models[file.removesuffix(".eqx")] for name, file in entry["models"].items()}


@pytest.mark.parametrize(
    "limits",
    [
        {"amplitude": 1.5},  # |u| ≤ 1.5
        {"bounds": (0.3, 1.8)},  # a one-sided range (a pump's)
        {"amplitude": 2.2, "slew": 1.5},  # and a slew limit
    ],
    ids=["amplitude", "bounds", "slew"],
)
def test_a_designed_drive_keeps_every_limit_and_separates_the_rivals_more_than_a_prbs(confounded, limits):
    noise = confounded.noise_floor.std
    design = hybrid.design_drive(  # all designed (rich=0): the gradient's work alone
        _rivals(confounded), duration=20.0, rate=RATE, noise_std=noise, starts=2, steps=60, rich=0.0, **limits
    )
    low, high = limits.get("bounds", (-limits.get("amplitude", 0.0), limits.get("amplitude", 0.0)))
    assert design.v_in.shape == (600,) and np.allclose(np.diff(design.t), 1 / RATE)
    assert np.min(design.v_in) >= low and np.max(design.v_in) <= high
    if "slew" in limits:
        assert np.max(np.abs(np.diff(design.v_in))) <= limits["slew"] / RATE * (1 + 1e-9)
    # the criterion, recomputed independently from the rivals' predictions under the drive
    a, b = (np.asarray(m.predict(design.v_in, 1 / RATE)) for m in _rivals(confounded).values())
    assert design.criterion == pytest.approx(np.mean((a - b) ** 2) / noise**2, rel=1e-9)
    # the gradient does the work: the control PRBS is the first start, and the design ends far beyond
    # it (4.2–5.4× when written; ≥ 2 asserted). A zero gradient w.r.t. the drive left it at 1×.
    assert design.criterion >= 2.0 * design.control_criterion > 0


def test_a_rich_share_keeps_the_control_prbs_at_the_start_and_designs_the_rest(confounded):
    noise, limits = confounded.noise_floor.std, {"amplitude": 2.2, "slew": 1.5}
    rivals = _rivals(confounded)
    design = hybrid.design_drive(
        rivals, duration=20.0, rate=RATE, noise_std=noise, starts=2, steps=60, rich=0.4, seed=3, **limits
    )
    _, control = hybrid.rich_drive(duration=20.0, rate=RATE, seed=3, **limits)
    kept = design.rich_samples
    assert kept == 240  # 0.4 of 600 samples
    np.testing.assert_array_equal(design.v_in[:kept], control[:kept])  # the kept part: the control's own
    assert np.max(np.abs(design.v_in)) <= 2.2  # and the limits hold across the seam
    assert np.max(np.abs(np.diff(design.v_in))) <= 1.5 / RATE * (1 + 1e-9)
    assert not np.allclose(design.v_in[kept:], control[kept:])  # the rest was designed
    a, b = (np.asarray(m.predict(design.v_in, 1 / RATE)) for m in rivals.values())
    assert design.criterion == pytest.approx(
        np.mean((a - b) ** 2) / noise**2, rel=1e-9
    )  # over the whole drive
    assert design.criterion > design.control_criterion > 0
    for bad in (1.0, -0.1, True, float("nan")):
        with pytest.raises(hybrid.InputError, match="rich must be a share") as caught:
            hybrid.design_drive(rivals, duration=5.0, rate=RATE, amplitude=1.0, rich=bad)
        assert "\n" not in str(caught.value)


def test_a_rich_drive_keeps_its_limits_and_refuses_bad_ones_in_one_line():
    t, v = hybrid.rich_drive(duration=40.0, rate=RATE, bounds=(0.3, 1.8), slew=0.5, seed=5)
    assert v.shape == t.shape == (1200,) and np.allclose(np.diff(t), 1 / RATE)
    assert np.min(v) >= 0.3 and np.max(v) <= 1.8 and np.max(np.abs(np.diff(v))) <= 0.5 / RATE * (1 + 1e-9)
    assert np.ptp(v) > 0.5 * 1.5  # levels spread over the range, not a constant
    again = hybrid.rich_drive(duration=40.0, rate=RATE, bounds=(0.3, 1.8), slew=0.5, seed=5)[1]
    np.testing.assert_array_equal(v, again)
    for kwargs, words in (({"amplitude": -1.0}, "amplitude must be > 0"), ({}, "amplitude=A")):
        with pytest.raises(hybrid.InputError, match=words) as caught:
            hybrid.rich_drive(duration=5.0, rate=RATE, **kwargs)
        assert "\n" not in str(caught.value) and str(caught.value).startswith("rich_drive:")


def test_a_rich_drive_reaches_both_ends_of_its_range_and_its_level_does_not_follow_time():
    """A probe's rich drive over 0.5–5 V for 60 s at 20 Hz stayed within 1.02–3.87, and a design's kept
    first half (the same levels) fell with time, r = −0.9, on a diagnosis that asked to tell a drift from a
    level effect. Over twenty seeds: each drive's levels reach within 20 % of the range of both ends, and
    neither the whole drive's level nor its first half's correlates with time by more than 0.3."""
    t = np.arange(1200) / 20.0
    for seed in range(20):
        v = hybrid.rich_drive(duration=60.0, rate=20.0, bounds=(0.5, 5.0), seed=seed)[1]
        assert v.min() <= 0.5 + 0.2 * 4.5 and v.max() >= 5.0 - 0.2 * 4.5, (seed, v.min(), v.max())
        for part in (slice(None), slice(0, 600)):
            assert abs(np.corrcoef(v[part], t[part])[0, 1]) <= 0.3, seed


def test_design_refuses_bad_limits_in_one_line(confounded):
    rivals = _rivals(confounded)
    for kwargs, words in (
        ({}, "amplitude=A"),
        ({"amplitude": 1.0, "bounds": (0, 1)}, "not both"),
        ({"bounds": (1.0, 0.0)}, "low < high"),
        ({"amplitude": 1.0, "slew": -1.0}, "slew must be > 0"),
    ):
        with pytest.raises(hybrid.InputError, match=words) as caught:
            hybrid.design_drive(rivals, duration=5.0, rate=RATE, **kwargs)
        assert "\n" not in str(caught.value)
    with pytest.raises(hybrid.InputError, match="two or more"):
        hybrid.design_drive({"one": next(iter(rivals.values()))}, duration=5.0, rate=RATE, amplitude=1.0)
    with pytest.raises(hybrid.InputError, match="more than the 1,000,000 a drive may have") as caught:
        hybrid.design_drive(rivals, duration=1e7, rate=RATE, amplitude=1.0)  # not a 186 GiB allocation
    assert "at most 33333.3 s at this rate" in str(caught.value)
    # a drive no diagnosis could read (a probe's 0.5 s at 25 Hz: 12 samples, written with exit 0)
    with pytest.raises(hybrid.InputError, match="is 15 samples, fewer than the 60 diagnose") as caught:
        hybrid.design_drive(rivals, duration=0.5, rate=RATE, amplitude=1.0)
    assert "at least 2 s" in str(caught.value)


def test_a_design_keeps_every_rivals_predicted_output_within_its_bounds(confounded):
    # A battery user's design drove the predicted cell voltage past its 4.2 V window: the drive's range
    # alone says nothing of where the output goes. With the output's bounds, every rival's prediction
    # (recomputed here from the models, not read from the design) keeps within them.
    rivals, noise = _rivals(confounded), confounded.noise_floor.std
    run = dict(duration=20.0, rate=RATE, noise_std=noise, starts=2, steps=60, amplitude=2.2)
    free = hybrid.design_drive(rivals, rich=0.0, **run)
    assert max(np.max(np.abs(p)) for p in free.predictions.values()) > 1.5  # the bound below bites
    for rich in (0.0, 0.5):  # the rich part (the control PRBS) is narrowed to keep within too
        design = hybrid.design_drive(rivals, rich=rich, output_bounds=(-1.0, 1.0), **run)
        assert np.max(np.abs(design.v_in)) <= 2.2
        for model in rivals.values():
            predicted = np.asarray(model.predict(design.v_in, 1 / RATE))
            assert np.min(predicted) >= -1.0 and np.max(predicted) <= 1.0
        assert design.limits["output_low"] == -1.0 and design.limits["output_high"] == 1.0
        assert design.criterion > design.control_criterion > 0  # and still designed beyond the control
    # no drive in the range keeps within: one line, not a drive that breaks the bound
    with pytest.raises(hybrid.InputError, match="keeps every rival's predicted output") as caught:
        hybrid.design_drive(rivals, output_bounds=(0.0, 0.01), **run)
    assert "\n" not in str(caught.value)
    with pytest.raises(hybrid.InputError, match="low < high"):
        hybrid.design_drive(rivals, output_bounds=(1.0, -1.0), **run)


def _runs(v) -> np.ndarray:
    """Lengths of the runs of equal consecutive samples of `v`."""
    edges = np.flatnonzero(np.diff(v) != 0) + 1
    return np.diff(np.r_[0, edges, len(v)])


def test_a_design_holds_each_level_at_least_the_hold_given(confounded):
    # A chamber user's design switched the heater every second: a relay, a contactor or a valve cannot.
    rivals, noise = _rivals(confounded), confounded.noise_floor.std
    run = dict(duration=20.0, rate=RATE, noise_std=noise, starts=2, steps=60, amplitude=2.2)
    design = hybrid.design_drive(rivals, rich=0.0, hold=2.0, **run)  # 600 samples, blocks of 60
    blocks = design.v_in.reshape(10, 60)
    np.testing.assert_array_equal(blocks, blocks[:, :1] * np.ones((1, 60)))  # each block one level
    assert np.max(np.abs(design.v_in)) <= 2.2 and design.limits["hold"] == 2.0
    assert design.criterion > design.control_criterion > 0  # designed, within the holds
    # with a rich part, the control's levels are held at least as long, and so is the designed rest
    # and at the seam: the kept part ends where a control's level does (cut inside one, a probe's design
    # held a level 0.2 s against a 2 s hold; here 12 of 60 samples with seed 2); the control holds a level
    # at most 5 s (150 samples), so a change lies within 75 of the share asked for
    for seed in (2, 3):
        design = hybrid.design_drive(rivals, rich=0.5, hold=2.0, seed=seed, **run)
        kept = design.rich_samples
        assert abs(kept - 300) <= 75 and design.v_in[kept] != design.v_in[kept - 1]  # a level's end
        assert np.min(_runs(design.v_in)[:-1]) >= 60  # every level but the last (cut by the end)
    # a hold between two samples rounds up, never short: 1.01 s at 30 Hz is blocks of 31 samples, not 30
    design = hybrid.design_drive(rivals, rich=0.0, hold=1.01, **run)
    changes = np.flatnonzero(np.diff(design.v_in)) + 1
    assert changes.size and np.all(changes % 31 == 0), changes
    t, v = hybrid.rich_drive(duration=40.0, rate=RATE, amplitude=1.0, hold=3.0, seed=2)
    assert np.min(_runs(v)[:-1]) >= 90  # every level but the last (cut by the end) held ≥ 3 s
    with pytest.raises(hybrid.InputError, match="longer than the drive"):
        hybrid.design_drive(rivals, hold=30.0, **run)
    with pytest.raises(hybrid.InputError, match="hold must be > 0"):
        hybrid.design_drive(rivals, hold=-1.0, **run)


def test_a_design_never_ends_below_the_control_it_starts_from(confounded):
    # Four rivals that all but agree (T ≪ the soft minimum's width): the gradient follows a near-mean of
    # the six pairs, and the drive kept must be the one with the best least T, not the best near-mean.
    (a, _), noise = _rivals(confounded).values(), confounded.noise_floor.std
    rivals = {
        k: eqx.tree_at(lambda m: m.readout, a, a.readout.rescaled(1.0, s))
        for k, s in (("a", 1.0), ("a2", 1.0005), ("a3", 0.9997), ("a4", 1.0011))
    }
    design = hybrid.design_drive(
        rivals, duration=60.0, rate=RATE, noise_std=noise, starts=2, steps=30, amplitude=2.0, slew=0.001
    )
    assert 0 < design.control_criterion <= design.criterion
    # the first start is the control itself: what it reached is read on the reported criterion (the least
    # T), never below the control's (a soft minimum of six pairs lies below their least)
    assert design.criteria_by_start[0] >= design.control_criterion


def test_hybrid_design_from_the_command_line_writes_a_drive_that_keeps_its_limits(
    confounded, tmp_path, capsys
):
    folder = tmp_path / "diag"
    hybrid.write_report(confounded, folder)
    done = h.run_hybrid(
        tmp_path, "design", folder, "--duration", "10", "--amplitude", "2", "--slew", "4", "--rate", "30",
        "--starts", "2", "--steps", "40", "--out", "drive.csv", "--quiet",
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    table = np.loadtxt(tmp_path / "drive.csv", delimiter=",", skiprows=1)
    assert table.shape == (300, 2) and np.max(np.abs(table[:, 1])) <= 2.0
    assert np.max(np.abs(np.diff(table[:, 1]))) <= 4.0 / 30 * (1 + 1e-6)
    assert (tmp_path / "drive.png").stat().st_size > 0 and "× a multilevel PRBS" in done.stdout
    assert "n·T = " in done.stdout  # how surely a recording under it tells the rivals apart
    # ±2 V on a staircase of 0.2-2 V: the rivals are extrapolated below 0.2 V (a probe's 50-60 V: unsaid)
    assert "beyond the 0.2 to 2 V of the diagnosed recordings" in done.stderr, done.stderr
    assert "--bounds 0.2:2 keeps it where they were fitted" in done.stderr
    # the default keeps design_drive's rich share (half of 300 samples) as the control PRBS, and says so
    assert "the first 150 kept as a multilevel PRBS" in done.stdout
    default = inspect.signature(hybrid.design_drive).parameters["rich"].default
    # The rest through the same command line in this process (`hybrid.cli.main`): refusals and the
    # rich drive's path, without a process start each.
    with pytest.raises(SystemExit):
        main(["design", "--help"])
    assert f"rich, {default:g}" in " ".join(capsys.readouterr().out.split())
    y = tmp_path / "y.csv"
    short = ["design", str(folder), "--duration", "5", "--amplitude", "1", "--out", str(y)]

    def design(*args, base=short):
        code = main([*base, *map(str, args)])
        out, err = capsys.readouterr()
        return code, out, err

    code, _, err = design("--rich", "1")
    assert code == 2 and "--rich" in err and not y.exists()
    code, _, err = design("--bounds", "0:1")
    assert code == 2 and "not both" in err and not y.exists()
    code, _, err = design("--output-bounds", "1:-1")
    assert code == 2 and "--output-bounds" in err and "LOW must be below" in err
    assert len(err.strip().splitlines()) == 1 and not y.exists()
    code, _, err = design("--min-hold", "0")
    assert code == 2 and "--min-hold" in err and not y.exists()
    within = ["design", str(folder), "--duration", "5", "--bounds", "0.2:2", "--starts", "1", "--steps", "5"]
    code, _, err = design("--out", y, base=within)
    assert code == 0 and "beyond" not in err and "nearly constant" not in err, err  # nothing to say
    y.unlink()
    y.with_suffix(".png").unlink()
    # a slew that lets the drive barely move: written, and said (a probe's "either drive tells them apart")
    code, out, err = design("--slew", "1e-9", "--out", y, base=within)
    assert code == 0 and "it is nearly constant" in err and "--slew 1e-09/s holds it there" in err, err
    # and its closing line does not then say the drive tells them apart (a probe's --slew 0.001)
    assert "tells them apart" not in out and "does not separate them" in out, out
    y.unlink()
    y.with_suffix(".png").unlink()
    # a second ambiguous step: the design goes to the first and names the other (a probe's design went to
    # step 1's two limits, and its open step 2 — a lag or nothing — was not said); --step 1 asks for that one
    report = json.loads((folder / "report.json").read_text())
    (first,) = report["ambiguous"]
    second = {**first, "step": 2, "named": "none", "rivals": [{**first["rivals"][0], "name": "lag"}]}
    (folder / "report.json").write_text(json.dumps({**report, "ambiguous": [first, second]}))
    code, out, _ = design("--out", y, base=within)
    rivals = " vs ".join([first["named"], first["rivals"][0]["name"]])
    assert code == 0 and f"design: step 1: {rivals}" in out, out
    assert (
        "the diagnosis leaves another step ambiguous (step 2: nothing more vs lag); --step N designs" in out
    ), out
    y.unlink()
    y.with_suffix(".png").unlink()
    code, out, _ = design("--step", "1", "--out", y, base=within)
    assert code == 0 and "leaves another step" not in out, out
    y.unlink()
    y.with_suffix(".png").unlink()
    (folder / "report.json").write_text(json.dumps(report))
    # a diagnosis with nothing ambiguous: one line, no file
    plain = tmp_path / "plain"
    plain.mkdir()
    report = json.loads((folder / "report.json").read_text())
    (plain / "report.json").write_text(json.dumps({**report, "ambiguous": [], "unexplained": None}))
    x = tmp_path / "x.csv"
    on_plain = ["design", str(plain), "--duration", "5", "--amplitude", "1", "--out", str(x)]
    code, _, err = design(base=on_plain)
    assert code == 2 and "nothing ambiguous" in err and "no design is needed" in err
    assert len(err.strip().splitlines()) == 1 and not x.exists()
    # nothing ambiguous, but a remainder no searched effect explains: a rich drive to record, written
    (plain / "report.json").write_text(
        json.dumps({**report, "ambiguous": [], "unexplained": {"ratio_to_floor": 3.0}})
    )
    code, out, err = design("--slew", "3", base=on_plain)
    assert code == 0 and "wrote a multilevel PRBS" in out, err
    assert "diagnose on both recordings together" in out
    table = np.loadtxt(x, delimiter=",", skiprows=1)
    expected = hybrid.rich_drive(duration=5.0, rate=30.0, amplitude=1.0, slew=3.0, seed=0)
    np.testing.assert_array_equal(table[:, 1], expected[1])
    assert np.max(np.abs(table[:, 1])) <= 1.0 and np.max(np.abs(np.diff(table[:, 1]))) <= 3.0 / 30 * (
        1 + 1e-9
    )
    assert (tmp_path / "x.png").stat().st_size > 0
    # without --rate, the drive is for the rig that made the diagnosed recording: its rate, not 30 Hz
    # (a 610 Hz Silverbox diagnosis got a 30 Hz drive); a report without that rate asks for --rate
    report_50 = {**report, "ambiguous": [], "unexplained": {"ratio_to_floor": 3.0}}
    report_50["evidence"] = {**report["evidence"], "rate_hz": 50.0}
    (plain / "report.json").write_text(json.dumps(report_50))
    five = ["design", str(plain), "--duration", "5", "--amplitude", "1"]
    code, out, err = design("--out", tmp_path / "r.csv", base=five)
    assert code == 0 and "250 samples at 50 Hz" in out, err + out
    t = np.loadtxt(tmp_path / "r.csv", delimiter=",", skiprows=1)[:, 0]
    np.testing.assert_allclose(np.diff(t), 0.02, rtol=1e-6)
    # a plug-in (for the rivals' classes) is probed at that rate too: a leapfrog oscillator at 12.7 Hz is
    # stable for ω·dt < 2, at 50 Hz but not at 30 Hz, where its square root is NaN (it was refused at 30 Hz
    # whatever the rig's rate)
    (tmp_path / "leapfrog.py").write_text(h.LEAPFROG)
    spec = f"{tmp_path / 'leapfrog.py'}:Leapfrog"
    code, out, err = design("--physics", spec, "--out", tmp_path / "p.csv", base=five)
    assert code == 0 and "250 samples at 50 Hz" in out, err + out
    code, _, err = design("--physics", spec, "--rate", "30", "--out", tmp_path / "q.csv", base=five)
    assert code == 2 and "at 30 Hz" in err and "non-finite" in err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "q.csv").exists()
    report_50["evidence"] = {k: v for k, v in report["evidence"].items() if k != "rate_hz"}
    (plain / "report.json").write_text(json.dumps(report_50))
    code, _, err = design("--out", tmp_path / "n.csv", base=five)
    assert code == 2 and "--rate HZ" in err and not (tmp_path / "n.csv").exists()
    (plain / "report.json").write_text(
        json.dumps({**report, "ambiguous": [], "unexplained": {"ratio_to_floor": 3.0}})
    )
    # ... but a step asked for by number, where no step is ambiguous: one line that says so, no file
    code, _, err = design("--step", "1", "--out", tmp_path / "s.csv", base=five)
    assert code == 2 and "--step 1" in err and "no ambiguous step" in err
    assert "no design is needed" not in err and "without --step" in err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "s.csv").exists()


def _candidate(name, gain, residual, eligible=False, material=True, reasons=()):
    candidate = SimpleNamespace(
        name=name, gain=gain, eligible=eligible, heldout_residual=residual, heldout=SimpleNamespace(nmse=1 / gain),
        parameters={}, derived={}, material=material, reasons=list(reasons),
    )  # fmt: skip
    candidate.refused_for_size = Candidate.refused_for_size.fget(candidate)  # the property, on this stand-in
    return candidate


def test_a_rival_that_misses_a_few_chunks_by_much_is_told_apart_by_its_mean_not_by_the_sign_test():
    # A loudspeaker whose amplifier clips, tried as a new user would: both saturations explain most of the
    # held-out part to the noise, the output's misses the clipped peaks by much; the sign test alone was a
    # coin toss (302 of 600 chunks) and called them indistinguishable.
    rng = np.random.default_rng(1)
    n = 3000
    base = rng.normal(size=n)
    named_residual = base + 0.3 * rng.normal(size=n)
    rival_residual = base + 0.3 * rng.normal(size=n)
    peaks = np.zeros(n, bool)
    for start in rng.choice(n - 5, 8, replace=False):
        peaks[start : start + 5] = True  # 8 clipped peaks of 5 samples, missed by 6 σ
    rival_residual[peaks] += 6.0 * rng.choice([-1.0, 1.0], peaks.sum())
    assert np.mean(rival_residual**2) > 1.4 * np.mean(named_residual**2)
    test = paired_difference(named_residual, rival_residual)
    assert test["chunks"] == 600 and test["p_value"] > 0.5  # the chunks are a coin toss (296 of 600) ...
    assert test["mean_p_value"] < 0.01  # ... the mean is not
    # the mean's p-value is the normal tail of mean / standard error (scipy as the reference)
    assert test["mean_p_value"] == pytest.approx(norm.sf(test["mean"] / test["std_error"]), rel=1e-9)
    effects = hybrid.resolve_effects(["drive_saturation", "saturation"])
    named = _candidate("drive_saturation", 98.5, named_residual, eligible=True)
    rival = _candidate("saturation", 48.5, rival_residual, eligible=True)
    step = SimpleNamespace(chosen=named, current=None, candidates=[named, rival], bar=1.0)
    assert ambiguities([step], base, 0.01, [rng.uniform(-1, 1, n)], RATE, effects) == []
    # where the rival is as good in the mean too, it stays a rival
    alike = _candidate("saturation", 97.0, base + 0.3 * rng.normal(size=n), eligible=True)
    step = SimpleNamespace(chosen=named, current=None, candidates=[named, alike], bar=1.0)
    (entry,) = ambiguities([step], base, 0.01, [rng.uniform(-1, 1, n)], RATE, effects)
    assert entry["rivals"][0]["mean_p_value"] > ALPHA and "sign test, mean" in sentence(entry)


def test_a_rival_within_the_noise_that_the_tests_separate_is_close_not_indistinguishable():
    # A 15-sample delay on a second-order plant, tried as a new user would: delay named at gain 30, a
    # resonance 18.7 beside it, sign test p 4e-16 over 225 chunks, and predictions 0.06 mm apart RMS, under
    # the noise. The report said the recording "cannot tell" them, against its own numbers.
    rng = np.random.default_rng(3)
    n = 3000
    t = np.arange(n) / RATE
    noise = rng.normal(size=n)  # the measurement noise, σ = 1
    named_residual = noise
    rival_residual = noise + 0.6 * np.sin(2 * np.pi * 0.7 * t)  # 0.42 σ RMS apart: within the noise
    effects = hybrid.resolve_effects(["delay", "resonance"])
    drive = [rng.uniform(-1, 1, n)]
    named = _candidate("delay", 30.0, named_residual, eligible=True)
    rival = _candidate("resonance", 18.7, rival_residual, eligible=True)
    step = SimpleNamespace(chosen=named, current=None, candidates=[named, rival], bar=1.0)
    (entry,) = ambiguities([step], noise, 1.0, drive, RATE, effects)
    (listed,) = entry["rivals"]
    # the reference: scipy's one-sided binomial test of the named cause's wins over the chunks
    assert listed["p_value"] == pytest.approx(
        binomtest(listed["named_wins"], listed["chunks"], alternative="greater").pvalue, rel=1e-9
    )
    assert listed["within_noise"] and listed["prediction_rms_difference"] < 1.0
    assert listed["named_better"] and min(listed["p_value"], listed["mean_p_value"]) < 1e-6
    said = sentence(entry)
    assert "cannot tell" not in said  # the tests do tell them apart ...
    assert "delay (gain 30) fits the held-out part significantly better than resonance (gain 18.7)" in said
    assert "differ by less than the noise" in said and "\n" not in said  # ... and the predictions are close
    # one the tests cannot separate, beside it: both are said, each as what it is
    same = _candidate("saturation", 29.0, -noise, eligible=True)  # as large an error on every sample
    step = SimpleNamespace(chosen=named, current=None, candidates=[named, rival, same], bar=1.0)
    (entry,) = ambiguities(
        [step], noise, 1.0, drive, RATE, hybrid.resolve_effects(["delay", "resonance", "saturation"])
    )
    said = sentence(entry)
    assert "cannot tell step 1's delay (gain 30) from saturation (gain 29)" in said
    assert "significantly better than resonance (gain 18.7)" in said and "the two are close" in said
    # the noise unknown (NaN): within the noise is not asked, and a rival the tests separate is no rival
    assert ambiguities([SimpleNamespace(chosen=named, current=None, candidates=[named, rival], bar=1.0)],
                       noise, float("nan"), drive, RATE, effects) == []  # fmt: skip


def test_a_candidate_refused_for_its_size_that_beats_the_named_cause_makes_the_name_unsure():
    # A piezo stage's creep under a staircase, tried as a new user would: drift named at 2.39x while
    # backlash gained 6.07x and was refused for its size alone, and the report did not doubt the name.
    rng = np.random.default_rng(5)
    base = rng.normal(size=600)
    levels = [rng.uniform(-1.0, 1.0, 600)]
    effects = hybrid.resolve_effects(["drift", "backlash", "hysteresis", "saturation"])
    named = _candidate("drift", 2.39, base / np.sqrt(2.39), eligible=True)
    size = ["not material: a play of 0.05 % of the drive's range, under 0.5 %"]
    better = _candidate("backlash", 6.07, base / np.sqrt(6.07), material=False, reasons=size)
    weaker = _candidate("hysteresis", 1.8, base / np.sqrt(1.8), material=False, reasons=size)
    refused = _candidate("saturation", 9.0, base / 3.0, material=False, reasons=[*size, "ΔBIC 3.0 > −10"])
    step = SimpleNamespace(chosen=named, current=None, candidates=[named, better, weaker, refused], bar=1.0)
    (entry,) = ambiguities([step], base, 0.01, levels, RATE, effects)
    # only the one refused for its size alone that gains more: one smaller, or refused by another rule, is not
    assert [(r["name"], r.get("too_small")) for r in entry["rivals"]] == [("backlash", True)]
    said = sentence(entry)
    assert "backlash (gain 6.07) fits the held-out part better" in said and "the name is not sure" in said
    assert "cannot tell" not in said  # the named cause is not "indistinguishable": it is beaten
    # beside a rival that the tests cannot tell apart, both are said
    alike = _candidate("saturation", 2.38, -base / np.sqrt(2.39), eligible=True)  # as large on every sample
    step = SimpleNamespace(chosen=named, current=None, candidates=[named, better, alike], bar=1.0)
    (entry,) = ambiguities([step], base, 0.01, levels, RATE, effects)
    said = sentence(entry)
    assert "cannot tell step 1's drift (gain 2.39) from saturation (gain 2.38)" in said
    assert "yet backlash (gain 6.07) fits" in said
    # no rival refused for its size that beats the name: no entry
    step = SimpleNamespace(chosen=named, current=None, candidates=[named, weaker], bar=1.0)
    assert ambiguities([step], base, 0.01, levels, RATE, effects) == []
    assert Candidate.refused_for_size.fget(SimpleNamespace(reasons=[])) is False  # a named one: no reasons


def test_an_open_last_step_has_nothing_more_against_its_best_gains_only_with_a_remainder():
    rng = np.random.default_rng(3)
    base = rng.normal(size=600)
    current = _candidate("none", 1.0, base)
    gains = {"delay": 1.3, "saturation": 1.1, "drift": 0.9, "backlash": 1.05}
    candidates = [_candidate(k, g, base / np.sqrt(g)) for k, g in gains.items()]
    step = SimpleNamespace(chosen=None, current=current, candidates=candidates, bar=current.heldout.nmse)
    drive = [np.repeat(rng.uniform(-1, 1, 40), 15)]
    (entry,) = ambiguities([step], base, 0.01, drive, RATE, [], open_remainder=True)
    assert entry["open"] and entry["named"] == "none" and entry["step"] == 1
    # "nothing more" against the OPEN_RIVALS largest gains above 1, best first (backlash, 1.05, is third)
    assert OPEN_RIVALS == 2 and [r["name"] for r in entry["rivals"]] == ["delay", "saturation"]
    # with a noise floor of 0.05, saturation's predictions (RMS 0.046 from nothing more's) are within
    # the noise: nothing more again; delay's (0.122) are not
    (wide,) = ambiguities([step], base, 0.05, drive, RATE, [], open_remainder=True)
    assert [r["name"] for r in wide["rivals"]] == ["delay"]
    # each rival's numbers are its residual's against nothing more's
    reference = paired_difference(base, candidates[0].heldout_residual)
    assert entry["rivals"][0]["p_value"] == reference["p_value"]
    assert "named nothing" in sentence(entry) and "delay (gain 1.3)" in sentence(entry)
    assert entry["evidence"] == "remainder"
    # no candidate gained: nothing to design against
    losers = SimpleNamespace(
        chosen=None, current=current, candidates=[candidates[2]], bar=current.heldout.nmse
    )
    assert ambiguities([losers], base, 0.01, drive, RATE, [], open_remainder=True) == []
    # an effect-free fit as good on training reaches held-out NMSE 0.8: delay (1/1.3 = 0.77) is still better
    # than it, saturation (1/1.1 = 0.91) is not: its gain is the simulation's extrapolation, no alternative
    bar = SimpleNamespace(chosen=None, current=current, candidates=candidates, bar=0.8)
    (entry,) = ambiguities([bar], base, 0.01, drive, RATE, [], open_remainder=True)
    assert [r["name"] for r in entry["rivals"]] == ["delay"]
    worse = SimpleNamespace(chosen=None, current=current, candidates=candidates, bar=0.7)
    assert ambiguities([worse], base, 0.01, drive, RATE, [], open_remainder=True) == []
    # a gain under HINT_GAIN is no experiment's worth (a new user's pendulum: a saturation gaining 1.03)
    slight = SimpleNamespace(
        chosen=None, current=current, candidates=[_candidate("saturation", 1.03, base / np.sqrt(1.03) + 0.2)],
        bar=current.heldout.nmse,
    )  # fmt: skip
    assert ambiguities([slight], base, 0.01, drive, RATE, [], open_remainder=True) == []
    # a candidate below its effect's materiality (a loop never closed) is no rival: the next one stands
    small = [_candidate("delay", 1.3, candidates[0].heldout_residual, material=False), *candidates[1:]]
    step = SimpleNamespace(chosen=None, current=current, candidates=small, bar=current.heldout.nmse)
    (entry,) = ambiguities([step], base, 0.01, drive, RATE, [], open_remainder=True)
    assert [r["name"] for r in entry["rivals"]] == ["saturation", "backlash"]


def test_at_the_floor_a_last_step_is_open_only_on_a_significant_gain_over_every_equally_good_fit():
    rng = np.random.default_rng(4)
    base = rng.normal(size=600)
    current = _candidate("none", 1.0, base)
    drive = [np.repeat(rng.uniform(-1, 1, 40), 15)]
    # each candidate's error is smaller in every sample: significant (p ≪ ALPHA)
    candidates = [_candidate(k, g, base / np.sqrt(g)) for k, g in {"delay": 1.3, "saturation": 1.1}.items()]
    step = SimpleNamespace(chosen=None, current=current, candidates=candidates, bar=current.heldout.nmse)
    (entry,) = ambiguities([step], base, 0.01, drive, RATE, [], open_remainder=False)
    assert entry["evidence"] == "significant" and [r["name"] for r in entry["rivals"]] == [
        "delay",
        "saturation",
    ]
    assert all(r["candidate_p_value"] <= ALPHA for r in entry["rivals"])
    # the candidate's side of the sign test is the test run the other way round
    for r, c in zip(entry["rivals"], candidates):
        assert r["candidate_p_value"] == paired_difference(c.heldout_residual, base)["p_value"]
    assert "not flagged as unexplained" in sentence(entry) and "each of delay (gain 1.3)" in sentence(entry)
    # an effect-free fit as good on training reaches held-out NMSE 0.8: delay's 1/1.3 is 1.04× better than
    # it, saturation's is worse (HINT_GAIN 1.05): a better fit of the simulation alone, no effect
    assert HINT_GAIN == 1.05
    bar = SimpleNamespace(chosen=None, current=current, candidates=candidates, bar=0.8)
    assert ambiguities([bar], base, 0.01, drive, RATE, [], open_remainder=False) == []
    # a gain of 1.3 that is no more than noise: each candidate's error a fresh draw, not consistently lower
    noisy = [_candidate("delay", 1.3, rng.normal(size=600))]
    chance = SimpleNamespace(chosen=None, current=current, candidates=noisy, bar=current.heldout.nmse)
    assert ambiguities([chance], base, 0.01, drive, RATE, [], open_remainder=False) == []


def test_an_open_step_of_a_real_diagnosis_saves_both_sides_and_a_drive_separates_them(tmp_path):
    """A drifting gain searched for with saturation and delay alone: nothing named, a remainder, delay gains."""
    found = hybrid.diagnose(
        _recording(staircase=False), simulation=hybrid.LTI(1), effects=["saturation", "delay"]
    )
    assert found.cause == "none" and found.unexplained is not None
    (entry,) = found.to_dict()["ambiguous"]
    assert entry["open"] and entry["named"] == "none" and entry["evidence"] == "remainder"
    assert all(r["gain"] > 1 for r in entry["rivals"])
    paths = hybrid.write_report(found, tmp_path)
    assert f"**Open.** {sentence(entry)}" in paths["report.md"].read_text()
    models = {name: hybrid.load_model(tmp_path / file) for name, file in entry["models"].items()}
    assert {e.name for e in models["none"].simulation.effects} == {"frame_timing"}
    for r in entry["rivals"]:
        assert {e.name for e in models[r["name"]].simulation.effects} == {"frame_timing", r["name"]}
    design = hybrid.design_drive(
        models, duration=10.0, rate=RATE, amplitude=2.0, noise_std=found.noise_floor.std, starts=1, steps=30
    )
    assert np.max(np.abs(design.v_in)) <= 2.0 and design.criterion >= design.control_criterion > 0


def test_the_design_says_how_surely_its_drive_tells_the_rivals_apart():
    """n·T is the lack-of-fit test's non-centrality: at `SEPARATES` a χ² test at 1 % rejects 9 times in 10."""
    from scipy.stats import chi2, ncx2

    from hybrid._cli_design import SEPARATES, separation

    assert ncx2.sf(chi2.ppf(0.99, 1), 1, SEPARATES) == pytest.approx(0.9, abs=0.005)
    assert "barely tell them apart" in separation(0.005, 0.001, 1000)  # n·T = 5
    assert "gains little over the multilevel PRBS" in separation(1.07, 1.0, 1200)  # the heater trial's
    assert "tells them apart at their fitted values (n·T" in separation(2.0, 0.5, 1200)
    assert "T is local" in separation(2.0, 0.5, 1200)  # a lab's refit absorbed a small-amplitude design's T
    # a final model 60× above its noise floor: what no rival explains is noise to the test too
    loose = separation(2.0, 0.5, 1200, excess=60.0)  # n·T 2,400 with the floor, 40 with the model's error
    assert "n·T = 2.4e+03 with the noise floor as σ, 40 with the final model's held-out error" in loose
    assert "tells them apart" in loose
    assert "barely tell them apart" in separation(2.0, 0.5, 1200, excess=600.0)  # n·T 4 with the error


def test_a_rising_drive_blames_level_and_time_only_between_an_effect_of_time_and_one_of_the_level():
    rng = np.random.default_rng(4)
    base = rng.normal(size=600)
    staircase = [np.repeat(np.linspace(0.2, 2.0, 8), 75)]  # level rises with time: |r| = 1
    effects = hybrid.resolve_effects(["saturation", "drive_saturation", "drift"])
    named = _candidate("saturation", 3.0, base / np.sqrt(3.0), eligible=True)
    for rival, blamed in (("drive_saturation", False), ("drift", True)):
        other = _candidate(rival, 2.99, base / np.sqrt(2.99), eligible=True)
        step = SimpleNamespace(chosen=named, current=None, candidates=[named, other], bar=1.0)
        (entry,) = ambiguities([step], base, 0.01, staircase, RATE, effects)
        assert [r["name"] for r in entry["rivals"]] == [rival]
        # two shapes of one static nonlinearity differ in where it sits, not in time
        assert any("level and time are correlated" in why for why in entry["why"]) is blamed, entry["why"]


def test_each_sentence_gives_the_reasons_of_its_own_rivals_and_gains_that_read_apart():
    """A probe's staircase (its own motor, a mild output saturation) named `saturation` (gain 6.5912),
    with `drift` it cannot tell apart and `drive_saturation` (gain 6.5875) it fits significantly better:
    both sentences said "the drive's level and time are correlated", which says nothing of two effects
    of the level, and the second read "saturation (gain 6.59) … better than drive_saturation (gain 6.59)"."""
    rng = np.random.default_rng(4)
    noise = rng.normal(size=600)
    staircase = [np.repeat(np.linspace(0.2, 2.0, 8), 75)]  # level rises with time: |r| = 1
    effects = hybrid.resolve_effects(["saturation", "drive_saturation", "drift"])
    named = _candidate("saturation", 6.5912, noise, eligible=True)
    level = _candidate("drive_saturation", 6.5875, noise + 0.3, eligible=True)  # worse on every sample
    time = _candidate("drift", 6.0, -noise, eligible=True)  # as large an error on every sample
    step = SimpleNamespace(chosen=named, current=None, candidates=[named, level, time], bar=1.0)
    (entry,) = ambiguities([step], noise, 1.0, staircase, RATE, effects)
    by_name = {r["name"]: r for r in entry["rivals"]}
    assert by_name["drive_saturation"]["named_better"] and not by_name["drift"]["named_better"]
    assert by_name["drive_saturation"]["why"] == [] and len(by_name["drift"]["why"]) == 1
    cannot, close = sentence(entry).split(" Another drive is needed to separate them. ")
    assert "cannot tell step 1's saturation (gain 6.59) from drift (gain 6)" in cannot
    assert "level and time are correlated" in cannot
    assert (
        "(gain 6.591) fits the held-out part significantly better than drive_saturation (gain 6.588)" in close
    )
    assert "level and time" not in close
    # two recordings diagnosed together are "these recordings"
    (entry,) = ambiguities([step], noise, 1.0, [*staircase, *staircase], RATE, effects)
    assert entry["recordings"] == 2 and sentence(entry).startswith("These recordings cannot tell step 1's")


def test_at_the_floor_a_drift_the_rising_level_hides_opens_the_step_on_its_training_evidence():
    """A material effect of time that passes the BIC rule on training but not held out, on a rising drive.

    Its held-out gain is within the noise and under the step's bar (an effect-free fit with biased
    parameters does as well held out: the confound itself); a random drive, an effect of the level, an
    immaterial drift or a BIC drop under the rule open nothing.
    """
    rng = np.random.default_rng(5)
    base = rng.normal(size=600)
    current = _candidate("none", 1.0, base)
    effects = hybrid.resolve_effects(["saturation", "baseline_drift"])
    staircase = [np.repeat(np.linspace(0.0, 50.0, 10), 60)]
    random_levels = [np.repeat(rng.uniform(0.0, 50.0, 40), 15)]

    def step(name="baseline_drift", delta_bic=-159.0, material=True):
        drift = _candidate(name, 1.07, base / np.sqrt(1.07) + 0.3 * rng.normal(size=600), material=material)
        drift.delta_bic = delta_bic
        return SimpleNamespace(chosen=None, current=current, candidates=[drift], bar=1 / 1.03 * 0.9)

    (entry,) = ambiguities([step()], base, 0.01, staircase, RATE, effects)
    assert entry["open"] and entry["evidence"] == "confound" and entry["named"] == "none"
    assert [r["name"] for r in entry["rivals"]] == ["baseline_drift"] and entry["rivals"][0][
        "delta_bic"
    ] == -159
    assert any("level and time are correlated" in why for why in entry["why"])
    assert "lowers the BIC by 159" in sentence(entry) and "hybrid design" in sentence(entry)
    for drives, kwargs in (
        (random_levels, {}),  # level and time apart: the held-out part would have told
        (staircase, {"name": "saturation"}),  # an effect of the level is no drift hidden by the level
        (staircase, {"material": False}),
        (staircase, {"delta_bic": -9.0}),  # under the search's BIC rule (10)
    ):
        assert ambiguities([step(**kwargs)], base, 0.01, drives, RATE, effects) == [], kwargs


def _heated_block(drop: float, seed: int = 0) -> hybrid.Recording:
    """A heated block read through a lag (τ 8 s, 0.4 K/W) under a rising staircase of heater power, 60 s at
    20 Hz; its sensor's baseline falls by `drop` of the response's range over the recording (scipy)."""
    rng = np.random.default_rng(seed)
    rate, n = 20.0, 1200
    u = np.repeat(np.linspace(0.0, 50.0, 10), n // 10)
    a = np.exp(-1.0 / (rate * 8.0))
    w = 0.4 * lfilter([1 - a], [1, -a], u)
    w = w - drop * np.ptp(w) * np.arange(n) / n
    w = w + 0.01 * np.ptp(w) * rng.normal(size=n)
    return hybrid.Recording.from_arrays(v_in=u, w=w, rate=rate)


def test_a_baseline_drift_absorbed_by_a_staircase_is_open_not_an_all_clear():
    """A new user's heated block: the report said nothing was missing and `hybrid design` refused to run.

    The drift (15 % of range) is absorbed held out by a gain and a time constant biased low; on
    training `baseline_drift` lowers the BIC by ~130. Without the drift, the same staircase opens nothing.
    """
    effects = ["baseline_drift", "saturation"]
    found = hybrid.diagnose(_heated_block(0.15), simulation=hybrid.LTI(1), effects=effects)
    assert found.causes == [] and found.unexplained is None  # at the floor: the rules name nothing
    (entry,) = found.to_dict()["ambiguous"]
    assert entry["evidence"] == "confound" and [r["name"] for r in entry["rivals"]] == ["baseline_drift"]
    assert set(entry["models"]) == {"none", "baseline_drift"}  # both sides saved: hybrid design has rivals
    said = found.to_dict()["verdict"]  # the headline is no all-clear
    assert "whether baseline_drift is missing is open" in said and "No effect is needed" not in said
    clean = hybrid.diagnose(_heated_block(0.0), simulation=hybrid.LTI(1), effects=effects)
    assert clean.causes == [] and clean.ambiguous == []


def test_an_open_step_of_level_effects_on_a_rising_staircase_says_a_drift_would_act_alike():
    """A probe's staircase hiding a saturation left the last step open, saturation against nothing more,
    with no reason, while the same drive hiding a drift gave the level/time correlation. An open step's
    rivals that are all effects of the level get it too; a named step's two level effects do not (a
    drive's saturation beside a saturation is no effect of time), nor does a drive that does not rise."""
    from hybrid.discovery._effect_set import resolve_effects

    effects = resolve_effects(None, hybrid.LTI(2))
    stair = [np.repeat(np.linspace(0.2, 2.0, 12), 250)]
    random = [np.repeat(np.random.default_rng(4).permutation(np.linspace(0.2, 2.0, 12)), 250)]
    none, saturation = SimpleNamespace(name="none"), SimpleNamespace(name="saturation", parameters={})
    open_why = _why(none, ["saturation"], [saturation], stair, 25.0, effects, True)
    assert len(open_why) == 1 and "an effect of time (a drift) would act on this drive" in open_why[0]
    assert "|r| = 0.99" in open_why[0] or "|r| = 1.00" in open_why[0]
    assert _why(none, ["saturation"], [saturation], random, 25.0, effects, True) == []
    assert _why(saturation, ["drive_saturation"], [], stair, 25.0, effects) == []  # a named step's
