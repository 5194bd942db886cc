"""Real files: mapping a lab's own columns onto a Recording (`hybrid.data._mapping`).

The two public benchmarks of ../shared/data (Cascaded Tanks, Silverbox) load with the
right lengths, rates and values (checked against a plain csv-module read); every option
works and both spellings of a mapping agree; every bad mapping is one InputError that
says what is wrong; 10⁶ rows load in well under 10 s.
"""

from __future__ import annotations

import csv
import json
import math
import pathlib

import numpy as np
import pytest
import scipy.io

from hybrid import InputError
from hybrid.data._loaders import sidecar
from hybrid.data._mapping import load_mapped, load_pair
from hybrid.data._mapping_options import parse_columns, parse_sample_range, parse_units
from hybrid.data._recording import Recording

DATA = pathlib.Path(__file__).resolve().parents[1].parent / "shared" / "data"
TANKS = DATA / "cascaded-tanks" / "dataBenchmark.csv"
SNLS = DATA / "silverbox" / "SNLS80mV.csv"
SCHROEDER = DATA / "silverbox" / "Schroeder80mV.csv"
SILVERBOX_HZ = 610.35

needs_data = pytest.mark.skipif(
    not (TANKS.is_file() and SNLS.is_file() and SCHROEDER.is_file()),
    reason=f"the benchmark files are not in {DATA} (../shared/data of the checkout)",
)


def _plain(path, *names):
    """The named columns read with the csv module alone: the reference the loader must match."""
    with open(path, newline="", encoding="utf-8") as handle:
        rows = list(csv.DictReader(handle))
    return [np.array([float(row[name]) for row in rows]) for name in names]


def _write(path, text, metadata=None):
    path.write_text(text)
    if metadata is not None:
        sidecar(path).write_text(json.dumps(metadata))
    return path


@pytest.fixture
def lab(tmp_path):
    """A small lab file: a time column in s, a drive, an output, a text column, a trailing comma."""
    t = np.arange(50) / 20.0
    lines = ['"time","u","y","note",'] + [
        f"{ti!r},{math.sin(ti)!r},{math.cos(ti)!r},ok {i}," for i, ti in enumerate(t.tolist())
    ]
    return _write(tmp_path / "lab.csv", "\n".join(lines) + "\n")


# ------------------------------------------------------------------ real benchmark files


@needs_data
def test_cascaded_tanks_estimation_and_validation():
    est = load_mapped(TANKS, input="uEst", output="yEst")
    assert est.n == 1024 and est.rate == pytest.approx(0.25)
    assert est.metadata["rate_hz"] == 0.25 and "'Ts'" in est.metadata["rate_from"]
    np.testing.assert_array_equal(est.t[:3], [0.0, 4.0, 8.0])
    u, y, u_val, y_val = _plain(TANKS, "uEst", "yEst", "uVal", "yVal")
    np.testing.assert_array_equal(est.v_in, u)
    np.testing.assert_array_equal(est.w, y)
    assert est.v_in[0] == 3.2567 and est.w[0] == 5.205 and est.w[-1] == y[-1]
    assert est.metadata["mapping"] == {"t": None, "v_in": "uEst", "w": "yEst"}
    estimation, validation = load_pair(
        TANKS,
        input="uEst",
        output="yEst",
        test_input="uVal",
        test_output="yVal",
        units={"v_in": "V", "w": "V"},
    )
    np.testing.assert_array_equal(estimation.w, est.w)
    assert estimation.name.endswith("(uEst -> yEst)") and validation.name.endswith("(uVal -> yVal)")
    assert validation.n == 1024 and validation.rate == pytest.approx(0.25)
    np.testing.assert_array_equal(validation.v_in, u_val)
    np.testing.assert_array_equal(validation.w, y_val)
    assert validation.v_in[0] == 0.97619 and validation.w[0] == 4.9728
    assert validation.metadata["units"] == {"t": "s", "v_in": "V", "w": "V"}
    assert load_mapped(TANKS, input="uVal", output="yVal") == load_mapped(
        TANKS, columns="input=uVal,output=yVal"
    )


@needs_data
def test_cascaded_tanks_rate_given_must_agree_with_ts():
    assert load_mapped(TANKS, input="uEst", output="yEst", rate=0.25).rate == pytest.approx(0.25)
    with pytest.raises(InputError, match=r"disagree.*'Ts' field \(4 s\).*0\.25 Hz.*1 Hz"):
        load_mapped(TANKS, input="uEst", output="yEst", rate=1.0)


