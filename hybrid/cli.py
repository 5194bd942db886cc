"""The `hybrid` command line.

    hybrid simulate (--drive prbs|sine|chirp|pulse --duration S | --drive-file DRIVE.csv) --out F.csv
    hybrid rc DRIVE.csv [--param NAME=VALUE ...] [--method tustin|zoh] --out F.csv
    hybrid fit RECORDING... --model hybrid|normal|physics [--physics SPEC] [--settle N] [--blocks N] [--out MODEL] [--test FILE...]
    hybrid table2 [--duration S] [--out-dir DIR]
    hybrid sensitivity --out DIR [RECORDING] [--physics SPEC] [--drive D] [--param NAME=VALUE ...] [--sobol N]
    hybrid diagnose RECORDING... --out DIR [--physics SPEC] [--effects SPEC,...] [--settle N | --no-auto-settle] [--hybrid] [--max-steps N] [--blocks N] [--keep-glitches] [--no-refine] [--quiet]
    hybrid design DIAG_DIR --duration S (--amplitude V | --bounds LO:HI) [--rate HZ] [--slew PER_S]
                  [--output-bounds LO:HI] [--min-hold S] --out DRIVE.csv

fit, diagnose and sensitivity take --physics rc|lti:N|file.py:Class|module:Class and read a lab's own
columns with --input/--output (or --columns), --rate, --range and --units.
Bad input of any kind ends with exit status 2 and one line on stderr.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import math
import os
import signal
import sys
import threading
import time
import traceback
from pathlib import Path

from ._cli_design import add_design, cmd_design
from ._cli_inputs import (
    add_mapping,
    add_physics,
    add_settle,
    effects_from_spec,
    load_recordings,
    long_record_note,
    parse_params,
    with_settle,
)
from ._cli_outputs import check_outputs, out_file, out_folder
from ._cli_sensitivity import add_sensitivity, cmd_sensitivity
from ._cli_stop import FitStop, partial_path
from ._cli_test import add_test_options, load_tests, print_scores, score_tests
from .util._cores import use_compilation_cache, use_cpu_cores, use_quick_compiles
from .util._errors import InputError
from .util._stdout import reader_may_leave
from .util._watchdog import Watchdog, stage
from .util.bounds import Parser


def _float_list(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(x) for x in text.split(","))
    except ValueError:
        raise InputError(f"expected comma-separated numbers like 0.3,0.5,0.2, got {text!r}") from None


def build_parser() -> argparse.ArgumentParser:
    from .core._fit import SOLVERS
    from .core._models import MODEL_KINDS
    from .data._drives import DRIVES
    from .util import bounds as B

    parser = Parser(prog="hybrid", description="Hybrid physics-ML identification of IPMC actuators.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=Parser)

    p = sub.add_parser("simulate", help="record the virtual IPMC under a drive (CSV t,v_in,w,w_true)")
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--drive", choices=DRIVES)
    which.add_argument(
        "--drive-file", help="a drive from a file, CSV t,v_in (e.g. hybrid design's); its rate and length"
    )
    p.add_argument(
        "--duration",
        type=B.number(*B.DURATION, include_low=False, unit="s"),
        default=None,
        help="seconds (with --drive)",
    )
    p.add_argument(
        "--rate",
        type=B.number(*B.RATE, unit="Hz"),
        default=None,
        help="samples per second (camera fps) of a --drive (default 30; a --drive-file brings its own)",
    )
    p.add_argument(
        "--amplitude",
        type=float,
        default=None,
        help="amplitude of a --drive, V (default 2; not for --drive-file)",
    )
    p.add_argument("--seed", type=int, default=0, help="seeds the drive (PRBS) and the noise")
    p.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="virtual IPMC parameter, NAME=VALUE (the fields of hybrid.ipmc.VirtualIPMCParameters; docs/virtual-ipmc.md)",
    )
    p.add_argument("--out", required=True, help="output .csv, .npz or .mat")

    p = sub.add_parser("rc", help="the RC network's tip voltage V_o for a drive (CSV t,v_in,v_o)")
    p.add_argument("drive", help="CSV with columns t,v_in (other columns ignored)")
    p.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="xi_rho, xi_h, alpha_E, alpha_I, alpha_C, C_clamp (F)",
    )
    p.add_argument("--stages", type=B.integer(*B.STAGES), default=45, help="N (the network has N+1 sections)")
    p.add_argument("--method", choices=("tustin", "zoh"), default="tustin")
    p.add_argument("--out", required=True)

    p = sub.add_parser("fit", help="fit a model to recordings, print metrics, save it")
    p.add_argument(
        "recordings", nargs="+", help=".csv/.npz/.mat recordings of one system (one strip, one rig)"
    )
    p.add_argument(
        "--model",
        choices=MODEL_KINDS,
        default="hybrid",
        help="hybrid (default: the simulation with the paper's D-MLP on its output, which can fit what the "
        "physics misses), physics (the simulation and a gain and offset alone: what --effects extends and a "
        "benchmark scores) or normal (the D-MLP alone)",
    )
    p.add_argument("--solver", choices=SOLVERS, default="lm")
    p.add_argument("--starts", type=B.integer(*B.STARTS), default=1)
    p.add_argument(
        "--screen",
        type=B.integer(*B.SCREEN),
        default=0,
        metavar="N",
        help="start from the best --starts of N points (e.g. 512) screened over the physics' typical "
        "ranges, one simulation each, not from its default or --param values (default 0: from them)",
    )
    p.add_argument(
        "--max-steps",
        type=B.integer(0, B.MAX_STEPS[1]),
        default=200,
        help="most LM steps per start (default 200); 0 with --start-from and --test scores the saved "
        "model on the test records as it is, nothing fitted or written but --json",
    )
    p.add_argument(
        "--freeze",
        action="append",
        default=[],
        metavar="NAME",
        help="keep a parameter fixed (repeatable; 'network' freezes the D-MLP); "
        "xi_h is frozen by default (only xi_rho/xi_h is identifiable)",
    )
    p.add_argument(
        "--free",
        action="append",
        default=[],
        metavar="NAME",
        help="free a parameter frozen by default (e.g. xi_h)",
    )
    p.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="starting value of a physical parameter",
    )
    p.add_argument(
        "--effects",
        default=None,
        metavar="SPEC[,SPEC...]",
        help="extend the physics by these effects, all fitted (built-in names, path/to/file.py:Class or "
        "package.module:Class, comma-separated; e.g. the causes hybrid diagnose named); each starts at its "
        "first start on the first recording (a saturation's knee, a line at the strongest line the physics "
        "leaves), not at a default LM cannot leave",
    )
    p.add_argument(
        "--start-from",
        default=None,
        metavar="MODEL.eqx",
        help="start from a saved model (its simulation, effects, readout and values), e.g. the "
        "extended.eqx that hybrid diagnose --out wrote; give --physics (and --effects) too when it "
        "uses a plug-in, so that its module is imported",
    )
    p.add_argument("--window", type=B.integer(*B.WINDOW), default=60)
    p.add_argument("--depth", type=B.integer(*B.DEPTH), default=11)
    p.add_argument("--width", type=B.integer(*B.WIDTH), default=10)
    p.add_argument(
        "--split",
        type=_float_list,
        default=(0.3, 0.5, 0.2),
        help="train,test,validation fractions of the fitted recordings (default 0.3,0.5,0.2; "
        "also with --test)",
    )
    p.add_argument(
        "--blocks",
        type=B.integer(*B.BLOCKS),
        default=None,
        help="cut each recording into N equal blocks and split each by --split, so that every part "
        "spans the recording (default 1: the paper's contiguous split; 3, as hybrid diagnose, where the "
        "model holds an effect of time such as baseline_drift, which one block would make extrapolate)",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=None, help="save the model here (default: <first recording>.<model>.eqx)")
    p.add_argument("--json", default=None, help="write the fit report (metrics, parameters) as JSON")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument(
        "--time-limit",
        type=B.number(*B.DURATION, include_low=False, unit="s"),
        default=None,
        metavar="SECONDS",
        help="stop fitting after SECONDS (checked between LM steps) and save the best model so far "
        "to <out stem>.partial.eqx, exit status 124 (SIGINT/SIGTERM: the same, 130/143)",
    )
    add_physics(p)
    add_settle(p, B)
    add_mapping(p, B)
    add_test_options(p)

    p = sub.add_parser("table2", help="reproduce the paper's Table 2 on the virtual IPMC")
    p.add_argument(
        "--duration",
        type=B.number(*B.DURATION, include_low=False, unit="s"),
        default=None,
        help="seconds per recording",
    )
    p.add_argument("--starts", type=B.integer(*B.STARTS), default=None)
    p.add_argument("--max-steps", type=B.integer(*B.MAX_STEPS), default=None)
    p.add_argument("--out-dir", default="experiments/results")
    p.add_argument("--quiet", action="store_true")

    add_sensitivity(sub, B)
    add_design(sub, B)

    p = sub.add_parser(
        "diagnose", help="which physical effect the simulation misses (report.md, report.json, PNGs)"
    )
    p.add_argument(
        "recordings",
        nargs="+",
        help=".csv/.npz/.mat recordings of one system (one strip, one rig), fitted jointly",
    )
    p.add_argument("--out", required=True, help="output directory (report.md, report.json, figures)")
    p.add_argument(
        "--hybrid",
        action="store_true",
        help="also fit the hybrid model (simulation + D-MLP) with and without the named effect",
    )
    p.add_argument(
        "--max-steps",
        type=B.integer(None, B.MAX_STEPS[1]),
        default=None,
        help="Levenberg-Marquardt steps per stage (default: DiagnoseSettings.max_steps)",
    )
    p.add_argument(
        "--blocks",
        type=B.integer(None, B.BLOCKS[1]),
        default=None,
        help="cut each recording into N blocks, each split train/validation/held-out, N as given "
        "(default: DiagnoseSettings.blocks, more where the held-out parts would miss where the output sits "
        "flat at an extreme: DiagnoseSettings.held_out_limits; 1: one held-out tail)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress messages")
    p.add_argument(
        "--keep-glitches",
        action="store_true",
        help="fit w's glitches as recorded (runs of a few samples that w jumps into and back out of: by "
        "default bridged by straight lines before any fit, as a tracker's lost frames; keep them when the "
        "system flips by itself, a relay or a chattering contact), and the samples a quality column marks 0 "
        "inside the record (rig's tracker held w there): DiagnoseSettings.bridge_glitches",
    )
    p.add_argument(
        "--no-refine",
        action="store_true",
        help="do not diagnose again with a named-only refinement (a clip for a saturation) where the default "
        "set names the saturation and leaves 1.5x the noise floor, or its remainder points at the clip: "
        "DiagnoseSettings.refine",
    )
    p.add_argument(
        "--racing-effects",
        type=B.integer(*B.RACING),
        default=None,
        metavar="N",
        help="after the race's first LM steps only the N leading effects on the drive and the output race on; "
        "the others keep that short fit (report.md: 'fitted only the race's first steps'). 0: every effect "
        "races, slower where many are searched (default: DiagnoseSettings.racing_effects)",
    )
    p.add_argument(
        "--materiality",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="the smallest size that counts as a cause, by the effect's threshold name (e.g. "
        "baseline_percent_of_range=0.5; repeatable; the names are in report.json's settings.materiality): a "
        "lab whose range dwarfs its noise may care about effects smaller than the defaults' share of it",
    )
    p.add_argument(
        "--effects",
        default=None,
        metavar="SPEC[,SPEC...]",
        help="the effects to search (default: every built-in): built-in names, 'builtins', "
        "path/to/file.py:Class or package.module:Class (your AbstractEffect), comma-separated",
    )
    add_physics(p, default="rc:zoh")
    add_settle(p, B)
    p.add_argument(
        "--no-auto-settle",
        action="store_true",
        help="when the model misses the record's start, say so but do not diagnose it again with the "
        "simulation held at a fitted drive first (what --settle does; by default diagnose tries it)",
    )
    add_mapping(p, B)
    _add_verbose(parser, sub)
    return parser


def _cmd_simulate(args):
    import dataclasses

    import numpy as np

    from .data._drive import DEFAULT_RATE
    from .data._drives import load_drive, make_drive
    from .data._loaders import SUFFIXES
    from .ipmc._virtual_ipmc import virtual_recording
    from .ipmc._virtual_parameters import VirtualIPMCParameters
    from .util.bounds import check_samples

    if args.drive_file is None and args.duration is None:
        raise InputError("--drive needs --duration S (a --drive-file brings its own length)")
    for flag, value in (
        ("--duration", args.duration),
        ("--rate", args.rate),
        ("--amplitude", args.amplitude),
    ):
        if args.drive_file is not None and value is not None:
            raise InputError(
                f"{flag} is for --drive: a --drive-file brings its own length, rate and levels "
                "(scale or resample the file itself)"
            )
    if args.drive_file is None:
        args.rate = DEFAULT_RATE if args.rate is None else args.rate
        args.amplitude = 2.0 if args.amplitude is None else args.amplitude
    if args.duration is not None:
        check_samples(args.duration, args.rate)
    lock = check_outputs(
        [out_file(args.out, suffixes=SUFFIXES)], inputs=[args.drive_file] if args.drive_file else ()
    )
    overrides = parse_params(args.param)
    known = {f.name for f in dataclasses.fields(VirtualIPMCParameters)}
    unknown = set(overrides) - known
    if unknown:
        raise InputError(
            f"unknown virtual IPMC parameter(s) {sorted(unknown)}: valid names are {sorted(known)}"
        )
    params = VirtualIPMCParameters(**overrides)
    if args.drive_file is not None:
        drive = load_drive(args.drive_file)
        # the virtual DAC would clip them at its rails, silently: refused, as rig record does
        outside = np.abs(drive.v) > params.full_scale_v
        if outside.any():
            raise InputError(
                f"--drive-file {args.drive_file}: {int(outside.sum())} of {len(drive.v)} samples lie outside "
                f"the virtual DAC's ±{params.full_scale_v:g} V (largest |v_in| {np.max(np.abs(drive.v)):.4g} V): "
                "scale the drive into range, or give --param full_scale_v=V"
            )
    else:
        drive = make_drive(
            args.drive, args.duration, rate=args.rate, seed=args.seed, amplitude=args.amplitude
        )
    with lock:
        recording = virtual_recording(drive, params, seed=args.seed)
        path = recording.save(args.out)
    print(
        f"wrote {path}: {len(recording)} samples at {recording.rate:g} Hz, "
        f"w from {recording.w.min():.3f} to {recording.w.max():.3f} mm"
    )


def _cmd_rc(args):
    import jax.numpy as jnp
    import numpy as np

    from .data._recording import Recording
    from .physics._rc_network import RCNetwork
    from .util._atomic import atomic_open

    lock = check_outputs([out_file(args.out)], inputs=[args.drive])
    # The same reader and checks as fit and diagnose; a drive needs no w.
    drive = Recording.load(args.drive, require_w=False)
    network = RCNetwork(n_stages=args.stages, method=args.method)
    params = parse_params(args.param)
    if params:
        network = network.replace(**params)
    t, v, dt = drive.t, drive.v_in, drive.dt
    with lock:
        v_o = np.asarray(network.simulate(jnp.asarray(v), dt))
        if not np.all(np.isfinite(v_o)):
            raise InputError("the RC network produced non-finite values: check the parameters' magnitudes")
        with atomic_open(args.out, "w", newline="") as handle:
            writer = csv.writer(handle)
            writer.writerow(["t", "v_in", "v_o"])
            for row in zip(t, v, v_o):
                writer.writerow([f"{x:.17g}" for x in row])
    print(
        f"wrote {args.out}: {len(t)} samples, V_o from {v_o.min():.6g} to {v_o.max():.6g} V "
        f"({args.method}, N={args.stages}, dt={dt:g} s)"
    )


def _start_of(model, recordings, simulation) -> dict | None:
    """Whether each recording starts where the fitted model does (`misfit_at_start`), from its free run.

    None for a model with a network: its first window − 1 samples see a held
    history (`hybrid/core/_windows.py`), a start misfit of its own.
    """
    import numpy as np

    if model.readout.window > 1:
        return None

    from .core._held_start import HeldStart
    from .core._problem import unmeasured_of
    from .discovery._start import misfit_at_start

    residuals = [  # no residual where w was not measured (a quality column's 0s)
        np.where(
            unmeasured_of(r),
            np.nan,
            np.asarray(r.w, float) - np.asarray(model.predict(r.v_in, r.dt), float),
        )
        for r in recordings
    ]
    return misfit_at_start(residuals, [r.name for r in recordings], isinstance(simulation, HeldStart))


#: A held start `hybrid fit` tries by itself is pointed at where it fits the held-out splits this many
#: times better (the least of the validation and test NMSE ratios).
HELD_HINT_GAIN = 1.5
#: ... and only where the first drive lies this share of the drive's peak away from 0: below it, a
#: simulation at rest and one settled at the first drive start alike.
HELD_HINT_DRIVE = 0.05


def _fit_as_asked(args, model, recordings, frozen, **more):
    """`hybrid.fit` of `model` with the command line's solver, starts, screen, split, blocks and seed."""
    from .core._fit import fit
    from .core._solvers import solver_named

    return fit(
        model,
        recordings,
        solver=solver_named(args.solver, max_steps=args.max_steps),
        starts=args.starts,
        screen=args.screen,
        frozen=frozen,
        split=args.split,
        blocks=args.blocks,
        seed=args.seed,
        **more,
    )


