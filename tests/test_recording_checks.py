"""Recordings that used to be answered wrong in silence, or refused with a message pointing the
wrong way (issue 20): a constant drive, t in milliseconds, camera timestamps with jitter, a gap,
';' / tab / space delimiters and decimal commas, MATLAB v7.3 files (read with h5py), diagnose's early checks, and
the null space of a sensitivity matrix with fewer rows than parameters.

Nothing here fits a model: every check runs before any compilation, so each test takes well
under a second.
"""

import json

import numpy as np
import pytest
import scipy.linalg
import scipy.signal

from hybrid import InputError, Recording, diagnose, fit, load_mapped, make_model, sensitivity as S
from hybrid.cli import main
from hybrid.data._recording_checks import JITTER_FRAMES, MS_STEP_S
from hybrid.physics._rc_network import RCNetwork

RATE = 30.0


def _signals(n, seed=0):
    rng = np.random.default_rng(seed)
    return np.sign(np.sin(np.arange(n) / 17.0)) * 2.0, rng.normal(size=n)


def _write_csv(path, t, v, w, delimiter=",", decimal="."):
    lines = [delimiter.join(("t", "v_in", "w"))]
    for row in zip(t, v, w):
        lines.append(delimiter.join(repr(float(x)).replace(".", decimal) for x in row))
    path.write_text("\n".join(lines) + "\n")
    return path


def _cli_error(argv, capsys):
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2, err
    assert "Traceback" not in err
    return lines


# ----------------------------------------------------------------- 3. a constant drive


@pytest.mark.parametrize("level", [0.0, 1.5])
def test_constant_drive_is_refused_with_its_likely_cause(level):
    _, w = _signals(300)
    rec = Recording.from_arrays(v_in=np.full(300, level), w=w, rate=RATE, name="run")
    with pytest.raises(
        InputError, match="the drive column v_in is constant .*right column, or was the drive off"
    ):
        rec.check_signals()
    # and fit refuses it before any fitting, instead of printing its start values as fitted
    with pytest.raises(InputError, match="v_in is constant"):
        fit(make_model("physics"), rec, progress=False)


def test_drive_varying_by_rounding_only_counts_as_constant():
    _, w = _signals(300)
    v = 2.0 + 1e-14 * np.random.default_rng(1).normal(size=300)  # std 5e-15 of its magnitude
    with pytest.raises(InputError, match="v_in is constant"):
        Recording.from_arrays(v_in=v, w=w, rate=RATE).check_signals()
    v, w = _signals(300)
    Recording.from_arrays(v_in=v, w=w, rate=RATE).check_signals()  # a real drive passes


def test_constant_w_is_refused_by_check_signals_too():
    v, _ = _signals(300)
    with pytest.raises(InputError, match="output column w is constant .*a disconnected or saturated sensor"):
        Recording.from_arrays(v_in=v, w=np.zeros(300), rate=RATE).check_signals()


