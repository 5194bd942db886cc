"""A new user's lab files (issue: trial of lab files): each was read wrong in silence, or refused
with a message that pointed the wrong way.

Decimal commas in a comma-separated file, units in the header's names (``Time [ms]``,
``Displacement/µm``), the rate of jittered or rounded timestamps, a logger's footer, a
preamble in a ``.txt``, spaces between cells, the time going back, a dead sensor, and text that
is not UTF-8. Every file is written here with numpy; each is read through the loaders the docs
name (``Recording.load``, ``load_mapped``) and, where the fix is a message, through the command
line (``hybrid.cli.main``), which refuses before any fitting: nothing here compiles a model.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from hybrid import InputError, Recording
from hybrid.cli import main
from hybrid.data._loaders import table_start

RATE = 30.0
N = 300


def _signals(n=N, seed=0):
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.uniform(-1.0, 1.0, n // 10 + 1), 10)[:n]
    y = np.convolve(u, np.exp(-np.arange(20) / 5.0) / 5.0)[:n] + 0.001 * rng.normal(size=n)
    return u, y


def _write(path, header, columns, fmt="%.6f", delimiter=",", tail=""):
    """A table of `columns` under `header`, written by numpy, with `tail` (a footer) after it."""
    table = np.column_stack(columns)
    np.savetxt(path, table, fmt=fmt, delimiter=delimiter, header=header, comments="")
    if tail:
        with open(path, "a", encoding="utf-8") as handle:
            handle.write(tail)
    return path


def _refused(match, path, **mapping):
    with pytest.raises(InputError, match=match) as caught:
        Recording.load(path, **mapping)
    assert "\n" not in str(caught.value)
    return str(caught.value)


def _cli(argv, capsys):
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return code, err


FIT = ["--model", "physics", "--physics", "lti:2", "--max-steps", "1", "--quiet"]


def _fit(tmp_path, capsys, *arguments):
    """`hybrid fit ARGUMENTS` (one LM step, `FIT`) into tmp_path/m.eqx: (exit status, stderr)."""
    return _cli(["fit", *arguments, *FIT, "--out", tmp_path / "m.eqx"], capsys)


# ----------------------------------------------------------- 1. a cell count that is not the header's


def test_decimal_commas_in_a_comma_separated_file_are_refused(tmp_path, capsys):
    u, y = _signals()
    lines = ["u,y"] + [f"{a:.6f},{b:.6f}".replace(".", ",") for a, b in zip(u, y)]  # 0,666667,0,009428
    path = tmp_path / "euro.csv"
    path.write_text("\n".join(lines) + "\n")
    _refused(
        r"has 4 cells at line 2 \(sample 0\) but 2 columns in its header \(decimal commas\?",
        path,
        columns="input=u,output=y",
        rate=RATE,
    )
    code, err = _cli(
        ["fit", path, "--columns", "input=u,output=y", "--rate", RATE, *FIT, "--out", tmp_path / "m.eqx"],
        capsys,
    )
    assert code == 2 and "decimal commas?" in err and not (tmp_path / "m.eqx").exists()
    # a time in '.' decimals beside signals in decimal commas; quoted cells; the project's own columns
    t = np.arange(N) / RATE
    lines = ["t,u,y"] + [f"{a:.6f}," + f"{b:.6f},{c:.6f}".replace(".", ",") for a, b, c in zip(t, u, y)]
    path.write_text("\n".join(lines) + "\n")
    _refused(
        r"has 5 cells at line 2 \(sample 0\) .*\(decimal commas\?", path, columns="input=u,output=y,time=t"
    )
    lines = ['"t","u","y"'] + [",".join(f'"{x:.6f}"'.replace(".", ",") for x in r) for r in zip(t, u, y)]
    path.write_text("\n".join(lines) + "\n")
    _refused(r"a number with a decimal comma '0,000000'", path, columns="input=u,output=y,time=t")
    lines = ["t,v_in,w"] + [f"{a:.6f},{b:.6f},{c:.6f}".replace(".", ",") for a, b, c in zip(t, u, y)]
    path.write_text("\n".join(lines) + "\n")
    _refused(r"has 6 cells at line 2 \(sample 0\) but 3 columns in its header \(decimal commas\?", path)


def test_a_line_with_a_cell_too_many_is_refused_at_its_line(tmp_path):
    u, y = _signals()
    path = _write(tmp_path / "extra.csv", "time,u,y", [np.arange(N) / RATE, u, y])
    lines = path.read_text().splitlines()
    lines[101] += ",0.5"  # sample 100: a value written twice
    path.write_text("\n".join(lines) + "\n")
    _refused(
        r"has 4 cells at line 102 \(sample 100\) but 3 columns", path, columns="input=u,output=y,time=time"
    )


def test_a_footer_after_the_data_is_skipped_with_a_note_and_a_short_line_refused(tmp_path):
    u, y = _signals()
    t = np.arange(N) / RATE
    footer = "End of data\nTotal scans: 300\n"
    path = _write(
        tmp_path / "daq.csv", "Scan,Time,Ch101 (VDC),Ch102 (VDC)", [np.arange(N) + 1, t, u, y], tail=footer
    )
    rec = Recording.load(path, columns="input=Ch101 (VDC),output=Ch102 (VDC),time=Time")
    assert rec.n == N and np.allclose(rec.w, y, atol=1e-6)
    assert any("after its data (from line 302, 'End of data') skipped as a footer" in n for n in rec.notes)
    # a line of numbers cut short is no footer: refused at its line, never dropped
    lines = path.read_text().splitlines()
    lines[-3] = lines[-3][:12]
    path.write_text("\n".join(lines) + "\n")
    _refused(
        r"at line 301 \(sample 299\) but 4 columns in its header \(a line cut short",
        path,
        columns="input=Ch101 (VDC),output=Ch102 (VDC),time=Time",
    )


# ------------------------------------------------------------------- 2. units in the header's names


def test_units_in_the_header_scale_the_time_and_label_the_signals(tmp_path):
    u, y = _signals(2000)
    t_ms = np.arange(2000) * 1.0  # 1 kHz in ms: a step of 1, too small for the ms heuristic
    path = _write(tmp_path / "daq.csv", "Time [ms],u [V],y (mm)", [t_ms, u, y])
    rec = Recording.load(path, columns="input=u [V],output=y (mm),time=Time [ms]")
    assert rec.rate == pytest.approx(1000.0) and rec.metadata["rate_hz"] == pytest.approx(1000.0)
    assert rec.metadata["units"] == {"t": "s", "v_in": "V", "w": "mm"}
    assert any("read in ms, as its name says" in n for n in rec.notes)
    # ISO 80000's quantity/unit, and words in brackets that are no unit
    path = _write(tmp_path / "iso.csv", "t/s,u (cmd),Displacement/µm", [np.arange(2000) / RATE, u, y])
    rec = Recording.load(path, columns="input=u (cmd),output=Displacement/µm,time=t/s")
    assert rec.metadata["units"] == {"t": "s", "v_in": "V", "w": "µm"} and rec.rate == pytest.approx(RATE)
    # an explicit unit wins, and a disagreement is said in one line
    rec = Recording.load(path, columns="input=u (cmd),output=Displacement/µm,time=t/s", units="w=mm")
    assert rec.metadata["units"]["w"] == "mm"
    assert any("the output's name 'Displacement/µm' says µm, but --units" in n for n in rec.notes)


def test_units_after_an_underscore_label_the_signals_and_an_unmapped_time_column_is_suggested(tmp_path):
    # a script's names: time_s, drive_V, pos_mm; mapped without --time, the refusal names the time column
    u, y = _signals()
    path = _write(tmp_path / "lab.csv", "time_ms,drive_V,pos_mm", [np.arange(N) * 40.0, u, y])
    message = _refused(
        r"no time column and no sampling rate.*--time time_ms.*its column 'time_ms' looks like one",
        path,
        columns="input=drive_V,output=pos_mm",
    )
    assert message.count("time_ms") == 3
    rec = Recording.load(path, columns="input=drive_V,output=pos_mm,time=time_ms")
    assert rec.metadata["units"] == {"t": "s", "v_in": "V", "w": "mm"} and rec.rate == pytest.approx(25.0)
    # one letter after '_' is a unit only where it is one scripts write (V, s, m, N, W), and v_in is no inches
    path = _write(tmp_path / "names.csv", "t,v_in,temp_C", [np.arange(N) / RATE, u, y])
    rec = Recording.load(path, columns="input=v_in,output=temp_C,time=t")
    assert rec.metadata["units"] == {"t": "s", "v_in": "V", "w": "a.u."}  # the defaults: nothing read


def test_a_time_column_whose_name_gives_no_time_unit_is_refused(tmp_path):
    u, y = _signals()
    path = _write(tmp_path / "idx.csv", "Time [samples],u,y", [np.arange(N) * 1.0, u, y])
    _refused(
        r"time column 'Time \[samples\]', whose name gives it the unit 'samples', not a time unit.*--rate",
        path,
        columns="input=u,output=y,time=Time [samples]",
    )
    assert Recording.load(path, columns="input=u,output=y", rate=RATE).rate == pytest.approx(RATE)


def test_the_command_line_reads_the_header_units(tmp_path, capsys):
    # t in ms stepping by 40 (25 Hz) and a dead output in µm: read in s, the dead sensor named in µm
    u, _ = _signals()
    path = _write(tmp_path / "dead.csv", "Time [ms],u [V],y [µm]", [np.arange(N) * 40.0, u, np.zeros(N)])
    code, err = _cli(
        [
            "fit",
            path,
            "--columns",
            "input=u [V],output=y [µm],time=Time [ms]",
            *FIT,
            "--out",
            tmp_path / "m.eqx",
        ],
        capsys,
    )
    assert code == 2 and "the output column w is constant (0 µm in all 300 samples)" in err
    assert "a disconnected or saturated sensor" in err and "tracking fail?" not in err


# ----------------------------------------------------------------------- 3. the rate of a time column


def test_jittered_millisecond_times_give_one_rate_and_accept_the_rate_given(tmp_path):
    rng = np.random.default_rng(5)
    n = 1800
    u, y = _signals(n)
    t_ms = np.round(np.arange(n) * 1000 / RATE + rng.uniform(-3, 3, n))  # 33, 34, 33, ... ± 3 ms
    path = _write(tmp_path / "cam.csv", "time,u,y", [t_ms, u, y], fmt=["%d", "%.6f", "%.6f"])
    rec = Recording.load(path, columns="input=u,output=y,time=time", units="t=ms")
    assert rec.metadata["time_base"]["rebuilt"]
    assert rec.metadata["rate_hz"] == pytest.approx(RATE, rel=1e-5) and rec.rate == rec.metadata["rate_hz"]
    again = Recording.load(path, columns="input=u,output=y,time=time", units="t=ms", rate=RATE)
    assert again.rate == rec.rate


def test_times_rounded_to_seven_digits_give_the_rate_not_their_median_step(tmp_path):
    u, y = _signals(1800)
    path = _write(tmp_path / "tek.csv", "TIME,CH1,CH2", [np.arange(1800) / RATE, u, y], fmt="%.6e")
    rec = Recording.load(path, columns="input=CH1,output=CH2,time=TIME")
    assert rec.rate == pytest.approx(RATE, rel=1e-6) and rec.metadata["rate_hz"] == pytest.approx(
        RATE, rel=1e-6
    )


# ---------------------------------------------------------------------------------- 4. messages


def test_cells_between_spaces_in_a_csv_say_so(tmp_path):
    u, y = _signals()
    path = _write(tmp_path / "ws.csv", "time u y", [np.arange(N) / RATE, u, y], delimiter="  ")
    message = _refused(
        "has its cells separated by spaces.*rename it to .txt", path, columns="input=u,output=y,time=time"
    )
    assert "--time time u y" not in message
    own = _write(tmp_path / "own.csv", "t v_in w", [np.arange(N) / RATE, u, y], delimiter=" ")
    _refused("has its cells separated by spaces.*--columns input=v_in,output=w --time t", own)
    txt = _write(tmp_path / "ws.txt", "time u y", [np.arange(N) / RATE, u, y], delimiter="  ")
    assert Recording.load(txt, columns="input=u,output=y,time=time").n == N


def test_a_preamble_is_skipped_in_a_txt_as_in_a_csv(tmp_path):
    u, y = _signals()
    preamble = "LabVIEW Measurement\t\nWriter_Version\t2\n***End_of_Header***\t\n\nChannels\t2\n"
    header = preamble + "X_Value\tUntitled\tUntitled 1\tComment"  # no line fills the Comment column
    for name in ("lv.txt", "lv.csv"):
        path = _write(tmp_path / name, header, [np.arange(N) / RATE, u, y], delimiter="\t")
        rec = Recording.load(path, columns="input=Untitled,output=Untitled 1,time=X_Value")
        assert rec.n == N and rec.rate == pytest.approx(RATE)
        assert any("the 4 line(s) before its header (line 6) skipped" in n for n in rec.notes), rec.notes


@pytest.mark.parametrize(
    "change, match",
    [
        (lambda t: np.delete(t, range(100, 110)), r"gap in time at line 102 \(sample 100; t = "),
        (lambda t: np.insert(t, 51, t[50]), r"repeats the time 1.66667 s at line 53 \(sample 51\)"),
        (
            lambda t: np.concatenate([t[:200], t[200:] - 1.0]),
            r"clock that restarted at line 202 \(sample 200\).*split the file there, or keep one run with "
            r"--range.*:200 or 200:",
        ),
    ],
)
def test_time_errors_name_the_line_and_the_sample(tmp_path, change, match):
    t = change(np.arange(N) / RATE)
    u, y = _signals(t.size)
    path = _write(tmp_path / "t.csv", "time,u,y", [t, u, y])
    message = _refused(match, path, columns="input=u,output=y,time=time")
    assert "sort the samples" not in message
    own = _write(tmp_path / "own.csv", "t,v_in,w", [t, u, y])
    _refused(match, own)  # a file in the project's own columns: the same words


def test_a_non_utf8_file_names_its_encoding_and_excels_format(tmp_path):
    path = tmp_path / "cp.csv"
    u, y = _signals()
    text = "Zeit [s];Spannung [V];Weg [µm]\n" + "".join(
        f"{a:.6f};{b:.6f};{c:.6f}\n".replace(".", ",") for a, b, c in zip(np.arange(N) / RATE, u, y)
    )
    path.write_bytes(text.encode("cp1252"))
    for mapping in ({"columns": "input=Spannung [V],output=Weg [µm],time=Zeit [s]"}, {}):
        _refused(
            r"not UTF-8 text \(byte 0xB5 at line 1; it looks like Windows-1252.*save it as CSV UTF-8",
            path,
            **mapping,
        )


@pytest.mark.parametrize(
    "content, says",
    [
        (b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 8, "a PNG image"),
        (b"PK\x03\x04" + bytes(range(256)) * 8, "a ZIP archive: an Excel workbook saved under another name"),
        (bytes(2048), "NUL bytes only, what a power loss or a full disk leaves of a log"),
        (bytes(np.random.default_rng(3).integers(0, 256, 4096, dtype=np.uint8)), "binary data"),
    ],
)
def test_a_binary_file_is_named_for_what_it_is_not_for_an_encoding(tmp_path, content, says):
    """A PNG, a workbook or random bytes under a .csv name were "not UTF-8 text (…): it looks like
    UTF-16", and a log of NUL bytes (a power loss) was read as one column named by 2048 NULs."""
    path = tmp_path / "data.csv"
    path.write_bytes(content)
    for mapping in ({"columns": "input=u,output=y", "rate": RATE}, {}):
        message = _refused(re.escape(f"is not text but {says}"), path, **mapping)
        assert "\x00" not in message and "UTF-16" not in message