@needs_data
def test_silverbox_with_rate_and_the_benchmark_ranges():
    whole = Recording.load(SNLS, input="V1", output="V2", rate=SILVERBOX_HZ)
    assert whole.n == 131072 and whole.rate == pytest.approx(SILVERBOX_HZ)
    v1, v2 = _plain(SNLS, "V1", "V2")
    np.testing.assert_array_equal(whole.v_in, v1)
    np.testing.assert_array_equal(whole.w, v2)
    assert (whole.v_in[0], whole.w[0]) == (0.0057756, 0.0093978)
    train, arrow = load_pair(
        SNLS,
        input="V1",
        output="V2",
        rate=SILVERBOX_HZ,
        sample_range="40650:127400",
        test_sample_range="100:40575",
    )
    assert (train.n, arrow.n) == (86750, 40475)
    assert train.metadata["segment"] == {"start": 40650, "stop": 127400}
    assert train.t[0] == pytest.approx(40650 / SILVERBOX_HZ)  # the file's clock is kept
    np.testing.assert_array_equal(train.w, v2[40650:127400])
    np.testing.assert_array_equal(arrow.v_in, v1[100:40575])
    with pytest.raises(
        InputError, match=r"no time column and no sampling rate: pass the rate in Hz \(--rate"
    ):
        load_mapped(SNLS, input="V1", output="V2")


@needs_data
def test_silverbox_schroeder_file_with_sparse_overload_columns():
    rec = load_mapped(SCHROEDER, columns="input=V1,output=V2", rate="610.35", units="v_in=V,w=V")
    assert rec.n == 131072
    v1, v2 = _plain(SCHROEDER, "V1", "V2")
    np.testing.assert_array_equal(rec.v_in, v1)
    assert (rec.v_in[0], rec.w[0], rec.w[-1]) == (0.005885, 0.033315, v2[-1])
    assert rec.metadata["units"]["w"] == "V"


# ------------------------------------------------------------------------- options


@pytest.mark.parametrize(
    "keywords, columns",
    [
        ({"input": "u", "output": "y", "time": "time"}, "t=time,v_in=u,w=y"),
        ({"input": "u", "output": "y", "time": "time"}, "time=time, input = u ,OUTPUT=y"),
        ({"input": "u", "output": "y", "time": "time"}, 'input="u",output="y",time=time'),
        ({"input": "u", "output": "y", "time": "time"}, {"time": "time", "input": "u", "OUTPUT": "y"}),
    ],
)
def test_both_spellings_give_the_same_recording(lab, keywords, columns):
    a = load_mapped(lab, **keywords)
    b = load_mapped(lab, columns=columns)
    c = Recording.load(lab, columns=columns)
    assert a == b == c and a.name == b.name
    assert a.rate == pytest.approx(20.0) and a.metadata["rate_from"].startswith("the time column")
    assert load_mapped(lab, columns="input=u", output="y", time="time") == a


def test_a_dict_of_column_numbers_maps_as_the_string_does(lab):
    """From Python a mapping is a dict; an int in it is a column's number, as ``input=1`` in the string."""
    by_name = load_mapped(lab, columns={"time": "time", "input": "u", "output": "y"})
    by_number = load_mapped(lab, columns={"t": 0, "v_in": 1, "w": 2})
    assert (
        by_number == load_mapped(lab, columns="t=0,v_in=1,w=2") == load_mapped(lab, input=1, output=2, time=0)
    )
    for channel in ("t", "v_in", "w"):
        np.testing.assert_array_equal(getattr(by_number, channel), getattr(by_name, channel))


def test_mapped_grammar_units_and_ranges_parse():
    assert parse_columns('input=uEst,output="level, V"') == {"v_in": "uEst", "w": "level, V"}
    assert parse_units("v_in=V,w=mm") == {"v_in": "V", "w": "mm"}
    assert parse_sample_range("40650:") == (40650, None)
    assert parse_sample_range(":40000") == (None, 40000)
    assert parse_sample_range(" 100 : 200 ") == (100, 200)
    assert parse_sample_range(slice(3, None)) == (3, None)


def test_quoted_name_with_a_comma_and_a_bom(tmp_path):
    path = _write(
        tmp_path / "q.csv", '\ufeff# exported by the rig\n\n"drive (V)","level, V"\n1,2\n3,4\n\n# end\n5,6\n'
    )
    rec = load_mapped(path, columns='input=drive (V),output="level, V"', rate=2)
    np.testing.assert_array_equal(rec.v_in, [1, 3, 5])
    np.testing.assert_array_equal(rec.w, [2, 4, 6])


@pytest.mark.parametrize(
    "text, expected", [("10:20", (10, 20)), ("45:", (45, 50)), (":7", (0, 7)), ("0:50", (0, 50))]
)
def test_sample_range_keeps_the_files_clock(lab, text, expected):
    start, stop = expected
    rec = load_mapped(lab, input="u", output="y", rate=20, sample_range=text)
    assert rec.n == stop - start
    assert rec.t[0] == pytest.approx(start / 20)
    np.testing.assert_allclose(rec.v_in, np.sin(np.arange(start, stop) / 20.0))
    assert rec.metadata.get("segment") == ({"start": start, "stop": stop} if expected != (0, 50) else None)
    timed = load_mapped(lab, input="u", output="y", time="time", sample_range=text)
    np.testing.assert_allclose(timed.t, rec.t)


