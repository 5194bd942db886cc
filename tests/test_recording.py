"""Recording: validation, exact file round trips, splits, and every input error."""

import json

import numpy as np
import pytest
import scipy.io

from hybrid import InputError
from hybrid.data._loaders import sidecar
from hybrid.data._recording import Recording
from hybrid.data._split import Split


def _recording(n=100, rate=30.0, extra=True, **metadata):
    rng = np.random.default_rng(0)
    t = np.arange(n) / rate
    channels = {"current": rng.normal(size=n), "temp_C": 20 + rng.random(n)} if extra else {}
    metadata = {
        "source": "synthetic",
        "strip": {"length_mm": 30.0, "width_mm": 5.0},
        "note": [1, "a"],
        **metadata,
    }
    return Recording(t, 2 * np.sin(t), rng.normal(size=n) / 3, channels, metadata)


def _write(path, text):
    path.write_text(text)
    return path


# ------------------------------------------------------------------ basics


def test_properties_and_defaults():
    rec = Recording.from_arrays(v_in=np.zeros(60), w=np.arange(60.0), rate=30.0)
    assert len(rec) == rec.n == 60
    assert rec.dt == pytest.approx(1 / 30) and rec.rate == pytest.approx(30.0)
    assert rec.duration == pytest.approx(2.0)
    assert rec.metadata["units"] == {"t": "s", "v_in": "V", "w": "mm"}
    assert "source" in rec.metadata
    assert rec.t.dtype == np.float64 and not rec.w.flags.writeable
    assert rec.extra == {}


def test_from_arrays_with_t_and_offset():
    rec = Recording.from_arrays(v_in=[0, 1, 2], w=[0, 1, 2], rate=10.0, t0=5.0)
    np.testing.assert_allclose(rec.t, [5.0, 5.1, 5.2])
    rec = Recording.from_arrays(t=[0, 1, 2], v_in=[0, 1, 2], w=[0, 1, 2])
    assert rec.rate == 1.0
    with pytest.raises(InputError, match="exactly one of t and rate"):
        Recording.from_arrays(t=[0, 1, 2], v_in=[0, 1, 2], w=[0, 1, 2], rate=1.0)
    with pytest.raises(InputError, match="positive number of Hz"):
        Recording.from_arrays(v_in=[0, 1, 2], w=[0, 1, 2], rate=0.0)


def test_inputs_are_copied():
    w = np.arange(5.0)
    rec = Recording.from_arrays(v_in=np.zeros(5), w=w, rate=1.0)
    w[0] = 99.0
    assert rec.w[0] == 0.0


def test_float_rounding_of_time_is_accepted():
    t = np.round(np.arange(300) / 30.0, 9)  # nanosecond text precision
    rec = Recording(t, np.zeros(300), np.zeros(300))
    assert rec.rate == pytest.approx(30.0)


# --------------------------------------------------------------- round trips


@pytest.mark.parametrize("suffix", [".csv", ".npz", ".mat"])
def test_round_trip_is_exact(tmp_path, suffix):
    rec = _recording()
    path = rec.save(tmp_path / f"run{suffix}")
    loaded = Recording.load(path)
    assert loaded == rec
    for name in ("t", "v_in", "w"):
        np.testing.assert_array_equal(getattr(loaded, name), getattr(rec, name))
    assert list(loaded.extra) == ["current", "temp_C"]
    for name, values in rec.extra.items():
        np.testing.assert_array_equal(loaded.extra[name], values)
    assert loaded.metadata == rec.metadata
    assert loaded.name == str(path)


def test_round_trip_without_extras(tmp_path):
    rec = _recording(extra=False)
    for suffix in (".csv", ".npz", ".mat"):
        assert Recording.load(rec.save(tmp_path / f"plain{suffix}")) == rec


def test_csv_layout_and_sidecar(tmp_path):
    path = _recording(n=5).save(tmp_path / "run.csv")
    assert path.read_text().splitlines()[0] == "t,v_in,w,current,temp_C"
    assert sidecar(path).name == "run.csv.json"
    assert json.loads(sidecar(path).read_text())["source"] == "synthetic"