def _held_start_hint(args, model, recordings, simulation, result, frozen, stop=None) -> str | None:
    """Where a physics model fitted from its own start met a record that started settled by bending: the
    same physics held at a fitted drive first (`held_at_start`), fitted alike, and a sentence if it fits
    the held-out splits `HELD_HINT_GAIN` times better; else None, as where `stop` (a `FitStop`) ended that fit.

    The start check cannot see it: `lti:1` from rest met a thermal record that started settled at its
    first drive by a direct term and τ 3.97 s (truth 20 s; a probe): its start fits, its held-out part
    does not (validation NMSE 4.7e-3, held 3.3e-5 with τ 19.9 s).
    """
    import numpy as np

    from .core._held_start import held_at_start
    from .core._simulation import unit_suffix
    from .discovery._start import settle_samples

    drive = np.asarray(recordings[0].v_in, float)
    peak = float(np.max(np.abs(drive))) if drive.size else 0.0
    if len(recordings) != 1 or peak == 0 or abs(float(np.mean(drive[:10]))) < HELD_HINT_DRIVE * peak:
        return None
    n = settle_samples(len(drive))
    held_model = type(model)(held_at_start(simulation, n, recordings[0]), model.readout, model.kind)
    held = _fit_as_asked(args, held_model, recordings, frozen, progress=False, stop=stop)
    if held.stopped:
        return None
    splits = [k for k in ("validation", "test") if k in result.metrics and k in held.metrics]
    ratios = [
        result.metrics[k]["nmse"] / held.metrics[k]["nmse"] for k in splits if held.metrics[k]["nmse"] > 0
    ]
    if not ratios or min(ratios) < HELD_HINT_GAIN:
        return None
    change = {  # the simulation's own parameters: what bent
        k: abs(held.parameters[k] / result.parameters[k] - 1.0)
        for k in simulation.parameter_names()
        if k in result.parameters and k in held.parameters and result.parameters[k]
    }
    moved = sorted((k for k in change if change[k] > 0.05), key=lambda k: -change[k])[:3]
    values = ", ".join(
        f"{k} {result.parameters[k]:.4g} → {held.parameters[k]:.4g}{unit_suffix(result.units.get(k))}"
        for k in moved
    )
    return (
        f"held at a fitted drive for {n} samples before the record, the same physics fits the held-out "
        f"parts {min(ratios):.3g}× better ({values}): the record most likely started settled, where the "
        f"simulation starts from its own state, and this fit bent its parameters to meet the start; fit "
        f"again with --settle {n} (hybrid.HeldStart in Python)"
    )


