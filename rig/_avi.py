"""Motion-JPEG AVI files read chunk by chunk, so every frame keeps its place in time.

Why: OpenCV's FFmpeg backend (opencv-python 5.0) stamps AVI frames by
counting the packets it delivers. When part of the file is damaged the demuxer
skips the damaged chunks and the timestamps (``CAP_PROP_POS_MSEC``,
``CAP_PROP_PTS``) stay uniform, so every later frame looks one period early
per lost frame; a truncated file just ends early. Here the AVI's own index
(``idx1``) says where frame ``k`` is, so a lost frame is a known gap and every
other frame keeps ``t = k / fps``.

Layout read: ``RIFF 'AVI '`` with ``LIST 'hdrl'`` (``avih`` total frames,
the first video stream's ``strh``: codec, rate/scale, length; ``strf``: size),
``LIST 'movi'`` (chunks ``NNdc`` / ``NNdb``, NN the stream number, possibly
inside ``LIST 'rec '``), and ``idx1`` at the end (offsets from the ``movi``
tag, or from the file's start). Without ``idx1`` (a truncated file loses it;
OpenDML files over 1 GB have ``AVIX`` parts) the ``movi`` chunks are walked in
order; after a damaged stretch there the walk resynchronises on the next frame
chunk, and the frames after it have unknown places (reported).

A frame chunk is *damaged* when its header is not where the index says, it
runs past the end of the file, it does not start with a JPEG SOI marker, it
lacks the EOI marker the file's other frames end with, or the JPEG does not
decode. Damaged frames are reported as lost. MJPEG from webcams often has no
Huffman tables (AVI1); the standard ones are put in, as decoders do.
"""

from __future__ import annotations

import dataclasses
import mmap
import pathlib
import re
import struct

import cv2
import numpy as np

__all__ = ["AviChunk", "MjpegAvi", "open_mjpeg_avi"]

_SOI, _EOI, _DHT, _SOS = b"\xff\xd8", b"\xff\xd9", b"\xff\xc4", b"\xff\xda"
_MJPEG = {b"MJPG", b"mjpg", b"AVRn", b"LJPG", b"dmb1", b"JPEG", b"jpeg", b"MJLS"}
_CHUNK_ID = re.compile(rb"^([0-9]{2}(dc|db|wb|tx|pc)|ix[0-9]{2}|JUNK|LIST|idx1|RIFF)$")


@dataclasses.dataclass(frozen=True)
class AviChunk:
    """One frame's chunk: ``number`` (frame k of the stream, None when unknown), file ``offset``
    of its data and ``size``, bytes."""

    number: int | None
    offset: int
    size: int  # -1 (and offset -1) when the index points at something that is not this chunk


class MjpegAvi:
    """The frames of a Motion-JPEG AVI, in order, with their frame numbers.

    Attributes:
        fps: frame rate from the stream header (rate / scale), Hz.
        expected: frames the headers announce (largest of ``avih``, ``strh`` length, ``dmlh``).
        size: (width, height) from the stream format, px.
        chunks: the frame chunks found, in file order (``number`` None after an unindexed resync).
        indexed: whether ``idx1`` gave the chunks (else a walk of ``movi``).
        damaged: frame numbers (or file offsets, for unnumbered chunks) that could not be read.
        empty: frame numbers of empty chunks (the writer repeated the previous frame).
    """

    def __init__(
        self,
        path,
        data,
        fps: float,
        expected: int,
        size: tuple[int, int],
        chunks: list[AviChunk],
        indexed: bool,
        requires_eoi: bool,
    ):
        self.path = pathlib.Path(path)
        self._data = data
        self.fps, self.expected, self.size = fps, expected, size
        self.chunks, self.indexed = chunks, indexed
        self.requires_eoi = requires_eoi
        self.damaged: list[int] = []
        self.empty: list[int] = []

    def close(self) -> None:
        """Release the file."""
        self._data.close()

    def decode(self, chunk: AviChunk) -> np.ndarray | None:
        """The chunk's picture (BGR), or None when it is damaged."""
        if chunk.offset < 0:
            return None
        payload = bytes(self._data[chunk.offset : chunk.offset + chunk.size])
        if not _looks_like_jpeg(payload, self.requires_eoi):
            return None
        image = cv2.imdecode(np.frombuffer(with_huffman_tables(payload), np.uint8), cv2.IMREAD_COLOR)
        if image is None or (image.shape[1], image.shape[0]) != self.size:
            return None
        return image

    def frames(self):
        """Yield ``(frame number or None, BGR image)`` for every readable frame, in order."""
        for chunk in self.chunks:
            if chunk.size == 0:
                self.empty.append(chunk.number)
                continue
            image = self.decode(chunk)
            if image is None:
                self.damaged.append(chunk.number if chunk.number is not None else -chunk.offset)
                continue
            yield chunk.number, image


