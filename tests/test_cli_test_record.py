"""`hybrid fit --test`: a model fitted on a benchmark's estimation record, scored on its validation record.

The file mimics Cascaded Tanks' dataBenchmark.csv: uEst, uVal, yEst, yVal and a period column Ts in
the first row only. The score is checked against an independent recomputation: the saved model's
parameters (read back with `hybrid.load_model`), the LTI's transfer function written out by hand,
scipy's ZOH discretisation, numpy's RMSE and Eq 18.
"""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import helpers as h
import numpy as np
import pytest

import hybrid
from hybrid import InputError
from hybrid.cli import main
from hybrid.data._mapping import load_mapped, load_pair

ROOT = Path(__file__).resolve().parents[1]
TRUE = {"f_1": 0.05, "zeta_1": 0.9, "bandpass_1": 0.4, "direct": 0.05}
N, TS = 400, 0.5  # samples per record, s


def _write(path, columns, ts=TS):
    names = list(columns)
    lines = [",".join(names + ["Ts"])]
    for i, row in enumerate(zip(*columns.values())):
        lines.append(",".join(f"{x:.12g}" for x in row) + f",{ts if i == 0 else ''}")
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    """Estimation and validation records of one planted LTI(2), 2 % noise, gain 2, offset 1."""
    folder = tmp_path_factory.mktemp("bench")
    rng = np.random.default_rng(5)
    u_est, u_val = h.step_drive(N, seed=1, low=4, high=30), h.step_drive(N, seed=2, low=4, high=30)

    def measure(u):
        y = 2.0 * h.lti2_zoh_response(TRUE, u, TS) + 1.0
        return y + 0.02 * np.std(y) * rng.normal(size=y.size)

    columns = {"uEst": u_est, "uVal": u_val, "yEst": measure(u_est), "yVal": measure(u_val)}
    return _write(folder / "bench.csv", columns), _write(folder / "fast.csv", columns, ts=0.25)


def _plain(path, *names):
    with open(path, newline="") as handle:
        rows = list(csv.DictReader(handle))
    return [np.array([float(r[n]) for r in rows]) for n in names]


@pytest.mark.parametrize("first", [None, 4])
def test_fit_scores_the_validation_record_as_an_independent_recomputation(bench, tmp_path, first):
    """The real entry point in a subprocess (a timeout instead of a hang): --test's RMSE is numpy's.

    With ``--initial-samples 4`` (Cascaded Tanks' rule) the first 4 samples are not scored.
    """
    path, _ = bench
    rule = [] if first is None else ["--initial-samples", str(first)]
    model, report = tmp_path / "m.eqx", tmp_path / "fit.json"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "hybrid.cli",
            "fit",
            str(path),
            "--model",
            "physics",
            "--physics",
            "lti:2",
            "--columns",
            "input=uEst,output=yEst",
            "--units",
            "w=cm",
            "--max-steps",
            "40",
            "--quiet",
            "--test",
            str(path),
            "--test-columns",
            "input=uVal,output=yVal",
            "--json",
            str(report),
            "--out",
            str(model),
            *rule,
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    data = json.loads(report.read_text())
    (score,) = data["test"]
    skip = first or 0
    assert (
        score["samples"] == N - skip and score["rate_hz"] == pytest.approx(1 / TS) and score["unit"] == "cm"
    )
    assert score["mapping"] == {"t": None, "v_in": "uVal", "w": "yVal"}
    assert "test record" in proc.stdout and f"RMSE {score['rmse']:.6g} cm" in proc.stdout

    fitted = hybrid.load_model(model)
    p = {k: float(v) for k, v in fitted.parameters().items()}
    u_val, y_val = _plain(path, "uVal", "yVal")
    w_hat = p["gain"] * h.lti2_zoh_response(p, u_val, TS) + p["offset"]  # free run from rest, every sample
    y_val, w_hat = y_val[skip:], w_hat[skip:]  # the rule's first samples are not scored
    rmse = np.sqrt(np.mean((y_val - w_hat) ** 2))
    nmse = np.mean((y_val / np.max(np.abs(y_val)) - w_hat / np.max(np.abs(w_hat))) ** 2)  # Eq 18
    assert score["rmse"] == pytest.approx(rmse, rel=1e-9)
    assert score["nmse"] == pytest.approx(nmse, rel=1e-9)
    assert score["nmse_variance"] == pytest.approx(rmse**2 / np.var(y_val), rel=1e-9)
    assert rmse < 0.1 * np.std(y_val)  # the planted system is recovered: it predicts the other record
    saved = json.loads(Path(f"{model}.json").read_text())["extra"]
    assert saved["test"] == data["test"] and "metrics" in saved

    # --max-steps 0 scores the saved model as it is: the same score, the model file untouched
    before = model.read_bytes()
    again = tmp_path / "again.json"
    args = ["fit", str(path), "--columns", "input=uEst,output=yEst", "--units", "w=cm", "--physics", "lti:2"]
    args += ["--start-from", str(model), "--max-steps", "0", "--quiet", "--test", str(path)]
    args += [
        "--test-columns",
        "input=uVal,output=yVal",
        "--json",
        str(again),
        "--out",
        str(tmp_path / "n.eqx"),
    ]
    assert main(args + rule) == 0
    (rescored,) = json.loads(again.read_text())["test"]
    assert (
        rescored["rmse"] == pytest.approx(score["rmse"], rel=1e-12)
        and rescored["samples"] == score["samples"]
    )
    assert model.read_bytes() == before and not (tmp_path / "n.eqx").exists()


