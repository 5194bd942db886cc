"""`--settle N`: a lab's record that does not start at rest, through the real command line.

The records are a first-order system's response (exact ZOH by numpy), each
started from its own held drive: the estimation record from 1.5, the test
record from −0.8. `hybrid fit --physics lti:1 --settle N` must recover the held
drive with the dynamics; with ``--test`` the test record's own held drive is
re-fitted on its first samples (and reported), so the free-run score sits at
the noise level; the saved model loads back as a `HeldStart`. Bad uses end
with exit 2 and one line.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers import held_lag_csv

import hybrid
from hybrid.cli import main

TAU, DT, NOISE = 3.0, 0.5, 0.002


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    rng = np.random.default_rng(4)
    folder = tmp_path_factory.mktemp("settle")
    paths = {}
    for name, held, seed in (("est", 1.5, 1), ("val", -0.8, 2)):
        u = np.repeat(np.random.default_rng(seed).uniform(-1.0, 1.0, 40), 15)
        paths[name] = held_lag_csv(folder / f"{name}.csv", u, held, DT, TAU, NOISE * rng.normal(size=u.size))
    return paths


def run(argv, capsys):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_fit_with_settle_recovers_the_held_drive_and_scores_a_test_record_from_its_own(lab, tmp_path, capsys):
    report, saved = tmp_path / "fit.json", tmp_path / "m.eqx"
    code, out, err = run(
        [
            "fit",
            lab["est"],
            "--columns",
            "input=u,output=y",
            "--rate",
            1 / DT,
            "--physics",
            "lti:1",
            "--settle",
            60,
            "--model",
            "physics",
            "--quiet",
            "--out",
            saved,
            "--json",
            report,
            "--test",
            lab["val"],
            "--split",
            "0.8,0.1,0.1",
        ],
        capsys,
    )
    assert code == 0, err
    fitted = json.loads(report.read_text())
    assert fitted["parameters"]["initial_drive"] == pytest.approx(1.5, abs=0.02)
    assert fitted["parameters"]["tau_1"] == pytest.approx(TAU, rel=0.02)
    test = fitted["test"][0]
    assert test["initial_drive"] == pytest.approx(-0.8, abs=0.05) and test["initial_samples"] == 15
    assert test["rmse"] < 3 * NOISE  # the noise, not the start transient (2 × 0.8 × e^{-t/3} otherwise)
    assert "re-fitted on its first 15 samples" in out
    assert "start: " not in out and fitted["start"]["off"] is False  # held first, the record's start fits
    model = hybrid.load_model(saved)
    assert isinstance(model.simulation, hybrid.HeldStart) and model.simulation.settle_samples == 60
    assert float(model.parameters()["initial_drive"]) == pytest.approx(fitted["parameters"]["initial_drive"])


@pytest.mark.parametrize(
    "extra, phrase",
    [
        (["--settle", "0"], "--settle"),
        (["--settle", "20", "--model", "normal"], "normal model has none"),
        (["--settle", "20", "TWICE"], "give one recording"),
    ],
)
def test_bad_settle_exits_2_with_one_line(lab, tmp_path, capsys, extra, phrase):
    recordings = [lab["est"], lab["val"]] if "TWICE" in extra else [lab["est"]]
    argv = [
        "fit",
        *recordings,
        "--columns",
        "input=u,output=y",
        "--rate",
        1 / DT,
        "--physics",
        "lti:1",
        "--model",
        "physics",
        "--quiet",
        "--out",
        tmp_path / "m.eqx",
        *(a for a in extra if a != "TWICE"),
    ]
    code, _, err = run(argv, capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and phrase in err, err


def test_diagnose_refuses_settle_on_two_recordings(lab, tmp_path, capsys):
    code, _, err = run(
        [
            "diagnose",
            lab["est"],
            lab["val"],
            "--columns",
            "input=u,output=y",
            "--rate",
            1 / DT,
            "--settle",
            20,
            "--out",
            tmp_path / "d",
        ],
        capsys,
    )
    assert code == 2 and len(err.strip().splitlines()) == 1 and "give one recording" in err, err
