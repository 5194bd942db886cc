"""The `rig` command line.

    rig ports
    rig track VIDEO --clamp X,Y --mm-per-px S [--axis DEG] [--led X,Y,R] --out F.csv   (no --axis: found)
    rig record (--port P --camera C | --virtual) (--drive KIND --duration S | --drive-file F.csv) --out F.csv
    rig calibrate (--port P | --virtual) [--codes ...] [--readings ...] --out cal.json
    rig simavr-timing [--rate HZ] [--duration S]

Bad input and hardware faults end with exit status 2 and one line on stderr;
every size argument is bounded (the bounds are in ``--help`` and in the
message). SIGTERM is handled like Ctrl-C: a recording is closed, flagged
``interrupted`` with its row count, and the exit status is 143 (130 for Ctrl-C).
`rig record` writes ``--out`` only when it succeeded: a failed or interrupted
recording is kept in ``F.partial.csv`` and the one-line error names it.
"""

from __future__ import annotations

import argparse
import math
import os
import pathlib
import signal
import sys
import threading

from hybrid import InputError
from hybrid.util import Watchdog, reader_may_leave
from hybrid.util.bounds import Parser

from ._errors import Terminated


def _numbers(count_min: int, count_max: int, what: str):
    """An argparse ``type``: ``count_min`` to ``count_max`` comma-separated finite numbers (`what`: the form)."""
    count = (
        f"{count_min}"
        if count_min == count_max
        else f"{count_min} or {count_max}"
        if count_max == count_min + 1
        else f"{count_min} to {count_max}"
    )

    def parse(text: str) -> tuple[float, ...]:
        # argparse.ArgumentTypeError: argparse turns any other ValueError into "invalid parse value"
        try:
            values = tuple(float(x) for x in text.split(","))
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected {what}: comma-separated numbers, got {text!r}"
            ) from None
        if not count_min <= len(values) <= count_max or not all(math.isfinite(v) for v in values):
            raise argparse.ArgumentTypeError(f"expected {what}: {count} finite numbers, got {text!r}")
        return values

    return parse


def _bounded(low: float, high: float, unit: str, low_open: bool = True, convert=float):
    """An argparse ``type``: a finite number in ``(low, high]`` (``[low, high]`` if not ``low_open``).

    ``convert`` turns the text into the number (``float``, ``int``, ...); the
    message names the bounds and the unit.
    """

    def parse(text: str):
        try:
            value = convert(text)
        except ValueError:
            value = None
        inside = (
            value is not None
            and math.isfinite(value)
            and value <= high
            and (value > low if low_open else value >= low)
        )
        if not inside:
            raise argparse.ArgumentTypeError(
                f"must be {'a number' if convert is float else 'an integer'} {'>' if low_open else '>='} {low:g} "
                f"and <= {high:g} {unit}, got {text!r}"
            )
        return value

    return parse


# Bounds of the size arguments: physical sense, and what the rig can do.
MM_PER_PX = _bounded(0, 10, "mm per pixel")
AXIS = _bounded(-360, 360, "degrees", low_open=False)
LENGTH = _bounded(0, 1000, "mm")
STRIP_PX = _bounded(0, 100, "px")
EXPOSURE = _bounded(0, 10, "s")
DURATION = _bounded(0, 86400, "s (one day)")
RATE = _bounded(1, 5000, "samples per second (the serial link carries about 10 k/s)", low_open=False)
AMPLITUDE = _bounded(0, 100, "V")
FPS = _bounded(0, 1000, "frames per second")
SPEED = _bounded(0, 100, "board seconds per second")
SEED = _bounded(0, 2**32 - 1, "", low_open=False, convert=int)
DAC_ADDRESS = _bounded(
    0x08, 0x77, "(a 7-bit I2C address, 0x08-0x77)", low_open=False, convert=lambda text: int(text, 0)
)
LED_RADIUS_MAX = 200.0  # px


