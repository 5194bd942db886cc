"""`rig track` on damaged videos: lost frames keep their places in time, a short file is reported."""

import csv
import json

import cv2
import numpy as np
import pytest
from rig_labvideo import LabVideo, write_video

from rig._avi import open_mjpeg_avi, with_huffman_tables
from rig._camera import find_gaps
from rig._scene import Scene
from rig.cli import main

FRAMES = 60
SWEEP = 6.2 * np.sin(np.linspace(0, 4 * np.pi, FRAMES))  # mm: fast, so a 133 ms slip is millimetres
ARGS = ["--clamp", "40,120", "--mm-per-px", "0.1", "--axis", "0"]


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    """(path, bytes) of a 60-frame 320x240 MJPG AVI of a strip pointing right."""
    path = tmp_path_factory.mktemp("video") / "clean.avi"
    video = LabVideo(Scene(), seed=1)
    write_video(path, [video.frame(w, k) for k, w in enumerate(SWEEP)])
    return path, path.read_bytes()


def _track(tmp_path, data, name, capsys, suffix=".avi"):
    path, out = tmp_path / f"{name}{suffix}", tmp_path / f"{name}.csv"
    path.write_bytes(data)
    status = main(["track", str(path), *ARGS, "--out", str(out)])
    captured = capsys.readouterr()
    if status != 0:  # a failed run keeps what it read under another name, never at --out
        assert not out.exists() and f"kept in {out.with_name(name + '.partial.csv')}" in captured.err
        out = out.with_name(name + ".partial.csv")
    rows = list(csv.DictReader(out.open()))
    t = np.array([float(r["t"]) for r in rows])
    w = np.array([float(r["w"]) for r in rows])
    quality = np.array([int(r["quality"]) for r in rows])
    meta = json.loads(out.with_name(out.name + ".json").read_text())
    return status, captured, t, w, quality, meta


def _corrupt_middle(data: bytes, size: int = 20_000) -> bytes:
    damaged = bytearray(data)
    middle = len(damaged) // 2
    damaged[middle : middle + size] = (
        np.random.default_rng(0).integers(0, 256, size, dtype=np.uint8).tobytes()
    )
    return bytes(damaged)


def test_corrupted_avi_keeps_every_frame_at_its_time(tmp_path, clean, capsys):
    # 20 KB of noise mid-file destroys ~5 frames. OpenCV alone skipped them and kept t uniform:
    # every later frame 133+ ms early, w off by up to 5 mm on this sweep.
    status, captured, t, w, quality, meta = _track(tmp_path, _corrupt_middle(clean[1]), "corrupt", capsys)
    assert status == 0
    warning = captured.err.strip().splitlines()
    assert len(warning) == 1 and warning[0].startswith("rig: warning:") and "1 gap" in warning[0]
    info = meta["video_integrity"]
    assert info["frames_expected"] == FRAMES and meta["complete"] is False and meta["status"] == "gaps"
    (gap,) = info["gaps"]
    assert gap["missing"] >= 3 and len(t) + gap["missing"] == FRAMES
    assert gap["missing"] == len(info["damaged_frames"])
    frame = t * 30.0
    np.testing.assert_allclose(frame, np.round(frame), atol=1e-9)  # on the frame grid
    k = np.round(frame).astype(int)
    assert k[gap["after"] + 1] - k[gap["after"]] == gap["missing"] + 1
    assert quality[gap["after"]] == 0 and quality[gap["after"] + 1] == 0  # flagged either side
    good = quality == 1
    assert good.sum() == len(t) - 2
    assert np.max(np.abs(w[good] - SWEEP[k[good]])) <= 0.1  # each w at its own time