@pytest.mark.parametrize(
    "extra,phrase",
    [
        (["--test", "{bench}", "--test-columns", "input=uVal,output=yVall"], "no column 'yVall'"),
        (
            ["--test", "{fast}", "--test-columns", "input=uVal,output=yVal"],
            "4 Hz but the model is fitted at 2 Hz",
        ),
        (["--test", "{bench}"], "the validation record is the estimation record"),
        (["--test-columns", "input=uVal,output=yVal"], "give --test FILE"),
        (["--test", "{bench}", "--test-range", "300:200"], "range"),
        (
            ["--test", "{bench}", "--test-columns", "input=uVal,output=yVal", "--initial-samples", "400"],
            "--initial-samples 400",
        ),
        (["--initial-samples", "4"], "give --test FILE"),
        (  # a probe's N − 1, offered as valid, ran the whole fit and then failed on "w is constant"
            ["--test", "{bench}", "--test-columns", "input=uVal,output=yVal", "--initial-samples", "399"],
            "at least 10 must be left to score; give a number from 1 to 390",
        ),
        (["--max-steps", "0"], "--max-steps 0 scores a saved model as it is: give it with --start-from"),
    ],
)
def test_bad_test_records_exit_2_with_one_line_before_fitting(bench, tmp_path, capsys, extra, phrase):
    path, fast = bench
    model = tmp_path / "m.eqx"
    argv = [
        "fit",
        path,
        "--model",
        "physics",
        "--physics",
        "lti:2",
        "--columns",
        "input=uEst,output=yEst",
        "--quiet",
        "--out",
        model,
    ] + [a.format(bench=path, fast=fast) for a in extra]
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and lines[0].startswith("hybrid: error:"), err
    assert phrase in lines[0], lines[0]
    assert not model.exists()  # refused before the fit, nothing written
    if "fast" in extra[1]:
        assert "2 Hz" in lines[0]  # both rates named


def test_load_pair_takes_the_validation_columns_in_one_string(bench):
    path, _ = bench
    _, validation = load_pair(path, columns="input=uEst,output=yEst", test_columns="input=uVal,output=yVal")
    assert validation == load_mapped(path, input="uVal", output="yVal")
    _, swapped = load_pair(path, input="uEst", output="yEst", test_columns="output=yVal")  # input stays uEst
    assert swapped.metadata["mapping"] == {"t": None, "v_in": "uEst", "w": "yVal"}
    with pytest.raises(InputError, match="given twice"):
        load_pair(path, input="uEst", output="yEst", test_columns="output=yVal", test_output="yEst")


def test_units_alone_on_files_in_the_projects_columns_read_the_test_record_as_the_fitted_one(
    tmp_path, capsys
):
    """`--units w=mm` on files in the project's own columns (t, v_in, w): the fitted file read, and the
    --test file refused with "no input column is named" (it went through the mapped loader, a probe).
    Now read as the fitted one, in the given unit."""
    paths = []
    for seed, name in ((1, "est.csv"), (2, "val.csv")):
        u = h.step_drive(N, seed=seed, low=4, high=30)
        y = 2.0 * h.lti2_zoh_response(TRUE, u, TS) + 1.0
        t = np.arange(N) * TS
        np.savetxt(tmp_path / name, np.c_[t, u, y], delimiter=",", header="t,v_in,w", comments="")
        paths.append(tmp_path / name)
    argv = ["fit", paths[0], "--model", "physics", "--physics", "lti:2", "--units", "w=mm"]
    argv += ["--test", paths[1], "--max-steps", "2", "--quiet", "--out", tmp_path / "m.eqx"]
    argv += ["--json", tmp_path / "f.json"]
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert code == 0, err
    (score,) = json.loads((tmp_path / "f.json").read_text())["test"]
    assert score["unit"] == "mm" and score["samples"] == N