def test_csv_comments_blank_lines_and_no_sidecar(tmp_path):
    path = _write(
        tmp_path / "hand.csv", "# camera run 3\nt, v_in, w, i\n\n0,1,2,3\n# pause\n0.5,1,2,3\n1.0,1,2.5,3\n"
    )
    rec = Recording.load(path)
    np.testing.assert_array_equal(rec.w, [2.0, 2.0, 2.5])
    assert list(rec.extra) == ["i"]
    assert rec.metadata["source"] == str(path)
    assert rec.metadata["units"]["w"] == "mm"


def test_npz_and_mat_from_other_tools(tmp_path):
    np.savez(tmp_path / "other.npz", t=np.arange(4.0), v_in=np.ones(4), w=np.zeros(4), current=np.arange(4.0))
    rec = Recording.load(tmp_path / "other.npz")
    assert list(rec.extra) == ["current"]
    scipy.io.savemat(
        tmp_path / "other.mat", {"t": np.arange(4.0)[None], "v_in": np.ones(4), "w": np.zeros(4)}
    )
    assert Recording.load(tmp_path / "other.mat").n == 4


# --------------------------------------------------------------- split


def test_default_split_matches_the_paper():
    rec = _recording(n=1000)
    split = rec.split()
    assert isinstance(split, Split)
    assert (split.train.n, split.test.n, split.validation.n) == (300, 500, 200)
    assert split.slices == {"train": slice(0, 300), "test": slice(300, 800), "validation": slice(800, 1000)}
    np.testing.assert_array_equal(np.concatenate([split.train.w, split.test.w, split.validation.w]), rec.w)
    assert split.train.t[-1] < split.test.t[0] < split.test.t[-1] < split.validation.t[0]
    np.testing.assert_array_equal(split.test.extra["current"], rec.extra["current"][300:800])
    assert split.test.metadata["split"] == "test"
    assert split.test.metadata["segment"] == {"start": 300, "stop": 800}
    assert split["validation"] is split.validation
    assert [name for name, _ in split.items()] == ["train", "test", "validation"]


def test_custom_split():
    rec = _recording(n=200)
    split = rec.split(fractions=(0.6, 0.2, 0.2), order=("validation", "train", "test"))
    assert split.slices == {"validation": slice(0, 120), "train": slice(120, 160), "test": slice(160, 200)}
    np.testing.assert_array_equal(split.train.w, rec.w[120:160])
    assert [name for name, _ in split.items()] == ["validation", "train", "test"]


def test_uneven_split_covers_every_sample():
    rec = _recording(n=101)
    split = rec.split()
    assert sum(s.stop - s.start for s in split.slices.values()) == 101
    assert split.slices["train"].stop == split.slices["test"].start


@pytest.mark.parametrize(
    "fractions, order, phrase",
    [
        ((0.5, 0.5, 0.5), ("train", "test", "validation"), "sum to 1.5"),
        ((0.5, 0.6, -0.1), ("train", "test", "validation"), "not all positive"),
        ((0.5, 0.5, 0.0), ("train", "test", "validation"), "not all positive"),
        ((0.5, 0.5), ("train", "test", "validation"), "2 fractions for 3 parts"),
        ((0.3, 0.5, 0.2), ("train", "test", "test"), "not a permutation"),
        (("a", 0.5, 0.2), ("train", "test", "validation"), "not numbers"),
    ],
)
def test_bad_split(fractions, order, phrase):
    with pytest.raises(InputError) as error:
        _recording().split(fractions, order)
    assert phrase in str(error.value)


def test_split_too_short():
    with pytest.raises(InputError, match="too short to split"):
        _recording(n=5).split()


def test_segment():
    rec = _recording(n=50)
    part = rec.segment(slice(10, 30)).segment(slice(5, 10))
    np.testing.assert_array_equal(part.w, rec.w[15:20])
    assert part.metadata["segment"] == {"start": 15, "stop": 20}
    with pytest.raises(InputError, match="step 1"):
        rec.segment(slice(0, 10, 2))
    with pytest.raises(InputError, match="at least 2"):
        rec.segment(slice(10, 11))


# --------------------------------------------------------------- errors


def test_shorter_than_window():
    rec = Recording.from_arrays(v_in=np.zeros(40), w=np.zeros(40), rate=30.0, name="x")
    assert rec.check_length(40) is rec
    with pytest.raises(InputError) as error:
        rec.check_length(60)
    assert str(error.value) == (
        "recording 'x' has 40 samples but the model's input window needs at least 60: "
        "record longer or use a shorter window (--window)"
    )


