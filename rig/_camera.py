"""Frames from a camera device or a video file, each with a timestamp.

`VideoSource` wraps ``cv2.VideoCapture``. A device (an integer index or
``/dev/videoN``) is asked for 30 fps; each frame is stamped with the driver's
timestamp when it gives one, else the host's monotonic clock at grab time.

A file's frames keep their places in time even when some are lost:

- a Motion-JPEG AVI (what lab cameras record) is read chunk by chunk through
  its index (`rig._avi`): frame k is stamped ``k / fps`` and a damaged
  frame leaves a gap, because OpenCV's FFmpeg backend skips damaged AVI chunks
  and keeps counting, so its timestamps hide the loss;
- anything else is stamped with the decoder's timestamp
  (``CAP_PROP_POS_MSEC`` after each read) while it increases, else one period
  after the previous frame (counted in ``timestamp_faults``).

``expected_frames`` is what the container announces, so a short read (a
truncated file) can be told; `VideoSource.integrity` sums it up and
`find_gaps` finds the holes in a run of timestamps. Every camera in the
rig (the virtual one too) has the same small interface: ``fps``,
``read() -> Frame | None``, ``close()``.
"""

from __future__ import annotations

import dataclasses
import math
import pathlib
import time

import cv2
import numpy as np

from ._avi import open_mjpeg_avi
from ._errors import RigError

__all__ = ["Frame", "VideoSource", "find_gaps", "open_camera"]


@dataclasses.dataclass(frozen=True)
class Frame:
    """One picture: ``index`` as delivered (from 0), ``t`` its timestamp (s), ``image``."""

    index: int
    t: float
    image: np.ndarray