def test_a_fit_of_records_at_two_rates_scores_a_test_record_at_either(bench, tmp_path, capsys):
    """Fitted records at 2 Hz and 4 Hz (a physics model runs at any rate): a test record at 2 Hz is scored.
    It was refused against the 4 Hz record, as every test record was against one or the other (a probe)."""
    path, fast = bench
    argv = ["fit", path, fast, *"--model physics --physics lti:2 --columns input=uEst,output=yEst".split()]
    argv += ["--test", path, "--test-columns", "input=uVal,output=yVal", "--max-steps", "2", "--quiet"]
    argv += ["--out", tmp_path / "m.eqx", "--json", tmp_path / "f.json"]
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert code == 0, err
    (score,) = json.loads((tmp_path / "f.json").read_text())["test"]
    assert score["rate_hz"] == pytest.approx(2.0) and score["samples"] == N


def test_effects_beside_a_saved_model_must_be_its_own(bench, tmp_path, capsys):
    """--effects beside --start-from imports the plug-ins a saved model uses; one the saved model lacks was
    dropped without a word (a probe's --effects delay): refused with one line, before any fitting."""
    path, _ = bench
    common = [path, *"--model physics --physics lti:2 --columns input=uEst,output=yEst --quiet".split()]
    saved = tmp_path / "saved.eqx"
    assert (
        main([str(a) for a in ["fit", *common, "--effects", "delay", "--max-steps", "2", "--out", saved]])
        == 0
    )
    again = ["fit", *common, "--start-from", saved, "--max-steps", "2", "--out", tmp_path / "again.eqx"]
    assert main([str(a) for a in [*again, "--effects", "delay"]]) == 0
    capsys.readouterr()
    code = main([str(a) for a in [*again, "--effects", "delay,backlash"]])
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and "--effects backlash: the saved model" in lines[0], lines
    assert "has no backlash" in lines[0]


def test_a_test_records_refusal_names_test_range_not_range(tmp_path, capsys):
    """A --test record whose output's last cells are missing: the loader's advice read "(--range 0:597)",
    which would cut the fitted record; for the test record the flag is --test-range."""
    rng = np.random.default_rng(0)
    u = np.repeat(rng.uniform(-1, 1, 30), 20)
    y = h.zoh_lag(u, 1 / 30.0, 0.5)
    est, val = tmp_path / "est.csv", tmp_path / "val.csv"
    est.write_text("u,y\n" + "".join(f"{p:.6f},{q:.6f}\n" for p, q in zip(u, y)))
    val.write_text(
        "u,y\n"
        + "".join(f"{p:.6f},{q:.6f}\n" if k < 597 else f"{p:.6f},\n" for k, (p, q) in enumerate(zip(u, y)))
    )
    argv = [
        "fit",
        est,
        "--columns",
        "input=u,output=y",
        "--rate",
        30,
        "--model",
        "physics",
        "--physics",
        "lti:1",
    ]
    argv += ["--quiet", "--max-steps", 1, "--test", val, "--fill-gaps", 2, "--out", tmp_path / "m.eqx"]
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert code == 2 and "--test " in err and "leave those samples out (--test-range 0:597)" in err, err
    assert "(--range " not in err and not (tmp_path / "m.eqx").exists()


def test_every_message_about_a_test_record_names_the_flag_that_cuts_it():
    """The rewrite of the loader's "(--range " missed "(--range, Recording.segment)" and "with --range":
    the flag is now the one `ranged_by` sets, wherever a message names it."""
    from hybrid.data._recording_checks import ranged_by

    t = np.delete(np.arange(100) / 30.0, 50)  # one frame lost: a gap
    arrays = {"t": t, "v_in": np.sin(t), "w": np.cos(t)}
    with pytest.raises(hybrid.InputError, match=r"gap \(--range, Recording\.segment\)"):
        hybrid.Recording(**arrays)
    with ranged_by("--test-range"), pytest.raises(hybrid.InputError, match=r"gap \(--test-range, Recording"):
        hybrid.Recording(**arrays)
    with pytest.raises(hybrid.InputError, match=r"gap \(--range, "):  # and back once the block ends
        hybrid.Recording(**arrays)


