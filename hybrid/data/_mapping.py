"""A lab's own file as a [`Recording`][hybrid.Recording]: which column is the drive,
which the measured output, where the time comes from.

`load_mapped` (also `Recording.load(path, input=..., output=..., ...)`) reads a
``.csv``, ``.npz`` or ``.mat`` file whose columns are not called ``t, v_in, w``;
`load_pair` reads a benchmark's estimation and validation records. The mapping:

* ``input`` / ``output`` / ``time``: the file's names (header names, array or
  variable names; exact, case-sensitive) of the drive (-> ``v_in``), the
  measured output (-> ``w``) and an optional time column in seconds (-> ``t``).
* ``columns``: the same in one string, ``"input=uEst,output=yEst"`` or
  ``"t=time,v_in=u,w=y"``. Grammar::

      columns ::= pair { "," pair }
      pair    ::= role "=" name
      role    ::= "input" | "v_in" | "output" | "w" | "time" | "t"   (any case)
      name    ::= a column name, spaces around it trimmed; in double quotes
                  when it holds a comma, e.g. output="level, V"

  ``units`` may be given as a string in the same grammar, ``"v_in=V,w=mm"``.
  Each role at most once, here and in the keywords together; ``input=a,output=b``
  and ``input="a", output="b"`` give the same recording.
* ``rate`` (Hz): with no time column, ``t = (start + k) / rate``. A rate or
  period field of the file (`RATE_FIELDS`: a ``Ts`` column whose first row holds
  the period, as in Cascaded Tanks; ``fs``/``rate`` columns; the same keys in the
  sidecar metadata) gives it too. Every rate given (argument, fields, metadata,
  the time column's step: its span over its steps to six digits of its rate, `time_step`, the least-squares
  step of jittered timestamps rebuilt as a grid) must agree within `RATE_RTOL` (or,
  against jittered timestamps, the drift their largest jitter allows), else one
  error; the time column wins, then the file's fields, the metadata, the argument.
* ``sample_range``: ``"start:stop"`` in samples from 0, Python-slice style,
  either side optional (``"40650:"``, ``":40000"``, ``"100:200"``); negative,
  out-of-range and empty ranges are refused. It is applied after mapping; the
  time then keeps the file's clock: ``t[0] = start / rate`` (or the time
  column's value), and ``metadata["segment"]`` records ``start`` and ``stop``,
  as [`Recording.segment`][hybrid.Recording.segment] does.
* ``units``: labels stored in ``metadata["units"]``, e.g. ``{"v_in": "V",
  "w": "V"}``; nothing is converted except a time column given in ``ms``,
  ``us``, ``ns``, ``min`` or ``h`` (`TIME_UNITS`). Defaults: the sidecar's units for the
  column (or role), else a units row's, else the unit in the column's name
  (``Time [ms]``, ``y (mm)``, ``Displacement/µm``: `hybrid.data._header_units` gives
  the rule; a time column's scales it), else ``V`` for the drive and ``a.u.`` for the
  output.

* **Several files, one record** (a logger that writes each channel to its own
  file): ``path`` is a list of files and each name in the mapping is ``FILE``
  (a file of one column: a text table, a one-column CSV, a ``.npz``/``.mat``
  with one array) or ``FILE:COLUMN`` (a column of it, by name or by number
  from 0), ``FILE`` being one of the files as given (or its name alone, when
  no other file has it): ``load_mapped(["u.txt", "y.txt"],
  columns="input=u.txt,output=y.txt", rate=100)``. The files must hold the
  same number of samples; every file given must be named, and every name must
  name a file. One file may also be named this way (``"input=run.txt:0,
  output=run.txt:1"``).

Every bad mapping raises one [`InputError`][hybrid.InputError] saying what is
wrong and how to fix it. Unmapped columns are not read (except rate fields, and
a column ``quality``: rig's 0/1 flag of the samples whose w was not measured, kept
as the extra channel ``quality`` over the range, as `Recording.load` keeps it:
`quality_column`) and may hold anything.
"""

from __future__ import annotations

import dataclasses
import numbers
import os
import pathlib
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..util._errors import InputError
from ._header_units import header_unit, is_unit, time_unit
from ._loaders import (
    RATE_FIELDS,
    MissingName,
    check_file,
    path_argument,
    quality_notes,
    require_names,
    role_of,
    shell_word,
    time_factor,
)
from ._mapping_options import (
    mapping_roles,
    parse_columns,
    parse_sample_range,
    range_bounds,
    rate_argument,
    units_argument,
)
from ._recording import Recording
from ._recording_checks import (
    FILL_GAPS_MAX,
    MS_STEP_S,
    TIME_UNITS,
    UNITS,
    check_time,
    fill_gaps as fill_missing,
    fill_values,
    sample_text,
    samples_text,
    time_step,
    time_unit_guess,
)
from ._table import MAPPED_SUFFIXES, OPTION, only_column, rate_field, read_columns

