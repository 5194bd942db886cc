"""Tip tracking on videos written to and read back from real files (MJPG AVI, MP4)."""

import csv

import numpy as np
import pytest
from rig_labvideo import LabVideo, write_video

from rig import RigError
from rig._camera import VideoSource
from rig._render import Look, render_frame
from rig._scene import Scene, arc_centreline
from rig._sync import LedDetector
from rig._tracker import TipTracker
from rig.cli import main

SCENE = Scene()  # clamp (40, 120), 0.1 mm/px, strip along +x
SWEEP = 6.2 * np.sin(np.linspace(0, 4 * np.pi, 75))  # deflections up to +-6.2 mm
TOLERANCE_RMS = 0.05  # mm, the target at the default scale
TOLERANCE_MAX = 0.15  # mm, no single frame far off


def _track_file(path, scene=SCENE):
    tracker = TipTracker(scene)
    with VideoSource(path) as video:
        results = [tracker.track(frame.image) for frame in video]
    return np.array([r.w for r in results]), np.array([r.quality for r in results])


def test_arc_centreline_has_the_asked_tip_and_length():
    for w in (-6.0, 0.5, 6.0):
        s, u = arc_centreline(w, 22.0, n=2001)
        assert u[-1] == pytest.approx(w, abs=1e-12)
        assert np.hypot(np.diff(s), np.diff(u)).sum() == pytest.approx(22.0, rel=1e-6)


@pytest.mark.parametrize("suffix, seed", [(".avi", 0), (".mp4", 1), (".avi", 2)])
def test_lab_video_accuracy(tmp_path, suffix, seed):
    # Different lighting, grain, blur, noise and flicker per seed; colour frames; lossy codecs.
    video = LabVideo(
        SCENE,
        seed=seed,
        noise=[4.0, 6.0, 3.0][seed],
        blur=[1.0, 1.4, 0.7][seed],
        flicker=[0.08, 0.12, 0.05][seed],
    )
    path = tmp_path / f"lab{suffix}"
    write_video(path, [video.frame(w, k) for k, w in enumerate(SWEEP)])
    w, quality = _track_file(path)
    assert len(w) == len(SWEEP) and quality.all()
    error = w - SWEEP
    assert np.sqrt(np.mean(error**2)) <= TOLERANCE_RMS
    assert np.max(np.abs(error)) <= TOLERANCE_MAX


def test_virtual_camera_pictures_accuracy_through_mjpg(tmp_path):
    rng = np.random.default_rng(3)
    frames = [render_frame(SCENE, Look(), w, gain=1 + 0.05 * np.sin(k), rng=rng) for k, w in enumerate(SWEEP)]
    path = tmp_path / "virtual.avi"
    write_video(path, frames)
    w, quality = _track_file(path)
    assert quality.all()
    assert np.sqrt(np.mean((w - SWEEP) ** 2)) <= TOLERANCE_RMS


def test_tilted_axis_and_other_scale():
    scene = Scene(clamp=(60.0, 60.0), mm_per_px=0.08, angle_deg=25.0)
    look = Look(size=(400, 320), led=None)
    rng = np.random.default_rng(4)
    errors = [
        TipTracker(scene).track(render_frame(scene, look, w, rng=rng)).w - w for w in (-5.0, 0.0, 3.0, 6.0)
    ]
    assert np.max(np.abs(errors)) <= TOLERANCE_MAX


def test_strip_out_of_view_is_flagged():
    rng = np.random.default_rng(5)
    empty = render_frame(Scene(clamp=(-500.0, -500.0)), Look(), 0.0, rng=rng)
    result = TipTracker(SCENE).track(empty)
    assert result.quality == 0 and np.isnan(result.w)
    # The tip beyond the picture's edge: a view too small for the strip.
    small = Look(size=(200, 240), led=None)
    cut = TipTracker(SCENE).track(render_frame(SCENE, small, 2.0, rng=rng))
    assert cut.quality == 0 and cut.reason == "tip out of view"


def test_led_sync_sub_frame(tmp_path):
    # LED turns on 12 ms into frame 10's 16.7 ms exposure: lit for 28 % of it.
    fps, exposure, edge = 30.0, 1 / 60, 10 / 30 + 0.012
    detector = LedDetector(*Look().led, fps=fps, exposure=exposure)
    rng = np.random.default_rng(6)
    sync = None
    for k in range(16):
        start = k / fps
        lit = np.clip((start + exposure - edge) / exposure, 0, 1)
        sync = detector.update(
            k, start, render_frame(SCENE, Look(), 1.0, led=lit, rng=rng, gain=1 + 0.05 * np.sin(k))
        )
    assert sync is not None and sync.frame == 10
    assert sync.t == pytest.approx(edge, abs=0.002)


def test_rig_track_cli(tmp_path, capsys):
    video = LabVideo(SCENE, seed=7)
    path = tmp_path / "lab.avi"
    write_video(path, [video.frame(w, k) for k, w in enumerate(SWEEP[:30])])
    out = tmp_path / "track.csv"
    assert main(["track", str(path), "--clamp", "40,120", "--mm-per-px", "0.1", "--out", str(out)]) == 0
    rows = list(csv.DictReader(out.open()))
    assert list(rows[0]) == ["t", "w", "quality"] and len(rows) == 30
    assert float(rows[3]["t"]) == pytest.approx(3 / 30)
    w = np.array([float(r["w"]) for r in rows])
    assert np.sqrt(np.mean((w - SWEEP[:30]) ** 2)) <= TOLERANCE_RMS


def test_unreadable_video_is_one_line_error(tmp_path, capsys):
    bad = tmp_path / "broken.avi"
    bad.write_bytes(b"RIFF\x00\x00\x00\x00AVI garbage" * 10)
    assert (
        main(["track", str(bad), "--clamp", "40,120", "--mm-per-px", "0.1", "--out", str(tmp_path / "x.csv")])
        == 2
    )
    err = capsys.readouterr().err
    assert err.startswith("rig: error:") and err.count("\n") == 1 and "broken.avi" in err
    assert (
        main(
            [
                "track",
                str(tmp_path / "none.avi"),
                "--clamp",
                "40,120",
                "--mm-per-px",
                "0.1",
                "--out",
                str(tmp_path / "x.csv"),
            ]
        )
        == 2
    )
    assert "does not exist" in capsys.readouterr().err
    with pytest.raises(RigError):
        TipTracker(SCENE).track(np.zeros((2, 2)))
