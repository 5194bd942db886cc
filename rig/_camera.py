"""Frames from a camera device or a video file, each with a timestamp.

:class:`VideoSource` wraps ``cv2.VideoCapture``. A device (an integer index or
``/dev/videoN``) is asked for 30 fps; each frame is stamped with the driver's
timestamp when it gives one, else the host's monotonic clock at grab time. A
file's frames are stamped ``index / fps``. Every camera in the rig (the virtual
one too) has the same small interface: ``fps``, ``read() -> Frame | None``,
``close()``.
"""

from __future__ import annotations

import dataclasses
import pathlib
import time

import cv2
import numpy as np

from ._errors import RigError

__all__ = ["Frame", "VideoSource", "open_camera"]


@dataclasses.dataclass(frozen=True)
class Frame:
    """One picture: ``index`` as delivered (from 0), ``t`` its timestamp (s), ``image``."""

    index: int
    t: float
    image: np.ndarray


class VideoSource:
    """A camera device or a video file through OpenCV.

    Arguments:
        source: device index (``0``), ``/dev/videoN``, or a video file path.
        fps: frame rate to ask a device for (files keep their own).
    """

    def __init__(self, source, fps: float = 30.0):
        self.source = source
        is_file = isinstance(source, (str, pathlib.Path)) and not str(source).startswith("/dev/video") \
            and not str(source).isdigit()
        self.is_file = is_file
        if is_file:
            path = pathlib.Path(source)
            if not path.is_file():
                raise RigError(f"video file '{path}' does not exist")
            self.capture = cv2.VideoCapture(str(path))
        else:
            index = int(source) if str(source).isdigit() else str(source)
            self.capture = cv2.VideoCapture(index)
            if self.capture.isOpened():
                self.capture.set(cv2.CAP_PROP_FPS, fps)
        if not self.capture.isOpened():
            kind = "video file" if is_file else "camera"
            raise RigError(f"{kind} '{source}' cannot be opened by OpenCV: "
                           + ("is it a video (MJPG AVI, MP4) and not damaged?" if is_file
                              else "is it connected and not used by another program?"))
        reported = self.capture.get(cv2.CAP_PROP_FPS)
        self.fps = float(reported) if reported and 1.0 <= reported <= 1000.0 else float(fps)
        self.index = 0
        self._t0 = time.monotonic()
        self._first_read = True

    def read(self) -> Frame | None:
        """The next frame, or None at the end of a file."""
        ok, image = self.capture.read()
        if not ok or image is None:
            if self._first_read:
                raise RigError(f"no frame could be read from '{self.source}': the "
                               + ("file is empty or its codec is unsupported" if self.is_file
                                  else "camera delivers nothing"))
            return None
        self._first_read = False
        if self.is_file:
            t = self.index / self.fps
        else:
            msec = self.capture.get(cv2.CAP_PROP_POS_MSEC)
            t = msec / 1000.0 if msec and msec > 0 else time.monotonic() - self._t0
        frame = Frame(self.index, t, image)
        self.index += 1
        return frame

    def close(self) -> None:
        self.capture.release()

    def __iter__(self):
        while (frame := self.read()) is not None:
            yield frame

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def open_camera(source, fps: float = 30.0) -> VideoSource:
    """A :class:`VideoSource` for a device index, ``/dev/videoN`` or a file."""
    return VideoSource(source, fps)
