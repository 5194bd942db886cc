"""Issue 33: no command replaces a file the user had unless it succeeded; a full disk names the file.

- `rig track` that fails over an existing ``wk.csv`` leaves it byte for byte and
  keeps what it read in ``wk.partial.csv`` (then ``wk.partial-2.csv``: a
  previous partial output is not replaced either), exit 2, one line naming it;
- a full disk (a writer that raises ENOSPC) while `rig track` writes leaves
  the previous output, no temporary and no partial file, and names the file;
- a lock whose pid cannot be written (full disk) is removed: the next run is
  not blocked.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path

import cv2
import numpy as np
from rig_labvideo import LabVideo, write_video

from hybrid.cli import main as hybrid_main
from rig._scene import Scene
from rig.cli import main as rig_main


def snapshot(folder: Path) -> dict:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def full_disk(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def _noise_video(path: Path, frames: int = 12) -> None:
    rng = np.random.default_rng(0)
    write_video(
        path,
        [
            cv2.GaussianBlur(rng.integers(0, 255, (240, 320, 3), dtype=np.uint8), (5, 5), 2)
            for _ in range(frames)
        ],
    )


def test_a_failed_track_keeps_the_users_file_and_what_it_read_elsewhere(tmp_path, capsys):
    video, out = tmp_path / "noise.avi", tmp_path / "wk.csv"
    _noise_video(video)
    out.write_text("t,w,quality\n0,1.5,1\n")
    (tmp_path / "wk.csv.json").write_text('{"good": true}\n')
    before = snapshot(tmp_path)
    argv = ["track", str(video), "--clamp", "160,20", "--mm-per-px", "0.1", "--out", str(out)]
    for partial in ("wk.partial.csv", "wk.partial-2.csv"):
        assert rig_main(argv) == 2
        err = capsys.readouterr().err.splitlines()
        assert len(err) == 1 and err[0].startswith("rig: error: no strip leaves the clamp"), err
        assert f"kept in {tmp_path / partial} (+ .json); {out} was left as it was" in err[0]
        rows = (tmp_path / partial).read_text().splitlines()
        assert rows[0] == "t,w,quality" and len(rows) == 13 and all(r.endswith(",nan,0") for r in rows[1:])
        assert '"partial_of"' in (tmp_path / (partial + ".json")).read_text()
    after = snapshot(tmp_path)
    assert {k: after[k] for k in before} == before  # the user's wk.csv and its sidecar, byte for byte
    assert sorted(set(after) - set(before)) == [
        "wk.partial-2.csv",
        "wk.partial-2.csv.json",
        "wk.partial.csv",
        "wk.partial.csv.json",
    ]


def test_rig_track_on_a_full_disk_names_the_file_and_changes_nothing(tmp_path, capsys, monkeypatch):
    video, out = tmp_path / "strip.avi", tmp_path / "wk.csv"
    lab = LabVideo(Scene(), seed=3)
    write_video(video, [lab.frame(w, k) for k, w in enumerate(np.linspace(-2, 2, 10))])
    out.write_text("previous\n")
    before = snapshot(tmp_path)
    monkeypatch.setattr(os, "fsync", full_disk)
    argv = ["track", str(video), "--clamp", "40,120", "--mm-per-px", "0.1", "--axis", "0", "--out", str(out)]
    assert rig_main(argv) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith(
        f"rig: error: cannot write {out} (and {out}.json): No space left"
    )
    assert snapshot(tmp_path) == before  # no temporary, no partial file, the previous output
    # a run that fails on a full disk: its problem, and why nothing was kept
    _noise_video(video)
    before = snapshot(tmp_path)
    argv[argv.index("--axis") + 1] = "90"
    assert rig_main(argv) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "what was read could not be kept either: cannot write" in err[0]
    assert "wk.partial.csv" in err[0] and snapshot(tmp_path) == before


def test_a_lock_whose_pid_cannot_be_written_never_blocks_the_next_run(tmp_path, capsys, monkeypatch):
    out = tmp_path / "rec.csv"
    real_write = os.write

    def write(fd, data):  # the disk fills up just as the lock's pid is written
        if os.path.exists(f"/proc/self/fd/{fd}") and os.readlink(f"/proc/self/fd/{fd}").endswith(".lock"):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real_write(fd, data)

    monkeypatch.setattr(os, "write", write)
    argv = ["simulate", "--drive", "sine", "--duration", "2", "--out", str(out)]
    assert hybrid_main(argv) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and f"cannot write the lock file {out}.lock (No space left on device)" in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no lock left behind, nothing written
    monkeypatch.setattr(os, "write", real_write)
    assert hybrid_main(argv) == 0 and out.exists()  # the next run is not blocked
    assert not Path(f"{out}.lock").exists()