#: `hybrid fit` with the hybrid model fits the physics model alone beside it (the simulation with a gain and
#: offset) and says so where that fits both held-out splits (validation and test) this many times better.
PEER_HINT_GAIN = 1.5


def _physics_peer_hint(args, model, recordings, result, frozen, stop) -> dict | None:
    """The hybrid model (the default) against the physics model alone, fitted alike from `model`'s
    simulation: `physics_alone_hint` of the two fits; None where `stop` (a `FitStop`) ended the second fit.

    The D-MLP on the simulation's output (1,721 weights at the paper's shape) is flexible: a second-order
    plant (`lti:2`, 1,500 samples at 30 Hz, 70 % for training; `tests/test_cli.py -k physics_alone`) fitted by
    the default hybrid model scores a validation NMSE of 1.4e-1, the physics model alone 2.0e-3, and nothing
    said which to keep.
    """
    from .core._models import make_model

    peer = make_model("physics", simulation=model.simulation)
    kept = frozenset(frozen) & set(peer.parameter_names)
    alone = _fit_as_asked(args, peer, recordings, kept, progress=False, stop=stop)
    if alone.stopped:
        return None
    return physics_alone_hint(result.metrics, alone.metrics, model.readout.n_weights)


def physics_alone_hint(hybrid_metrics: dict, physics_metrics: dict, weights: int) -> dict | None:
    """A sentence and both models' held-out NMSE where the physics model alone fits every held-out split
    (validation, test) `PEER_HINT_GAIN` times better than the hybrid model; else None."""
    splits = [k for k in ("validation", "test") if k in hybrid_metrics and k in physics_metrics]
    nmse = {k: (hybrid_metrics[k]["nmse"], physics_metrics[k]["nmse"]) for k in splits}
    ratios = [h / a for h, a in nmse.values() if a > 0 and math.isfinite(h) and math.isfinite(a)]
    if not splits or len(ratios) < len(splits) or min(ratios) < PEER_HINT_GAIN:
        return None
    said = ", ".join(f"{k} NMSE {h:.2e} against {a:.2e}" for k, (h, a) in nmse.items())
    return {
        "sentence": (
            f"the physics model alone (the simulation with a gain and offset, fitted alike) fits the held-out "
            f"parts {min(ratios):.3g}× better than this hybrid model ({said}): the network's {weights} "
            "weights fit what the training part alone holds; fit with --model physics, or give the hybrid "
            "model more data"
        ),
        "ratio": min(ratios),
        "nmse": {k: {"hybrid": h, "physics": a} for k, (h, a) in nmse.items()},
    }