def _looks_like_jpeg(payload: bytes, requires_eoi: bool) -> bool:
    """SOI at the start and, when the file's frames have one, EOI at the end (zero padding allowed)."""
    if not payload.startswith(_SOI):
        return False
    return not requires_eoi or payload.rstrip(b"\x00").endswith(_EOI)


_TABLES: bytes | None = None


def _standard_huffman_tables() -> bytes:
    """The DHT segments of a baseline JPEG with the standard tables (those libjpeg writes by default)."""
    global _TABLES
    if _TABLES is None:
        ok, jpeg = cv2.imencode(".jpg", np.zeros((8, 8, 3), np.uint8))
        data = bytes(jpeg)
        tables, pos = [], 2
        while pos + 4 <= len(data) and data[pos] == 0xFF and data[pos + 1] != 0xDA:
            length = struct.unpack(">H", data[pos + 2 : pos + 4])[0]
            if data[pos + 1] == 0xC4:
                tables.append(data[pos : pos + 2 + length])
            pos += 2 + length
        _TABLES = b"".join(tables)
    return _TABLES


def with_huffman_tables(payload: bytes) -> bytes:
    """``payload`` with the standard Huffman tables put after SOI if it has none before its scan."""
    scan = payload.find(_SOS)
    if scan < 0 or payload.find(_DHT, 0, scan) >= 0:
        return payload
    return payload[:2] + _standard_huffman_tables() + payload[2:]


def _u32(data, pos: int) -> int:
    return struct.unpack_from("<I", data, pos)[0]


def _walk(data, start: int, end: int):
    """Yield ``(fourcc, data offset, size, list type or None)`` of the chunks in ``data[start:end]``."""
    pos = start
    while pos + 8 <= end:
        fourcc, size = data[pos : pos + 4], _u32(data, pos + 4)
        kind = data[pos + 8 : pos + 12] if fourcc in (b"RIFF", b"LIST") else None
        yield fourcc, pos + 8, size, kind
        pos += 8 + size + (size & 1)


@dataclasses.dataclass
class _Headers:
    fps: float = 0.0
    expected: int = 0
    size: tuple[int, int] = (0, 0)
    codec: tuple[bytes, bytes] = (b"", b"")  # strh handler, strf compression
    stream: int | None = None  # number of the first video stream
    streams: int = 0
    movi: list[tuple[int, int]] = dataclasses.field(default_factory=list)  # ('movi' tag position, end)
    idx1: tuple[int, int] | None = None  # (data offset, size)
    extended: bool = False  # OpenDML AVIX parts


def _read_headers(data) -> _Headers:
    head = _Headers()
    riff_pos = 0
    while riff_pos + 12 <= len(data) and data[riff_pos : riff_pos + 4] == b"RIFF":
        riff_size = _u32(data, riff_pos + 4)
        riff_end = min(len(data), riff_pos + 8 + riff_size)
        head.extended |= data[riff_pos + 8 : riff_pos + 12] == b"AVIX"
        for fourcc, offset, size, kind in _walk(data, riff_pos + 12, riff_end):
            if fourcc == b"LIST" and kind == b"movi":
                head.movi.append((offset, min(riff_end, offset + size)))
            elif fourcc == b"LIST" and kind in (b"hdrl", b"odml"):
                _read_header_list(data, offset + 4, min(riff_end, offset + size), head)
            elif fourcc == b"idx1" and offset + size <= len(data):
                head.idx1 = (offset, size)
        riff_pos = riff_pos + 8 + riff_size + (riff_size & 1)
    return head


def _read_header_list(data, start: int, end: int, head: _Headers) -> None:
    """``avih``, ``dmlh`` and the streams' ``strl`` lists of ``hdrl`` / ``odml``."""
    for fourcc, offset, size, kind in _walk(data, start, end):
        if fourcc == b"avih" and size >= 20:
            head.expected = max(head.expected, _u32(data, offset + 16))
            if _u32(data, offset) and not head.fps:
                head.fps = 1e6 / _u32(data, offset)
        elif fourcc == b"dmlh" and size >= 4:
            head.expected = max(head.expected, _u32(data, offset))
        elif fourcc == b"LIST" and kind == b"strl":
            if head.stream is None:
                _read_stream(data, offset + 4, min(end, offset + size), head)
            head.streams += 1


def _read_stream(data, start: int, end: int, head: _Headers) -> None:
    """A stream's ``strh`` and ``strf``: taken if it is video (fps, length, codec, size)."""
    fields = {fourcc: (offset, size) for fourcc, offset, size, _ in _walk(data, start, end)}
    if b"strh" not in fields or fields[b"strh"][1] < 36:
        return
    offset = fields[b"strh"][0]
    if data[offset : offset + 4] != b"vids":
        return
    head.stream = head.streams
    scale, rate, length = _u32(data, offset + 20), _u32(data, offset + 24), _u32(data, offset + 32)
    if scale and rate:
        head.fps = rate / scale
    head.expected = max(head.expected, length)
    compression = b""
    if b"strf" in fields and fields[b"strf"][1] >= 20:
        at = fields[b"strf"][0]
        width, height = struct.unpack_from("<ii", data, at + 4)
        head.size = (abs(width), abs(height))
        compression = bytes(data[at + 16 : at + 20])
    head.codec = (bytes(data[offset + 4 : offset + 8]), compression)