def test_rate_fields_in_columns_and_sidecar_metadata(tmp_path):
    rows = "\n".join(f"{i},{i * i}," + ("1000" if i == 0 else "") for i in range(10))
    path = _write(tmp_path / "fs.csv", f"u,y,fs\n{rows}\n")
    assert load_mapped(path, input="u", output="y").rate == pytest.approx(1000.0)
    same = "\n".join(f"{i},{i * i},0.01" for i in range(10))  # a Ts repeated on every row
    assert load_mapped(
        _write(tmp_path / "ts.csv", f"u,y,Ts\n{same}\n"), input="u", output="y"
    ).rate == pytest.approx(100)
    meta = _write(tmp_path / "m.csv", "u,y\n1,2\n3,4\n5,7\n", {"rate_hz": 50.0, "units": {"y": "mm"}})
    rec = load_mapped(meta, input="u", output="y")
    assert rec.rate == pytest.approx(50.0) and rec.metadata["units"] == {"t": "s", "v_in": "V", "w": "mm"}
    varying = "\n".join(
        f"{i},{i * i},{i + 1}" for i in range(10)
    )  # a data column called rate: not a rate field
    with pytest.raises(InputError, match="--rate"):
        load_mapped(_write(tmp_path / "r.csv", f"u,y,rate\n{varying}\n"), input="u", output="y")


def test_units_default_and_given(lab):
    assert load_mapped(lab, input="u", output="y", rate=20).metadata["units"] == {
        "t": "s",
        "v_in": "V",
        "w": "a.u.",
    }
    rec = load_mapped(lab, input="u", output="y", time="time", units={"input": "mV", "w": "µm"})
    assert rec.metadata["units"] == {"t": "s", "v_in": "mV", "w": "µm"}


def test_time_column_in_milliseconds(tmp_path):
    rows = "\n".join(f"{i * 33.3:.1f},{i % 3},{i % 5}" for i in range(30))
    path = _write(tmp_path / "ms.csv", f"stamp,u,y\n{rows}\n")
    with pytest.raises(InputError, match="looks like milliseconds.*t=ms"):
        load_mapped(path, input="u", output="y", time="stamp")
    rec = load_mapped(path, input="u", output="y", time="stamp", units="t=ms")
    assert rec.rate == pytest.approx(1000 / 33.3) and rec.metadata["units"]["t"] == "s"


@pytest.mark.parametrize("step", [1, 5])
def test_a_unitless_whole_step_time_column_is_read_in_seconds_and_said(tmp_path, step):
    """A logger's millisecond counter at 1 kHz or 200 Hz: a probe's 1.5 Hz plant fitted at 0.0015 Hz, unsaid."""
    rows = "\n".join(f"{i * step},{i % 3},{i % 5}" for i in range(30))
    path = _write(tmp_path / "counter.csv", f"time,u,y\n{rows}\n")
    rec = load_mapped(path, input="u", output="y", time="time")
    assert rec.dt == pytest.approx(step)  # seconds, as documented: a slow logger's whole seconds are valid
    (note,) = [n for n in rec.notes if "has no unit" in n]
    assert f"steps by {step}: read in seconds" in note and "--units t=ms" in note
    for units in ("t=ms", "t=s"):  # said either way: no note
        said = load_mapped(path, input="u", output="y", time="time", units=units)
        assert not [n for n in said.notes if "has no unit" in n]
    fractional = _write(
        tmp_path / "seconds.csv", "time,u,y\n" + "\n".join(f"{i * 0.02:.2f},1,2" for i in range(30))
    )
    assert not load_mapped(fractional, input="u", output="y", time="time").notes


@pytest.mark.parametrize("rate", [0.1, 1.0, 100_000.0])
def test_rates_from_a_tenth_of_a_hertz_to_100_khz(lab, rate):
    rec = load_mapped(lab, input="u", output="y", rate=rate, sample_range="5:")
    assert rec.rate == pytest.approx(rate) and rec.t[0] == pytest.approx(5 / rate)


def test_npz_and_mat_files(tmp_path):
    u, y = np.linspace(0, 1, 40), np.linspace(1, 2, 40) ** 2
    np.savez(tmp_path / "a.npz", drive=u, out=y, metadata=json.dumps({"fs": 25.0}))
    rec = Recording.load(tmp_path / "a.npz", input="drive", output="out")
    assert rec.rate == pytest.approx(25.0)
    np.testing.assert_array_equal(rec.w, y)
    scipy.io.savemat(
        tmp_path / "b.mat",
        {"uEst": u[:, None], "yEst": y[:, None], "Ts": np.array([[4.0]]), "label": "not numeric"},
    )
    rec = load_mapped(tmp_path / "b.mat", input="uEst", output="yEst", sample_range="10:")
    assert rec.rate == pytest.approx(0.25) and rec.n == 30 and rec.t[0] == pytest.approx(40.0)
    with pytest.raises(
        InputError, match=r"has no variable 'yVal' for the output \(its variables: .*uEst.*\)"
    ):
        load_mapped(tmp_path / "b.mat", input="uEst", output="yVal")
    with pytest.raises(InputError, match="has no array 'y' for the output.*drive, out"):
        load_mapped(tmp_path / "a.npz", input="drive", output="y")
    np.savez(tmp_path / "c.npz", u=u, y=y[:30])
    with pytest.raises(InputError, match="input 'u' has 40, the output 'y' has 30 values"):
        load_mapped(tmp_path / "c.npz", input="u", output="y", rate=1)