def test_a_file_with_one_project_name_misspelt_is_pointed_at_its_own_columns(tmp_path):
    """A header typo (v_inn) beside the project's own w and a w_true: the hint mapped output=w_true (the
    noise-free truth of `hybrid simulate`'s file), not the w the file names exactly."""
    path = tmp_path / "typo.csv"
    path.write_text("t,v_inn,w,w_true\n" + "".join(f"{k / 10},{k % 2},{k},{k}\n" for k in range(8)))
    with pytest.raises(InputError) as caught:
        Recording.load(path)
    assert "--columns input=v_inn,output=w --time t" in str(caught.value), caught.value
    # a drive named exactly beside an output of another name: the drive keeps its name
    other = tmp_path / "other.csv"
    other.write_text("t,v_in,displacement_mm\n" + "".join(f"{k / 10},{k % 2},{k}\n" for k in range(8)))
    with pytest.raises(InputError) as caught:
        Recording.load(other)
    assert "--columns input=v_in,output=displacement_mm --time t" in str(caught.value), caught.value
    # a name close to the drive's takes it before the columns' order does (a verifier's t,w_true,v_inn,w
    # was offered input=w_true)
    from hybrid.data._loaders import mapping_example

    assert (
        mapping_example(["t", "w_true", "v_inn", "w"], time="t") == "--columns input=v_inn,output=w --time t"
    )
    assert mapping_example(["t", "w_ref", "v_in_cmd", "w"], time="t").startswith("--columns input=v_in_cmd,")
    assert (
        mapping_example(["t", "w_true", "v_inn"], time="t") == "--columns input=v_inn,output=w_true --time t"
    )
    # a time named with its unit after an underscore, as scripts write it (a probe's t_min was offered
    # "--rate HZ (or --time COLUMN)"), whatever the unit's length
    assert mapping_example(["t_min", "v_in", "w"]) == "--columns input=v_in,output=w --time t_min"
    assert mapping_example(["time_ms", "v_in", "w"]).endswith("--time time_ms")
    assert mapping_example(["t", "v_in", "w_true"], time="t") == "--columns input=v_in,output=w_true --time t"


def test_missing_columns_csv(tmp_path):
    path = _write(tmp_path / "a.csv", "t,V_in,w\n0,1,2\n1,1,2\n")
    with pytest.raises(InputError, match=r"missing column\(s\) v_in \(found 't', 'V_in', 'w'\)"):
        Recording.load(path)


def test_missing_arrays_npz_and_mat(tmp_path):
    np.savez(tmp_path / "a.npz", t=np.arange(3.0), w=np.zeros(3))
    with pytest.raises(InputError, match=r"missing array\(s\) v_in"):
        Recording.load(tmp_path / "a.npz")
    scipy.io.savemat(tmp_path / "a.mat", {"t": np.arange(3.0), "v_in": np.zeros(3)})
    with pytest.raises(InputError, match=r"missing variable\(s\) w"):
        Recording.load(tmp_path / "a.mat")


def test_missing_column_in_arrays():
    with pytest.raises(InputError, match="missing column 'w'"):
        Recording(np.arange(3.0), np.zeros(3), None)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_arrays(bad):
    w = np.zeros(10)
    w[[3, 4]] = bad
    with pytest.raises(InputError) as error:
        Recording.from_arrays(v_in=np.zeros(10), w=w, rate=1.0, name="x")
    assert "non-finite values in column 'w' at samples 3, 4 (2 in all)" in str(error.value)


def test_non_finite_csv_names_file_lines(tmp_path):
    path = _write(tmp_path / "a.csv", "# header next\nt,v_in,w\n0,1,2\n1,nan,2\n2,1,inf\n")
    with pytest.raises(
        InputError, match=r"missing values \(empty or non-finite cells\) in column 'v_in' at line 4 "
    ):
        Recording.load(path)


def test_non_finite_extra_channel():
    with pytest.raises(InputError, match="column 'current'"):
        Recording(np.arange(3.0), np.zeros(3), np.zeros(3), {"current": [0, np.nan, 0]})


