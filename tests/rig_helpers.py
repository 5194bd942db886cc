"""Shared fixtures for the rig tests: the firmware built once, and fault-injecting ports."""

from __future__ import annotations

import pytest

from rig._simavr import build, missing_tools


@pytest.fixture(scope="session")
def firmware(tmp_path_factory):
    """(elf, harness) built from rig/firmware, or skip with the reason."""
    reason = missing_tools()
    if reason:
        pytest.skip(reason)
    return build(tmp_path_factory.mktemp("firmware"))


class CorruptingPort:
    """A serial port that flips one byte of the ``nth`` frame of type ``type_`` it writes."""

    def __init__(self, port, type_: int, nth: int, offset: int = 9):
        self.port, self.type, self.nth, self.offset = port, type_, nth, offset
        self.seen = 0
        self.corrupted = 0

    def write(self, data: bytes) -> int:
        if len(data) > 2 and data[2] == self.type:
            self.seen += 1
            if self.seen == self.nth:
                data = bytearray(data)
                data[min(self.offset, len(data) - 1)] ^= 0x40
                data = bytes(data)
                self.corrupted += 1
        return self.port.write(data)

    def __getattr__(self, name):
        return getattr(self.port, name)

    def __setattr__(self, name, value):
        if name == "timeout":
            self.port.timeout = value
        else:
            object.__setattr__(self, name, value)