def test_a_drive_without_output_and_plain_load_unchanged(lab, tmp_path):
    drive = Recording.load(lab, require_w=False, input="u", rate=20)
    assert not drive.w.any() and drive.metadata["mapping"]["w"] is None
    own = Recording.from_arrays(v_in=np.arange(5.0), w=np.arange(5.0) ** 2, rate=30.0)
    path = own.save(tmp_path / "own.csv")
    assert Recording.load(path) == own == Recording.load(path, input=None, rate=None)
    mapped = Recording.load(path, columns="t=t,v_in=v_in,w=w")
    np.testing.assert_array_equal(mapped.w, own.w)
    with pytest.raises(TypeError):
        Recording.load(path, inptu="v_in")


def test_a_million_rows_load(tmp_path):
    """10⁶ rows (a 1000-row block written 1000 times) load to the last sample.

    Their time (about 0.7 s here) is `benchmarks/long_record.py`'s, not a test's: no test passes or
    fails on the wall clock of a shared machine.
    """
    block = np.random.default_rng(0).normal(size=(1000, 3))
    text = "".join(f"{a!r},{b!r},{c!r},x\n" for a, b, c in block.tolist())
    path = tmp_path / "big.csv"
    with open(path, "w") as handle:
        handle.write("u,y,other,comment\n")
        for _ in range(1000):
            handle.write(text)
    rec = load_mapped(path, input="u", output="y", rate=100_000.0)
    assert rec.n == 1_000_000 and rec.duration == pytest.approx(10.0)
    assert rec.v_in[123_456] == block[456, 0] and rec.w[-1] == block[-1, 1]


# ------------------------------------------------------------------------ bad mappings


def _bad(path, match, **options):
    with pytest.raises(InputError, match=match) as caught:
        load_mapped(path, **options)
    assert "\n" not in str(caught.value)  # one line, as the CLI prints it
    return str(caught.value)


def test_a_misnamed_column_suggests_the_likely_one_not_the_time(tmp_path):
    """``--output pos`` on time,drive,position suggested ``--output time``: a prefix is a likely name."""
    path = tmp_path / "lab.csv"
    path.write_text("time,drive,position\n" + "".join(f"{k / 30:.4f},{k % 3},{k % 5}\n" for k in range(40)))
    message = _bad(path, "did you mean 'position'", time="time", input="drive", output="pos")
    assert "--output position" in message and "--output time" not in message
    # No likely name at all: the example is the file's last column for an output, its second for a drive.
    assert "--output position (" in _bad(path, "no column 'zz'", time="time", input="drive", output="zz")
    assert "--input drive (" in _bad(path, "no column 'qq'", time="time", input="qq", output="position")
    # A logger's name with a space and brackets is quoted as a shell needs it (pasted bare it was two
    # arguments, '[V]' a glob)
    logger = tmp_path / "logger.csv"
    logger.write_text(
        "Zeit,Heizspannung [V],Temperatur [C]\n" + "".join(f"{k},{k % 3},{k % 5}\n" for k in range(40))
    )
    message = _bad(logger, "did you mean 'Heizspannung", time="Zeit", input="Heiz", output="Temperatur [C]")
    assert "--input 'Heizspannung [V]' (" in message


