"""The board emulated in Python, following rig/firmware/rig_dac/rig_dac.ino line by line.

Used by ``rig record --virtual`` and wherever simavr is not installed. It
serves the protocol on a pseudo-terminal (``port`` is its path, to open with
pyserial like a real port) from a thread. Time is simulated: the board's clock
runs ``speed`` times faster than the host's monotonic clock. Each timer tick
runs `timer_isr` as the sketch's ISR would; the DAC latches
``DAC_LATENCY`` s after its tick (the I2C write, as measured on simavr).

What the DAC and the LED did is kept in `dac_log` and `led_log`
(board seconds) for the virtual world: the wires from the board to the strip.
Faults for tests: `reset`, `unplug`, ``corrupt_tx`` (flip a byte of
the next frame sent).
"""

from __future__ import annotations

import os
import select
import struct
import threading
import time
import tty
from collections.abc import Callable

from . import protocol as P

__all__ = ["EmulatedBoard"]

F_CPU = 16_000_000
DAC_LATENCY = 1048 / F_CPU  # tick -> DAC latch measured on simavr (rig simavr-timing), s
RX_RING = 128


class EmulatedBoard:
    """The rig_dac firmware's behaviour on a pty.

    Arguments:
        speed: board seconds per host second (1 = real time).
        dac_present: False makes every DAC write fail (a wiring fault).
    """

    def __init__(self, speed: float = 1.0, dac_present: bool = True):
        self.speed = float(speed)
        self.dac_present = dac_present
        self.master, slave = os.openpty()
        tty.setraw(slave)
        self.port = os.ttyname(slave)
        self._slave = slave  # kept open: no hang-up while the host reconnects
        os.set_blocking(self.master, False)
        self.lock = threading.Lock()
        self.dac_log: list[tuple[float, int]] = []
        self.led_log: list[tuple[float, int]] = []
        self.corrupt_tx = 0
        # (samples played, action(board)) for tests
        self.fault_at: tuple[int, Callable[[EmulatedBoard], object]] | None = None
        self._t0 = time.monotonic()
        self._stop = threading.Event()
        self._power_up()
        self.thread = threading.Thread(target=self._run, name="emulated-board", daemon=True)
        self.thread.start()

    # ------------------------------------------------------------ clock

    def now(self) -> float:
        """Board time, s since power-up."""
        return (time.monotonic() - self._t0) * self.speed

    # ------------------------------------------------------------ setup()

    def _power_up(self, cause: int = 1) -> None:
        self.ring = [0] * P.RING_CAPACITY
        self.played = self.ticks = self.written = self.end_index = 0
        self.ended = False
        self.state = 0
        self.underrun_ticks = 0
        self.starving = False
        self.underrun_index = self.underrun_length = self.underrun_tick = 0
        self.underrun_report = self.status_due = self.done_due = self.dac_error_report = False
        self.dac_errors = 0
        self.dac_error_status = 0
        self.bad_frames = 0
        self.status_every = 8
        self.sync_samples = 15
        self.idle_code = 2048
        self.dac_addr = 0x60
        self.prescaler_code, self.top = 3, 8332
        self.timer_running = False
        self.next_tick = 0.0
        self.rx = bytearray()
        self.parse_state = 0
        self.frame = bytearray()
        self.parse_len = 0
        self.tx_seq = 0
        self.led = 0
        self._set_led(0, self.now())
        self._twi_write(self.idle_code, self.now())
        self.send_frame(P.T_BOOT, bytes((cause, P.PROTOCOL_VERSION)))

    # ------------------------------------------------------------ hardware

    @property
    def period(self) -> float:
        return (self.top + 1) * P.PRESCALERS[self.prescaler_code] / F_CPU

    def _set_led(self, value: int, t: float) -> None:
        if value != self.led or not self.led_log:
            self.led = value
            with self.lock:
                self.led_log.append((t, value))

    def _twi_write(self, code: int, t: float) -> None:
        if not self.dac_present:
            self.dac_errors += 1
            self.dac_error_status = 0x20  # SLA+W sent, NACK received
            self.dac_error_report = True
            return
        with self.lock:
            self.dac_log.append((t + DAC_LATENCY, int(code)))

    # ------------------------------------------------------------ ISR(TIMER1_COMPA_vect)

    def timer_isr(self, t: float) -> None:
        index = self.played
        if index == self.sync_samples:
            self._set_led(0, t)
        if index != self.written:
            if index == 0:
                self._set_led(1, t)
            self._twi_write(self.ring[index % P.RING_CAPACITY], t)
            self.played = index + 1
            if self.starving:
                self.starving = False
                self.underrun_tick = self.ticks
                self.underrun_report = True
            if self.ended and self.played == self.end_index:
                self.timer_running = False
                self.state = 3
                self.done_due = True
        elif self.ended and index == self.end_index:
            self.timer_running = False
            self.state = 3
            self.done_due = True
        else:
            self.underrun_ticks += 1
            if not self.starving:
                self.starving = True
                self.underrun_index = index
                self.underrun_length = 0
            self.underrun_length += 1
        self.ticks += 1
        if self.ticks % self.status_every == 0:
            self.status_due = True

    # ------------------------------------------------------------ UART

    def send_frame(self, type_: int, payload: bytes) -> None:
        data = bytearray(P.encode_frame(type_, self.tx_seq, payload))
        self.tx_seq = (self.tx_seq + 1) & 0xFF
        if self.corrupt_tx:
            self.corrupt_tx -= 1
            data[-1] ^= 0x55
        try:
            os.write(self.master, bytes(data))
        except (BlockingIOError, OSError):
            pass  # the host is not reading: bytes are lost, as on a UART

    def send_ack(self, type_: int) -> None:
        self.send_frame(P.T_ACK, struct.pack("<BII", type_, self.written, self.played + P.RING_CAPACITY))

    def send_nak(self, reason: int, type_: int) -> None:
        self.bad_frames += 1
        self.send_frame(P.T_NAK, struct.pack("<BBI", reason, type_, self.written))

    def send_status(self, t: float) -> None:
        tcnt = 0
        if self.timer_running:
            into = (t - (self.next_tick - self.period)) / self.period
            tcnt = int(max(0.0, min(1.0, into)) * self.top)
        self.send_frame(
            P.T_STATUS,
            struct.pack(
                "<BIIHHHHHI",
                self.state,
                self.played,
                self.ticks,
                tcnt,
                self.written - self.played,
                self.underrun_ticks & 0xFFFF,
                self.bad_frames & 0xFFFF,
                self.dac_errors & 0xFFFF,
                self.played + P.RING_CAPACITY,
            ),
        )

    def send_info(self) -> None:
        self.send_frame(
            P.T_INFO,
            struct.pack("<BBBHIB", P.PROTOCOL_VERSION, 1, 0, P.RING_CAPACITY, F_CPU, P.MAX_SAMPLES_PER_FRAME),
        )

    def idle_dac(self, t: float) -> None:
        self.timer_running = False
        self._set_led(0, t)
        self._twi_write(self.idle_code, t)

    # ------------------------------------------------------------ handle_frame()

    def handle_frame(self, type_: int, p: bytes, t: float) -> None:
        if type_ == P.T_HELLO:
            self.send_info()
        elif type_ == P.T_STATUS_REQ:
            self.send_status(t)
        elif type_ == P.T_CONFIG:
            if self.state in (1, 2):
                return self.send_nak(6, type_)
            if len(p) != 10:
                return self.send_nak(2, type_)
            code, top, idle, sync, every, addr = struct.unpack("<BHHHHB", p)
            if not 1 <= code <= 5 or idle > 4095 or every == 0:
                return self.send_nak(2, type_)
            self.prescaler_code, self.top, self.idle_code = code, top, idle
            self.sync_samples, self.status_every, self.dac_addr = sync, every, addr & 0x7F
            self.played = self.ticks = self.written = self.end_index = 0
            self.ended = False
            self.underrun_ticks = self.dac_errors = 0
            self.starving = self.underrun_report = self.status_due = self.done_due = False
            self.dac_error_report = False
            self.bad_frames = 0
            self.state = 0
            self.idle_dac(t)
            self.send_ack(type_)
        elif type_ == P.T_DATA:
            if self.state not in (0, 1):
                return self.send_nak(6, type_)
            if len(p) < 6 or (len(p) - 4) % 2 or (len(p) - 4) // 2 > P.MAX_SAMPLES_PER_FRAME:
                return self.send_nak(2, type_)
            count = (len(p) - 4) // 2
            first = struct.unpack_from("<I", p)[0]
            if first != self.written:
                return self.send_nak(3, type_)
            if first + count > self.played + P.RING_CAPACITY:
                return self.send_nak(4, type_)
            codes = struct.unpack_from(f"<{count}H", p, 4)
            if any(c > 4095 for c in codes):
                return self.send_nak(5, type_)
            for i, c in enumerate(codes):
                self.ring[(first + i) % P.RING_CAPACITY] = c
            self.written = first + count
            self.send_ack(type_)
        elif type_ == P.T_START:
            if self.state != 0:
                return self.send_nak(6, type_)
            self.state = 2 if self.ended else 1
            self.send_ack(type_)
            self.timer_running = True
            self.next_tick = t + self.period  # sample 0 plays at the first compare match
        elif type_ == P.T_END:
            if len(p) != 4:
                return self.send_nak(2, type_)
            if self.state not in (0, 1):
                return self.send_nak(6, type_)
            if struct.unpack("<I", p)[0] != self.written:
                return self.send_nak(3, type_)
            self.end_index = self.written
            self.ended = True
            if self.state == 1:
                self.state = 2
            self.send_ack(type_)
        elif type_ == P.T_STOP:
            self.idle_dac(t)
            self.state = 0
            self.played = self.ticks = self.written = self.end_index = 0
            self.ended = False
            self.send_ack(type_)
        else:
            self.send_nak(7, type_)

    # ------------------------------------------------------------ parse_byte()

    def parse_byte(self, byte: int, t: float) -> None:
        s = self.parse_state
        if s == 0:
            if byte == P.SYNC[0]:
                self.parse_state = 1
        elif s == 1:
            self.parse_state = 2 if byte == P.SYNC[1] else (1 if byte == P.SYNC[0] else 0)
            self.frame = bytearray()
        elif s == 2:
            self.frame.append(byte)
            if len(self.frame) == 3:
                self.parse_len = byte
                if byte > P.MAX_PAYLOAD:
                    self.parse_state = 0
                    self.send_nak(2, self.frame[0])
                    return
                self.parse_state = 3 if byte else 4
        elif s == 3:
            self.frame.append(byte)
            if len(self.frame) == 3 + self.parse_len:
                self.parse_state = 4
        elif s == 4:
            self.crc_low = byte
            self.parse_state = 5
        else:
            self.parse_state = 0
            if P.crc16(bytes(self.frame)) != (self.crc_low | byte << 8):
                return self.send_nak(1, self.frame[0])
            self.handle_frame(self.frame[0], bytes(self.frame[3:]), t)

    # ------------------------------------------------------------ loop()

    def loop(self, t: float) -> None:
        for byte in bytes(self.rx):
            self.parse_byte(byte, t)
        self.rx.clear()
        if self.underrun_report:
            self.underrun_report = False
            self.send_frame(
                P.T_UNDERRUN,
                struct.pack("<IHI", self.underrun_index, self.underrun_length & 0xFFFF, self.underrun_tick),
            )
        if self.dac_error_report:
            self.dac_error_report = False
            self.send_frame(
                P.T_DAC_ERROR,
                struct.pack("<IBH", self.ticks, self.dac_error_status, self.dac_errors & 0xFFFF),
            )
        if self.status_due:
            self.status_due = False
            self.send_status(t)
        if self.done_due:
            self.done_due = False
            self.send_frame(
                P.T_DONE,
                struct.pack(
                    "<IIHH", self.played, self.ticks, self.underrun_ticks & 0xFFFF, self.bad_frames & 0xFFFF
                ),
            )

    def _run(self) -> None:
        while not self._stop.is_set():
            t = self.now()
            while self.timer_running and self.next_tick <= t:  # every tick due, in order
                tick_t = self.next_tick
                self.next_tick += self.period
                self.timer_isr(tick_t)
                self.loop(tick_t)
                if self.fault_at is not None and self.played >= self.fault_at[0]:
                    fault, self.fault_at = self.fault_at[1], None
                    fault(self)
                    if self._stop.is_set():
                        return
            wait = 0.01
            if self.timer_running:
                wait = min(wait, max(0.0, (self.next_tick - self.now()) / self.speed))
            try:
                ready, _, _ = select.select([self.master], [], [], wait)
            except (OSError, ValueError):
                return
            if ready:
                try:
                    data = os.read(self.master, 4096)
                except BlockingIOError:
                    data = b""
                except OSError:
                    return
                if len(self.rx) + len(data) > RX_RING * 64:
                    data = data[: max(0, RX_RING * 64 - len(self.rx))]
                self.rx += data
            self.loop(self.now())

    # ------------------------------------------------------------ faults and teardown

    def reset(self) -> None:
        """Reset the board (reset button, brown-out): all state lost, BOOT sent."""
        self._power_up(cause=2)

    def unplug(self) -> None:
        """The cable is pulled: the port disappears."""
        self.close()

    def close(self) -> None:
        self._stop.set()
        if self.thread.is_alive() and threading.current_thread() is not self.thread:
            self.thread.join(timeout=2)
        for fd in (self.master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
