"""Videos of a clamped strip bent as an Euler-Bernoulli cantilever, drawn independently of rig.

Nothing here comes from ``rig`` (not its scene, renderer or tracker) or from
``rig_labvideo``: geometry, drawing and file writing are numpy and OpenCV only,
so a shared mistake cannot hide an error of the tracker.

Shape. A cantilever of free length L clamped along its rest axis carries a tip
load P and a uniform load q; the bending moment at arc length z from the clamp
is ``M(z) = P (L - z) + q (L - z)^2 / 2``, and its curvature is ``M / EI``
(Euler-Bernoulli). The strip is inextensible: its tangent turns by
``theta(z) = integral of the curvature`` and the centreline is
``x(z) = integral cos(theta)``, ``u(z) = integral sin(theta)``. For small
deflections this is the textbook ``u = P x^2 (3L - x) / 6EI`` (tip load) or
``q x^2 (6L^2 - 4Lx + x^2) / 24EI`` (uniform load): zero slope at the clamp,
highest curvature there, none at the tip -- not a circular arc. The load's
scale is solved (bisection) so the tip sits ``w`` across the rest axis; that
``w`` is the truth a tracker must report.

Picture. The strip (a flat-ended band of the given thickness) is
anti-aliased from each sub-pixel's distance to its centreline (4 x 4 per
pixel), the clamp's jaws are polygons filled on a 4x canvas and
area-averaged down, over a background with a lamp's fall-off, a paper texture
and a thin dark edge far from the clamp, then defocus blur, flicker and
noise. Gray frames are written as Motion-JPEG AVI with OpenCV's VideoWriter.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

SUPER = 4  # supersampling: sub-pixels per pixel side
SHIFT = 4  # fractional bits of the polygon vertices on that canvas
TEXTURE_PX = 3.0
TEXTURE_LEVELS = 12.0


def cantilever_shape(w_mm: float, length_mm: float, tip_share: float = 1.0, n: int = 801):
    """Centreline of the bent strip, mm from the clamp: (x along the rest axis, u across it).

    ``tip_share`` splits the load: 1 all tip load, 0 all uniform load (moments
    at the clamp in that proportion). ``u[-1] == w_mm`` (to 1e-9 mm).
    """
    z = np.linspace(0.0, length_mm, n)
    rel = 1.0 - z / length_mm
    moment = tip_share * rel + (1.0 - tip_share) * rel**2  # per unit clamp moment

    def curve(scale):
        kappa = scale * moment
        theta = np.concatenate([[0.0], np.cumsum(0.5 * (kappa[1:] + kappa[:-1]) * np.diff(z))])
        c, s = np.cos(theta), np.sin(theta)
        x = np.concatenate([[0.0], np.cumsum(0.5 * (c[1:] + c[:-1]) * np.diff(z))])
        u = np.concatenate([[0.0], np.cumsum(0.5 * (s[1:] + s[:-1]) * np.diff(z))])
        return x, u, theta

    if abs(w_mm) < 1e-12:
        return z.copy(), np.zeros_like(z), np.zeros_like(z)
    lo, hi = 0.0, 3.0 / length_mm  # the tip turns by at most ~1.5 rad: far beyond any test's bend
    target = abs(w_mm)
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if curve(mid)[1][-1] < target:
            lo = mid
        else:
            hi = mid
    x, u, theta = curve(0.5 * (lo + hi))
    assert abs(u[-1] - target) < 1e-9, "tip displacement out of reach"
    return x, math.copysign(1.0, w_mm) * u, math.copysign(1.0, w_mm) * theta


class CantileverVideo:
    """Frames of a strip clamped at ``clamp`` (x, y px) whose rest axis points ``angle_deg``
    (0 = right, 90 = down), ``mm_per_px`` mm per pixel, free length ``length_mm``.

    ``frame(w_mm, k)`` draws frame k with the tip ``w_mm`` off the rest axis, positive
    along ``(sin a, -cos a)``.
    """

    def __init__(
        self,
        clamp,
        angle_deg,
        size=(200, 260),
        mm_per_px=0.1,
        length_mm=22.0,
        thickness_mm=0.35,
        tip_share=1.0,
        seed=0,
        noise=3.0,
        blur=0.9,
        flicker=0.06,
    ):
        self.clamp = np.asarray(clamp, float)
        a = math.radians(angle_deg)
        self.axis = np.array([math.cos(a), math.sin(a)])
        self.normal = np.array([math.sin(a), -math.cos(a)])
        self.size, self.mm, self.length, self.thickness = size, mm_per_px, length_mm, thickness_mm
        self.tip_share, self.noise, self.blur, self.flicker = tip_share, noise, blur, flicker
        self.rng = np.random.default_rng(seed)
        width, height = size
        yy, xx = np.mgrid[0:height, 0:width].astype(np.float64)
        lamp = np.array([0.3 * width, -0.2 * height])
        fall = 1.0 / (1.0 + ((xx - lamp[0]) ** 2 + (yy - lamp[1]) ** 2) / (1.6 * max(size)) ** 2)
        texture = cv2.GaussianBlur(self.rng.normal(0.0, 1.0, (height, width)), (0, 0), TEXTURE_PX)
        self.background = 90.0 + 140.0 * fall + TEXTURE_LEVELS * texture / max(texture.std(), 1e-9)
        self._rest_grid = (
            (xx - self.clamp[0]) * self.axis[0] + (yy - self.clamp[1]) * self.axis[1],
            (xx - self.clamp[0]) * self.normal[0] + (yy - self.clamp[1]) * self.normal[1],
        )
        self.level = float(self.rng.uniform(30.0, 70.0))
        self.phase = float(self.rng.uniform(0.0, 2 * math.pi))

    def _to_px(self, x_mm, u_mm):
        """Image points (N, 2) px of rest-frame points (mm)."""
        p = self.clamp[None, :] + (np.outer(x_mm, self.axis) + np.outer(u_mm, self.normal)) / self.mm
        return p

    def _fill(self, canvas, points, value):
        # Canvas coordinates of image points (sub-pixel centres at integers). fillPoly samples
        # sub-pixel centres, so an edge is placed to within a sub-pixel: good enough for the
        # clamp's jaws, not for the strip (see `coverage`).
        canvas_xy = points * SUPER + (SUPER - 1) / 2.0
        pts = np.round(canvas_xy * (1 << SHIFT)).astype(np.int32)
        cv2.fillPoly(canvas, [pts], value, cv2.LINE_8, SHIFT)

    def coverage(self, w_mm):
        """Fraction of each pixel the strip covers (0..1): a band of the given thickness along the
        centreline, cut flat at its tip, running 3 mm back into the clamp.

        Each pixel is split into ``SUPER`` x ``SUPER`` sub-pixels; a sub-pixel's share is a linear
        ramp of its signed distance to the band's edge, ``clip(0.5 + SUPER * (h - |d|), 0, 1)`` (exact
        for an edge along the pixel grid, where plain point sampling -- cv2.fillPoly -- quantises
        the edge to a sub-pixel and shifts the strip by up to 1/(2 SUPER) px). ``d`` is found by
        projecting the sub-pixel onto the centreline (Newton on the arc length).
        """
        x, u, theta = cantilever_shape(w_mm, self.length, self.tip_share)
        z = np.linspace(0.0, self.length, len(x))
        lead = np.linspace(-3.0, 0.0, 31)[:-1]  # straight into the clamp
        z, x = np.concatenate([lead, z]), np.concatenate([lead, x])
        u, theta = np.concatenate([np.zeros_like(lead), u]), np.concatenate([np.zeros_like(lead), theta])
        h = 0.5 * self.thickness / self.mm  # px
        xs, us = x / self.mm, u / self.mm  # px, rest frame
        width, height = self.size
        rx, ru = self._rest_grid
        near = (rx > xs[0] - 2) & (rx < xs[-1] + h + 2) & (np.abs(ru - np.interp(rx, xs, us)) < 2 * h + 3)
        iy, ix = np.nonzero(near)
        offsets = (np.arange(SUPER) + 0.5) / SUPER - 0.5
        oy, ox = np.meshgrid(offsets, offsets, indexing="ij")
        px = (ix[:, None] + ox.ravel()[None, :]).ravel()
        py = (iy[:, None] + oy.ravel()[None, :]).ravel()
        qx = (px - self.clamp[0]) * self.axis[0] + (py - self.clamp[1]) * self.axis[1]
        qu = (px - self.clamp[0]) * self.normal[0] + (py - self.clamp[1]) * self.normal[1]
        zs = z / self.mm
        at = np.interp(qx, xs, zs)  # arc length guess, px
        for _ in range(4):
            cx, cu, th = np.interp(at, zs, xs), np.interp(at, zs, us), np.interp(at, zs, theta)
            along = (qx - cx) * np.cos(th) + (qu - cu) * np.sin(th)
            at = at + along
        cx, cu, th = np.interp(at, zs, xs), np.interp(at, zs, us), np.interp(at, zs, theta)
        across = -(qx - cx) * np.sin(th) + (qu - cu) * np.cos(th)
        end = zs[-1]
        share = np.clip(0.5 + SUPER * (h - np.abs(across)), 0.0, 1.0) * np.clip(
            0.5 + SUPER * (end - at), 0.0, 1.0
        )
        cover = np.zeros((height, width))
        cover[iy, ix] = share.reshape(len(iy), SUPER * SUPER).mean(axis=1)
        return cover

    def tip_px(self, w_mm):
        """Image position of the end of the centreline, px."""
        x, u, _ = cantilever_shape(w_mm, self.length, self.tip_share)
        return self._to_px(x[-1:], u[-1:])[0]

    def frame(self, w_mm: float, k: int) -> np.ndarray:
        """Frame k (uint8 gray) with the tip ``w_mm`` across the rest axis."""
        width, height = self.size
        cover = self.coverage(w_mm)
        strip = np.zeros((height * SUPER, width * SUPER), np.uint8)
        # Clamp: two jaws behind the clamp point, 2.5 mm either side of the strip, 4 mm deep.
        jaws = np.zeros_like(strip)
        jaw = np.array([[0.0, -2.5], [0.0, 2.5], [-4.0, 2.5], [-4.0, -2.5]])
        self._fill(jaws, self._to_px(jaw[:, 0], jaw[:, 1]), 255)
        block = cv2.resize(jaws, (width, height), interpolation=cv2.INTER_AREA) / 255.0
        image = self.background * (1 - cover) + self.level * cover
        image = image * (1 - block) + 25.0 * block
        # A thin dark table edge across one corner, far from the clamp.
        edge = np.zeros_like(strip)
        cv2.line(
            edge, (0, int(0.85 * height * SUPER)), (int(0.35 * width * SUPER), height * SUPER), 255, 2 * SUPER
        )
        image = image - 60.0 * cv2.resize(edge, (width, height), interpolation=cv2.INTER_AREA) / 255.0
        gain = 1.0 + self.flicker * math.sin(0.9 * k + self.phase)
        image = cv2.GaussianBlur(image * gain, (0, 0), self.blur)
        image = image + self.rng.normal(0.0, self.noise, image.shape)
        return np.clip(np.round(image), 0, 255).astype(np.uint8)


def write_avi(path, frames, fps=30.0) -> None:
    """Gray frames to a Motion-JPEG AVI (OpenCV's writer)."""
    height, width = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (width, height))
    if not writer.isOpened():
        raise RuntimeError(f"OpenCV cannot write {path}")
    for frame in frames:
        writer.write(cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR))
    writer.release()