def _scene_args(p, track: bool = False):
    p.add_argument(
        "--clamp",
        type=_numbers(2, 2, "--clamp X,Y"),
        default=None,
        help="clamp point in the picture, px (required for a real camera or a video; --virtual: default 40,120)",
    )
    p.add_argument(
        "--mm-per-px",
        type=MM_PER_PX,
        default=None,
        help="image scale, mm per pixel, in (0, 10] (required for a real camera or a video; --virtual: default 0.1)",
    )
    if track:
        p.add_argument(
            "--axis",
            type=AXIS,
            default=None,
            help="rest axis angle, degrees (0 = strip points right, 90 = down); "
            "default: found in the video and printed",
        )
    else:
        p.add_argument(
            "--axis",
            type=AXIS,
            default=0.0,
            help="rest axis angle, degrees (0 = strip points right, 90 = down)",
        )
    p.add_argument(
        "--length",
        type=LENGTH,
        default=22.0,
        help="free strip length, mm, in (0, 1000] (default 22; the search reaches 1.4x it, and a tip tracked "
        "well short of it is warned about: a wrong --mm-per-px or --length)",
    )
    p.add_argument(
        "--strip-px",
        type=STRIP_PX,
        default=4.0,
        help="visible strip thickness, px, in (0, 100] (default 4; give it for a strip over about 10 px thick)",
    )
    p.add_argument(
        "--led",
        type=_numbers(2, 3, "--led X,Y[,R]"),
        default=None,
        help=f"sync LED position (and radius, in (0, {LED_RADIUS_MAX:g}]) in the picture, px",
    )


