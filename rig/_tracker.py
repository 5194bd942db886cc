"""Tip tracking: the signed tip displacement w (mm) of a dark strip in a video frame.

Method, per frame (nothing here knows how the picture was made):

1. Dark-line contrast. The background under the strip is estimated by a
   grey-level closing with a disk wider than the strip, which erases thin
   dark things and keeps the slowly varying lighting; the contrast is
   ``(background - image) / background``. Dividing by the local background
   makes it independent of gradients, vignetting and frame-to-frame flicker.
2. Straighten the view: resample the contrast on a grid aligned with the rest
   axis (s along it from the clamp, u across it), px.
3. Cross-sections. For each s, the strip's centre across the axis is the
   contrast-weighted centroid around the darkest point near the previous
   section's centre (sub-pixel), following the strip out from the clamp until
   its contrast falls below half of its median along the strip.
4. The tip. A cubic fitted to the centres (the last few sections excluded,
   where the end cap distorts them) gives the centreline u(s); the contrast
   sampled along that line falls from its plateau to zero at the tip, and the
   half-way crossing (linear interpolation) is the tip's s. w = u(s_tip) * mm/px.

Quality: 1 when the strip is found from the clamp to a tip inside the view with
clear contrast, 0 otherwise (the reason is in ``TipResult.reason``); w is NaN
when nothing could be measured.
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np

from ._errors import RigError
from ._scene import Scene

__all__ = ["TipResult", "TipTracker"]


@dataclasses.dataclass(frozen=True)
class TipResult:
    """Tracking result of one frame: w (mm, NaN if none), quality (1 good, 0 bad), reason, tip (x, y) px."""

    w: float
    quality: int
    reason: str
    tip_xy: tuple[float, float]


class TipTracker:
    """Find the strip's tip in frames of one camera view.

    Arguments:
        scene: clamp point, scale, rest-axis angle (and the strip length if known).
        strip_px: expected visible strip thickness, px (sets the closing size);
            a rough value is enough.
        start_px: sections start this far from the clamp point (clears the clamp's edge).
        half_width_px: how far across the axis the strip may wander, px; default
            0.7 x the free length (covers the paper's deflections).
        min_contrast: below this relative contrast there is no strip.
    """

    def __init__(self, scene: Scene, strip_px: float = 4.0, start_px: float = 4.0,
                 half_width_px: float | None = None, min_contrast: float = 0.12):
        self.scene = scene
        self.strip_px = float(strip_px)
        self.start_px = float(start_px)
        length_px = (scene.length_mm or 40.0) / scene.mm_per_px
        self.max_s = 1.4 * length_px
        self.half_width = half_width_px if half_width_px is not None else 0.7 * length_px
        self.min_contrast = min_contrast
        radius = max(3, int(math.ceil(1.5 * self.strip_px)))
        self._kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
        self._window = max(2, int(math.ceil(0.5 * self.strip_px + 2)))

    # ------------------------------------------------------------------ helpers

    def contrast(self, frame: np.ndarray) -> np.ndarray:
        """Relative darkness of thin dark structures, 0 (background) .. ~1 (black)."""
        if frame.ndim == 3:
            frame = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        gray = frame.astype(np.float32)
        background = cv2.morphologyEx(gray, cv2.MORPH_CLOSE, self._kernel)
        background = cv2.GaussianBlur(background, (0, 0), 1.0)
        return np.clip((background - gray) / np.maximum(background, 1.0), 0.0, 1.0)

    def _sample(self, contrast, s, u):
        x, y = self.scene.to_image(s, u)
        return cv2.remap(contrast, x.astype(np.float32), y.astype(np.float32), cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=-1.0)

    # ------------------------------------------------------------------ tracking

    def track(self, frame: np.ndarray) -> TipResult:
        """Track one frame (gray or BGR, any dtype convertible to float)."""
        if frame is None or frame.ndim not in (2, 3) or min(frame.shape[:2]) < 8:
            raise RigError("frame is empty or not an image")
        contrast = self.contrast(frame)
        h, w = contrast.shape
        s = np.arange(self.start_px, self.max_s, 1.0)
        u = np.arange(-self.half_width, self.half_width + 0.25, 0.5)
        grid = self._sample(contrast, s[:, None] * np.ones_like(u)[None, :], np.ones_like(s)[:, None] * u[None, :])
        outside = grid < 0
        grid = np.where(outside, 0.0, grid)

        # Follow the strip out from the clamp.
        centres, peaks, inside = [], [], []
        prev = None
        win = self._window * 2  # in 0.5 px steps
        for k in range(len(s)):
            row = grid[k]
            if prev is None:
                j0 = int(np.argmax(row))
            else:
                lo, hi = max(0, prev - 2 * win), min(len(u), prev + 2 * win + 1)
                j0 = lo + int(np.argmax(row[lo:hi]))
            peak = row[j0]
            lo, hi = max(0, j0 - win), min(len(u), j0 + win + 1)
            part = row[lo:hi] - 0.2 * peak
            part = np.clip(part, 0.0, None)
            if peak < self.min_contrast or part.sum() <= 0:
                if prev is not None and len(centres) > 3:
                    break
                centres.append(np.nan)
                peaks.append(peak)
                inside.append(not outside[k, j0])
                continue
            centres.append(float((part * u[lo:hi]).sum() / part.sum()))
            peaks.append(float(peak))
            inside.append(not outside[k, j0])
            prev = j0
        centres = np.array(centres)
        peaks = np.array(peaks)
        reached_end = len(centres) == len(s)
        s = s[: len(centres)]
        good = np.isfinite(centres)
        if good.sum() < 8:
            return TipResult(math.nan, 0, "no strip found next to the clamp", (math.nan, math.nan))
        plateau = float(np.median(peaks[good]))
        strong = good & (peaks > 0.5 * plateau)
        last = int(np.flatnonzero(strong)[-1])
        if not inside[min(last + 1, len(inside) - 1)] or (reached_end and last + 3 >= len(s)):
            return TipResult(math.nan, 0, "tip out of view", (math.nan, math.nan))
        # Centreline: cubic through the sections, the end cap excluded.
        use = strong.copy()
        use[max(0, last - int(self.strip_px) - 1):] = False
        if use.sum() < 6:
            use = strong
        ss, uu = s[use], centres[use]
        degree = 3 if len(ss) > 12 else 1
        scale = max(ss.max(), 1.0)
        coef = np.polyfit(ss / scale, uu, degree)

        def line(sv):
            return np.polyval(coef, np.asarray(sv) / scale)

        # Contrast along the centreline, averaged over +-1 px across it.
        s_fine = np.arange(s[last] - 3 * self.strip_px - 4, s[last] + 2 * self.strip_px + 4, 0.1)
        u_fine = line(s_fine)
        along = np.mean([self._sample(contrast, s_fine[None, :], (u_fine + du)[None, :])[0]
                         for du in (-1.0, 0.0, 1.0)], axis=0)
        along = np.where(along < 0, 0.0, along)
        body = along[s_fine < s[last] - self.strip_px]
        level = float(np.median(body)) if body.size else plateau
        if level < self.min_contrast:
            return TipResult(math.nan, 0, "low contrast", (math.nan, math.nan))
        half = 0.5 * level
        below = np.flatnonzero((along[:-1] >= half) & (along[1:] < half))
        below = below[s_fine[below] > s[last] - 2 * self.strip_px]
        if below.size == 0:
            return TipResult(math.nan, 0, "tip not found", (math.nan, math.nan))
        i = below[0]
        f = (along[i] - half) / (along[i] - along[i + 1])
        s_tip = s_fine[i] + f * (s_fine[i + 1] - s_fine[i])
        u_tip = float(line(s_tip))
        x, y = self.scene.to_image(np.array([s_tip]), np.array([u_tip]))
        x, y = float(x[0]), float(y[0])
        if not (1 <= x < w - 1 and 1 <= y < h - 1):
            return TipResult(math.nan, 0, "tip out of view", (x, y))
        # The tip is the end of the strip, not its centreline: add back half the cap.
        return TipResult(u_tip * self.scene.mm_per_px, 1, "ok", (x, y))