__all__ = ["DEFAULT_UNITS", "RATE_RTOL", "file_references", "load_mapped", "load_pair"]

#: Units stored when neither the call nor the file's metadata gives one.
DEFAULT_UNITS: dict[str, str] = {"t": "s", "v_in": "V", "w": "a.u."}
#: Largest relative difference between two rates that still agree: of one recording (610.35 Hz, the
#: Silverbox's rate as usually quoted, against 10⁷/2¹⁴ Hz: 2.6e-6), and of the recordings `fit_batch`
#: runs at the first one's rate (time columns stored with 6 decimals put a 30 Hz recording at
#: 30.0003 Hz; a dt off by 1e-4 moves a fitted time constant by 1e-4).
RATE_RTOL: float = 1e-4


def _standard_roles(path, require_w: bool, fill: bool) -> tuple[dict[str, str], tuple] | InputError | None:
    """(``t``, ``v_in``, ``w`` mapped to themselves, `read_columns`'s result, `fill` as its) where the file has
    them (``t`` optional); else why not: the error of a reading whose columns the file has (a missing value,
    a bad cell), or of the first (the names it lacks); None where it is no file the mapped reader takes."""
    try:
        suffix = check_file(path, MAPPED_SUFFIXES)
    except InputError:
        return None
    errors: list[InputError] = []
    for roles in ({"t": "t", "v_in": "v_in", "w": "w"}, {"v_in": "v_in", "w": "w"}):
        if not require_w:
            roles = {k: v for k, v in roles.items() if k != "w"}
        try:
            return roles, read_columns(path, suffix, roles, fill=fill)
        except InputError as error:
            errors.append(error)
    return next((e for e in errors if not isinstance(e, MissingName)), errors[0])


def header_names(path) -> list[str]:
    """A text table's column names (its header's; "0", "1", … without one), read without converting its
    numbers, or [] where it is none (a .mat, a .npz) or cannot be read: the mapped read says what is wrong."""
    from ._table import text_columns

    try:
        return text_columns(pathlib.Path(path))
    except (InputError, OSError, UnicodeDecodeError, ValueError):
        return []


