"""Render a bent strip as a camera would see it (the virtual camera's pictures).

A dark strip of visible thickness ``thickness_mm`` bent along a circular arc
(`rig._scene.arc_centreline`), a clamp block behind the clamp point, an
uneven background (gradient and vignetting), shading across the strip, a sync
LED, Gaussian blur, lighting flicker and sensor noise. Anti-aliased exactly:
each pixel's darkness is the strip's coverage from its distance to the arc.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from ._errors import RigError
from ._scene import Scene

__all__ = ["Look", "render_frame", "strip_coordinates"]


@dataclasses.dataclass(frozen=True)
class Look:
    """How the picture looks (gray levels 0..255).

    Arguments:
        size: (width, height), px.
        background: mean background level.
        gradient: background change across the picture (left to right), levels.
        vignette: fractional darkening at the corners.
        strip_level: the strip's level at its centreline (before lighting).
        thickness_mm: visible thickness of the strip, mm.
        blur_px: Gaussian blur sigma, px (defocus).
        noise: sensor noise std, levels.
        led: (x, y, radius) of the sync LED, px, or None.
    """

    size: tuple[int, int] = (320, 240)
    background: float = 190.0
    gradient: float = 50.0
    vignette: float = 0.25
    strip_level: float = 45.0
    thickness_mm: float = 0.3
    blur_px: float = 0.8
    noise: float = 3.0
    led: tuple[float, float, float] | None = (296.0, 20.0, 5.0)


def strip_coordinates(scene: Scene, w_mm: float, x: np.ndarray, y: np.ndarray):
    """For image points: distance across the strip's centreline and arc length past its tip, both px.

    The centreline is the arc bent to tip displacement ``w_mm``; ``past`` is
    negative along the strip and positive beyond its (flat, cut) end.
    """
    length = scene.length_mm
    if length is None:
        raise RigError("a strip is drawn at its free length: give the scene's length_mm (mm)")
    px = scene.mm_per_px
    dx, dy = x - scene.clamp[0], y - scene.clamp[1]
    s = (dx * scene.axis[0] + dy * scene.axis[1]) * px  # mm
    u = (dx * scene.normal[0] + dy * scene.normal[1]) * px
    if abs(w_mm) < 1e-9:
        return np.abs(u) / px, (s - length) / px
    from ._scene import arc_centreline

    s_arc, u_arc = arc_centreline(w_mm, length, n=3)
    tip_s, tip_u = s_arc[-1], u_arc[-1]
    r = (tip_s**2 + tip_u**2) / (2 * tip_u)  # signed radius, centre (0, r)
    ang = np.arctan2(s, np.sign(r) * (r - u))  # arc angle of each point from the clamp
    across = np.abs(np.hypot(s, u - r) - abs(r))
    return across / px, (ang * abs(r) - length) / px


def render_frame(
    scene: Scene,
    look: Look,
    w_mm: float,
    led: float = 0.0,
    gain: float = 1.0,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """One 8-bit gray frame of the strip with tip displacement ``w_mm``.

    Arguments:
        led: fraction of the exposure during which the sync LED was lit, 0..1.
        gain: lighting level of this frame (flicker), 1 = nominal.
        rng: noise source (None: no noise).
    """
    width, height = look.size
    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    xn, yn = x / width - 0.5, y / height - 0.5
    back = look.background + look.gradient * xn - 0.3 * look.gradient * yn
    back = back * (1.0 - look.vignette * (xn**2 + yn**2) / 0.5)
    half = 0.5 * look.thickness_mm / scene.mm_per_px
    d, past = strip_coordinates(scene, w_mm, x, y)
    cover = np.clip(half + 0.5 - d, 0.0, 1.0) * np.clip(0.5 - past, 0.0, 1.0)
    # Shading: the strip's faces catch a little light at the middle of its thickness.
    shade = look.strip_level * (1.0 + 0.25 * np.clip(1.0 - (d / max(half, 0.5)) ** 2, 0.0, 1.0))
    image = back * (1.0 - cover) + shade * cover
    # The clamp: a dark block ending at the clamp point, across the axis.
    s = (x - scene.clamp[0]) * scene.axis[0] + (y - scene.clamp[1]) * scene.axis[1]
    u = (x - scene.clamp[0]) * scene.normal[0] + (y - scene.clamp[1]) * scene.normal[1]
    clamp = np.clip(0.5 - s, 0, 1) * np.clip(12.5 - np.abs(u), 0, 1) * np.clip(s + 30.5, 0, 1)
    image = image * (1 - clamp) + 30.0 * clamp
    if look.led is not None:
        lx, ly, lr = look.led
        spot = np.clip(lr + 0.5 - np.hypot(x - lx, y - ly), 0.0, 1.0)
        image = image * (1 - spot) + spot * (70.0 + 185.0 * float(np.clip(led, 0.0, 1.0)))
    image = image * gain
    if look.blur_px > 0:
        image = cv2.GaussianBlur(image, (0, 0), look.blur_px)
    if rng is not None and look.noise > 0:
        image = image + rng.normal(0.0, look.noise, image.shape)
    return np.clip(np.round(image), 0, 255).astype(np.uint8)
