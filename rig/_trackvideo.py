"""``rig track``: the tip displacement of every frame of a video, with an honest account of the video.

Steps: the first frames find (or check) the rest axis (`rig._axis`);
every frame is tracked; the frame times come from the video itself
(`rig._camera.VideoSource`), holes in them are gaps, and the frames
read are compared with the frames the file announces. The CSV (``t,w,quality``)
and its JSON sidecar (``F.csv.json``) are written together, atomically, at the
end. When the run fails (below, or Ctrl-C) what was read is still written, so
nothing read is lost, but under another name, ``F.partial.csv`` (``-2``, ...
if taken: `hybrid.util._atomic.partial_path`), so that a file the user had at
``F.csv`` is never replaced by a failed run; the error names it:

- a gap (frames lost inside the file, places known): the frames either side
  get quality 0, the gap is listed, a warning is printed; exit 0;
- frames missing at the end (a truncated file) or whose places are unknown:
  ``"complete": false``, and a `RigError` (exit 2) says how many of how
  many frames were read;
- no strip along any axis (or along the given one): every row has quality 0
  and w NaN, and a `RigError` says so.
"""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib
import sys
from typing import Any

import numpy as np

from hybrid import InputError

from ._axis import AxisEstimate, find_axis
from ._camera import Frame, VideoSource, find_gaps
from ._errors import RigError
from ._files import check_csv_out, check_outputs, jsonable, partial_path, write_together
from ._scene import Scene, check_in_picture
from ._sync import LedDetector
from ._tracker import BLURRED, TipTracker

__all__ = ["TrackJob", "track_video"]

HEAD_FRAMES = 30  # frames read first to find the axis; every other one is used
HEAD_WINDOWS = 3  # windows of HEAD_FRAMES tried in turn where the strip is not found in the first
AXIS_WARN_DEG = 1.0  # a given axis this far from the detected one earns a warning
#: The tip's median distance from the clamp, as a fraction of --length, below which the scale or the
#: length is doubted (a cantilever's tip stays within a few per cent of its free length).
LENGTH_WARN_FRACTION = 0.75
#: ... and above which: no strip's tip lies farther from its clamp than its length (the tracked tip's
#: round end and a pixel's rounding add a few per cent).
LENGTH_WARN_BEYOND = 1.1
CLAMP_WARN_PX = 1.0  # so does a given clamp point this far beside the strip
REPEAT_REASON = "repeats the frame before"  # untracked reason of a frame identical to the one before
#: A tracked strip whose length differs from the tracked frames' median by more than this share is not
#: the strip alone (`_runaways`).
RUNAWAY = 0.05
RUNAWAY_REASON = (
    "strip longer or shorter than in the other frames (its tip covered, or another dark line there?)"
)


@dataclasses.dataclass(frozen=True)
class TrackJob:
    """What ``rig track`` was asked.

    Arguments:
        video, out: input video and output CSV paths (the sidecar is ``out + '.json'``).
        clamp: clamp point (x, y), px.
        mm_per_px: image scale, mm per pixel.
        axis_deg: rest axis, degrees (0 = right, 90 = down); None: find it.
        length_mm: free strip length, mm.
        strip_px: visible strip thickness, px.
        led: sync LED (x, y, radius) px, or None.
        exposure: camera exposure, s (for the LED), or None.
    """

    video: str
    out: str
    clamp: tuple[float, float]
    mm_per_px: float
    axis_deg: float | None = None
    length_mm: float | None = 22.0
    strip_px: float = 4.0
    led: tuple[float, float, float] | None = None
    exposure: float | None = None

    @property
    def sidecar(self) -> pathlib.Path:
        return pathlib.Path(f"{pathlib.Path(self.out)}.json")  # `--out .` too (refused by check_csv_out)


def _warn(message: str) -> None:
    print(f"rig: warning: {message}", file=sys.stderr)


def _check_scene(job: TrackJob, image) -> None:
    """Refuse a clamp point outside the picture, and a strip too short or too long in pixels to follow."""
    check_in_picture(job.clamp, job.mm_per_px, job.length_mm, image.shape, job.video)