def _cmd_fit(args):
    import jax

    from .core._arguments import as_names
    from .core._fit import TIME_EFFECT_BLOCKS, of_time_said, time_effect_names
    from .core._models import make_model
    from .core._serialise import save_model
    from .physics._plugins import resolve_physics
    from .util._atomic import write_text

    if len(args.split) != 3:  # a flag's fault is refused before any reading or compiling
        raise InputError(f"--split needs three fractions train,test,validation, got {len(args.split)}")
    out = args.out or f"{Path(args.recordings[0]).with_suffix('')}.{args.model}.eqx"
    partial = partial_path(out)  # a stopped fit's best model: never over --out
    lock = check_outputs(
        [
            out_file(out, "--out" if args.out else "the default --out", (".eqx",)),
            out_file(partial, "the partial model (--out's .partial.eqx)", (".eqx",)),
            out_file(args.json, "--json", (".json",)) if args.json else None,
        ],
        inputs=args.recordings + (args.test or []),
    )
    if args.screen and (args.start_from is not None or args.model == "normal"):
        raise InputError(
            "--screen chooses the physics' starting values: "
            + (
                "with --start-from they are the saved model's"
                if args.start_from
                else "the normal model has none"
            )
        )
    if args.max_steps == 0 and (args.start_from is None or not args.test):
        raise InputError(
            "--max-steps 0 scores a saved model as it is: give it with --start-from MODEL.eqx and the "
            "records to score with --test FILE (e.g. --initial-samples N, the benchmark's rule)"
        )
    if args.max_steps == 0 and (args.screen or args.starts > 1):
        raise InputError("--max-steps 0 scores the saved model as it is: --screen and --starts choose starts")
    if args.start_from is not None and (args.param or args.settle is not None):
        flag = "--param" if args.param else "--settle"
        raise InputError(f"{flag} sets how the fit starts; with --start-from that comes from the saved model")
    recordings = load_recordings(args, args.recordings)
    if not args.quiet:
        for r in recordings:  # what was read, before minutes of fitting: the rate, the length, the units
            units = r.metadata["units"]
            print(
                f"read '{r.name}': {r.n} samples at {r.rate:.6g} Hz ({r.duration:.6g} s), "
                f"drive in {units['v_in']}, output in {units['w']}"
            )
    simulation = None
    if args.model != "normal":
        simulation = resolve_physics(args.physics, recordings)  # rc: the paper's RC network
        if args.effects is not None:
            from .discovery._effect_stack import EffectStack, at_first_starts
            from .discovery._search import drive_unit

            effects = effects_from_spec(args.effects, simulation)
            simulation = EffectStack(simulation, effects, drive_unit=drive_unit(recordings))
            if args.start_from is None:  # from each effect's first start, not a default LM cannot leave
                simulation = at_first_starts(simulation, recordings[0])
        params = parse_params(args.param)
        if params:
            simulation = simulation.replace(**params)
        simulation = with_settle(simulation, args, recordings)
    elif args.settle is not None:
        raise InputError("--settle holds the physics before the record; the normal model has none")
    elif args.param:
        raise InputError("--param sets physical parameters; the normal model has none")
    elif args.effects is not None:
        raise InputError(
            "--effects extends the physics; the normal model has none (use --model physics or hybrid)"
        )
    if args.start_from is not None:
        model = start_model(args)
        _check_saved_effects(args, model, simulation)
    else:
        model = make_model(
            args.model,
            simulation=simulation,
            window=args.window,
            depth=args.depth,
            width=args.width,
            key=jax.random.key(args.seed),
        )
    frozen = set(args.freeze)
    as_names(
        args.free, "--free", "parameter", model.parameter_names
    )  # an unknown name is refused, not ignored
    frozen |= set(model.simulation.frozen_by_default) - set(args.free)  # the RC network's xi_h
    if args.blocks is None:  # an effect of time fitted in one block extrapolates into every held-out part
        timed = time_effect_names(model, frozen) if args.max_steps != 0 else []  # 0: nothing is fitted
        args.blocks = TIME_EFFECT_BLOCKS if timed else 1
        if timed:
            print(
                f"hybrid: warning: {of_time_said(timed)}: each recording is cut into {TIME_EFFECT_BLOCKS} blocks, "
                "each split by --split, as hybrid diagnose does, so that the held-out parts lie between training "
                "samples, not after them where the effect extrapolates (--blocks 1: one contiguous split)",
                file=sys.stderr,
            )
    tests = load_tests(args, recordings, model.readout.window)  # --test: refused before fitting, not after
    if args.max_steps == 0:  # the saved model scored as it is: no readout re-initialised, no step
        with lock:
            scores = {"test": score_tests(model, tests, args.initial_samples)}
            print(f"scored {args.start_from} as saved (--max-steps 0: nothing fitted, nothing saved)")
            print_scores(scores["test"])
            if args.json:
                write_text(args.json, json.dumps({"model": str(args.start_from), **scores}, indent=2) + "\n")
        return
    with lock:
        began = time.monotonic()
        with FitStop(args.time_limit) as stop:  # SIGINT, SIGTERM, --time-limit: stop between steps
            result = _fit_as_asked(args, model, recordings, frozen, progress=not args.quiet, stop=stop)
        print(result.summary(said={note for r in recordings for note in r.notes}))
        if result.stopped:
            steps = max(s.get("steps", 0) for s in result.starts)
            save_model(
                partial,
                result.model,
                extra={
                    "metrics": result.metrics,
                    "settings": result.settings,
                    "stopped": stop.reason,
                    "steps": steps,
                },
            )
            stop.exit(
                f"fit stopped by {stop.reason} after {steps} steps: saved the best model so far to "
                f"{partial} (+ {partial}.json), {out} untouched"
            )
        start = _start_of(result.model, recordings, simulation)
        if start and start["sentence"]:
            print(f"start: {start['sentence']}")
        scores = {"test": score_tests(result.model, tests, args.initial_samples)} if tests else {}
        print_scores(scores.get("test", []))
        save_model(
            out, result.model, extra={"metrics": result.metrics, "settings": result.settings, **scores}
        )
        print(f"saved model to {out} (+ {out}.json)")
        if (
            start
            and not start["sentence"]
            and args.settle is None
            and args.start_from is None
            and args.effects is None
        ):
            held = _after_saving(
                args,
                out,
                began,
                "fitting the physics held at a drive before the record",
                lambda stop: _held_start_hint(args, model, recordings, simulation, result, frozen, stop),
            )
            if held:
                print(f"start: {held}")
                start = {**start, "held_hint": held}
        peer = None
        if model.kind == "hybrid":
            peer = _after_saving(
                args,
                out,
                began,
                "fitting the physics alone beside the model",
                lambda stop: _physics_peer_hint(args, model, recordings, result, frozen, stop),
            )
            if peer:
                print(f"hybrid: warning: {peer['sentence']}", file=sys.stderr)
        if args.json:
            more = {**({"start": start} if start else {}), **({"physics_alone": peer} if peer else {})}
            write_text(args.json, json.dumps({**result.to_dict(), **scores, **more}, indent=2) + "\n")


