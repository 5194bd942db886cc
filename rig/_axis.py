"""Find the strip's rest axis (the direction it leaves the clamp in) from the video itself.

The strip is clamped at one end, so whatever its deflection its centreline
leaves the clamp point along the rest axis (no linear term in ``u(s)`` across
the axis, whatever the bend: an IPMC's near-uniform curvature, a cantilever's
curvature falling from the clamp to its tip under a load). Three steps,
each using only the tracker's dark-line contrast (nothing about colours or how
the picture was made):

1. **Angular profile.** The contrast of the first frames, averaged, is sampled
   along rays from the clamp point, every 0.5 degree, from just past the
   clamp to 30 % of the free length (where even a strongly bent strip is still
   within a few pixels of its rest axis). Dark lines leaving the clamp are
   peaks of the mean contrast along the ray; the few highest, at least 20
   degrees apart, are the candidates.
2. **Continuity.** For each candidate the tracker follows the strip along
   that axis in five of the frames; it accepts a strip only if it leaves the
   clamp along the axis and runs out to at least 40 % of the free length. The
   candidate followed in the most frames (then: with the highest contrast) is
   the strip; after step 3 it must be followed in at least half of all frames.
3. **Refinement.** The sections the tracker found are fitted together, all
   frames at once, with strips that leave one point ``(0, e)`` near the
   clamp along one tangent at angle ``tilt`` and whose curvature along them is
   a polynomial in arc length: arcs (an IPMC), one shape of degree 1 or 2 for
   all frames with each frame's own size (a cantilever under a tip or a
   distributed load, Euler-Bernoulli), or each frame's own quadratic; the
   simplest that fits within 25 % of the best residual is kept
   (`_shared_line`). The axis turns by the tilt and the clamp point moves
   ``e`` across it, onto the strip; four rounds bring the axis to a few
   hundredths of a degree, which is what the tip needs (0.1 degree is 0.04 mm
   at the end of a 22 mm strip). Without ``e``, a clamp point given 2 px
   beside the strip tilts the axis by 2 degrees; a polynomial
   ``a s + b s^2 + c s^3`` in place of the curvature model leaks the shape's
   ``s^4`` term into ``a`` (0.3 degree for a 6 mm bend); arcs alone on a
   cantilever bent to one side in every frame used (a strip moving from the
   first frame) tilt it by 3-5 degrees.

Confidence: the mean contrast along the best direction against that along
the darkest direction at least 20 degrees away from it (the clamp's edge, a
cable). A ratio below 1 is possible: a longer dark line (a lead running out
of the picture) is not a strip, whose tip must lie about a free length away.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ._scene import Scene
from ._tracker import TipTracker

__all__ = ["AxisEstimate", "angular_profile", "find_axis", "refine_axis", "strip_along"]

PROFILE_STEP_DEG = 0.5
SEPARATION_DEG = 20.0
CANDIDATES = 3
MIN_TRACKED = 0.5  # a strip must be followed in at least half the frames
MIN_OUTLIER_FRAMES = 6  # frames `_consistent` needs to leave any out
#: A frame's arc misfit beyond this × the median frame's: not the strip alone (`_consistent`).
OUTLIER_MISFIT = 3.0
SHAPE_MODELS = ((True, 0), (True, 1), (True, 2), (False, 2))  # (one shape for all frames, curvature degree)
BETTER_FIT = 1.25  # the simplest shape whose residual RMS is within this factor of the lowest


@dataclasses.dataclass(frozen=True)
class AxisEstimate:
    """The rest axis found in a video.

    Attributes:
        angle_deg: direction of the rest axis, degrees (0 = pointing right,
            90 = down in the picture), in [0, 360); None when no strip was found.
        contrast_best: mean relative contrast along the best direction (0..1).
        contrast_next: the same for the best direction at least 20 degrees away.
        next_deg: that direction, degrees (None if nothing else).
        tracked: frames (of ``frames``) in which the tracker followed the strip along the axis.
        frames: frames used.
        reason: "ok" or why no strip was found.
        clamp_xy: where the strip's rest line passes the given clamp point (x, y px): the
            point moved across the axis onto the strip.
        offset_px: how far it moved, px, positive along ``(sin a, -cos a)`` (the sign of w).
    """

    angle_deg: float | None
    contrast_best: float
    contrast_next: float
    next_deg: float | None
    tracked: int
    frames: int
    reason: str
    clamp_xy: tuple[float, float] | None = None
    offset_px: float = 0.0

    @property
    def confidence(self) -> float:
        """Contrast of the best direction over the next best (inf when nothing else is dark)."""
        if self.contrast_next <= 0:
            return math.inf
        return self.contrast_best / self.contrast_next

    def metadata(self) -> dict:
        """JSON-able summary (angles in degrees, contrasts relative)."""
        return {
            "angle_deg": self.angle_deg,
            "contrast_best": self.contrast_best,
            "contrast_next": self.contrast_next,
            "next_deg": self.next_deg,
            "confidence": None if math.isinf(self.confidence) else self.confidence,
            "tracked_frames": self.tracked,
            "frames": self.frames,
            "reason": self.reason,
            "clamp_xy": list(self.clamp_xy) if self.clamp_xy is not None else None,
            "offset_px": self.offset_px,
        }

    def describe(self) -> str:
        """One line for people."""
        if self.angle_deg is None:
            return f"no strip found leaving the clamp ({self.reason})"
        other = (
            f"next darkest direction {self.next_deg:.1f} deg at {self.contrast_next:.3f} "
            f"(ratio {self.confidence:.1f})"
            if self.next_deg is not None
            else "no other dark direction"
        )
        return (
            f"{round(self.angle_deg, 2) % 360:.2f} deg (0 = right, 90 = down), contrast {self.contrast_best:.3f} "
            f"along it; {other}; strip followed in {self.tracked} of {self.frames} frames; "
            f"it leaves the clamp {self.offset_px:+.2f} px across the axis from the given point"
        )


def angular_profile(
    contrast: np.ndarray, clamp, r_min: float, r_max: float, step_deg: float = PROFILE_STEP_DEG
) -> tuple[np.ndarray, np.ndarray]:
    """Mean contrast along rays from ``clamp`` (x, y px) between radii ``r_min`` and ``r_max`` px.

    Returns (angles in degrees, 0 = +x, 90 = +y; mean contrast per ray). Rays
    leaving the picture count the part outside as zero contrast.
    """
    import cv2

    angles = np.arange(0.0, 360.0, step_deg)
    radii = np.arange(r_min, r_max + 0.5, 1.0)
    t = np.radians(angles)[:, None]
    x = (clamp[0] + radii[None, :] * np.cos(t)).astype(np.float32)
    y = (clamp[1] + radii[None, :] * np.sin(t)).astype(np.float32)
    values = cv2.remap(
        contrast.astype(np.float32), x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0.0
    )
    return angles, values.mean(axis=1)


def _peaks(angles: np.ndarray, profile: np.ndarray, count: int, separation: float) -> list[int]:
    """Indices of the ``count`` highest local maxima of a circular profile, ``separation`` degrees apart."""
    order = np.argsort(profile)[::-1]
    chosen: list[int] = []
    for i in order:
        if profile[i] <= 0:
            break
        if all(_angle_diff(angles[i], angles[j]) >= separation for j in chosen):
            chosen.append(int(i))
            if len(chosen) == count:
                break
    return chosen


def _angle_diff(a: float, b: float) -> float:
    """Absolute difference of two directions, degrees in [0, 180]."""
    return abs((a - b + 180.0) % 360.0 - 180.0)


def strip_along(contrasts, scene: Scene, strip_px: float) -> tuple[int, float]:
    """How well a strip runs along ``scene``'s axis: (frames tracked, median contrast of those).

    ``contrasts`` are the tracker's contrast images of the frames.
    """
    tracker = TipTracker(scene, strip_px=strip_px)
    tracked, levels = 0, []
    for contrast in contrasts:
        result = tracker.track_contrast(contrast)
        if result.quality:
            tracked += 1
            sec = tracker.sections(contrast)
            levels.append(float(np.nanmedian(sec.peak[np.isfinite(sec.u)])))
    return tracked, float(np.median(levels)) if levels else 0.0


def refine_axis(contrasts, scene: Scene, strip_px: float, rounds: int = 4) -> Scene | None:
    """The strip's rest line near ``scene``'s axis: ``scene`` with the angle and clamp point it really has.

    Each round follows the strip in every frame along the current axis and
    fits all frames' sections at once with arcs that share their start and
    tangent (`_shared_line`); the axis turns by ``-atan(a)`` and the
    clamp point moves ``e`` px across it. None when no frame gives a strip.
    """
    for _ in range(rounds):
        tracker = TipTracker(scene, strip_px=strip_px)
        points = []
        for contrast in contrasts:
            sec = tracker.sections(contrast)
            if not tracker.leaves_clamp(sec):
                continue
            found = tracker.centreline_points(sec)
            if found is not None and len(found[0]) >= 12:
                points.append(found)
        if not points:
            return None
        tilt, offset = _shared_line(_consistent(points))
        x, y = scene.to_image(np.array([0.0]), np.array([offset]))
        scene = dataclasses.replace(
            scene,
            clamp=(float(x[0]), float(y[0])),
            angle_deg=(scene.angle_deg - math.degrees(math.atan(tilt))) % 360.0,
        )
        if abs(tilt) < 1e-5 and abs(offset) < 1e-3:
            break
    return scene


def _consistent(points):
    """The frames' sections that one strip's shapes share: those whose arc misfit is not an outlier.

    Arcs through one point along one tangent (`_shared_arc`) are fitted to the
    frames kept (at first the half that all frames' arcs misfit least), and a
    frame whose RMS misfit exceeds `OUTLIER_MISFIT` × the median kept frame's
    (and 0.5 px) is left out, the others kept, until that holds: where the
    strip crosses a dark line beside it (a probe's bar along its path), the
    tracker's section runs on along that line in some frames (290 px for a
    220 px strip), and those frames tilted the shared tangent by 2 degrees
    (0.75 mm at the tip, on every frame). Fitted with them, every frame
    misfits by about 2 px, and they by 3.6-7 px; without them, 0.05 px. A
    cantilever's arcs misfit every frame alike (0.9 px): none is left out.
    """
    if len(points) < MIN_OUTLIER_FRAMES:  # too few to tell a strip's spread from an outlier
        return points
    scale = max(float(np.max(s)) for s, _ in points)
    data = [(np.asarray(s, float) / scale, np.asarray(u, float) / scale) for s, u in points]

    def misfits(kept):
        slope, offset, _ = _shared_arc([data[i] for i in kept])
        return np.array([_arc_misfit(s, u, slope, offset) for s, u in data]) * scale

    first = misfits(range(len(points)))
    kept = [i for i in range(len(points)) if first[i] <= np.median(first)]  # the better half, to start
    for _ in range(len(points)):
        misfit = misfits(kept)
        bound = max(OUTLIER_MISFIT * float(np.median(misfit[kept])), 0.5)
        now = [i for i in range(len(points)) if misfit[i] <= bound]
        if now == kept:
            break
        kept = now
    return [points[i] for i in kept] if len(kept) >= len(points) // 2 else points


def _arc_misfit(s: np.ndarray, u: np.ndarray, slope: float, offset: float) -> float:
    """RMS misfit of the best arc through ``(0, offset)`` along ``(1, slope)`` (`_shared_arc`'s form)."""
    basis = (s**2 + u**2) / 2
    rest = u - offset - slope * s
    k = float(basis @ rest / max(float(basis @ basis), 1e-300))
    return float(np.sqrt(np.mean((rest - k * basis) ** 2)))


def _cumulative(values: np.ndarray, step: float) -> np.ndarray:
    """Running trapezoid integral along the last axis, starting at 0."""
    out = np.zeros_like(values)
    out[..., 1:] = np.cumsum(0.5 * (values[..., 1:] + values[..., :-1]), axis=-1) * step
    return out


def _bent_strip(theta: np.ndarray, dtheta: np.ndarray, z: np.ndarray, s: np.ndarray, offset: float):
    """A strip leaving ``(0, offset)`` whose tangent turns as ``theta`` along the arc lengths ``z``,
    read where its axial coordinate is ``s``: (u, du/dp for the parameters whose dtheta/dp are the
    rows of ``dtheta``), or None when it turns back (past 87 degrees) before the last ``s``.

    The centreline is the integral of ``(cos theta, sin theta)`` (trapezoids); at fixed
    ``s`` a parameter moves ``u`` by ``dy/dp - tan(theta) dx/dp``.
    """
    step = z[1] - z[0]
    cos, sin = np.cos(theta), np.sin(theta)
    turned = np.flatnonzero(cos <= 0.05)
    end = int(turned[0]) if turned.size else len(z)
    x = _cumulative(cos[:end], step)
    if end < 2 or x[-1] < float(np.max(s)):
        return None
    y = offset + _cumulative(sin[:end], step)
    dx = _cumulative(-sin[:end] * dtheta[:, :end], step)
    dy = _cumulative(cos[:end] * dtheta[:, :end], step)
    slope = np.tan(np.interp(s, x, theta[:end]))
    jac = np.array([np.interp(s, x, dy[j]) - slope * np.interp(s, x, dx[j]) for j in range(len(dtheta))])
    return np.interp(s, x, y), jac


def _curvature_fit(data, shared_shape: bool, start, degree: int, iterations: int = 25, samples: int = 256):
    """Least-squares strips with a common tangent at the clamp: (tilt rad, e, residual sum of squares,
    parameter count), ``data`` in units of the longest ``s``; None if the fit fails.

    Each frame's curvature along the strip is ``A_f (1 + b_1 z + .. + b_d z^d)``; the
    shape ``b`` is each frame's own (``shared_shape`` False: any polynomial of degree d)
    or the same in every frame (True: one kind of load whose size changes).
    Gauss-Newton from ``start`` = (slope, e, per-frame curvature) of the arcs, with
    steps halved until the residual falls.
    """
    frames = len(data)
    per = 1 if shared_shape else degree + 1
    count = 2 + (degree if shared_shape else 0) + per * frames
    params = np.zeros(count)
    params[0], params[1] = math.atan(start[0]), start[1]
    first = 2 + (degree if shared_shape else 0)
    params[first::per] = start[2]
    grids = [np.linspace(0.0, 1.6 * float(np.max(s)) + 1e-3, samples) for s, _ in data]

    def evaluate(p):
        residuals, blocks = [], []
        for f, (s, u) in enumerate(data):
            z = grids[f]
            powers = np.vstack([z ** (j + 1) / (j + 1) for j in range(degree + 1)])  # z, z^2/2, ..
            block = np.zeros((len(s), count))
            own = slice(first + per * f, first + per * (f + 1))
            if shared_shape:
                size, shape = p[own][0], np.concatenate([[1.0], p[2:first]])
                turn = shape @ powers
                dtheta = np.vstack([np.ones_like(z), size * powers[1:], turn[None, :]])
                theta = p[0] + size * turn
            else:
                theta = p[0] + p[own] @ powers
                dtheta = np.vstack([np.ones_like(z), powers])
            found = _bent_strip(theta, dtheta, z, s, p[1])
            if found is None:
                return None, None
            model, jac = found
            block[:, 0], block[:, 1] = jac[0], 1.0
            if shared_shape:
                block[:, 2:first] = jac[1 : first - 1].T
                block[:, own] = jac[-1][:, None]
            else:
                block[:, own] = jac[1:].T
            residuals.append(u - model)
            blocks.append(block)
        return np.concatenate(residuals), np.vstack(blocks)

    residual, jacobian = evaluate(params)
    if residual is None:
        return None
    for _ in range(iterations):
        delta = _least_squares(jacobian, residual)
        cost = float(residual @ residual)
        for _ in range(20):
            trial = params + delta
            new_residual, new_jacobian = evaluate(trial)
            if new_residual is not None and float(new_residual @ new_residual) <= cost:
                break
            delta = 0.5 * delta
        else:
            break
        params, residual, jacobian = trial, new_residual, new_jacobian
        if np.max(np.abs(delta)) < 1e-9:
            break
    return float(params[0]), float(params[1]), float(residual @ residual), count


def _shared_line(points) -> tuple[float, float]:
    """Slope ``a = tan(tilt)`` and offset ``e`` (px) of the tangent at the clamp shared by all frames' strips.

    Every frame's strip leaves the point ``(0, e)`` along the direction
    ``tilt``; along it, its curvature is a polynomial in arc length
    (`_curvature_fit`): constant for an IPMC's near-uniform bend (a circular
    arc, exact however far bent), linear for a cantilever under a tip load,
    quadratic under a distributed load (Euler-Bernoulli: curvature is the
    bending moment over EI, zero slope at the clamp). The models, simplest
    first (`SHAPE_MODELS`): arcs; one curvature shape of degree 1, then 2,
    shared by all frames with each frame's own size (one kind of load); each
    frame's own quadratic (loads that change their kind). The simplest one
    whose residual RMS is within `BETTER_FIT` of the lowest is taken: a wrong
    shape leaves residuals many times the sections' noise (0.04 px; an arc on
    a cantilever 0.9 px, one shape for loads that change 0.2 px), whereas a more
    flexible model than the strip needs bends to the few hundredths of a pixel
    that a textured background or the clamp's edge adds next to the clamp,
    and tilts (0.1-0.25 degree with every frame's own shape). An arc fitted
    to a cantilever tilts the tangent by 3-5 degrees for a 2-7 mm bend of a
    22 mm strip all to one side (issue 33: 1.9 degrees, 0.66 mm at the tip).
    ``points`` is a list of (s, u) px per frame.
    """
    scale = max(float(np.max(s)) for s, _ in points)
    data = [(np.asarray(s, float) / scale, np.asarray(u, float) / scale) for s, u in points]
    start = _shared_arc(data)
    fits = [_curvature_fit(data, shared, start, degree) for shared, degree in SHAPE_MODELS]
    fits = [fit for fit in fits if fit is not None]
    if not fits:
        return start[0], start[1] * scale
    floor = min(fit[2] for fit in fits)
    chosen = next(fit for fit in fits if fit[2] <= BETTER_FIT**2 * floor)
    return math.tan(chosen[0]), chosen[1] * scale


def _shared_arc(data) -> tuple[float, float, np.ndarray]:
    """Slope ``a``, offset ``e`` and each frame's curvature ``k`` of circular arcs through ``(0, e)``
    along ``(1, a)``, linear least squares (``data`` in units of the longest ``s``).

    A circle of radius r through ``(0, e)`` whose tangent there is ``(1, a)``
    satisfies ``u = e + a s + k (s^2 + (u - e)^2) / 2`` exactly, with
    ``k = sqrt(1 + a^2) / r`` (signed); with the measured ``u`` in place of
    ``u - e`` (``e`` is a few px at most) it is linear in ``e``, ``a`` and the
    ``k``. Exact for arcs; the start of `_shared_line`'s fit for other shapes.
    """
    rows = sum(len(s) for s, _ in data)
    design = np.zeros((rows, 2 + len(data)))
    target = np.zeros(rows)
    at = 0
    for f, (s, u) in enumerate(data):
        n = len(s)
        design[at : at + n, 0] = s
        design[at : at + n, 1] = 1.0
        design[at : at + n, 2 + f] = (s**2 + u**2) / 2
        target[at : at + n] = u
        at += n
    coef = _least_squares(design, target)
    return float(coef[0]), float(coef[1]), coef[2:] * math.sqrt(1.0 + coef[0] ** 2)


def _least_squares(design: np.ndarray, target: np.ndarray) -> np.ndarray:
    """``x`` minimising ``|design x - target|``, by the normal equations with unit-scaled columns.

    ``design`` is thousands of rows by a few dozen columns: a dense SVD of it
    (``np.linalg.lstsq``) is fast on one thread but took 0.4 s a call with a
    multi-threaded BLAS on a busy 2-core machine; the small square system does not.
    """
    norms = np.sqrt(np.einsum("ij,ij->j", design, design))
    norms[norms == 0] = 1.0
    scaled = design / norms
    normal = np.einsum("ki,kj->ij", scaled, scaled)
    rhs = np.einsum("ki,k->i", scaled, target)
    try:
        solution = np.linalg.solve(normal + 1e-12 * np.eye(len(normal)), rhs)
    except np.linalg.LinAlgError:
        solution = np.linalg.lstsq(normal, rhs, rcond=None)[0]
    return solution / norms


def find_axis(
    frames, clamp, mm_per_px: float, length_mm: float | None, strip_px: float = 4.0
) -> AxisEstimate:
    """Find the rest axis of the strip clamped at ``clamp`` (x, y px) in ``frames`` (a few, BGR or gray).

    Arguments:
        frames: images from the start of the video (10-20 are plenty).
        mm_per_px: image scale, mm per pixel.
        length_mm: free strip length, mm (None: 40 mm is searched).
        strip_px: visible strip thickness, px.
    """
    frames = list(frames)
    scene = Scene(clamp=tuple(clamp), mm_per_px=mm_per_px, angle_deg=0.0, length_mm=length_mm)
    tracker = TipTracker(scene, strip_px=strip_px)
    contrasts = [tracker.contrast(f) for f in frames]
    length_px = (length_mm or 40.0) / mm_per_px
    r_min = tracker.start_px + strip_px
    r_max = max(r_min + 10.0, 0.3 * length_px)
    angles, profile = angular_profile(np.mean(contrasts, axis=0), clamp, r_min, r_max)
    # Rank the candidate directions on a few frames, refine the best on all of them.
    few = contrasts[:: max(1, len(contrasts) // 5)][:5]
    ranked = []
    peaks = _peaks(angles, profile, CANDIDATES, SEPARATION_DEG)
    for i in peaks:
        tracked, level = strip_along(few, dataclasses.replace(scene, angle_deg=float(angles[i])), strip_px)
        if tracked:
            ranked.append(((tracked, level), float(angles[i])))
    rest, tracked = None, 0
    if ranked:
        coarse = max(ranked)[1]
        rest = refine_axis(contrasts, dataclasses.replace(scene, angle_deg=coarse), strip_px)
        if rest is not None:
            tracked, _ = strip_along(contrasts, rest, strip_px)
    if rest is None or tracked < MIN_TRACKED * len(frames):
        reason = (
            (
                "no strip was followed along the darkest direction"
                if (len(ranked) or len(peaks)) == 1
                else f"no strip was followed along any of the {len(ranked) or len(peaks)} darkest directions"
            )
            if rest is None
            else f"a strip was followed in only {tracked} of {len(frames)} frames"
        )
        return AxisEstimate(None, float(profile.max(initial=0.0)), 0.0, None, tracked, len(frames), reason)
    angle = rest.angle_deg
    angles, profile = angular_profile(np.mean(contrasts, axis=0), rest.clamp, r_min, r_max)
    best_value = _profile_at(angles, profile, angle)
    far = np.array([_angle_diff(a, angle) >= SEPARATION_DEG for a in angles])
    j = int(np.flatnonzero(far)[np.argmax(profile[far])])
    next_value = float(profile[j])
    offset = float(np.dot(np.subtract(rest.clamp, clamp), rest.normal))
    return AxisEstimate(
        angle,
        best_value,
        next_value,
        float(angles[j]) if next_value > 0 else None,
        tracked,
        len(frames),
        "ok",
        clamp_xy=rest.clamp,
        offset_px=offset,
    )


def _profile_at(angles: np.ndarray, profile: np.ndarray, angle: float) -> float:
    """The profile's highest value within one step of ``angle`` (degrees)."""
    near = np.array([_angle_diff(a, angle) <= PROFILE_STEP_DEG for a in angles])
    return float(profile[near].max())
