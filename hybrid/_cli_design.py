"""`hybrid design DIAG_DIR`: the drive that tells a diagnosis's rival explanations apart.

Reads ``report.json`` of ``hybrid diagnose --out DIAG_DIR``: its ``ambiguous``
step (``--step``, default the first; an open last step's rivals are "nothing
more" against the effects that may still be missing), the rivals' models saved
beside it (``step<k>_<effect>.eqx``, ``step<k>_none.eqx``) and the noise floor; runs `hybrid.design_drive`
within the limits given; writes the drive (CSV ``t,v_in``, which
``rig record --drive-file`` and ``hybrid simulate --drive-file`` play) and a
figure of the rivals' predictions under it and under the control (``.png``
beside the CSV). A diagnosis with nothing ambiguous but a remainder that no
searched effect explains gets a rich drive instead (`hybrid.rich_drive`, a
multilevel PRBS within the same limits): there are no rivals to tell apart, and
another recording under a rich drive, diagnosed with the first, is the
experiment that can show what one did not. Nothing is written until the
design has succeeded.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np

from .util._errors import InputError


def add_design(sub, B) -> None:
    p = sub.add_parser(
        "design", help="the drive that tells a diagnosis's rival explanations apart (CSV t,v_in and a PNG)"
    )
    p.add_argument("diagnosis", help="the folder hybrid diagnose --out wrote (report.json, step<k>_*.eqx)")
    p.add_argument(
        "--duration", type=B.number(*B.DURATION, include_low=False, unit="s"), required=True, help="seconds"
    )
    p.add_argument(
        "--amplitude",
        type=B.number(0.0, 1e9, include_low=False),
        default=None,
        help="|drive| ≤ this (the DAC's range), in the drive's unit",
    )
    p.add_argument(
        "--bounds",
        default=None,
        metavar="LOW:HIGH",
        help="the drive's range instead of --amplitude, e.g. 0:10",
    )
    p.add_argument(
        "--output-bounds",
        default=None,
        metavar="LOW:HIGH",
        help="the range every rival's predicted output must keep within (a cell's voltage window, an "
        "actuator's travel), in the output's unit, e.g. 2.8:4.2 (default: none)",
    )
    p.add_argument(
        "--min-hold",
        type=B.number(0.0, 1e9, include_low=False, unit="s"),
        default=None,
        metavar="S",
        help="the shortest time the drive may stay at a level (a relay, a heater's contactor, a valve), "
        "seconds (default: one sample)",
    )
    p.add_argument(
        "--rate",
        type=B.number(*B.RATE, unit="Hz"),
        default=None,
        help="the rig's samples per second (default: the diagnosed recording's rate)",
    )
    p.add_argument(
        "--slew",
        type=B.number(0.0, 1e12, include_low=False),
        default=None,
        help="largest |d drive/dt|, drive unit per second (default: none)",
    )
    p.add_argument(
        "--step",
        type=B.integer(1, 1000),
        default=None,
        help="which ambiguous or open step (default: the first)",
    )
    p.add_argument("--starts", type=B.integer(*B.STARTS), default=4, help="starts of the gradient search")
    p.add_argument("--steps", type=B.integer(*B.MAX_STEPS), default=300, help="Adam steps per start")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--rich",
        type=B.number(0.0, 0.95),
        default=None,
        metavar="SHARE",
        help="share of the drive, at its start, kept as a multilevel PRBS (default: hybrid.design_drive's "
        "rich, 0.5; 0: all designed)",
    )
    p.add_argument("--out", required=True, help="the drive, .csv (t,v_in); the figure goes beside it as .png")
    p.add_argument("--quiet", action="store_true", help="no progress messages")
    p.add_argument(
        "--physics",
        default=None,
        metavar="SPEC",
        help="a plug-in physics (path/to/file.py:Class) the rivals' models need imported first",
    )


def _pair(flag: str, text: str) -> tuple[float, float]:
    """LOW:HIGH of a command-line flag, both finite and LOW below HIGH (one line if not)."""
    try:
        low, high = (float(x) for x in text.split(":"))
    except ValueError:
        raise InputError(f"{flag} {text!r}: give LOW:HIGH, e.g. {flag} 0:10") from None
    if not (math.isfinite(low) and math.isfinite(high) and low < high):
        raise InputError(f"{flag} {text!r}: LOW must be below HIGH, both finite")
    return low, high


def _bounds(args) -> dict:
    if args.amplitude is not None and args.bounds is not None:
        raise InputError(
            "give the drive's range once: --amplitude V (|drive| ≤ V) or --bounds LOW:HIGH, not both"
        )
    if args.amplitude is None and args.bounds is None:
        raise InputError("give the drive's range: --amplitude V (|drive| ≤ V) or --bounds LOW:HIGH")
    if args.amplitude is not None:
        return {"amplitude": args.amplitude}
    return {"bounds": _pair("--bounds", args.bounds)}


def _report(folder: Path) -> dict:
    """The ``report.json`` of a diagnosis folder, read once."""
    report_path = folder / "report.json"
    if not report_path.is_file():
        raise InputError(f"{folder}: no report.json; give the folder that hybrid diagnose --out wrote")
    try:
        return json.loads(report_path.read_text())
    except (OSError, ValueError) as error:
        raise InputError(f"{report_path}: not a readable report ({error})") from None


def _rivals(folder: Path, report: dict, step: int | None) -> tuple[dict | None, dict, float]:
    """(the chosen ``ambiguous`` entry, its rivals' models by name, the noise floor's σ) of a diagnosis.

    (None, {}, nan) where nothing is ambiguous but a remainder is unexplained: a rich drive's case.
    """
    from .core._serialise import load_model

    report_path = folder / "report.json"
    entries = report.get("ambiguous")
    if entries is None:
        raise InputError(
            f"{report_path} has no 'ambiguous' key: it was written by an older hybrid; run hybrid diagnose again"
        )
    if not entries and report.get("unexplained") and step is None:  # a question, but no rivals
        return None, {}, math.nan
    if not entries and report.get("unexplained"):  # --step given: that step has no rivals
        raise InputError(
            f"--step {step}: the diagnosis in {report_path} found no ambiguous step; its unexplained "
            "remainder asks for a rich drive: run hybrid design without --step"
        )
    if not entries:
        raise InputError(
            f"{report_path}: the diagnosis found nothing ambiguous, so there are no rivals to tell apart "
            "(no design is needed)"
        )
    if step is None:
        entry = entries[0]
    else:
        entry = next((e for e in entries if e["step"] == step), None)
        if entry is None:
            raise InputError(
                f"--step {step}: no ambiguous step {step} in {report_path} (ambiguous steps: "
                f"{', '.join(str(e['step']) for e in entries)})"
            )
    if "models" not in entry:
        raise InputError(f"{report_path}: the ambiguous step names no models; run hybrid diagnose again")
    models = {}
    for name, file in entry["models"].items():
        path = folder / file
        if not path.is_file():
            raise InputError(f"{path}: missing (hybrid diagnose --out saves it); run hybrid diagnose again")
        models[name] = load_model(path)
    noise = (report.get("noise_floor") or {}).get("std")
    if not isinstance(noise, (int, float)) or not math.isfinite(noise) or noise <= 0:
        raise InputError(f"{report_path}: its noise floor is not a positive number, the design's scale")
    return entry, models, float(noise)


#: A designed drive this share of the recorded drive's span beyond it is said to leave it (`_beyond_recorded`).
BEYOND_SHARE = 0.05


def _beyond_recorded(report: dict, drive) -> str | None:
    """The sentence where `drive` goes beyond the diagnosed recordings' drive range (``evidence.drive_range``)
    by more than `BEYOND_SHARE` of its span, else None: the rivals were fitted there only, and what they
    predict beyond is an extrapolation (a probe's --bounds 50:60 on a 0.2-2 V record: T = 2.7e5, unsaid)."""
    known = (report.get("evidence") or {}).get("drive_range")
    if not (isinstance(known, list) and len(known) == 2 and all(isinstance(x, (int, float)) for x in known)):
        return None
    low, high = float(known[0]), float(known[1])
    margin = BEYOND_SHARE * max(high - low, 1e-300)
    lo, hi = float(np.min(drive)), float(np.max(drive))
    if lo >= low - margin and hi <= high + margin:
        return None
    unit = (report.get("units") or {}).get("v_in", "")
    unit = f" {unit}" if unit else ""
    return (
        f"the drive spans {lo:.4g} to {hi:.4g}{unit}, beyond the {low:.4g} to {high:.4g}{unit} of the diagnosed "
        "recordings, where the rivals were fitted: what they predict there, and so how well the drive tells "
        f"them apart, is an extrapolation; --bounds {low:.4g}:{high:.4g} keeps it where they were fitted"
    )


#: A drive that moves over less than this share of its range is said to be nearly constant (`_nearly_constant`).
STILL_SHARE = 0.05


def _nearly_constant(drive, limits: dict, slew: float | None) -> str | None:
    """The sentence where the written drive spans under `STILL_SHARE` of the range it was given, else None:
    a probe's --slew 1e-9 gave a constant drive called "a multilevel PRBS" that "tells them apart", while a
    constant level tells rivals apart by that level alone, which a refit takes up."""
    low, high = limits["bounds"] if "bounds" in limits else (-limits["amplitude"], limits["amplitude"])
    width = float(high) - float(low)
    moved = float(np.ptp(drive)) if len(drive) else 0.0
    if not width > 0 or moved >= STILL_SHARE * width:
        return None
    return (
        f"the drive moves over {moved:.3g} of the {width:.3g} its limits allow: it is nearly constant, and a "
        "constant level tells the rivals apart by that level alone, which a refit of either takes up"
        + (f"; --slew {slew:g}/s holds it there: allow a faster slew or a longer --duration" if slew else "")
    )


def _diagnosed_rate(folder: Path, report: dict) -> float:
    """The sample rate (Hz) of the recording the diagnosis was made on (``evidence.rate_hz``)."""
    rate = (report.get("evidence") or {}).get("rate_hz")
    if not isinstance(rate, (int, float)) or not math.isfinite(rate) or rate <= 0:
        raise InputError(
            f"{folder / 'report.json'}: no sample rate of the diagnosed recording in it (evidence.rate_hz); "
            "give the rig's with --rate HZ"
        )
    return float(round(rate, 6))


def cmd_design(args) -> None:
    from ._cli_outputs import check_outputs, out_file
    from .discovery._design import design_drive, rich_drive
    from .physics._plugins import resolve_physics

    limits = _bounds(args)
    output = None if args.output_bounds is None else _pair("--output-bounds", args.output_bounds)
    folder = Path(args.diagnosis)
    out = Path(args.out)
    figure = out.with_suffix(".png")
    lock = check_outputs(
        [out_file(out, suffixes=(".csv",), companions=(figure,))], inputs=[folder / "report.json"]
    )
    with lock:
        report = _report(folder)
        if args.rate is None:  # a drive for the rig that made the diagnosed recording: its rate
            args.rate = _diagnosed_rate(folder, report)
        # a plug-in's classes imported before its models load, probed at the rig's rate
        if args.physics is not None:
            resolve_physics(args.physics, [], rate=args.rate)
        entry, models, noise = _rivals(folder, report, args.step)
        if entry is None and output is not None:
            raise InputError(
                "--output-bounds: the diagnosis found nothing ambiguous, so there are no rivals whose predicted "
                "output a rich drive could be kept within; narrow --amplitude/--bounds instead"
            )
        if entry is None:
            t, drive = rich_drive(
                duration=args.duration,
                rate=args.rate,
                slew=args.slew,
                seed=args.seed,
                hold=args.min_hold,
                **limits,
            )
            _write(
                out, figure, t, drive, {}, "a multilevel PRBS (nothing ambiguous; a remainder unexplained)"
            )
        else:
            if not args.quiet:
                rivals = " vs ".join("nothing more" if m == "none" else m for m in models)
                print(
                    f"design: step {entry['step']}: {rivals} (noise floor σ = {noise:.3g}), "
                    f"{args.starts} starts × {args.steps} steps",
                    flush=True,
                )
            rich = {} if args.rich is None else {"rich": args.rich}
            design = design_drive(
                models,
                duration=args.duration,
                rate=args.rate,
                slew=args.slew,
                noise_std=noise,
                starts=args.starts,
                steps=args.steps,
                seed=args.seed,
                output_bounds=output,
                hold=args.min_hold,
                **limits,
                **rich,
            )
            title = (
                f"designed drive: T = {design.criterion:.3g} (control PRBS {design.control_criterion:.3g})"
            )
            _write(out, figure, design.t, design.v_in, design.predictions, title)
    written = drive if entry is None else design.v_in
    still = _nearly_constant(written, limits, args.slew)
    for said in (_beyond_recorded(report, written), still):
        if said:
            print(f"hybrid: warning: {said}", file=sys.stderr)
    if entry is None:
        print(
            "the diagnosis found nothing ambiguous, so no rivals to tell apart, but it leaves a remainder no "
            f"searched effect explains: wrote a multilevel PRBS ({len(drive)} samples at {args.rate:g} Hz within "
            f"[{drive.min():.3g}, {drive.max():.3g}]) to {out} and {figure}; record it and run hybrid diagnose "
            "on both recordings together, or add an effect of your own (docs/effects.md)"
        )
        return
    low, high = design.limits["low"], design.limits["high"]
    slew = f", slew ≤ {args.slew:g}/s" if args.slew else ""
    kept = f", the first {design.rich_samples} kept as a multilevel PRBS" if design.rich_samples else ""
    versus = (
        f", {design.criterion / design.control_criterion:.3g}× a multilevel PRBS's {design.control_criterion:.3g}"
        if design.control_criterion > 0
        else ""
    )
    if args.min_hold:
        slew += f", each level held ≥ {design.limits['hold']:g} s"
    if output is not None:
        slew += f", every rival's predicted output within [{output[0]:g}, {output[1]:g}]"
    print(
        f"designed {len(design.v_in)} samples at {args.rate:g} Hz within [{low:g}, {high:g}]{slew}{kept}: "
        f"T = {design.criterion:.3g} ({design.pair[0]} vs {design.pair[1]}){versus}"
    )
    left = report.get("unexplained") or {}
    excess = left.get("ratio_to_floor") if isinstance(left, dict) else None
    excess = float(excess) if isinstance(excess, (int, float)) and math.isfinite(excess) else 1.0
    if still:  # n·T is then the level's alone, which a refit takes up: no claim that it tells them apart
        print(
            f"n·T = {len(design.v_in) * design.criterion:.3g}, from a nearly constant drive (the warning above): "
            "its level alone tells the rivals apart, which a refit of either takes up, so this drive does not "
            "separate them"
        )
    else:
        print(separation(design.criterion, design.control_criterion, len(design.v_in), max(excess, 1.0)))
    print(f"wrote {out} and {figure}")
    others = [e for e in report.get("ambiguous") or () if e.get("step") != entry.get("step")]
    # a probe's design went to step 1's two limits of the states, and its open step 2 was not said
    if args.step is None and others:
        listed = "; ".join(
            f"step {e.get('step')}: "
            + " vs ".join(
                "nothing more" if n == "none" else n
                for n in [e.get("named", "?")] + [r.get("name", "?") for r in e.get("rivals", ())]
            )
            for e in others
        )
        print(
            f"the diagnosis leaves {'another step' if len(others) == 1 else f'{len(others)} more steps'} "
            f"ambiguous ({listed}); --step N designs a drive for that step instead"
        )


#: n·T (the lack-of-fit test's non-centrality) below which a recording barely tells two rivals apart: a
#: one-degree χ² test at 1 % rejects the wrong rival with probability 0.5 at 6.6 and 0.9 at 14.9.
SEPARATES = 14.9
#: A designed T within this factor of the control's gains little over recording the multilevel PRBS.
LITTLE_GAIN = 1.2


def separation(criterion: float, control: float, n: int, excess: float = 1.0) -> str:
    """One sentence: how surely a recording under the designed drive tells the rivals apart, against the PRBS.

    n·T is the non-centrality of the lack-of-fit test of one rival when the other is
    true (`hybrid.discovery._design`); a design barely better than the control is said to be.
    T's σ is the noise floor. Where the diagnosis's final model leaves `excess` times
    the floor's variance held out (`unexplained.ratio_to_floor`), what no rival
    explains is noise to that test too: the verdict uses n·T / `excess`, and says so
    (a Silverbox diagnosis 60× above its floor was told n·T = 2.6e9).
    """
    strength = n * criterion
    shown = f"n·T = {strength:.3g}"
    if excess > 1.0:
        strength /= excess
        shown += (
            f" with the noise floor as σ, {strength:.3g} with the final model's held-out error ({excess:.3g}× the "
            "floor's variance, which no rival explains)"
        )
    if strength < SEPARATES:
        return (
            f"{shown}: a recording under it would barely tell them apart (a χ² test at 1 % "
            f"needs n·T ≈ {SEPARATES:g} to reject the wrong rival 9 times in 10); record longer, or give a "
            "wider --amplitude/--bounds or a looser --slew: n·T grows with each"
        )
    if control > 0 and criterion < LITTLE_GAIN * control:
        return (
            f"{shown}: either drive tells them apart; the design gains little over the multilevel "
            "PRBS of the same length and range, which already separates them"
        )
    return (
        f"{shown}: a recording under it tells them apart at their fitted values (n·T ≫ {SEPARATES:g}); T is "
        "local: refitted to the new recording, the rivals can absorb part of what tells them apart (a drive "
        "that stays where their nonlinearities act alike leaves only gains and offsets a refit takes up)"
    )


def _write(out: Path, figure: Path, t, drive, predictions: dict, title: str) -> None:
    """The drive as CSV (t,v_in) and its figure (with the rivals' predictions, where there are rivals)."""
    import numpy as np

    from .util._atomic import atomic_open
    from .util._figures import pyplot, save_png

    plt = pyplot()
    fig, axes = plt.subplots(2 if predictions else 1, 1, figsize=(9, 5 if predictions else 3), sharex=True)
    top = axes[0] if predictions else axes
    top.plot(t, drive, lw=1)
    top.set(ylabel="drive", title=title)
    if predictions:
        for name, prediction in predictions.items():
            axes[1].plot(t, prediction, lw=1, label=name)
        axes[1].set(ylabel="predicted output", title="the rivals' predictions under it")
        axes[1].legend(fontsize=8)
    (axes[-1] if predictions else axes).set(xlabel="time (s)")
    fig.tight_layout()
    save_png(fig, figure)
    with atomic_open(out, "w", newline="") as handle:
        handle.write("t,v_in\n")
        np.savetxt(handle, np.column_stack([t, drive]), delimiter=",", fmt="%.17g")
