"""End-to-end recordings on the virtual rig (emulated board on a pty, virtual camera), faults included."""

import json

import numpy as np
import pytest
import serial

import hybrid
from hybrid.ipmc._virtual_elements import dac_output
from hybrid.ipmc._virtual_parameters import VirtualIPMCParameters
from rig import Board, Calibration, RigError, fit_calibration
from rig._emulator import EmulatedBoard
from rig._record import RecordSettings, record
from rig._render import Look
from rig._virtual import VirtualCamera
from rig.cli import main

SPEED = 3.0
LOOK = Look()
SETTINGS = RecordSettings(led=LOOK.led, exposure=1 / 60)


def _meta(path):
    return json.loads(open(f"{path}.json").read())


def test_calibration_default_is_the_virtual_rigs_dac():
    volts = np.linspace(-3.5, 3.5, 1001)
    cal = Calibration()
    np.testing.assert_allclose(
        cal.volts(cal.codes(volts)), dac_output(volts, VirtualIPMCParameters()), atol=1e-12
    )


def test_fit_calibration_recovers_gain_offset_and_rails():
    truth = Calibration(gain=1.17, offset=-2.93, rail_low=-2.9, rail_high=2.8)
    codes = np.array([0, 512, 1024, 1536, 2048, 2560, 3072, 3584, 4095])
    readings = np.round(truth.volts(codes), 3)
    fitted, report = fit_calibration(codes, readings)
    assert fitted.gain == pytest.approx(1.17, rel=2e-3)
    assert fitted.offset == pytest.approx(-2.93, abs=3e-3)
    assert fitted.rail_low == pytest.approx(-2.9, abs=1e-3) and fitted.rail_high == pytest.approx(
        2.8, abs=1e-3
    )
    assert report["clipped"][0] and report["clipped"][-1] and not any(report["clipped"][1:-1])