def test_empty_cells_are_counted_in_one_message(tmp_path):
    """A tracker that lost the tip wrote empty cells at 7 rows: one message names the first and counts
    them all (each was a separate try before), and points at --fill-gaps for a few frames in a row."""
    u, y = _signals()
    path = _write(tmp_path / "lost.csv", "time,u,y", [np.arange(N) / RATE, u, y])
    rows = path.read_text().splitlines()
    lost = [40, 41, 42, 120, 200, 201, 250]  # samples; the header is line 1, sample k is line k + 2
    for k in lost:
        t, v, _ = rows[k + 1].split(",")
        rows[k + 1] = f"{t},{v},"
    path.write_text("\n".join(rows) + "\n")
    message = _refused(
        r"an empty cell \(a missing value\) in column 'y' \(mapped as output\) at line 42 \(sample 40\) "
        r"\(lines 42, 43, 44, 122, 202, \.\.\.: 7 lines have such a cell\)",
        path,
        columns="input=u,output=y,time=time",
    )
    assert "--fill-gaps N" in message


def _side_by_side(path, delimiter, short=200, u_end=None, time=False):
    """An estimation record of N samples and a validation record of `short` beside it, as a spreadsheet
    writes two experiments: the validation columns' cells empty below its last sample (uVal's from
    `u_end` if given). With `time`, one time column of N rows for both."""
    u, y = _signals()
    uv, yv = _signals(short, seed=1)
    names = ["t"] * time + ["uEst", "yEst", "uVal", "yVal"]
    lines = [delimiter.join(names)]
    for k in range(N):
        val = [f"{uv[k]:.6f}" if k < (u_end or short) else "", f"{yv[k]:.6f}" if k < short else ""]
        lines.append(delimiter.join([f"{k / RATE:.6f}"] * time + [f"{u[k]:.6f}", f"{y[k]:.6f}", *val]))
    path.write_text("\n".join(lines) + "\n")
    return path, (u, y), (uv, yv)