def _length_warning(job: TrackJob, tips, clamp) -> str | None:
    """A warning when the tracked tips lie well short of --length from the clamp, or beyond it: the scale or
    the length is off (a probe's --mm-per-px 0.12 for 0.1 scaled w by 1.2 without a word)."""
    if job.length_mm is None or not tips:
        return None
    reach = float(np.median([math.hypot(x - clamp[0], y - clamp[1]) for x, y in tips])) * job.mm_per_px
    if LENGTH_WARN_FRACTION * job.length_mm <= reach <= LENGTH_WARN_BEYOND * job.length_mm:
        return None
    share = f"{reach / job.length_mm:.2f} of" if reach < job.length_mm else f"{reach / job.length_mm:.2f} ×"
    return (
        f"the strip's tip lies a median {reach:.3g} mm from the clamp, {share} --length {job.length_mm:g} mm: "
        f"if the strip is that long, give --length {reach:.3g}; if not, --mm-per-px {job.mm_per_px:g} is off "
        "by about that factor, and w with it"
    )


def _runaways(w: list, quality: list, lengths: list, held: list, tips: list, reasons: dict) -> None:
    """Frames whose strip, measured along its centreline to the tip found (`lengths`), is longer or shorter
    than the tracked frames' median by more than `RUNAWAY`: quality 0.

    A strip keeps its length however it bends; a longer one is a section that ran on along another
    dark line the strip crossed (a verifier's bar beyond the tip, tilted across its path: 41 frames of
    quality 1 read the bar, up to 2.1 mm off), a shorter one a tip found where the strip meets such a
    line, or a tip covered by something light (a verifier's light disc: 18 frames of quality 1, w up to
    1.1 mm short). Their w is held at the last tracked frame's, as a frame not tracked (and so are the held
    frames after them), their tips leave `tips`, and they are counted under `RUNAWAY_REASON`. Edits
    the lists in place; nothing where fewer than 5 frames were tracked.
    """
    r = np.asarray(lengths, float)
    tracked = np.isfinite(r)
    if tracked.sum() < 5:
        return
    away = tracked & (np.abs(r / float(np.median(r[tracked])) - 1.0) > RUNAWAY)
    if not away.any():
        return
    tips[:] = [tip for tip, k in zip(tips, np.flatnonzero(tracked)) if not away[k]]
    last = math.nan
    for k in range(len(w)):
        if away[k]:
            quality[k], held[k] = 0, True
        if held[k]:
            w[k] = last
        elif quality[k]:
            last = w[k]
    reasons[RUNAWAY_REASON] = int(away.sum())


def _untracked_warning(reasons: dict, frames: int) -> str | None:
    """A warning for the frames whose tip was not measured as the others (quality 0), by reason, or None.

    A probe's covered tip (15 frames, w held up to 11.9 mm off) showed only as "285 tracked"; the reasons
    were in the sidecar alone. Repeated frames have a warning of their own. It said that `hybrid fit` fitted
    them as measured, which it does not (`quality_notes`): a probe took that as leave to drop the column,
    and its fit of a blurred video took the smeared frames as data.
    """
    counted = {reason: n for reason, n in reasons.items() if reason != REPEAT_REASON}
    if not counted:
        return None
    listed = "; ".join(f"{reason}: {n}" for reason, n in sorted(counted.items(), key=lambda kv: -kv[1]))
    return (
        f"{sum(counted.values())} of {frames} frames have quality 0 ({listed}): w there is held at the last "
        "tracked value, or measured less surely where the reason says so; keep the quality column beside w: "
        "hybrid fit and hybrid diagnose leave those samples out of their fits and scores"
    )


def _inverted(image: np.ndarray) -> np.ndarray:
    """The picture in negative: a strip brighter than its background becomes a dark one."""
    top = np.iinfo(image.dtype).max if np.issubdtype(image.dtype, np.integer) else float(np.max(image))
    return top - image


def _find_axis(job: TrackJob, window) -> tuple[AxisEstimate, bool]:
    """The axis estimate from a window of frames (every other one), and whether the strip is brighter
    than its background (then tracked in negative): the tracker follows a dark strip, and where none
    is found the negative is tried."""
    images = [frame.image for frame in window[::2]]
    estimate = find_axis(images, job.clamp, job.mm_per_px, job.length_mm, job.strip_px)
    if estimate.angle_deg is None and images:
        negative = find_axis(
            [_inverted(i) for i in images], job.clamp, job.mm_per_px, job.length_mm, job.strip_px
        )
        if negative.angle_deg is not None:
            return negative, True
    return estimate, False


