"""One experiment end to end: drive -> board -> camera -> tracking -> a synchronised recording.

The board streams the drive from a thread; the main thread reads frames, tracks
the tip, watches the sync LED and writes rows as soon as each row's drive
voltage is known (the board's reports cover its time). Rows are flushed one by
one and the JSON sidecar is rewritten every second, so a crash or a pulled
cable loses at most about a second, and what is on disk is a valid recording
flagged ``"complete": false`` with the error.

The rows stream into ``rec.partial.csv`` (``rec.partial-2.csv``, ... if taken:
`hybrid.util._atomic.partial_path`), never into ``--out``: only a recording that
succeeded (complete, valid, its sidecar written) is renamed onto ``rec.csv``,
CSV and sidecar together (`rig._files.rename_together`). A failure, Ctrl-C or a
full disk leaves the rows in the partial file (its sidecar says ``partial_of``)
and the user's ``rec.csv`` byte for byte; the error names both.

Columns: ``t`` (s from sample 0 on the LED edge; uniform, ``slot / fps``),
``v_in`` (V, the voltage the board had on the DAC at the start of the frame's
exposure, through the calibration), ``w`` (mm, tracked), then ``quality``
(1 good, 0 dropped/untracked: w interpolated or held), ``t_camera`` (the
camera's own timestamp, s), ``sample`` (the drive sample on the DAC, -1 before
sample 0) and, for the virtual rig, ``w_true`` (mm, the virtual strip's
exposure-averaged displacement).
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import pathlib
import threading
import time

import numpy as np

from hybrid import InputError, Recording
from hybrid.util import stage

from ._board import Board
from ._calibration import Calibration
from ._errors import RigError
from ._files import partial_path, rename_together, write_json_atomic
from ._playback import PlayReport
from ._scene import Scene, check_in_picture
from ._sync import LedDetector
from ._tracker import TipTracker

__all__ = ["RecordSettings", "record"]


@dataclasses.dataclass(frozen=True)
class RecordSettings:
    """How to run one experiment.

    Arguments:
        calibration: volts <-> DAC codes.
        scene: the camera view (clamp, scale, axis).
        led: (x, y, radius) px of the sync LED in the picture, or None (then the
            host clock aligns camera and board, to about a frame).
        exposure: camera exposure, s (None: a whole frame).
        pre_roll: seconds of frames before START (the LED's off level).
        sync_s: how long the LED stays on from sample 0, s.
        dac_address: MCP4725 I2C address.
        strip_px: visible strip thickness, px, for the tracker.
    """

    calibration: Calibration = Calibration()
    scene: Scene = Scene()
    led: tuple[float, float, float] | None = None
    exposure: float | None = None
    pre_roll: float = 0.5
    sync_s: float = 0.5
    dac_address: int = 0x60
    strip_px: float = 4.0


class _Writer:
    """CSV rows flushed as written, plus a JSON sidecar rewritten atomically (`hybrid`'s staged writes).

    Any `OSError` (a full disk) becomes one `RigError` naming the file. When
    the header or the first sidecar cannot be written, nothing is left behind.
    """

    def __init__(self, path: pathlib.Path, columns: list[str], metadata: dict):
        self.path = path
        self.sidecar = path.with_name(path.name + ".json")
        self.metadata = metadata
        self.rows = 0
        self.discarded = False
        self._saved = 0.0
        handle = None
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            self.handle = handle = open(path, "x", newline="")
            handle.write(",".join(columns) + "\n")
            handle.flush()
            self.save_metadata(force=True)
        except (OSError, InputError) as error:
            if handle is not None:
                with contextlib.suppress(OSError):
                    handle.close()
                for made in (path, self.sidecar):
                    with contextlib.suppress(OSError):
                        made.unlink()
            if isinstance(error, InputError):
                raise RigError(f"{error}; nothing was recorded") from None
            raise RigError(
                f"cannot write recording '{path}' ({error.strerror or error}); nothing was recorded"
            ) from None

    def row(self, values) -> None:
        try:
            self.handle.write(",".join(f"{float(v):.17g}" for v in values) + "\n")
            self.handle.flush()
        except OSError as error:
            raise RigError(
                f"cannot write {self.path}: {error.strerror or error} (after {self.rows} rows)"
            ) from None
        self.rows += 1
        self.save_metadata()

    def save_metadata(self, force: bool = False) -> None:
        """Rewrite the sidecar (at most once a second unless `force`); a failure is one `InputError` line."""
        now = time.monotonic()
        if not force and now - self._saved < 1.0:
            return
        self._saved = now
        self.metadata["rows"] = self.rows
        write_json_atomic(self.sidecar, self.metadata)

    def discard(self) -> None:
        """Remove the (closed) files: nothing was recorded in them, they keep nothing of the user's."""
        for made in (self.path, self.sidecar):
            with contextlib.suppress(OSError):
                made.unlink()
        self.discarded = True

    def close(self) -> None:
        """Flush the rows, close, cut a row the disk took only part of, count the rows in the file (an
        interruption between writing a row and counting it must not leave a stale count), save the
        sidecar (an `InputError` if it cannot be written: the CSV is closed and valid all the same)."""
        with contextlib.suppress(OSError):  # a full disk: what reached the file is what there is
            self.handle.flush()
        with contextlib.suppress(OSError):
            self.handle.close()
        with self.path.open("rb+") as written:
            size = written.seek(0, os.SEEK_END)
            written.seek(max(0, size - 65536))
            tail = written.read()
            if tail and not tail.endswith(b"\n") and b"\n" in tail:
                written.truncate(size - len(tail) + tail.rfind(b"\n") + 1)
            written.seek(0)
            self.rows = max(0, sum(1 for _ in written) - 1)
        self.save_metadata(force=True)


def _describe(error: BaseException) -> str:
    """The error's message; for Ctrl-C (which has none) what happened."""
    text = str(error)
    if not text and isinstance(error, KeyboardInterrupt):
        return "interrupted by Ctrl-C (SIGINT)"
    return text or type(error).__name__


def _kept(
    out: pathlib.Path,
    writer: _Writer,
    existed: bool,
    unsaved: Exception | None,
    what: str = "what was recorded",
) -> str:
    """Where a failed recording is: ``what was recorded (N rows) is kept in rec.partial.csv ...``."""
    untouched = f"{out} was " + ("left as it was" if existed else "not written")
    if writer.discarded:
        return f"nothing was recorded; {untouched}"
    sidecar = " (+ .json)"
    if unsaved is not None:  # hybrid's "cannot write F: REASON; nothing was changed at F (...)": the reason
        reason = (
            getattr(unsaved, "strerror", None)
            or str(unsaved).split("; nothing was changed")[0].split(": ")[-1]
        )
        sidecar = f" (its sidecar {writer.sidecar.name} could not be updated: {reason})"
    return f"{what} ({writer.rows} rows) is kept in {writer.path}{sidecar}; {untouched}"


def record(
    board: Board,
    camera,
    drive,
    settings: RecordSettings,
    out,
    metadata: dict | None = None,
    truth: dict | None = None,
) -> dict:
    """Run ``drive`` on ``board`` while filming with ``camera``; write the recording to ``out`` (CSV).

    Arguments:
        board: a `Board` that has said hello.
        camera: ``fps``, ``read() -> Frame | None``, ``clock()`` (now on the camera's clock).
        drive: a `hybrid.Drive`.
        settings: `RecordSettings`.
        out: the CSV path (``out.json`` is the metadata sidecar).
        metadata: extra JSON-able metadata.
        truth: for the virtual rig, the camera's ``truth`` dict (frame index -> true w).

    Returns:
        The final metadata. Raises `RigError` (or re-raises Ctrl-C/SIGTERM, with
        ``.kept`` saying where the rows are) after keeping a partial recording in
        ``partial_path(out)``; ``out`` is written only when the recording succeeded.
    """
    cal = settings.calibration
    codes = cal.codes(drive.v)
    clipped = int(np.count_nonzero(cal.clipped(drive.v)))
    fps = float(camera.fps)
    idle = int(cal.codes(0.0))
    sync_samples = max(2, round(settings.sync_s * drive.rate))
    timing = board.configure(
        drive.rate, idle_code=idle, sync_samples=sync_samples, dac_address=settings.dac_address
    )
    period = timing.period
    n = len(codes)
    columns = ["t", "v_in", "w", "quality", "t_camera", "sample"] + (["w_true"] if truth is not None else [])
    meta = {
        "source": f"rig record, {drive.name} drive",
        "units": {"t": "s", "v_in": "V", "w": "mm", "t_camera": "s", "w_true": "mm"},
        "complete": False,
        "status": "recording",
        "error": None,
        "drive": drive.metadata,
        "calibration": cal.to_dict(),
        "clipped_samples": clipped,
        "board": {
            "rate_hz": timing.rate,
            "period_s": period,
            "idle_code": idle,
            "sync_samples": sync_samples,
            "info": dataclasses.asdict(board.info) if board.info else None,
        },
        "camera": {"fps": fps, "exposure_s": settings.exposure},
        "scene": dataclasses.asdict(settings.scene),
        "sync": None,
        "dropped_frames": [],
        "duplicated_frames": 0,
        "untracked_frames": 0,
        "tracked_frames": 0,
        **(metadata or {}),
    }
    out = pathlib.Path(out)
    existed = out.exists()
    partial = partial_path(out)
    meta["partial_of"] = str(out)  # until the recording has succeeded and is renamed onto `out`
    writer = _Writer(partial, columns, meta)
    tracker = TipTracker(settings.scene, strip_px=settings.strip_px)
    led = None
    if settings.led is not None:
        led = LedDetector(*settings.led, fps=fps, exposure=settings.exposure)

    result: dict = {}
    stop = threading.Event()
    started = threading.Event()
    covered = [0.0]  # board time (s after sample 0) up to which the schedule is known
    report_box: list[PlayReport] = []

    def on_progress(report: PlayReport) -> None:
        report_box[:] = [report]
        covered[0] = (report.ticks - 1) * period

    def on_start(host_t: float) -> None:
        result["start_camera_t"] = camera.clock()
        started.set()

    def stream() -> None:
        try:
            result["report"] = board.play(
                codes, on_progress=on_progress, should_stop=stop.is_set, on_start=on_start
            )
        except RigError as error:
            result["error"] = error
            result["report"] = getattr(error, "report", None)
        finally:
            started.set()
            board.stop()

    thread = threading.Thread(target=stream, name="rig-board", daemon=True)
    pending: list[list] = []  # [slot, t_camera, w, quality, w_true]
    last_slot, last_good = None, 0.0
    t_cam0 = None
    sync_t = None
    done_slots = -1
    error: BaseException | None = None
    unsaved: InputError | OSError | None = None

    def schedule():
        rep = result.get("report") or (report_box[0] if report_box else None)
        return rep.sample_ticks(n) * period if rep is not None else np.arange(n) * period

    def flush(final: bool = False) -> None:
        nonlocal done_slots
        if sync_t is None:
            return
        play_times = schedule()
        end_t = play_times[-1] + period
        horizon = math.inf if final else covered[0] - 0.05
        keep = []
        for row in pending:
            slot, t_cam, w, quality, w_true = row
            if slot <= done_slots:
                # written by a flush that Ctrl-C or SIGTERM cut short before it could forget its rows
                continue
            t = t_cam0 + slot / fps - sync_t
            if t < 0:
                continue
            if t >= end_t:
                continue
            if t > horizon:
                keep.append(row)
                continue
            i = int(np.searchsorted(play_times, t + 1e-9, side="right")) - 1
            volts = cal.volts(codes[i]) if i >= 0 else cal.volts(idle)
            values = [t, volts, w, quality, t_cam, i]
            if truth is not None:
                values.append(w_true)
            # Counted as written before it is: an interruption inside `row` (its sidecar rewrite takes
            # milliseconds) must not write it twice, which left a repeated time the file cannot be loaded with;
            # at worst an interrupted recording ends one row short.
            done_slots = slot
            writer.row(values)
        pending[:] = keep

    try:
        # Pre-roll: the LED's off level, before the board starts.
        while True:
            stage("pre-roll: the camera before the drive")  # a Ctrl-C lost at startup ends it here, undriven
            frame = camera.read()
            if frame is None:
                raise RigError("camera stopped delivering frames before the drive started")
            if t_cam0 is None:
                t_cam0 = frame.t
                scene = settings.scene  # before the board plays: with the clamp outside, no frame is tracked
                check_in_picture(
                    scene.clamp, scene.mm_per_px, scene.length_mm, frame.image.shape, "the camera"
                )
            if led is not None:
                led.update(frame.index, frame.t, frame.image)
            if frame.t - t_cam0 >= settings.pre_roll:
                break
        thread.start()
        sync_deadline = None
        while True:
            frame = camera.read()
            if frame is None:
                raise RigError(f"camera stopped delivering frames after {writer.rows} rows")
            # Slots: dropped frames leave gaps, duplicates repeat a slot.
            slot = round((frame.t - t_cam0) * fps)
            stage(f"recording, {slot / fps:.0f} s of about {n / drive.rate:.0f} s")  # what the heartbeat says
            if last_slot is not None and slot <= last_slot:
                meta["duplicated_frames"] += 1
                continue
            result_track = tracker.track(frame.image)
            w_true = truth.get(frame.index, math.nan) if truth is not None else math.nan
            if result_track.quality:
                w = result_track.w
                meta["tracked_frames"] += 1
            else:
                meta["untracked_frames"] += 1
                w = last_good
            if last_slot is not None and slot > last_slot + 1:
                prev_w = pending[-1][2] if pending else last_good
                prev_true = pending[-1][4] if pending else w_true
                for k in range(last_slot + 1, slot):
                    meta["dropped_frames"].append(k)
                    f = (k - last_slot) / (slot - last_slot)
                    pending.append(
                        [
                            k,
                            t_cam0 + k / fps,
                            prev_w + f * (w - prev_w),
                            0,
                            prev_true + f * (w_true - prev_true),
                        ]
                    )
            if result_track.quality:
                last_good = w
            pending.append([slot, frame.t, w, result_track.quality, w_true])
            last_slot = slot
            if led is not None and sync_t is None:
                sync = led.update(frame.index, frame.t, frame.image)
                if sync is not None:
                    sync_t = sync.t
                    meta["sync"] = {
                        "method": "led",
                        "t_camera": sync.t,
                        "frame": sync.frame,
                        "fraction_lit": sync.fraction,
                    }
            if sync_t is None and started.is_set() and "start_camera_t" in result:
                if sync_deadline is None:
                    sync_deadline = result["start_camera_t"] + settings.sync_s + 1.0
                if led is None or frame.t > sync_deadline:
                    sync_t = result["start_camera_t"] + period
                    meta["sync"] = {
                        "method": "host-clock",
                        "t_camera": sync_t,
                        "note": "LED not configured"
                        if led is None
                        else "LED edge not seen: aligned by the START acknowledgement (about one frame)",
                    }
            flush()
            if "error" in result:
                # Keep filming up to where the board's reports reach, then stop: a camera
                # that lags the board (the virtual one does) still delivers those rows.
                if "start_camera_t" not in result:
                    raise result["error"]
                if sync_t is None:
                    if frame.t > result["start_camera_t"] + settings.sync_s + 2.0:
                        raise result["error"]
                elif frame.t - sync_t >= covered[0]:
                    raise result["error"]
            if not thread.is_alive() and "report" in result and sync_t is not None:
                end_t = schedule()[-1] + period
                if t_cam0 + slot / fps - sync_t >= end_t:
                    break
    except BaseException as caught:
        error = caught
    finally:
        stop.set()
        if thread.is_alive():
            thread.join(timeout=5)
        try:
            flush(final=error is None)
        except Exception:  # the partial file must be closed whatever happened
            pass
        report = result.get("report")
        meta["board"]["report"] = report.metadata() if report is not None else None
        if error is None and report is not None and report.complete:
            meta["complete"], meta["status"] = True, "complete"
        else:
            meta["status"] = "interrupted"
            meta["error"] = _describe(error) if error is not None else (report.error if report else "unknown")
        try:
            writer.close()
        except (InputError, OSError) as caught:  # the sidecar: a full disk
            unsaved = caught
        if writer.rows == 0 and unsaved is None:  # stopped before a row (before the drive started)
            writer.discard()
    # Anything but success leaves the rows in `partial` and `out` as it was; the error says so.
    kept = _kept(out, writer, existed, unsaved)
    if error is not None:
        if isinstance(error, InputError):  # RigError, and a sidecar that could not be written
            raise RigError(f"{error}; {kept}") from None
        if isinstance(error, (OSError, ValueError)):
            raise RigError(f"{type(error).__name__}: {error}; {kept}") from None
        # Ctrl-C, SIGTERM: the command line says where the rows are (it reads getattr(error, "kept"))
        error.kept = kept  # type: ignore[attr-defined]  # an attribute added to any exception
        if not isinstance(error, KeyboardInterrupt):
            error.add_note(kept)  # a bug: its traceback, and where the rows are
        raise error
    if unsaved is not None:
        raise RigError(kept)
    if not meta["complete"]:
        raise RigError(f"the board did not play the whole drive ({meta['error']}); {kept}")
    if writer.rows < 2:
        raise RigError(f"the recording has {writer.rows} rows: too short to be valid; {kept}")
    if meta["tracked_frames"] == 0:  # w would be a constant 0: not a recording of the strip
        raise RigError(
            f"no frame showed the strip where the scene says (clamp {settings.scene.clamp[0]:g},"
            f"{settings.scene.clamp[1]:g} px, {settings.scene.mm_per_px:g} mm/px): check --clamp and the "
            f"camera's view; {kept}"
        )
    try:
        Recording.load(writer.path)  # what was written is a valid recording
    except InputError as invalid:
        raise RigError(f"the recording is not valid ({invalid}); {kept}") from None
    del meta["partial_of"]
    try:
        writer.save_metadata(force=True)
    except InputError as caught:
        raise RigError(_kept(out, writer, existed, caught, "the complete recording")) from None
    try:
        rename_together({writer.path: out, writer.sidecar: out.with_name(out.name + ".json")})
    except RigError as failed:  # the recording is whole, but where it was streamed
        raise RigError(f"{failed}; {_kept(out, writer, existed, None, 'the complete recording')}") from None
    return meta