def load_mapped(
    path: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    *,
    input: str | None = None,
    output: str | None = None,
    columns: str | Mapping[str, str] | None = None,
    rate: float | None = None,
    sample_range: str | slice | None = None,
    time: str | None = None,
    units: Mapping[str, str] | None = None,
    name: str | None = None,
    require_w: bool = True,
    fill_gaps: int | None = None,
    default_units: Mapping[str, str] | None = None,
) -> Recording:
    """Read a file whose columns have the lab's names; see the module's rules.

    Arguments:
        path: a ``.csv`` (with an optional ``<file>.csv.json`` sidecar), ``.npz``, ``.mat``, ``.txt`` or
            ``.dat`` file; or a list of files joined into one record (each name ``FILE`` or ``FILE:COLUMN``).
        input: the drive's column (-> ``v_in``).
        output: the measured output's column (-> ``w``).
        columns: the whole mapping in one string, ``"input=uEst,output=yEst"``, or as a dict,
            ``{"input": "uEst", "output": "yEst"}``.
        rate: sampling rate, Hz, when there is no time column (or to check one).
        sample_range: ``"start:stop"`` in samples from 0, either side optional.
        time: a time column (-> ``t``), in seconds unless ``units["t"]`` says otherwise.
        units: unit labels by role (``t``/``time``, ``v_in``/``input``, ``w``/``output``).
        name: how messages refer to the recording; default the path and the mapping.
        require_w: False to allow no output (``w`` is then zeros), as `Recording.load`.
        fill_gaps: fill each gap of the time column of at most this many missing frames (1 to
            `FILL_GAPS_MAX`) by straight lines in every column (`fill_gaps`), and each run of at most
            this many missing values (empty or non-finite cells) of the drive or output by straight
            lines between the values either side (`fill_values`); default: refuse them.
        default_units: the units, by channel (``v_in``, ``w``), of a channel whose unit nothing
            (``units``, the file, its names) states; default V and a.u., or V and mm for the project's own
            columns. `load_pair` reads a validation record in its estimation record's units so.

    Returns:
        The validated recording; ``metadata`` holds ``units``, ``mapping`` (role -> the
        file's name), ``rate_hz`` and ``rate_from``, ``segment`` for a sample range, and
        ``filled`` where samples were filled: ``samples`` (every sample with a filled value), with
        ``gaps`` and ``frames`` where gaps were filled, ``runs`` and ``values`` (by channel, ``v_in``
        and ``w``, the samples whose value was filled) where missing values were.
    """
    several = isinstance(path, (list, tuple))
    given = path if isinstance(path, (list, tuple)) else [path]
    paths = [path_argument(p, "load_mapped") for p in given]
    if not paths:
        raise InputError("load_mapped got an empty list of files: give a file, or the files of one record")
    if fill_gaps is not None and (
        isinstance(fill_gaps, bool)
        or not isinstance(fill_gaps, (int, np.integer))
        or not 1 <= fill_gaps <= FILL_GAPS_MAX
    ):
        raise InputError(
            f"load_mapped got fill_gaps={fill_gaps!r}: give the most missing frames (or values) in a row to "
            f"fill, a whole number from 1 to {FILL_GAPS_MAX} (a longer gap is cut, not guessed), or leave it out"
        )
    fill = fill_gaps is not None  # missing values of the drive and output are read as NaN, then filled
    read = None  # the file's columns, where finding its roles already read them
    defaults = DEFAULT_UNITS  # a lab's columns: nothing says what w is
    try:
        roles = mapping_roles(input=input, output=output, time=time, columns=columns, require_w=require_w)
    except InputError:
        # only --units, --range, --rate or a name: a file with the standard columns maps them itself
        standard = None
        if all(x is None for x in (input, output, time, columns)) and len(paths) == 1:
            if not paths[0].exists():  # a wrong path, not a missing mapping (a probe's --units on a typo)
                check_file(paths[0], MAPPED_SUFFIXES)
            standard = _standard_roles(paths[0], require_w, fill)
        if standard is None:
            raise
        # no mapping given: every name the file lacks and a mapping of its own, or what is wrong in it
        if isinstance(standard, MissingName) and (header := header_names(paths[0])):
            require_names(paths[0], header, "column(s)")
        if isinstance(standard, InputError):
            raise standard from None
        roles, read = standard
        defaults = UNITS  # the project's own columns, as `Recording.load` reads them (V, mm)
    if set(roles.items()) >= {("v_in", "v_in"), ("w", "w")} and roles.get("t", "t") == "t":
        # the project's own columns mapped by name (t=t,input=v_in,output=w): read as unmapped (a probe's
        # file read "in mm" unmapped and "in a.u." mapped, and its --test record's units row then refused)
        defaults = UNITS
    rate_arg = rate_argument(rate)
    given_units = units_argument(units, "t" in roles)
    bounds = parse_sample_range(sample_range)
    if name is not None and (not isinstance(name, str) or not name.strip()):
        raise InputError(f"load_mapped got name {name!r}: give a non-empty string or leave it out")
    references = file_references(roles, paths)
    lines = None  # the file line of each sample, for messages
    quality = None  # a single file's rig quality column (`quality_column`)
    notes: list[str] = []
    # the columns read but not mapped, as a flag names them and as a message does: a likely time column
    unmapped: list[tuple[str, str, str]] = []  # (the flag's value, the column's name, how a message says it)
    if references:
        data, fields, file_meta, notes, headers = _read_joined(references, fill)
        path = " + ".join(str(p) for p in dict.fromkeys(p for p, _ in references.values()))  # for messages
        mapped = set(references.values())
        unmapped = [
            (f"{file}:{c}", c, f"the column '{c}' of '{file}'")
            for file, columns in headers.items()
            for c in columns
            if (file, c) not in mapped
        ]
    elif several and len(paths) > 1:
        raise InputError(
            f"load_mapped got {len(paths)} files, and the mapping names none of them: join them by naming each "
            f"role's file, e.g. input={paths[0]},output={paths[1]} (FILE:COLUMN for a column of a wider file)"
        )
    else:
        path = paths[0]
        suffix = check_file(path, MAPPED_SUFFIXES)
        data, fields, file_meta, table = read or read_columns(path, suffix, roles, fill=fill)
        lines, notes = table.lines, list(table.notes)
        unmapped = [(c, c, f"its column '{c}'") for c in table.columns if c not in roles.values()]
        if QUALITY in table.columns and QUALITY not in roles.values():
            quality = quality_column(path, suffix, roles, fill, len(data["v_in"]))
    lengths = {role: len(values) for role, values in data.items()}
    if len(set(lengths.values())) > 1:
        listed = ", ".join(f"the {OPTION[r]} '{roles[r]}' has {k}" for r, k in lengths.items())
        fix = (
            "join files of one record, one value per sample in each (cut them to the same samples)"
            if references
            else "map columns of one record, of one length"
        )
        raise InputError(f"recording '{path}': {listed} values: {fix}")
    n = lengths["v_in"]
    start, stop = range_bounds(path, sample_range, bounds, n)
    ranged = (start, stop) != (0, n)
    label = (
        name.strip()
        if name
        else (
            (f"{path} (" if not references else "")
            + f"{roles['v_in']} -> {roles.get('w', 'no output')}"
            + (f", samples {start}:{stop}" if ranged else "")
            + (")" if not references else "")
        )
    )
    names = {role: (references[role][1] or "") if references else roles[role] for role in roles}
    t = None
    grid: np.ndarray | None = None  # t as the Recording will hold it (a jittered one rebuilt)
    jitter = 0.0  # the largest timestamp jitter of a rebuilt time base, s
    if lines is not None:
        lines = lines[start:stop]
    signals: dict[str, np.ndarray] = {role: data[role][start:stop] for role in ("v_in", "w") if role in data}
    if quality is not None:
        quality = quality[start:stop]
    filled = np.zeros(0, int)  # the frames put in the time column's gaps
    values: dict[str, np.ndarray] = {}  # role -> its samples whose missing value was filled
    if fill_gaps:
        said = {role: f"column '{roles[role]}' (mapped as {OPTION[role]})" for role in signals}
        at = data["t"][start:stop] if "t" in data else None  # as read: a line's scale does not matter
        signals, values = fill_values(label, at, signals, int(fill_gaps), lines, said, start)
    runs = {role: int(np.count_nonzero(np.diff(k) != 1)) + 1 for role, k in values.items()}  # before gaps
    if "t" in data:
        file_units = file_meta.get("units")  # by column name: a units row under the header, or a sidecar's
        stated = file_units.get(roles["t"]) if isinstance(file_units, Mapping) else None
        declared = "t" in given_units or isinstance(stated, str)  # in seconds unless its unit is given
        dates = "start_time" in file_meta and not references
        if dates:  # date-times, read as seconds (`Clock`)
            if given_units.get("t", "s") != "s":
                raise InputError(
                    f"recording '{path}' has date-times in its time column '{roles['t']}', read in "
                    f"seconds: leave t={given_units['t']} out of the units"
                )
            given_units["t"], declared = "s", True
        named = None if dates else _time_unit_of_name(path, names["t"], declared)
        if "t" in given_units:
            unit = given_units.pop("t")
            where = "--units (units=)"
        elif isinstance(stated, str):
            unit, where = stated, "the file's units"
        else:
            unit, where = named or "s", ""
        factor = time_factor(path, unit, where) if where else TIME_UNITS[unit]
        if named is not None and where and TIME_UNITS.get(named) != factor:
            notes.append(
                f"recording '{path}': the time column's name '{names['t']}' says {named}, but {where} "
                f"gives {unit}: read in {unit}"
            )
        elif named is not None and not where and named != "s":
            notes.append(
                f"recording '{path}': the time column '{names['t']}' read in {named}, as its name says"
            )
        declared = declared or named is not None
        t = data["t"][start:stop] * factor
        step = float(np.median(np.diff(t)))
        if not declared and step >= MS_STEP_S:
            looks, may_be = time_unit_guess(step)
            raise InputError(
                f"recording '{label}' has a time column '{roles['t']}' stepping by {step:.4g}: it "
                f"looks like {looks}: give its unit, --units {' or '.join(f't={u}' for u in may_be)} "
                "(units= in Python; t=s for a recording really sampled this slowly)"
            )
        if not declared and step >= 1.0 and abs(step - round(step)) <= 1e-9 * step:
            # a logger's millisecond counter at 200 Hz or 1 kHz steps by 5 or 1: read as a slow recording in
            # seconds (a probe's 1.5 Hz plant fitted at 0.0015 Hz, exit 0); a whole second per step can be
            # a slow logger's own, so it is said, not refused
            notes.append(
                f"recording '{label}': its time column '{roles['t']}' has no unit and steps by {step:g}: read "
                f"in seconds ({1 / step:.3g} Hz); if it counts milliseconds ({1e3 / step:.4g} Hz), give "
                "--units t=ms (units= in Python), or t=s to say it is seconds"
            )
        if fill_gaps:
            t, signals, lines, filled = fill_missing(label, t, signals, int(fill_gaps), lines)
            kept = np.setdiff1d(np.arange(t.size), filled)  # where each sample read went
            values = {role: kept[k] for role, k in values.items()}
            if quality is not None:  # a frame put in a gap was not measured: quality 0, as rig marks one
                quality = _placed(t.size, kept, quality)
        # the checks the Recording makes, here with the file's lines; the rate is the grid's
        grid, base = check_time(label, t, {"units": {"t": "s"}}, lines)
        jitter = float(base["jitter_max_s"]) if base is not None else 0.0
    hz, rate_from = _resolve_rate(label, rate_arg, grid, fields, file_meta, jitter)
    if t is None:
        if hz is None:
            times = [(flag, said) for flag, c, said in unmapped if role_of(c) == "time"]
            named = (
                f"--time {shell_word(times[0][0])}; time={times[0][0]!r}" if times else "--time COLUMN; time="
            )
            raise InputError(
                f"recording '{label}' has no time column and no sampling rate: pass the rate in "
                f"Hz (--rate HZ; rate= in Python) or name a time column ({named})"
                + (f": {times[0][1]} looks like one" if times else "")
                + (f" (so does {' and '.join(said for _, said in times[1:])})" if times[1:] else "")
            )
        t = (start + np.arange(stop - start, dtype=np.float64)) / hz
        if fill_gaps and not values:
            notes.append(
                f"recording '{label}': --fill-gaps {fill_gaps} (fill_gaps={fill_gaps}) filled nothing: with no "
                f"time column its rows are read as evenly spaced at {hz:g} Hz, so a dropped frame cannot be "
                "seen; name the time column (--time COLUMN; time=) to find and fill them"
            )
    metadata = dict(file_meta)
    metadata.update(
        source=str(path),
        units=_units(
            roles, given_units, file_meta, names, notes, path, {**defaults, **(default_units or {})}
        ),
        mapping={role: roles.get(role) for role in ("t", "v_in", "w")},
        rate_hz=hz,
        rate_from=rate_from,
    )
    if ranged:
        previous = file_meta.get("segment")
        offset = int(previous.get("start", 0)) if isinstance(previous, dict) else 0
        metadata["segment"] = {"start": offset + start, "stop": offset + stop}
    if filled.size or values:
        every = np.unique(np.concatenate([filled, *values.values()]))
        record: dict[str, Any] = {"samples": [int(k) for k in every]}
        what = []
        if filled.size:
            gaps = int(np.count_nonzero(np.diff(filled) != 1)) + 1
            record.update(gaps=gaps, frames=int(filled.size))
            what.append(f"{filled.size} missing frame(s) in {gaps} gap(s)")
        if values:
            record.update(
                runs=sum(runs.values()), values={r: [int(k) for k in ks] for r, ks in values.items()}
            )
            for r, ks in values.items():
                where = samples_text(ks, lines) if ks.size > 1 else sample_text(int(ks[0]), lines)
                what.append(f"{ks.size} missing value(s) in {runs[r]} run(s) of the {OPTION[r]}, at {where},")
        metadata["filled"] = record
        if quality is not None and filled.size:  # `quality_column`: a frame put in a gap has quality 0
            counted = (
                "the frames put in the gaps have quality 0, as rig marks its own, and every fit and score "
                + (
                    "leaves them out; the values filled it counts as measured"
                    if values
                    else "leaves them out"
                )
            )
        else:
            counted = "every fit and score counts them as measured"
        notes.append(
            f"recording '{label}': {' and '.join(what)} filled by straight lines (--fill-gaps {fill_gaps}), the "
            f"first at t = {t[every[0]]:.6g} s: {counted} (metadata['filled'] lists them)"
        )
    w = signals["w"] if "w" in signals else np.zeros(len(t))
    extra = {} if quality is None else {QUALITY: quality}
    notes += quality_notes(label, quality, start)
    return Recording(t, signals["v_in"], w, extra, metadata, label, tuple(notes))