def _find_or_check_axis(
    job: TrackJob, video: VideoSource, head: list, said: list[str]
) -> tuple[AxisEstimate, float | None, tuple[float, float], bool]:
    """The axis estimate, the axis (None: no strip) and clamp point to track with, and whether the strip
    is tracked in negative; a warning about a given axis is added to `said`.

    The axis comes from the first `HEAD_FRAMES` frames (`head`, read here); where
    no strip is found in them (something passing over it at the start), from the
    next ones, up to `HEAD_WINDOWS` windows, every frame read kept in `head`.
    Without --axis, the detected rest line: its angle, and the clamp point
    moved across it onto the strip. With --axis, the given axis and clamp
    point, and a warning when the strip leaves the clamp elsewhere.
    """
    estimate, bright, start = None, False, 0
    for window in range(HEAD_WINDOWS):
        start = len(head)
        while len(head) < start + HEAD_FRAMES and (frame := video.read()) is not None:
            head.append(frame)
        if len(head) == start:
            break
        if window == 0:
            _check_scene(job, head[0].image)
        estimate, bright = _find_axis(job, head[start:])
        if estimate.angle_deg is not None:
            break
    if estimate is None:
        raise RigError(f"no frame could be read from {job.video}: check that it is a video")
    if bright:
        print("the strip is brighter than its background: tracked in negative")
    if start and estimate.angle_deg is not None:
        print(
            f"no strip in the first {start} frames (covered?): the axis comes from frames {start}-{len(head) - 1}"
        )
    axis, clamp = _axis_and_clamp(job, estimate, said)
    return estimate, axis, clamp, bright


def _axis_and_clamp(
    job: TrackJob, estimate: AxisEstimate, said: list[str]
) -> tuple[float | None, tuple[float, float]]:
    """The axis and the clamp point to track from; a given axis the strip does not leave along is warned of
    at once and added to `said` (the sidecar's ``warnings``: a script reading the sidecar alone sees it too)."""
    if job.axis_deg is None:
        print(f"rest axis: {estimate.describe()}")
        return estimate.angle_deg, estimate.clamp_xy or (job.clamp[0], job.clamp[1])
    if estimate.angle_deg is not None:
        off = abs((estimate.angle_deg - job.axis_deg + 180.0) % 360.0 - 180.0)
        if off > AXIS_WARN_DEG:
            tip = (
                f": about {(job.length_mm or 22.0) * math.sin(math.radians(off)):.2f} mm at the tip"
                if off < 30
                else ""
            )
            said.append(
                f"--axis {job.axis_deg:g} deg given, but the strip leaves the clamp at "
                f"{estimate.angle_deg:.2f} deg ({off:.1f} deg off{tip}); leave --axis out to use the detected axis"
            )
            _warn(said[-1])
        elif abs(estimate.offset_px) > CLAMP_WARN_PX:
            said.append(
                f"the strip leaves the clamp {estimate.offset_px:+.1f} px across the axis from --clamp: w is "
                f"offset by about {estimate.offset_px * job.mm_per_px:+.2f} mm; leave --axis out to measure "
                "from the strip's own rest line"
            )
            _warn(said[-1])
    return job.axis_deg, (job.clamp[0], job.clamp[1])


def _track_rows(
    job: TrackJob,
    video: VideoSource,
    head,
    angle: float | None,
    clamp,
    meta: dict,
    t,
    w,
    quality,
    tips,
    bright: bool = False,
) -> None:
    """Track every frame (the ``head`` already read, then the rest) along ``angle`` (degrees) from
    ``clamp`` (x, y px), appending to the lists t (s), w (mm), quality, and the good frames' tips (x, y px)."""
    tracker = None
    if angle is not None:
        scene = Scene(clamp=tuple(clamp), mm_per_px=job.mm_per_px, angle_deg=angle, length_mm=job.length_mm)
        tracker = TipTracker(scene, strip_px=job.strip_px)
    led = LedDetector(*job.led, fps=video.fps, exposure=job.exposure) if job.led else None
    reasons: dict[str, int] = {}
    last = math.nan
    previous = None
    repeats: list[int] = []
    lengths: list[
        float
    ] = []  # per frame, the tracked strip's length along its centreline (px); NaN where none
    held: list[bool] = []  # per frame, whether its w is the last tracked one's

    def frames():
        yield from head
        while (frame := video.read()) is not None:
            yield frame

    try:
        for frame in frames():
            if _repeats(frame.image, previous):
                # A camera never takes the same picture twice (sensor noise): the frame was repeated
                # (by a driver or a capture program short of frames) and does not show its time.
                ok, value, reason = 0, last, REPEAT_REASON
                repeats.append(len(t))
            elif tracker is not None:
                result = tracker.track(_inverted(frame.image) if bright else frame.image)
                ok, value, reason = result.quality, result.w, result.reason
            else:
                ok, value, reason = 0, math.nan, "no strip along any axis"
            previous = frame.image
            if ok:
                last = value
                tips.append(result.tip_xy)
                lengths.append(result.length_px)
            else:
                reasons[reason] = reasons.get(reason, 0) + 1
                lengths.append(math.nan)
            t.append(frame.t)
            w.append(value if ok or reason == BLURRED else last)  # a blurred tip's w is still measured
            held.append(not ok and reason != BLURRED)
            quality.append(ok)
            if led is not None:
                led.update(frame.index, frame.t, frame.image)
        _runaways(w, quality, lengths, held, tips, reasons)
    except KeyboardInterrupt as error:
        meta["status"] = "interrupted"
        meta["error"] = f"{error or 'interrupted by Ctrl-C (SIGINT)'} before the end of the video"
        raise
    finally:
        meta["untracked_reasons"] = reasons
        meta["repeated_frames"] = repeats
        if led is not None and led.sync is not None:
            meta["sync"] = {
                "method": "led",
                "t": led.sync.t,
                "frame": led.sync.frame,
                "fraction_lit": led.sync.fraction,
            }
        elif led is not None:
            meta["sync"] = {"method": "led", "t": None, "note": "LED edge not seen"}


