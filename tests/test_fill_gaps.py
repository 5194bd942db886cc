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