@pytest.mark.parametrize(
    "options, match",
    [
        (
            {"input": "U", "output": "y"},
            r"no column 'U' for the input \(its columns: time, u, y, note\): .*did you mean 'u'\?",
        ),
        ({"input": "u", "output": "yy"}, r"no column 'yy' for the output.*did you mean 'y'"),
        ({"input": "u", "output": "u"}, "input and the output are the same column 'u'"),
        ({"input": "u", "output": "y", "time": "u"}, "column 'u' is mapped twice, as the input and the time"),
        ({"input": "u"}, r"no output column is named.*--output"),
        ({"output": "y"}, r"no input column is named.*--input"),
        ({"columns": "input=u", "input": "u", "output": "y"}, "input column is given twice"),
        ({"columns": "input=u,output"}, "entry 'output' without '='"),
        ({"columns": "drive=u,output=y"}, "names the role 'drive': the roles are input"),
        ({"columns": "input=u,output="}, "gives output an empty column"),
        ({"columns": "input=u,in=y"}, "names the role 'in'"),
        ({"columns": "input=u;output=y"}, "with two '=': separate the pairs with commas"),
        ({"columns": "input=u,v_in=y"}, "gives the input twice"),
        ({"columns": 'input="u,output=y'}, "unclosed"),
        ({"columns": " "}, "columns mapping ' ' is empty"),
        ({"columns": ["input=u", "output=y"]}, r"is not a string: give role=column pairs \(or a dict"),
        ({"columns": {"input": "u"}}, r"no output column is named"),
        ({"columns": {"input": "u", "drive": "y"}}, r"names the role 'drive'.*e\.g\. \{'input': 'uEst'"),
        ({"columns": {"input": "u", "output": 2.5}}, r"gives output the column 2\.5: give the column's name"),
        ({"columns": {}}, r"columns mapping \{\} is empty"),
        ({"input": 3.5, "output": "y"}, r"input column 3\.5 is not a name: .* \(or its number, from 0\)"),
        ({"input": "u", "output": "y", "rate": 0}, "not a positive number of Hz"),
        ({"input": "u", "output": "y", "rate": "fast"}, "not a positive number of Hz"),
        ({"input": "u", "output": "y", "rate": float("nan")}, "not a positive number of Hz"),
        (
            {"input": "u", "output": "y", "rate": 10.0, "time": "time"},
            r"disagree: the time column .* 20 Hz.* 10 Hz",
        ),
        ({"input": "u", "output": "y", "sample_range": "-5:"}, "negative bound"),
        ({"input": "u", "output": "y", "sample_range": "5"}, "is not start:stop"),
        ({"input": "u", "output": "y", "sample_range": "1:2:3"}, "is not start:stop"),
        ({"input": "u", "output": "y", "sample_range": "30:10"}, "holds 0 sample"),
        ({"input": "u", "output": "y", "sample_range": "10:11"}, "holds 1 sample"),
        ({"input": "u", "output": "y", "sample_range": "0:51"}, r"out of range.*has 50 samples \(0 to 49\)"),
        ({"input": "u", "output": "y", "sample_range": "50:"}, "out of range"),
        ({"input": "u", "output": "y", "sample_range": slice(0, 10, 2)}, "is not start:stop"),
        ({"input": "u", "output": "y", "units": {"x": "V"}}, "units names 'x'"),
        ({"input": "u", "output": "y", "units": {"w": ""}}, "non-empty label"),
        ({"input": "u", "output": "y", "rate": 1, "units": {"t": "ms"}}, "no time column is mapped"),
        ({"input": "u", "output": "y", "time": "time", "units": {"t": "fortnight"}}, "use one of s, ms"),
        ({"input": "u", "output": "y", "units": "w:mm"}, "without '='"),
        ({"input": "u", "output": "y", "name": ""}, "non-empty string"),
        (
            {"input": "u", "output": "note"},
            r"non-numeric cell 'ok 0' in column 'note' \(mapped as output\) at line 2 \(sample 0\)",
        ),
    ],
)
def test_every_bad_mapping_is_one_input_error(lab, options, match):
    _bad(lab, match, **options)


@pytest.mark.parametrize(
    "body, match",
    [
        (
            "u,y\n1,2\n3,\n5,6\n",
            r"empty cell \(a missing value\) in column 'y' \(mapped as output\) at line 3 \(sample 1\)",
        ),
        (
            "u,y\n1,2\n3,4\nx,6\n",
            r"non-numeric cell 'x' in column 'u' \(mapped as input\) at line 4 \(sample 2\)",
        ),
        (
            "u,y\n1,2\n\n# note\n3,nan\n",
            r"non-finite value 'nan' in column 'y' \(mapped as output\) at line 5 \(sample 1\)",
        ),
        (
            "u,y\n1,2\n3\n",
            r"has 1 cells at line 3 \(sample 1\) but 2 columns in its header \(a line cut short",
        ),
        ("u,y\n", "has a header but no data lines"),
        # the line of a bad cell in a ';' file with decimal commas, and under a units row
        (
            "u;y\n1,5;2\n3;x,5\n",
            r"non-numeric cell 'x 5' in column 'y' \(mapped as output\) at line 3 \(sample 1\)",
        ),
        (
            "u,y\nV,mm\n1,2\n3,x\n",
            r"non-numeric cell 'x' in column 'y' \(mapped as output\) at line 4 \(sample 1\)",
        ),
        ("u,y,u\n1,2,3\n", r"has 2 columns named 'u' \(columns 0, 2, counting from 0\).*--input 0"),
        # a mapped column past the end of a line in a file whose lines vary: numbered from 0, as --input 0
        ("u,x,y\n1,2,3\n4,5,6\n7,8\n", r"has 2 cells at line 4 \(sample 2\) but 3 columns"),
    ],
)
def test_bad_cells_name_the_column_and_the_line(tmp_path, body, match):
    _bad(_write(tmp_path / "bad.csv", body), match, input="u", output="y", rate=1)


