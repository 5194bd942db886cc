"""Dropped frames: `load_mapped(..., fill_gaps=N)` and `--fill-gaps N` fill short gaps by straight lines.

A camera that drops a frame now and then writes a time column with steps of two
frames there. Refused by default (a gap); asked to, the loader puts the missing
frames back on the gap's own grid and draws every column straight across. The
reference is numpy's `np.interp` on the samples kept, and the grid the file had
before its frames were dropped.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from hybrid import InputError
from hybrid.data._mapping import load_mapped

RATE = 30.0
DROPPED = [100, 200, 201, 400]  # one frame, two in a row, one


def _write(path, dropped=DROPPED, t_of=None):
    n = 600
    t = np.arange(n) / RATE if t_of is None else t_of(np.arange(n))
    v = np.repeat(np.random.default_rng(0).uniform(-1.0, 1.0, n // 20), 20)
    w = np.sin(2 * np.pi * 0.7 * t) + 0.1 * v
    keep = np.setdiff1d(np.arange(n), dropped)
    np.savetxt(
        path, np.c_[t[keep], v[keep], w[keep]], delimiter=",", header="time,u,y", comments="", fmt="%.10f"
    )
    return t, v, w, keep


def test_filled_frames_lie_on_straight_lines_between_their_neighbours(tmp_path):
    path = tmp_path / "dropped.csv"
    t, v, w, keep = _write(path)
    record = load_mapped(path, input="u", output="y", time="time", fill_gaps=2)
    assert record.n == len(t)
    np.testing.assert_allclose(record.t, t, atol=1e-9)  # the grid before the frames were dropped
    np.testing.assert_allclose(record.v_in[keep], v[keep], atol=1e-9)  # measured samples as read
    np.testing.assert_allclose(record.w[keep], w[keep], atol=1e-9)
    for column, truth in ((record.v_in, v), (record.w, w)):
        np.testing.assert_allclose(column[DROPPED], np.interp(t[DROPPED], t[keep], truth[keep]), atol=1e-9)
    assert record.metadata["filled"] == {"samples": DROPPED, "gaps": 3, "frames": 4}
    assert any(
        "4 missing frame(s) in 3 gap(s) filled by straight lines (--fill-gaps 2)" in n for n in record.notes
    )


def test_without_filling_a_gap_is_refused_and_the_message_offers_it(tmp_path):
    path = tmp_path / "dropped.csv"
    _write(path)
    with pytest.raises(InputError, match=r"frames are missing there.*--fill-gaps N; fill_gaps=N in Python"):
        load_mapped(path, input="u", output="y", time="time")


@pytest.mark.parametrize(
    ("dropped", "t_of", "fill", "says"),
    [
        (
            DROPPED,
            None,
            1,
            r"2 missing frames, more than --fill-gaps 1 .*or fill up to 2 frames \(--fill-gaps 2\)",
        ),
        (
            [],
            lambda k: (k + 1.5 * (k >= 300)) / RATE,
            2,
            r"2.5 steps long, no whole number of missing frames",
        ),
        (list(range(300, 312)), None, 10, r"12 missing frames, more than --fill-gaps 10"),
    ],
)
def test_a_gap_that_is_not_a_few_whole_frames_is_refused_with_one_line(tmp_path, dropped, t_of, fill, says):
    path = tmp_path / "gap.csv"
    _write(path, dropped, t_of)
    with pytest.raises(InputError, match=says) as error:
        load_mapped(path, input="u", output="y", time="time", fill_gaps=fill)
    assert "\n" not in str(error.value) and "cut the recording at the gap" in str(error.value)


@pytest.mark.parametrize("bad", [0, 11, 1.5, True, "2"])
def test_a_fill_gaps_outside_its_range_is_refused(tmp_path, bad):
    path = tmp_path / "dropped.csv"
    _write(path)
    with pytest.raises(InputError, match="fill_gaps="):
        load_mapped(path, input="u", output="y", time="time", fill_gaps=bad)


def test_the_command_line_fills_with_its_flag_and_refuses_without(tmp_path):
    path = tmp_path / "dropped.csv"
    _write(path)
    base = [
        sys.executable,
        "-m",
        "hybrid.cli",
        "fit",
        str(path),
        "--input",
        "u",
        "--output",
        "y",
        "--time",
        "time",
    ]
    fit = [
        "--model",
        "physics",
        "--physics",
        "lti:1",
        "--max-steps",
        "2",
        "--quiet",
        "--out",
        str(tmp_path / "m.eqx"),
    ]
    refused = subprocess.run(base + fit, capture_output=True, text=True, check=False)
    assert refused.returncode == 2 and "--fill-gaps N" in refused.stderr and "Traceback" not in refused.stderr
    filled = subprocess.run(base + fit + ["--fill-gaps", "2"], capture_output=True, text=True, check=False)
    assert filled.returncode == 0, filled.stderr[-2000:]
    assert "hybrid: warning:" in filled.stderr and "4 missing frame(s) in 3 gap(s)" in filled.stderr
    bad = subprocess.run(base + fit + ["--fill-gaps", "0"], capture_output=True, text=True, check=False)
    assert bad.returncode == 2 and "--fill-gaps: must be from 1 to 10, got 0" in bad.stderr


def test_without_a_time_column_there_is_nothing_to_fill_and_the_notes_say_so(tmp_path):
    path = tmp_path / "dropped.csv"
    _write(path)
    evenly = load_mapped(path, input="u", output="y", rate=RATE, fill_gaps=2)
    assert evenly.t.size == 600 - len(DROPPED) and "filled" not in evenly.metadata
    assert any("filled nothing" in note and "--time COLUMN" in note for note in evenly.notes)
    plain = load_mapped(path, input="u", output="y", rate=RATE)
    assert not any("fill" in note for note in plain.notes)


# --------------------------------------------------------------------------- missing values (NaN, empty cells)

LOST = {"y": [40, 41, 42, 120, 300], "u": [200, 201]}  # a tracker lost the tip 3 frames, then 1, then 1


def _lost(path, lost=LOST, dropped=()):
    """A record with the cells of `lost` (column -> samples) missing, as NaN or empty cells, in a .csv, a
    tab-separated .txt or an .npz; rows of `dropped` left out. Returns (t, u, y) before either."""
    n = 400
    t = np.arange(n) / RATE
    u = np.repeat(np.random.default_rng(1).uniform(-1.0, 1.0, n // 20), 20)
    y = np.sin(2 * np.pi * 0.7 * t) + 0.1 * u
    columns = {"time": t, "u": u.copy(), "y": y.copy()}
    for name, samples in lost.items():
        columns[name][samples] = np.nan
    keep = np.setdiff1d(np.arange(n), dropped)
    if path.suffix == ".npz":
        np.savez(path, **{k: v[keep] for k, v in columns.items()})
        return t, u, y
    delimiter = "\t" if path.suffix == ".txt" else ","
    rows = [delimiter.join(columns)]
    for k in keep:
        cells = [f"{columns[c][k]:.10f}" for c in columns]
        if k % 2:  # every other lost cell left empty (the last of a tab-separated line too: a trailing
            # tab), the others 'nan' as a tracker writes it
            cells = ["" if c == "nan" else c for c in cells]
        rows.append(delimiter.join(cells))
    path.write_text("\n".join(rows) + "\n")
    return t, u, y


@pytest.mark.parametrize("suffix", [".csv", ".txt", ".npz"])
def test_missing_values_lie_on_straight_lines_between_their_neighbours(tmp_path, suffix):
    path = tmp_path / f"lost{suffix}"
    t, u, y = _lost(path)
    record = load_mapped(path, input="u", output="y", time="time", fill_gaps=3)
    assert record.n == len(t)
    for column, truth, name in ((record.v_in, u, "u"), (record.w, y, "y")):
        lost = LOST[name]
        kept = np.setdiff1d(np.arange(len(t)), lost)
        np.testing.assert_allclose(column[kept], truth[kept], atol=1e-9)  # measured values as read
        np.testing.assert_allclose(column[lost], np.interp(t[lost], t[kept], truth[kept]), atol=1e-9)
    assert record.metadata["filled"] == {
        "samples": [40, 41, 42, 120, 200, 201, 300],
        "runs": 4,
        "values": {"v_in": [200, 201], "w": [40, 41, 42, 120, 300]},
    }
    said = "2 missing value(s) in 1 run(s) of the input, at " + (
        "samples 200, 201 (2 in all)" if suffix == ".npz" else "lines 202, 203 (samples 200, 201; 2 in all)"
    )
    assert any(
        said in note and "5 missing value(s) in 3 run(s) of the output" in note for note in record.notes
    )
    assert any("filled by straight lines (--fill-gaps 3)" in note for note in record.notes)


def test_missing_values_without_a_time_column_are_filled_at_the_rate(tmp_path):
    path = tmp_path / "lost.csv"
    t, u, y = _lost(path)
    record = load_mapped(path, input="u", output="y", rate=RATE, fill_gaps=3)
    lost = LOST["y"]
    kept = np.setdiff1d(np.arange(len(t)), lost)
    np.testing.assert_allclose(record.w[lost], np.interp(t[lost], t[kept], y[kept]), atol=1e-9)
    assert not any("filled nothing" in note for note in record.notes)


def test_missing_values_beside_dropped_frames_are_filled_on_one_line_through_the_rest(tmp_path):
    """A frame dropped right after a lost value: both are on the line through the measured neighbours (the
    values are filled by time first, then the gap), and metadata['filled'] counts each kind."""
    path = tmp_path / "both.csv"
    t, u, y = _lost(path, {"y": [120]}, dropped=[121, 250])
    record = load_mapped(path, input="u", output="y", time="time", fill_gaps=1)
    np.testing.assert_allclose(record.t, t, atol=1e-9)
    filled = [120, 121, 250]
    kept = np.setdiff1d(np.arange(len(t)), filled)
    np.testing.assert_allclose(record.w[filled], np.interp(t[filled], t[kept], y[kept]), atol=1e-9)
    assert record.metadata["filled"] == {
        "samples": filled,
        "gaps": 2,
        "frames": 2,
        "runs": 1,
        "values": {"w": [120]},
    }
    assert any(
        "2 missing frame(s) in 2 gap(s) and 1 missing value(s) in 1 run(s) of the output, at line 122" in note
        for note in record.notes
    )


@pytest.mark.parametrize(
    ("lost", "fill", "says"),
    [
        (
            {"y": [40, 41, 42]},
            2,
            r"has 3 missing values in a row in column 'y' \(mapped as output\) from line 42 \(sample 40\), more "
            r"than --fill-gaps 2 \(fill_gaps=2\) fills: fix them, or cut the recording there \(--range A:B\), or "
            r"fill up to 3 in a row \(--fill-gaps 3\)",
        ),
        (
            {"u": list(range(100, 112)), "y": [40, 41, 42]},
            2,
            r"3 missing values in a row in column 'y'.* \(2 such runs in all\): fix them, or cut the recording "
            r"there \(--range A:B\)$",
        ),
        (
            {"y": [0, 1]},
            3,
            r"has 2 missing value\(s\) in column 'y' \(mapped as output\) from its first sample, at line 2 "
            r"\(sample 0\): .*none comes before them; fix them, or leave those samples out \(--range 2:400\)",
        ),
        (
            {"u": [399]},
            3,
            r"1 missing value\(s\) in column 'u' \(mapped as input\) up to its last sample, at line 401 "
            r"\(sample 399\): .*none comes after them; .*\(--range 0:399\)",
        ),
        (
            {"y": list(range(400))},
            3,
            r"has no value in column 'y' \(mapped as output\): all 400 samples are missing",
        ),
        (
            {"time": [50]},
            3,
            r"in column 'time' \(mapped as time\) at line 52 \(sample 50\): every value of a mapped column must "
            r"be a finite number; fix those cells or delete those lines$",
        ),
    ],
)
def test_missing_values_that_cannot_be_filled_are_refused_with_one_line(tmp_path, lost, fill, says):
    path = tmp_path / "lost.csv"
    _lost(path, lost)
    with pytest.raises(InputError, match=says) as error:
        load_mapped(path, input="u", output="y", time="time", fill_gaps=fill)
    assert "\n" not in str(error.value)


def test_a_run_at_the_start_of_a_range_is_refused_with_a_range_that_keeps_its_end(tmp_path):
    """Within --range 100:350, missing values at its first samples: the range offered starts after them and
    still stops at 350, where the user's did."""
    path = tmp_path / "lost.csv"
    _lost(path, {"y": [100, 101]})
    with pytest.raises(InputError, match=r"from its first sample, .*\(--range 102:350\)$"):
        load_mapped(path, input="u", output="y", time="time", fill_gaps=3, sample_range="100:350")


