"""Issue 33: `rig record` never replaces the user's recording unless it succeeded.

The rows stream into ``rec.partial.csv`` and are renamed onto ``--out`` (with
the sidecar) only when the recording is complete and valid. Through the real
command line on the virtual rig (emulated board on a pty, virtual camera):

- a board that resets mid-stream over an existing ``rec.csv`` (and a previous
  ``rec.partial.csv``) leaves both byte for byte, keeps what was recorded in
  ``rec.partial-2.csv``, exit 2, one line naming it;
- a full disk (a fake writer: ENOSPC after some rows, the cut row and the
  sidecar's fsync too) names the file it could not write, keeps the whole rows
  before it in the partial file, and leaves nothing under the output's name;
  full from the start, it leaves nothing at all;
- a full disk at the final rename (fsync of the finished files) changes nothing
  at ``rec.csv`` and says where the complete recording is.
"""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path

import pytest

import hybrid
import rig._emulator
import rig._files
import rig._record
from rig.cli import main

ARGV = ["record", "--virtual", "--drive", "sine", "--duration", "2", "--speed", "3"]
ENOSPC = os.strerror(errno.ENOSPC)


def snapshot(folder: Path) -> dict:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def _one_line(capsys) -> str:
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("rig: error: ") and "Traceback" not in err[0], err
    return err[0]


def _users_files(folder: Path) -> Path:
    out = folder / "rec.csv"
    out.write_text("t,v_in,w\n0,0,1.5\n")
    (folder / "rec.csv.json").write_text('{"good": true}\n')
    return out


def test_a_board_reset_mid_record_keeps_the_users_file_and_the_rows_elsewhere(tmp_path, capsys, monkeypatch):
    class Resets(rig._emulator.EmulatedBoard):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self.fault_at = (30, lambda board: board.reset())

    monkeypatch.setattr(rig._emulator, "EmulatedBoard", Resets)
    out = _users_files(tmp_path)
    (tmp_path / "rec.partial.csv").write_text("an earlier partial recording\n")
    before = snapshot(tmp_path)
    assert main([*ARGV, "--out", str(out)]) == 2
    err = _one_line(capsys)
    partial = tmp_path / "rec.partial-2.csv"
    assert "reset during the stream" in err
    assert f"is kept in {partial} (+ .json); {out} was left as it was" in err
    after = snapshot(tmp_path)
    assert {name: after[name] for name in before} == before  # byte for byte, the earlier partial too
    assert sorted(set(after) - set(before)) == ["rec.partial-2.csv", "rec.partial-2.csv.json"]
    meta = json.loads(after["rec.partial-2.csv.json"])
    loaded = hybrid.Recording.load(partial)  # the hybrid commands warn that it ends early (they said nothing)
    rows = len(loaded)
    assert meta["partial_of"] == str(out) and meta["status"] == "interrupted" and meta["complete"] is False
    assert any("incomplete" in note and "reset during the stream" in note for note in loaded.notes), (
        loaded.notes
    )
    assert meta["rows"] == rows >= 10 and f"({rows} rows)" in err