def _after_saving(args, out, began: float, doing: str, second_fit):
    """`second_fit(stop)`, a fit `hybrid fit` runs after saving `out`, within what --time-limit leaves of the
    time since `began` (None where nothing is left, said in a warning); SIGINT/SIGTERM during it keep the
    saved model: one line, and its exit status."""
    left = None if args.time_limit is None else args.time_limit - (time.monotonic() - began)
    if left is None or left > 0:
        with FitStop(left) as stop:
            found = second_fit(stop)
        if stop.signal is not None:  # what it would have added is not written
            stop.exit(
                f"stopped by {stop.reason} while {doing}: {out} is saved{', --json not written' if args.json else ''}"
            )
        if not stop.timed_out:
            return found
    when = "before" if left is not None and left <= 0 else "while"  # a deadline: only with --time-limit
    print(
        f"hybrid: warning: --time-limit {args.time_limit:g} s ran out {when} {doing}: not checked",
        file=sys.stderr,
    )
    return None


def _check_saved_effects(args, model, simulation) -> None:
    """With --start-from, --effects imports the plug-ins the saved model uses; an effect it names that the
    saved model lacks is refused (it was dropped without a word: a probe's --effects delay)."""
    if args.effects is None:
        return
    saved = {e.name for e in getattr(model.simulation, "effects", ())}
    named = [e.name for e in getattr(simulation, "effects", ())]
    missing = [n for n in named if n not in saved]
    if missing:
        raise InputError(
            f"--effects {','.join(missing)}: the saved model (--start-from {args.start_from}) has no "
            f"{' or '.join(missing)}; --start-from fits the saved model with the effects it has "
            f"({', '.join(sorted(saved)) or 'none'}): leave --start-from out to build a model with them"
        )