def test_the_command_line_fills_missing_values_with_its_flag_and_refuses_them_without(tmp_path):
    path = tmp_path / "lost.csv"
    _lost(path)
    base = [sys.executable, "-m", "hybrid.cli", "fit", str(path), "--input", "u", "--output", "y"]
    fit = ["--time", "time", "--model", "physics", "--physics", "lti:1", "--max-steps", "2", "--quiet"]
    fit += ["--out", str(tmp_path / "m.eqx")]
    refused = subprocess.run(base + fit, capture_output=True, text=True, check=False)
    assert refused.returncode == 2 and "Traceback" not in refused.stderr, refused.stderr[-2000:]
    assert "(lines 42, 43, 44, 122, 202, ...: 7 lines have such a cell)" in refused.stderr
    assert "--fill-gaps N (fill_gaps=N) fills them" in refused.stderr and not (tmp_path / "m.eqx").exists()
    short = subprocess.run(base + fit + ["--fill-gaps", "2"], capture_output=True, text=True, check=False)
    lines = short.stderr.strip().splitlines()
    assert short.returncode == 2 and len(lines) == 1 and "more than --fill-gaps 2" in lines[0], short.stderr
    assert not (tmp_path / "m.eqx").exists()
    filled = subprocess.run(base + fit + ["--fill-gaps", "3"], capture_output=True, text=True, check=False)
    assert filled.returncode == 0, filled.stderr[-2000:]
    assert (
        "hybrid: warning:" in filled.stderr
        and "5 missing value(s) in 3 run(s) of the output" in filled.stderr
    )
    assert (tmp_path / "m.eqx").exists()


