"""Rows a ``quality`` column marks 0 (rig's: w held there, not measured) are neither fitted nor scored.

`rig record` and `rig track` write w on every row and mark with quality 0 the frames their tracker could
not measure (the tip out of view: w held at its last value). `diagnose` left them out; `hybrid fit` fitted
them as measured, and every mapped read (``--range``, ``--units``, ``--columns``) dropped the column, so
that a user who followed the loader's own advice ("leave a stretch of them out with --range") lost the
flag for the rest of the record without a word. The planted system here is an LTI(2) checked by scipy
alone (`helpers.lti2_zoh_response`): 40 held rows in the training part keep the old fit at its start
(its validation loss never falls), and the test record's score is numpy's over the measured rows.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import helpers as h
import numpy as np
import pytest

import hybrid
from hybrid.cli import main

ROOT = Path(__file__).resolve().parents[1]
TRUE = {"f_1": 0.05, "zeta_1": 0.9, "bandpass_1": 0.4, "direct": 0.05}
N, TS = 400, 0.5  # samples per record, s
HELD = slice(60, 100)  # the training part's held rows (the train part is samples 0–119)
HELD_TEST = slice(200, 230)  # the test record's


def _record(path, seed, held, rng):
    """A rig-like file (t, v_in, w, quality): w held at its last measured value over `held`, quality 0 there."""
    u = h.step_drive(N, seed=seed, low=4, high=30)
    clean = 2.0 * h.lti2_zoh_response(TRUE, u, TS) + 1.0
    y = clean + 0.02 * np.std(clean) * rng.normal(size=N)
    w, quality = y.copy(), np.ones(N)
    w[held], quality[held] = y[held.start - 1], 0.0
    np.savetxt(
        path, np.c_[np.arange(N) * TS, u, w, quality], delimiter=",", header="t,v_in,w,quality", comments=""
    )
    return u, y, w, quality


@pytest.fixture(scope="module")
def records(tmp_path_factory):
    folder = tmp_path_factory.mktemp("quality")
    rng = np.random.default_rng(3)
    fit_path, test_path = folder / "rec.csv", folder / "val.csv"
    return (fit_path, _record(fit_path, 1, HELD, rng)), (test_path, _record(test_path, 2, HELD_TEST, rng))


def test_fit_and_its_test_score_leave_the_rows_of_quality_0_out(records, tmp_path):
    """The real entry point in a subprocess, the file mapped by --units as a lab would: the planted
    system is recovered, and --test's RMSE is numpy's over the test record's measured rows alone."""
    (fit_path, (u, y, _, _)), (test_path, (u_val, y_val, w_val, q_val)) = records
    model, report = tmp_path / "m.eqx", tmp_path / "fit.json"
    proc = subprocess.run(
        [sys.executable, "-m", "hybrid.cli", "fit", str(fit_path), "--units", "w=mm", "--model", "physics"]
        + ["--physics", "lti:2", "--max-steps", "40", "--quiet", "--test", str(test_path)]
        + ["--json", str(report), "--out", str(model)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    assert "40 of 400 samples have quality 0 (the first at sample 60)" in proc.stderr
    p = {k: float(v) for k, v in hybrid.load_model(model).parameters().items()}
    predicted = p["gain"] * h.lti2_zoh_response(p, u, TS) + p["offset"]
    # held rows fitted as measured kept the fit at its start: 0.74 of w's std off the true w
    assert np.sqrt(np.mean((predicted - y) ** 2)) < 0.05 * np.std(y)

    (score,) = json.loads(report.read_text())["test"]
    measured = q_val == 1
    assert score["samples"] == N - 30 and score["unmeasured"] == 30
    w_hat = p["gain"] * h.lti2_zoh_response(p, u_val, TS) + p["offset"]
    assert score["rmse"] == pytest.approx(np.sqrt(np.mean((w_val - w_hat)[measured] ** 2)), rel=1e-9)
    assert score["rmse"] < 0.05 * np.std(y_val)  # the held rows would have added their own miss
    assert "30 samples of quality 0 left out of the score" in proc.stdout


def test_a_mapped_read_keeps_the_quality_column_over_its_range(records, tmp_path):
    (fit_path, (_, _, w, quality)), _ = records
    for options, first in (({"sample_range": "50:400"}, 50), ({"units": {"w": "mm"}}, 0)):
        rec = hybrid.load_mapped(fit_path, **options)
        np.testing.assert_array_equal(rec.extra["quality"], quality[first:])
        np.testing.assert_allclose(rec.w, w[first:], rtol=1e-12)
        said = f"40 of {N - first} samples have quality 0 (the first at sample {60 - first}"
        assert any(said in n for n in rec.notes), rec.notes
        assert any("the file's 60)" in n for n in rec.notes) == bool(first), rec.notes
    # a column named quality that is not rig's 0/1 flag is a lab's own: not read
    data = np.loadtxt(fit_path, delimiter=",", skiprows=1)
    data[:, 3] = np.linspace(0.0, 5.0, N)
    other = tmp_path / "other.csv"
    np.savetxt(other, data, delimiter=",", header="t,v_in,w,quality", comments="")
    assert "quality" not in hybrid.load_mapped(other, sample_range="50:400").extra


def test_a_part_of_quality_0_throughout_is_refused_in_one_line(records, tmp_path, capsys):
    (fit_path, _), _ = records
    data = np.loadtxt(fit_path, delimiter=",", skiprows=1)
    data[320:, 3] = 0.0  # the validation part (the last 20 %) never measured
    path = tmp_path / "lost.csv"
    np.savetxt(path, data, delimiter=",", header="t,v_in,w,quality", comments="")
    code = main(["fit", str(path), "--model", "physics", "--physics", "lti:2", "--max-steps", "2", "--quiet"])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "every sample of its validation part has quality 0" in err and "--range" in err
    assert "Traceback" not in err


def test_rows_of_quality_0_at_the_start_do_not_read_as_a_start_the_model_misses(records, tmp_path, capsys):
    """A verifier's record that starts where the model does, its samples 2–29 garbage of quality 0 (5–29 in its own): the
    start check read them as the model missing its first 40 samples by 782× and asked for --settle."""
    (fit_path, _), _ = records
    data = np.loadtxt(fit_path, delimiter=",", skiprows=1)
    data[:, 3] = 1.0
    data[2:30, 2], data[2:30, 3] = 50.0, 0.0
    path, report = tmp_path / "start.csv", tmp_path / "start.json"
    np.savetxt(path, data, delimiter=",", header="t,v_in,w,quality", comments="")
    argv = ["fit", str(path), "--model", "physics", "--physics", "lti:2", "--max-steps", "40", "--quiet"]
    assert main([*argv, "--json", str(report), "--out", str(tmp_path / "m.eqx")]) == 0, (
        capsys.readouterr().err
    )
    data = json.loads(report.read_text())
    assert not data["start"]["off"], data["start"]
    assert not [w for w in data["warnings"] if "misses the first" in w]


def test_a_test_record_of_quality_0_throughout_is_refused_before_the_fit(records, tmp_path, capsys):
    (fit_path, _), (test_path, _) = records
    data = np.loadtxt(test_path, delimiter=",", skiprows=1)
    data[:, 3] = 0.0
    path, out = tmp_path / "blind.csv", tmp_path / "m.eqx"
    np.savetxt(path, data, delimiter=",", header="t,v_in,w,quality", comments="")
    argv = ["fit", str(fit_path), "--model", "physics", "--physics", "lti:2", "--quiet", "--out", str(out)]
    assert main([*argv, "--test", str(path)]) == 2
    err = capsys.readouterr().err
    assert "has 0 samples of quality 1 to score (at least 10 are needed" in err and "Traceback" not in err
    assert not out.exists()


def test_every_format_says_how_many_rows_have_quality_0(records, tmp_path):
    """A verifier's .npz with rig's quality column got no note (only a CSV's did); its rows were left out."""
    (fit_path, (_, _, w, quality)), _ = records
    data = np.loadtxt(fit_path, delimiter=",", skiprows=1)
    path = tmp_path / "rec.npz"
    np.savez(path, t=data[:, 0], v_in=data[:, 1], w=data[:, 2], quality=data[:, 3])
    rec = hybrid.Recording.load(path)
    np.testing.assert_array_equal(rec.extra["quality"], quality)
    assert [n for n in rec.notes if "40 of 400 samples have quality 0 (the first at sample 60)" in n], (
        rec.notes
    )


def test_a_frame_filled_into_a_gap_has_quality_0_and_the_note_says_it_is_left_out(records, tmp_path):
    (fit_path, (_, _, _, quality)), _ = records
    data = np.delete(np.loadtxt(fit_path, delimiter=",", skiprows=1), 200, axis=0)  # a dropped frame
    path = tmp_path / "gap.csv"
    np.savetxt(path, data, delimiter=",", header="t,v_in,w,quality", comments="")
    rec = hybrid.load_mapped(path, fill_gaps=1)
    expected = quality.copy()
    expected[200] = 0.0
    np.testing.assert_array_equal(rec.extra["quality"], expected)
    (said,) = [n for n in rec.notes if "filled by straight lines" in n]
    assert "the frames put in the gaps have quality 0" in said and "counts them as measured" not in said


def test_a_text_table_of_the_projects_columns_is_a_test_record_as_it_is_a_fitted_one(
    records, tmp_path, capsys
):
    """`hybrid fit x.txt` reads a text table headed t v_in w; a verifier's `--test test.txt` beside a
    fitted CSV was refused ("unknown suffix '.txt'"), and --test-columns alone could not map it."""
    (fit_path, _), (test_path, (_, _, w_val, q_val)) = records
    data = np.loadtxt(test_path, delimiter=",", skiprows=1)
    table, report = tmp_path / "val.txt", tmp_path / "fit.json"
    np.savetxt(table, data, header="t v_in w quality", comments="", fmt="%.10g")
    argv = ["fit", str(fit_path), "--model", "physics", "--physics", "lti:2", "--max-steps", "40", "--quiet"]
    assert (
        main([*argv, "--test", str(table), "--json", str(report), "--out", str(tmp_path / "m.eqx")]) == 0
    ), capsys.readouterr().err
    (score,) = json.loads(report.read_text())["test"]
    assert score["samples"] == N - 30 and score["unmeasured"] == 30 and score["unit"] == "mm"
