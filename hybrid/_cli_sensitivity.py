"""`hybrid sensitivity`: the RC network's study (`--physics rc`, the default) or any simulation's on a recording.

- ``--physics rc``: `hybrid.ipmc._sensitivity_study`, exactly as before: the
  four synthetic drives (an IPMC's voltages, ``--drive``/``--duration``/``--rate``),
  Table 1's parameters, the frequency views; a recording adds its drive.
- any other ``--physics`` (``lti:N``, ``file.py:Class``): `hybrid.sensitivity._study`
  on the drive of the recording given, which is required: the synthetic drives
  are an IPMC's voltages at 30 Hz and say nothing honest about another system.
  Its `frozen_by_default` parameters are left out, as `fit` leaves them fixed.

The recording may be a lab's file (the column options of `hybrid fit`).
"""

from __future__ import annotations

import sys
from pathlib import Path

from .util._errors import InputError

#: Fewest samples a recording needs for a study of a simulation other than rc
#: (and at least two per parameter, gain and offset included).
MIN_SAMPLES = 10
_RC_ONLY = ("drive", "duration", "stages")


def add_sensitivity(sub, B) -> None:
    from ._cli_inputs import add_mapping, add_physics

    p = sub.add_parser(
        "sensitivity",
        help="sensitivities and identifiability of a simulation's parameters (the RC network's by default)",
    )
    p.add_argument(
        "recording",
        nargs="?",
        default=None,
        help="a recording whose drive is the primary one (required unless --physics rc)",
    )
    p.add_argument("--out", required=True, help="output directory (sensitivity.json, sensitivity.md, PNGs)")
    p.add_argument(
        "--drive",
        choices=("prbs", "sine", "chirp", "pulse"),
        default=None,
        help="primary drive (rc only; default prbs)",
    )
    p.add_argument(
        "--duration",
        type=B.number(*B.DURATION, include_low=False, unit="s"),
        default=None,
        help="seconds per drive (rc only; default 120)",
    )
    p.add_argument(
        "--rate",
        type=B.number(*B.RATE, unit="Hz"),
        default=None,
        help="samples per second: of the synthetic drives (rc; default 30), and of a recording in a "
        "lab's columns (--input/--output/--columns) whose file gives none",
    )
    p.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="nominal parameter: for rc xi_rho, xi_h, alpha_E, alpha_I, alpha_C, C_clamp (F); "
        "for other physics its own names (default: its defaults)",
    )
    p.add_argument(
        "--stages",
        type=B.integer(*B.STAGES),
        default=None,
        help="N, the network has N+1 sections (rc only; default 45)",
    )
    p.add_argument(
        "--noise",
        type=float,
        default=0.01,
        help="noise as a fraction of rms(w), for standard errors (default 0.01: 1 %%)",
    )
    p.add_argument(
        "--sobol",
        type=B.integer(*B.SOBOL),
        default=0,
        metavar="N",
        help="also Sobol indices from N base samples",
    )
    p.add_argument("--seed", type=int, default=0)
    add_physics(p)
    add_mapping(p, B, rate=False)  # --rate is above: it serves both


def cmd_sensitivity(args) -> None:
    from ._cli_inputs import load_recordings, parse_params
    from ._cli_outputs import check_outputs, out_folder

    rc = args.physics.strip().lower() == "rc"
    inputs = [args.recording] if args.recording else []
    if not rc:
        given = [f"--{k}" for k in _RC_ONLY if getattr(args, k) is not None]
        if given:
            raise InputError(
                f"{', '.join(given)} {'belongs' if len(given) == 1 else 'belong'} to the RC network's study (an IPMC's synthetic voltage "
                f"drives): with --physics {args.physics} the drive is the recording's"
            )
        if args.recording is None:
            raise InputError(
                f"--physics {args.physics}: give a recording of your system (RECORDING; --input/"
                "--output for a lab's columns): the synthetic drives are an IPMC's voltages at 30 Hz, "
                "studied only with --physics rc"
            )
        return _generic(args)
    from .ipmc._sensitivity_study import OUTPUT_FILES, SensitivityStudySettings, run_sensitivity_study
    from .util.bounds import check_samples

    duration, rate = args.duration or 120.0, args.rate or 30.0
    check_samples(duration, rate)
    lock = check_outputs([out_folder(args.out, OUTPUT_FILES)], inputs=inputs)
    recording = load_recordings(args, inputs, rate_alone_maps=False)[0] if inputs else None
    settings = SensitivityStudySettings(
        parameters=parse_params(args.param),
        n_stages=args.stages or 45,
        drive=args.drive or "prbs",
        duration=duration,
        rate=rate,
        noise=args.noise,
        sobol=args.sobol,
        seed=args.seed,
    )
    with lock:
        result = run_sensitivity_study(settings, out_dir=args.out, recording=recording)
    _print(result, "V_o")
    print(f"wrote {Path(args.out) / 'sensitivity.json'} and figures ({result['seconds']:.1f} s)")


