"""Geometry of the camera's view: where the strip is clamped, its rest axis and the scale.

Image coordinates are pixels, x to the right and y down. The strip's rest axis
leaves the clamp point along ``a = (cos angle, sin angle)``; the signed tip
displacement w is measured along ``n = (sin angle, -cos angle)``, which is
*up* in the image for a strip pointing right (angle 0).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ._errors import RigError

__all__ = ["Scene", "arc_centreline", "check_in_picture"]

#: The shortest strip, px, the tracker can follow; the longest is this many picture diagonals.
MIN_STRIP_PX, MAX_STRIP_DIAGONALS = 8.0, 1.25
#: The length taken for a strip whose length is not given, mm (the paper's).
DEFAULT_LENGTH_MM = 22.0


def check_in_picture(clamp, mm_per_px: float, length_mm: float | None, shape, source: str) -> None:
    """Refuse a clamp point outside a `shape` (height, width, ...) picture, and a strip too short or long in it.

    `source` names the picture in the message (``"the 320x240 picture of v.avi"``'s ``v.avi``). `rig
    track` checks its video's first frame, `rig record` the camera's first frame before the board plays:
    with the clamp outside, no frame would be tracked.
    """
    height, width = shape[:2]
    x, y = clamp
    if not (0 <= x < width and 0 <= y < height):
        raise RigError(
            f"--clamp {x:g},{y:g} is outside the {width}x{height} picture of {source}: give the clamp "
            "point in the picture's pixels (x from the left, y from the top)"
        )
    length = length_mm or DEFAULT_LENGTH_MM
    length_px = length / mm_per_px
    diagonal = math.hypot(width, height)
    if not MIN_STRIP_PX <= length_px <= MAX_STRIP_DIAGONALS * diagonal:
        raise RigError(
            f"--length {length:g} mm at --mm-per-px {mm_per_px:g} is a strip "
            f"{length_px:.4g} px long, {'too short to follow' if length_px < MIN_STRIP_PX else 'longer than'}"
            + ("" if length_px < MIN_STRIP_PX else f" the {width}x{height} picture can show")
            + ": check both (the scale is mm per pixel: a 30 mm strip 300 px long is 0.1)"
        )


@dataclasses.dataclass(frozen=True)
class Scene:
    """The view of the strip.

    Arguments:
        clamp: (x, y) of the clamp point in the image, px (where the free
            length starts).
        mm_per_px: image scale, mm per pixel.
        angle_deg: direction of the rest axis, degrees, 0 = towards +x,
            positive turns towards +y (down).
        length_mm: free length of the strip, mm (22 in the paper), or None
            when unknown (the tracker finds the tip without it).
    """

    clamp: tuple[float, float] = (40.0, 120.0)
    mm_per_px: float = 0.1
    angle_deg: float = 0.0
    length_mm: float | None = 22.0

    def __post_init__(self):
        if len(self.clamp) != 2 or not all(math.isfinite(c) for c in self.clamp):
            raise RigError(f"clamp point {self.clamp!r} must be two finite pixel coordinates X,Y")
        if not (math.isfinite(self.mm_per_px) and self.mm_per_px > 0):
            raise RigError(f"scale {self.mm_per_px!r} mm/px must be a positive number")
        if not math.isfinite(self.angle_deg):
            raise RigError(f"axis angle {self.angle_deg!r} must be a finite number of degrees")
        if self.length_mm is not None and not self.length_mm > 0:
            raise RigError(f"strip length {self.length_mm!r} mm must be positive")

    @property
    def axis(self) -> np.ndarray:
        t = math.radians(self.angle_deg)
        return np.array([math.cos(t), math.sin(t)])

    @property
    def normal(self) -> np.ndarray:
        t = math.radians(self.angle_deg)
        return np.array([math.sin(t), -math.cos(t)])

    def to_image(self, s_px, u_px) -> tuple[np.ndarray, np.ndarray]:
        """Image (x, y) of axial coordinate s and normal coordinate u (px from the clamp)."""
        s, u = np.asarray(s_px, float), np.asarray(u_px, float)
        p = np.asarray(self.clamp)[:, None, None] if s.ndim == 2 else np.asarray(self.clamp)[:, None]
        a, n = self.axis, self.normal
        shape = (2,) + (1,) * s.ndim
        xy = p.reshape(shape) + a.reshape(shape) * s + n.reshape(shape) * u
        return xy[0], xy[1]


def arc_centreline(w_mm: float, length_mm: float, n: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """A strip of arc length ``length_mm`` bent at constant curvature so its tip sits
    ``w_mm`` off the rest axis (an IPMC bends at nearly uniform curvature).

    Returns ``(s, u)`` in mm along the arc from the clamp: axial and normal coordinates.
    The tip is ``(s[-1], u[-1])`` with ``u[-1] == w_mm``.
    """
    if abs(w_mm) >= length_mm * 0.72:
        raise RigError(f"tip displacement {w_mm} mm is too large for a {length_mm} mm strip")
    arc = np.linspace(0.0, length_mm, n)
    if abs(w_mm) < 1e-9:
        return arc, np.zeros_like(arc)
    # Solve w = (1 - cos(kL)) / k for the curvature k by Newton's method.
    sign, w = math.copysign(1.0, w_mm), abs(w_mm)
    k = 2 * w / length_mm**2
    for _ in range(50):
        f = (1 - math.cos(k * length_mm)) / k - w
        df = (length_mm * math.sin(k * length_mm) * k - (1 - math.cos(k * length_mm))) / k**2
        step = f / df
        k -= step
        if abs(step) < 1e-15 * max(k, 1.0):
            break
    return np.sin(k * arc) / k, sign * (1 - np.cos(k * arc)) / k