#: The name of rig's quality column (`rig record`, `rig track`: 1 where w was measured, 0 where not).
QUALITY = "quality"


def quality_column(path, suffix: str, roles: Mapping[str, str], fill: bool, n: int) -> np.ndarray | None:
    """A file's unmapped ``quality`` column where it is rig's 0/1 flag, one value per sample; else None.

    A mapped read takes only the columns it is told, so `diagnose` and `fit` lost
    the flag whenever a flag (``--range``, ``--units``) mapped the file, and fitted
    rig's held frames as measured without a word. Read with the mapped columns
    (the same data lines); a column that cannot be read so, or holds anything
    but 0 and 1, is not rig's: None, as before.
    """
    try:
        values = read_columns(path, suffix, {**roles, QUALITY: QUALITY}, fill=fill)[0][QUALITY]
    except (InputError, KeyError, ValueError):
        return None
    values = np.asarray(values, np.float64)
    if values.shape != (n,) or not np.isin(values, (0.0, 1.0)).all():
        return None
    return values


def _placed(size: int, at: np.ndarray, values: np.ndarray) -> np.ndarray:
    """An array of `size` zeros with `values` at the indices `at`."""
    out = np.zeros(size)
    out[at] = values
    return out


def file_references(
    roles: Mapping[str, str], paths: Sequence[str | pathlib.Path]
) -> dict[str, tuple[pathlib.Path, str | None]]:
    """Role -> (file, column or None for its only column) when the mapping names files; {} when it names none.

    A name refers to a file when it is one of `paths` as given, the same file, or the
    file's name alone (one file of that name among `paths`); ``FILE:COLUMN`` names a
    column of it. When one name refers to a file, every name must, and every file
    of `paths` must be named.
    """
    files = [pathlib.Path(p) for p in paths]
    found: dict[str, tuple[pathlib.Path, str | None]] = {}
    for role, value in roles.items():
        target = _named_file(value, files)
        if target is not None:
            found[role] = (target, None)
            continue
        head, colon, column = value.rpartition(":")
        target = _named_file(head, files) if colon else None
        if target is not None:
            if not column.strip():
                raise InputError(
                    f"the {OPTION[role]} '{value}' names no column after ':': give one (by name, or by number "
                    f"from 0), e.g. {OPTION[role]}={head}:0, or leave ':' out for a file of one column"
                )
            found[role] = (target, column.strip())
    if not found:
        return {}
    listed = ", ".join(str(p) for p in files)
    for role, value in roles.items():
        if role not in found:
            raise InputError(
                f"the {OPTION[role]} '{value}' names none of the files ({listed}) while the "
                f"{OPTION[next(iter(found))]} names one: name each role's file, {OPTION[role]}=FILE "
                f"(a file of one column) or {OPTION[role]}=FILE:COLUMN"
            )
    used = {p for p, _ in found.values()}
    for p in files:
        if p not in used:
            named = ",".join(f"{OPTION[r]}={roles[r]}" for r in found)
            raise InputError(
                f"file '{p}' is given but the mapping ({named}) names none of its columns: the files it "
                "names are joined into one record; drop the file, or name it in the mapping"
            )
    return found


