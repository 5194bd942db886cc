"""The real firmware (avr-gcc) on simavr, driven by the host driver over a pty.

Times here are simulated CPU cycles at 16 MHz from the MCP4725 model's log,
not wall-clock times, so the assertions do not depend on the machine's load.
"""

import numpy as np
import pytest
import serial
from rig_helpers import CorruptingPort, firmware  # noqa: F401  (fixture)

import hybrid
from rig import Board, Calibration, RigError, protocol as P
from rig._simavr import SimavrBoard

RATE = 200.0  # Hz: 1.28 s of buffer, so 3 s of drive really streams
PERIOD = 80_000  # cycles at 200 Hz: (9999 + 1) * 8
SPEED = 2.0  # simulated seconds per wall second
# Worst-case interrupt latency added to a DAC write: a UART RX ISR (~50 cycles) and a
# TWI ISR (~50) can each delay the Timer1 ISR once; the main loop's cli sections are
# shorter. 160 cycles = 10 us, 0.2 % of a 5 ms period.
JITTER_CYCLES = 160


def _open(sim, wrap=None):
    port = serial.Serial(sim.port, 250000, timeout=0.02)
    board = Board(wrap(port) if wrap else port, name=sim.port)
    board.hello()
    return board


def _played(log, n):
    """The last n DAC latches (earlier ones are the idle code at boot and CONFIG)."""
    return log.dac_cycle[-n:], log.dac_code[-n:]


def test_streamed_drive_plays_every_code_on_its_tick(firmware, tmp_path):
    drive = hybrid.make_drive("chirp", 3.0, rate=RATE, f0=0.5, f1=20.0, amplitude=2.5)
    codes = Calibration().codes(drive.v)
    with SimavrBoard(*firmware, tmp_path / "dac.log", speed=SPEED) as sim:
        board = _open(sim)
        timing = board.configure(RATE, idle_code=2048, sync_samples=10)
        report = board.play(codes)
        board.close()
    assert timing.period_cycles == PERIOD
    assert report.complete and report.played == len(codes)
    log = sim.log()
    cycles, played = _played(log, len(codes))
    np.testing.assert_array_equal(played, codes)
    # Each latch sits on the board's reported schedule (tick i plus underrun gaps).
    ticks = report.sample_ticks()
    error = (cycles - cycles[0]) - (ticks - ticks[0]) * PERIOD
    assert np.max(np.abs(error)) <= JITTER_CYCLES
    # Sync LED: rises before sample 0's latch by the I2C write time, falls at sample 10's tick.
    rise = log.led_cycle[(log.led_value == 1)][-1]
    fall = log.led_cycle[(log.led_value == 0)][-1]
    latency = cycles[0] - rise
    assert 0 < latency < 16 * 100  # an I2C write at 400 kHz: 29 bits ~ 73 us
    assert abs((fall - rise) - 10 * PERIOD) <= JITTER_CYCLES


def test_corrupt_data_frame_is_nakked_and_resent(firmware, tmp_path):
    codes = np.arange(600) * 6 % 4096
    with SimavrBoard(*firmware, tmp_path / "dac.log", speed=SPEED) as sim:
        board = _open(sim, wrap=lambda p: CorruptingPort(p, P.T_DATA, nth=14))
        board.configure(RATE, idle_code=2048)
        report = board.play(codes)
        board.close()
    assert board.port.corrupted == 1
    assert report.bad_frames_board >= 1 and report.resent_samples > 0
    np.testing.assert_array_equal(_played(sim.log(), len(codes))[1], codes)


def test_underrun_is_reported_and_timed(firmware, tmp_path):
    codes = np.arange(400) * 10
    stalled = []

    def stall(report):  # the host hangs for 2 s once: longer than the 1.28 s buffer
        if not stalled and report.played > 50:
            stalled.append(True)
            import time

            time.sleep(2.0 / SPEED)

    with SimavrBoard(*firmware, tmp_path / "dac.log", speed=SPEED) as sim:
        board = _open(sim)
        board.configure(RATE, idle_code=2048)
        report = board.play(codes, on_progress=stall)
        board.close()
    assert report.complete and report.underruns and report.underrun_ticks > 0
    assert report.ticks == len(codes) + report.underrun_ticks
    cycles, played = _played(sim.log(), len(codes))
    np.testing.assert_array_equal(played, codes)
    ticks = report.sample_ticks()
    error = (cycles - cycles[0]) - (ticks - ticks[0]) * PERIOD
    assert np.max(np.abs(error)) <= JITTER_CYCLES