def start_model(args):
    """--start-from: the saved model a fit starts from (the plug-ins named by --physics/--effects imported)."""
    from .core._serialise import load_model

    path = Path(args.start_from)
    if path.suffix != ".eqx" or not path.is_file():
        raise InputError(
            f"--start-from {path}: not a saved model (.eqx) file; give e.g. the extended.eqx that "
            "hybrid diagnose --out wrote"
        )
    return load_model(path)


def _cmd_table2(args):
    from .ipmc._table2 import OUTPUT_FILES, Table2Settings, reproduce_table2
    from .util.bounds import check_samples

    overrides = {
        k: v
        for k, v in (("duration", args.duration), ("starts", args.starts), ("max_steps", args.max_steps))
        if v is not None
    }
    settings = Table2Settings(**overrides)
    check_samples(settings.duration, settings.rate, "--duration × the rate")
    with check_outputs([out_folder(args.out_dir, OUTPUT_FILES, "--out-dir")]):
        reproduce_table2(settings, out_dir=args.out_dir, progress=not args.quiet)


def cause_line(step: dict, n_causes: int, gain: float) -> str:
    """The line `hybrid diagnose` prints for a named cause (report.json's `causes` entry `step`).

    A pair's second is measured over the first alone. One cause alone whose incremental gain differs from
    the headline's `gain` (over the baseline) says what it is over: a probe read 33.75x and 17.04x side by
    side, the second over the best effect-free fit the search found, not over the baseline.
    """
    from .discovery._report import PLACE_WORDS

    with_ = step.get("named_jointly_with")
    over = f"gain over {with_} alone" if with_ else "incremental gain"
    why = (
        ": over the best effect-free fit the search found; the gain above is over the baseline"
        if n_causes == 1 and not with_ and abs(step["incremental_gain"] - gain) > 0.1 * gain
        else ""
    )
    where = PLACE_WORDS.get(step.get("place") or "")
    return f"  {step['name']}{f', {where}' if where else ''} ({over} {step['incremental_gain']:.2f}x{why})"