def _named_file(text: str, paths: Sequence[pathlib.Path]) -> pathlib.Path | None:
    """The path among `paths` that `text` names (as given, the same file, or its name alone), or None."""
    text = text.strip()
    if not text:
        return None
    for p in paths:
        if text == str(p) or pathlib.Path(text) == p:
            return p
    candidate = pathlib.Path(text)
    if candidate.exists():
        for p in paths:
            try:
                if p.exists() and os.path.samefile(candidate, p):
                    return p
            except OSError:
                continue
    same_name = [p for p in paths if p.name == text]
    if len(same_name) > 1:
        raise InputError(
            f"'{text}' names {len(same_name)} files ({', '.join(str(p) for p in same_name)}): give the path "
            "as on the command line"
        )
    return same_name[0] if same_name else None


def _read_joined(
    references: Mapping[str, tuple[pathlib.Path, str | None]], fill: bool = False
) -> tuple[
    dict[str, np.ndarray], dict[str, np.ndarray], dict, list[str], dict[pathlib.Path, tuple[str, ...]]
]:
    """The columns of several files, one role each (or several of one file), their rate fields, metadata,
    notes (what reading each file did: a preamble skipped, a footer) and the column names of each file
    read by column (for a message that names a likely time column); `fill` as `read_columns`'s."""
    data: dict[str, np.ndarray] = {}
    fields: dict[str, np.ndarray] = {}
    metadata: dict = {}
    notes: list[str] = []
    headers: dict[pathlib.Path, tuple[str, ...]] = {}
    for file in dict.fromkeys(p for p, _ in references.values()):
        suffix = check_file(file, MAPPED_SUFFIXES)
        named = {role: column for role, (p, column) in references.items() if p == file and column is not None}
        for role, (p, column) in references.items():
            if p == file and column is None:
                data[role], read = only_column(file, suffix, role, str(file), fill)
                notes += read
        if named:
            columns, found, meta, table = read_columns(file, suffix, named, f"{file}:", fill)
            notes += table.notes
            headers[file] = table.columns
            data.update(columns)
            fields.update({k: v for k, v in found.items() if k not in fields})
            metadata = {**meta, **metadata}
    return {role: data[role] for role in references}, fields, metadata, list(dict.fromkeys(notes)), headers