def test_board_reset_mid_stream_is_a_clear_error(firmware, tmp_path):
    with SimavrBoard(*firmware, tmp_path / "dac.log", speed=SPEED) as sim:
        board = _open(sim)
        board.configure(RATE, idle_code=2048)

        def reset(report):
            if report.played > 100:
                sim.reset()

        with pytest.raises(RigError, match="reset during the stream") as caught:
            board.play(np.full(1000, 3000), on_progress=reset)
        board.close()
    assert 100 < caught.value.report.played < 1000
    assert sim.log().resets


def test_unplugged_port_is_a_clear_error(firmware, tmp_path):
    sim = SimavrBoard(*firmware, tmp_path / "dac.log", speed=SPEED)
    board = _open(sim)
    board.configure(RATE, idle_code=2048)

    def unplug(report):
        if report.played > 100:
            sim.unplug()

    with pytest.raises(RigError, match="unplugged|silent") as caught:
        board.play(np.full(1000, 1000), on_progress=unplug)
    board.close()
    assert caught.value.report.played > 100 and not caught.value.report.complete


def test_missing_dac_is_a_clear_error(firmware, tmp_path):
    with SimavrBoard(*firmware, tmp_path / "dac.log", speed=SPEED, dac=False) as sim:
        board = _open(sim)
        with pytest.raises(RigError, match="DAC did not acknowledge"):
            board.configure(RATE, idle_code=2048)
            board.play(np.full(100, 1000))
        board.close()


def test_missing_port_is_a_clear_error():
    with pytest.raises(RigError, match="cannot be opened"):
        Board.open("/dev/ttyNO_SUCH_PORT")


def test_python_emulator_plays_like_the_firmware(firmware, tmp_path):
    """The emulator (used by --virtual and where simavr is missing) against the real firmware."""
    from rig._emulator import DAC_LATENCY, EmulatedBoard

    codes = (np.arange(500) * 37) % 4096
    with SimavrBoard(*firmware, tmp_path / "dac.log", speed=SPEED) as sim:
        board = _open(sim, wrap=lambda p: CorruptingPort(p, P.T_DATA, nth=5))
        board.configure(RATE, idle_code=1234, sync_samples=7)
        real = board.play(codes)
        board.close()
    log = sim.log()
    with EmulatedBoard(speed=SPEED) as emulated:
        port = serial.Serial(emulated.port, 250000, timeout=0.02)
        board = Board(CorruptingPort(port, P.T_DATA, nth=5), name=emulated.port)
        board.hello()
        board.configure(RATE, idle_code=1234, sync_samples=7)
        emulated_report = board.play(codes)
        board.close()
        dac = np.array(emulated.dac_log)
        led = np.array(emulated.led_log)
    for report in (real, emulated_report):
        assert report.complete and report.played == len(codes) and report.bad_frames_board >= 1
    # Same codes in the same order, idle code included, on the same tick grid.
    np.testing.assert_array_equal(dac[-len(codes) - 1 :, 1], log.dac_code[-len(codes) - 1 :])
    assert log.dac_code[-len(codes) - 1] == 1234
    emulated_ticks = (dac[-len(codes) :, 0] - dac[-len(codes), 0]) / (PERIOD / 16e6)
    np.testing.assert_allclose(emulated_ticks, real.sample_ticks(), atol=1e-6)
    # Same LED pulse: on at sample 0's tick, off 7 ticks later; latch DAC_LATENCY after the tick.
    on, off = led[led[:, 1] == 1][-1, 0], led[led[:, 1] == 0][-1, 0]
    assert (off - on) * 16e6 == pytest.approx(7 * PERIOD, abs=1)
    assert (dac[-len(codes), 0] - on) * 16e6 == pytest.approx(
        log.dac_cycle[-len(codes)] - log.led_cycle[log.led_value == 1][-1], abs=1
    )
    assert DAC_LATENCY * 16e6 == pytest.approx(1048, abs=1)
