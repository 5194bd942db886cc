"""`hybrid diagnose`: report.json is strict JSON, the figures are PNGs, report.md says what was found.

One diagnose run (a synthetic strip with a hidden drift, through the CLI in
process) feeds every test of the report; the error and JSON tests fit nothing.
"""

import contextlib
import io
import json
import math

import numpy as np
import pytest

from hybrid._diagnose import CAUSES, DiagnoseSettings
from hybrid._diagnose_report import FIGURES, _correlations, _jsonable, _nmse
from hybrid._effects import EFFECTS
from hybrid._residual_tests import confidence_bound
from hybrid._synthetic import discrepancy_drive, random_effect, random_strip, synthetic_recording
from hybrid.cli import main

MAX_STEPS = DiagnoseSettings().max_steps
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    """Run `hybrid diagnose` once on a strip with a hidden drift."""
    tmp_path = tmp_path_factory.mktemp("diagnose")
    # The same draw as tests/test_diagnose.py's drift case (60 s at 30 Hz): the
    # search compiled there is reused here.
    rng = np.random.default_rng([0, len("drift"), sum(map(ord, "drift"))])
    strip = random_strip(rng)
    params = random_effect("drift", rng, 30.0)
    rec = synthetic_recording(discrepancy_drive(60.0, 30.0, 0), strip, "drift", params, noise_fraction=0.01, seed=0)
    path = rec.save(tmp_path / "rec.csv")
    out = tmp_path / "report"
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        # The default step limit, given explicitly: the option is exercised and the
        # LM program compiled for tests/test_diagnose.py (max_steps is static) is reused.
        code = main(["diagnose", str(path), "--out", str(out), "--max-steps", str(MAX_STEPS), "--quiet"])
    return {"code": code, "out": out, "path": path, "stdout": stdout.getvalue()}


def test_diagnose_exits_zero_and_writes_every_file(report):
    assert report["code"] == 0
    for name in ("report.json", "report.md") + FIGURES:
        assert (report["out"] / name).is_file(), name
    assert not [p for p in report["out"].iterdir() if p.name.endswith(".tmp")]


def test_summary_names_cause_nmse_parameters_and_report(report):
    data = json.loads((report["out"] / "report.json").read_text())
    lines = report["stdout"].splitlines()
    assert lines[0] == f"cause: {data['cause']}"
    assert f"baseline {data['baseline']['nmse']:.2e} -> extended {data['extended']['nmse']:.2e}" in lines[1]
    if data["cause"] != "none":
        for name in EFFECTS[data["cause"]].constraints:
            assert any(line.strip().startswith(f"{name} = ") and "±" in line for line in lines), name
    assert str(report["out"] / "report.md") in lines[-1]


def test_report_json_is_strict_and_consistent(report):
    text = (report["out"] / "report.json").read_text()
    data = json.loads(text, parse_constant=lambda c: pytest.fail(f"non-standard JSON constant {c}"))
    assert data["cause"] in CAUSES
    assert data["settings"]["max_steps"] == MAX_STEPS  # --max-steps reaches DiagnoseSettings
    assert data["recordings"] == [str(report["path"])]
    for key in ("baseline", "extended"):
        assert math.isfinite(data[key]["nmse"]) and data[key]["nmse"] > 0
        assert math.isfinite(data[key]["fitting"])
    assert data["gain"] == pytest.approx(data["baseline"]["nmse"] / data["extended"]["nmse"], rel=1e-9)
    names = [c["name"] for c in data["candidates"]]
    assert sorted(names) == sorted(EFFECTS) and len(names) == len(EFFECTS)
    for c in data["candidates"]:
        assert {"name", "heldout_nmse", "criterion", "parameters"} <= set(c)
        assert "delta_bic" in c["criterion"]
    if data["cause"] != "none":
        effect_names = set(EFFECTS[data["cause"]].constraints)
        assert effect_names <= set(data["parameters"])
    for entry in data["parameters"].values():
        assert {"value", "std_error", "unit"} <= set(entry)


def test_figures_are_png_images(report):
    import matplotlib.image

    for name in FIGURES:
        path = report["out"] / name
        assert path.read_bytes()[:8] == PNG_MAGIC, name
        image = matplotlib.image.imread(path)
        assert image.ndim == 3 and image.shape[1] > 400 and image.shape[0] > 200, (name, image.shape)


def test_report_md_names_cause_figures_and_nmse(report):
    data = json.loads((report["out"] / "report.json").read_text())
    text = (report["out"] / "report.md").read_text()
    assert text.startswith("# Diagnosis of ")
    assert "rec.csv" in text.splitlines()[0]
    assert data["cause"] in text
    if data["cause"] == "none":
        assert "none: the simulation is right within the measurement noise" in text
    for name in FIGURES:
        assert f"]({name})" in text, name
    assert _nmse(data["baseline"]["nmse"]) in text
    assert _nmse(data["extended"]["nmse"]) in text
    for c in data["candidates"]:
        assert c["name"] in text


# --------------------------------------------------------------------------- #
# No fitting below
# --------------------------------------------------------------------------- #


def _one_line_error(code, err):
    assert code == 2
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("hybrid: error:"), lines[0]


def test_missing_recording_is_one_line_error(tmp_path, capsys):
    code = main(["diagnose", str(tmp_path / "missing.csv"), "--out", str(tmp_path / "d")])
    _one_line_error(code, capsys.readouterr().err)
    assert not (tmp_path / "d").exists()


def test_recording_with_nan_is_one_line_error(tmp_path, capsys):
    path = tmp_path / "nan.csv"
    rows = ["t,v_in,w"] + [f"{i / 30:.6f},{np.sin(i / 5):.6f},{'nan' if i == 40 else f'{np.cos(i / 5):.6f}'}"
                           for i in range(200)]
    path.write_text("\n".join(rows) + "\n")
    code = main(["diagnose", str(path), "--out", str(tmp_path / "d")])
    _one_line_error(code, capsys.readouterr().err)


def test_max_steps_below_one_is_one_line_error(tmp_path, capsys):
    path = tmp_path / "ok.csv"
    rows = ["t,v_in,w"] + [f"{i / 30:.6f},{np.sin(i / 5):.6f},{np.cos(i / 5):.6f}" for i in range(200)]
    path.write_text("\n".join(rows) + "\n")
    code = main(["diagnose", str(path), "--out", str(tmp_path / "d"), "--max-steps", "0"])
    _one_line_error(code, capsys.readouterr().err)


def test_jsonable_writes_nan_as_null_and_converts_numpy():
    value = {"a": float("nan"), "b": np.float64(1.5), "c": np.array([1.0, np.inf, 2.0]), "d": [np.int64(3), -np.inf],
             "e": np.bool_(True), "f": {"g": np.float32(0.25), "h": None, "i": "x"}}
    text = json.dumps(_jsonable(value), allow_nan=False)
    assert json.loads(text) == {"a": None, "b": 1.5, "c": [1.0, None, 2.0], "d": [3, None], "e": True,
                                "f": {"g": 0.25, "h": None, "i": "x"}}


def test_correlation_figure_bound_is_the_99_percent_bound():
    rng = np.random.default_rng(0)
    e, v = rng.normal(size=777), rng.normal(size=777)
    c = _correlations(e, v)
    assert c["bound"] == confidence_bound(777)
    assert c["bound"] == pytest.approx(2.5758293035489 / math.sqrt(777), rel=1e-12)
    assert c["acf_lags"][0] == 1 and c["acf_lags"][-1] == 50 and len(c["acf"]) == 50
    assert c["ccf_lags"][0] == -50 and c["ccf_lags"][-1] == 50