@pytest.mark.parametrize("suffix, delimiter", [(".csv", ","), (".txt", "\t")])
@pytest.mark.parametrize("time", [False, True])
def test_a_shorter_record_beside_a_longer_one_ends_where_its_cells_do(tmp_path, suffix, delimiter, time):
    """A validation record shorter than the estimation record in the same file: its columns' last cells are
    empty. Each line of them was refused as a missing value (with --test-range too, as the cells were
    checked before the range), so the file had to be cut by hand; now the record ends where its cells do."""
    path, (u, y), (uv, yv) = _side_by_side(tmp_path / f"two{suffix}", delimiter, time=time)
    mapping = {"columns": "input=uVal,output=yVal" + (",time=t" if time else "")} | (
        {} if time else {"rate": RATE}
    )
    short = Recording.load(path, **mapping)
    assert short.v_in.size == 200
    np.testing.assert_allclose(short.v_in, uv, atol=1e-6)
    np.testing.assert_allclose(short.w, yv, atol=1e-6)
    assert any(
        "'uVal' and 'yVal' end at line 201 (200 samples); the 100 line(s) after it" in n for n in short.notes
    )
    long = Recording.load(path, **(mapping | {"columns": mapping["columns"].replace("Val", "Est")}))
    # the shorter record's empty cells are not "not read" for the longer one's (a .txt said so, a .csv not)
    assert long.v_in.size == N and not any("end at line" in n or "not read" in n for n in long.notes)
    np.testing.assert_allclose(long.w, y, atol=1e-6)


@pytest.mark.parametrize("suffix, delimiter", [(".csv", ","), (".txt", "\t")])
def test_a_shorter_record_whose_columns_end_apart_or_have_a_gap_is_refused_for_what_it_is(
    tmp_path, suffix, delimiter
):
    """A drive that ends a line before its output is refused as such (it read "1501 lines have such a
    cell", counting the tail); a gap within the record is its own missing value, refused alone, and
    --fill-gaps fills it (it read "1501 lines", then "1500 missing values … up to its last sample")."""
    apart, _, _ = _side_by_side(tmp_path / f"apart{suffix}", delimiter, u_end=199)
    _refused(
        r"has columns that end on different lines, 'uVal' \(mapped as input\) at line 200 and 'yVal' "
        r"\(mapped as output\) at line 201: a record's drive and output must end together",
        apart,
        columns="input=uVal,output=yVal",
        rate=RATE,
    )
    gap, _, (uv, yv) = _side_by_side(tmp_path / f"gap{suffix}", delimiter)
    rows = gap.read_text().splitlines()
    rows[51] = delimiter.join(rows[51].split(delimiter)[:3] + [""])  # sample 50's yVal
    gap.write_text("\n".join(rows) + "\n")
    message = _refused(
        r"in column 'yVal' \(mapped as output\) at line 52 \(sample 50\): every value",
        gap,
        columns="input=uVal,output=yVal",
        rate=RATE,
    )
    assert "lines have such a" not in message  # one, not the tail's hundred beside it
    filled = Recording.load(gap, columns="input=uVal,output=yVal", rate=RATE, fill_gaps=1)
    assert filled.w.size == 200 and filled.w[50] == pytest.approx(0.5 * (yv[49] + yv[51]), abs=1e-6)


def test_a_fit_scores_a_shorter_validation_record_of_the_same_file(tmp_path, capsys):
    """`hybrid fit` on the estimation columns, --test on the validation columns of the same file, with and
    without --test-range (which was refused too: the cells were checked before the range was cut)."""
    path, _, _ = _side_by_side(tmp_path / "two.csv", ",")
    for extra, samples in (([], 200), (["--test-range", "0:150"], 150)):
        argv = ["fit", path, "--columns", "input=uEst,output=yEst", "--rate", RATE, "--test", path]
        argv += ["--test-columns", "input=uVal,output=yVal", *extra, *FIT, "--out", tmp_path / "m.eqx"]
        code = main([str(a) for a in argv])
        out, err = capsys.readouterr()
        assert code == 0 and "Traceback" not in err, err
        assert "two.csv (uVal -> yVal" in out and f"({samples} samples)" in out, out
        (tmp_path / "m.eqx").unlink()
        (tmp_path / "m.eqx.json").unlink()