def test_virtual_record_cli_gives_a_valid_synchronised_recording(tmp_path, capsys):
    out = tmp_path / "rec.csv"
    assert (
        main(
            [
                "record",
                "--virtual",
                "--drive",
                "prbs",
                "--duration",
                "5",
                "--speed",
                str(SPEED),
                "--seed",
                "1",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    rec = hybrid.Recording.load(out)
    meta = _meta(out)
    assert meta["complete"] and meta["sync"]["method"] == "led"
    # streamed into rec.partial.csv, renamed onto --out with its sidecar once it succeeded
    assert (
        sorted(p.name for p in tmp_path.iterdir()) == ["rec.csv", "rec.csv.json"] and "partial_of" not in meta
    )
    assert abs(len(rec) - 150) <= 1 and rec.rate == pytest.approx(30.0, rel=1e-3)
    # Tracking against the virtual strip's exposure-averaged truth.
    error = rec.w - rec.extra["w_true"]
    assert np.sqrt(np.mean(error**2)) <= 0.05
    assert np.ptp(rec.w) > 4.0  # the strip really moved
    # v_in: the drive, through the calibration, on the DAC at each frame.
    drive = hybrid.make_drive("prbs", 5, rate=30.0, seed=1, amplitude=2.0)
    expected = Calibration().volts(Calibration().codes(drive.v))[rec.extra["sample"].astype(int)]
    np.testing.assert_allclose(rec.v_in, expected, atol=1e-12)
    # Frame k starts t_k after sample 0; sample i plays at i / 30.0012 s: the row's sample must be it
    # (sync error < 1/120 s keeps it right except within that of a sample edge).
    period = meta["board"]["period_s"]
    ideal = np.floor(rec.t / period + 1e-9).astype(int)
    assert np.mean(rec.extra["sample"] == ideal) >= 0.95
    assert "RMS error" in capsys.readouterr().out


def _virtual(tmp_path, fault_at=None, duration=4.0, rate=30.0, **camera_kwargs):
    """Record on the virtual rig; ``fault_at = (samples played, action(emulated))`` fires on the board."""
    emulated = EmulatedBoard(speed=SPEED)
    board = Board(serial.Serial(emulated.port, 250000, timeout=0.02), name=emulated.port, reply_timeout=1.0)
    board.hello()
    camera = VirtualCamera(emulated, look=LOOK, **camera_kwargs)
    emulated.fault_at = fault_at
    drive = hybrid.make_drive("sine", duration, rate=rate, amplitude=2.0, frequency=0.5)
    out = tmp_path / "rec.csv"
    try:
        meta = record(board, camera, drive, SETTINGS, out, truth=camera.truth)
        error = None
    except RigError as caught:
        # A failed recording is kept beside --out, never at it: the error names it.
        partial = tmp_path / "rec.partial.csv"
        assert not out.exists() and f"kept in {partial} (+ .json); {out} was not written" in str(caught)
        out, error = partial, caught
        meta = _meta(out)
        assert meta["partial_of"] == str(tmp_path / "rec.csv")
    finally:
        board.close()
        emulated.close()
    return out, meta, error


def test_board_reset_mid_record_keeps_a_flagged_partial_recording(tmp_path):
    out, meta, error = _virtual(tmp_path, fault_at=(60, lambda e: e.reset()))
    assert error is not None and "reset during the stream" in str(error) and "is kept in" in str(error)
    rec = hybrid.Recording.load(out)
    assert 30 <= len(rec) <= 66  # rows up to the reset at sample 60, less < 1 s
    assert meta["complete"] is False and meta["status"] == "interrupted" and "reset" in meta["error"]


def test_unplugged_board_mid_record_keeps_a_flagged_partial_recording(tmp_path):
    out, meta, error = _virtual(tmp_path, fault_at=(60, lambda e: e.unplug()))
    assert error is not None and ("unplugged" in str(error) or "silent" in str(error))
    assert 30 <= len(hybrid.Recording.load(out)) <= 66
    assert meta["complete"] is False


def test_corrupt_board_frames_and_dropped_duplicated_hidden_frames(tmp_path):
    def corrupt(emulated):
        emulated.corrupt_tx = 2  # the next two frames from the board arrive damaged

    drop, hide = {70, 71, 110}, {120, 121, 122}
    out, meta, error = _virtual(
        tmp_path, fault_at=(20, corrupt), drop=sorted(drop), duplicate=[80], hide=sorted(hide)
    )
    assert error is None, error
    rec = hybrid.Recording.load(out)  # uniform time base despite the gaps
    assert meta["complete"]
    assert meta["board"]["report"]["bad_frames_host"] >= 2
    slots = np.round(rec.extra["t_camera"] * 30).astype(int)
    faulty = {k for k in drop | hide if slots[0] <= k <= slots[-1]}
    assert len(faulty) >= 4  # the faults fell inside the recording
    assert set(slots[rec.extra["quality"] == 0]) == faulty
    assert meta["duplicated_frames"] == 1
    assert drop <= set(meta["dropped_frames"]) and meta["untracked_frames"] == 3
    good = rec.extra["quality"] > 0
    assert np.sqrt(np.mean((rec.w - rec.extra["w_true"])[good] ** 2)) <= 0.05


def test_underrun_is_recorded_in_metadata(tmp_path):
    # The board's clock jumps 3.5 s ahead of the host (a stalled host): the 2.56 s buffer runs dry.
    def stall(emulated):
        emulated._t0 -= 3.5 / emulated.speed

    out, meta, error = _virtual(tmp_path, fault_at=(40, stall), duration=4.0, rate=100.0)
    report = meta["board"]["report"]
    assert error is None and meta["complete"]
    assert report["underrun_ticks"] > 0 and report["underruns"]
    rec = hybrid.Recording.load(out)
    # Rows follow the board's real schedule: the sample on the DAC stalls during the underrun.
    index, length, tick = report["underruns"][0]
    period = meta["board"]["period_s"]
    during = (rec.t > (index + 1) * period) & (rec.t < (tick - 1) * period)
    assert during.sum() > 10 and np.all(rec.extra["sample"][during] == index - 1)


def test_cli_errors_are_one_line(tmp_path, capsys):
    for argv, fragment in [
        (
            [
                "record",
                "--port",
                "/dev/ttyNO_SUCH",
                "--camera",
                "0",
                "--drive",
                "prbs",
                "--duration",
                "2",
                "--clamp",
                "1,1",
                "--mm-per-px",
                "0.1",
                "--out",
                str(tmp_path / "r.csv"),
            ],
            "cannot be opened",
        ),
        (["record", "--drive", "prbs", "--duration", "2", "--out", str(tmp_path / "r.csv")], "--virtual"),
        (["record", "--virtual", "--drive", "nope", "--duration", "2", "--out", "x.csv"], "invalid choice"),
        (["track", "v.avi", "--out", "x.csv"], "--clamp"),
        (["calibrate", "--virtual", "--readings", "1,2", "--out", "c.json"], "--readings"),
    ]:
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.startswith("rig: error:") and err.count("\n") == 1 and fragment in err, (argv, err)


def test_calibrate_virtual_recovers_the_virtual_amplifier(tmp_path):
    out = tmp_path / "cal.json"
    assert main(["calibrate", "--virtual", "--out", str(out)]) == 0
    cal = Calibration.load(out)
    assert cal.gain == pytest.approx(1.17, rel=3e-3) and cal.offset == pytest.approx(-2.93, abs=5e-3)
    assert cal.rail_low == pytest.approx(-2.9, abs=2e-3) and cal.rail_high == pytest.approx(2.8, abs=2e-3)


def test_sigterm_closes_the_recording_like_ctrl_c(tmp_path):
    # SIGTERM (a service manager stopping rig, `kill`) used to leave the sidecar at "recording" with a
    # stale row count; it is handled like Ctrl-C now.
    import os
    import signal
    import subprocess
    import sys
    import time

    out, partial = tmp_path / "rec.csv", tmp_path / "rec.partial.csv"
    process = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "rig.cli",
            "record",
            "--virtual",
            "--drive",
            "prbs",
            "--duration",
            "30",
            "--speed",
            "3",
            "--out",
            str(out),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and process.poll() is None:
            if partial.exists() and partial.read_text().count("\n") > 6:
                break
            time.sleep(0.1)
        assert process.poll() is None, process.communicate()
        process.send_signal(signal.SIGTERM)
        _, err = process.communicate(timeout=30)
    finally:
        if process.poll() is None:
            os.kill(process.pid, signal.SIGKILL)
    assert process.returncode == 143 and "terminated by SIGTERM" in err and "Traceback" not in err
    assert err.count("\n") == 1 and f"is kept in {partial} (+ .json); {out} was not written" in err, err
    assert not out.exists()  # an interrupted recording is never at --out
    meta = _meta(partial)
    rows = partial.read_text().count("\n") - 1
    assert meta["status"] == "interrupted" and meta["complete"] is False
    assert meta["error"] == "terminated by SIGTERM" and meta["rows"] == rows >= 6
    assert f"({rows} rows)" in err
    assert len(hybrid.Recording.load(partial)) == rows


def test_an_interruption_inside_a_row_write_leaves_no_repeated_row(tmp_path, monkeypatch):
    # Ctrl-C or SIGTERM landing after a row reached the file but before the flush forgot it (the sidecar's
    # rewrite, milliseconds) made the clean-up write it again: a repeated time, a file that cannot be loaded.
    import rig._record as recording

    original = recording._Writer.row

    def row_then_interrupt(self, values):
        original(self, values)
        if self.rows == 20:
            raise KeyboardInterrupt

    monkeypatch.setattr(recording._Writer, "row", row_then_interrupt)
    with pytest.raises(KeyboardInterrupt):
        _virtual(tmp_path)
    partial = tmp_path / "rec.partial.csv"
    rec = hybrid.Recording.load(partial)  # strictly increasing times, or one line saying where not
    assert len(rec) == _meta(partial)["rows"] >= 20
    assert _meta(partial)["status"] == "interrupted"