def test_truncated_avi_is_reported_and_kept(tmp_path, clean, capsys):
    data = clean[1][: len(clean[1]) // 2]
    status, captured, t, w, quality, meta = _track(tmp_path, data, "cut", capsys)
    assert status == 2
    err = captured.err
    assert err.startswith("rig: error: read ") and err.count("\n") == 1
    n = len(t)
    assert f"read {n} of {FRAMES} frames" in err and "only those were tracked" in err
    assert 20 <= n < FRAMES and quality.all()
    assert meta["complete"] is False and meta["status"] == "incomplete" and meta["rows"] == n
    assert meta["video_integrity"]["frames_missing_at_end"] == FRAMES - n
    np.testing.assert_allclose(t, np.arange(n) / 30.0)
    assert np.sqrt(np.mean((w - SWEEP[:n]) ** 2)) <= 0.05


def test_chunk_removed_without_index_is_flagged_not_guessed(tmp_path, clean, capsys):
    # 20 KB cut out of the middle: the index no longer matches and the walk resynchronises; the frames
    # after the cut have unknown places, so they are flagged and the command fails.
    data = clean[1]
    middle = len(data) // 2
    status, captured, t, w, quality, meta = _track(
        tmp_path, data[:middle] + data[middle + 20_000 :], "hole", capsys
    )
    assert status == 2 and "places in time of the last" in captured.err and captured.err.count("\n") == 1
    info = meta["video_integrity"]
    assert info["unplaced_frames"] > 0 and meta["complete"] is False
    assert not quality[info["first_unplaced_frame"] :].any()


def test_corrupted_mp4_gap_from_decoder_timestamps(tmp_path, capsys):
    path = tmp_path / "clean.mp4"
    video = LabVideo(Scene(), seed=2)
    write_video(path, [video.frame(w, k) for k, w in enumerate(SWEEP)])
    status, captured, t, w, quality, meta = _track(
        tmp_path, _corrupt_middle(path.read_bytes()), "c", capsys, suffix=".mp4"
    )
    info = meta["video_integrity"]
    assert info["time_base"].startswith("decoder timestamps") and info["decode_failures"] > 0
    assert len(info["gaps"]) >= 1 and "gap" in captured.err
    k = np.round(t * 30.0).astype(int)
    good = quality == 1
    assert np.max(np.abs(w[good] - SWEEP[k[good]])) <= 0.1
    lost = sum(g["missing"] for g in info["gaps"]) + (info["frames_missing_at_end"] or 0)
    assert len(t) + lost == FRAMES and status == (2 if info["frames_missing_at_end"] else 0)


def test_avi_reader_matches_opencv_on_a_clean_file(clean):
    avi = open_mjpeg_avi(clean[0])
    capture = cv2.VideoCapture(str(clean[0]))
    try:
        assert avi.fps == 30.0 and avi.expected == FRAMES and avi.indexed
        frames = list(avi.frames())
        assert [n for n, _ in frames] == list(range(FRAMES))
        for _, image in frames[:5]:
            ok, reference = capture.read()
            assert ok and np.mean(np.abs(image.astype(float) - reference)) < 2.0  # two JPEG decoders
    finally:
        avi.close()
        capture.release()


def test_jpeg_without_huffman_tables_gets_the_standard_ones():
    # Webcam MJPEG often leaves out the DHT segments (AVI1); the standard tables are implied.
    image = np.random.default_rng(3).integers(0, 255, (32, 48, 3), dtype=np.uint8)
    jpeg = bytes(cv2.imencode(".jpg", image)[1])
    stripped, pos = bytearray(jpeg[:2]), 2
    while jpeg[pos + 1] != 0xDA:
        length = int.from_bytes(jpeg[pos + 2 : pos + 4], "big")
        if jpeg[pos + 1] != 0xC4:
            stripped += jpeg[pos : pos + 2 + length]
        pos += 2 + length
    stripped = bytes(stripped + jpeg[pos:])
    assert b"\xff\xc4" not in stripped[: stripped.find(b"\xff\xda")]
    decoded = cv2.imdecode(np.frombuffer(with_huffman_tables(stripped), np.uint8), cv2.IMREAD_COLOR)
    np.testing.assert_array_equal(decoded, cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR))


def test_find_gaps():
    t = np.array([0, 1, 2, 5, 6, 8.4]) / 30.0
    gaps = find_gaps(t, 30.0)
    assert [(g["after"], g["missing"]) for g in gaps] == [(2, 2), (4, 1)]
    assert find_gaps(np.arange(10) / 30.0 + 0.001 * np.sin(np.arange(10)), 30.0) == []
