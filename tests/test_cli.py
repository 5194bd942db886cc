"""The `hybrid` command line: outputs against independent references, and one-line errors."""

import csv
import json
import subprocess
import sys
from pathlib import Path

import helpers as h
import numpy as np
import pytest
from scipy import signal

from hybrid import Recording
from hybrid.cli import main


def run(argv, capsys):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line_error(code, err, phrase):
    assert code == 2
    # a heartbeat ("hybrid fit: still working: ...") is progress on a busy machine, not part of the error
    lines = [line for line in err.splitlines() if line.strip() and ": still working: " not in line]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    assert phrase in lines[0], lines[0]


@pytest.fixture(scope="module")
def virtual_csv(tmp_path_factory):
    path = tmp_path_factory.mktemp("cli") / "rec.csv"
    assert main(["simulate", "--drive", "prbs", "--duration", "20", "--seed", "3", "--out", str(path)]) == 0
    return path


def test_simulate_writes_a_valid_recording(virtual_csv):
    rec = Recording.load(virtual_csv)
    assert len(rec) == 600 and abs(rec.rate - 30.0) < 1e-9
    assert set(rec.extra) == {"w_true"}
    # The virtual strip moves by millimetres under a ±2 V drive.
    assert 1.0 < np.ptp(rec.w) < 30.0
    assert np.max(np.abs(rec.v_in)) <= 3.0 + 1e-12


def test_rc_matches_independent_implementation(virtual_csv, tmp_path, capsys):
    params = dict(xi_rho=17.0, xi_h=1.3, alpha_E=0.7, alpha_I=0.4, alpha_C=0.55, C_clamp=0.012)
    out = tmp_path / "vo.csv"
    argv = ["rc", virtual_csv, "--out", out] + [f"--param={k}={v}" for k, v in params.items()]
    code, _, err = run(argv, capsys)
    assert code == 0, err
    with out.open() as handle:
        rows = list(csv.reader(handle))
    assert rows[0] == ["t", "v_in", "v_o"]
    data = np.array(rows[1:], float)
    # Independent reference: Eqs 4–13 in numpy (tests/helpers.py), each section
    # mapped by scipy's bilinear_zpk, filtered by sosfilt.
    G, Z, P = h.stage_zpk_np(**params, n_stages=45)
    dt = 1 / 30
    sos = []
    for g, z, p in zip(G, Z, P):
        zd, pd, kd = signal.bilinear_zpk([-z], [-p], g, fs=1 / dt)
        sos.append(signal.zpk2sos(zd, pd, kd)[0])
    expected = signal.sosfilt(np.array(sos), data[:, 1])
    # Issue 2: `hybrid rc` agrees with an independent implementation to ≤ 1e-9 relative.
    assert np.max(np.abs(data[:, 2] - expected)) <= 1e-9 * np.max(np.abs(expected))


@pytest.mark.filterwarnings("error::DeprecationWarning")  # the CLI uses the library's current spelling
def test_fit_physics_end_to_end(virtual_csv, tmp_path, capsys):
    model_path = tmp_path / "m.eqx"
    report = tmp_path / "fit.json"
    code, out, err = run(
        [
            "fit",
            virtual_csv,
            "--model",
            "physics",
            "--max-steps",
            "30",
            "--quiet",
            "--out",
            model_path,
            "--json",
            report,
        ],
        capsys,
    )
    assert code == 0, err
    assert "test" in out and "gain" in out
    assert model_path.exists() and Path(f"{model_path}.json").exists() and report.exists()


def test_fit_nan_recording_exits_2_with_one_line(virtual_csv, tmp_path, capsys):
    rows = virtual_csv.read_text().splitlines()
    fields = rows[40].split(",")
    fields[2] = "nan"
    rows[40] = ",".join(fields)
    bad = tmp_path / "nan.csv"
    bad.write_text("\n".join(rows) + "\n")
    code, _, err = run(["fit", bad, "--model", "hybrid", "--quiet"], capsys)
    assert_one_line_error(code, err, "non-finite")


