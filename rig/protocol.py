"""The binary protocol between the host and the DAC board (``rig/firmware/rig_dac``).

Every message, both ways, is one frame::

    A5 5A | type | seq | len | payload (len bytes, <= 64) | crc16 (2 bytes, little-endian)

``crc16`` is CRC-16/CCITT-FALSE (polynomial 0x1021, initial value 0xFFFF, no
reflection, no final xor) over ``type, seq, len, payload``. Multi-byte fields
are little-endian. ``seq`` counts each sender's frames modulo 256 (it lets a
log show a lost frame; sample order is carried by sample indices instead).

The host streams DAC codes in DATA frames that carry the absolute index of
their first sample; the board accepts only the next index it expects, and
grants credits as an absolute limit: the host may send samples with
``index < limit`` (``limit = played + capacity``). rig/README.md has the full
table of messages; the constants here are checked against the sketch's
``#define`` lines by the tests.
"""

from __future__ import annotations

import dataclasses
import struct
from typing import ClassVar

__all__ = [
    "Frame",
    "FrameParser",
    "crc16",
    "encode_frame",
    "decode_message",
    "Message",
    "Info",
    "Ack",
    "Nak",
    "Status",
    "Underrun",
    "Done",
    "Boot",
    "DacError",
]

PROTOCOL_VERSION = 1
SYNC = b"\xa5\x5a"
MAX_PAYLOAD = 64
RING_CAPACITY = 256
MAX_SAMPLES_PER_FRAME = 24
CODE_MAX = 4095

# host -> board
T_HELLO = 0x01
T_CONFIG = 0x02
T_DATA = 0x03
T_START = 0x04
T_STOP = 0x05
T_END = 0x06
T_STATUS_REQ = 0x07
# board -> host
T_INFO = 0x81
T_ACK = 0x82
T_NAK = 0x83
T_STATUS = 0x84
T_UNDERRUN = 0x85
T_DONE = 0x86
T_BOOT = 0x87
T_DAC_ERROR = 0x88

NAK_REASONS = {
    1: "bad checksum",
    2: "bad length",
    3: "out of order",
    4: "credit overflow",
    5: "code above 4095",
    6: "not allowed in this state",
    7: "unknown frame type",
}
STATES = {0: "idle", 1: "running", 2: "draining", 3: "done"}

#: Timer1 prescaler: CS12..CS10 value -> division of the 16 MHz clock.
PRESCALERS = {1: 1, 2: 8, 3: 64, 4: 256, 5: 1024}