def build_parser() -> argparse.ArgumentParser:
    from hybrid import DRIVES

    parser = Parser(prog="rig", description="IPMC rig: DAC streaming, camera, tip tracking, recordings.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=Parser)

    sub.add_parser("ports", help="list serial ports")

    p = sub.add_parser("track", help="track the strip tip in a video (CSV t,w,quality and a JSON sidecar)")
    p.add_argument("video")
    _scene_args(p, track=True)
    p.add_argument(
        "--exposure", type=EXPOSURE, default=None, help="exposure, s, in (0, 10] (for the LED sub-frame edge)"
    )
    p.add_argument("--out", required=True)

    p = sub.add_parser("record", help="run a drive and film it: a synchronised recording")
    p.add_argument("--port", help="serial port of the board")
    p.add_argument("--camera", help="camera index, /dev/videoN or a video file")
    p.add_argument("--virtual", action="store_true", help="emulated board and virtual camera")
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--drive", choices=DRIVES)
    which.add_argument(
        "--drive-file",
        help="play a drive from a file, CSV t,v_in (e.g. hybrid design's): its rate and length",
    )
    p.add_argument("--duration", type=DURATION, default=None, help="seconds, in (0, 86400] (with --drive)")
    p.add_argument(
        "--rate",
        type=RATE,
        default=None,
        help="drive samples per second, in [1, 5000] (--drive's, default 30; a --drive-file has its own)",
    )
    p.add_argument(
        "--amplitude",
        type=AMPLITUDE,
        default=None,
        help="V, in (0, 100] (--drive's, default 2; not a file's)",
    )
    p.add_argument("--seed", type=SEED, default=0)
    p.add_argument("--calibration", help="JSON from `rig calibrate` (default: gain 1.2, offset -3 V)")
    p.add_argument("--fps", type=FPS, default=30.0, help="frames per second, in (0, 1000]")
    p.add_argument("--exposure", type=EXPOSURE, default=None, help="s, in (0, 10] (virtual default 1/60)")
    p.add_argument("--dac-address", type=DAC_ADDRESS, default=0x60, help="I2C address, 0x08-0x77")
    p.add_argument(
        "--speed", type=SPEED, default=1.0, help="virtual only: board seconds per second, in (0, 100]"
    )
    _scene_args(p)
    p.add_argument("--out", required=True)

    p = sub.add_parser("calibrate", help="measure the amplifier mapping with a multimeter")
    p.add_argument("--port")
    p.add_argument("--virtual", action="store_true", help="emulated board, a virtual multimeter")
    p.add_argument(
        "--codes", type=_numbers(3, 64, "--codes"), default=(0, 512, 1024, 1536, 2048, 2560, 3072, 3584, 4095)
    )
    p.add_argument(
        "--readings",
        type=_numbers(3, 64, "--readings"),
        default=None,
        help="multimeter readings, V, one per code (else asked one by one)",
    )
    p.add_argument("--out", required=True)

    p = sub.add_parser("simavr-timing", help="measure DAC update timing of the real firmware on simavr")
    p.add_argument("--rate", type=RATE, default=30.0, help="samples per second, in [1, 5000]")
    p.add_argument("--duration", type=DURATION, default=10.0, help="s, in (0, 86400]")
    p.add_argument("--speed", type=SPEED, default=4.0, help="simulated seconds per second, in (0, 100]")
    p.add_argument("--build-dir", default=None)
    return parser


def _cmd_ports(args):
    from serial.tools import list_ports

    ports = sorted(list_ports.comports(), key=lambda p: p.device)
    if not ports:
        print("no serial ports found (is the board plugged in?)")
    for port in ports:
        print(f"{port.device}\t{port.description}")


def _led(args, default=None):
    """The --led X,Y[,R] argument as (x, y, r) px (r = 5 if not given), or ``default``."""
    if args.led is None:
        return default
    led = tuple(args.led) if len(args.led) == 3 else (*args.led, 5.0)
    if not 0 < led[2] <= LED_RADIUS_MAX:
        raise InputError(
            f"argument --led: the radius must be > 0 and <= {LED_RADIUS_MAX:g} px, got {led[2]:g}"
        )
    return led


def _scene(args, virtual: bool):
    from ._scene import Scene

    if not virtual and (args.clamp is None or args.mm_per_px is None):
        raise InputError("give the clamp point and the scale: --clamp X,Y --mm-per-px S")
    return Scene(
        clamp=tuple(args.clamp) if args.clamp is not None else (40.0, 120.0),
        mm_per_px=args.mm_per_px if args.mm_per_px is not None else 0.1,
        angle_deg=args.axis if args.axis is not None else 0.0,
        length_mm=args.length,
    )


def _cmd_track(args):
    from hybrid.util import OutputFile, prepare_outputs

    from ._files import check_csv_out, check_outputs
    from ._trackvideo import TrackJob, track_video

    scene = _scene(args, virtual=False)
    check_outputs([args.out, args.out + ".json"], [args.video])
    check_csv_out(args.out, "rig track")
    # --out's folder writable before the video is read, not after it (a probe's read-only folder: the whole
    # video tracked, then refused); a second writer of the same --out is refused while this one runs
    with prepare_outputs([OutputFile(pathlib.Path(args.out), "--out", (".csv",))], [args.video]):
        track_video(
            TrackJob(
                video=args.video,
                out=args.out,
                clamp=scene.clamp,
                mm_per_px=scene.mm_per_px,
                axis_deg=args.axis,
                length_mm=args.length,
                strip_px=args.strip_px,
                led=_led(args),
                exposure=args.exposure,
            )
        )


def _refuse_unplayable(drive, calibration, what: str, fix: str) -> None:
    """One line where the DAC cannot play `drive` at `calibration` (it would hold those samples at a rail)."""
    outside = calibration.clipped(drive.v)
    if outside.any():
        reach = calibration.volts([0, calibration.top])
        low, high = max(calibration.rail_low, reach.min()), min(calibration.rail_high, reach.max())
        raise InputError(
            f"{what}: {int(outside.sum())} of {len(drive)} samples lie outside what the DAC can play at this "
            f"calibration, [{low:.4g}, {high:.4g}] V (first at t = {drive.t[int(outside.argmax())]:g} s): {fix}"
        )


def _drive(args, calibration):
    """--drive's generated drive, or --drive-file's, refused in one line where the DAC cannot play it."""
    import hybrid

    if args.drive_file is None:
        if args.duration is None:
            raise InputError("--drive needs --duration S (a --drive-file brings its own length)")
        amplitude = 2.0 if args.amplitude is None else args.amplitude
        drive = hybrid.make_drive(
            args.drive,
            args.duration,
            rate=30.0 if args.rate is None else args.rate,
            seed=args.seed,
            amplitude=amplitude,
        )
        _refuse_unplayable(
            drive,
            calibration,
            f"--drive {args.drive} --amplitude {amplitude:g}",
            "give a smaller --amplitude",
        )
        return drive
    given = [
        flag for flag, value in (("--duration", args.duration), ("--rate", args.rate)) if value is not None
    ]
    if args.amplitude is not None:
        given.append("--amplitude")
    if given:  # they would be ignored: the file is played as written
        raise InputError(
            f"{', '.join(given)} {'is' if len(given) == 1 else 'are'} for --drive: a --drive-file brings its own "
            "length, rate and levels (resample or scale the file, e.g. hybrid design --rate/--bounds)"
        )
    try:
        drive = hybrid.load_drive(args.drive_file)
    except hybrid.InputError as error:
        raise InputError(f"--drive-file: {error}") from None
    if not 1.0 <= drive.rate <= 5000.0:
        raise InputError(
            f"--drive-file {args.drive_file}: {drive.rate:g} samples per second; the board plays 1-5000"
        )
    _refuse_unplayable(
        drive,
        calibration,
        f"--drive-file {args.drive_file}",
        "scale the drive into that range (hybrid design --bounds)",
    )
    return drive


def _record_settings(args, calibration, scene, led, exposure):
    """`RecordSettings` from the command line's flags (the virtual and the real rig alike)."""
    from ._record import RecordSettings

    return RecordSettings(
        calibration=calibration,
        scene=scene,
        led=led,
        exposure=exposure,
        strip_px=args.strip_px,
        dac_address=args.dac_address,
    )


def _cmd_record(args):
    import hybrid

    from ._board import Board
    from ._calibration import Calibration
    from ._record import record

    if args.virtual == bool(args.port or args.camera):
        raise InputError("give either --virtual or both --port and --camera")
    if not args.virtual and not (args.port and args.camera):
        raise InputError("a real recording needs both --port and --camera")
    from hybrid.util import OutputFile, prepare_outputs

    from ._files import check_csv_out, check_outputs

    sources = [p for p in (args.calibration, args.camera, args.drive_file) if p and os.path.exists(p)]
    check_outputs([args.out, args.out + ".json"], sources)  # `--camera v.avi --out v.avi` is refused
    check_csv_out(args.out, "rig record")  # before the recording, not after minutes of it
    calibration = Calibration.load(args.calibration) if args.calibration else Calibration()
    drive = _drive(args, calibration)
    scene = _scene(args, virtual=args.virtual)
    # a second rig record (or hybrid command) writing the same --out is refused while this one runs
    with prepare_outputs([OutputFile(pathlib.Path(args.out), "--out", (".csv",))], sources):
        if args.virtual:
            import serial

            from ._emulator import EmulatedBoard
            from ._render import Look
            from ._virtual import VirtualCamera

            look = Look()
            exposure = args.exposure if args.exposure is not None else 1 / 60
            settings = _record_settings(args, calibration, scene, _led(args, default=look.led), exposure)
            with EmulatedBoard(speed=args.speed) as emulated:
                board = Board(serial.Serial(emulated.port, 250000, timeout=0.02), name=emulated.port)
                board.hello()
                camera = VirtualCamera(
                    emulated, scene=scene, look=look, fps=args.fps, exposure=exposure, seed=args.seed
                )
                virtual = {"virtual": True, "speed": args.speed}
                try:
                    meta = record(
                        board, camera, drive, settings, args.out, truth=camera.truth, metadata=virtual
                    )
                finally:
                    board.close()
                rises = [t for t, value in emulated.led_log if value == 1]
                if rises and meta.get("sync"):
                    sync_error = meta["sync"]["t_camera"] - (rises[-1] - camera.t0)
                    print(f"sync: LED edge found {sync_error * 1000:+.2f} ms from the board's true edge")
        else:
            from ._camera import VideoSource

            settings = _record_settings(args, calibration, scene, _led(args), args.exposure)
            board = Board.open(args.port)
            try:
                with VideoSource(args.camera, fps=args.fps) as camera:
                    import time

                    t0 = time.monotonic()
                    camera.clock = lambda: time.monotonic() - t0
                    lab = {"port": args.port, "camera": str(args.camera)}
                    meta = record(board, camera, drive, settings, args.out, metadata=lab)
            finally:
                board.close()
    rec = hybrid.Recording.load(args.out)
    report = meta["board"]["report"]
    print(
        f"wrote {args.out}: {len(rec)} samples at {rec.rate:.4g} Hz, w from {rec.w.min():.3f} to "
        f"{rec.w.max():.3f} mm; sync by {meta['sync']['method']}; underrun ticks "
        f"{report['underrun_ticks']}, bad frames {report['bad_frames_board'] + report['bad_frames_host']}, "
        f"dropped frames {len(meta['dropped_frames'])}, untracked frames {meta['untracked_frames']}"
    )
    if "w_true" in rec.extra:
        import numpy as np

        err = rec.w - rec.extra["w_true"]
        good = np.isfinite(err) & (rec.extra["quality"] > 0)
        print(
            f"tracker vs virtual strip: RMS error {np.sqrt(np.mean(err[good] ** 2)):.4f} mm, "
            f"max {np.max(np.abs(err[good])):.4f} mm over {good.sum()} frames"
        )


def _cmd_calibrate(args):
    import numpy as np

    from ._board import Board
    from ._calibration import Calibration, fit_calibration

    if args.virtual == bool(args.port):
        raise InputError("give either --virtual or --port")
    codes = [int(c) for c in args.codes]
    if any(not 0 <= c <= 4095 for c in codes):
        raise InputError("--codes must be DAC codes in 0..4095")
    if args.readings is not None and len(args.readings) != len(codes):
        raise InputError(f"--readings has {len(args.readings)} values for {len(codes)} codes")
    emulated = None
    if args.virtual:
        import serial

        from ._emulator import EmulatedBoard

        emulated = EmulatedBoard(speed=1.0)
        board = Board(serial.Serial(emulated.port, 250000, timeout=0.02), name=emulated.port)
        board.hello()
        # A virtual amplifier a little off its nominal values, and a 3-digit multimeter.
        truth = Calibration(gain=1.17, offset=-2.93, rail_low=-2.9, rail_high=2.8)
    else:
        board = Board.open(args.port)
    readings = []
    try:
        for k, code in enumerate(codes):
            board.hold(code)
            if args.readings is not None:
                value = args.readings[k]
            elif emulated is not None:
                value = round(float(truth.volts(emulated.dac_log[-1][1])), 3)
            else:
                text = input(f"DAC code {code}: multimeter reading at the strip terminals, V? ")
                try:
                    value = float(text)
                except ValueError:
                    raise InputError(f"reading {text!r} is not a number of volts") from None
            readings.append(value)
        board.hold(int(Calibration().codes(0.0)))
    finally:
        board.close()
        if emulated is not None:
            emulated.close()
    calibration, report = fit_calibration(np.array(codes), np.array(readings))
    data = {**calibration.to_dict(), "fit": report}
    from ._files import write_json_atomic

    write_json_atomic(args.out, data)
    print(
        f"wrote {args.out}: gain {calibration.gain:.4f} V/V, offset {calibration.offset:.4f} V, rails "
        f"[{calibration.rail_low:.3f}, {calibration.rail_high:.3f}] V, RMS residual "
        f"{report['rms_residual_v'] * 1000:.1f} mV ({sum(report['clipped'])} readings at a rail)"
    )


def _cmd_simavr_timing(args):
    from ._timing import measure_simavr_timing

    print(
        measure_simavr_timing(
            rate=args.rate, duration=args.duration, speed=args.speed, build_dir=args.build_dir
        )
    )


COMMANDS = {
    "ports": _cmd_ports,
    "track": _cmd_track,
    "record": _cmd_record,
    "calibrate": _cmd_calibrate,
    "simavr-timing": _cmd_simavr_timing,
}


def _on_sigterm(signum, frame):
    """SIGTERM: raise `Terminated` in the main thread (the clean-up of Ctrl-C runs); once."""
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # a second SIGTERM must not cut the clean-up short
    raise Terminated()


def main(argv=None) -> int:
    # FFmpeg's own lines ("moov atom not found", "header damaged") would come before rig's one-line
    # error, and beside its account of a damaged file's gaps; read once, when OpenCV first opens a
    # video, so set here (a user's own setting is kept).
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
    previous = None
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        args = build_parser().parse_args(argv)
        # A heartbeat on stderr while it works (a drive file at 1 Hz records for many minutes). No stall
        # check: a real board's recording waits on its frames with the CPU idle.
        with Watchdog(f"rig {args.command}", stall=0), reader_may_leave():
            COMMANDS[args.command](args)
    except InputError as error:
        print(f"rig: error: {error}", file=sys.stderr)
        return 2
    except (OSError, ValueError) as error:
        print(f"rig: error: {type(error).__name__}: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as error:
        kept = (
            getattr(error, "kept", None) or "what was recorded so far is kept"
        )  # `rig record` names the file
        if isinstance(error, Terminated):
            print(f"rig: terminated by SIGTERM ({kept})", file=sys.stderr)
            return 143
        print(f"rig: interrupted ({kept})", file=sys.stderr)
        return 130
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    return 0


if __name__ == "__main__":
    sys.exit(main())