def test_bad_files_and_pairs(tmp_path, lab):
    _bad(tmp_path / "missing.csv", "does not exist", input="u", output="y")
    _bad(tmp_path / "x.xls", "unknown suffix", input="u", output="y")
    (tmp_path / "latin.csv").write_bytes(b"u,y\n1,2\n\xe9,3\n")
    _bad(tmp_path / "latin.csv", "not UTF-8", input="u", output="y", rate=1)
    with pytest.raises(InputError, match="has no validation record.*test_input=.*--test-columns"):
        load_pair(lab, input="u", output="y", time="time")
    with pytest.raises(InputError, match="the validation record is the estimation record"):
        load_pair(lab, input="u", output="y", time="time", test_input="u")
    estimation, validation = load_pair(
        lab, columns="t=time,input=u,output=y", test_input="y", test_output="u"
    )
    assert validation.metadata["mapping"] == {"t": "time", "v_in": "y", "w": "u"}
    np.testing.assert_array_equal(validation.v_in, estimation.w)


def test_units_or_a_range_alone_map_a_file_that_has_the_standard_columns(tmp_path, lab):
    """--units / --range without --columns: a file with t, v_in, w maps them itself; a lab's names still ask."""
    t = np.arange(40) / 10.0
    lines = ["t,v_in,w"] + [f"{a!r},{math.sin(a)!r},{math.cos(a)!r}" for a in t.tolist()]
    path = _write(tmp_path / "plain.csv", "\n".join(lines) + "\n")
    rec = load_mapped(path, units={"w": "rad/s"}, sample_range="5:30")
    t_ref, v_ref, w_ref = _plain(path, "t", "v_in", "w")
    np.testing.assert_array_equal(rec.v_in, v_ref[5:30])
    np.testing.assert_array_equal(rec.w, w_ref[5:30])
    assert rec.rate == pytest.approx(10.0) and rec.metadata["units"]["w"] == "rad/s"
    assert rec.metadata["mapping"] == {"t": "t", "v_in": "v_in", "w": "w"}
    # time, u, y: which is the drive is the lab's to say, and the error offers a mapping of its names
    with pytest.raises(
        InputError, match=r"missing column\(s\) t, v_in, w .*e\.g\. --columns input=u,output=y"
    ):
        load_mapped(lab, units={"w": "mm"})


@pytest.mark.parametrize("name, sep", [("lab.csv", ","), ("lab.txt", "\t")])
def test_a_units_row_reaches_a_mapped_recording(tmp_path, name, sep):
    """Mapped columns under a units row: w's unit is the row's, a time column in ms is read in seconds.

    In a .csv and in a tab-separated .txt (a LabVIEW or DAQ export), which refused the row as a
    non-numeric cell."""
    rows = "".join(
        f"{1000 * i / 30:.6f}{sep}{np.sin(i / 9):.6f}{sep}{np.cos(i / 7):.6f}\n" for i in range(90)
    )
    path = _write(tmp_path / name, f"Time{sep}Drive{sep}Disp\nms{sep}V{sep}um\n" + rows)
    rec = load_mapped(path, input="Drive", output="Disp", time="Time")
    assert rec.rate == pytest.approx(30.0) and rec.metadata["units"] == {"t": "s", "v_in": "V", "w": "um"}
    np.testing.assert_allclose(rec.w[:2], [1.0, np.cos(1 / 7)], atol=1e-6)  # no data line was taken as units
    assert any("units read from its units row" in note for note in rec.notes), rec.notes
    given = load_mapped(path, input="Drive", output="Disp", time="Time", units="w=mm,t=ms")
    assert given.metadata["units"]["w"] == "mm"  # the flag wins over the row


def test_a_space_separated_tables_units_row_in_brackets_and_words_that_are_no_units(tmp_path):
    rows = "".join(f"{1000 * i / 30:.6f} {np.sin(i / 9):.6f} {np.cos(i / 7):.6f}\n" for i in range(90))
    spaced = _write(tmp_path / "lab.dat", "t u y\n(ms) [V] (mm)\n" + rows)
    rec = load_mapped(spaced, input="u", output="y", time="t")
    assert rec.rate == pytest.approx(30.0) and rec.metadata["units"] == {"t": "s", "v_in": "V", "w": "mm"}
    # words under the header are read as a units row, as in a CSV file: a time unit it cannot be is refused
    words = _write(tmp_path / "words.txt", "t u y\nfirst run here\n" + rows)
    _bad(words, "gives its time column the unit 'first'", input="u", output="y", time="t")


def test_a_semicolon_file_with_decimal_commas_maps_its_columns(tmp_path):
    path = _write(tmp_path / "eu.csv", "Zeit;Spannung;Weg\n0;1,5;-0,25\n0,5;2;1,5e-3\n1;-1,25;,5\n")
    rec = load_mapped(path, input="Spannung", output="Weg", time="Zeit")
    np.testing.assert_array_equal(rec.v_in, [1.5, 2.0, -1.25])
    np.testing.assert_array_equal(rec.w, [-0.25, 1.5e-3, 0.5])
    assert rec.rate == pytest.approx(2.0)
    # the note the docs promise (the commands print it as a warning)
    assert any("read as cells separated by ';' with decimal commas" in note for note in rec.notes)