class VideoSource:
    """A camera device or a video file through OpenCV (Motion-JPEG AVI files through their index).

    Arguments:
        source: device index (``0``), ``/dev/videoN``, or a video file path.
        fps: frame rate to ask a device for (files keep their own).

    Attributes:
        fps: frame rate, Hz.
        expected_frames: frames the file's container announces (None for a device or when unknown).
        time_base: how frames are stamped (words).
        timestamp_faults: frames whose decoder timestamp did not increase (stamped one period on).
        decode_failures: reads of a file the decoder failed on (damaged frames passed over).
        unplaced: frames read after a damaged stretch of an unindexed AVI: their places are unknown.
    """

    def __init__(self, source, fps: float = 30.0):
        self.source = source
        is_file = (
            isinstance(source, (str, pathlib.Path))
            and not str(source).startswith("/dev/video")
            and not str(source).isdigit()
        )
        self.is_file = is_file
        self.capture = None
        self._avi = None
        self.expected_frames: int | None = None
        self.timestamp_faults = 0
        self.decode_failures = 0
        self.unplaced = 0
        self.first_unplaced: int | None = None
        if is_file:
            path = pathlib.Path(source)
            if path.is_dir():
                raise RigError(f"video file '{path}' is a folder: give the video file inside it")
            if not path.is_file():
                raise RigError(f"video file '{path}' does not exist")
            self._avi = open_mjpeg_avi(path)
            if self._avi is None:
                self.capture = cv2.VideoCapture(str(path))
        else:
            index = int(source) if str(source).isdigit() else str(source)
            self.capture = cv2.VideoCapture(index)
            if self.capture.isOpened():
                self.capture.set(cv2.CAP_PROP_FPS, fps)
        if self._avi is not None:
            self.fps = self._avi.fps
            self.expected_frames = self._avi.expected
            self.time_base = "AVI index: frame number / fps"
            self._chunks = self._avi.frames()
        else:
            capture = self.capture
            assert capture is not None  # no AVI reader: OpenCV's, opened above
            if not capture.isOpened():
                kind = "video file" if is_file else "camera"
                raise RigError(
                    f"{kind} '{source}' cannot be opened by OpenCV: "
                    + (
                        "is it a video (MJPG AVI, MP4) and not damaged?"
                        if is_file
                        else "is it connected and not used by another program?"
                    )
                )
            reported = capture.get(cv2.CAP_PROP_FPS)
            self.fps = float(reported) if reported and 1.0 <= reported <= 1000.0 else float(fps)
            if is_file:
                count = capture.get(cv2.CAP_PROP_FRAME_COUNT)
                self.expected_frames = int(count) if count and count > 0 else None
                self.time_base = "decoder timestamps (CAP_PROP_POS_MSEC)"
            else:
                self.time_base = "driver timestamps or the host clock"
        self.index = 0
        self._t0 = time.monotonic()
        self._last_t: float | None = None
        self._first_read = True

    def read(self) -> Frame | None:
        """The next frame, or None at the end of a file."""
        if self._avi is not None:
            number, image = next(self._chunks, (None, None))
            ok = image is not None
        else:
            ok, image = self._read_capture()
        if not ok or image is None:
            if self._first_read:
                raise RigError(
                    f"no frame could be read from '{self.source}': the "
                    + (
                        "file is empty or its codec is unsupported"
                        if self.is_file
                        else "camera delivers nothing"
                    )
                )
            return None
        self._first_read = False
        if self._avi is not None:
            t = self._avi_time(number)
        else:
            assert self.capture is not None  # no AVI reader: OpenCV's
            msec = self.capture.get(cv2.CAP_PROP_POS_MSEC)
            if self.is_file:
                t = self._decoder_time(msec)
            else:
                t = msec / 1000.0 if msec and msec > 0 else time.monotonic() - self._t0
        self._last_t = t
        frame = Frame(self.index, t, image)
        self.index += 1
        return frame

    def _read_capture(self):
        """``capture.read()``; in a file, read on past frames the decoder fails on.

        FFmpeg fails one read per damaged frame and then goes on (an MP4's
        timestamps then show the gap), so up to the frames still announced
        (+ 8) failures in a row are passed over and counted.
        """
        ok, image = self.capture.read()
        if ok or not self.is_file:
            return ok, image
        left = (self.expected_frames or 0) - self.index
        for tries in range(1, max(left, 0) + 9):
            ok, image = self.capture.read()
            if ok:
                self.decode_failures += tries
                return ok, image
        return False, None

    def _step(self) -> float:
        """One period after the previous frame (0 for the first), s."""
        return 0.0 if self._last_t is None else self._last_t + 1.0 / self.fps

    def _avi_time(self, number: int | None) -> float:
        """Frame ``number``'s time, s; after an unindexed damaged stretch (None), one period on."""
        if number is not None:
            return number / self.fps
        if self.first_unplaced is None:
            self.first_unplaced = self.index
        self.unplaced += 1
        return self._step()

    def _decoder_time(self, msec: float) -> float:
        """The decoder's timestamp (ms) in s when finite, >= 0 and increasing; else one period on."""
        t = msec / 1000.0 if msec is not None and math.isfinite(msec) else math.nan
        if t >= 0 and (self._last_t is None or t > self._last_t):
            return t
        self.timestamp_faults += 1
        return self._step()

    def integrity(self) -> dict:
        """What was read against what the file announced (JSON-able)."""
        info = {
            "time_base": self.time_base,
            "fps": self.fps,
            "frames_expected": self.expected_frames,
            "frames_read": self.index,
            "timestamp_faults": self.timestamp_faults,
            "decode_failures": self.decode_failures,
        }
        if self._avi is not None:
            info.update(
                indexed=self._avi.indexed,
                damaged_frames=list(self._avi.damaged),
                empty_chunks=len(self._avi.empty),
                unplaced_frames=self.unplaced,
                first_unplaced_frame=self.first_unplaced,
            )
        return info

    def close(self) -> None:
        if self.capture is not None:
            self.capture.release()
        if self._avi is not None:
            self._chunks.close()
            self._avi.close()

    def __iter__(self):
        while (frame := self.read()) is not None:
            yield frame

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def find_gaps(t, fps: float, factor: float = 1.5) -> list[dict]:
    """Holes in a run of frame times: steps longer than ``factor`` frame periods.

    Returns one dict per gap: ``after`` (index of the frame before it), ``t_before``
    and ``t_after`` (s) and ``missing`` (whole frame periods lost, rounded).
    """
    t = np.asarray(t, float)
    period = 1.0 / fps
    steps = np.diff(t)
    return [
        {
            "after": int(i),
            "t_before": float(t[i]),
            "t_after": float(t[i + 1]),
            "missing": int(round(steps[i] / period)) - 1,
        }
        for i in np.flatnonzero(steps > factor * period)
    ]


def open_camera(source, fps: float = 30.0) -> VideoSource:
    """A `VideoSource` for a device index, ``/dev/videoN`` or a file."""
    return VideoSource(source, fps)
