"""Serial transport to the DAC board: frames written to and read from a pyserial-like port.

`SerialLink` wraps the port (``read``, ``write``, ``close``; a real
``serial.Serial``, a pty, or a test double), numbers and encodes outgoing frames
with `rig.protocol`, decodes what arrives (bad frames are counted, not
fatal) and waits for a reply of a given kind. A failing port raises
`RigError` with one line. The commands the board
understands are `rig._board.Board`'s.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TypeVar

from . import protocol as P
from ._errors import RigError

__all__ = ["BAUD", "SerialLink"]

#: A kind of message `_wait_for` waits for.
M = TypeVar("M", bound=P.Message)

#: UART speed of the firmware: exact at 16 MHz (U2X, UBRR0 = 7).
BAUD = 250000


class SerialLink:
    """Frames over a serial port.

    Arguments:
        port: an open pyserial-like object (its ``timeout`` is set to 0.02 s).
        name: how messages name the port.
        reply_timeout: seconds to wait for a reply before calling the board silent.
    """

    def __init__(self, port, name: str = "board", reply_timeout: float = 2.0):
        self.port = port
        self.name = name
        self.reply_timeout = reply_timeout
        self.parser = P.FrameParser()
        self._seq = 0
        try:
            port.timeout = 0.02
        except (AttributeError, ValueError):
            pass

    def close(self) -> None:
        try:
            self.port.close()
        except Exception:  # closing a port that vanished must not hide the real error
            pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # ------------------------------------------------------------- low level

    def send(self, type_: int, payload: bytes = b"") -> None:
        """Write one frame."""
        frame = P.encode_frame(type_, self._seq, payload)
        self._seq = (self._seq + 1) & 0xFF
        try:
            self.port.write(frame)
        except Exception as error:  # pyserial raises SerialException, ptys OSError
            raise RigError(
                f"serial port {self.name} failed while writing ({failure_reason(error)}): "
                "was the board unplugged?"
            ) from None

    def receive(self) -> list[P.Message]:
        """Read what has arrived (waits up to the port timeout) and decode it."""
        try:
            data = self.port.read(4096)
        except Exception as error:
            raise RigError(
                f"serial port {self.name} failed while reading ({failure_reason(error)}): "
                "was the board unplugged?"
            ) from None
        messages = []
        for frame in self.parser.feed(data or b""):
            try:
                messages.append(P.decode_message(frame))
            except ValueError:
                self.parser.bad_frames += 1
        return messages

    def _wait_for(
        self,
        kinds: tuple[type[M], ...],
        what: str,
        timeout: float | None = None,
        on_other: Callable | None = None,
    ) -> M:
        deadline = time.monotonic() + (self.reply_timeout if timeout is None else timeout)
        while time.monotonic() < deadline:
            for message in self.receive():
                if isinstance(message, kinds):
                    return message
                if on_other is not None:
                    on_other(message)
        raise RigError(
            f"no {what} from the board on {self.name} within "
            f"{self.reply_timeout if timeout is None else timeout:g} s: is the rig_dac "
            f"firmware flashed and the port at {BAUD} baud?"
        )


def failure_reason(error: Exception) -> str:
    text = str(error).strip() or type(error).__name__
    return text.splitlines()[0]
