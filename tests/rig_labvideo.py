"""Synthetic 'ordinary lab video' for the tracker tests, made differently from rig._render.

Uneven background from an upsampled random field plus a gradient and paper
grain, a strip drawn as a filled polygon on a 4x canvas and area-downsampled,
a clamp with a bright screw, a dark cable elsewhere in the view, per-frame
lighting flicker, defocus blur and sensor noise, in colour. The truth is the
tip displacement the strip was drawn with.
"""

from __future__ import annotations

import cv2
import numpy as np

from rig._scene import Scene, arc_centreline

SUPER = 4


def strip_polygon(scene: Scene, w_mm: float, thickness_mm: float) -> np.ndarray:
    s, u = arc_centreline(w_mm, scene.length_mm, n=200)
    ds, du = np.gradient(s), np.gradient(u)
    norm = np.hypot(ds, du)
    ns, nu = -du / norm, ds / norm  # unit normal to the centreline
    h = thickness_mm / 2
    s = np.concatenate([[-3.0], s])  # the strip runs into the clamp
    u = np.concatenate([[0.0], u])
    ns, nu = np.concatenate([[0.0], ns]), np.concatenate([[1.0], nu])
    side_a = (s + h * ns, u + h * nu)
    side_b = (s - h * ns, u - h * nu)
    ss = np.concatenate([side_a[0], side_b[0][::-1]]) / scene.mm_per_px
    uu = np.concatenate([side_a[1], side_b[1][::-1]]) / scene.mm_per_px
    x, y = scene.to_image(ss, uu)
    return np.stack([x, y], axis=1)


class LabVideo:
    """Frames of one synthetic lab video; ``frame(w_mm, k)`` is frame k with tip displacement w."""

    def __init__(
        self,
        scene: Scene,
        size=(320, 240),
        seed=0,
        noise=4.0,
        blur=1.0,
        flicker=0.08,
        thickness_mm=0.35,
        led=(300, 24, 5),
    ):
        rng = np.random.default_rng(seed)
        self.scene, self.size, self.rng = scene, size, rng
        self.noise, self.blur, self.flicker, self.thickness, self.led = (
            noise,
            blur,
            flicker,
            thickness_mm,
            led,
        )
        width, height = size
        field = cv2.resize(rng.uniform(-1, 1, (3, 4)).astype(np.float32), size, interpolation=cv2.INTER_CUBIC)
        yy, xx = np.mgrid[0:height, 0:width] / max(size)
        base = 175 + 30 * field + 40 * (xx - 0.5) + 25 * (yy - 0.3)
        grain = cv2.GaussianBlur(rng.normal(0, 4, (height, width)), (0, 0), 0.7)
        tint = np.array([0.92, 1.0, 1.06])  # warm light, BGR
        self.background = np.clip(base + grain, 60, 250)[..., None] * tint
        self.strip_level = rng.uniform(25, 60)
        self.phase = rng.uniform(0, 2 * np.pi)

    def frame(self, w_mm: float, k: int, led_on: float = 0.0) -> np.ndarray:
        width, height = self.size
        canvas = np.zeros((height * SUPER, width * SUPER), np.uint8)
        poly = strip_polygon(self.scene, w_mm, self.thickness)
        cv2.fillPoly(canvas, [np.round((poly + 0.5) * SUPER - 0.5).astype(np.int32)], 255, cv2.LINE_8)
        cover = cv2.resize(canvas, self.size, interpolation=cv2.INTER_AREA).astype(np.float64) / 255
        image = self.background * (1 - cover[..., None]) + self.strip_level * cover[..., None]
        # The clamp block behind the clamp point (turned with the rest axis), a bright screw on it.
        block = np.array(
            self.scene.to_image(np.array([-30.0, 0.0, 0.0, -30.0]), np.array([14.0, 14.0, -14.0, -14.0]))
        )
        cv2.fillPoly(image, [np.round(block.T).astype(np.int32)], (35, 38, 40))
        sx, sy = self.scene.to_image(np.array([-15.0]), np.array([0.0]))
        cv2.circle(image, (int(round(sx[0])), int(round(sy[0]))), 4, (200, 200, 205), -1)
        cv2.line(image, (width - 40, height), (width - 10, height // 2 + 30), (50, 50, 50), 3, cv2.LINE_AA)
        if self.led is not None:
            lx, ly, lr = self.led
            level = 80 + 175 * led_on
            cv2.circle(image, (lx, ly), lr, (level * 0.6, level * 0.7, level), -1, cv2.LINE_AA)
        gain = (
            1 + self.flicker * np.sin(2 * np.pi * 0.37 * k + self.phase) + 0.02 * self.rng.standard_normal()
        )
        image = cv2.GaussianBlur(image * gain, (0, 0), self.blur)
        image = image + self.rng.normal(0, self.noise, image.shape)
        return np.clip(np.round(image), 0, 255).astype(np.uint8)


def write_video(path, frames, fps=30.0) -> None:
    fourcc = {".avi": "MJPG", ".mp4": "mp4v"}[str(path)[-4:]]
    height, width = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, (width, height))
    assert writer.isOpened(), f"OpenCV cannot write {path}"
    for frame in frames:
        writer.write(frame if frame.ndim == 3 else cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR))
    writer.release()


if __name__ == "__main__":
    # Tracker error on three lab-like videos (the numbers quoted in rig/README.md).
    import pathlib
    import tempfile

    from rig._camera import VideoSource
    from rig._tracker import TipTracker

    scene = Scene()
    sweep = 6.2 * np.sin(np.linspace(0, 4 * np.pi, 300))
    with tempfile.TemporaryDirectory() as tmp:
        for seed, suffix, noise, blur, flicker in [
            (0, ".avi", 4.0, 1.0, 0.08),
            (1, ".mp4", 6.0, 1.4, 0.12),
            (2, ".avi", 3.0, 0.7, 0.05),
        ]:
            video = LabVideo(scene, seed=seed, noise=noise, blur=blur, flicker=flicker)
            path = pathlib.Path(tmp) / f"lab{seed}{suffix}"
            write_video(path, [video.frame(w, k) for k, w in enumerate(sweep)])
            tracker = TipTracker(scene)
            with VideoSource(path) as source:
                w = np.array([tracker.track(frame.image).w for frame in source])
            error = w - sweep
            print(
                f"{path.name}: noise {noise:g}, blur {blur:g} px, flicker {flicker:.0%}: "
                f"RMS {np.sqrt(np.mean(error**2)):.4f} mm, max {np.max(np.abs(error)):.4f} mm "
                f"over {len(w)} frames, deflections +-6.2 mm"
            )
