"""Every size argument of `rig` is bounded: one clear line and exit status 2, never a traceback."""

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