def _cmd_diagnose(args):
    import dataclasses

    from .discovery._ambiguity import sentence as ambiguity_sentence
    from .discovery._diagnosis import DiagnoseSettings
    from .discovery._report import MODEL_FILES, REMAINDER_FIGURE, plus_minus, write_report
    from .discovery._report_figures import FIGURES
    from .discovery._verdict import too_small_sentence
    from .ipmc._defaults import diagnose
    from .physics._plugins import resolve_physics

    lock = check_outputs(
        [
            out_folder(
                args.out,
                (
                    "report.json",
                    "report.md",
                    *FIGURES,
                    REMAINDER_FIGURE,
                    *MODEL_FILES,
                    *(f"{name}.json" for name in MODEL_FILES),
                ),
            )
        ],
        inputs=args.recordings,
    )
    recordings = load_recordings(args, args.recordings)
    long = long_record_note(recordings)
    if long and not args.quiet:
        print(f"hybrid: note: {long}", file=sys.stderr)
    settings = DiagnoseSettings()
    if args.max_steps is not None:
        if args.max_steps < 1:
            raise InputError(f"--max-steps must be at least 1, got {args.max_steps}")
        settings = dataclasses.replace(settings, max_steps=args.max_steps)
    if args.blocks is not None:  # checked where every split is built (series_from_recording)
        settings = dataclasses.replace(settings, blocks=args.blocks, held_out_limits=False)  # as given
    if args.no_auto_settle:
        settings = dataclasses.replace(settings, settle_when_off=False)
    if args.keep_glitches:
        settings = dataclasses.replace(settings, bridge_glitches=False)
    if args.no_refine:
        settings = dataclasses.replace(settings, refine=False)
    if args.racing_effects is not None:
        settings = dataclasses.replace(settings, racing_effects=args.racing_effects)
    if args.materiality:
        given = parse_params(args.materiality)  # names and sizes are checked where every caller's are
        settings = dataclasses.replace(settings, materiality={**settings.materiality, **given})
    with lock:
        simulation = resolve_physics(args.physics, recordings)
        simulation = with_settle(simulation, args, recordings)
        effects = None if args.effects is None else effects_from_spec(args.effects, simulation)
        diagnosis = diagnose(
            recordings,
            simulation=simulation,
            effects=effects,
            hybrid=args.hybrid,
            settings=settings,
            progress=not args.quiet,
        )
        paths = write_report(diagnosis, args.out)
    report = diagnosis.to_dict()
    base, ext = report["baseline"]["nmse"], report["extended"]["nmse"]
    print(f"cause: {diagnosis.cause}")
    print(f"held-out NMSE: baseline {base:.2e} -> extended {ext:.2e} (gain {diagnosis.gain:.2f}x)")
    print(diagnosis.verdict)
    for step in report["causes"]:
        print(cause_line(step, len(report["causes"]), diagnosis.gain))
        if step.get("reading"):
            print(f"    {step['reading']}")
        if step.get("as_recorded"):  # an output-side level, through the readout: where w levels off
            unit = step.get("as_recorded_unit", "")
            print(
                "    as recorded: "
                + ", ".join(
                    f"{k.replace('_', ' ')} {v:.4g} {unit}".rstrip() for k, v in step["as_recorded"].items()
                )
            )
        for name in diagnosis.effect_parameters(step["name"]):
            if name in report["parameters"]:
                print(f"    {name} = {plus_minus(report['parameters'][name])}")
    for entry in report["ambiguous"]:
        print(f"ambiguous: {ambiguity_sentence(entry)}")
    for entry in report["too_small"]:
        print(f"too small: {too_small_sentence(entry)}")
    start = report["evidence"].get("start") or {}
    if start.get("sentence"):
        print(f"start: {start['sentence']}")
    refined = report["evidence"].get("refined") or {}
    if refined.get("sentence"):
        print(f"refined: {refined['sentence']}")
    floor, left = report["noise_floor"], report["unexplained"]
    print(f"noise floor: sigma = {floor['std']:.3g} {report['units']['w']} ({floor['method']})")
    if left is not None:
        print(
            f"unexplained: {left['fraction_above_floor']:.0%} of the held-out error lies above the noise floor: "
            f"{left['description'].get('summary', '')}"
        )
    for warning in [
        *floor.get("warnings", ()),
        *([left["floor_warning"]] if left and "floor_warning" in left else []),
    ]:
        print(f"noise floor: warning: {warning}")
    said = {note for r in recordings for note in r.notes}  # printed as each recording was read
    for warning in report.get("warnings", ()):
        if warning not in said:
            print(f"warning: {warning}")
    if diagnosis.hybrid is not None:
        h = diagnosis.hybrid
        print(f"hybrid model NMSE: {h['baseline']['nmse']:.2e} -> {h['extended']['nmse']:.2e}")
    figures = len([p for p in paths if p.endswith(".png")])
    print(
        f"wrote {paths['report.md']}, report.json, {figures} figures and the fitted models "
        f"{', '.join(MODEL_FILES)} ({diagnosis.seconds:.1f} s)"
    )