def test_decimal_commas_with_thousands_separators_read_as_the_numbers_they_show(tmp_path):
    """A probe's German export: -1.089,759 µm was refused, quoted as '-1.089 759', a cell the file lacks."""
    text = "Zeit;Spannung;Weg\n0;1,5;-1.089,759\n0,5;2;12.345.678,5\n1;-1,25;1 089,25\n1,5;0;2\u00a0000,0\n"
    rec = load_mapped(_write(tmp_path / "eu.csv", text), input="Spannung", output="Weg", time="Zeit")
    np.testing.assert_array_equal(rec.w, [-1089.759, 12345678.5, 1089.25, 2000.0])
    (note,) = [n for n in rec.notes if "separated by ';'" in n]
    assert "with decimal commas (4 with thousands separators, dropped)" in note
    # a point with no comma is a point-decimal number, not a thousands separator; a group of two is no group
    assert (
        load_mapped(
            _write(tmp_path / "p.csv", "t;u;y\n0;1;1.089\n1;2;2\n"), input="u", output="y", time="t"
        ).w[0]
        == 1.089
    )
    with pytest.raises(InputError, match=r"non-numeric cell .* at line 2 "):
        load_mapped(_write(tmp_path / "q.csv", "t;u;y\n0;1;1.08,9\n1;2;2\n"), input="u", output="y", time="t")


def test_numbers_stored_as_text_with_decimal_commas_in_a_workbook_read_as_numbers(tmp_path):
    """A probe's .xlsx of text cells '0,000000' (a ';' CSV pasted into Excel): refused as '0 000000'."""
    import openpyxl

    book = openpyxl.Workbook()
    sheet = book.active
    sheet.append(["Zeit", "Spannung", "Weg"])
    for i in range(5):
        sheet.append([f"{i * 0.5}".replace(".", ","), f"{i},25", 1.5 * i])  # text, text, a number
    path = tmp_path / "text.xlsx"
    book.save(path)
    rec = load_mapped(path, input="Spannung", output="Weg", time="Zeit")
    np.testing.assert_array_equal(rec.v_in, [0.25, 1.25, 2.25, 3.25, 4.25])
    assert rec.rate == pytest.approx(2.0)
    assert any("10 cell(s) hold numbers stored as text with a decimal comma" in n for n in rec.notes), (
        rec.notes
    )


def test_a_mat_files_struct_fields_are_named_with_dots(tmp_path):
    """A lab's .mat keeps its signals in a struct: run.data.u, run.data.y and run.Ts map like variables."""
    import scipy.io

    t = np.arange(300) / 50.0
    u, y = np.sin(t), np.cos(3 * t)
    path = tmp_path / "lab.mat"
    scipy.io.savemat(
        path, {"run": {"data": {"u": u[:, None], "y": y[None, :]}, "Ts": 0.02, "note": "bench 3"}}
    )
    rec = load_mapped(path, input="run.data.u", output="run.data.y")
    np.testing.assert_array_equal(rec.v_in, u)
    np.testing.assert_array_equal(rec.w, y)
    assert rec.rate == pytest.approx(50.0) and "'run.Ts' field" in rec.metadata["rate_from"]
    message = _bad(path, "has no variable 'u' for the input", input="u", output="run.data.y")
    assert "did you mean 'run.data.u'?" in message and "run.data.u, run.data.y, run.Ts" in message


def test_a_time_column_of_date_times_is_read_in_seconds(tmp_path):
    """A logger's ISO 8601 time stamps: seconds after the first, which metadata['start_time'] keeps."""
    import datetime

    start = datetime.datetime(2026, 12, 1, 10, 0, 0)
    stamps = [(start + datetime.timedelta(seconds=k / 50)).isoformat(sep=" ") for k in range(100)]
    rows = "".join(f"{s},{np.sin(k / 20):.6f},{np.cos(k / 30):.6f}\n" for k, s in enumerate(stamps))
    path = _write(tmp_path / "log.csv", "timestamp,drive,pos\n" + rows)
    rec = load_mapped(path, input="drive", output="pos", time="timestamp")
    np.testing.assert_allclose(rec.t, np.arange(100) / 50, atol=1e-9)
    assert rec.metadata["start_time"] == "2026-12-01T10:00:00"
    _bad(
        path,
        "date-times in its time column 'timestamp'",
        input="drive",
        output="pos",
        time="timestamp",
        units="t=ms",
    )
    bad = _write(tmp_path / "bad.csv", "timestamp,drive,pos\n" + rows + "yesterday,1,2\n")
    _bad(
        bad,
        r"non-numeric cell 'yesterday' in column 'timestamp' \(mapped as time\) at line 102",
        input="drive",
        output="pos",
        time="timestamp",
    )