def _repeats(image: np.ndarray, previous: np.ndarray | None) -> bool:
    """Whether ``image`` is, pixel for pixel, the frame before it."""
    return previous is not None and image.shape == previous.shape and bool(np.array_equal(image, previous))


def _repeat_warning(job: TrackJob, repeats: list[int], t) -> str:
    return (
        f"{len(repeats)} frame{'s' if len(repeats) > 1 else ''} of {job.video} repeat the frame before pixel "
        f"for pixel (first at t = {t[repeats[0]]:.4f} s): copies made for frames the camera did not deliver "
        "(its noise never repeats), and such a camera may also have dropped frames without a trace, so t may "
        "be off after them; they have quality 0"
    )


def _account(video: VideoSource, t, quality) -> dict:
    """Gaps, missing and unplaced frames: flags ``quality`` around gaps in place; returns the account."""
    info = video.integrity()
    gaps = find_gaps(t, video.fps)
    for gap in gaps:
        for k in (gap["after"], gap["after"] + 1):
            quality[k] = 0
    in_gaps = sum(g["missing"] for g in gaps)
    expected = info["frames_expected"]
    read = len(t)
    missing = max(0, expected - read) if expected is not None else None
    info.update(
        gaps=gaps,
        frames_missing=missing,
        frames_missing_in_gaps=in_gaps,
        frames_missing_at_end=None if missing is None else max(0, missing - in_gaps),
    )
    unplaced = info.get("unplaced_frames", 0)
    if unplaced:
        first = info["first_unplaced_frame"]
        for k in range(first, read):
            quality[k] = 0
    info["complete"] = (
        bool(missing == 0 and not unplaced) if expected is not None else not gaps and not unplaced
    )
    return info


def _write(job: TrackJob, t, w, quality, meta: dict, failed: bool = False) -> pathlib.Path:
    """The CSV and its sidecar, staged together (both or neither); returns the CSV's path.

    At ``job.out`` when the run succeeded; when it `failed`, at
    `partial_path` (``w.partial.csv``), so a file the user had at ``job.out``
    is never replaced by a failed run.
    """
    out = partial_path(job.out) if failed else pathlib.Path(job.out)
    if failed:
        meta["partial_of"] = str(job.out)
    rows = [f"{a:.17g},{b:.17g},{int(c)}" for a, b, c in zip(t, w, quality)]
    meta["rows"] = len(rows)
    meta["tracked_frames"] = int(np.sum(quality))
    write_together(
        {
            out: "t,w,quality\n" + "".join(r + "\n" for r in rows),
            out.with_name(out.name + ".json"): json.dumps(meta, indent=2, default=jsonable) + "\n",
        }
    )
    return out


def _kept(job: TrackJob, written: pathlib.Path, existed: bool) -> str:
    return f"what was read is kept in {written} (+ .json); {job.out} was " + (
        "left as it was" if existed else "not written"
    )


def _gap_warning(job: TrackJob, gaps) -> str:
    total = sum(g["missing"] for g in gaps)
    if len(gaps) == 1:
        where = f"{total} frames lost after t = {gaps[0]['t_before']:.4f} s"
    else:
        where = f"{total} frames lost: " + "; ".join(
            f"{g['missing']} after t = {g['t_before']:.4f} s" for g in gaps[:5]
        )
        where += f" and {len(gaps) - 5} more gaps" if len(gaps) > 5 else ""
    return (
        f"{job.video} has {len(gaps)} gap{'s' if len(gaps) > 1 else ''} ({where}); t keeps every frame's "
        "own time and the frames either side of a gap have quality 0"
    )