def test_bad_cells_of_a_text_table_are_counted_in_one_message(tmp_path):
    """A tab-separated logger file with a tracker's NaN, an empty cell and a word: one message names the first,
    its column and role, and counts the lines (it named the first alone, and said 'remove or interpolate it')."""
    u, y = _signals()
    path = _write(tmp_path / "lost.txt", "time\tu\ty", [np.arange(N) / RATE, u, y], delimiter="\t")
    rows = path.read_text().splitlines()
    for k, (column, cell) in {40: (2, "nan"), 41: (2, "NaN"), 120: (1, ""), 200: (2, "lost")}.items():
        cells = rows[k + 1].split("\t")
        cells[column] = cell
        rows[k + 1] = "\t".join(cells)
    path.write_text("\n".join(rows) + "\n")
    message = _refused(
        r"has a non-finite value 'nan' in column 'y' \(mapped as output\) at line 42 \(sample 40\) "
        r"\(lines 42, 43, 122, 202: 4 lines have such a cell\): every value of a mapped column",
        path,
        columns="input=u,output=y,time=time",
    )
    assert "--fill-gaps N" in message


def test_bad_cells_of_a_column_no_role_maps_are_left_unread_with_a_note(tmp_path):
    """A logger's spare channel with NaN and a word: not mapped, so not read (it refused the file, as if
    every column were asked for); the mapped columns are read as written."""
    u, y = _signals()
    spare = np.zeros(N)
    path = _write(
        tmp_path / "spare.txt", "time\tu\ty\tspare", [np.arange(N) / RATE, u, y, spare], delimiter="\t"
    )
    rows = path.read_text().splitlines()
    for k, cell in {10: "nan", 11: "off"}.items():
        cells = rows[k + 1].split("\t")
        cells[3] = cell
        rows[k + 1] = "\t".join(cells)
    path.write_text("\n".join(rows) + "\n")
    record = Recording.load(path, columns="input=u,output=y,time=time")
    np.testing.assert_allclose(record.w, y, atol=1e-6)
    assert any(
        "column 'spare' has 2 cell(s) that are not finite numbers; not read" in n for n in record.notes
    )
    with pytest.raises(InputError, match="in column 'spare' \\(mapped as output\\)"):  # mapped, refused
        Recording.load(path, columns="input=u,output=spare,time=time")


def test_non_finite_values_of_arrays_are_counted_in_one_message(tmp_path):
    """An .npz (and an .npy) whose output has NaN at three samples: one message names the first as the file
    calls it, with its role, and counts the samples (it came from the Recording's own check, with no role
    and no pointer to --fill-gaps)."""
    u, y = _signals()
    y[[10, 11, 30]] = np.nan
    np.savez(tmp_path / "lost.npz", time=np.arange(N) / RATE, u=u, y=y)
    message = _refused(
        r"has a non-finite value \(nan\) in array 'y' \(mapped as output\) at sample 10 \(samples 10, 11, 30: 3 "
        r"samples have such a value\): every value of a mapped column must be a finite number",
        tmp_path / "lost.npz",
        columns="input=u,output=y,time=time",
    )
    assert "--fill-gaps N" in message and "--range" in message
    np.save(tmp_path / "lost.npy", np.c_[np.arange(N) / RATE, u, y])
    _refused(
        r"in column '2' \(mapped as output\) at sample 10 \(samples 10, 11, 30: 3",
        tmp_path / "lost.npy",
        columns="input=1,output=2,time=0",
    )


def test_utf16_text_is_still_told_as_utf16(tmp_path):
    u, y = _signals()
    path = tmp_path / "wide.csv"
    path.write_bytes(
        ("t,u,y\n" + "".join(f"{k / RATE},{a},{b}\n" for k, (a, b) in enumerate(zip(u, y)))).encode("utf-16")
    )
    _refused(r"not UTF-8 text \(byte 0xFF at line 1; it looks like UTF-16\)", path)
    path.write_bytes(path.read_bytes()[2:])  # no byte-order mark: told by its NULs, every other byte
    _refused(r"not UTF-8 text \(NUL bytes every other byte; it looks like UTF-16\)", path)


# ----------------------------------------------------------- rig's quality column


def test_samples_of_quality_0_are_named_in_a_note_not_fitted_in_silence(tmp_path):
    # `rig record` writes w on every row and marks with quality 0 where its tracker could not measure
    # it (held, interpolated, or a smeared tip): a fit weighs them as any other sample.
    u, y = _signals()
    t = np.arange(N) / RATE
    quality = np.ones(N)
    quality[120:135] = 0.0  # the strip out of view for half a second
    path = _write(tmp_path / "rec.csv", "t,v_in,w,quality", [t, u, y, quality])
    notes = [n for n in Recording.load(path).notes if "quality 0" in n]
    assert len(notes) == 1 and "15 of 300 samples have quality 0 (the first at sample 120)" in notes[0]
    assert "--range" in notes[0]
    # every sample measured, or a 'quality' that is not rig's 0/1 flag: no note
    for values in (np.ones(N), np.linspace(0.0, 100.0, N)):
        path = _write(tmp_path / "other.csv", "t,v_in,w,quality", [t, u, y, values])
        assert not [n for n in Recording.load(path).notes if "quality 0" in n]


def test_a_cyclers_columns_are_guessed_in_the_message_index_and_time_by_any_word(tmp_path):
    """A battery cycler's export (Arbin-like): the guess skips the data point, takes the test time."""
    u, y = _signals()
    header = "Data_Point,Test_Time(s),Step_Index,Current(A),Voltage(V),Aux_Temperature(C)"
    columns = [np.arange(N) + 1, np.arange(N) / RATE, np.ones(N), u, y, np.full(N, 25.0)]
    path = _write(tmp_path / "cycler.csv", header, columns)
    message = _refused(
        r"e\.g\. --columns \"input=Current\(A\),output=Voltage\(V\)\" --time \"Test_Time\(s\)\"", path
    )
    assert "Data_Point" not in message.split("e.g.")[1]
    rec = Recording.load(path, columns="input=Current(A),output=Voltage(V),time=Test_Time(s)")
    assert rec.metadata["units"]["v_in"] == "A" and rec.metadata["units"]["w"] == "V" and rec.n == N


# ----------------------------------------------------------- a table without a header


def test_a_csv_without_a_header_keeps_its_first_sample_and_unmapped_is_refused_with_the_mapping(
    tmp_path, capsys
):
    # A logger's export without a header, mapped by column numbers, tried as a new user would: its first
    # line was read as the header, so its first sample was lost without a word.
    u, y = _signals()
    t = np.arange(N) / RATE
    path = _write(tmp_path / "bare.csv", "", [t, u, y])
    path.write_text(path.read_text().lstrip("\n"))  # numpy's empty header leaves a blank first line
    reference = np.loadtxt(path, delimiter=",")  # every line a sample
    rec = Recording.load(path, columns="input=1,output=2,time=0")
    assert rec.n == N == reference.shape[0]
    np.testing.assert_array_equal(rec.v_in, reference[:, 1])
    np.testing.assert_array_equal(rec.w, reference[:, 2])
    assert any("no header" in note and "by number from 0" in note for note in rec.notes), rec.notes
    # unmapped: one line that says so and gives the mapping, which then reads it
    message = _refused(
        r"has no header: its first line holds numbers.*--columns input=1,output=2 --time 0", path
    )
    assert "0.000000" in message
    code, err = _cli(["fit", path, *FIT], capsys)
    assert code == 2 and "has no header" in err and len(err.strip().splitlines()) == 1
    two = _write(tmp_path / "two.csv", "", [u, y])
    two.write_text(two.read_text().lstrip("\n"))
    _refused(r"has no header.*--columns input=0,output=1 --rate HZ", two)
    assert Recording.load(two, columns="input=0,output=1", rate=RATE).n == N
    # a header of names is still a header (and a date-time first line, a sample)
    named = _write(tmp_path / "named.csv", "time,u,y", [t, u, y])
    assert Recording.load(named, columns="input=u,output=y,time=time").n == N