@pytest.mark.parametrize("suffix", [".npz", ".csv"])
def test_a_file_in_the_projects_columns_points_at_the_filling_and_is_filled_with_it(tmp_path, suffix):
    """An .npz (or .csv) with t, v_in, w needs no mapping: its NaN in w was refused by the Recording's own
    check, without a word of --fill-gaps; asked to, it is filled as a mapped file's is."""
    from hybrid import Recording

    t = np.arange(200) / RATE
    v = np.repeat([0.0, 1.0], 100)
    w = np.cos(t) + v
    lost = w.copy()
    lost[[50, 51]] = np.nan
    path = tmp_path / f"lost{suffix}"
    if suffix == ".npz":
        np.savez(path, t=t, v_in=v, w=lost)
    else:
        np.savetxt(path, np.c_[t, v, lost], delimiter=",", header="t,v_in,w", comments="", fmt="%.10f")
    with pytest.raises(
        InputError,
        match=r"(non-finite values|missing values \(empty or non-finite cells\)) in column 'w' at .*--fill-gaps N \(fill_gaps=N\)",
    ):
        Recording.load(path)
    record = Recording.load(path, fill_gaps=2)
    kept = np.setdiff1d(np.arange(200), [50, 51])
    np.testing.assert_allclose(record.w[[50, 51]], np.interp(t[[50, 51]], t[kept], w[kept]), atol=1e-9)
    assert record.metadata["filled"] == {"samples": [50, 51], "runs": 1, "values": {"w": [50, 51]}}


