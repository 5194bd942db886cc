"""The frame format: CRC against an independent implementation, framing and resync as properties."""

import binascii
import dataclasses
import re
import struct

import hypothesis.strategies as st
from hypothesis import given, settings

from rig import protocol as P
from rig._simavr import SKETCH


def test_crc_matches_binascii_and_check_value():
    # CRC-16/CCITT-FALSE's published check value, and binascii's CRC-CCITT with init 0xFFFF.
    assert P.crc16(b"123456789") == 0x29B1
    for data in (b"", b"\x00", b"\xa5\x5a\x03\x00", bytes(range(256))):
        assert P.crc16(data) == binascii.crc_hqx(data, 0xFFFF)


@given(st.binary(max_size=200))
def test_crc_property_matches_binascii(data):
    assert P.crc16(data) == binascii.crc_hqx(data, 0xFFFF)


frames = st.lists(
    st.tuples(st.integers(0, 255), st.integers(0, 255), st.binary(max_size=P.MAX_PAYLOAD)),
    min_size=1,
    max_size=12,
)
garbage = st.binary(max_size=20).map(lambda b: b.replace(b"\xa5", b"\x00"))


@settings(max_examples=200, deadline=None)
@given(frames, st.lists(garbage, min_size=13, max_size=13), st.data())
def test_frames_survive_garbage_and_any_chunking(items, noise, data):
    stream = b"".join(noise[i] + P.encode_frame(*item) for i, item in enumerate(items))
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=10)))
    parser = P.FrameParser()
    got = []
    for a, b in zip([0, *cuts], [*cuts, len(stream)]):
        got += parser.feed(stream[a:b])
    assert [(f.type, f.seq, f.payload) for f in got] == items
    assert parser.bad_frames == 0


@settings(max_examples=300, deadline=None)
@given(frames.filter(lambda f: len(f) >= 2), st.data())
def test_one_corrupt_byte_loses_at_most_its_frame(items, data):
    encoded = [P.encode_frame(*item) for item in items]
    k = data.draw(st.integers(0, len(items) - 1))
    pos = data.draw(st.integers(0, len(encoded[k]) - 1))
    flip = data.draw(st.integers(1, 255))
    bad = bytearray(encoded[k])
    bad[pos] ^= flip
    encoded[k] = bytes(bad)
    # Trailing filler flushes a frame whose length byte was corrupted upwards.
    stream = b"".join(encoded) + b"\x00" * (P.MAX_PAYLOAD + 8)
    got = [(f.type, f.seq, f.payload) for f in P.FrameParser().feed(stream)]
    others = items[:k] + items[k + 1 :]
    assert items[k] not in got or items.count(items[k]) > 1
    assert got == others


def _random_message(cls, data):
    values = []
    for code, _field in zip(re.findall(r"[BHI]", cls.FORMAT), dataclasses.fields(cls)[1:]):
        values.append(data.draw(st.integers(0, {"B": 255, "H": 65535, "I": 2**32 - 1}[code])))
    return cls(data.draw(st.integers(0, 255)), *values)


@given(st.sampled_from([P.Info, P.Ack, P.Nak, P.Status, P.Underrun, P.Done, P.Boot, P.DacError]), st.data())
def test_board_messages_round_trip(cls, data):
    message = _random_message(cls, data)
    (frame,) = P.FrameParser().feed(P.encode_message(message))
    assert P.decode_message(frame) == message


def test_data_payload_layout():
    payload = P.data_payload(70000, [0, 4095, 2048])
    assert payload == struct.pack("<IHHH", 70000, 0, 4095, 2048)
    assert len(P.config_payload(3, 8332, 2048, 15, 3, 0x60)) == 10  # the sketch checks len == 10


def test_sketch_constants_match_python():
    text = SKETCH.read_text()
    block = text[text.index("// ---- protocol") : text.index("// ---- end protocol")]
    defines = {
        name: int(value, 0) for name, value in re.findall(r"#define (\w+) (0x[0-9A-Fa-f]+|\d+)", block)
    }
    assert defines["PROTOCOL_VERSION"] == P.PROTOCOL_VERSION
    assert bytes([defines["SYNC0"], defines["SYNC1"]]) == P.SYNC
    for name in ("MAX_PAYLOAD", "RING_CAPACITY", "MAX_SAMPLES_PER_FRAME"):
        assert defines[name] == getattr(P, name), name
    for name, value in defines.items():
        if name.startswith("T_"):
            assert getattr(P, name) == value, name
    naks = {v: k for k, v in defines.items() if k.startswith("NAK_")}
    assert sorted(naks) == sorted(P.NAK_REASONS)
    states = {v for k, v in defines.items() if k.startswith("S_")}
    assert states == set(P.STATES)
    assert defines["BAUD"] == 250000
