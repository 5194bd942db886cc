"""The virtual camera: the virtual IPMC strip, driven by what the board's DAC really played, filmed.

The wires from the board onward are simulated: the DAC log of the emulated
board (board seconds, codes) goes through the *true* amplifier (a
`Calibration`, which need not equal the host's) into
``hybrid.ipmc._virtual_ipmc`` (its RC line, back-relaxation, saturation and first
mode); the tip displacement is averaged over each exposure and rendered by
`rig._render` with the sync LED lit for the fraction of the exposure it
was on. The tracker sees only the pictures.

The strip is simulated on a grid of ``fps * 8`` Hz from the board's power-up
(DAC events are held from the grid point at or after them, so the simulated
drive may lag the board by up to 1/240 s; the truth and the pictures share it).
Because the simulation needs the drive up to a frame's time, frames come out in
batches ``batch_s`` of board time behind the board, like a camera with latency.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from hybrid.ipmc import VirtualIPMCParameters, simulate_virtual_ipmc

from ._calibration import Calibration
from ._camera import Frame
from ._errors import RigError
from ._render import Look, render_frame
from ._scene import Scene

__all__ = ["VirtualCamera"]


class VirtualCamera:
    """Camera interface (``fps``, ``read``, ``close``, ``clock``) over an emulated board's world.

    Arguments:
        board: an `EmulatedBoard` (its ``dac_log``, ``led_log``, ``now``).
        scene, look: the view and how it looks.
        strip: parameters of the virtual IPMC (its camera and noise fields are ignored:
            the camera and the tracker make the measurement).
        amplifier: the true amplifier between DAC and strip.
        fps, exposure: frame rate (Hz) and exposure (s).
        seed: seeds sensor noise and flicker.
        flicker: relative amplitude of the lighting flicker.
        drop, duplicate: frame slots to drop or deliver twice (fault injection).
        hide: frame slots in which the strip is out of view (e.g. a hand in front).
    """

    OVERSAMPLE = 8

    def __init__(
        self,
        board,
        scene: Scene = Scene(),
        look: Look = Look(),
        strip: VirtualIPMCParameters = VirtualIPMCParameters(),
        amplifier: Calibration = Calibration(),
        fps: float = 30.0,
        exposure: float = 1 / 60,
        seed: int = 0,
        flicker: float = 0.05,
        batch_s: float = 0.5,
        drop=(),
        duplicate=(),
        hide=(),
    ):
        self.board, self.scene, self.look = board, scene, look
        self.strip = dataclasses.replace(
            strip,
            camera_fps=None,
            exposure_s=0.0,
            noise_std_mm=0.0,
            pixel_mm=None,
            dac_bits=24,
            oversample=2,
            full_scale_v=max(abs(amplifier.rail_low), abs(amplifier.rail_high)),
        )
        self.amplifier = amplifier
        self.fps, self.exposure = float(fps), float(exposure)
        self.grid = 1.0 / (self.fps * self.OVERSAMPLE)
        self.rng = np.random.default_rng(seed)
        self.flicker = flicker
        self.batch = batch_s
        self.drop, self.duplicate, self.hide = set(drop), set(duplicate), set(hide)
        self.t0 = board.now()
        self.slot = 0
        self.delivered = 0
        self._pending_duplicate: Frame | None = None
        self._sim_t: np.ndarray = np.zeros(0)
        self._sim_w = np.zeros(0)
        self.truth: dict[int, float] = {}  # delivered index -> exposure-averaged true w, mm

    def clock(self) -> float:
        """Now on this camera's clock (s since it opened)."""
        return self.board.now() - self.t0

    def _simulate_to(self, t_end: float) -> None:
        dac = np.array(self.board.dac_log, dtype=float).reshape(-1, 2)
        n = int(np.floor(t_end / self.grid)) + 2
        t = np.arange(n) * self.grid
        index = np.searchsorted(dac[:, 0], t, side="right") - 1
        codes = np.where(index >= 0, dac[np.maximum(index, 0), 1], dac[0, 1])
        volts = self.amplifier.volts(codes)
        self._sim_t = t
        self._sim_w = simulate_virtual_ipmc(t, volts, self.strip).w_true

    def _led_fraction(self, start: float, end: float) -> float:
        log = list(self.board.led_log)
        on = 0.0
        for k, (t, value) in enumerate(log):
            t_next = log[k + 1][0] if k + 1 < len(log) else np.inf
            if value:
                on += max(0.0, min(end, t_next) - max(start, t))
        return on / max(end - start, 1e-12)

    def read(self) -> Frame | None:
        if self._pending_duplicate is not None:
            frame, self._pending_duplicate = self._pending_duplicate, None
            self.delivered += 1
            return Frame(self.delivered - 1, frame.t, frame.image)
        while self.slot in self.drop:
            self.slot += 1
        start = self.t0 + self.slot / self.fps
        end = start + self.exposure
        if self._sim_t.size == 0 or self._sim_t[-1] < end:
            target = end + self.batch
            while self.board.now() < target:
                time.sleep(max(0.001, (target - self.board.now()) / self.board.speed))
            self._simulate_to(target)
        sub = np.linspace(start, end, 9)
        w = float(np.interp(sub, self._sim_t, self._sim_w).mean())
        led = self._led_fraction(start, end)
        gain = 1.0 + self.flicker * np.sin(2 * np.pi * 0.7 * start) + 0.01 * self.rng.standard_normal()
        scene = self.scene
        if self.slot in self.hide:
            scene = dataclasses.replace(scene, clamp=(-500.0, -500.0))
        try:
            image = render_frame(scene, self.look, w, led=led, gain=gain, rng=self.rng)
        except RigError:
            image = render_frame(
                dataclasses.replace(scene, clamp=(-500.0, -500.0)),
                self.look,
                0.0,
                led=led,
                gain=gain,
                rng=self.rng,
            )
        frame = Frame(self.delivered, start - self.t0, image)
        self.truth[self.delivered] = w
        self.delivered += 1
        if self.slot in self.duplicate:
            self._pending_duplicate = frame
            self.truth[self.delivered] = w
        self.slot += 1
        return frame

    def close(self) -> None:
        pass
