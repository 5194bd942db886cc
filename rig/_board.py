"""Host driver of the DAC board: handshake, configuration and credit-based streaming.

`Board` wraps a pyserial-like port (``read``, ``write``, ``close``; a
real ``serial.Serial``, a pty, or a test double) and speaks the protocol of
`rig.protocol`. `Board.play` streams a whole drive of DAC codes
through the board's 256-sample ring buffer and returns a `PlayReport`
with the board's own account of what it played and when (its timer ticks).

The serial transport (frames in and out, waiting for a reply) is
`rig._link.SerialLink`; the timer setting and the report are in
`rig._playback`.

Faults raise `RigError` with one line: port missing or
unplugged, no reply, board reset mid-stream, DAC not acknowledging. Bad frames
and underruns are not fatal: they are counted and reported.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

import numpy as np

from . import protocol as P
from ._errors import RigError
from ._link import BAUD, SerialLink, failure_reason
from ._playback import F_CPU, PlayReport, Timing, sample_timing

__all__ = ["Board"]


class Board(SerialLink):
    """The DAC board on a serial port.

    Arguments:
        port: an open pyserial-like object (its ``timeout`` is set to 0.02 s).
        name: how messages name the port.
        reply_timeout: seconds to wait for a reply before calling the board silent.
    """

    def __init__(self, port, name: str = "board", reply_timeout: float = 2.0):
        super().__init__(port, name, reply_timeout)
        self.info: P.Info | None = None
        self.timing: Timing | None = None

    # ------------------------------------------------------------- opening

    @classmethod
    def open(cls, path: str, baud: int = BAUD, **kwargs) -> Board:
        """Open a serial port by path and say hello (see `hello`)."""
        import serial

        try:
            port = serial.Serial(path, baud, timeout=0.02)
        except (serial.SerialException, OSError, ValueError) as error:
            raise RigError(
                f"serial port {path} cannot be opened ({failure_reason(error)}): check the cable "
                "and the name (`rig ports` lists them)"
            ) from None
        board = cls(port, name=path, **kwargs)
        try:
            board.hello()
        except RigError:
            board.close()
            raise
        return board

    # ------------------------------------------------------------- commands

    def hello(self, attempts: int = 4) -> P.Info:
        """Ask the board who it is; tolerates the UNO's auto-reset when the port opens."""
        per_try = self.reply_timeout / 2
        for _ in range(attempts):
            self.send(P.T_HELLO)
            try:
                info = self._wait_for((P.Info,), "reply to HELLO", timeout=per_try)
            except RigError:
                continue
            if info.protocol != P.PROTOCOL_VERSION:
                raise RigError(
                    f"board on {self.name} speaks protocol {info.protocol}, this host "
                    f"speaks {P.PROTOCOL_VERSION}: flash rig/firmware/rig_dac"
                )
            self.info = info
            return info
        raise RigError(
            f"no reply to HELLO from the board on {self.name} after {attempts} tries: is "
            f"the rig_dac firmware flashed and the port at {BAUD} baud?"
        )

    def _command(self, type_: int, payload: bytes, what: str) -> P.Ack:
        self.send(type_, payload)

        def other(message):
            if isinstance(message, P.Nak) and message.rejected == type_:
                raise RigError(f"board rejected {what}: {message.reason_text}")
            if isinstance(message, P.Boot):
                raise RigError(f"board on {self.name} reset during {what}")
            if isinstance(message, P.DacError):
                raise RigError(_dac_error_text(self, message))

        while True:
            ack = self._wait_for((P.Ack,), f"acknowledgement of {what}", on_other=other)
            if ack.acked == type_:
                return ack

    def configure(
        self,
        rate: float,
        idle_code: int,
        sync_samples: int = 15,
        dac_address: int = 0x60,
        status_hz: float = 10.0,
    ) -> Timing:
        """Set the sample rate, the 0 V code (written to the DAC now), the LED length and the I2C address."""
        timing = sample_timing(rate, self.info.f_cpu if self.info else F_CPU)
        status_every = max(1, min(64, round(timing.rate / status_hz)))
        if not 0 <= idle_code <= P.CODE_MAX:
            raise RigError(f"idle code {idle_code} is outside 0..{P.CODE_MAX}")
        payload = P.config_payload(
            timing.prescaler_code,
            timing.top,
            int(idle_code),
            int(sync_samples),
            status_every,
            int(dac_address),
        )
        self._command(P.T_CONFIG, payload, "CONFIG")
        self.status_every = status_every
        self.timing = timing
        self.idle_code = int(idle_code)
        return timing

    def hold(self, code: int) -> None:
        """Put ``code`` on the DAC and hold it (for calibration): a CONFIG with that idle code."""
        self.configure(self.timing.rate if self.timing else 30.0, int(code))

    def status(self) -> P.Status:
        self.send(P.T_STATUS_REQ)
        return self._wait_for((P.Status,), "STATUS")

    def stop(self) -> None:
        """Stop playback and put the idle code back on the DAC (best effort)."""
        try:
            self.send(P.T_STOP)
        except RigError:
            pass

    # ------------------------------------------------------------- streaming

    def play(
        self,
        codes: Sequence[int] | np.ndarray,
        on_progress: Callable[[PlayReport], None] | None = None,
        should_stop: Callable[[], bool] | None = None,
        prefill: int | None = None,
        silence_timeout: float | None = None,
        on_start: Callable[[float], None] | None = None,
    ) -> PlayReport:
        """Stream ``codes`` (after `configure`) and play them; returns the board's report.

        Prefills the ring buffer, sends START, keeps the buffer topped up within
        the credits, sends END after the last sample and waits for DONE. A NAK
        rewinds the stream to the board's next expected index (go-back-N).

        Arguments:
            codes: DAC codes 0..4095.
            on_progress: called with the report after each STATUS.
            should_stop: polled; True stops the board and ends the stream early.
            prefill: samples sent before START (default: the whole buffer).
            silence_timeout: seconds without any frame from the board that count
                as a dead link (default: 2 s + 3 STATUS periods).
            on_start: called with the host time at which START was acknowledged.

        Raises:
            RigError: port failure, board reset, DAC fault, silent board. The
            partial report is attached as the error's ``report`` attribute.
        """
        if self.timing is None:
            raise RigError("configure the board (rate, idle code) before playing")
        given = np.asarray(codes)
        if given.ndim != 1 or len(given) == 0:
            raise RigError("play needs a non-empty 1-D sequence of DAC codes")
        if np.any((given < 0) | (given > P.CODE_MAX)) or not np.all(given == np.round(given)):
            raise RigError(f"DAC codes must be integers in 0..{P.CODE_MAX}")
        dac = given.astype(np.int64)
        n = len(dac)
        report = PlayReport(n=n, timing=self.timing)
        try:
            self._play(dac, report, on_progress, should_stop, prefill, silence_timeout, on_start)
        except RigError as error:
            report.error = str(error)
            report.bad_frames_host = self.parser.bad_frames
            self.stop()
            error.report = report
            raise
        report.bad_frames_host = self.parser.bad_frames
        return report

    def _play(self, codes, report, on_progress, should_stop, prefill, silence_timeout, on_start):
        n = len(codes)
        capacity = self.info.capacity if self.info else P.RING_CAPACITY
        per_frame = self.info.max_samples if self.info else P.MAX_SAMPLES_PER_FRAME
        status_period = self.status_every * self.timing.period
        silence = silence_timeout if silence_timeout is not None else 2.0 + 3 * status_period
        state = {
            "sent": 0,
            "limit": capacity,
            "acked": 0,
            "rewound": -1,
            "last_progress": time.monotonic(),
            "heard": time.monotonic(),
            "started": False,
            "end_sent": False,
            "done": None,
        }
        self.parser.bad_frames = 0

        def send_some(upto: int) -> None:
            while state["sent"] < min(upto, state["limit"], n):
                first = state["sent"]
                count = min(per_frame, n - first, state["limit"] - first)
                self.send(P.T_DATA, P.data_payload(first, codes[first : first + count]))
                state["sent"] = first + count
            if state["started"] and state["sent"] == n and state["acked"] == n and not state["end_sent"]:
                self.send(P.T_END, P.end_payload(n))
                state["end_sent"] = True

        def handle(message) -> None:
            state["heard"] = time.monotonic()
            if isinstance(message, P.Ack):
                state["limit"] = max(state["limit"], message.limit)
                if message.next_index > state["acked"]:
                    state["acked"] = message.next_index
                    state["last_progress"] = time.monotonic()
            elif isinstance(message, P.Nak):
                report.bad_frames_board += 1
                if message.reason == 4 or message.reason == 5 or message.reason == 6:  # host bugs
                    raise RigError(
                        f"board rejected a frame: {message.reason_text} at sample {message.next_index}"
                    )
                if message.next_index < state["sent"] and message.next_index != state["rewound"]:
                    report.resent_samples += state["sent"] - message.next_index
                    state["sent"] = message.next_index
                    state["rewound"] = message.next_index
            elif isinstance(message, P.Status):
                state["limit"] = max(state["limit"], message.limit)
                report.played, report.ticks = message.played, message.ticks
                report.underrun_ticks = message.underrun_ticks
                report.dac_errors = message.dac_errors
                report.statuses.append((state["heard"], message.ticks, message.played))
                if on_progress is not None:
                    on_progress(report)
            elif isinstance(message, P.Underrun):
                report.underruns.append((message.index, message.length, message.tick))
            elif isinstance(message, P.Done):
                state["done"] = message
            elif isinstance(message, P.Boot):
                raise RigError(
                    f"board on {self.name} reset during the stream after "
                    f"{report.played} of {n} samples (power glitch or reset button?)"
                )
            elif isinstance(message, P.DacError):
                report.dac_errors = message.count
                raise RigError(_dac_error_text(self, message))

        # Prefill, then START once the board has acknowledged the prefill.
        send_some(prefill if prefill is not None else capacity)
        target = state["sent"]
        deadline = time.monotonic() + self.reply_timeout
        while state["acked"] < target:
            for message in self.receive():
                handle(message)
            send_some(target)
            if time.monotonic() > deadline:
                raise RigError(
                    f"board on {self.name} did not acknowledge the prefill "
                    f"({state['acked']} of {target} samples) within {self.reply_timeout:g} s"
                )
        self._command(P.T_START, b"", "START")
        report.start_time = time.monotonic()
        state["started"] = True
        state["heard"] = state["last_progress"] = report.start_time
        if on_start is not None:
            on_start(report.start_time)
        send_some(n)

        while state["done"] is None:
            if should_stop is not None and should_stop():
                self.stop()
                report.error = "stopped by the host"
                return
            for message in self.receive():
                handle(message)
            now = time.monotonic()
            if state["sent"] > state["acked"] and now - state["last_progress"] > 0.5:
                # A frame vanished without a NAK: go back to what the board has.
                report.resent_samples += state["sent"] - state["acked"]
                state["sent"] = state["acked"]
                state["rewound"] = state["acked"]
                state["last_progress"] = now
            send_some(n)
            if now - state["heard"] > silence:
                raise RigError(
                    f"board on {self.name} went silent for {silence:.1f} s after "
                    f"{report.played} of {n} samples: cable pulled or board hung?"
                )
        done = state["done"]
        report.played, report.ticks = done.played, done.ticks
        report.underrun_ticks = done.underrun_ticks
        report.complete = done.played == n


def _dac_error_text(board: Board, message: P.DacError) -> str:
    return (
        f"DAC did not acknowledge its I2C write (TWI status 0x{message.twi_status:02x}) at tick "
        f"{message.tick}: check the MCP4725 wiring (SDA A4, SCL A5, power) and its address"
    )