def _turning(n, seed=0):
    """A drive and the angle (rad) of a shaft it turns several times, with an encoder's noise; not wrapped."""
    rng = np.random.default_rng(seed)
    v = np.repeat(rng.uniform(-1.0, 1.0, n // 30), 30)
    angle = scipy.signal.lfilter([0.02], [1.0, -0.98], v) * 40.0
    return v, angle + 0.01 * rng.normal(size=n)


def _pushed_past(angle):
    """An angle near 2.6 rad that two pushes carry past π for a few samples each (its own noise kept)."""
    rest = 2.6 + 0.05 * np.tanh(angle / 40.0)
    push = np.zeros_like(angle)
    for at in (1000, 2000):
        push[at : at + 8] = 0.6 * np.sin(np.linspace(0.0, np.pi, 8))
    return rest + push + 0.005 * np.random.default_rng(3).normal(size=angle.size)


@pytest.mark.parametrize(
    "wrap, turn, unwrap",
    [
        (lambda a: np.angle(np.exp(1j * a)), "(2π)", "numpy.unwrap(w)"),  # atan2's ±π
        (lambda a: np.mod(a, 2 * np.pi), "(2π)", "numpy.unwrap(w)"),  # 0 to 2π
        (lambda a: np.degrees(np.angle(np.exp(1j * a))), "(360)", "period=360"),  # an encoder's ±180°
        # an angle that swings about its turn's end and wraps back and forth (a probe's, read as glitches)
        (lambda a: np.angle(np.exp(1j * (np.pi + 0.3 * np.sin(a / 4)))), "(2π)", "numpy.unwrap(w)"),
        # a shaft resting short of the wrap point, pushed past it for a few samples twice (a verifier's:
        # 13 samples of 3200, its values spanning little of the turn)
        (lambda a: np.angle(np.exp(1j * _pushed_past(a))), "(2π)", "numpy.unwrap(w)"),
    ],
    ids=["atan2", "mod", "degrees", "about_the_end", "crossing_briefly"],
)
def test_an_angle_that_wraps_around_is_refused_with_how_to_unwrap_it(wrap, turn, unwrap):
    # A wrapped angle read "static and odd in the drive" with its wraps bridged as glitches (a probe's):
    # each jump of a whole turn is read as the plant's response unless it is unwrapped first.
    v, angle = _turning(3000)
    with pytest.raises(InputError, match="an angle that wraps around") as caught:
        Recording.from_arrays(v_in=v, w=wrap(angle), rate=RATE).check_signals()
    assert turn in str(caught.value) and unwrap in str(caught.value)
    # unwrapped it passes, as do signals of a similar range that do not wrap
    Recording.from_arrays(v_in=v, w=np.unwrap(wrap(angle)), rate=RATE).check_signals()
    rng = np.random.default_rng(1)
    for w in (
        angle,  # the angle itself, nine turns
        np.where(v > 0, 2.5, -2.5) + 0.01 * rng.normal(size=v.size),  # a relay's output, steps < a turn apart
        0.5 * np.sin(angle / 10) + 0.01 * rng.normal(size=v.size),  # a small swing
        np.clip(angle, -np.pi, np.pi),  # a signal within ±π that steps nowhere by more than half a turn
    ):
        Recording.from_arrays(v_in=v, w=w, rate=RATE).check_signals()


def test_cli_diagnose_refuses_a_wrapped_angle_in_one_line(tmp_path, capsys):
    v, angle = _turning(3000)
    path = _write_csv(tmp_path / "encoder.csv", np.arange(3000) / RATE, v, np.angle(np.exp(1j * angle)))
    lines = _cli_error(["diagnose", path, "--physics", "lti:2", "--out", tmp_path / "d"], capsys)
    assert len(lines) == 1 and "wraps around" in lines[0] and "numpy.unwrap(w)" in lines[0]
    assert not (tmp_path / "d").exists()
    # a file whose own name for the angle is another: the line names that column (a verifier's npz said "w")
    other = tmp_path / "shaft.csv"
    other.write_text(path.read_text().replace("t,v_in,w", "time,volts,angle", 1))
    argv = [
        "diagnose",
        other,
        "--columns",
        "input=volts,output=angle",
        "--time",
        "time",
        "--physics",
        "lti:2",
    ]
    lines = _cli_error([*argv, "--out", tmp_path / "d"], capsys)
    assert len(lines) == 1 and "w (the file's column 'angle') jumps by a whole turn" in lines[0], lines


def test_loading_a_rest_recording_still_works(tmp_path):
    # Loading does not refuse a constant column (an interrupted or rest recording is still data)
    path = _write_csv(tmp_path / "rest.csv", np.arange(10) / RATE, np.zeros(10), np.zeros(10))
    assert len(Recording.load(path)) == 10


def test_cli_fit_refuses_a_constant_drive_in_one_line(tmp_path, capsys):
    t = np.arange(300) / RATE
    _, w = _signals(300)
    path = _write_csv(tmp_path / "off.csv", t, np.zeros(300), w)
    lines = _cli_error(["fit", path, "--model", "physics", "--quiet"], capsys)
    assert len(lines) == 1 and "v_in is constant" in lines[0] and "was the drive off" in lines[0]


@pytest.mark.parametrize("column", ["v_in", "w"])
def test_one_corrupt_cell_is_named_not_fitted(tmp_path, capsys, column):
    """A 1e300 cell among millimetres would set the fit's scale (every other sample reads 0): named instead."""
    v, w = _signals(300)
    signals = {"v_in": v.copy(), "w": w.copy()}
    signals[column][123] = 1e300
    rec = Recording.from_arrays(**signals, rate=RATE, name="run")
    with pytest.raises(InputError, match=f"{column} at sample 123 .* is 1e\\+300, .*corrupt cell"):
        rec.check_signals()
    path = _write_csv(tmp_path / "cell.csv", np.arange(300) / RATE, signals["v_in"], signals["w"])
    for physics in ("rc", "lti:1"):  # lti:N centres its time scales on the data first: checked before that
        lines = _cli_error(["fit", path, "--model", "physics", "--physics", physics, "--quiet"], capsys)
        assert len(lines) == 1 and "at sample 123" in lines[0], lines
    # what is not corrupt passes: a whole column in other units, a pulse drive mostly at rest, heavy tails
    Recording.from_arrays(v_in=v, w=1e300 * w, rate=RATE).check_signals()
    pulses = np.zeros(300)
    pulses[100:110] = 2.0
    pulses[200:203] = -1.5
    Recording.from_arrays(v_in=pulses, w=w, rate=RATE).check_signals()
    tails = np.random.default_rng(2).standard_cauchy(300)  # its largest is ~10⁴ typical deviations
    Recording.from_arrays(v_in=v, w=tails, rate=RATE).check_signals()


# ----------------------------------------------------------------- 4. t in milliseconds


def test_t_in_milliseconds_is_refused():
    v, w = _signals(300)
    t_ms = np.arange(300) * 1000.0 / RATE  # a 30 fps log written in ms: steps of 33.3
    with pytest.raises(
        InputError, match=r"t stepping by 33.33: t looks like milliseconds \(30 Hz if so.*t/1000"
    ):
        Recording(t_ms, v, w)


def test_slow_recordings_in_seconds_are_accepted():
    v, w = _signals(300)
    assert Recording(np.arange(300) * 1.0, v, w).rate == 1.0  # a 1 Hz benchmark: dt = 1 s
    assert Recording(np.arange(300) * 5.0, v, w).rate == 0.2  # below MS_STEP_S
    slow = np.arange(300) * MS_STEP_S * 2
    with pytest.raises(InputError, match="milliseconds"):
        Recording(slow, v, w)
    # declared: a recording really sampled every 20 s
    assert Recording(slow, v, w, metadata={"units": {"t": "s"}}).rate == pytest.approx(0.05)


def test_a_slow_csv_is_told_the_flag_that_declares_seconds_and_keeps_its_units(tmp_path, capsys):
    """A 0.1 Hz thermal record in the project's columns: the refusal said 'declare metadata units
    {"t": "s"}', which no flag names; and --units t=s, which reads it, relabelled w from mm to a.u."""
    v, w = _signals(300)
    path = _write_csv(tmp_path / "slow.csv", np.arange(300) * 10.0, v, w)
    lines = _cli_error(["fit", path, "--model", "physics", "--quiet"], capsys)
    assert len(lines) == 1 and "--units t=s on the command line" in lines[0], lines
    record = load_mapped(path, units={"t": "s"})
    assert record.rate == pytest.approx(0.1) and record.metadata["units"] == {
        "t": "s",
        "v_in": "V",
        "w": "mm",
    }
    assert Recording.load(path, units={"t": "s"}).metadata["units"]["w"] == "mm"


def test_t_in_milliseconds_in_a_csv_file(tmp_path, capsys):
    v, w = _signals(300)
    path = _write_csv(tmp_path / "ms.csv", np.arange(300) * 1000.0 / RATE, v, w)
    lines = _cli_error(["fit", path, "--model", "physics", "--quiet"], capsys)
    assert len(lines) == 1 and "looks like milliseconds" in lines[0]


# ----------------------------------------------------------------- 5. timestamp jitter, gaps


def _camera_log(n=3000, seed=0, jitter_s=0.004):
    """A 30 Hz camera's timestamps: frame k at k/30 s plus jitter, logged in whole milliseconds."""
    rng = np.random.default_rng(seed)
    t = 12.0 + np.arange(n) / RATE + rng.uniform(-jitter_s, jitter_s, n)
    return np.round(t * 1000.0) / 1000.0


def test_millisecond_timestamps_with_jitter_become_a_uniform_grid():
    t = _camera_log()
    v, w = _signals(t.size)
    rec = Recording(t, v, w, name="camera")
    # the rate from the least-squares line (the median step, 33 ms, would be 30.3 Hz)
    assert rec.rate == pytest.approx(RATE, rel=1e-5)
    steps = np.diff(rec.t)
    assert np.max(np.abs(steps - steps.mean())) < 1e-9 * steps.mean()
    assert np.max(np.abs(rec.t - t)) < 0.005  # within the jitter (4 ms) + rounding (0.5 ms)
    base = rec.metadata["time_base"]
    assert base["rebuilt"] and base["rate_hz"] == pytest.approx(RATE, rel=1e-5)
    assert 0.003 < base["jitter_max_s"] < 0.005 and 0.001 < base["jitter_rms_s"] < 0.003
    assert len(rec.notes) == 1 and "t rebuilt as a uniform grid" in rec.notes[0] and "jitter" in rec.notes[0]
    json.dumps(rec.metadata)


def test_rebuilt_time_base_round_trips_and_is_not_noted_again(tmp_path):
    t = _camera_log(600)
    v, w = _signals(t.size)
    path = Recording(t, v, w).save(tmp_path / "cam.csv")
    again = Recording.load(path)
    assert again.notes == () and again.metadata["time_base"]["rebuilt"]
    assert again.rate == pytest.approx(RATE, rel=1e-4)


def test_jitter_limit_and_gaps():
    n = 600
    v, w = _signals(n)
    t = np.arange(n) / RATE
    t_jitter = t.copy()
    t_jitter[100] += 0.2 / RATE  # one timestamp 0.2 frame late: jitter, absorbed
    assert Recording(t_jitter, v, w).metadata["time_base"]["rebuilt"]
    t_bad = t.copy()
    t_bad[100] += (JITTER_FRAMES + 0.05) / RATE  # 0.3 frame late: beyond jitter, not a gap
    with pytest.raises(
        InputError, match=r"non-uniform time: sample 100 \(t = 3.34333 s\) is 0.3 of a step off"
    ):
        Recording(t_bad, v, w)
    t_rate = np.concatenate([t[:300], t[299] + np.arange(1, 301) / 27.0])  # 30 fps, then 27 fps
    with pytest.raises(
        InputError,
        match=r"non-uniform time: the steps first change at sample 300 \(t = 10.0037 s\), 0.037037 s against "
        r"0.0333333 s before \(300 such steps\), and sample 299 \(t = 9.96667 s\) is 7.9 steps off.*"
        r"did the frame rate change",
    ):
        Recording(t_rate, v, w)
    t_double = np.insert(t, 400, t[399] + 0.2 / RATE)  # an extra row 0.2 frame after row 399
    with pytest.raises(InputError, match="non-uniform time: the step into sample 400 is 0.00666667 s"):
        Recording(t_double, np.append(v, 0.0), np.append(w, 0.0))
    t_gap = t.copy()
    t_gap[250:] += 2 / RATE  # two dropped frames before row 250
    with pytest.raises(InputError, match=r"gap in time at sample 250 \(t = 8.4 s\).*3 times the median step"):
        Recording(t_gap, v, w)
    # a clock that slips half a step is no gap of missing frames: not offered --fill-gaps (a verifier
    # followed that advice into "1.5 steps long, no whole number of missing frames")
    t_slip = t.copy()
    t_slip[250:] += 0.5 / RATE
    with pytest.raises(
        InputError, match=r"step in time of 1.5 median steps into sample 250 .*clock slipped"
    ) as e:
        Recording(t_slip, v, w)
    assert "--fill-gaps" not in str(e.value) and "\n" not in str(e.value)


def test_exact_time_bases_are_kept_bit_for_bit():
    t = np.round(np.arange(300) / RATE, 9)  # text rounding, far below TIME_RTOL
    v, w = _signals(300)
    rec = Recording(t, v, w)
    assert np.array_equal(rec.t, t) and "time_base" not in rec.metadata and rec.notes == ()


def test_cli_warns_when_it_rebuilds_the_time_base(tmp_path, capsys):
    # diagnose prints the note first; its constant-w check then ends it before any fitting
    t = _camera_log(600)
    v, _ = _signals(t.size)
    path = _write_csv(tmp_path / "cam.csv", t, v, np.zeros(t.size))
    lines = _cli_error(["diagnose", path, "--out", tmp_path / "out", "--quiet"], capsys)
    assert lines[0].startswith("hybrid: warning:") and "t rebuilt as a uniform grid" in lines[0]
    assert lines[-1].startswith("hybrid: error:") and "w is constant" in lines[-1]


# ----------------------------------------------------------------- 6. messages that pointed the wrong way


@pytest.mark.parametrize(
    "delimiter, decimal, how",
    [(";", ",", "';' with decimal commas"), ("\t", ",", "tabs with decimal commas"), ("\t", ".", "tabs")],
)
def test_a_spreadsheets_semicolons_tabs_and_decimal_commas_are_read(tmp_path, delimiter, decimal, how):
    """Where the comma is the decimal mark, spreadsheets separate cells by ';' (or tabs): read as written."""
    v, w = _signals(20)
    t = np.arange(20) / RATE
    path = _write_csv(tmp_path / "x.csv", t, v, w, delimiter=delimiter, decimal=decimal)
    recording = Recording.load(path)
    np.testing.assert_array_equal(recording.w, w)  # repr() of each value, read back exactly
    np.testing.assert_array_equal(recording.v_in, v)
    assert recording.notes == (f"recording '{path}': read as cells separated by {how}",)
    mapped = Recording.load(path, input="v_in", output="w", time="t")
    np.testing.assert_array_equal(mapped.w, w)


def test_space_separated_csv_is_named(tmp_path):
    v, w = _signals(20)
    path = _write_csv(tmp_path / "x.csv", np.arange(20) / RATE, v, w, delimiter=" ")
    with pytest.raises(
        InputError, match="cells separated by spaces.*comma-separated with '.' decimals.*rename it to .txt"
    ):
        Recording.load(path)


def test_decimal_commas_in_a_comma_file_are_named(tmp_path):
    path = tmp_path / "x.csv"
    path.write_text("t,v_in,w\n0,0,1,5,0,25\n0,033,1,5,0,3\n")
    with pytest.raises(InputError, match="decimal commas"):
        Recording.load(path)


_MAT73_HEADER = (
    b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan  1 00:00:00 2024 HDF5 schema 1.00 ."
)


def _write_mat73(path, variables):
    """A .mat file laid out as MATLAB's save -v7.3 writes it: HDF5 after a 512-byte header, every array
    transposed (column-major), MATLAB_class on each, char as UTF-16 codes, a struct as a group."""
    import h5py

    def put(group, name, value):
        if isinstance(value, dict):
            sub = group.create_group(name)
            sub.attrs["MATLAB_class"] = np.bytes_("struct")
            for key, item in value.items():
                put(sub, key, item)
        elif isinstance(value, str):
            group.create_dataset(name, data=np.array([[ord(c)] for c in value], np.uint16))
            group[name].attrs["MATLAB_class"] = np.bytes_("char")
        else:
            group.create_dataset(name, data=np.atleast_2d(np.asarray(value, float)).T)  # n x 1 -> (1, n)
            group[name].attrs["MATLAB_class"] = np.bytes_("double")

    with h5py.File(path, "w", userblock_size=512) as handle:
        for name, value in variables.items():
            put(handle, name, value)
    with open(path, "r+b") as handle:
        handle.write(_MAT73_HEADER.ljust(116, b" ") + b"\x00" * 8 + b"\x00\x02IM")


def test_a_matlab_v73_file_reads_as_a_v7_one(tmp_path):
    """save -v7.3 (HDF5; any file over 2 GB, and a MATLAB preference): read, metadata and struct fields too."""
    t = np.arange(50) / 10.0
    v, w = _signals(50)
    path = tmp_path / "run.mat"
    _write_mat73(
        path,
        {"t": t[:, None], "v_in": v[:, None], "w": w[None, :], "metadata": '{"strip": {"length_mm": 30}}'},
    )
    rec = Recording.load(path)
    np.testing.assert_array_equal(np.stack([rec.t, rec.v_in, rec.w]), np.stack([t, v, w]))
    assert rec.metadata["strip"] == {"length_mm": 30}
    lab = tmp_path / "lab.mat"
    _write_mat73(lab, {"run": {"data": {"u": v[:, None], "y": w[:, None]}, "Ts": [[0.1]]}})
    mapped = Recording.load(lab, input="run.data.u", output="run.data.y")
    np.testing.assert_array_equal(mapped.w, w)
    assert mapped.rate == pytest.approx(10.0)


def test_a_damaged_matlab_v73_file_says_so(tmp_path):
    data = _MAT73_HEADER.ljust(116, b" ") + b"\x00" * 8 + b"\x00\x02IM"
    data = data.ljust(512, b"\x00") + b"\x89HDF\r\n\x1a\n" + b"\x00" * 200
    path = tmp_path / "run.mat"
    path.write_bytes(data)
    with pytest.raises(InputError, match=r"damaged MATLAB v7.3 \(HDF5\) .mat file .*save it again"):
        Recording.load(path)


def test_diagnose_checks_recordings_before_any_fitting():
    v, w = _signals(40)
    short = Recording.from_arrays(v_in=v, w=w, rate=RATE, name="short")
    with pytest.raises(InputError, match="record at least 60 samples") as error:
        diagnose(short)
    assert "--window" not in str(error.value)  # diagnose has no --window
    # in its own rate's seconds (a probe's 50 Hz file was told "2 s at 30 Hz")
    fifty = Recording.from_arrays(v_in=v, w=w, rate=50.0, name="short")
    with pytest.raises(InputError, match=r"record at least 60 samples \(1.2 s at 50 Hz\)"):
        diagnose(fifty)
    v, _ = _signals(600)
    flat = Recording.from_arrays(v_in=v, w=np.full(600, 0.3), rate=RATE, name="flat")
    with pytest.raises(InputError, match="w is constant"):
        diagnose(flat)  # used to fail only after ~1 min of fitting
    v, w = _signals(600)
    with pytest.raises(InputError, match="v_in is constant"):
        diagnose(Recording.from_arrays(v_in=np.zeros(600), w=w, rate=RATE))


# ----------------------------------------------------------------- 7. null space with fewer rows than parameters


@pytest.mark.parametrize("rows", [1, 2, 4])
def test_identifiability_reports_the_null_space_of_a_wide_matrix(rows):
    names = ("a", "b", "c", "d", "e", "f")
    S_matrix = np.random.default_rng(rows).normal(size=(rows, len(names)))
    ident = S.identifiability(S_matrix, names, keep=0.0)
    reference = scipy.linalg.null_space(S_matrix)  # (6, 6 - rows), orthonormal
    assert len(ident.singular_values) == len(names)
    np.testing.assert_allclose(ident.singular_values[:rows], np.linalg.svd(S_matrix, compute_uv=False))
    assert np.all(ident.singular_values[rows:] == 0)
    assert len(ident.null_directions) == len(names) - rows
    null = np.array([[d[n] for n in names] for d in ident.null_directions]).T
    # the same subspace: projecting either basis on the other keeps it whole
    np.testing.assert_allclose(reference @ (reference.T @ null), null, atol=1e-12)
    np.testing.assert_allclose(np.linalg.svd(reference.T @ null, compute_uv=False), 1.0, atol=1e-12)
    np.testing.assert_allclose(S_matrix @ null, 0.0, atol=1e-12)


def test_sensitivities_of_a_two_sample_drive_have_null_directions():
    sens = S.local_sensitivities(RCNetwork(n_stages=3), np.array([0.0, 1.0]), 1 / RATE)
    ident = sens.identifiability()
    assert len(ident.null_directions) >= len(sens.names) - 2  # at least 4 of 6 (used to be [])


def test_cli_sensitivity_refuses_a_two_row_recording(tmp_path, capsys):
    path = _write_csv(tmp_path / "two.csv", [0.0, 1 / RATE], [0.0, 1.0], [0.0, 0.5])
    lines = _cli_error(["sensitivity", path, "--out", tmp_path / "sens"], capsys)
    assert len(lines) == 1 and "has 2 samples" in lines[0] and "at least 60" in lines[0]