def test_a_labview_measurement_file_and_a_tsv_are_read_as_text_tables(tmp_path):
    """Read through a mapping, with the preamble skipped; unmapped, the message writes the mapping."""
    u, y = _signals()
    header = "LabVIEW Measurement\t\nWriter_Version\t2\n***End_of_Header***\t\n\nX_Value\tUntitled\tUntitled 1\tComment"
    lvm = _write(tmp_path / "run.lvm", header, [np.arange(N) / RATE, u, y], delimiter="\t")
    _refused(
        r"unknown suffix '.lvm'.*LabVIEW measurement file is read with its columns mapped.*--time X_Value",
        lvm,
    )
    rec = Recording.load(lvm, columns="input=Untitled,output=Untitled 1,time=X_Value")
    np.testing.assert_allclose(rec.v_in, u, atol=1e-6)  # written with 6 decimals
    np.testing.assert_allclose(rec.w, y, atol=1e-6)
    assert rec.rate == pytest.approx(RATE)
    tsv = _write(tmp_path / "run.tsv", "time\tdrive\ttip", [np.arange(N) / RATE, u, y], delimiter="\t")
    rec = Recording.load(tsv, columns="input=drive,output=tip,time=time")
    np.testing.assert_allclose(rec.w, y, atol=1e-6)


#: What LabVIEW's Write To Measurement File puts above the table: a file block and a channel block.
LVM_PREAMBLE = "\n".join(
    [
        "LabVIEW Measurement\t",
        "Writer_Version\t2",
        "Reader_Version\t2",
        "Separator\tTab",
        "Decimal_Separator\t.",
        "Multi_Headings\tNo",
        "X_Columns\tOne",
        "Time_Pref\tRelative",
        "Operator\tlab",
        "Date\t2026/12/05",
        "Time\t15:40:02.5",
        "***End_of_Header***\t",
        "",
        "Channels\t2\t",
        "Samples\t300\t300\t",
        "Date\t2026/12/05\t2026/12/05\t",
        "Y_Unit_Label\tVolts\tmm\t",
        "X_Dimension\tTime\tTime\t",
        "X0\t0.0000000000000000E+0\t0.0000000000000000E+0\t",
        "Delta_X\t0.033333\t0.033333\t",
        "***End_of_Header***\t\t\t",
        "X_Value\tUntitled\tUntitled 1\tComment",
    ]
)


