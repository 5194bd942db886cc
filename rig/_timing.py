"""Timing of DAC updates by the real firmware on simavr (``rig simavr-timing``)."""

from __future__ import annotations

import tempfile

import numpy as np


def measure_simavr_timing(
    rate: float = 30.0, duration: float = 10.0, speed: float = 4.0, build_dir=None
) -> str:
    """Stream a PRBS drive through the firmware on simavr; compare each DAC latch with its tick.

    The error of latch i is its cycle minus (cycle of latch 0 + tick_i * period),
    tick_i from the board's report (underruns included). Returns a summary line.
    """
    import serial

    import hybrid

    from ._board import Board
    from ._calibration import Calibration
    from ._simavr import SimavrBoard, build

    with tempfile.TemporaryDirectory() as tmp:
        elf, harness = build(build_dir or tmp)
        drive = hybrid.make_drive(
            "prbs", duration, rate=rate, seed=0, amplitude=2.0, min_hold=0.1, max_hold=1.0
        )
        codes = Calibration().codes(drive.v)
        with SimavrBoard(elf, harness, f"{tmp}/dac.log", speed=speed) as sim:
            board = Board(serial.Serial(sim.port, 250000, timeout=0.02), name=sim.port)
            board.hello()
            timing = board.configure(rate, idle_code=2048, sync_samples=5)
            report = board.play(codes)
            board.close()
        log = sim.log()
    cycles, played = log.dac_cycle[-len(codes) :], log.dac_code[-len(codes) :]
    if not np.array_equal(played, codes):
        raise RuntimeError("the DAC did not play the drive's codes")
    ticks = report.sample_ticks()
    error = (cycles - cycles[0]) - (ticks - ticks[0]) * timing.period_cycles
    rise = log.led_cycle[log.led_value == 1][-1]
    us = 1e6 / 16e6
    period_error_ppm = (timing.period - 1 / rate) * rate * 1e6
    return (
        f"{len(codes)} samples at {timing.rate:.6f} Hz (asked {rate:g} Hz; period error {period_error_ppm:+.1f} ppm): "
        f"all codes played in order; DAC latch vs tick grid: max |error| {np.max(np.abs(error)) * us:.2f} us, "
        f"RMS {np.sqrt(np.mean(error.astype(float) ** 2)) * us:.2f} us; LED edge -> sample 0 latch "
        f"{(cycles[0] - rise) * us:.1f} us ({cycles[0] - rise} cycles); underrun ticks {report.underrun_ticks}"
    )