def _indexed_chunks(data, head: _Headers, ids: tuple[bytes, ...]) -> list[AviChunk] | None:
    """Frame chunks from ``idx1`` (numbered), or None if the index is unusable."""
    if head.idx1 is None:
        return None
    offset, size = head.idx1
    entries = [struct.unpack_from("<4sIII", data, offset + 16 * i) for i in range(size // 16)]
    video = [(cid, off, length) for cid, _flags, off, length in entries if cid in ids]
    if not video or not head.movi:
        return None
    movi = head.movi[0][0]
    # Offsets count from the 'movi' tag (usual) or from the file's start: try both on the first entry.
    base = None
    for candidate in (movi, 0):
        cid, off, length = video[0]
        pos = candidate + off
        if data[pos : pos + 4] == cid and (length == 0 or _u32(data, pos + 4) == length):
            base = candidate
            break
    if base is None:
        return None
    chunks = []
    for number, (cid, off, length) in enumerate(video):
        pos = base + off
        intact = (
            pos + 8 + length <= len(data) and data[pos : pos + 4] == cid and _u32(data, pos + 4) == length
        )
        chunks.append(AviChunk(number, pos + 8 if intact else -1, length if intact else -1))
    return chunks


def _walked_chunks(data, head: _Headers, ids: tuple[bytes, ...]) -> list[AviChunk]:
    """Frame chunks found by walking the ``movi`` lists; unnumbered after a resync."""
    chunks: list[AviChunk] = []
    numbered = True
    for start, end in head.movi:
        pos = start + 4
        while pos + 8 <= end:
            fourcc, size = data[pos : pos + 4], _u32(data, pos + 4)
            if fourcc == b"LIST":
                pos += 12
                continue
            if not _CHUNK_ID.match(fourcc) or pos + 8 + size > len(data):
                if pos + 8 + size > len(data) and _CHUNK_ID.match(fourcc):
                    break  # the file ends inside this chunk: truncated
                numbered = False  # damaged: resynchronise on the next frame chunk
                pos = _resync(data, pos + 1, end, ids)
                continue
            if fourcc in ids:
                chunks.append(AviChunk(len(chunks) if numbered else None, pos + 8, size))
            pos += 8 + size + (size & 1)
    return chunks


def _resync(data, pos: int, end: int, ids: tuple[bytes, ...]) -> int:
    """Position of the next plausible frame chunk header after ``pos`` (``end`` if none)."""
    while pos < end:
        hits = [h for h in (data.find(i, pos, end) for i in ids) if h >= 0]
        if not hits:
            return end
        pos = min(hits)
        size = _u32(data, pos + 4) if pos + 8 <= len(data) else 0
        if pos + 8 + size <= len(data) and data[pos + 8 : pos + 10] == _SOI:
            return pos
        pos += 1
    return end


def open_mjpeg_avi(path) -> MjpegAvi | None:
    """An `MjpegAvi` for a Motion-JPEG AVI whose first frame decodes here; None for anything else.

    None means: read it with OpenCV instead (another codec, another container,
    or a JPEG flavour this reader does not decode).
    """
    path = pathlib.Path(path)
    try:
        with path.open("rb") as handle:
            if handle.read(12)[8:12] != b"AVI ":
                return None
            data = mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ)
    except (OSError, ValueError):
        return None
    avi = _open(path, data)
    if avi is None:
        data.close()
    return avi


def _open(path: pathlib.Path, data) -> MjpegAvi | None:
    head = _read_headers(data)
    if head.stream is None or not head.movi or not any(c in _MJPEG for c in head.codec):
        return None
    ids = (b"%02ddc" % head.stream, b"%02ddb" % head.stream)
    chunks = None
    if head.idx1 is not None and not head.extended:
        chunks = _indexed_chunks(data, head, ids)
    indexed = chunks is not None
    if chunks is None:
        chunks = _walked_chunks(data, head, ids)
    first = next((c for c in chunks if c.size > 0 and data[c.offset : c.offset + 2] == _SOI), None)
    if first is None or not head.fps:
        return None
    requires_eoi = data[first.offset : first.offset + first.size].rstrip(b"\x00").endswith(_EOI)
    avi = MjpegAvi(
        path,
        data,
        head.fps,
        max(head.expected, len(chunks) if indexed else 0),
        head.size,
        chunks,
        indexed,
        requires_eoi,
    )
    if avi.decode(first) is None:
        return None  # a JPEG flavour OpenCV's imdecode cannot read
    return avi
