"""The real firmware on simavr: build it, run it behind a pty, read its DAC log.

Needs the Debian packages gcc-avr, avr-libc, simavr, libsimavr-dev (and gcc,
pkg-config, libelf-dev); ``make rig-deps`` installs them. `missing_tools`
says what is absent so tests can skip with a clear reason.

The harness ``rig/firmware/simavr/rig_sim.c`` bridges the ATmega328P's UART to a
pseudo-terminal and models an MCP4725 on the I2C bus that logs every DAC latch
with its CPU cycle (16 MHz).
"""

from __future__ import annotations

import dataclasses
import pathlib
import shutil
import signal
import subprocess
import time

import numpy as np

from ._errors import RigError

__all__ = ["FIRMWARE_DIR", "SimavrBoard", "SimavrLog", "build", "missing_tools"]

FIRMWARE_DIR = pathlib.Path(__file__).resolve().parent / "firmware"
SKETCH = FIRMWARE_DIR / "rig_dac" / "rig_dac.ino"
MAIN = FIRMWARE_DIR / "rig_dac" / "standalone_main.cpp"
HARNESS = FIRMWARE_DIR / "simavr" / "rig_sim.c"
F_CPU = 16_000_000


def missing_tools() -> str | None:
    """None when the firmware can be built and simulated here, else why not."""
    missing = [tool for tool in ("avr-g++", "gcc", "pkg-config") if shutil.which(tool) is None]
    if not pathlib.Path("/usr/include/simavr/sim_avr.h").exists():
        missing.append("libsimavr-dev (/usr/include/simavr)")
    if missing:
        return (
            "cannot build/run the firmware on simavr: missing "
            + ", ".join(missing)
            + " (run `make rig-deps` as root on Debian: gcc-avr avr-libc simavr libsimavr-dev)"
        )
    return None


def _run(cmd: list[str], what: str) -> None:
    result = subprocess.run(cmd, capture_output=True, text=True)
    if result.returncode != 0:
        raise RigError(f"{what} failed: {(result.stderr or result.stdout).strip().splitlines()[-1:]}")


def build(out_dir) -> tuple[pathlib.Path, pathlib.Path]:
    """Compile the sketch (avr-g++ -Os for the ATmega328P) and the harness; returns (elf, harness)."""
    reason = missing_tools()
    if reason:
        raise RigError(reason)
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    elf = out / "rig_dac.elf"
    harness = out / "rig_sim"
    _run(
        [
            "avr-g++",
            "-mmcu=atmega328p",
            f"-DF_CPU={F_CPU}UL",
            "-Os",
            "-Wall",
            "-Wextra",
            "-x",
            "c++",
            str(SKETCH),
            "-x",
            "none",
            str(MAIN),
            "-o",
            str(elf),
        ],
        "avr-g++ (firmware)",
    )
    flags = subprocess.run(
        ["pkg-config", "--cflags", "--libs", "simavr"], capture_output=True, text=True
    ).stdout.split() or ["-I/usr/include/simavr", "-lsimavr"]
    _run(
        ["gcc", "-O2", "-Wall", "-o", str(harness), str(HARNESS), *flags, "-lutil", "-lelf"],
        "gcc (simavr harness)",
    )
    return elf, harness


@dataclasses.dataclass
class SimavrLog:
    """Events of one run: DAC latches ``dac_cycle``/``dac_code``, LED edges, resets (CPU cycles)."""

    dac_cycle: np.ndarray
    dac_code: np.ndarray
    led_cycle: np.ndarray
    led_value: np.ndarray
    resets: list

    @classmethod
    def read(cls, path) -> SimavrLog:
        dac, led, resets = [], [], []
        for line in pathlib.Path(path).read_text().splitlines():
            parts = line.split()
            if not parts:
                continue
            if parts[0] == "dac" and len(parts) >= 3:
                dac.append((int(parts[1]), int(parts[2])))
            elif parts[0] == "led" and len(parts) >= 3:
                led.append((int(parts[1]), int(parts[2])))
            elif parts[0] == "reset":
                resets.append(int(parts[1]))
        dac_a = np.array(dac, dtype=np.int64).reshape(-1, 2)
        led_a = np.array(led, dtype=np.int64).reshape(-1, 2)
        return cls(dac_a[:, 0], dac_a[:, 1], led_a[:, 0], led_a[:, 1], resets)


class SimavrBoard:
    """The firmware running on simavr; ``port`` is the pty path to open with pyserial.

    Arguments:
        elf, harness: from `build`.
        log: the DAC/LED log file to write.
        speed: simulated seconds per wall-clock second (1 = real time).
        dac: False leaves the I2C bus empty (a wiring fault).
    """

    def __init__(self, elf, harness, log, speed: float = 1.0, dac: bool = True):
        self.log_path = pathlib.Path(log)
        cmd = [str(harness), str(elf), "--log", str(self.log_path), "--speed", str(speed)]
        if not dac:
            cmd.append("--no-dac")
        self.process = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        self.port = None
        stdout = self.process.stdout
        assert stdout is not None  # Popen(stdout=PIPE)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            line = stdout.readline()
            if not line:
                break
            if line.startswith("pty "):
                self.port = line.split()[1]
                break
        if self.port is None:
            self.close()
            raise RigError("simavr harness did not report its pty")

    def log(self) -> SimavrLog:
        return SimavrLog.read(self.log_path)

    def reset(self) -> None:
        """Reset the AVR, as the reset button or a brown-out would."""
        self.process.send_signal(signal.SIGUSR1)

    def unplug(self) -> None:
        """End the simulation: the pty disappears, like a pulled USB cable."""
        self.close()

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        if self.process.stdout:
            self.process.stdout.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