def test_time_not_increasing():
    with pytest.raises(InputError, match="repeats the time 1 s at sample 2"):
        Recording(np.array([0.0, 1.0, 1.0, 2.0]), np.zeros(4), np.zeros(4))
    with pytest.raises(InputError, match="time going back .* at sample 1 .*sort the lines by time"):
        Recording(np.array([3.0, 2.0, 1.0]), np.zeros(3), np.zeros(3))


def test_time_not_uniform():
    t = np.arange(20) / 30.0
    t[12:] += 1 / 30.0  # one dropped frame before row 12: a gap, said where it is
    with pytest.raises(InputError, match=r"gap in time at sample 12 \(t = 0.433333 s\)"):
        Recording(t, np.zeros(20), np.zeros(20))
    t = np.concatenate([np.arange(10) / 30.0, 9 / 30.0 + np.arange(1, 11) / 25.0])  # 30, then 25 fps
    with pytest.raises(
        InputError,
        match=r"non-uniform time: the steps first change at sample 10 \(t = 0.34 s\), 0.04 s against 0.0333333 s "
        r"before \(10 such steps\), and sample 9 \(t = 0.3 s\) is 0.45 of a step off the closest uniform grid",
    ):
        Recording(t, np.zeros(20), np.zeros(20))


def test_length_mismatch():
    with pytest.raises(InputError, match=r"different lengths \(t=4, v_in=4, w=3\)"):
        Recording(np.arange(4.0), np.zeros(4), np.zeros(3))
    with pytest.raises(InputError, match="current=5"):
        Recording(np.arange(4.0), np.zeros(4), np.zeros(4), {"current": np.zeros(5)})


def test_too_few_samples():
    with pytest.raises(InputError, match="at least 2 samples"):
        Recording(np.zeros(1), np.zeros(1), np.zeros(1))


def test_not_a_vector_and_not_numeric():
    with pytest.raises(InputError, match="not a vector"):
        Recording(np.zeros((2, 2)), np.zeros(2), np.zeros(2))
    with pytest.raises(InputError, match="non-numeric values in column 'v_in'"):
        Recording(np.arange(2.0), ["a", "b"], np.zeros(2))


def test_bad_extra_names_and_metadata():
    args = (np.arange(3.0), np.zeros(3), np.zeros(3))
    with pytest.raises(InputError, match="reserved"):
        Recording(*args, {"w": np.zeros(3)})
    with pytest.raises(InputError, match="comma"):
        Recording(*args, {"a,b": np.zeros(3)})
    with pytest.raises(InputError, match="not JSON-able"):
        Recording(*args, {}, {"when": object()})


def test_mat_needs_matlab_names(tmp_path):
    rec = Recording(np.arange(3.0), np.zeros(3), np.zeros(3), {"2nd probe": np.zeros(3)})
    with pytest.raises(InputError, match="not MATLAB variable names"):
        rec.save(tmp_path / "a.mat")
    assert Recording.load(rec.save(tmp_path / "a.csv")) == rec


def test_unknown_suffix(tmp_path):
    with pytest.raises(InputError, match=r"unknown suffix '\.txt': use \.csv, \.npz, \.mat"):
        Recording.load(_write(tmp_path / "a.txt", "t,v_in,w\n"))
    with pytest.raises(InputError, match="unknown suffix"):
        _recording().save(tmp_path / "a.xlsx")


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        Recording.load(tmp_path / "nope.csv")


def test_unwritable_path(tmp_path):
    with pytest.raises(InputError, match="cannot write"):
        _recording().save(tmp_path / "no" / "such" / "dir.npz")


def test_non_numeric_cell(tmp_path):
    path = _write(tmp_path / "a.csv", "t,v_in,w\n0,1,2\n1,1,2\n2,oops,2\n")
    with pytest.raises(InputError, match=r"non-numeric cell 'oops' in column 'v_in' at line 4 \(sample 2\)"):
        Recording.load(path)
    path = _write(tmp_path / "b.csv", "t,v_in,w\n0,1,2\n1,,2\n")
    with pytest.raises(
        InputError, match=r"missing values \(empty .*\) in column 'v_in' at line 3 \(sample 1\)"
    ):
        Recording.load(path)
    # a probe's nan at line 1002 and empty cells at 2002-2003: the message named line 2002 alone
    path = _write(tmp_path / "c.csv", "t,v_in,w\n0,1,2\n1,1,nan\n2,1,2\n3,1,\n4,1,\n5,1,2\n")
    with pytest.raises(InputError, match=r"in column 'w' at lines 3, 5, 6 \(samples 1, 3, 4; 3 in all\)"):
        Recording.load(path)
    path = _write(tmp_path / "d.csv", "t,v_in,w\n0,1,2\n1,,2\n2,x,2\n3,y,2\n")  # text beside a missing value
    with pytest.raises(
        InputError, match=r"non-numeric cell 'x' in column 'v_in' at line 4 \(sample 2\) \(2 lines"
    ):
        Recording.load(path)