def load_pair(
    path: str | pathlib.Path,
    *,
    test_input: str | None = None,
    test_output: str | None = None,
    test_columns: str | Mapping[str, str] | None = None,
    test_sample_range: str | slice | None = None,
    test_path: str | pathlib.Path | None = None,
    **options: Any,
) -> tuple[Recording, Recording]:
    """A benchmark's estimation and validation records, e.g. Cascaded Tanks'
    ``uEst -> yEst`` and ``uVal -> yVal``, or two sample ranges of the Silverbox.

    Arguments:
        path: the file of the estimation record.
        test_input: the validation record's input column; default the estimation's.
        test_output: the validation record's output column; default the estimation's.
        test_columns: the validation record's mapping in the ``columns`` grammar
            (``"input=uVal,output=yVal"``, or a dict; a ``time`` role too); the roles it names
            replace the estimation's, each role given once here and in ``test_input``/``test_output``.
        test_sample_range: the validation record's samples; default all of them
            (``sample_range`` is the estimation record's only).
        test_path: the validation record's file; default ``path``.
        options: the estimation record's options of `load_mapped`; all but
            ``sample_range`` and ``name`` apply to the validation record too.

    Returns:
        ``(estimation, validation)``.
    """
    estimation = load_mapped(path, **options)
    roles = mapping_roles(
        **{k: options.get(k) for k in ("input", "output", "time", "columns")},
        require_w=options.get("require_w", True),
    )
    if all(x is None for x in (test_input, test_output, test_columns, test_sample_range, test_path)):
        raise InputError(
            f"recording '{estimation.name}' has no validation record: give its columns (test_input=, "
            "test_output= or test_columns=; --test-columns on the command line), its samples "
            "(test_sample_range=; --test-range) or its file (test_path=; --test FILE)"
        )
    given = parse_columns(test_columns) if test_columns is not None else {}
    for channel, value in (("v_in", test_input), ("w", test_output)):
        if value is not None and channel in given:
            raise InputError(
                f"the validation record's {OPTION[channel]} column is given twice, as {value!r} and in "
                f"its columns ({given[channel]!r}): give it once"
            )
        if value is not None:
            given[channel] = value
    units = estimation.metadata["units"]
    test = {
        **options,
        # what its file does not state is in the estimation record's units (a probe's u,y file read in
        # a.u. beside an estimation record in the project's own columns, in mm, and was refused)
        "default_units": {c: str(units[c]) for c in ("v_in", "w") if c in units},
        "columns": None,
        "sample_range": test_sample_range,
        "name": None,
        "input": given.get("v_in", roles["v_in"]),
        "output": given.get("w", roles.get("w")),
        "time": given.get("t", roles.get("t")),
    }
    test_file = path if test_path is None else test_path
    try:
        validation = load_mapped(test_file, **test)
    except MissingName as error:
        # The estimation's time column, not named for the validation record, is not in its file (a
        # probe's u,y file was offered --test-columns input=u,output=y, and then refused for that): read it
        # at the estimation's rate, as a record sampled alike, and say so.
        if error.role != "t" or "t" in given or test["time"] is None:
            raise
        validation = load_mapped(test_file, **{**test, "time": None, "rate": estimation.rate})
        note = (
            f"recording '{validation.name}': no time column ({test['time']!r} is the estimation record's): read "
            f"at {estimation.rate:.6g} Hz, the estimation record's rate"
        )
        validation = dataclasses.replace(validation, notes=(*validation.notes, note))

    def same(r: Recording) -> tuple:
        return r.metadata["source"], r.metadata["mapping"], r.metadata.get("segment")

    if same(validation) == same(estimation):
        raise InputError(
            f"recording '{estimation.name}': the validation record is the estimation record "
            "(same file, columns and samples): give other columns or another sample range"
        )
    return estimation, validation


