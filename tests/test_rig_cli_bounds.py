"""Every size argument of `rig` is bounded: one clear line and exit status 2, never a traceback."""

import json

import pytest

from rig.cli import main

TRACK = ["track", "v.avi", "--clamp", "40,120", "--mm-per-px", "0.1", "--out", "x.csv"]
RECORD = ["record", "--virtual", "--drive", "prbs", "--duration", "2", "--out", "r.csv"]


def _with(argv, option, value):
    argv = list(argv)
    if option in argv:
        argv[argv.index(option) + 1] = value
    else:
        argv[-2:-2] = [option, value]
    return argv


@pytest.mark.parametrize(
    "argv, fragment",
    [
        (
            _with(TRACK, "--mm-per-px", "0"),
            "--mm-per-px: must be a number > 0 and <= 10 mm per pixel, got '0'",
        ),
        (_with(TRACK, "--mm-per-px", "-0.1"), "--mm-per-px: must be a number > 0"),
        (_with(TRACK, "--mm-per-px", "nan"), "--mm-per-px: must be a number > 0"),
        (_with(TRACK, "--mm-per-px", "inf"), "--mm-per-px: must be a number > 0"),
        (_with(TRACK, "--axis", "1e9"), "--axis: must be a number >= -360 and <= 360 degrees"),
        (_with(TRACK, "--length", "0"), "--length: must be a number > 0 and <= 1000 mm"),
        (_with(TRACK, "--strip-px", "0"), "--strip-px: must be a number > 0 and <= 100 px"),
        (_with(TRACK, "--exposure", "0"), "--exposure: must be a number > 0 and <= 10 s"),
        (_with(TRACK, "--led", "10,10,0"), "--led: the radius must be > 0 and <= 200 px"),
        (_with(RECORD, "--fps", "0"), "--fps: must be a number > 0 and <= 1000 frames per second"),
        (_with(RECORD, "--fps", "5000"), "--fps: must be a number > 0 and <= 1000"),
        (_with(RECORD, "--duration", "0"), "--duration: must be a number > 0 and <= 86400 s (one day)"),
        (_with(RECORD, "--duration", "1e6"), "--duration: must be a number > 0 and <= 86400"),
        (_with(RECORD, "--rate", "0"), "--rate: must be a number >= 1 and <= 5000 samples per second"),
        (_with(RECORD, "--amplitude", "0"), "--amplitude: must be a number > 0 and <= 100 V"),
        (_with(RECORD, "--speed", "0"), "--speed: must be a number > 0 and <= 100"),
        (_with(RECORD, "--exposure", "-1"), "--exposure: must be a number > 0"),
        (_with(RECORD, "--strip-px", "inf"), "--strip-px: must be a number > 0"),
        (_with(RECORD, "--mm-per-px", "0"), "--mm-per-px: must be a number > 0"),
        (_with(RECORD, "--dac-address", "0x200"), "--dac-address: must be an integer >= 8 and <= 119"),
        (_with(RECORD, "--seed", "-1"), "--seed: must be an integer >= 0"),
        (["simavr-timing", "--rate", "0"], "--rate: must be a number >= 1 and <= 5000"),
        (["simavr-timing", "--duration", "-5"], "--duration: must be a number > 0"),
        (_with(TRACK, "--clamp", "100"), "--clamp: expected --clamp X,Y: 2 finite numbers, got '100'"),
        (_with(TRACK, "--led", "1,a"), "--led: expected --led X,Y[,R]: comma-separated numbers"),
    ],
)
def test_size_arguments_are_bounded(argv, fragment, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("rig: error: argument ") and err.count("\n") == 1 and fragment in err, err


def test_track_never_writes_over_its_video(tmp_path, capsys):
    video = tmp_path / "v.avi"
    video.write_bytes(b"not really a video")
    assert main(["track", str(video), "--clamp", "1,1", "--mm-per-px", "0.1", "--out", str(video)]) == 2
    assert "is the input" in capsys.readouterr().err
    assert video.read_bytes() == b"not really a video"


def _track_strip(video, out):
    """`rig track` of `strip_video`'s strip, at its clamp point and scale."""
    return ["track", str(video), "--clamp", "20,100", "--mm-per-px", "0.1", "--out", str(out)]


@pytest.fixture(scope="module")
def strip_video(tmp_path_factory):
    """Eight frames of a 22 mm strip at 0.1 mm/px pointing right from (20, 100), in 480 x 260 (tests' renderer)."""
    from rig_cantilever_render import CantileverVideo, write_avi

    path = tmp_path_factory.mktemp("scene") / "strip.avi"
    video = CantileverVideo((20.0, 100.0), 0.0, size=(480, 260), mm_per_px=0.1, seed=2)
    write_avi(path, [video.frame(0.5 * k, k) for k in range(8)])
    return path


@pytest.mark.parametrize(
    "flags, fragment",
    [
        (["--clamp", "700,100"], "--clamp 700,100 is outside the 480x260 picture"),
        (["--mm-per-px", "10"], "is a strip 2.2 px long, too short to follow"),
        (["--mm-per-px", "0.01", "--length", "1000"], "longer than the 480x260 picture can show"),
    ],
)
def test_a_scene_that_cannot_be_in_the_picture_is_refused_before_tracking(
    strip_video, tmp_path, capsys, flags, fragment
):
    """Before: an OpenCV assertion, or numpy asking for 292 GiB; now one line and nothing written."""
    argv = _track_strip(strip_video, tmp_path / "w.csv")
    for option, value in zip(flags[::2], flags[1::2]):
        argv = _with(argv, option, value)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("rig: error: ") and err.count("\n") == 1 and fragment in err, err
    assert list(tmp_path.iterdir()) == []


def test_track_refuses_an_out_that_is_a_folder_or_not_a_csv_and_a_folder_as_video(
    strip_video, tmp_path, capsys
):
    base = ["track", str(strip_video), "--clamp", "20,100", "--mm-per-px", "0.1", "--out"]
    other = tmp_path / "other.avi"
    other.write_bytes(b"someone's video")
    for out, fragment in [(tmp_path, "is a folder: give the CSV file"), (other, "has suffix '.avi'")]:
        assert main([*base, str(out)]) == 2
        assert fragment in capsys.readouterr().err
    assert other.read_bytes() == b"someone's video"
    assert main(["track", str(tmp_path), "--clamp", "20,100", "--mm-per-px", "0.1", "--out", "w.csv"]) == 2
    assert "is a folder: give the video file inside it" in capsys.readouterr().err


def test_a_strip_tracked_short_of_or_beyond_its_length_warns_of_the_scale(strip_video, tmp_path, capsys):
    """--mm-per-px half the true scale halves w; the tip at half of --length says so."""
    out = tmp_path / "w.csv"
    argv = _with(_with(_track_strip(strip_video, out), "--mm-per-px", "0.05"), "--length", "22")
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert "the strip's tip lies a median 11" in err and "0.50 of --length 22 mm" in err, err
    assert "0.50 of --length" in json.loads(out.with_name("w.csv.json").read_text())["warnings"][0]
    assert main(_with(argv, "--mm-per-px", "0.1")) == 0  # the right scale: no warning
    assert "warning" not in capsys.readouterr().err
    # a scale 20 % too large puts the tip beyond the strip's length, which no strip reaches (a probe's
    # --mm-per-px 0.12 for 0.1 scaled w by 1.2 without a word)
    assert main(_with(argv, "--mm-per-px", "0.12")) == 0
    err = capsys.readouterr().err
    assert "1.20 × --length 22 mm" in err and "--mm-per-px 0.12 is off" in err, err


def test_record_refuses_an_out_that_is_not_a_csv_before_recording(tmp_path, capsys):
    """It recorded the whole drive, then failed validating 'r.partial.avi' (minutes on a real rig)."""
    for out, fragment in [
        (tmp_path / "r.avi", "has suffix '.avi', but rig record writes a CSV"),
        (tmp_path, "is a folder"),
    ]:
        assert main(_with(RECORD, "--out", str(out))) == 2
        err = capsys.readouterr().err
        assert err.startswith("rig: error: ") and err.count("\n") == 1 and fragment in err, err
    assert list(tmp_path.iterdir()) == []