@pytest.mark.parametrize(
    "text, phrase",
    [
        ("", "is empty"),
        ("# only a comment\n\n", "no header or data"),
        ("t,v_in,w\n", "no data lines"),
        ("t,v_in,w\n0,1\n", "2 cells at line 2"),
        ("t,v_in,w,w\n0,1,2,3\n", "more than once"),
        ("t,,w\n0,1,2\n", "missing column(s) v_in (found 't', an unnamed one, 'w')"),
        ("t,v_in,w,,\n0,1,2,,\n1,1,2,5,\n", "3 columns in its header"),  # a trailing column with data
        (
            "t,v_in,w,T\n0,1,2,20\n1,1,2,oops\n2,1,2,21\n",
            "non-numeric cell 'oops' in column 'T' at line 3 (sample 1)",
        ),
    ],
)
def test_malformed_csv(tmp_path, text, phrase):
    with pytest.raises(InputError) as error:
        Recording.load(_write(tmp_path / "a.csv", text))
    assert phrase in str(error.value)


def test_spreadsheet_trailing_commas_and_text_columns_are_left_out(tmp_path):
    """An export with empty trailing columns and a column of labels reads as its signals, with a note."""
    plain = Recording.load(_write(tmp_path / "plain.csv", "t,v_in,w\n0,1,2\n0.5,-1,3\n1,0,4\n"))
    trailing = Recording.load(_write(tmp_path / "x.csv", "t,v_in,w,,\n0,1,2,,\n0.5,-1,3,,\n1,0,4,,\n"))
    np.testing.assert_array_equal(
        np.stack([trailing.t, trailing.v_in, trailing.w]), np.stack([plain.t, plain.v_in, plain.w])
    )
    assert trailing.extra == {} and trailing.notes == ()
    text = "time_stamp,t,v_in,w,T\n12:00:00,0,1,2,20\n12:00:01,0.5,-1,3,21\n12:00:02,1,0,4,22\n"
    labelled = Recording.load(_write(tmp_path / "y.csv", text))
    np.testing.assert_array_equal(labelled.w, plain.w)
    assert list(labelled.extra) == ["T"]  # the numeric extra channel is kept
    assert (
        len(labelled.notes) == 1 and "column 'time_stamp' holds text (e.g. '12:00:00')" in labelled.notes[0]
    )
    marker = Recording.load(_write(tmp_path / "m.csv", "t,v_in,w,event\n0,1,2,\n0.5,-1,3,1\n1,0,4,\n"))
    assert marker.extra == {} and "column 'event' holds mostly empty cells, not a signal" in marker.notes[0]


def test_unreadable_binary_files(tmp_path):
    for suffix in (".npz", ".mat"):
        with pytest.raises(InputError, match="not a readable"):
            Recording.load(_write(tmp_path / f"junk{suffix}", "not a binary file"))
    (tmp_path / "bytes.csv").write_bytes(b"t,v_in,w\n\xff\xfe\n")
    with pytest.raises(InputError, match="not UTF-8"):
        Recording.load(tmp_path / "bytes.csv")


def test_bad_sidecar(tmp_path):
    path = _recording(n=5).save(tmp_path / "a.csv")
    sidecar(path).write_text("{not json")
    with pytest.raises(InputError, match="unreadable metadata in 'a.csv.json'"):
        Recording.load(path)
    sidecar(path).write_text("[1, 2]")
    with pytest.raises(InputError, match="not a JSON object"):
        Recording.load(path)


def test_non_numeric_npz_array(tmp_path):
    np.savez(tmp_path / "a.npz", t=np.arange(3.0), v_in=np.array(["a", "b", "c"]), w=np.zeros(3))
    with pytest.raises(InputError, match="variable 'v_in' of type"):
        Recording.load(tmp_path / "a.npz")