def test_a_test_file_with_other_columns_is_pointed_at_test_columns_and_the_advice_works(tmp_path, capsys):
    """A --test file whose columns are not the fitted files' was offered "--columns input=u,output=y"
    (a probe): that maps the fitted records, which it breaks. The advice now names --test-columns, with
    --columns for the fitted files in the project's own columns, and followed it scores the record."""
    rng = np.random.default_rng(1)
    u = np.repeat(rng.uniform(-1, 1, 30), 20)
    y = h.zoh_lag(u, 1 / 30.0, 0.5)
    t = np.arange(u.size) / 30.0
    est, val = tmp_path / "est.csv", tmp_path / "val.csv"
    est.write_text("t,v_in,w\n" + "".join(f"{a:.6f},{p:.6f},{q:.6f}\n" for a, p, q in zip(t, u, y)))
    val.write_text("time,u,y\n" + "".join(f"{a:.6f},{p:.6f},{q:.6f}\n" for a, p, q in zip(t, u, y)))
    base = ["fit", est, "--model", "physics", "--physics", "lti:1", "--quiet", "--max-steps", 2]
    code = main([str(a) for a in base + ["--test", val, "--out", tmp_path / "m.eqx"]])
    err = capsys.readouterr().err
    assert code == 2 and not (tmp_path / "m.eqx").exists(), err
    assert "--test-columns time=time,input=u,output=y" in err and "--columns t=t,input=v_in,output=w" in err
    assert "e.g. --columns input=" not in err  # the fitted records' flag, which would break them
    # a test file in the project's columns refused for another reason is not pointed at the columns
    holed = tmp_path / "holed.csv"
    holed.write_text(
        est.read_text().replace("\n", "\nnan,nan,nan\n", 1).replace("nan,nan,nan", "0.0,0.1,", 1)
    )
    code = main([str(a) for a in base + ["--test", holed, "--out", tmp_path / "m.eqx"]])
    err = capsys.readouterr().err
    assert code == 2 and f"--test {holed}: " in err and "--test-columns" not in err, err
    advised = ["--columns", "t=t,input=v_in,output=w", "--test-columns", "time=time,input=u,output=y"]
    code = main([str(a) for a in base + advised + ["--test", val, "--out", tmp_path / "m.eqx"]])
    out, err = capsys.readouterr()
    assert code == 0 and "val.csv (u -> y): RMSE" in out and (tmp_path / "m.eqx").exists(), out

    # fitted records mapped: the names the test file lacks are given in --test-columns, all at once (a
    # probe's took three runs, one role each), not in --input or --time
    mapped = ["fit", val, "--columns", "time=time,input=u,output=y"] + base[2:]
    code = main([str(a) for a in mapped + ["--test", est, "--out", tmp_path / "n.eqx"]])
    err = capsys.readouterr().err
    assert code == 2 and "e.g. --test-columns time=t,input=v_in,output=w" in err and "--time t" not in err, (
        err
    )

    # the advice followed where the test file has a units row (the fitted file, mapped by its own names,
    # is read in mm as unmapped, not in a.u.) or no time column (read at the fitted record's rate)
    units = tmp_path / "units.csv"
    units.write_text("time,u,y\ns,V,mm\n" + "".join(f"{a:.6f},{p:.6f},{q:.6f}\n" for a, p, q in zip(t, u, y)))
    untimed = tmp_path / "untimed.csv"
    untimed.write_text("u,y\n" + "".join(f"{p:.6f},{q:.6f}\n" for p, q in zip(u, y)))
    for test, columns in ((units, "time=time,input=u,output=y"), (untimed, "input=u,output=y")):
        advised = ["--columns", "t=t,input=v_in,output=w", "--test-columns", columns]
        code = main([str(a) for a in base + advised + ["--test", test, "--out", tmp_path / "m.eqx"]])
        out, err = capsys.readouterr()
        assert code == 0 and f"{test.name} (u -> y): RMSE" in out and " mm " in out, err
        if test is untimed:
            assert "no time column ('t' is the estimation record's): read at 30 Hz" in err