def test_a_jittered_clock_is_one_clock_with_its_dropped_frames_filled(tmp_path):
    """A probe's 50 Hz timestamps, each up to 0.2 of a step off its grid (the docs absorb a quarter), were
    refused as "non-uniform time … did the frame rate change?" (two neighbours 0.4 of a step closer than
    the median: a rule of its own), and with frames dropped, "1.74 steps long, no whole number of missing
    frames" for a one-frame gap. Jittered either side, a gap is whole where every time lies near one grid
    with its frames counted; a clock that slips half a step at its gap is still refused."""
    jitter = np.random.default_rng(7).uniform(-0.2, 0.2, 600)
    path = tmp_path / "jittered.csv"
    t, v, w, keep = _write(path, [], lambda k: (k + jitter) / RATE)
    record = load_mapped(path, input="u", output="y", time="time")
    np.testing.assert_allclose(record.t, np.arange(600) / RATE + np.mean(jitter) / RATE, atol=0.02 / RATE)
    t, v, w, keep = _write(path, DROPPED, lambda k: (k + jitter) / RATE)
    record = load_mapped(path, input="u", output="y", time="time", fill_gaps=2)
    assert record.n == 600 and record.metadata["filled"] == {"samples": DROPPED, "gaps": 3, "frames": 4}
    np.testing.assert_allclose(
        record.t, np.arange(600) / RATE + np.mean(jitter[keep]) / RATE, atol=0.02 / RATE
    )
    np.testing.assert_allclose(record.w[keep], w[keep], atol=1e-9)  # measured samples as read
    _write(path, [], lambda k: (k + 0.1 * jitter + 0.5 * (k >= 300)) / RATE)  # slips half a step at 300
    with pytest.raises(InputError, match=r"no whole number of missing frames|of a step off the closest"):
        load_mapped(path, input="u", output="y", time="time", fill_gaps=2)