def test_a_units_row_under_the_header_gives_the_units_and_the_time_scale(tmp_path):
    """A data logger's second header line: its units reach the metadata, a time in ms becomes seconds."""
    seconds = Recording.load(_write(tmp_path / "s.csv", "t,v_in,w\ns,V,mm\n0,1,2\n0.5,-1,3\n1,0,4\n"))
    assert seconds.metadata["units"] == {"t": "s", "v_in": "V", "w": "mm"}
    np.testing.assert_array_equal(seconds.w, [2.0, 3.0, 4.0])  # the first line of data is kept
    assert len(seconds.notes) == 1 and "units row (line 2)" in seconds.notes[0]
    ms = Recording.load(_write(tmp_path / "ms.csv", "t,v_in,w\n(ms),[V],(µm)\n0,1,2\n500,-1,3\n1000,0,4\n"))
    np.testing.assert_allclose(ms.t, [0.0, 0.5, 1.0])
    assert ms.metadata["units"] == {"t": "s", "v_in": "V", "w": "µm"}
    with pytest.raises(InputError, match="gives its time column the unit 'days'.*write one of s, ms"):
        Recording.load(_write(tmp_path / "d.csv", "t,v_in,w\ndays,V,mm\n0,1,2\n1,1,2\n"))
    with pytest.raises(
        InputError, match=r"non-numeric cell 'NA' in column 't' at line 2 \(sample 0\)"
    ):  # missing values, not units
        Recording.load(_write(tmp_path / "na.csv", "t,v_in,w\nNA,NA,NA\n0,1,2\n1,1,2\n"))
    plain = Recording.load(_write(tmp_path / "p.csv", "t,v_in,w\n0,1,2\n0.5,-1,3\n1,0,4\n"))
    assert plain.notes == () and plain.metadata["units"] == {"t": "s", "v_in": "V", "w": "mm"}


def test_a_t_column_of_date_times_is_read_in_seconds(tmp_path):
    text = (
        "t,v_in,w\n2026-12-01T10:00:00.000,1,2\n2026-12-01T10:00:00.500,-1,3\n2026-12-01T10:00:01.000,0,4\n"
    )
    rec = Recording.load(_write(tmp_path / "d.csv", text))
    np.testing.assert_allclose(rec.t, [0.0, 0.5, 1.0])
    assert rec.metadata["start_time"] == "2026-12-01T10:00:00"
    assert rec.notes == (
        f"recording '{tmp_path / 'd.csv'}': its time column holds date-times, read as seconds after 2026-12-01T10:00:00",
    )


@pytest.mark.parametrize(
    "suffix, words",
    [
        (".xls", r"an older or another spreadsheet's workbook: save the sheet as \.xlsx or as CSV"),
        (".ods", r"an older or another spreadsheet's workbook: save the sheet as \.xlsx or as CSV"),
        (".tsv", r"a text table is read with its columns mapped: --columns input=COLUMN"),
    ],
)
def test_a_workbook_or_tsv_says_what_to_save_it_as_or_how_to_map_it(tmp_path, suffix, words):
    with pytest.raises(InputError, match=f"unknown suffix '{suffix}'.*{words}"):
        Recording.load(_write(tmp_path / f"a{suffix}", "t,v_in,w\n0,1,2\n"))


def test_a_loggers_preamble_before_the_header_and_quoted_numbers_are_read(tmp_path):
    """An oscilloscope's export: device and date lines, then the header; and an export that quotes every cell."""
    text = "PicoScope 6 export\nDate: 2026-12-01\n\nt,v_in,w\n0,1,2\n0.5,-1,3\n1,0,4\n"
    rec = Recording.load(_write(tmp_path / "p.csv", text))
    np.testing.assert_array_equal(rec.w, [2.0, 3.0, 4.0])
    assert rec.notes == (
        f"recording '{tmp_path / 'p.csv'}': the 2 line(s) before its header (line 4) skipped",
    )
    quoted = Recording.load(_write(tmp_path / "q.csv", '"t","v_in","w"\n"0","1.5","2"\n"0.5","1","3"\n'))
    np.testing.assert_array_equal(quoted.v_in, [1.5, 1.0])
    with pytest.raises(InputError, match="missing column"):  # no header names them: the first line is named
        Recording.load(_write(tmp_path / "n.csv", "device X\ntime,u,y\n0,1,2\n"))