def _generic(args) -> None:
    import jax

    from ._cli_inputs import load_recordings, parse_params
    from ._cli_outputs import check_outputs, out_folder
    from .core._fit import recording_units
    from .physics._plugins import resolve_physics
    from .sensitivity._study import OUTPUT_FILES, simulation_study, write_simulation_study

    params = parse_params(args.param)
    mapped = any(
        getattr(args, k) is not None for k in ("input", "output", "time", "columns", "sample_range", "units")
    )
    if args.rate is not None and not mapped:
        raise InputError(
            f"--rate with --physics {args.physics} is the rate of a lab's file (with --input/--output or "
            "--columns); a recording in the project's columns t, v_in, w has its own t"
        )
    lock = check_outputs([out_folder(args.out, OUTPUT_FILES)], inputs=[args.recording])
    recording = load_recordings(args, [args.recording], rate_alone_maps=False)[0]
    # probed on a step at the recording's rate (its first samples would centre an lti:N's defaults on it)
    simulation = resolve_physics(args.physics, rate=recording.rate)
    if params:
        simulation = simulation.replace(**params)
    k = len(set(simulation.parameter_names()) - set(simulation.frozen_by_default)) + 2  # + gain and offset
    recording.check_length(
        max(MIN_SAMPLES, 2 * k),
        f"the study of {k} parameters (gain and offset included)",
        "give a longer recording",
    )
    recording.check_signals()
    with lock:
        result, sensitivity = simulation_study(
            simulation,
            recording.v_in,
            recording.dt,
            noise=args.noise,
            sobol=args.sobol,
            seed=args.seed,
            drive=f"recording:{recording.name}",
            drive_unit=(recording_units([recording]) or ("mm", "V"))[1],
        )
        result["physics"] = args.physics
        result["settings"] = {
            "physics": args.physics,
            "parameters": params,
            "noise": args.noise,
            "sobol": args.sobol,
            "seed": args.seed,
            "recording": recording.name,
            "rate_hz": float(recording.rate),
        }
        result["x64"] = bool(jax.config.read("jax_enable_x64"))
        write_simulation_study(result, sensitivity, args.out)
    _print(result, "w")
    for said in result["warnings"]:
        print(f"hybrid: warning: {said}", file=sys.stderr)
    noise = result["noise"]["fraction_of_rms_w"]
    out_unit = result["units"].get("offset", "")
    print(
        f"standard errors (Cramér–Rao, noise {100 * noise:g} % of rms(w), gain and offset unknown; w is the "
        f"simulation's output under the recording's drive, in {out_unit or 'its own unit'}: the recording's "
        "own output is not read):"
    )
    for name, se in result["std_error"].items():
        rel = result["relative_std_error"][name]
        unit = result["units"].get(name, "")
        unit = "" if unit in ("", "1") else f" {unit}"
        value = result["nominal"].get(name, 1.0 if name == "gain" else 0.0)
        rel_text = "" if rel is None or isinstance(rel, str) else f" ({100 * rel:.3g} %)"
        print(f"  {name} = {value:.6g} ± {se if isinstance(se, str) else f'{se:.3g}'}{unit}{rel_text}")
    print(f"wrote {Path(args.out) / 'sensitivity.json'} and figures ({result['seconds']:.1f} s)")


def _print(result, output) -> None:
    values = ", ".join(f"{v:.2e}" for v in result["relative_singular_values"])
    print(f"relative singular values ({result['primary_drive']}): {values}")
    for direction in result["null_directions"]:
        text = " ".join(f"{c:+.4f}·{'log ' if output == 'V_o' else ''}{n}" for n, c in direction.items())
        print(f"null direction ({output} does not change along it): {text}")
    for pair in result["collinear_pairs"]:
        print(f"near-collinear: {pair['pair'][0]} and {pair['pair'][1]} (cosine {pair['cosine']:+.4f})")
