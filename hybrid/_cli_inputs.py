"""What the `hybrid` command line reads: a lab's own files (column mapping) and, later, its physics.

Kept apart from `hybrid.cli` (the commands) so each stays a room about one thing.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from .data._recording_checks import FILL_GAPS_MAX
from .util._errors import InputError


def add_mapping(p, B, rate: bool = True) -> None:
    """Options that read a lab's own file: which columns are the drive and the output, the rate, the samples.

    `rate` False leaves --rate out, for a command that has its own (`hybrid sensitivity`).
    """
    g = p.add_argument_group("files with other columns (hybrid.load_mapped; docs/command-line.md)")
    g.add_argument("--input", default=None, metavar="COLUMN", help="the drive's column (e.g. uEst)")
    g.add_argument(
        "--output", default=None, metavar="COLUMN", help="the measured output's column (e.g. yEst)"
    )
    g.add_argument(
        "--time", default=None, metavar="COLUMN", help="a time column (default: none; t from the rate)"
    )
    g.add_argument(
        "--columns",
        default=None,
        metavar="MAP",
        help="the mapping in one flag: input=uEst,output=yEst; or files joined into one record, "
        "one per channel: input=u.txt,output=y.txt (FILE:COLUMN for a column of a wider file)",
    )
    if rate:
        g.add_argument(
            "--rate",
            type=B.number(*B.RATE, unit="Hz"),
            default=None,
            help="samples per second, when the file has no time column or Ts/fs field",
        )
    g.add_argument(
        "--range",
        dest="sample_range",
        default=None,
        metavar="START:STOP",
        help="the samples to use, Python-slice style (e.g. 40650:)",
    )
    g.add_argument("--units", default=None, metavar="MAP", help="unit labels, e.g. v_in=V,w=V (labels only)")
    g.add_argument(
        "--fill-gaps",
        type=B.integer(1, FILL_GAPS_MAX),
        default=None,
        metavar="N",
        help=f"fill each gap of the time column of at most N missing frames (1 to {FILL_GAPS_MAX}: a camera "
        "that dropped a frame), and each run of at most N missing values (empty or NaN cells: a tracker that "
        "lost the tip) of the drive or output, by straight lines, and say so (default: refuse them)",
    )


def load_recordings(args, paths, rate_alone_maps: bool = True):
    """Recordings from the command line's paths: the project's own columns, or the mapped ones.

    `rate_alone_maps` False: --rate alone does not make a file mapped (`hybrid sensitivity`'s
    --rate is its synthetic drives' rate too, and a file in the project's columns has its t).
    Several are put in the first's units (`in_shared_units`: µm beside mm converted, counts
    beside mm refused). What validation did to each (`Recording.notes`: t rebuilt, frames
    filled, a unit converted) is said on stderr, whichever command reads them.
    """
    from .data._recording import in_shared_units

    recordings = in_shared_units(_load_recordings(args, paths, rate_alone_maps), "fitted together")
    _warn_notes(recordings)
    return recordings


def _load_recordings(args, paths, rate_alone_maps: bool):

    from .data._loaders import TEXT_SUFFIXES
    from .data._mapping import file_references, header_names, load_mapped
    from .data._mapping_options import mapping_roles
    from .data._recording import Recording

    seen: dict[Path, str] = {}
    for path in paths:
        key = Path(path).resolve()
        if key in seen:  # the same samples twice: weighted double, and in both train and validation
            raise InputError(
                f"recording '{path}' is given twice ({seen[key]!r} and {path!r} are one file): give each "
                "recording once"
            )
        seen[key] = path
    options: dict[str, Any] = {  # argparse's values, any of them None when not given
        k: getattr(args, k, None)
        for k in ("input", "output", "time", "columns", "rate", "sample_range", "units", "fill_gaps")
    }
    if not any(options[k] is not None for k in ("input", "output", "time", "columns")):
        text = [p for p in paths if Path(p).suffix.lower() in TEXT_SUFFIXES]
        names = [header_names(p) for p in text]
        if text and all({"t", "v_in", "w"} <= set(n) for n in names):  # the project's own columns
            return [load_mapped(p, **{**options, "input": "v_in", "output": "w", "time": "t"}) for p in paths]
        if text:  # a text table has no t, v_in, w: say how to map it, or how to join one file per channel
            raise InputError(
                f"'{text[0]}' is a text table without the columns t, v_in, w: say which is the drive "
                f"and which the output, e.g. {_text_example(paths, names[0])}"
            )
    if not any(v is not None for k, v in options.items() if rate_alone_maps or k != "rate"):
        return _each(paths, Recording.load)
    if len(paths) > 1 and any(options[k] is not None for k in ("input", "output", "time", "columns")):
        roles = mapping_roles(**{k: options[k] for k in ("input", "output", "time", "columns")})
        if file_references(roles, paths):  # the mapping names the files: one record joined from them
            return [load_mapped(list(paths), **options)]
    return _each(paths, lambda p: load_mapped(p, **options))


def _each(paths, load) -> list:
    """`load` of each path; where one lacks a column and the files name their columns differently, the
    error says so: one mapping reads every file (a probe's second recording named its output `speed`, the
    first `w`, and each file's advice broke the other)."""
    from .data._loaders import MissingName
    from .data._mapping import header_names

    out = []
    for path in paths:
        try:
            out.append(load(path))
        except MissingName as error:
            headers = {str(p): header_names(p) for p in paths}
            if len(paths) < 2 or len({tuple(h) for h in headers.values()}) < 2:
                raise
            named = "; ".join(f"'{p}': {', '.join(h) or '(unread)'}" for p, h in headers.items())
            raise InputError(
                f"{error}; the recordings name their columns differently ({named}), and one mapping reads "
                "them all: rename the column in one file to match the others"
            ) from None
    return out


def _text_example(paths, names: list[str]) -> str:
    """The mapping to write for unmapped text tables: one file per channel, or the table's own columns."""
    from .data._loaders import mapping_example

    if len(paths) > 1:
        return f"--columns input={paths[0]},output={paths[1]} (one file per channel, of one length), with --rate HZ"
    if len(names) >= 2 and not all(n.isdigit() for n in names):  # a header: guess from its names
        return f"{mapping_example(names)} (its columns: {', '.join(n or '(unnamed)' for n in names)})"
    return (
        f"--columns input={paths[0]}:0,output={paths[0]}:1 (columns by number from 0, or by the header's "
        "names), with --rate HZ or --time COLUMN"
    )


def add_physics(p, default: str = "rc") -> None:
    """--physics: the simulation (hybrid.physics._plugins); each name means one simulation everywhere.

    `default`: the command's own, ``rc`` (the paper's Tustin network) for fit and sensitivity,
    ``rc:zoh`` (the same network, exact for a held drive) for diagnose.
    """
    p.add_argument(
        "--physics",
        default=default,
        metavar="SPEC",
        help=f"the simulation (default {default}): rc (the paper's RC network, Tustin sections), rc:zoh (the "
        "same network exact for a drive held between samples, C_clamp 30 mF), lti:N (a linear system of "
        "order N), path/to/file.py:Class or package.module:Class (your AbstractSimulation)",
    )


def add_settle(p, B) -> None:
    """--settle N: the physics starts where a fitted constant drive left it (hybrid.HeldStart)."""
    p.add_argument(
        "--settle",
        type=B.integer(1, B.SETTLE_MAX),
        default=None,
        metavar="SAMPLES",
        help="the record does not start at rest: hold the physics at a constant drive (the fitted "
        "parameter initial_drive) for SAMPLES samples before it, several of its slowest time "
        "constant (one recording)",
    )


def with_settle(simulation, args, recordings):
    """The simulation wrapped in HeldStart for --settle, started at the record's first drive level."""
    if getattr(args, "settle", None) is None:
        return simulation
    from .core._held_start import held_at_start

    if len(recordings) != 1:
        raise InputError(
            f"--settle fits one held drive before the record, and {len(recordings)} recordings each "
            "start from their own state: give one recording"
        )
    return held_at_start(simulation, args.settle, recordings[0])


def _warn_notes(recordings):
    """One stderr line per thing validation did to a recording (e.g. t rebuilt from jittered times)."""
    for recording in recordings:
        for note in recording.notes:
            print(f"hybrid: warning: {note}", file=sys.stderr)


#: Samples (over every recording) from which `hybrid diagnose` says how to make the record shorter.
LONG_RECORD = 50_000


def long_record_note(recordings) -> str | None:
    """What `hybrid diagnose` says before it starts on `LONG_RECORD` samples or more, else None.

    Every candidate's lanes are fitted to every sample: a probe's 200,000 samples at 1 kHz (a 5 Hz mode) ran
    over 11 minutes without a word on why, where `hybrid fit` took 11 s.
    """
    n = sum(int(r.v_in.size) for r in recordings)
    if n < LONG_RECORD:
        return None
    rate = min(float(r.rate) for r in recordings)
    return (
        f"{n} samples: diagnose fits each candidate effect to every one of them, which takes many minutes; "
        f"a part (--range A:B) or the record at a lower rate (here {rate:g} Hz: keep a few samples per period "
        "of the fastest dynamics) diagnoses in a fraction of the time"
    )


def parse_params(items):
    from .core._parameters import parse_assignment

    return dict(parse_assignment(item) for item in items)


#: What ``--effects`` takes, item by item.
EFFECT_FORMS = (
    "builtins, a built-in's name, limit_<state>, floor_<state>, friction_<state>, window_<state> or "
    "window_<group>, "
    "path/to/file.py:ClassName or "
    "package.module:ClassName"
)


def effects_from_spec(spec: str, simulation=None) -> tuple:
    """The effects a command line's ``--effects`` names: comma-separated items of `EFFECT_FORMS`.

    ``builtins`` stands for every built-in `simulation` can take (see
    `resolve_effects`: inside the dynamics only for a state-space form);
    ``--effects builtins,friction.py:Coulomb`` searches them and a plug-in.
    """
    from .core._simulation import AbstractSimulation
    from .discovery._effect_set import EFFECTS, NAMED_ONLY, resolve_effects
    from .discovery._effects import AbstractEffect
    from .physics._plugins import plugin_module, register

    items = [x.strip() for x in str(spec).split(",") if x.strip()]
    if not items:
        raise InputError(f"--effects needs one or more of {EFFECT_FORMS}, comma-separated; got {spec!r}")
    chosen: list = []
    specs: dict[str, str] = {}  # a plug-in class's name -> its spec, for the checks' messages
    for text in items:
        if text == "builtins":
            chosen += list(resolve_effects(None, simulation))
            continue
        if (
            text in EFFECTS
            or text in NAMED_ONLY
            or (":" not in text and text.startswith(("limit_", "floor_", "friction_", "window_")))
        ):
            chosen.append(text)  # resolve_effects says which states there are
            continue
        module, label, name = plugin_module(
            text,
            "--effects",
            f"not an effect I know; give {EFFECT_FORMS} (the built-ins: {', '.join([*EFFECTS, *NAMED_ONLY])})",
        )
        cls = getattr(module, name, None)
        if not isinstance(cls, type) or not issubclass(cls, AbstractEffect):
            mine = sorted(
                k
                for k, v in vars(module).items()
                if isinstance(v, type) and issubclass(v, AbstractEffect) and v.__module__ == module.__name__
            )
            has = f"it defines {', '.join(mine)}" if mine else "it defines no AbstractEffect subclass"
            what = "has no class" if cls is None else "has no AbstractEffect subclass"
            if isinstance(cls, type) and issubclass(cls, AbstractSimulation):  # a probe's physics given here
                has = f"{name} is a simulation: give it as --physics {text}, and effects here"
            raise InputError(f"--effects {text}: {label} {what} {name}; {has}")
        register(cls.__module__, text, flag="--effects")
        specs[cls.__name__] = text
        chosen.append(cls)
    try:
        return resolve_effects(chosen, simulation)
    except InputError as error:  # a plug-in's check names its class; the spec names its file too
        said = str(error)
        named = next(
            (v for k, v in specs.items() if said.startswith((f"effect {k}:", f"{k}.", f"{k} "))), None
        )
        if named is None or said.startswith("--effects"):
            raise
        error.args = (f"--effects {named}: {said}", *error.args[1:])
        raise