def crc16(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE of ``data`` (``crc16(b"123456789") == 0x29B1``)."""
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


@dataclasses.dataclass(frozen=True)
class Frame:
    """One decoded frame: ``type``, ``seq`` (0..255) and the raw ``payload``."""

    type: int
    seq: int
    payload: bytes


def encode_frame(type_: int, seq: int, payload: bytes = b"") -> bytes:
    """The bytes of one frame (sync, header, payload, CRC)."""
    if not 0 <= type_ <= 255 or not 0 <= seq <= 255:
        raise ValueError(f"frame type {type_} and seq {seq} must be bytes (0..255)")
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"frame payload of {len(payload)} bytes exceeds {MAX_PAYLOAD}")
    body = bytes((type_, seq, len(payload))) + bytes(payload)
    return SYNC + body + struct.pack("<H", crc16(body))


class FrameParser:
    """Incremental frame decoder: feed it bytes in any chunks, get whole frames.

    Bytes that are not part of a valid frame are skipped: after a bad CRC or an
    impossible length the parser resynchronises on the next ``A5 5A`` *after*
    the rejected frame's first sync byte, so a corrupted frame never hides the
    good one that follows. ``bad_frames`` counts rejected frames,
    ``skipped_bytes`` the bytes thrown away.
    """

    def __init__(self) -> None:
        self._buffer = bytearray()
        self.bad_frames = 0
        self.skipped_bytes = 0

    def feed(self, data: bytes) -> list[Frame]:
        """Append ``data`` and return every complete, valid frame now in the buffer."""
        self._buffer += data
        frames = []
        buf = self._buffer
        while True:
            start = buf.find(SYNC)
            if start < 0:
                keep = 1 if buf.endswith(SYNC[:1]) else 0
                self.skipped_bytes += len(buf) - keep
                del buf[: len(buf) - keep]
                break
            if start:
                self.skipped_bytes += start
                del buf[:start]
            if len(buf) < 5:
                break
            length = buf[4]
            if length > MAX_PAYLOAD:
                self._reject(buf)
                continue
            end = 5 + length + 2
            if len(buf) < end:
                break
            body = bytes(buf[2 : 5 + length])
            (crc,) = struct.unpack_from("<H", buf, 5 + length)
            if crc16(body) != crc:
                self._reject(buf)
                continue
            frames.append(Frame(body[0], body[1], body[3:]))
            del buf[:end]
        return frames

    def _reject(self, buf: bytearray) -> None:
        self.bad_frames += 1
        self.skipped_bytes += 1
        del buf[:1]


# --------------------------------------------------------------------------- #
# Host -> board payloads
# --------------------------------------------------------------------------- #


def config_payload(
    prescaler_code: int, top: int, idle_code: int, sync_samples: int, status_every: int, dac_address: int
) -> bytes:
    """CONFIG: Timer1 prescaler code and OCR1A, the 0 V code, LED samples, STATUS period, I2C address."""
    return struct.pack("<BHHHHB", prescaler_code, top, idle_code, sync_samples, status_every, dac_address)


def data_payload(first_index: int, codes) -> bytes:
    """DATA: index of the first sample (uint32) then up to 24 codes (uint16, 0..4095)."""
    codes = [int(c) for c in codes]
    if not 1 <= len(codes) <= MAX_SAMPLES_PER_FRAME:
        raise ValueError(f"a DATA frame holds 1..{MAX_SAMPLES_PER_FRAME} samples, got {len(codes)}")
    return struct.pack(f"<I{len(codes)}H", first_index, *codes)


def end_payload(total: int) -> bytes:
    """END: the total number of samples in the drive."""
    return struct.pack("<I", total)


# --------------------------------------------------------------------------- #
# Board -> host messages
# --------------------------------------------------------------------------- #


@dataclasses.dataclass(frozen=True)
class Message:
    """Base of the decoded board messages; ``seq`` is the frame's sequence number."""

    TYPE: ClassVar[int] = -1
    FORMAT: ClassVar[str] = ""
    seq: int

    @classmethod
    def decode(cls, frame: Frame) -> Message:
        if len(frame.payload) != struct.calcsize(cls.FORMAT):
            raise ValueError(
                f"{cls.__name__} frame has {len(frame.payload)} payload bytes, "
                f"expected {struct.calcsize(cls.FORMAT)}"
            )
        return cls(frame.seq, *struct.unpack(cls.FORMAT, frame.payload))


@dataclasses.dataclass(frozen=True)
class Info(Message):
    """Reply to HELLO: versions, ring capacity (samples), clock (Hz), samples per DATA frame."""

    TYPE: ClassVar[int] = T_INFO
    FORMAT: ClassVar[str] = "<BBBHIB"
    protocol: int
    fw_major: int
    fw_minor: int
    capacity: int
    f_cpu: int
    max_samples: int


@dataclasses.dataclass(frozen=True)
class Ack(Message):
    """A frame accepted: the next sample index expected and the credit limit."""

    TYPE: ClassVar[int] = T_ACK
    FORMAT: ClassVar[str] = "<BII"
    acked: int
    next_index: int
    limit: int


@dataclasses.dataclass(frozen=True)
class Nak(Message):
    """A frame rejected, with the reason (``NAK_REASONS``) and the next index expected."""

    TYPE: ClassVar[int] = T_NAK
    FORMAT: ClassVar[str] = "<BBI"
    reason: int
    rejected: int
    next_index: int

    @property
    def reason_text(self) -> str:
        return NAK_REASONS.get(self.reason, f"reason {self.reason}")


@dataclasses.dataclass(frozen=True)
class Status(Message):
    """Periodic report: state, samples played, timer ticks since START (the board's
    clock, one per sample period), Timer1 count into the current tick, buffer level
    (samples), underrun ticks, bad frames, DAC errors, credit limit."""

    TYPE: ClassVar[int] = T_STATUS
    FORMAT: ClassVar[str] = "<BIIHHHHHI"
    state: int
    played: int
    ticks: int
    tcnt: int
    level: int
    underrun_ticks: int
    bad_frames: int
    dac_errors: int
    limit: int


@dataclasses.dataclass(frozen=True)
class Underrun(Message):
    """An underrun episode ended: sample ``index`` came ``length`` ticks late and played at ``tick``."""

    TYPE: ClassVar[int] = T_UNDERRUN
    FORMAT: ClassVar[str] = "<IHI"
    index: int
    length: int
    tick: int


@dataclasses.dataclass(frozen=True)
class Done(Message):
    """The drive has played to its END: samples played, ticks, underrun ticks, bad frames."""

    TYPE: ClassVar[int] = T_DONE
    FORMAT: ClassVar[str] = "<IIHH"
    played: int
    ticks: int
    underrun_ticks: int
    bad_frames: int


@dataclasses.dataclass(frozen=True)
class Boot(Message):
    """Sent once after power-up or reset: the MCUSR reset cause and the protocol version."""

    TYPE: ClassVar[int] = T_BOOT
    FORMAT: ClassVar[str] = "<BB"
    cause: int
    protocol: int


@dataclasses.dataclass(frozen=True)
class DacError(Message):
    """The DAC did not acknowledge a write (TWI status), at timer tick ``tick``."""

    TYPE: ClassVar[int] = T_DAC_ERROR
    FORMAT: ClassVar[str] = "<IBH"
    tick: int
    twi_status: int
    count: int


_MESSAGES = {cls.TYPE: cls for cls in (Info, Ack, Nak, Status, Underrun, Done, Boot, DacError)}


def decode_message(frame: Frame) -> Message:
    """The typed message of a board frame; ``ValueError`` for an unknown type or size."""
    cls = _MESSAGES.get(frame.type)
    if cls is None:
        raise ValueError(f"unknown board frame type 0x{frame.type:02x}")
    return cls.decode(frame)


def encode_message(message: Message) -> bytes:
    """The frame of a board message (the board emulator and tests use this)."""
    fields = [getattr(message, f.name) for f in dataclasses.fields(message)][1:]
    return encode_frame(message.TYPE, message.seq, struct.pack(message.FORMAT, *fields))