COMMANDS = {
    "simulate": _cmd_simulate,
    "rc": _cmd_rc,
    "fit": _cmd_fit,
    "table2": _cmd_table2,
    "sensitivity": cmd_sensitivity,
    "design": cmd_design,
    "diagnose": _cmd_diagnose,
}


@contextlib.contextmanager
def _sigint_watch(seen: list):
    """Note a real Ctrl-C (SIGINT) in `seen`, so that a KeyboardInterrupt raised by a plug-in's code is told
    apart from one (where a Python SIGINT handler is in place, Python's own or `hybrid_launch`'s, in the
    main thread); the handler in place still runs."""
    previous = signal.getsignal(signal.SIGINT)
    if threading.current_thread() is not threading.main_thread() or not callable(previous):
        yield
        return

    def handler(signum, frame):
        seen.append(signum)
        previous(signum, frame)

    signal.signal(signal.SIGINT, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _add_verbose(parser, sub) -> None:
    """-v/--verbose, before or after the command: an error's traceback after its one line."""
    help_ = "on an error, print the traceback after the one-line message"
    parser.add_argument("-v", "--verbose", action="store_true", help=help_)
    for command in sub.choices.values():
        command.add_argument("-v", "--verbose", action="store_true", default=argparse.SUPPRESS, help=help_)


def _report(error: BaseException, verbose: bool, ctrl_c: bool) -> int:
    """The exit status for an error that ended a command, after one line on stderr (and, with -v, its traceback).

    A failure in a plug-in's code, at load or at run time (an exception, sys.exit, os._exit in the main
    thread, a KeyboardInterrupt that was no Ctrl-C) is one line naming the plug-in and its method, exit
    status 2: never the plug-in's own status, so none can pass for success or for the watchdog's.
    """
    from .physics._plugins import HardExit, describe_failure
    from .util._errors import PluginError

    if isinstance(error, KeyboardInterrupt) and ctrl_c:
        print("hybrid: interrupted", file=sys.stderr)
        return 130
    message = describe_failure(error)
    if message is None and isinstance(error, InputError):
        message = str(error)
    elif message is None and isinstance(
        error, (OSError, ValueError)
    ):  # unreadable files, bad numbers deep in numpy
        message = f"{type(error).__name__}: {error}"
    if message is None:
        if isinstance(error, KeyboardInterrupt):
            print("hybrid: interrupted", file=sys.stderr)
            return 130
        if isinstance(error, HardExit):  # not from a plug-in's code: what was asked
            os._exit(error.status)
        raise error  # argparse's --help (SystemExit), or a bug: its traceback
    print(f"hybrid: error: {' '.join(message.split())}", file=sys.stderr)
    if verbose:
        original = error.original if isinstance(error, PluginError) and error.original is not None else error
        traceback.print_exception(original, file=sys.stderr)
    return 2


def main(argv=None) -> int:
    import jax

    from .physics._plugins import exit_guard

    jax.config.update("jax_enable_x64", True)  # the entry point chooses float64
    use_cpu_cores()  # and one CPU device per core: diagnose's lanes run side by side
    use_quick_compiles()  # XLA:CPU's loop emitters at LLVM's level 1: about half the compile time
    try:
        use_compilation_cache()  # $HYBRID_JAX_CACHE or ~/.cache/hybrid/jax: a warm diagnose compiles nothing
    except InputError as error:  # a cache is a speed-up: without it the command compiles afresh
        print(f"hybrid: warning: HYBRID_JAX_CACHE: {error}; compiling without it", file=sys.stderr)
    args = None
    ctrl_c: list[int] = []  # the signals _sigint_watch saw
    try:
        with _sigint_watch(ctrl_c), exit_guard(), reader_may_leave():
            args = build_parser().parse_args(argv)
            stage(f"hybrid {args.command}")  # a Ctrl-C lost while JAX started is raised here (hybrid_launch)
            # A heartbeat on stderr while it works, and exit status 3 instead of a silent hang (_watchdog).
            with Watchdog(f"hybrid {args.command}", quiet=getattr(args, "quiet", False)):
                COMMANDS[args.command](args)
    except BaseException as error:
        verbose = bool(getattr(args, "verbose", False)) or any(
            a in ("-v", "--verbose") for a in (argv or sys.argv[1:])
        )
        return _report(error, verbose, bool(ctrl_c))
    return 0


if __name__ == "__main__":
    sys.exit(main())
