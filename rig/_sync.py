"""The sync LED: find the frame (and the time within it) at which sample 0 was played.

The board lights the LED on the tick of sample 0 (rig_dac.ino). The LED's
brightness in a small disk around its position is compared with a ring of
background around it; the ratio does not care about lighting flicker. The
first frames (LED off) give the baseline; the first frame clearly above it
contains the edge. Within that frame the fraction of the exposure for which
the LED was on is ``f = (b_edge - b_off) / (b_on - b_off)`` (b_on from the next
frame), so the edge is at ``t_frame + exposure (1 - f)``. When ``f`` is ~1 the
edge fell in the gap between two exposures and the middle of that gap is the
best guess (error at most half the gap).
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from ._errors import RigError

__all__ = ["LedDetector", "LedSync"]


@dataclasses.dataclass(frozen=True)
class LedSync:
    """The sync edge: ``t`` on the camera's clock (s), the edge ``frame``, ``fraction`` lit in it."""

    t: float
    frame: int
    fraction: float


class LedDetector:
    """Watch the LED at ``(x, y)`` with radius ``radius`` px; feed frames in order.

    Arguments:
        exposure: exposure time, s (default: a whole frame period, no gap).
        baseline_frames: frames before the edge used for the off level (at least 3).
    """

    def __init__(
        self,
        x: float,
        y: float,
        radius: float = 5.0,
        fps: float = 30.0,
        exposure: float | None = None,
        baseline_frames: int = 5,
    ):
        self.x, self.y, self.r = float(x), float(y), float(radius)
        self.period = 1.0 / fps
        self.exposure = self.period if exposure is None else float(exposure)
        if not 0 < self.exposure <= self.period * 1.0001:
            raise RigError(f"exposure {self.exposure:g} s must be in (0, {self.period:g}] s at {fps:g} fps")
        self.baseline_frames = max(3, baseline_frames)
        self.levels: list[tuple[int, float, float]] = []  # (index, t, level)
        self.edge: tuple[int, float, float] | None = None
        self.sync: LedSync | None = None
        self._masks: tuple[np.ndarray, np.ndarray] | None = None  # (disk, ring), from the first frame

    def level(self, image: np.ndarray) -> float:
        """LED disk brightness over its surrounding ring (1 = same as background)."""
        if image.ndim == 3:
            image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        if self._masks is None:
            h, w = image.shape
            yy, xx = np.mgrid[0:h, 0:w]
            d = np.hypot(xx - self.x, yy - self.y)
            disk, ring = d <= self.r, (d > self.r + 2) & (d <= self.r * 2 + 4)
            if disk.sum() == 0 or ring.sum() == 0:
                raise RigError(f"sync LED at ({self.x:g}, {self.y:g}) is outside the {w}x{h} picture")
            self._masks = (disk, ring)
        disk, ring = self._masks
        return float(image[disk].mean()) / max(float(image[ring].mean()), 1.0)

    def update(self, index: int, t: float, image: np.ndarray) -> LedSync | None:
        """Add a frame; returns the sync once it is known (the frame after the edge is needed)."""
        if self.sync is not None:
            return self.sync
        level = self.level(image)
        self.levels.append((index, t, level))
        if self.edge is not None:
            return self._finish(level)
        if len(self.levels) <= self.baseline_frames:
            return None
        base = np.array([lv for _, _, lv in self.levels[:-1]][-30:])
        threshold = float(base.mean()) + max(6 * float(base.std()), 0.15)
        if level > threshold:
            self.edge = self.levels[-1]
            self.baseline = float(base.mean())
        return None

    def _finish(self, on_level: float) -> LedSync:
        assert self.edge is not None  # update calls this once the edge is seen
        index, t, level = self.edge
        span = on_level - self.baseline
        fraction = 1.0 if span <= 0 else float(np.clip((level - self.baseline) / span, 0.0, 1.0))
        gap = self.period - self.exposure
        if fraction > 0.97:  # lit for the whole exposure: the edge was in the gap before it
            edge_t = t - 0.5 * gap if gap > 1e-6 else t
        else:
            edge_t = t + self.exposure * (1.0 - fraction)
        self.sync = LedSync(edge_t, index, fraction)
        return self.sync
