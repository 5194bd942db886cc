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
   its contrast falls below half of its median along the strip. The strip
   starts where `START_SECTIONS` sections in a row lie on the axis, each near
   the last, with at least half the contrast the line near the axis has over
   the first 30 % of the free length: before that, a faint or off-axis section
   is a clamp's edge (a dark block reaching past the clamp point), not the strip.
4. The tip. A quartic fitted to the centres (the last few sections excluded,
   where the end cap distorts them) gives the centreline u(s): exact for a
   cantilever under a uniform load (Euler-Bernoulli), where a cubic was
   0.02 mm off at the tip for a 7 mm bend; the contrast
   sampled along that line falls from its plateau to zero at the tip, and the
   half-way crossing (linear interpolation) is the tip's s. w = u(s_tip) * mm/px.

Quality: 1 when the strip is found from the clamp to a tip inside the view with
clear contrast, its sections on one smooth line, 0 otherwise (the reason is in
``TipResult.reason``; something dark across the strip bends its sections off
the line by several pixels, and the tip beyond it would be wrong); w is NaN
when nothing could be measured. A tip smeared sideways by motion (its contrast
fading along the smear) is measured where the strip was mid-exposure, with
quality 0 and the reason `BLURRED`. A dark line that does not leave the clamp along
the rest axis (met far from the clamp, or across the axis: the axis is wrong),
or that ends before 40 % of the free length (the clamp's edge, a short mark),
is not the strip.
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np

from ._errors import RigError
from ._scene import Scene

__all__ = ["BLURRED", "Sections", "TipResult", "TipTracker"]

#: The reason of a frame whose tip was smeared by motion beyond the sharp tip's measure: its w is
#: measured (where the strip was mid-exposure, not NaN), its quality 0.
BLURRED = "tip blurred by motion (w measured, less sure)"
#: Strip thicknesses of weaker sections after which a strong one is no longer the strip's (`TipTracker._strong`).
STRONG_GAP = 2
#: Sections in a row on the rest axis, each within half a thickness of the last, that make the strip's
#: start: before them, one off the axis is not the strip's (`TipTracker.sections`).
START_SECTIONS = 3


@dataclasses.dataclass(frozen=True)
class TipResult:
    """Tracking result of one frame: w (mm, NaN if none), quality (1 good, 0 bad), reason, tip (x, y) px,
    and the length (px) of the centreline from the clamp to that tip (NaN if none)."""

    w: float
    quality: int
    reason: str
    tip_xy: tuple[float, float]
    length_px: float = math.nan


def _climb(row: np.ndarray, j: int) -> int:
    """From index ``j``, step to the higher neighbour until none is higher: the nearest peak."""
    while True:
        left = row[j - 1] if j > 0 else -np.inf
        right = row[j + 1] if j + 1 < len(row) else -np.inf
        if max(left, right) <= row[j]:
            return j
        j = j - 1 if left > right else j + 1


def _run_above(row: np.ndarray, j: int, level: float, reach: int) -> tuple[int, int]:
    """The first and last index of the run of ``row`` above ``level`` around index ``j``, at most
    ``reach`` either side."""
    left = j
    while left > 0 and j - left < reach and row[left - 1] > level:
        left -= 1
    right = j
    while right + 1 < len(row) and right - j < reach and row[right + 1] > level:
        right += 1
    return left, right


@dataclasses.dataclass(frozen=True)
class Sections:
    """Cross-sections of the strip along the rest axis, px: position ``s`` from the clamp,
    centre ``u`` across the axis (NaN where none was found), ``peak`` contrast, ``inside``
    the picture; ``reached_end`` when the strip ran to the end of the search."""

    s: np.ndarray
    u: np.ndarray
    peak: np.ndarray
    inside: np.ndarray
    reached_end: bool


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

    MIN_LENGTH = 0.4  # a tip nearer the clamp than this fraction of the free length is not the strip's
    #: The sections' RMS distance from the fitted centreline above which the strip is not one smooth
    #: line: this many px, or this fraction of the strip's thickness when larger.
    MAX_BEND_RMS_PX = 0.75
    MAX_BEND_RMS_STRIP = 0.15

    def __init__(
        self,
        scene: Scene,
        strip_px: float = 4.0,
        start_px: float = 4.0,
        half_width_px: float | None = None,
        min_contrast: float = 0.12,
    ):
        self.scene = scene
        self.strip_px = float(strip_px)
        self.start_px = float(start_px)
        length_px = (scene.length_mm or 40.0) / scene.mm_per_px
        self.length_px = length_px
        self.max_s = 1.4 * length_px
        self.half_width = half_width_px if half_width_px is not None else 0.7 * length_px
        self.min_contrast = min_contrast
        radius = max(3, int(math.ceil(1.5 * self.strip_px)))
        self._kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
        self._window = max(2, int(math.ceil(0.5 * self.strip_px + 2)))
        self._wide_tracker: TipTracker | None = None

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
        return cv2.remap(
            contrast,
            x.astype(np.float32),
            y.astype(np.float32),
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=-1.0,
        )

    def _along(self, contrast, s, u):
        """The contrast along the line (s, u) px, averaged over +-1 px across it (0 outside the picture)."""
        along = np.mean(
            [self._sample(contrast, s[None, :], (u + du)[None, :])[0] for du in (-1.0, 0.0, 1.0)], axis=0
        )
        return np.where(along < 0, 0.0, along)

    # ------------------------------------------------------------------ tracking

    def sections(self, contrast: np.ndarray) -> Sections:
        """Follow the strip out from the clamp in a contrast image (see `contrast`).

        Returns the cross-sections along the rest axis (px): their s, centre u
        (NaN where none), peak contrast and whether the peak lay inside the picture.
        """
        s = np.arange(self.start_px, self.max_s, 1.0)
        u = np.arange(-self.half_width, self.half_width + 0.25, 0.5)
        grid = self._sample(
            contrast, s[:, None] * np.ones_like(u)[None, :], np.ones_like(s)[:, None] * u[None, :]
        )
        outside = grid < 0
        grid = np.where(outside, 0.0, grid)

        # The strip's start is at least half the contrast the line near the axis has over the first
        # 30 % of the free length, where even a strongly bent strip is near it: fainter sections there
        # are a clamp's edge (its closing-made rim, 0.13-0.25 against a strip's 0.85).
        near_max = np.max(np.where(np.abs(u)[None, :] <= self._near_axis(s)[:, None], grid, 0.0), axis=1)
        first = s <= self.start_px + 0.3 * self.length_px
        start_level = max(self.min_contrast, 0.5 * float(np.median(near_max[first])))
        centres: list[float] = []
        peaks: list[float] = []
        inside: list[bool] = []
        prev = None
        settled = 0  # sections in a row found on the axis since the strip was first met
        win = self._window * 2  # in 0.5 px steps
        for k in range(len(s)):
            row = grid[k]
            if prev is None:
                # The strip leaves the clamp along the axis: take the contrast peak nearest the
                # axis (climbing from it), not a darker line elsewhere across the row.
                # If the axis passes beside the strip (clamp point off by a few px), the darkest
                # point near the axis instead.
                j0 = _climb(row, int(np.argmin(np.abs(u))))
                if abs(u[j0]) > self._near_axis(s[k]) or row[j0] < self.min_contrast:
                    near = np.flatnonzero(np.abs(u) <= self._near_axis(s[k]))
                    j0 = int(near[np.argmax(row[near])])
            else:
                lo, hi = max(0, prev - 2 * win), min(len(u), prev + 2 * win + 1)
                j0 = lo + int(np.argmax(row[lo:hi]))
            peak = row[j0]
            # The window spans the section's run above half its peak and 2 px beside it (at least
            # `win` either side of the peak, as before): across a strip thicker than --strip-px the
            # peak lies anywhere on a flat top, and a window centred there cut the strip unevenly
            # (centres off by up to a quarter of its thickness, at random from section to section:
            # w tenths of a mm off in frames of quality 1, or the strip refused).
            left, right = _run_above(row, j0, 0.5 * peak, 3 * win)
            lo = max(0, min(j0 - win, left - 4))  # 2 px beside the run
            hi = min(len(u), max(j0 + win, right + 4) + 1)
            part = row[lo:hi] - 0.2 * peak
            part = np.clip(part, 0.0, None)
            started = settled >= START_SECTIONS
            last = centres[-1] if centres else math.nan
            if peak < (self.min_contrast if started else start_level) or part.sum() <= 0:
                if prev is not None and len(centres) > 3 and started:
                    break  # the strip's end
                centre = math.nan  # not yet the strip: a clamp's edge fading, or nothing
            else:
                centre = float((part * u[lo:hi]).sum() / part.sum())
                # Until the strip has run START_SECTIONS sections in a row along the axis, each within
                # half a thickness of the last, a section off the axis is the clamp's edge (a dark clamp
                # block reaching past the clamp point: its corners pulled sections 11-15 px off the axis
                # and the search after them, and a strip plain beyond was refused).
                if not started and abs(centre) > self._near_axis(s[k]):
                    centre = math.nan
            centres.append(centre)
            peaks.append(float(peak))
            inside.append(not outside[k, j0])
            if math.isnan(centre):  # none here: the next is looked for on the axis again
                prev, settled = None, 0
                continue
            if not started:
                settled = settled + 1 if abs(centre - last) <= 0.5 * self.strip_px else 1
            prev = j0
        n = len(centres)
        return Sections(
            s=s[:n],
            u=np.array(centres),
            peak=np.array(peaks),
            inside=np.array(inside, bool),
            reached_end=n == len(s),
        )

    def centreline_points(self, sections: Sections) -> tuple[np.ndarray, np.ndarray] | None:
        """The sections a centreline is fitted to: (s, u) px, the end cap left out; None if too few."""
        good = np.isfinite(sections.u)
        if good.sum() < 8:
            return None
        _, strong = self._strong(sections)
        last = int(np.flatnonzero(strong)[-1])
        use = strong.copy()
        use[max(0, last - int(self.strip_px) - 1) :] = False
        if use.sum() < 6:
            use = strong
        return sections.s[use], sections.u[use]

    def _strong(self, sections: Sections) -> tuple[float, np.ndarray]:
        """The strip's contrast plateau (the median peak of the sections found) and its strong sections.

        A section is strong above half the plateau, and in the strip's run of them from the clamp:
        after more than `STRONG_GAP` strip thicknesses of weaker ones, strong sections in short runs
        only are lines the search met beyond the tip (graph paper behind the strip: a grid line
        crossing the axis past it was taken for the tip, 8 mm out); a long run there is the strip
        beyond something that covers it, which the smooth-line check then refuses.
        """
        good = np.isfinite(sections.u)
        plateau = float(np.median(sections.peak[good]))
        strong = good & (sections.peak > 0.5 * plateau)
        found = np.flatnonzero(strong)
        reach = STRONG_GAP * self.strip_px + 2
        breaks = np.flatnonzero(np.diff(found) > reach)
        if breaks.size:
            beyond = found[breaks[0] + 1 :]
            runs = np.split(beyond, np.flatnonzero(np.diff(beyond) > 2) + 1)
            if max(len(run) for run in runs) < reach:  # only short marks: crossings, not the strip
                strong[found[breaks[0]] + 1 :] = False
        return plateau, strong

    def leaves_clamp(self, sections: Sections) -> bool:
        """Whether the strip starts at the clamp along the rest axis.

        The first sections found must lie next to the clamp (within 2 strip
        thicknesses + 10 % of the free length of where they start) and close to
        the axis (within 2 thicknesses + 20 % of their distance, about 11
        degrees): a strip met far from the clamp or across the axis is not this
        strip along this axis.
        """
        good = np.flatnonzero(np.isfinite(sections.u))
        if good.size == 0:
            return False
        first = good[:3]
        s0 = sections.s[first[0]]
        if s0 > self.start_px + 2 * self.strip_px + 0.1 * self.length_px:
            return False
        return bool(np.all(np.abs(sections.u[first]) <= self._near_axis(sections.s[first])))

    def _near_axis(self, s):
        """How far across the axis the strip may be at ``s`` px from the clamp where it starts, px."""
        return self.strip_px + 0.1 * np.asarray(s)

    def track(self, frame: np.ndarray) -> TipResult:
        """Track one frame (gray or BGR, any dtype convertible to float)."""
        if frame is None or frame.ndim not in (2, 3) or min(frame.shape[:2]) < 8:
            raise RigError("frame is empty or not an image")
        result = self.track_contrast(self.contrast(frame))
        if result.reason in (BLURRED, "tip not found"):
            # A tip smeared sideways by motion is wider than the closing erases: its contrast fades
            # along the smear (the tip was found short, or not at all). Seen as a strip twice as
            # thick, the smear is measured whole (synthetic smears of 1.2-1.6 mm: within 0.012 mm
            # of the exposure's mean, where the tip found short was up to 0.8 mm off); the frame
            # keeps quality 0 (BLURRED), a measured w.
            wide = self._wide()
            again = wide.track_contrast(wide.contrast(frame))
            if math.isfinite(again.w):
                return TipResult(again.w, 0, BLURRED, again.tip_xy)
        return result

    def _wide(self) -> TipTracker:
        """This tracker for a strip twice as thick (made once)."""
        if self._wide_tracker is None:
            self._wide_tracker = TipTracker(
                self.scene,
                strip_px=2 * self.strip_px,
                start_px=self.start_px,
                half_width_px=self.half_width,
                min_contrast=self.min_contrast,
            )
        return self._wide_tracker

    def track_contrast(self, contrast: np.ndarray) -> TipResult:
        """Track one frame given its contrast image (`contrast`)."""
        h, w = contrast.shape
        sec = self.sections(contrast)
        s, centres, inside = sec.s, sec.u, sec.inside
        good = np.isfinite(centres)
        if good.sum() < 8:
            return TipResult(math.nan, 0, "no strip found next to the clamp", (math.nan, math.nan))
        if not self.leaves_clamp(sec):
            return TipResult(math.nan, 0, "no strip leaves the clamp along the axis", (math.nan, math.nan))
        plateau, strong = self._strong(sec)
        last = int(np.flatnonzero(strong)[-1])
        if not inside[min(last + 1, len(inside) - 1)] or (sec.reached_end and last + 3 >= len(s)):
            return TipResult(math.nan, 0, "tip out of view", (math.nan, math.nan))
        # Centreline: quartic through the sections, the end cap excluded.
        points = self.centreline_points(sec)
        assert points is not None  # None only below 8 sections, refused above
        ss, uu = points
        degree = 4 if len(ss) > 16 else 3 if len(ss) > 12 else 1
        scale = max(ss.max(), 1.0)
        coef = np.polyfit(ss / scale, uu, degree)

        def line(sv):
            return np.polyval(coef, np.asarray(sv) / scale)

        # A strip's sections lie on one smooth line, within a fraction of a pixel (more for a thick
        # strip); something dark across the strip (a hand, a cable, a tool) pulls them off by several
        # px, and the tip found beyond it is wrong by millimetres, of either sign
        # (tests/test_rig_track_cantilever.py: a disk sweeping over the strip).
        broken = float(np.sqrt(np.mean((uu - line(ss)) ** 2)))
        if broken > max(self.MAX_BEND_RMS_PX, self.MAX_BEND_RMS_STRIP * self.strip_px):
            return TipResult(math.nan, 0, "strip not one smooth line (covered?)", (math.nan, math.nan))

        # Contrast along the centreline, averaged over +-1 px across it.
        s_fine = np.arange(s[last] - 3 * self.strip_px - 4, s[last] + 2 * self.strip_px + 4, 0.1)
        along = self._along(contrast, s_fine, line(s_fine))
        body = along[s_fine < s[last] - self.strip_px]
        level = float(np.median(body)) if body.size else plateau
        if level < self.min_contrast:
            return TipResult(math.nan, 0, "low contrast", (math.nan, math.nan))
        half = 0.5 * level
        below = np.flatnonzero((along[:-1] >= half) & (along[1:] < half))
        below = below[s_fine[below] > s[last] - 2 * self.strip_px]
        blurred = below.size == 0 and s[-1] > s[last]
        if blurred:
            # Motion blur: the strip's end, moving fastest, is smeared across the axis, its sections
            # followed on (above min_contrast) but under half the plateau, so the strong ones stop
            # short of the tip: the centreline through every section followed (the smear's centres:
            # where the strip was mid-exposure), the tip looked for out to the last of them. A smear
            # wider than the closing erases fades along it, and this tip falls short: `track`
            # measures such a frame again as a strip twice as thick.
            s_fine = np.arange(s[last] - 3 * self.strip_px - 4, s[-1] + 2 * self.strip_px + 4, 0.1)
            use = good.copy()
            use[max(0, len(s) - int(self.strip_px) - 1) :] = False
            coef = np.polyfit(s[use] / scale, centres[use], degree)
            along = self._along(contrast, s_fine, line(s_fine))
            below = np.flatnonzero((along[:-1] >= half) & (along[1:] < half))
            below = below[s_fine[below] > s[last] - 2 * self.strip_px]
        if below.size == 0:
            return TipResult(math.nan, 0, "tip not found", (math.nan, math.nan))
        i = below[0]
        f = (along[i] - half) / (along[i] - along[i + 1])
        s_tip = s_fine[i] + f * (s_fine[i + 1] - s_fine[i])
        if (
            self.scene.length_mm is not None
            and s_tip * self.scene.mm_per_px < self.MIN_LENGTH * self.scene.length_mm
        ):
            return TipResult(math.nan, 0, "strip much shorter than its length", (math.nan, math.nan))
        u_tip = float(line(s_tip))
        xs, ys = self.scene.to_image(np.array([s_tip]), np.array([u_tip]))
        x, y = float(xs[0]), float(ys[0])
        if not (1 <= x < w - 1 and 1 <= y < h - 1):
            return TipResult(math.nan, 0, "tip out of view", (x, y))
        # The tip is the end of the strip, not its centreline: add back half the cap.
        grid = np.linspace(0.0, s_tip, 256)
        length = float(np.sum(np.hypot(np.diff(grid), np.diff(line(grid)))))  # the strip's, however bent
        if blurred:  # measured, but less sure: w within ~0.1-0.2 mm where a sharp tip is within ~0.05
            return TipResult(u_tip * self.scene.mm_per_px, 0, BLURRED, (x, y), length)
        return TipResult(u_tip * self.scene.mm_per_px, 1, "ok", (x, y), length)