def _units(
    roles: Mapping[str, str],
    given: Mapping[str, str],
    file_meta: Mapping,
    names: Mapping[str, str],
    notes: list[str],
    path: object,
    defaults: Mapping[str, str] = DEFAULT_UNITS,
) -> dict[str, str]:
    """The units by channel: given, else the file's (by column, then role), else the column name's
    (`header_unit`), else `defaults`; a name's unit that differs from the one kept goes into `notes`."""
    declared = file_meta.get("units")
    declared = declared if isinstance(declared, Mapping) else {}
    out = {"t": "s"}
    # units taken from the file (its source, what), said in a note as an unmapped file's units row is
    read: list[tuple[str, str]] = []
    for channel in ("v_in", "w"):
        written = header_unit(names.get(channel, ""))
        named = written[0] if written is not None and is_unit(written[0]) else None
        found = [given.get(channel), declared.get(roles.get(channel, "")), declared.get(channel)]
        explicit = next((u for u in found if isinstance(u, str) and u), None)
        out[channel] = explicit or named or defaults[channel]
        if explicit and named and explicit != named:
            where = "--units (units=)" if given.get(channel) else "the file's units"
            notes.append(
                f"recording '{path}': the {OPTION[channel]}'s name '{names[channel]}' says {named}, but "
                f"{where} gives {explicit}: {explicit} kept"
            )
        elif not given.get(channel) and (explicit or named):
            source = "its units row (or sidecar)" if explicit else "its column names"
            read.append((source, f"{OPTION[channel]} in {out[channel]}"))
    if read:
        said = "; ".join(
            f"from {source}: " + ", ".join(what for s, what in read if s == source)
            for source in dict.fromkeys(s for s, _ in read)
        )
        notes.append(f"recording '{path}': units read {said} (--units to say otherwise)")
    return out