class _Disk:
    """A disk that fills up after `rows` lines of the CSV: the next line is cut, every later write and
    fsync (the sidecar's, through hybrid's staged writes) fails with ENOSPC."""

    def __init__(self, monkeypatch, rows: int):
        self.room, self.full = rows, False
        real_open, real_fsync = open, os.fsync

        def fsync(fd):
            if self.full:
                raise OSError(errno.ENOSPC, ENOSPC)
            return real_fsync(fd)

        disk = self

        class Filling:
            def __init__(self, *args, **kwargs):
                self.handle = real_open(*args, **kwargs)

            def write(self, text):
                if disk.room <= 0 and not disk.full:
                    self.handle.write(text[: len(text) // 2])  # what fitted
                    self.handle.flush()
                    disk.full = True
                if disk.full:
                    raise OSError(errno.ENOSPC, ENOSPC)
                disk.room -= text.count("\n")
                return self.handle.write(text)

            def flush(self):
                if disk.full:
                    raise OSError(errno.ENOSPC, ENOSPC)
                self.handle.flush()

            def close(self):
                self.handle.close()

        monkeypatch.setattr(rig._record, "open", Filling, raising=False)  # the CSV's writer
        monkeypatch.setattr(os, "fsync", fsync)


def test_a_full_disk_mid_record_names_the_file_and_keeps_the_whole_rows(tmp_path, capsys, monkeypatch):
    _Disk(monkeypatch, rows=15)  # the header and 14 rows fit
    out = _users_files(tmp_path)
    before = snapshot(tmp_path)
    assert main([*ARGV, "--out", str(out)]) == 2
    err = _one_line(capsys)
    partial = tmp_path / "rec.partial.csv"
    assert err == (
        f"rig: error: cannot write {partial}: {ENOSPC} (after 14 rows); "
        f"what was recorded (14 rows) is kept in {partial} (its sidecar rec.partial.csv.json "
        f"could not be updated: {ENOSPC}); {out} was left as it was"
    ), err
    after = snapshot(tmp_path)
    assert {name: after[name] for name in before} == before  # nothing under the output's name
    assert sorted(set(after) - set(before)) == ["rec.partial.csv", "rec.partial.csv.json"]  # no temporary
    text = after["rec.partial.csv"].decode()
    assert text.endswith("\n") and text.count("\n") == 15  # the cut row is cut off
    assert len(hybrid.Recording.load(partial)) == 14
    assert json.loads(after["rec.partial.csv.json"])["partial_of"] == str(out)


def test_a_disk_full_from_the_start_leaves_nothing(tmp_path, capsys, monkeypatch):
    _Disk(monkeypatch, rows=0)
    out = _users_files(tmp_path)
    before = snapshot(tmp_path)
    assert main([*ARGV, "--out", str(out)]) == 2
    err = _one_line(capsys)
    assert f"cannot write recording '{tmp_path / 'rec.partial.csv'}' ({ENOSPC}); nothing was recorded" in err
    assert snapshot(tmp_path) == before


def test_a_full_disk_at_the_rename_leaves_the_users_file_and_says_where_the_recording_is(
    tmp_path, capsys, monkeypatch
):
    def full(path):
        raise OSError(errno.ENOSPC, ENOSPC)

    monkeypatch.setattr(rig._files, "_sync", full)
    out = _users_files(tmp_path)
    before = snapshot(tmp_path)
    assert main([*ARGV, "--out", str(out)]) == 2
    err = _one_line(capsys)
    partial = tmp_path / "rec.partial.csv"
    assert err.startswith(
        f"rig: error: cannot write {out} (and {out}.json): {ENOSPC}; the complete recording ("
    )
    assert err.endswith(f"rows) is kept in {partial} (+ .json); {out} was left as it was"), err
    after = snapshot(tmp_path)
    assert {name: after[name] for name in before} == before
    assert sorted(set(after) - set(before)) == ["rec.partial.csv", "rec.partial.csv.json"]
    meta = json.loads(after["rec.partial.csv.json"])
    assert meta["complete"] is True and meta["rows"] == len(hybrid.Recording.load(partial)) >= 50


@pytest.mark.parametrize("flag", ["--camera", "--calibration"])
def test_an_output_that_is_an_input_is_refused_before_anything_is_written(tmp_path, capsys, flag):
    source = tmp_path / "v.avi"
    source.write_bytes(b"the user's input")
    argv = ["record", "--drive", "sine", "--duration", "2", "--out", str(source)]
    argv += (
        ["--port", "/dev/ttyNO_SUCH", "--camera", str(source), "--clamp", "1,1", "--mm-per-px", "0.1"]
        if flag == "--camera"
        else ["--virtual", "--calibration", str(source)]
    )
    assert main(argv) == 2
    assert f"output '{source}' is the input '{source}'" in _one_line(capsys)
    assert snapshot(tmp_path) == {"v.avi": b"the user's input"}


# --- a new lab user's mistakes (a helper's trial of the lab workflow) --------------------------------


def test_a_sidecar_path_that_is_a_folder_is_refused_before_recording_and_the_users_file_kept(
    tmp_path, capsys
):
    """It was found at the rename, after the CSV had replaced the user's file, and said it had not."""
    out = tmp_path / "rec.csv"
    out.write_text("precious\n")
    (tmp_path / "rec.csv.json").mkdir()
    assert main([*ARGV, "--out", str(out)]) == 2
    assert "rec.csv.json is a folder" in _one_line(capsys)
    assert out.read_text() == "precious\n" and sorted(p.name for p in tmp_path.iterdir()) == [
        "rec.csv",
        "rec.csv.json",
    ]


def test_a_scene_that_shows_no_strip_is_refused_not_written_as_a_complete_recording(tmp_path, capsys):
    """A clamp outside the picture before the board plays; inside, but off the strip: no frame tracked."""
    out = tmp_path / "rec.csv"
    assert main([*ARGV, "--clamp", "9999,9999", "--out", str(out)]) == 2
    line = _one_line(capsys)
    assert "outside the 320x240 picture" in line and "nothing was recorded" in line, line
    assert list(tmp_path.iterdir()) == []  # not even an empty partial file
    assert main([*ARGV, "--clamp", "200,200", "--out", str(out)]) == 2  # w was 0 throughout, "complete"
    line = _one_line(capsys)
    assert "no frame showed the strip" in line and "rec.partial.csv" in line, line
    assert not out.exists()
    assert json.loads((tmp_path / "rec.partial.csv.json").read_text())["tracked_frames"] == 0


def test_a_drive_the_dac_cannot_play_is_refused_whether_generated_or_from_a_file(tmp_path, capsys):
    """--amplitude 5 was held at the ±3 V rails without a word (every sample), where a file was refused."""
    out = tmp_path / "rec.csv"
    argv = "record --virtual --drive prbs --amplitude 5 --duration 2".split()
    assert main([*argv, "--out", str(out)]) == 2
    line = _one_line(capsys)
    assert "--amplitude 5" in line and "[-3, 3] V" in line and "smaller --amplitude" in line, line
    assert list(tmp_path.iterdir()) == []


def test_a_drive_file_is_played_as_written_or_refused(tmp_path, capsys):
    """--rate/--amplitude were ignored with a file, a units row of mV played as volts."""
    drive = tmp_path / "d.csv"
    drive.write_text(
        "t,v_in\ns,mV\n" + "".join(f"{k / 10:g},{v}\n" for k, v in enumerate([0, 500, 1000, -800] * 5))
    )
    out = tmp_path / "rec.csv"
    assert main(["record", "--virtual", "--drive-file", str(drive), "--rate", "30", "--out", str(out)]) == 2
    assert "--rate is for --drive" in _one_line(capsys)
    assert (
        main(["record", "--virtual", "--drive-file", str(drive), "--amplitude", "1", "--out", str(out)]) == 2
    )
    assert "--amplitude is for --drive" in _one_line(capsys)
    assert main(["record", "--virtual", "--speed", "3", "--drive-file", str(drive), "--out", str(out)]) == 0
    capsys.readouterr()
    played = hybrid.Recording.load(out).v_in
    assert played.max() == pytest.approx(1.0, abs=2e-3) and played.min() == pytest.approx(-0.8, abs=2e-3)
    drive.write_text("t,v_in\ns,counts\n0,0\n0.1,500\n")
    assert main(["record", "--virtual", "--drive-file", str(drive), "--out", str(tmp_path / "x.csv")]) == 2
    assert "'counts'" in _one_line(capsys)
    drive.write_text("time,voltage\n0,0\n0.1,0.5\n")
    assert main(["record", "--virtual", "--drive-file", str(drive), "--out", str(tmp_path / "x.csv")]) == 2
    line = _one_line(capsys)
    assert "name them exactly t and v_in" in line and "--columns" not in line, line  # rig record has none


def test_a_second_recording_to_the_same_out_is_refused_while_the_first_runs(tmp_path, capsys):
    """Both said 'wrote' and one recording was lost; the lock of the hybrid commands now covers rig record."""
    out = tmp_path / "rec.csv"
    (tmp_path / "rec.csv.lock").write_text(f"{os.getpid()}\n")  # a live process holds it
    assert main([*ARGV, "--out", str(out)]) == 2
    assert "is writing" in _one_line(capsys) and not out.exists()