def track_video(job: TrackJob) -> dict:
    """Run ``rig track``: write ``job.out`` and its sidecar; return the sidecar's metadata.

    Raises `RigError` (after writing what was read) when no strip was
    found, when frames are missing at the end of the file, or when frames'
    places in time are unknown.
    """
    check_outputs([job.out, job.sidecar], [job.video])
    check_csv_out(job.out, "rig track")
    existed = pathlib.Path(job.out).exists()
    meta: dict[str, Any] = {
        "source": "rig track",
        "video": str(job.video),
        "columns": ["t", "w", "quality"],
        "units": {"t": "s", "w": "mm"},
        "complete": False,
        "status": "tracking",
        "error": None,
    }
    with VideoSource(job.video) as video:
        head: list[Frame] = []
        said: list[str] = []  # the warnings, said as they come and kept in the sidecar
        estimate, angle, clamp, bright = _find_or_check_axis(job, video, head, said)
        meta["axis"] = {
            "angle_deg": angle,
            "given": job.axis_deg is not None,
            "detection": estimate.metadata(),
        }
        meta["scene"] = {
            "clamp": list(clamp),
            "clamp_given": list(job.clamp),
            "mm_per_px": job.mm_per_px,
            "angle_deg": angle,
            "length_mm": job.length_mm,
            "strip_px": job.strip_px,
            "strip_brighter": bright,
        }
        t: list[float] = []
        w: list[float] = []
        quality: list[int] = []
        tips: list[tuple[float, float]] = []
        try:
            _track_rows(job, video, head, angle, clamp, meta, t, w, quality, tips, bright)
        except KeyboardInterrupt:
            meta["video_integrity"] = video.integrity()
            written = _write(job, t, w, quality, meta, failed=True)
            _warn(f"interrupted: {_kept(job, written, existed)}")
            raise
        account = _account(video, t, quality)
    meta["video_integrity"] = account
    meta["complete"] = account["complete"]
    # what is said once the file is written, kept in the sidecar with what was said before
    maybe = [
        _length_warning(job, tips, clamp),
        _untracked_warning(meta["untracked_reasons"], len(t)),
        _gap_warning(job, account["gaps"]) if account["gaps"] else None,
        _repeat_warning(job, meta["repeated_frames"], t) if meta["repeated_frames"] else None,
        (
            f"{account['timestamp_faults']} frames of {job.video} had no increasing decoder timestamp: "
            "they were stamped one frame period after the previous frame"
        )
        if account["timestamp_faults"]
        else None,
    ]
    later = [message for message in maybe if message is not None]
    if said or later:
        meta["warnings"] = said + later
    good = int(np.sum(quality))
    problems = []
    if angle is None:
        problems.append(
            f"no strip leaves the clamp at {job.clamp[0]:g},{job.clamp[1]:g} in any direction "
            f"({estimate.reason}; neither a dark nor a bright strip): check --clamp, --mm-per-px, --length, --strip-px"
        )
    elif good == 0:
        problems.append(
            f"the strip was not found along the axis {angle:g} deg in any frame of {job.video}: "
            "check --clamp, --mm-per-px, --axis, --length"
        )
    missing_end, unplaced = account.get("frames_missing_at_end"), account.get("unplaced_frames", 0)
    if missing_end or unplaced:
        expected = account["frames_expected"]
        problems.append(
            f"read {len(t)} of {expected} frames of {job.video} (the file is truncated or damaged"
            + (
                f"; the places in time of the last {unplaced} are unknown, flagged quality 0"
                if unplaced
                else ""
            )
            + "): only those were tracked, marked incomplete"
        )
    meta["status"] = (
        "no strip"
        if angle is None or good == 0
        else "incomplete"
        if missing_end or unplaced
        else "gaps"
        if account["gaps"]
        else "complete"
    )
    meta["error"] = "; ".join(problems) or None
    if problems:
        try:
            written = _write(job, t, w, quality, meta, failed=True)
        except InputError as error:  # a full disk: the tracking problem, and why nothing was kept
            raise RigError(
                "; ".join(problems) + f"; what was read could not be kept either: {error}"
            ) from None
        raise RigError("; ".join(problems) + f"; {_kept(job, written, existed)}")
    _write(job, t, w, quality, meta)
    sync = meta.get("sync")
    print(
        f"wrote {job.out}: {len(t)} frames at {account['fps']:g} fps, {int(np.sum(quality))} tracked"
        + (
            f", sync LED edge at t = {sync['t']:.4f} s (frame {sync['frame']})"
            if sync and sync.get("t") is not None
            else (", sync LED not seen" if sync else "")
        )
    )
    for message in later:
        _warn(message)
    return meta