def _time_unit_of_name(path: object, name: str, given: bool) -> str | None:
    """The time unit (a `TIME_UNITS` key) a time column's name gives (``Time [ms]``), or None.

    Brackets holding anything but a time unit are refused unless the unit is `given`;
    ``name/word`` where the word is no unit (``Date/Time``) is a name.
    """
    written = header_unit(name)
    if written is None:
        return None
    text, bracketed = written
    unit = time_unit(text)
    if unit is not None or given or not (bracketed or is_unit(text)):
        return unit
    raise InputError(
        f"recording '{path}' has the time column '{name}', whose name gives it the unit {text!r}, "
        f"not a time unit ({', '.join(TIME_UNITS)}): if it counts samples, leave --time out and give "
        "the rate (--rate HZ; rate=); else give its unit (--units t=ms; units=)"
    )


def _resolve_rate(
    label: str,
    rate: float | None,
    t: np.ndarray | None,
    fields: Mapping[str, np.ndarray],
    metadata: Mapping,
    jitter: float = 0.0,
) -> tuple[float | None, str]:
    """The sampling rate and where it came from; every source must agree within RATE_RTOL.

    The time column's rate is its grid's (`time_step`: for a grid rebuilt from jittered
    timestamps, the least-squares line's); another rate agrees with it within RATE_RTOL or
    within the `jitter` (the drift over the record that the largest jitter allows).
    """
    sources: list[tuple[str, float]] = []
    tolerance = RATE_RTOL
    if t is not None and len(t) > 1:
        step = time_step(t)
        if step > 0:
            sources.append((f"the time column (step {step:.6g} s)", 1.0 / step))
            tolerance = max(RATE_RTOL, jitter / float(t[-1] - t[0]))
    found = [(f"the file's '{k}' field", rate_field(v), k) for k, v in fields.items()]
    for k, v in metadata.items():
        if isinstance(k, str) and k.lower() in RATE_FIELDS:
            number = isinstance(v, numbers.Real) and not isinstance(v, bool)
            found.append((f"metadata '{k}'", rate_field(v) if number else None, k))
    for where, value, key in found:
        if value is not None:
            unit = RATE_FIELDS[key.rsplit(".", 1)[-1].lower()]  # a struct's field: data.fs
            sources.append((f"{where} ({value:.6g} {unit})", value if unit == "Hz" else 1.0 / value))
    if rate is not None:
        sources.append(("the rate given", rate))
    if not sources:
        return None, ""
    first_where, first = sources[0]
    for where, hz in sources[1:]:
        if abs(hz - first) > tolerance * first:
            hint = (
                " (is the time column in milliseconds? give units {'t': 'ms'})"
                if t is not None and 9e-4 < first / hz < 1.1e-3
                else ""
            )
            raise InputError(
                f"recording '{label}' has sampling rates that disagree: {first_where} says "
                f"{first:.6g} Hz, {where} says {hz:.6g} Hz{hint}: give one rate, or make them agree"
            )
    return first, first_where