@pytest.mark.parametrize(
    "argv, phrase",
    [
        (["simulate", "--drive", "square", "--duration", "5", "--out", "x.csv"], "invalid choice"),
        (["simulate", "--drive", "sine", "--duration", "-1", "--out", "x.csv"], "duration"),
        (["simulate", "--drive", "sine", "--duration", "5", "--param", "bogus=1", "--out", "x.csv"], "bogus"),
        (["rc", "missing.csv", "--out", "y.csv"], "does not exist"),
        (["fit", "missing.csv"], "missing.csv"),
        # a flag that maps the file (a probe's --units) told a wrong path "no input column is named"
        (["diagnose", "missing.csv", "--units", "v_in=N,w=mm", "--out", "d"], "'missing.csv' does not exist"),
        (["fit", "missing.csv", "--range", "10:100"], "'missing.csv' does not exist"),
        (["fit", "REC", "--split", "0.5,0.5"], "three fractions"),
        (["fit", "REC", "--freeze", "nonsense", "--quiet"], "nonsense"),
        (["rc", "REC", "--param", "xi_rho", "--out", "y.csv"], "NAME=VALUE"),
        (["rc", "REC", "--param", "alpha_E=1.5", "--out", "y.csv"], "alpha_E"),
        (["fit", "REC", "--window", "5000", "--quiet"], "window"),
        ([], "required"),
    ],
)
def test_bad_input_exits_2_with_one_line(argv, phrase, virtual_csv, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    argv = [str(virtual_csv) if a == "REC" else a for a in argv]
    code, _, err = run(argv, capsys)
    assert_one_line_error(code, err, phrase)


def test_fit_refuses_one_recording_given_twice(virtual_csv, tmp_path, capsys, monkeypatch):
    """The same samples twice would weigh double and sit in both the training and the validation part."""
    monkeypatch.chdir(virtual_csv.parent)
    out = tmp_path / "m.eqx"
    code, _, err = run(["fit", virtual_csv, virtual_csv.name, "--physics", "lti:1", "--out", out], capsys)
    assert_one_line_error(code, err, "is given twice")
    assert not out.exists()


def test_rc_rejects_drive_without_columns(tmp_path, capsys):
    drive = tmp_path / "d.csv"
    drive.write_text("time,volts\n0,1\n0.1,1\n")
    code, _, err = run(["rc", drive, "--out", tmp_path / "o.csv"], capsys)
    assert_one_line_error(code, err, "v_in")


def test_console_script_reports_errors_without_traceback(tmp_path):
    # The installed entry point, as a user runs it.
    exe = Path(sys.executable).with_name("hybrid")
    proc = subprocess.run([str(exe), "fit", str(tmp_path / "nope.csv")], capture_output=True, text=True)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1


def test_fit_refuses_an_unknown_free_name(virtual_csv, tmp_path, capsys):
    """`--free nope` used to be ignored (the fit ran with ξh frozen and said nothing)."""
    code, _, err = run(
        ["fit", virtual_csv, "--model", "physics", "--free", "nope", "--out", tmp_path / "m.eqx"], capsys
    )
    assert_one_line_error(code, err, "--free: unknown parameter name(s) ['nope']")
    assert not (tmp_path / "m.eqx").exists()


@pytest.mark.parametrize("factor", [1e300, 1e-100])
def test_diagnose_refuses_w_in_an_absurd_unit_before_fitting(virtual_csv, tmp_path, capsys, factor):
    """diagnose fits in the recording's units: w × 1e300 ended in an OverflowError traceback after the search."""
    rec = Recording.load(virtual_csv)
    path = tmp_path / "scaled.csv"
    Recording(t=rec.t, v_in=rec.v_in, w=rec.w * factor, metadata={}, name="scaled").save(path)
    code, _, err = run(["diagnose", path, "--out", tmp_path / "d", "--quiet"], capsys)
    assert_one_line_error(code, err, "w has a standard deviation of")
    assert "rescale w" in err


def test_fit_refuses_a_training_part_at_rest_and_fits_it_in_blocks(tmp_path):
    """A record that rests for its first 35 % (a lab's quiet baseline) gave the contiguous split a
    training part with nothing to learn from: the fit stopped at its start, warning of a plateau.
    The real command refuses it in one line naming `--blocks`, and fits the same file with it
    (first-order lag, tau = 0.5 s, gain 2, made here in numpy)."""
    rng = np.random.default_rng(0)
    n, rate = 3000, 50.0
    u = np.repeat(rng.uniform(-1, 1, n // 40 + 1), 40)[:n]
    u[: int(0.35 * n)] = 0.0
    y = h.zoh_lag(u, 1.0 / rate, 0.5)
    path = tmp_path / "quiet_start.csv"
    np.savetxt(
        path,
        np.c_[np.arange(n) / rate, u, 2 * y + 0.01 * rng.standard_normal(n)],
        delimiter=",",
        header="t,v_in,w",
        comments="",
        fmt="%.6f",
    )
    exe = Path(sys.executable).with_name("hybrid")
    argv = [str(exe), "fit", str(path), "--physics", "lti:1", "--model", "physics", "--quiet"]
    out = tmp_path / "m.eqx"
    proc = subprocess.run([*argv, "--out", str(out)], capture_output=True, text=True)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and "at rest in the training part" in proc.stderr
    assert "--blocks 5" in proc.stderr and not out.exists()
    report = tmp_path / "fit.json"
    proc = subprocess.run(
        [*argv, "--blocks", "5", "--out", str(out), "--json", str(report)], capture_output=True, text=True
    )
    assert proc.returncode == 0, proc.stderr
    fitted = json.loads(report.read_text())["parameters"]
    assert fitted["tau_1"] == pytest.approx(0.5, rel=0.03) and fitted["gain"] == pytest.approx(2.0, rel=0.03)


def test_a_lone_causes_incremental_gain_says_what_it_is_over():
    """A probe read "gain 33.75x" and "hysteresis (incremental gain 17.04x)" side by side, unexplained."""
    from hybrid.cli import cause_line

    step = {"name": "saturation", "incremental_gain": 17.04}
    assert cause_line(step, 1, 33.75) == (
        "  saturation (incremental gain 17.04x: over the best effect-free fit the search found; "
        "the gain above is over the baseline)"
    )
    assert (
        cause_line(step, 1, 17.5) == "  saturation (incremental gain 17.04x)"
    )  # the same gain: nothing to say
    assert (
        cause_line(step, 2, 33.75) == "  saturation (incremental gain 17.04x)"
    )  # each of several: its own step's
    pair = {**step, "named_jointly_with": "delay"}
    assert cause_line(pair, 1, 33.75) == "  saturation (gain over delay alone 17.04x)"
    # where it acts, beside its name (report.json's causes[].place; a probe found it only in effects[])
    inside = {"name": "friction_speed", "incremental_gain": 37.41, "place": "inside"}
    assert cause_line(inside, 1, 37.5) == "  friction_speed, inside the dynamics (incremental gain 37.41x)"


def test_a_reader_that_leaves_early_costs_no_files_and_no_error(tmp_path):
    """``hybrid ... | head -2``: Python ignores SIGPIPE, so the next print raised BrokenPipeError and the
    command ended "hybrid: error: BrokenPipeError" without its files (a probe). The reader here leaves
    before the command prints anything; the command finishes, writes its files and exits 0."""
    u = h.step_drive(300, seed=3, low=4, high=30)
    path = tmp_path / "lab.csv"
    path.write_text("u,y\n" + "".join(f"{a:.9g},{0.5 * a:.9g}\n" for a in u))
    out, err = tmp_path / "sens", tmp_path / "err.txt"
    argv = ["sensitivity", path, "--columns", "input=u,output=y", "--rate", 2, "--physics", "lti:1"]
    with open(err, "w") as stderr:
        proc = subprocess.Popen(
            [sys.executable, "-m", "hybrid.cli", *map(str, argv), "--out", str(out)],
            stdout=subprocess.PIPE,
            stderr=stderr,
            cwd=Path(__file__).resolve().parents[1],
        )
        proc.stdout.close()  # the reader leaves
        code = proc.wait(timeout=300)
    said = err.read_text()
    assert code == 0 and "BrokenPipe" not in said and "Exception ignored" not in said, said
    assert json.loads((out / "sensitivity.json").read_text())["names"] == ["tau_1", "direct"]


@pytest.mark.parametrize(
    "option, value", [("--bounds", "-5:0"), ("--output-bounds", "-1:45"), ("--bounds", "-1e1:0")]
)
def test_a_range_that_starts_below_zero_is_a_value_not_an_option(option, value, tmp_path, capsys):
    """A probe's `hybrid design D --bounds -5:0` ended in "argument --bounds: expected one argument":
    argparse reads a token that starts with "-" as an option unless it is a plain negative number. The
    range is read, and the command goes on to the next thing it checks (here: no diagnosis there)."""

    def design(text):
        drive = [] if option == "--bounds" else ["--amplitude", "5"]
        return main(
            ["design", str(tmp_path / "none"), "--duration", "10", *drive, option, text, "--out", "d.csv"]
        )

    assert design(value) == 2
    err = capsys.readouterr().err
    assert "expected one argument" not in err and "no report.json" in err, err
    # a range the wrong way round is still refused by its own check, negative or not
    low, high = value.split(":")
    assert design(f"{high}:{low}") == 2
    assert "LOW must be below HIGH" in capsys.readouterr().err


def test_recordings_that_name_their_columns_differently_are_told_so(tmp_path, capsys):
    """A probe's two recordings of one motor, the second's output named `speed`: each file's advice
    (`--output speed`, then `--output w`) broke the other, and nothing said one mapping reads both."""
    t = np.arange(300) / 30.0
    for name, output in (("a.csv", "w"), ("b.csv", "speed")):
        np.savetxt(tmp_path / name, np.c_[t, np.sin(t), np.cos(t)], delimiter=",", header=f"t,v_in,{output}",
                   comments="")  # fmt: skip
    for mapping in ([], ["--input", "v_in", "--output", "speed"]):
        args = [
            "fit",
            str(tmp_path / "a.csv"),
            str(tmp_path / "b.csv"),
            *mapping,
            "--out",
            str(tmp_path / "m.eqx"),
        ]
        assert main(args) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "the recordings name their columns differently" in err, err
        assert "'t', 'v_in', 'speed'" in err or "t, v_in, speed" in err
    assert not (tmp_path / "m.eqx").exists()


def test_what_reading_a_recording_did_is_said_once(tmp_path, capsys):
    """A verifier's `hybrid fit` of jittered times printed "t rebuilt as a uniform grid" twice: as the file
    was read (stderr) and again among the fit's warnings (stdout). Said once; the fit's JSON keeps it."""
    rng = np.random.default_rng(2)
    t = (np.arange(600) + rng.uniform(-0.2, 0.2, 600)) / 30.0
    v = np.repeat(rng.uniform(-1, 1, 30), 20)
    w = signal.lsim(signal.lti([1.0], [0.5, 1.0]), v, np.arange(600) / 30.0)[1]
    np.savetxt(tmp_path / "j.csv", np.c_[t, v, w], delimiter=",", header="t,v_in,w", comments="")
    args = ["fit", str(tmp_path / "j.csv"), "--physics", "lti:1", "--model", "physics", "--max-steps", "3"]
    assert main([*args, "--quiet", "--json", str(tmp_path / "f.json"), "--out", str(tmp_path / "m.eqx")]) == 0
    out, err = capsys.readouterr()
    assert (out + err).count("t rebuilt as a uniform grid") == 1, out + err
    assert any("t rebuilt" in w for w in json.loads((tmp_path / "f.json").read_text())["warnings"])


def _two_lag_plant(path, seed: int) -> None:
    """50 s at 30 Hz: random levels of ±2 V held 0.3–3 s into 1.5/((0.4 s + 1)(0.08 s + 1)) (scipy), noise
    1 % of the range; the output in mm."""
    rng = np.random.default_rng(seed)
    t = np.arange(1500) / 30.0
    v = h.held_levels(rng, t, -2.0, 2.0, 0.3, 3.0, count=200)
    _, x, _ = signal.lsim(signal.lti([1.5], np.polymul([0.4, 1.0], [0.08, 1.0])), v, t, interp=False)
    w = x + 0.01 * np.ptp(x) * rng.normal(size=t.size)
    np.savetxt(path, np.c_[t, v, w], delimiter=",", header="t,v_in,w\ns,V,mm", comments="")


def test_the_default_hybrid_fit_says_when_the_physics_alone_fits_the_held_out_parts_better(tmp_path):
    """A second-order plant, 1,500 samples (validation NMSE 1.4e-1 from the hybrid, 2.0e-3 from the physics
    alone; pytest -s prints them): the D-MLP's 1,721 weights fit the training part and miss the held-out ones,
    and the fit said nothing."""
    _two_lag_plant(tmp_path / "rec.csv", seed=0)
    run = h.run_hybrid(tmp_path, "fit", "rec.csv", "--physics", "lti:2", "--json", "fit.json", "--quiet")
    assert run.returncode == 0, run.stderr[-2000:]
    said = json.loads((tmp_path / "fit.json").read_text())
    alone = said["physics_alone"]
    assert [line for line in run.stderr.splitlines() if "physics model alone" in line] == [
        f"hybrid: warning: {alone['sentence']}"
    ]
    print(alone["sentence"])  # the numbers docs/command-line.md quotes (pytest -s)
    assert "--model physics" in alone["sentence"] and "1721 weights" in alone["sentence"]  # n_weights
    for split in ("validation", "test"):  # the hybrid's own held-out scores, and the physics' 1.5× below
        assert alone["nmse"][split]["hybrid"] == said["metrics"][split]["nmse"]
        assert alone["nmse"][split]["physics"] * 1.5 <= alone["nmse"][split]["hybrid"]
    assert (tmp_path / "rec.hybrid.eqx").is_file()  # the model asked for is saved all the same


def test_the_physics_alone_is_pointed_at_only_where_it_fits_every_held_out_split_better():
    from hybrid.cli import PEER_HINT_GAIN, physics_alone_hint

    def metrics(validation, test):
        return {"train": {"nmse": 1e-3}, "validation": {"nmse": validation}, "test": {"nmse": test}}

    hint = physics_alone_hint(metrics(4e-3, 5e-3), metrics(4e-4, 1e-3), 1725)
    assert hint["ratio"] == pytest.approx(5.0) and "5× better" in hint["sentence"]
    assert physics_alone_hint(metrics(4e-3, 5e-3), metrics(4e-4, 5e-3 / PEER_HINT_GAIN * 1.01), 1725) is None
    assert (
        physics_alone_hint(metrics(1e-3, 1e-3), metrics(2e-3, 1e-3), 1725) is None
    )  # the hybrid fits better
    assert physics_alone_hint(metrics(4e-3, 5e-3), metrics(0.0, 1e-3), 1725) is None  # a ratio it cannot read
    assert physics_alone_hint({"train": {"nmse": 1.0}}, metrics(4e-4, 1e-3), 1725) is None  # no held-out part
    assert physics_alone_hint(metrics(float("nan"), 5e-3), metrics(4e-4, 1e-3), 1725) is None  # not "nan×"
