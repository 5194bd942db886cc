"""An effect of time (a baseline's wander) fitted with the recording in one block extrapolates into every
held-out part, and the fit is chosen on them.

A probe's heater (two thermal masses, 120 s at 20 Hz) with a dead zone of 2 W and a baseline wandering
1.5 °C, fitted by ``hybrid fit --effects drive_dead_zone,baseline_drift`` in one contiguous block: a dead
zone of 0.52 W and a test record missed by 0.63 °C (noise 0.2); in 3 blocks, as `hybrid diagnose` splits
it, 1.79 W and 0.21 °C. The recordings here are made with scipy: a first-order plant behind a dead zone of
the drive, its output wandering by a slow sine, not by the effects fitted. A change the training part does
not show (a jump of the output's zero) leaves the held-out parts worse than their mean, and the fit says so.
"""

from __future__ import annotations

import json

import helpers as h
import numpy as np
import pytest
from scipy import signal

import hybrid
from hybrid.cli import main

WIDTH = 1.0  # the drive's dead zone, V
RATE, N = 20.0, 2400


def _heater(seed: int):
    """(t, drive, output): levels of 0–5 V held 2–8 s behind a dead zone of `WIDTH` into 1/(4 s + 1); the
    output's zero wanders by 0.4 over a 200 s sine; noise 1 % of the range."""
    rng = np.random.default_rng(seed)
    t = np.arange(N) / RATE
    v = h.held_levels(rng, t, 0.0, 5.0, 2.0, 8.0, count=100)
    _, x, _ = signal.lsim(signal.lti([1.0], [4.0, 1.0]), np.maximum(v - WIDTH, 0.0), t, interp=False)
    w = x + 0.4 * np.sin(2 * np.pi * t / 200.0)
    return t, v, w + 0.01 * np.ptp(w) * rng.normal(size=N)


def test_fit_cuts_a_record_with_an_effect_of_time_as_diagnose_does():
    from hybrid.core._fit import TIME_EFFECT_BLOCKS
    from hybrid.discovery._diagnosis import DiagnoseSettings

    assert (
        TIME_EFFECT_BLOCKS == DiagnoseSettings().blocks
    )  # core cannot import discovery: one number, kept equal


def test_a_fit_in_one_block_with_an_effect_of_time_says_it_extrapolates_and_in_three_it_does_not():
    t, v, w = _heater(0)
    recording = hybrid.Recording(t=t, v_in=v, w=w)
    effects = hybrid.resolve_effects(["baseline_drift"])
    model = hybrid.make_model(
        "physics", simulation=hybrid.EffectStack(hybrid.resolve_physics("lti:1"), effects)
    )
    solver = hybrid.LevenbergMarquardt(max_steps=5)  # the sentence reads the model, not how far LM went
    said = [hybrid.fit(model, [recording], solver=solver, blocks=b).warnings for b in (1, 3)]
    assert [sum("baseline_drift is a function of time" in s for s in w) for w in said] == [1, 0], said
    frozen = hybrid.fit(
        model,
        [recording],
        solver=solver,
        frozen={"baseline_slope_per_min", "baseline_curvature_per_min2", "baseline_cubic_per_min3"},
    ).warnings
    assert not any("function of time" in s for s in frozen)  # nothing of it fitted: nothing extrapolated


def _write(path, seed: int) -> None:
    t, v, w = _heater(seed)
    np.savetxt(path, np.c_[t, v, w], delimiter=",", header="t,v_in,w\ns,V,mm", comments="")


def test_hybrid_fit_cuts_a_recording_into_blocks_where_its_effects_include_one_of_time(tmp_path, capsys):
    """The command line fits the named causes in 3 blocks, says so, and finds the dead zone; --blocks 1 is
    kept as given, with the fit's warning."""
    _write(tmp_path / "rec.csv", 0)
    common = ["fit", "rec.csv", "--model", "physics", "--physics", "lti:1", "--quiet"]
    common += ["--effects", "drive_dead_zone,baseline_drift"]
    run = h.run_hybrid(tmp_path, *common, "--json", "fit.json", "--out", "fit.eqx")
    assert run.returncode == 0, run.stderr[-2000:]
    said = json.loads((tmp_path / "fit.json").read_text())
    assert said["settings"]["blocks"] == 3
    assert "baseline_drift is a function of time: each recording is cut into 3 blocks" in run.stderr
    assert said["parameters"]["drive_dead_zone_width"] == pytest.approx(WIDTH, rel=0.1)

    # The rest through the same command line in this process (`hybrid.cli.main`), without a process start each.
    def cli(*args):
        code = main([str(a) for a in args])
        out, err = capsys.readouterr()
        assert code == 0, err[-2000:]
        return err

    common = [a if a != "rec.csv" else tmp_path / "rec.csv" for a in common]
    err = cli(*common, "--blocks", "1", "--json", tmp_path / "one.json", "--out", tmp_path / "one.eqx")
    kept = json.loads((tmp_path / "one.json").read_text())
    assert kept["settings"]["blocks"] == 1 and "cut into 3 blocks" not in err
    assert any("function of time: with the recording in one block" in s for s in kept["warnings"])
    # scoring the saved model as it is fits nothing: nothing is cut into blocks, nothing said of it
    _write(tmp_path / "other.csv", 1)
    saved = ["fit", tmp_path / "rec.csv", "--start-from", tmp_path / "fit.eqx"]
    err = cli(*saved, "--max-steps", "0", "--test", tmp_path / "other.csv", "--quiet")
    assert "function of time" not in err, err
    # a saved physics model refitted with the default --model (hybrid): no physics-alone fit beside it
    err = cli(*saved, "--max-steps", "3", "--json", tmp_path / "a.json", "--out", tmp_path / "a.eqx")
    assert "physics model alone" not in err and "physics_alone" not in json.loads(
        (tmp_path / "a.json").read_text()
    )


def test_a_fit_whose_held_out_parts_are_no_better_than_their_mean_says_so():
    """The heater whose output's zero jumps by twice its range after the training part (70 %): the held-out
    parts are predicted worse than by their mean, which the fit said nothing of; without the jump, nothing."""
    from hybrid.core._fit import no_better_than_the_mean

    t, v, w = _heater(1)
    solver = hybrid.LevenbergMarquardt(max_steps=30)
    model = hybrid.make_model("physics", simulation=hybrid.resolve_physics("lti:1"))
    jumped = np.where(t > 0.72 * t[-1], w + 2.0 * np.ptp(w), w)
    said = [hybrid.fit(model, [hybrid.Recording(t=t, v_in=v, w=y)], solver=solver) for y in (jumped, w)]
    assert [sum("no better than their mean" in s for s in r.warnings) for r in said] == [1, 0]
    assert all(said[0].metrics[k]["nmse_variance"] >= 1.0 for k in ("validation", "test"))
    one = no_better_than_the_mean({"validation": {"nmse_variance": 1.07}, "test": {"nmse_variance": 0.4}})
    assert len(one) == 1 and "on the validation part 1.07× its variance" in one[0] and "test" not in one[0]
    assert no_better_than_the_mean({"train": {"nmse_variance": 3.0}, "test": {"nmse_variance": 0.99}}) == []