def test_an_oscilloscope_export_maps_below_its_preamble(tmp_path):
    """Preamble lines, ';' cells with decimal commas and a units row in ms: a PicoScope-style CSV as written."""
    body = "PicoScope 6\nDate: 2026-12-01\n\nTime;Channel A;Channel B\n(ms);(V);(mV)\n"
    body += "".join(
        f"{1000 * k / 30:.3f};{np.sin(k / 5):.4f};{np.cos(k / 7):.4f}\n".replace(".", ",") for k in range(60)
    )
    rec = load_mapped(
        _write(tmp_path / "scope.csv", body), input="Channel A", output="Channel B", time="Time"
    )
    assert rec.rate == pytest.approx(30.0, rel=1e-4) and rec.metadata["units"]["w"] == "mV"
    np.testing.assert_allclose(rec.w, [round(np.cos(k / 7), 4) for k in range(60)])
    assert any("the 2 line(s) before its header (line 4) skipped" in note for note in rec.notes), rec.notes


def test_units_a_mapped_file_gives_are_said_as_an_unmapped_files_units_row_is(tmp_path):
    """A logger's units row, or units in its column names, were read silently in a mapped file."""
    rows = "".join(f"{k},{k % 3},{k % 5}\n" for k in range(40))
    row = tmp_path / "row.csv"
    row.write_text("time,heater,temperature\ns,V,°C\n" + rows)
    rec = load_mapped(row, time="time", input="heater", output="temperature")
    assert rec.metadata["units"]["w"] == "°C"
    assert any("units read from its units row (or sidecar): input in V, output in °C" in n for n in rec.notes)
    named = tmp_path / "named.csv"
    named.write_text("time,heater [V],temperature [°C]\n" + rows)
    rec = load_mapped(named, time="time", input="heater [V]", output="temperature [°C]")
    assert any("units read from its column names: input in V, output in °C" in n for n in rec.notes)
    # given units: nothing read, nothing said
    rec = load_mapped(
        named, time="time", input="heater [V]", output="temperature [°C]", units={"v_in": "V", "w": "°C"}
    )
    assert not any("units read" in n for n in rec.notes)


@pytest.mark.parametrize(
    "step, says, unit, rate",
    [
        (
            1e6 / 30,
            r"looks like microseconds \(30 Hz if so; 0.03 Hz if milliseconds\).*--units t=us ",
            "us",
            30.0,
        ),
        (
            4000.0,
            r"milliseconds \(0.25 Hz if so\) or microseconds \(250 Hz\).*--units t=ms or t=us",
            "ms",
            0.25,
        ),
        (33.3, r"looks like milliseconds \(30.03 Hz if so\).*--units t=ms ", "ms", 1000 / 33.3),
    ],
)
def test_a_time_column_in_micro_or_milliseconds_is_told_by_its_step(tmp_path, step, says, unit, rate):
    """A camera's 30 Hz stamped in µs steps by 33 333: called milliseconds, `--units t=ms` as told
    gave 0.03 Hz without a word. Between 10³ and 10⁴ either may be: both are said."""
    rows = "\n".join(f"{i * step:.3f},{i % 3},{i % 5}" for i in range(30))
    path = _write(tmp_path / "stamped.csv", f"time,u,y\n{rows}\n")
    with pytest.raises(InputError, match=says):
        load_mapped(path, input="u", output="y", time="time")
    assert load_mapped(path, input="u", output="y", time="time", units=f"t={unit}").rate == pytest.approx(
        rate
    )


def test_units_alone_on_a_file_without_the_project_s_columns_name_what_it_lacks(tmp_path):
    """A probe's `hybrid diagnose stair.csv col.csv --units v_in=V,w=rad/s`, the second file's output
    named `speed`, was told "no input column is named: give the input's column": with only --units (or
    --rate, --range) given, a file is read by its own t, v_in, w, and where that fails the error is
    what the file lacks or holds (as without --units), not that no mapping was given."""
    t = np.arange(200) / 20.0
    lacking = tmp_path / "speed.csv"
    np.savetxt(lacking, np.c_[t, np.sin(t), np.cos(t)], delimiter=",", header="t,v_in,speed", comments="")
    with pytest.raises(
        InputError, match=r"missing column\(s\) w \(found 't', 'v_in', 'speed'\).*output=speed"
    ):
        load_mapped(lacking, units={"v_in": "V", "w": "rad/s"})
    holed = np.c_[t, np.sin(t), np.cos(t)]
    holed[50, 2] = np.nan
    standard = tmp_path / "hole.csv"
    np.savetxt(standard, holed, delimiter=",", header="t,v_in,w", comments="")
    with pytest.raises(InputError, match=r"non-finite value 'nan' in column 'w' .* line 52"):
        load_mapped(standard, units={"v_in": "V", "w": "rad/s"})
    without_time = tmp_path / "no_t.csv"
    np.savetxt(without_time, holed[:, 1:], delimiter=",", header="v_in,w", comments="")
    with pytest.raises(InputError, match=r"non-finite value 'nan' in column 'w'"):
        load_mapped(without_time, rate=20.0)
    holed[50, 2] = 0.0  # and a whole file reads as before
    np.savetxt(standard, holed, delimiter=",", header="t,v_in,w", comments="")
    assert load_mapped(standard, units={"v_in": "V", "w": "rad/s"}).metadata["units"]["w"] == "rad/s"
