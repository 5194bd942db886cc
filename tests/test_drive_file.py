"""A drive from a file (issue 35, item 4): `hybrid simulate --drive-file` and `rig record --drive-file`.

The file is what `hybrid design` writes (CSV t,v_in). The virtual IPMC's
recording under it must carry that drive, and the virtual rig (emulated board
and camera) must play it through the calibrated DAC; a drive the DAC cannot
play is refused in one line before anything runs.
"""

from __future__ import annotations

import json

import helpers as h
import numpy as np

import hybrid
from hybrid.cli import main as hybrid_main
from hybrid.ipmc._virtual_elements import dac_output
from hybrid.ipmc._virtual_parameters import VirtualIPMCParameters
from rig import Calibration
from rig.cli import main as rig_main

RATE = 30.0


def _drive_file(folder, seconds=3.0, peak=1.5, fmt="%.17g", name="drive.csv"):
    t = np.arange(int(seconds * RATE)) / RATE
    v = peak * np.sin(2 * np.pi * 0.7 * t) * np.minimum(1.0, t)  # a smooth designed-looking drive
    path = folder / name
    with open(path, "w") as handle:
        handle.write("t,v_in\n")
        np.savetxt(handle, np.column_stack([t, v]), delimiter=",", fmt=fmt)
    return path, v


def test_hybrid_simulate_records_the_virtual_ipmc_under_a_drive_file(tmp_path, capsys, monkeypatch):
    path, v = _drive_file(tmp_path)
    done = h.run_hybrid(tmp_path, "simulate", "--drive-file", path, "--out", "rec.csv")  # the real command
    assert done.returncode == 0, done.stderr
    rec = hybrid.Recording.load(tmp_path / "rec.csv")
    assert len(rec) == len(v) and abs(rec.rate - RATE) < 1e-6 * RATE
    # the voltage the virtual DAC applies: the file's drive, quantised and clipped
    np.testing.assert_allclose(rec.v_in, dac_output(v, VirtualIPMCParameters()), atol=1e-9)
    assert np.ptp(rec.w) > 0  # the strip moved

    # the rest through the same command line in this process (`hybrid.cli.main`): no process start each
    monkeypatch.chdir(tmp_path)

    def simulate(*args):
        code = hybrid_main(["simulate", *map(str, args)])
        return code, capsys.readouterr().err

    for flag, value in (("--duration", "3"), ("--rate", "60"), ("--amplitude", "0.1")):  # the file says
        code, err = simulate("--drive-file", path, flag, value, "--out", "x.csv")
        assert code == 2 and f"{flag} is for --drive" in err, err
        assert len(err.strip().splitlines()) == 1 and not (tmp_path / "x.csv").exists()
    # t written to 6 decimals (0.033333, 0.066667, ...): a uniform 30 Hz drive all the same
    rounded, _ = _drive_file(tmp_path, fmt="%.6f", name="rounded.csv")
    code, err = simulate("--drive-file", rounded, "--out", "six.csv")
    assert code == 0, err
    assert abs(hybrid.Recording.load(tmp_path / "six.csv").rate - RATE) < 1e-6 * RATE
    # a drive faster than the camera's exposure allows: refused in one line that names the flag to change
    fast = tmp_path / "fast.csv"
    fast.write_text("t,v_in\n" + "".join(f"{k / 2000.0!r},{0.1 * (k % 7)!r}\n" for k in range(400)))
    code, err = simulate("--drive-file", fast, "--out", "fast_rec.csv")
    assert code == 2 and "--param exposure_s=0.0005" in err, err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "fast_rec.csv").exists()
    # beyond the virtual DAC's rails: refused in one line, as rig record does, not clipped in silence
    loud, _ = _drive_file(tmp_path, peak=5.0, name="loud.csv")
    code, err = simulate("--drive-file", loud, "--out", "loud_rec.csv")
    assert code == 2 and "outside the virtual DAC's ±3 V" in err, err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "loud_rec.csv").exists()


def test_rig_record_plays_a_drive_file_on_the_virtual_rig_and_refuses_one_the_dac_cannot_play(
    tmp_path, capsys, monkeypatch
):
    path, v = _drive_file(tmp_path)
    out = tmp_path / "rec.csv"
    monkeypatch.setenv("HYBRID_HEARTBEAT_S", "0.2")  # a long recording is never silent: a heartbeat
    assert (
        rig_main(["record", "--virtual", "--drive-file", str(path), "--speed", "3", "--out", str(out)]) == 0
    )
    monkeypatch.delenv("HYBRID_HEARTBEAT_S")
    assert "rig record: still working" in capsys.readouterr().err
    rec = hybrid.Recording.load(out)
    meta = json.loads((tmp_path / "rec.csv.json").read_text())
    assert meta["complete"] and abs(len(rec) - len(v)) <= 1
    # v_in is the file's drive through the calibration, on the DAC at each frame
    cal = Calibration()
    expected = cal.volts(cal.codes(v))[rec.extra["sample"].astype(int)]
    np.testing.assert_allclose(rec.v_in, expected, atol=1e-12)

    loud, _ = (
        _drive_file(tmp_path / "loud", peak=9.0) if (tmp_path / "loud").mkdir() is None else (None, None)
    )
    capsys.readouterr()
    assert rig_main(["record", "--virtual", "--drive-file", str(loud), "--out", str(tmp_path / "l.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert "outside what the DAC can play" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "l.csv").exists()
    # the drive file is an input: recording over it is refused, and it stays as it was
    before = path.read_bytes()
    assert rig_main(["record", "--virtual", "--drive-file", str(path), "--out", str(path)]) == 2
    assert path.read_bytes() == before