def test_an_unmapped_labview_file_is_answered_from_its_own_header_below_the_preamble(tmp_path, capsys):
    """The command line names the table's own columns (not the preamble's first line) in its one-line
    refusal, and the flags it gives, or columns by number, read the file."""
    u, y = _signals()
    lvm = _write(tmp_path / "run.lvm", LVM_PREAMBLE, [np.arange(N) / RATE, u, y], delimiter="\t")
    code, err = _cli(["fit", lvm, *FIT], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert '--columns "input=Untitled,output=Untitled 1" --time X_Value' in err, err
    for columns in ("input=Untitled,output=Untitled 1,time=X_Value", "input=1,output=2,time=0"):
        rec = Recording.load(lvm, columns=columns)
        np.testing.assert_allclose(rec.v_in, u, atol=1e-6)
        np.testing.assert_allclose(rec.w, y, atol=1e-6)
        assert rec.rate == pytest.approx(RATE)
        assert any("20 line(s) before its header (line 22)" in note for note in rec.notes), rec.notes


def test_a_labview_file_without_a_time_column_is_sampled_at_its_delta_x(tmp_path, capsys):
    """X_Columns No: LabVIEW writes the channels alone and their period as Delta_X in its header. That is the
    rate, as a declared one would be, with a note (the file was refused for want of a rate); a --rate that
    disagrees is refused in one line naming both."""
    u, y = _signals()
    header = LVM_PREAMBLE.replace("X_Columns\tOne", "X_Columns\tNo").replace("X_Value\t", "")
    lvm = _write(tmp_path / "nox.lvm", header, [u, y], delimiter="\t")
    columns = "input=Untitled,output=Untitled 1"
    for rate in (None, 30.0):  # 30 Hz agrees with 0.033333 s within 1e-4
        rec = Recording.load(lvm, columns=columns, rate=rate)
        np.testing.assert_allclose(rec.w, y, atol=1e-6)
        assert rec.rate == pytest.approx(1 / 0.033333, rel=1e-6) and rec.metadata["rate_from"].startswith(
            "the file's 'Delta_X' field (0.033333 s)"
        )
        np.testing.assert_allclose(rec.t, np.arange(N) / rec.rate)
        assert any("no time column (X_Columns No)" in n and "Delta_X = 0.033333 s" in n for n in rec.notes)
    _refused(
        r"sampling rates that disagree: the file's 'Delta_X' field \(0.033333 s\) says 30.0003 Hz, the rate "
        r"given says 25 Hz",
        lvm,
        columns=columns,
        rate=25.0,
    )
    code, err = _fit(tmp_path, capsys, lvm, "--columns", columns, "--rate", "25")
    assert code == 2 and len(err.strip().splitlines()) == 1 and "'Delta_X'" in err, err
    assert not (tmp_path / "m.eqx").exists()
    # with a time column (X_Columns One) Delta_X is not the time base: the time column is named instead
    timed = _write(tmp_path / "run.lvm", LVM_PREAMBLE, [np.arange(N) / RATE, u, y], delimiter="\t")
    _refused(r"no time column and no sampling rate.*--time X_Value", timed, columns=columns)


def test_a_csv_with_a_logger_preamble_is_answered_from_its_header_and_read_by_column_number(tmp_path):
    """Without t, v_in, w the refusal lists the header's names (it listed the preamble's first line); a
    mapping by number reads the columns under the header (it stopped at the preamble)."""
    u, y = _signals()
    preamble = "Device: DAQ 6009\nOperator: lab\ntime_s,drive_V,tip_mm"
    path = _write(tmp_path / "logger.csv", preamble, [np.arange(N) / RATE, u, y])
    message = _refused(r"missing column\(s\) t, v_in, w \(found 'time_s', 'drive_V', 'tip_mm'\)", path)
    assert "Device" not in message
    rec = Recording.load(path, columns="input=1,output=2,time=0")
    np.testing.assert_allclose(rec.w, y, atol=1e-6)
    assert any("2 line(s) before its header" in note for note in rec.notes), rec.notes


@pytest.mark.parametrize(
    "rows, first",
    [
        ([["time", "drive", "tip"], ["0", "1", "2"], ["1", "2", "3"]], 0),  # a header
        ([["0", "1", "2"], ["1", "2", "3"]], 0),  # none
        ([["time", "drive", "tip"], ["s", "V", "mm"], ["0", "1", "2"], ["1", "2", "3"]], 0),  # and units
        ([["Dev: x"], ["time", "drive", "tip"], ["s", "V", "mm"], ["0", "1", "2"], ["1", "2", "3"]], 1),
        ([["Device: scope X"], ["Date: 2026"], ["t", "u", "y"], ["0", "1", "2"], ["1", "2", "3"]], 2),
        ([["Dev"], [], ["t", "u", "y", ""], ["0", "1", "2", ""], ["1", "2", "3", ""]], 2),  # trailing commas
        ([["Log"], ["time", "u"], ["2026-12-05T10:00:00", "1"], ["2026-12-05T10:00:01", "2"]], 1),
        ([["u", "y", "Ts"], ["1", "2", "0.5"], ["2", "3", ""], ["3", "4", ""]], 0),  # Ts in one row
        ([["0", "1", "0.5"], ["1", "2"], ["2", "3"]], 0),
        ([["Dev"], ["t", "", "y"], ["0", "", "2"], ["1", "", "3"]], 1),  # a column left blank
        ([["a"], ["b"]], 0),  # no two rows of values
    ],
)
def test_a_tables_first_line_is_the_one_above_its_first_two_rows_of_values(rows, first):
    assert table_start(rows) == first


def test_a_labview_file_with_an_x_column_per_channel_is_mapped_by_number_where_a_name_repeats(
    tmp_path, capsys
):
    """LabVIEW's X_Columns Multi writes X_Value over each channel: the file is read (it was refused for its
    repeated names), the refusal's example maps the repeated time by number, and mapping by the repeated
    name says which columns hold it, in one line."""
    u, y = _signals()
    t = np.arange(N) / RATE
    header = LVM_PREAMBLE.replace("X_Value\tUntitled\tUntitled 1", "X_Value\tVoltage\tX_Value\tDisplacement")
    lvm = _write(tmp_path / "multi.lvm", header, [t, u, t, y], delimiter="\t")
    code, err = _cli(["fit", lvm, *FIT], capsys)
    assert code == 2 and "--columns input=Voltage,output=Displacement --time 0 " in err, err
    rec = Recording.load(lvm, columns="input=Voltage,output=Displacement,time=0")
    np.testing.assert_allclose(rec.w, y, atol=1e-6)
    assert rec.rate == pytest.approx(RATE)
    _refused(
        r"2 columns named 'X_Value' \(columns 0, 2.*--time 0",
        lvm,
        columns="input=Voltage,output=Displacement,time=X_Value",
    )


def _pandas_table(path, names, delimiter):
    """What pandas' ``DataFrame.to_csv`` writes (not imported here: pandas is no dependency): a row index
    under an empty name first, then `names`, ``%.6f`` values; a header line that starts with the delimiter."""
    u, y = _signals()
    lines = [delimiter + delimiter.join(names)]
    lines += [
        delimiter.join([str(i), f"{i / RATE:.6f}", f"{a:.6f}", f"{b:.6f}"])
        for i, (a, b) in enumerate(zip(u, y))
    ]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path, u, y


@pytest.mark.parametrize("suffix, delimiter", [(".csv", ","), (".tsv", "\t")])
def test_pandas_row_index_under_an_empty_name_is_left_out_with_a_note(tmp_path, capsys, suffix, delimiter):
    """pandas' to_csv (and R's write.csv) put the row index first under an empty name. It was refused
    ("an empty column name") in a .csv, and a .tsv's header, its leading tab stripped, read one name short."""
    path, u, y = _pandas_table(tmp_path / f"a{suffix}", ["t", "v_in", "w"], delimiter)
    columns = None if suffix == ".csv" else "input=v_in,output=w,time=t"  # a text table is read mapped
    rec = Recording.load(path, columns=columns) if columns else Recording.load(path)
    np.testing.assert_allclose(rec.v_in, u, atol=1e-6)
    np.testing.assert_allclose(rec.w, y, atol=1e-6)
    assert rec.rate == pytest.approx(RATE) and rec.extra == {}
    assert any("row index" in note for note in rec.notes), rec.notes
    named, _, _ = _pandas_table(tmp_path / f"b{suffix}", ["time", "drive", "tip"], delimiter)
    code, err = _fit(tmp_path, capsys, named)
    assert code == 2 and "--columns input=drive,output=tip --time time" in err, err
    assert "'', " not in err and ", ," not in err  # the unnamed column is not listed as an empty name
    by_number = Recording.load(named, columns="input=2,output=3,time=1")  # numbers count the index: column 0
    np.testing.assert_allclose(by_number.w, y, atol=1e-6)


def test_an_unnamed_column_between_the_signals_is_left_out_and_named_by_its_number(tmp_path):
    u, y = _signals()
    path = _write(tmp_path / "a.csv", "t,v_in,,w", [np.arange(N) / RATE, u, 5.0 + u, y])
    rec = Recording.load(path)
    np.testing.assert_allclose(rec.w, y, atol=1e-6)
    assert rec.extra == {}
    assert any("column 2 (from 0) has no name" in note and "row index" not in note for note in rec.notes)


@pytest.mark.parametrize("suffix, delimiter", [(".csv", ","), (".txt", " ")])
def test_numpy_savetxt_header_written_as_a_comment_is_the_header(tmp_path, capsys, suffix, delimiter):
    """``np.savetxt(..., header=...)`` writes ``# t,v_in,w`` (numpy's default comments="# "), which
    ``np.genfromtxt(names=True)`` reads back as the names; it was refused as "no header"."""
    u, y = _signals()
    columns = [np.arange(N) / RATE, u, y]
    path = tmp_path / f"a{suffix}"
    table = np.column_stack(columns)
    np.savetxt(path, table, fmt="%.6f", delimiter=delimiter, header=delimiter.join(["t", "v_in", "w"]))
    assert path.read_text().startswith("# t")
    rec = (
        Recording.load(path)
        if suffix == ".csv"
        else Recording.load(path, columns="input=v_in,output=w,time=t")
    )
    np.testing.assert_allclose(rec.w, y, atol=1e-6)
    assert rec.rate == pytest.approx(RATE) and len(rec.w) == N  # no sample taken for a header
    assert any("header is the comment on line 1" in note for note in rec.notes), rec.notes
    if suffix == ".txt":  # unmapped, a text table headed t, v_in, w reads as it is
        code, err = _fit(tmp_path, capsys, path)
        assert code == 0, err
    named = tmp_path / f"b{suffix}"
    np.savetxt(named, table, fmt="%.6f", delimiter=delimiter, header=delimiter.join(["time", "drive", "tip"]))
    code, err = _fit(tmp_path, capsys, named)
    assert code == 2 and "--columns input=drive,output=tip --time time" in err, err


def test_a_comment_that_is_not_a_header_stays_a_comment(tmp_path):
    """A preamble comment with another number of cells, or one of numbers, is not taken for the names: the
    file has no header, as before, and its first line of numbers stays its first sample."""
    u, y = _signals()
    table = np.column_stack([np.arange(N) / RATE, u, y])
    for i, comment in enumerate(["# logged by rig 2, 30 Hz", "# 1,2,3"]):
        path = tmp_path / f"a{i}.csv"
        np.savetxt(path, table, fmt="%.6f", delimiter=",", header=comment.lstrip("# "))
        rec = Recording.load(path, columns="input=1,output=2,time=0")
        assert len(rec.w) == N and not any("header is the comment" in note for note in rec.notes), rec.notes


@pytest.mark.parametrize("suffix, rows", [(".mat", False), (".mat", True), (".npz", False)])
def test_signals_stored_as_one_matrix_are_mapped_by_column_number(tmp_path, capsys, suffix, rows):
    """MATLAB's ``data = [t u y]; save run.mat data`` (or numpy's ``savez(data=table)``): the record is one
    matrix. Unmapped, the refusal writes the mapping by number; ``data:K`` maps its column (or row) K."""
    import scipy.io

    u, y = _signals()
    table = np.column_stack([np.arange(N) / RATE, u, y])
    stored = table.T if rows else table
    path = tmp_path / f"run{suffix}"
    if suffix == ".mat":
        scipy.io.savemat(path, {"data": stored})
    else:
        np.savez(path, data=stored)
    code, err = _fit(tmp_path, capsys, path)
    example = "--columns input=data:1,output=data:2 --time data:0"
    assert code == 2 and "'data' is a matrix of 3 channels" in err and example in err, err
    rec = Recording.load(path, columns="input=data:1,output=data:2,time=data:0")
    np.testing.assert_array_equal(rec.v_in, u)
    np.testing.assert_array_equal(rec.w, y)
    assert rec.rate == pytest.approx(RATE)
    message = _refused(r"not a vector", path, columns="input=data,output=data:2,time=data:0")
    assert "data:0 to data:2" in message


def test_a_matrix_beside_the_signals_is_left_out_with_a_note(tmp_path):
    """A calibration matrix, the raw table or the operator's name saved beside t, v_in and w was refused
    ("not a vector", "rather than real numbers"); a numeric vector beside them is still an extra channel."""
    import scipy.io

    u, y = _signals()
    t = np.arange(N) / RATE
    path = tmp_path / "run.mat"
    extras = {"calib": 2 * np.eye(3), "raw": np.column_stack([t, u, y]), "operator": "A. Lab", "T": 20 + u}
    scipy.io.savemat(path, {"t": t, "v_in": u, "w": y, **extras})
    rec = Recording.load(path)
    np.testing.assert_array_equal(rec.w, y)
    assert list(rec.extra) == ["T"]
    left_out = sorted(n.split("'")[3] for n in rec.notes if "not a signal" in n)
    assert left_out == ["calib", "operator", "raw"], rec.notes
    np.savez(tmp_path / "a.npz", t=t, v_in=np.array(["a"] * N), w=y)  # a signal of text is still refused
    _refused("variable 'v_in' of type", tmp_path / "a.npz")


def test_a_numpy_npy_array_is_read_by_column_number_or_field_name(tmp_path, capsys):
    """``np.save(file, table)``: columns by number from 0 (a per-row table too), a structured array's fields by
    name, a vector as one file per channel; unmapped, the refusal writes the mapping."""
    u, y = _signals()
    t = np.arange(N) / RATE
    table = np.column_stack([t, u, y])
    np.save(tmp_path / "cols.npy", table)
    np.save(tmp_path / "rows.npy", table.T)
    for name in ("cols.npy", "rows.npy"):
        rec = Recording.load(tmp_path / name, columns="input=1,output=2,time=0")
        np.testing.assert_array_equal(rec.v_in, u)
        np.testing.assert_array_equal(rec.w, y)
        assert rec.rate == pytest.approx(RATE)
    record = np.zeros(N, dtype=[("time", "f8"), ("drive", "f8"), ("tip", "f4")])
    record["time"], record["drive"], record["tip"] = t, u, y
    np.save(tmp_path / "fields.npy", record)
    rec = Recording.load(tmp_path / "fields.npy", columns="input=drive,output=tip,time=time")
    np.testing.assert_allclose(rec.w, y, rtol=1e-6)  # stored as float32
    np.save(tmp_path / "u.npy", u)
    np.save(tmp_path / "y.npy", y)
    joined = f"input={tmp_path / 'u.npy'},output={tmp_path / 'y.npy'}"
    code, err = _fit(
        tmp_path, capsys, tmp_path / "u.npy", tmp_path / "y.npy", "--columns", joined, "--rate", RATE
    )
    assert code == 0, err
    code, err = _fit(tmp_path, capsys, tmp_path / "cols.npy")
    assert code == 2 and "--columns input=1,output=2 --time 0" in err, err
    np.save(tmp_path / "cube.npy", np.zeros((4, 5, 6)))
    _refused(r"shape \(4, 5, 6\): store a table", tmp_path / "cube.npy", columns="input=1,output=2")


def _rigol(path, u, y, increment=1 / RATE, start=-2.0):
    """A Rigol oscilloscope's CSV export (DS1000Z): the sampling period and the first sample's time in
    the units row, under the header's last names, which no data line fills; every data line ends in ','."""
    lines = ["X,CH1,CH2,Start,Increment,", f"Sequence,Volt,Volt,{start:.6e},{increment:.6e}"]
    lines += [f"{i},{a:.4e},{b:.4e}," for i, (a, b) in enumerate(zip(u, y))]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def test_an_oscilloscopes_csv_gives_its_rate_from_the_increment_under_its_header(tmp_path, capsys):
    """A scope records the drive and the response on two channels; Rigol's export was refused ("names
    column(s) Volt more than once": its units row read as the header), and mapped, at line 3."""
    u, y = _signals()
    path = _rigol(tmp_path / "scope.csv", u, y)
    code, err = _fit(tmp_path, capsys, path)
    assert code == 2 and "--columns input=CH1,output=CH2 (the rate from the file's own field)" in err, err
    rec = Recording.load(path, columns="input=CH1,output=CH2")
    np.testing.assert_allclose(rec.v_in, u, rtol=1e-4, atol=1e-6)  # written with 4 decimals
    np.testing.assert_allclose(rec.w, y, rtol=1e-4, atol=1e-6)
    assert rec.rate == pytest.approx(RATE, rel=1e-6)  # 1 / Increment
    assert any("Increment = 0.0333333" in note for note in rec.notes), rec.notes
    assert rec.metadata["units"]["v_in"] == "Volt"
    code, err = _fit(tmp_path, capsys, path, "--columns", "input=CH1,output=CH2")
    assert code == 0, err
    code, err = _fit(tmp_path, capsys, path, "--columns", "input=CH1,output=CH2", "--rate", 50)
    assert code == 2 and "Increment" in err, err  # a rate given that the file's field contradicts is named


#: Two more scopes' CSV exports: Keysight's names its channels 1 and 2 over a units row whose time unit is
#: "second"; a header of units alone (Second,Volt,Volt) under a preamble (a layout written here, not taken from an instrument's file).
_SCOPES = {
    "keysight": ("x-axis,1,2\nsecond,Volt,Volt", "--columns input=1,output=2 --time x-axis"),
    "units_header": (
        "Record Length,Analog:300\nSample Interval,Analog:3.333333E-02\nSecond,Volt,Volt",
        "--columns input=1,output=2 --time Second",
    ),
}


@pytest.mark.parametrize("scope", sorted(_SCOPES))
def test_a_scopes_csv_is_answered_with_the_mapping_that_reads_it(tmp_path, capsys, scope):
    """Unmapped, the refusal's example took Keysight's time column for the drive (--columns
    input=x-axis,output=1 with --rate HZ), and a header of units was refused for naming Volt twice with no
    way on; each example now reads the file as it is, time from its column."""
    head, example = _SCOPES[scope]
    u, y = _signals()
    path = _write(tmp_path / f"{scope}.csv", head, [np.arange(N) / RATE - 1.0, u, y], fmt="%.8e")
    code, err = _fit(tmp_path, capsys, path)
    assert code == 2 and example in err, err
    flags = example.split()
    mapping = flags[1] + ",time=" + flags[3]
    rec = Recording.load(path, columns=mapping)
    np.testing.assert_allclose(rec.w, y, rtol=1e-7, atol=1e-9)
    assert rec.rate == pytest.approx(RATE, rel=1e-6)
    code, err = _fit(tmp_path, capsys, path, *flags)
    assert code == 0, err


def _tektronix(path, t, values, channel):
    """A Tektronix scope's CSV export (TDS series), one channel per file: its settings as name, value in the
    first two columns of its first lines, beside the samples' time and value in the fourth and fifth."""
    settings = [
        ("Record Length", f"{len(t):.6e}"),
        ("Sample Interval", f"{t[1] - t[0]:.6e}"),
        ("Trigger Point", "0"),
    ]
    settings += [("", "")] * 3 + [
        ("Source", f"CH{channel}"),
        ("Vertical Units", "V"),
        ("Horizontal Units", "s"),
    ]
    lines = []
    for i, (a, b) in enumerate(zip(t, values)):
        name, value = settings[i] if i < len(settings) else ("", "")
        lines.append(f"{name},{value},,{a:15.6f},{b:12.6f},")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def test_a_tektronix_export_keeps_its_first_samples_and_a_joined_file_says_what_was_skipped(tmp_path, capsys):
    """Columns mapped by number whose first line holds numbers start at that line, whatever the columns not
    read hold: a Tektronix file's first three samples were taken for a preamble and its header, and, its
    channels joined from two files, that went unsaid (a joined file's notes were dropped)."""
    u, y = _signals()
    t = np.arange(N) / RATE - 1.0
    ch1, ch2 = _tektronix(tmp_path / "F0000CH1.CSV", t, u, 1), _tektronix(tmp_path / "F0000CH2.CSV", t, y, 2)
    rec = Recording.load([ch1, ch2], columns=f"input={ch1}:4,output={ch2}:4,time={ch1}:3")
    assert len(rec.w) == N
    np.testing.assert_allclose(rec.v_in, u, atol=1e-6)
    np.testing.assert_allclose(rec.w, y, atol=1e-6)
    assert rec.rate == pytest.approx(RATE, rel=1e-5)
    code, err = _fit(tmp_path, capsys, ch1, ch2, "--columns", f"input={ch1}:4,output={ch2}:4", "--rate", RATE)
    assert code == 0, err
    code, err = _fit(tmp_path, capsys, ch1)  # unmapped: numbers are no names
    assert code == 2 and "the columns by number from 0" in err and "input=0." not in err, err
    # a logger's preamble above a header, in a joined file: skipped, and said
    _write(tmp_path / "u.csv", "Device: logger 7\ntime,volts", [t, u])
    _write(tmp_path / "y.csv", "time,mm", [t, y])
    joined = f"input={tmp_path / 'u.csv'}:volts,output={tmp_path / 'y.csv'}:mm"
    rec = Recording.load([tmp_path / "u.csv", tmp_path / "y.csv"], columns=joined, rate=RATE)
    np.testing.assert_allclose(rec.v_in, u, atol=1e-6)
    assert any("the 1 line(s) before its header (line 2) skipped" in note for note in rec.notes), rec.notes


def test_an_excel_workbook_is_read_as_its_first_sheets_table(tmp_path, capsys):
    """A lab's .xlsx (written here with openpyxl, as Excel stores one): a preamble, a header with units in
    its names, a date-time column, a note on the first sample, a second sheet. It was refused ("save the
    sheet as CSV"); now it reads as that CSV would, with a note for every choice made."""
    import datetime

    import openpyxl

    u, y = _signals()
    t = np.arange(N) / RATE
    book = openpyxl.Workbook()
    sheet = book.active
    sheet.title = "Messung"
    sheet.append(["Operator:", "A. Lab"])
    sheet.append(["Date:", datetime.datetime(2026, 12, 5, 10, 0)])
    sheet.append([])
    sheet.append(["Timestamp", "Time (s)", "Drive (V)", "Tip (mm)", "Comment"])
    start = datetime.datetime(2026, 12, 5, 10, 0)
    for i in range(N):
        stamp = start + datetime.timedelta(seconds=float(t[i]))
        note = {0: "drive on", 5: 'gain 2, "high"', 9: "step\nup"}.get(i)  # a comma, quotes, a line break
        sheet.append([stamp, float(t[i]), float(u[i]), float(y[i]), note])
    book.create_sheet("notes").append(["calibration", 1.5])
    path = tmp_path / "lab.xlsx"
    book.save(path)
    code, err = _fit(tmp_path, capsys, path)
    example = '--columns "input=Drive (V),output=Tip (mm)"'
    assert code == 2 and example in err and "Timestamp" in err, err  # its header found below the preamble
    rec = Recording.load(path, columns="input=Drive (V),output=Tip (mm),time=Time (s)")
    np.testing.assert_allclose(rec.v_in, u, rtol=1e-15, atol=0)  # as the sheet stores them (to an ulp)
    np.testing.assert_allclose(rec.w, y, rtol=1e-15, atol=0)
    assert rec.rate == pytest.approx(RATE) and rec.metadata["units"]["w"] == "mm"
    assert any("first sheet, 'Messung', of 2" in note for note in rec.notes), rec.notes
    assert any("the 3 line(s) before its header (line 4) skipped" in note for note in rec.notes), rec.notes
    stamped = Recording.load(path, columns="input=Drive (V),output=Tip (mm),time=Timestamp")
    np.testing.assert_allclose(stamped.t - stamped.t[0], t, atol=1e-5)  # a sheet's date-time: days, ~1 µs
    assert stamped.rate == pytest.approx(RATE, rel=1e-6)
    bad = tmp_path / "bad.xlsx"
    bad.write_bytes(b"PK\x03\x04 not a workbook")
    code, err = _fit(tmp_path, capsys, bad)
    assert code == 2 and "is not a readable Excel workbook" in err and err.count("\n") == 1, err


def test_a_time_column_of_times_of_day_reads_as_seconds_across_midnight(tmp_path):
    """A logger that writes the time of day alone (10:15:32.125), beside or without the date: the column
    was refused as non-numeric when mapped as the time, and unmapped its rows did not count as values."""
    u, y = _signals()
    start = 23 * 3600 + 59 * 60 + 55.0  # 5 s before midnight: the clock wraps at sample 150
    stamps = [(start + k / RATE) % 86400 for k in range(N)]
    clock = [f"{int(s // 3600):02d}:{int(s // 60 % 60):02d}:{s % 60:06.3f}" for s in stamps]
    rows = [f"{c},{a:.6f},{b:.6f}" for c, a, b in zip(clock, u, y)]
    path = tmp_path / "logger.csv"
    path.write_text("Logger 7, channel list\nTime,Drive,Tip\n" + "\n".join(rows) + "\n", encoding="utf-8")
    rec = Recording.load(path, columns="input=Drive,output=Tip,time=Time")
    # written to the ms, so read as jittered and rebuilt as a grid; a day lost at midnight would be 86400 s
    np.testing.assert_allclose(rec.t - rec.t[0], np.arange(N) / RATE, atol=1e-3)
    assert rec.rate == pytest.approx(RATE, rel=1e-4)
    assert any("holds times of day, read as seconds after 23:59:55" in note for note in rec.notes), rec.notes
    plain = tmp_path / "plain.csv"
    plain.write_text("t,v_in,w\n" + "\n".join(rows) + "\n", encoding="utf-8")
    np.testing.assert_allclose(Recording.load(plain).w, y, atol=1e-6)  # unmapped, the project's own names
    assert table_start([["Logger 7"], ["Time", "Drive", "Tip"], *(r.split(",") for r in rows[:3])]) == 1
