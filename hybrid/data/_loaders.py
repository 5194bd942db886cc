"""Reading recording files: ``.csv`` (with a ``<file>.csv.json`` metadata
sidecar), ``.npz`` and ``.mat``.

`read_file` (behind `Recording.load
<hybrid.data._recording.Recording.load>`) checks the path, picks the reader by
suffix (`SUFFIXES`) and returns the file's channels and metadata, for
[`Recording`][hybrid.Recording] to validate. The naming shared with
`hybrid.data._writers` (suffixes, sidecar, ``extra_`` prefix) lives here.

Messages about CSV files give the line in the file (from 1) and the sample (from 0):
``line 14 (sample 12)``.
"""

from __future__ import annotations

import datetime
import difflib
import json
import math
import os
import pathlib
import re
import zipfile
from collections.abc import Collection, Mapping, Sequence
from typing import Any

import numpy as np

from ..util._errors import InputError
from ._header_units import is_unit
from ._recording_checks import (
    FILL_VALUES_HINT,
    REQUIRED,
    TIME_UNITS,
    UNITS,
    columns_flag,
    range_flag,
    samples_text,
)

__all__ = [
    "FOOTER_LINES",
    "MissingName",
    "require_names",
    "PREAMBLE_LINES",
    "RATE_FIELDS",
    "CSV_SUFFIXES",
    "SHEET_SUFFIXES",
    "SUFFIXES",
    "TEXT_SUFFIXES",
    "Clock",
    "check_file",
    "DECIMAL_COMMA",
    "comma_separated",
    "csv_text",
    "cut_cells",
    "commented_header",
    "decode_text",
    "find_header",
    "is_time_unit",
    "header_fields",
    "footer_start",
    "is_number",
    "is_value",
    "mapping_example",
    "spaced_cells_message",
    "mat_variables",
    "matrix_columns",
    "npy_table",
    "npz_arrays",
    "read_file",
    "sheet_text",
    "sidecar",
    "table_text",
    "table_start",
    "time_factor",
    "units_row",
]

#: File suffixes `Recording.load` and `Recording.save` understand.
SUFFIXES: tuple[str, ...] = (".csv", ".npz", ".mat")
#: Excel workbooks, read (not written) as their first sheet's table, like a CSV (`sheet_text`).
SHEET_SUFFIXES: tuple[str, ...] = (".xlsx", ".xlsm")
#: What the CSV readers read: a CSV file, or a workbook's sheet as one (`csv_text`).
CSV_SUFFIXES: tuple[str, ...] = (".csv", *SHEET_SUFFIXES)
#: Suffixes of plain text tables, read through a mapping only (`hybrid.data._table.read_text_table`):
#: a logger's ``.txt``/``.dat``, tab-separated ``.tsv``, and LabVIEW's measurement file ``.lvm`` (a
#: preamble, then a tab-separated table).
TEXT_SUFFIXES: tuple[str, ...] = (".txt", ".dat", ".tsv", ".lvm")

NPZ_EXTRA = "extra_"

#: Column, array or metadata names (any case) read as the sampling rate (Hz) or the
#: sampling period (s) when they are not mapped: a single positive number, or a column
#: whose first row holds it and whose other rows are empty, NaN or the same number
#: (the Cascaded Tanks file's ``Ts``). Anything else under these names is ignored.
RATE_FIELDS: dict[str, str] = {
    "fs": "Hz",
    "rate": "Hz",
    "rate_hz": "Hz",
    "sample_rate": "Hz",
    "sampling_rate": "Hz",
    "ts": "s",
    "increment": "s",  # a Rigol oscilloscope's sampling period (`header_fields`)
    "delta_x": "s",  # a LabVIEW measurement file's, where it writes no time column (`lvm_period`)
    "dt": "s",
    "dt_s": "s",
    "sample_time": "s",
    "sampling_time": "s",
}


def read_file(
    path: pathlib.Path, *, require_w: bool = True
) -> tuple[dict[str, np.ndarray], dict, tuple[str, ...], np.ndarray | None]:
    """Read the channels and metadata of a recording file; see `Recording.load`.

    Arguments:
        path: the file; its suffix picks the format.
        require_w: False to accept a file without ``w``, which is then filled
            with zeros.

    Returns:
        ``(columns, metadata, notes, lines)``: every channel by name (t, v_in and w
        first as found in the file), the metadata, with ``"source"`` set to
        ``path`` when missing, a sentence for each thing done to the file (a CSV
        column of text beside the signals left out, a preamble or a footer
        skipped), and the file line (from 1) of each sample of a CSV file (None
        for the others).
    """
    suffix = check_file(path, (*SUFFIXES, *SHEET_SUFFIXES))
    required = REQUIRED if require_w else REQUIRED[:2]
    notes: tuple[str, ...] = ()
    lines = None
    if suffix in CSV_SUFFIXES:
        columns, metadata, notes, lines = _load_csv(path, required)
    else:
        columns, metadata, notes = (_load_npz if suffix == ".npz" else _load_mat)(path, required)
    # every format's quality note (a verifier's .npz had none)
    notes = (*notes, *quality_notes(path, columns.get("quality")))
    if "w" not in columns:
        columns["w"] = np.zeros_like(columns["t"])
    metadata.setdefault("source", str(path))
    return columns, metadata, notes, lines


# --------------------------------------------------------------------------- #
# Paths and shared checks
# --------------------------------------------------------------------------- #


def check_file(path: pathlib.Path, suffixes: Sequence[str] = SUFFIXES) -> str:
    """Require a non-empty file with a known suffix (one of `suffixes`); return the suffix, lower case."""
    suffix = file_suffix(path, suffixes)
    if not path.exists():
        raise InputError(f"recording file '{path}' does not exist: check the path")
    if not path.is_file():
        raise InputError(f"recording file '{path}' is not a file: give a file path")
    if path.stat().st_size == 0:
        raise InputError(f"recording file '{path}' is empty: give a file with a header and data")
    return suffix


def file_suffix(path: pathlib.Path, suffixes: Sequence[str] = SUFFIXES) -> str:
    suffix = path.suffix.lower()
    if suffix not in suffixes:
        hint = ""
        if suffix == ".lvm" and suffix not in suffixes:  # LabVIEW's: a preamble, then a tab-separated table
            hint = (
                " (a LabVIEW measurement file is read with its columns mapped, its header blocks skipped, "
                'e.g. --columns input=Untitled,output="Untitled 1" --time X_Value)'
            )
        elif suffix in TEXT_SUFFIXES and suffix not in suffixes:
            hint = (
                " (a text table is read with its columns mapped: --columns input=COLUMN,output=COLUMN "
                "--rate HZ, or one file per channel: --columns input=u.txt,output=y.txt)"
            )
        elif suffix == ".npy" and suffix not in suffixes:
            hint = (
                " (a numpy array is read with its columns mapped by number from 0, e.g. --columns "
                "input=1,output=2 --time 0, or by field name for a structured array)"
            )
        elif suffix in SHEET_SUFFIXES and suffix not in suffixes:
            hint = " (an Excel workbook is read by hybrid fit, diagnose and Recording.load, not written)"
        elif suffix in (".xls", ".ods"):
            hint = " (an older or another spreadsheet's workbook: save the sheet as .xlsx or as CSV, and give that)"
        raise InputError(
            f"recording '{path}' has unknown suffix '{path.suffix}': use " + ", ".join(suffixes) + hint
        )
    return suffix


def sidecar(path: str | pathlib.Path) -> pathlib.Path:
    """The metadata sidecar of a CSV recording: ``run.csv`` -> ``run.csv.json``."""
    path = pathlib.Path(path)
    return path.with_name(path.name + ".json")


class MissingName(InputError):
    """A name (a column, a variable) the file lacks; `role` is the one it was for (``t``, ``v_in``, ``w``)."""

    def __init__(self, message: str, role: str):
        super().__init__(message)
        self.role = role


def path_argument(path: Any, where: str) -> pathlib.Path:
    """``path`` as a Path; anything but a str or os.PathLike is an InputError."""
    if not isinstance(path, (str, os.PathLike)) or not str(path).strip():
        raise InputError(
            f"{where} needs a file path (str or pathlib.Path), got {path!r}: give e.g. 'run.csv'"
        )
    return pathlib.Path(path)


def require_names(
    path: pathlib.Path,
    found: Sequence[str],
    kind: str,
    required: Sequence[str] = REQUIRED,
    example: str = "",
) -> None:
    """Refuse a file without the `required` names, with the mapping `example` (default: what its names
    suggest, `mapping_example`)."""
    missing = [c for c in required if c not in found]
    if missing and len(found) > 1 and all(is_value(c) for c in found):
        # no header: the first line is a sample (the mapped reader names such columns by number)
        names = ",".join(required)
        example = (
            "--columns input=1,output=2 --time 0"
            if len(found) > 2
            else "--columns input=0,output=1 --rate HZ"
        )
        if "w" not in required:
            raise InputError(
                f"'{path}' has no header: its first line holds numbers ({', '.join(found)}); add a header "
                f"line {names} above them, as hybrid design writes a drive"
            )
        raise InputError(
            f"recording '{path}' has no header: its first line holds numbers ({', '.join(found)}); add a "
            f"header line {names} above them, or name the columns by number from 0, e.g. {example}"
        )
    if missing:
        shown = ", ".join(f"'{c}'" if c else "an unnamed one" for c in found) or "none"
        if "w" not in required:  # a drive alone (a --drive-file): the command takes no column mapping
            raise InputError(
                f"'{path}' is missing {kind} {', '.join(missing)} (found {shown}): name them exactly "
                f"{' and '.join(required)} (case-sensitive), as hybrid design writes a drive"
            )
        raise MissingName(
            f"recording '{path}' is missing {kind} {', '.join(missing)} (found "
            f"{shown}): name them exactly t, v_in and w (case-sensitive), or say which of "
            f"yours are which, e.g. {example or mapping_example(list(found))}",
            missing[0],
        )


#: What a cell of a units row may hold: a short unit (s, V, mm, µm, rad/s, m/s^2, °C, %).
_UNIT = re.compile(r"^[A-Za-zµμ°%Ω/^*·.\d\s-]{1,16}$")
#: How spreadsheets and loggers write a missing value (never a unit).
_MISSING = frozenset({"na", "n/a", "nan", "null", "none", "-", "--", "#n/a"})
#: Spellings of the time units `TIME_UNITS` knows.
_TIME_SPELLINGS = {"sec": "s", "secs": "s", "second": "s", "seconds": "s", "msec": "ms", "μs": "µs"}


def units_row(cells: Sequence[str]) -> list[str] | None:
    """The units a line under the header gives, one per cell ('' where none), or None when it holds data.

    A units row (a data logger's or spreadsheet's second header line: ``s,V,mm`` or
    ``(s),[V],(µm)``) has no number in any cell, at least one unit, and only short
    unit-like cells; brackets around a unit are dropped.
    """
    cleaned = []
    for cell in cells:
        text = cell.strip().strip('"').strip()
        try:
            float(text)
            return None  # a number (or nan): a line of data
        except ValueError:
            pass
        cleaned.append(re.sub(r"^[\(\[]\s*(.*?)\s*[\)\]]$", r"\1", text))
    if not any(cleaned) or not all(_UNIT.match(c) for c in cleaned if c):
        return None
    if any(c.lower() in _MISSING for c in cleaned):  # a line of missing values, not of units
        return None
    return cleaned


#: A time of day as loggers write it beside (or without) the date: ``10:15:32`` or ``10:15:32.125``.
TIME_OF_DAY = re.compile(r"(\d{1,2}):(\d{2}):(\d{2}(?:\.\d+)?)")


def _seconds_of_day(text: str) -> float | None:
    """The seconds since midnight of a `TIME_OF_DAY` cell, or None."""
    match = TIME_OF_DAY.fullmatch(text)
    if match is None:
        return None
    hours, minutes, seconds = int(match[1]), int(match[2]), float(match[3])
    if hours > 23 or minutes > 59 or seconds >= 61:
        return None
    return 3600.0 * hours + 60.0 * minutes + seconds


class Clock:
    """A time column's cells in seconds: numbers as they are, ISO 8601 date-times (a data logger's
    ``2026-12-01 10:00:00.033``) as seconds after the first date-time read, and times of day
    (``10:00:00.033``, `TIME_OF_DAY`) as seconds after the first, a day added where one falls back
    by more than 12 h (midnight passed).

    Called cell by cell in the file's order (`np.loadtxt`'s converter); NaN for a cell
    that is none of these, which the readers then name. `start` is the first date-time or time of day.
    """

    def __init__(self) -> None:
        self.start: datetime.datetime | datetime.time | None = None
        self._day_start: float | None = None  # the first time of day, s after midnight
        self._last = 0.0  # the last time of day read, s after the first
        self._days = 0

    def __call__(self, cell: str) -> float:
        text = cell.strip().strip('"').strip()
        try:
            return float(text)
        except ValueError:
            pass
        of_day = _seconds_of_day(text)
        if of_day is not None and not isinstance(self.start, datetime.datetime):
            if self._day_start is None:
                self._day_start = of_day
                whole = int(of_day)
                micro = round((of_day - whole) * 1e6) % 1_000_000
                self.start = datetime.time(whole // 3600, whole // 60 % 60, min(whole % 60, 59), micro)
            seconds = of_day - self._day_start + 86400.0 * self._days
            if seconds < self._last - 43200.0:  # midnight passed
                self._days += 1
                seconds += 86400.0
            self._last = seconds
            return seconds
        if isinstance(self.start, datetime.time):
            return math.nan  # a date-time among times of day
        try:
            moment = datetime.datetime.fromisoformat(text)
            if self.start is None:
                self.start = moment
            return (moment - self.start).total_seconds()
        except (ValueError, TypeError):  # not a date-time, or one with a time zone beside one without
            return math.nan

    def note(self, path: pathlib.Path | str) -> str:
        """What was read, for the recording's notes (after a date-time was read: `start` is set)."""
        assert self.start is not None
        what = "times of day" if isinstance(self.start, datetime.time) else "date-times"
        return f"recording '{path}': its time column holds {what}, read as seconds after {self.start.isoformat()}"


def is_time_unit(unit: str) -> bool:
    """Whether `unit` names a time unit `time_factor` reads (``s``, ``ms``, ``second``, ``Sec``)."""
    return _TIME_SPELLINGS.get(unit.strip().lower(), unit.strip()) in TIME_UNITS


def time_factor(path: pathlib.Path | str, unit: str, where: str) -> float:
    """Seconds per unit of a time column whose unit a file states (`where`: e.g. 'its units row')."""
    key = _TIME_SPELLINGS.get(unit.strip().lower(), unit.strip())
    if key not in TIME_UNITS:
        raise InputError(
            f"recording '{path}' gives its time column the unit {unit!r} in {where}: "
            f"write one of {', '.join(TIME_UNITS)}"
        )
    return TIME_UNITS[key]


#: Words that name a column's role in lab files (lower case, units and punctuation stripped).
_ROLE_WORDS = {
    "time": ("t", "time", "times", "timestamp", "sec", "secs", "second", "seconds", "zeit", "x_value"),
    "input": (
        "u",
        "v",
        "vin",
        "input",
        "in",
        "drive",
        "voltage",
        "volt",
        "volts",
        "cmd",
        "command",
        "excitation",
        "current",
        "curr",
    ),
    "output": ("y", "w", "output", "out", "disp", "displacement", "position", "pos", "deflection", "tip"),
    "index": (
        "n",
        "i",
        "k",
        "idx",
        "index",
        "sample",
        "samples",
        "frame",
        "frames",
        "step",
        "point",
        "record",
        "row",
    ),
}
#: Roles a word anywhere in a column's name gives (a cycler's 'Test_Time(s)', 'Data_Point'): a time and an
#: index are named so in any position; a drive or an output word counts only first ('Voltage(V)').
_ANY_TOKEN = ("time", "index")


def role_of(name: str) -> str | None:
    """The role a column's name suggests: 'Time (s)' -> time, 'uEst' -> input, 'Displacement [mm]' -> output."""
    words = re.sub(r"[\(\[].*?[\)\]]", " ", name).lower()  # units in brackets
    words = re.sub(r"(est|val|meas|measured|_?\d+)$", "", re.sub(r"[^a-z0-9]+", " ", words).strip())
    tokens = words.split()
    for role, names in _ROLE_WORDS.items():
        # t_s, v_mV, t_min, pos_deg: a name and its unit
        short_unit = len(tokens) == 2 and (len(tokens[1]) <= 2 or is_unit(tokens[1]))
        if words.replace(" ", "_") in names or (
            tokens and tokens[0] in names and (len(tokens[0]) > 2 or short_unit)
        ):
            return role
    for role in _ANY_TOKEN:
        if any(len(token) > 2 and token in _ROLE_WORDS[role] for token in tokens):
            return role
    return None


#: How alike (difflib's ratio) a column's name and the project's own name of a role must be to take that
#: role in a mapping's example before the columns' order gives it: v_inn (0.89), v_in_cmd (0.67) read as
#: the drive; w_true (0.29) not as w.
_CLOSE = 0.6


def mapping_example(
    names: Sequence[str], rate_known: bool = False, time: str | None = None, skip: Collection[str] = ()
) -> str:
    """The flags that would map a lab file's columns `names` (its header, in order), guessed from them.

    The time, the drive and the output by their names (`role_of`), else the drive and the output the
    first two columns left; a name the header holds twice by its column's number (LabVIEW's
    ``X_Value`` over each channel, a scope's ``Second,Volt,Volt``). `rate_known`: the file gives its
    rate (a field), so without a time column none is asked for; `time`: the column known to be the
    time (its unit a time's in a units row); `skip`: names that are no signal (a field, a counter).
    """
    names = list(names)
    roles: dict[str, int] = {} if time not in names else {"time": names.index(time)}
    # a measured value is no name (a channel's number, Keysight's 1 and 2, is)
    wanted = [i for i, n in enumerate(names) if n and n not in skip and (n.isdigit() or not is_value(n))]
    for i in wanted:
        role = role_of(names[i])
        if role is not None and role not in roles and i not in roles.values():
            roles[role] = i
    rest = [i for i in wanted if i not in roles.values() and role_of(names[i]) != "index"]
    # a name close to the project's own (a typo: v_inn, v_in_cmd) takes its role before column order does:
    # in t,w_true,v_inn,w the first name left, w_true, was offered as the drive
    for role, own in (("input", "v_in"), ("output", "w")):
        alike = {i: difflib.SequenceMatcher(None, names[i].lower(), own).ratio() for i in rest}
        best = max(alike, key=alike.__getitem__, default=None)
        if role not in roles and best is not None and alike[best] >= _CLOSE:
            roles[role] = best
            rest.remove(best)
    for role in ("input", "output"):
        if role not in roles and rest:
            roles[role] = rest.pop(0)
    # another record's own flag (--test-columns) takes the time's role too, and the fitted records' rate
    flag = columns_flag()
    other = flag != "--columns"
    if "input" not in roles or "output" not in roles:
        if other:
            return f"{flag} input=COLUMN,output=COLUMN (the columns by name, or by number from 0)"
        if any(n and n not in skip and not n.isdigit() and is_value(n) for n in names):
            return (  # a line of settings beside a sample, read as the header (Tektronix)
                "--columns input=N,output=M with --time K or --rate HZ, the columns by number from 0 (the "
                "line taken for its header holds numbers: a setting beside a sample?)"
            )
        return "--columns input=COLUMN,output=COLUMN with --rate HZ or --time COLUMN"
    shown = {role: str(i) if names.count(names[i]) > 1 else names[i] for role, i in roles.items()}
    mapped = ("time", "input", "output") if other else ("input", "output")
    columns = ",".join(f"{role}={shown[role]}" for role in mapped if role in shown)
    if re.search(r"[^\w.=,:-]", columns):
        columns = f'"{columns}"'  # a name with spaces or brackets: one shell word
    if other:
        return f"{flag} {columns}"
    if "time" in shown:
        return f"--columns {columns} --time {shell_word(shown['time'])}"
    if rate_known:
        return f"--columns {columns} (the rate from the file's own field)"
    return f"--columns {columns} with --rate HZ (or --time COLUMN)"


def shell_word(name: str) -> str:
    """A column's name as one word of a shell command: quoted where it has spaces or brackets."""
    return f'"{name}"' if re.search(r"[^\w.-]", name) else name


def parse_metadata(path: pathlib.Path, text: str, where: str) -> dict:
    try:
        metadata = json.loads(text)
    except ValueError as error:
        raise InputError(
            f"recording '{path}' has unreadable metadata in {where} ({error}): fix the JSON or delete it"
        ) from None
    if not isinstance(metadata, dict):
        raise InputError(
            f"recording '{path}' has metadata in {where} that is not a JSON object: write it as {{...}}"
        )
    return metadata


# ------------------------------------------------------------------- CSV


def read_text(path: pathlib.Path) -> str:
    return decode_text(path, "save it as CSV UTF-8 (Excel: Save As, 'CSV UTF-8 (Comma delimited)')")


def table_text(path: pathlib.Path) -> tuple[str, list[str]]:
    """A CSV file's text, or an Excel workbook's first sheet written as one (`sheet_text`), and notes."""
    if path.suffix.lower() in SHEET_SUFFIXES:
        return sheet_text(path)
    return read_text(path), []


def sheet_text(path: pathlib.Path) -> tuple[str, list[str]]:
    """An Excel workbook's first sheet as CSV text, to be read as a CSV file is.

    A row per line, cells between commas: numbers as Python writes them ('.' decimals,
    full precision), date-times in ISO 8601 (`Clock` reads them), empty cells empty, text
    on one line with a space for each comma in it; a formula gives the value Excel last saved
    with it (none for a file no spreadsheet has computed). Line k is the sheet's row k. A
    workbook of several sheets is read from its first, and a note says so.
    """
    import openpyxl

    try:
        book = openpyxl.load_workbook(path, read_only=True, data_only=True)
    except Exception as error:  # zipfile, XML and openpyxl's own errors for a file that is no workbook
        raise InputError(
            f"recording '{path}' is not a readable Excel workbook ({type(error).__name__}: {error}): save it "
            "from Excel as .xlsx, or as CSV"
        ) from None
    try:
        if not book.worksheets:
            raise InputError(f"recording '{path}' is a workbook without a sheet: save the data in one")
        sheet, count = book.worksheets[0], len(book.worksheets)
        lines, as_text = [], 0
        for row in sheet.iter_rows(values_only=True):
            cells = []
            for value in row:
                # a number stored as text with a decimal comma (a CSV of such a locale pasted in): a number
                number = comma_number(value.strip()) if isinstance(value, str) else None
                as_text += number is not None
                cells.append(number if number is not None else _sheet_cell(value))
            lines.append(",".join(cells))
    finally:
        book.close()
    notes = (
        [
            f"recording '{path}': read from its first sheet, {sheet.title!r}, of {count} (save the one you mean first)"
        ]
        if count > 1
        else []
    )
    if as_text:
        notes.append(
            f"recording '{path}': {as_text} cell(s) hold numbers stored as text with a decimal comma "
            "(e.g. '0,5'): read as numbers"
        )
    return "\n".join(lines), notes


def _sheet_cell(value) -> str:
    """One cell of a sheet as a CSV cell (`sheet_text`)."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return str(int(value))
    if isinstance(value, (int, float)):
        return str(value)  # a float's shortest repr: it reads back to the same double
    if isinstance(value, (datetime.datetime, datetime.date, datetime.time)):
        return value.isoformat(sep=" ") if isinstance(value, datetime.datetime) else value.isoformat()
    # a comma or a line break in a name or a label: not a separator (as `comma_separated` reads one)
    return " ".join(str(value).replace(",", " ").split())


def decode_text(path: pathlib.Path, fix: str) -> str:
    """A text file's contents (UTF-8, with or without Excel's byte-order mark).

    Other text is refused in one line naming its first byte that is not UTF-8, the
    encoding it looks like where that can be told (UTF-16; Windows-1252, Excel's
    plain "CSV" on Western-European Windows), and `fix`; a file that is not text
    at all, in one line saying what it is (`_binary_kind`).
    """
    try:
        raw = path.read_bytes()
    except OSError as error:
        raise InputError(
            f"recording '{path}' cannot be read ({error.strerror or error}): check its permissions"
        ) from None
    kind = _binary_kind(raw)
    if kind is not None:
        raise InputError(f"recording '{path}' is not text but {kind}")
    try:
        text = raw.decode("utf-8-sig")  # -sig: Excel's byte-order mark
    except UnicodeDecodeError as error:
        line = raw[: error.start].count(b"\n") + 1
        where = f"byte 0x{raw[error.start]:02X} at line {line}"
        raise InputError(
            f"recording '{path}' is not UTF-8 text ({where}{_encoding_guess(raw)}): {fix}"
        ) from None
    if "\x00" in text[:4096]:  # UTF-16 without a byte-order mark: ASCII's NULs decode as UTF-8 too
        raise InputError(
            f"recording '{path}' is not UTF-8 text (NUL bytes every other byte; it looks like UTF-16): {fix}"
        )
    return text


#: The first bytes of binary formats a lab's file may turn out to be, renamed or mistaken for a table.
_SIGNATURES = (
    (b"\x89PNG\r\n\x1a\n", "a PNG image: give the table of samples, as CSV"),
    (b"\xff\xd8\xff", "a JPEG image: give the table of samples, as CSV"),
    (b"%PDF-", "a PDF document: give the table of samples, as CSV"),
    (
        b"PK\x03\x04",
        "a ZIP archive: an Excel workbook saved under another name is one; give it its .xlsx name",
    ),
    (b"\xd0\xcf\x11\xe0\xa1\xb1\x1a\xe1", "an old Office file (an Excel .xls?): save it as .xlsx or CSV"),
    (b"\x1f\x8b", "a gzip archive: unpack it first"),
    (
        b"\x89HDF\r\n\x1a\n",
        "an HDF5 file: export the columns as CSV (a MATLAB v7.3 .mat is one: save it with -v7)",
    ),
    (b"\x93NUMPY", "a NumPy .npy array: save the columns with numpy.savez as .npz, or as CSV"),
)


def _binary_kind(raw: bytes) -> str | None:
    """What a file that should be text is instead, from its first bytes; None for (possibly) text.

    Known signatures (`_SIGNATURES`: an image, an archive, a workbook renamed);
    a file of NUL bytes only (what a power loss or a full disk leaves of a log);
    NUL bytes among the first 4 KiB that are not UTF-16's (every other byte,
    or a byte-order mark): binary data of some other kind.
    """
    for signature, kind in _SIGNATURES:
        if raw.startswith(signature):
            return kind
    head = raw[:4096]
    if head and not head.strip(b"\x00"):
        return "NUL bytes only, what a power loss or a full disk leaves of a log: record it again"
    if b"\x00" in head and not _utf16_like(head):
        return "binary data (NUL bytes among its first 4 KiB): export the columns as CSV UTF-8"
    return None


def _utf16_like(head: bytes) -> bool:
    """Whether bytes with NULs read as UTF-16: a byte-order mark, or NULs at most places of one parity."""
    if head[:2] in (b"\xff\xfe", b"\xfe\xff"):
        return True
    even, odd = head[0::2].count(0), head[1::2].count(0)
    return max(even, odd) >= 0.4 * (len(head) // 2) and min(even, odd) <= 0.05 * (len(head) // 2)


def _encoding_guess(raw: bytes) -> str:
    """``"; it looks like ..."`` naming the encoding of text that is not UTF-8, or '' when it cannot be told."""
    if _utf16_like(raw[:4096]):
        return "; it looks like UTF-16"
    try:
        raw.decode("cp1252")
    except UnicodeDecodeError:
        return ""
    return "; it looks like Windows-1252 (Western European)"


#: Lines a header is looked for in, below a logger's preamble (device, date, settings).
PREAMBLE_LINES = 50


#: Lines after the data that are taken for a logger's footer at most (`footer_start`).
FOOTER_LINES = 50
_LETTER = re.compile(r"[^\W\d_]")


def footer_start(rows: Sequence[Sequence[str]], indices: Sequence[int]) -> int:
    """The index among a table's data `rows` (split into cells) where its footer begins; ``len(rows)`` for none.

    A footer (a logger's ``End of data``, ``Total scans: 1800``) is the run of at most
    `FOOTER_LINES` lines at the end, after at least one other line, each holding a letter
    and no number (nor date-time) in any of the read columns `indices`: text, not
    samples. Lines in the middle are never taken for one.
    """
    end = len(rows)
    while end > 1 and len(rows) - end < FOOTER_LINES:
        cells = rows[end - 1]
        text = any(_LETTER.search(cell) for cell in cells)
        if not text or any(i < len(cells) and is_value(cells[i]) for i in indices):
            break
        end -= 1
    return end


def is_value(cell: str) -> bool:
    """Whether a cell holds a number, an ISO date-time or a time of day (data, not a name)."""
    text = cell.strip().strip('"').strip()
    if is_number(text) or _seconds_of_day(text) is not None:
        return True
    try:
        datetime.datetime.fromisoformat(text)
        return True
    except ValueError:
        return False


def find_header(rows: Sequence[Sequence[str]], needed: Sequence[str]) -> int:
    """The index of the header among a CSV's first `rows` (split into cells): the first that names
    every one of `needed` (an oscilloscope's or logger's preamble lines come before it); where none
    does in the first `PREAMBLE_LINES`, or none is needed, the line above the numbers (`table_start`), so that the
    header's names, not a preamble's, go into the message (or a column number is read under it)."""
    wanted = set(needed)
    for i, cells in enumerate(rows[:PREAMBLE_LINES] if wanted else ()):
        if wanted <= {cell.strip().strip('"').strip() for cell in cells}:
            return i
    return table_start(rows)


def table_start(rows: Sequence[Sequence[str]]) -> int:
    """The index of a table's first line among its `rows` (split into cells; [] for a blank line).

    The table's data begin at the first two rows of values (numbers, ISO
    date-times; empty cells between them) of one width within the first `PREAMBLE_LINES`, or at the rows
    of values right above them (a column filled in its first row alone, a note in a column after them:
    `_annotated`); its
    first line is the row above the data, its header (a units row between them
    passed over where the row above that is at least as wide), or the data's
    first row where there is none. Lines above the first line are a preamble
    (LabVIEW's header blocks, a logger's ``Device: X``). 0 where no two such
    rows come.
    """

    cells = [cut_cells(row) for row in rows[: PREAMBLE_LINES + 2]]
    # every cell a value, or empty (a column left blank)
    values = [bool(c) and all(is_value(cell) for cell in c if cell) for c in cells]
    filled = [i for i, c in enumerate(cells) if c]
    for k in range(len(filled) - 1):
        first, second = filled[k], filled[k + 1]
        if not (values[first] and values[second] and len(cells[first]) == len(cells[second])):
            continue
        width = len(cells[first])
        while k and (values[filled[k - 1]] or _annotated(cells[filled[k - 1]], width)):
            k -= 1  # rows of values above, of another width (a column filled once), or with a note beside
        if k == 0:
            return filled[0]
        header = filled[k - 1]
        above = filled[k - 2] if k >= 2 else None
        if (
            above is not None
            and units_row(rows[header]) is not None
            and not values[above]
            and len(cells[above]) >= len(cells[header])
        ):
            return above  # a header over a units row (a short header may read as units)
        return header
    return 0


def _annotated(cells: Sequence[str], width: int) -> bool:
    """Whether a row holds values in its first `width` cells and text after them: a sample with a note in
    a column the other samples leave empty (an event marker, a spreadsheet's comment column)."""
    head = [cell for cell in cells[:width] if cell]
    return len(cells) > width and bool(head) and all(is_value(cell) for cell in head)


def is_number(text: str) -> bool:
    """Whether `text` reads as a float (nan and inf included)."""
    try:
        float(text)
    except ValueError:
        return False
    return True


#: A number written with a decimal comma: 1,5 or -0,25 or ,5 or 1,5e-3.
DECIMAL_COMMA = re.compile(r"[+-]?(\d+,\d*|,\d+)([eE][+-]?\d+)?")
#: ... with its thousands grouped by '.', an apostrophe or a (non-breaking) space before the comma, as a
#: spreadsheet in such a locale shows them: -1.089,759 or 12 345,6 (the comma marks it: 1.089 alone is
#: a point-decimal number).
_GROUPED_COMMA = re.compile(r"([+-]?\d{1,3}(?:([.' \u00a0\u202f])\d{3})(?:\2\d{3})*)(,\d*)([eE][+-]?\d+)?")


def comma_number(cell: str) -> str | None:
    """`cell` (stripped) with a decimal comma written with a point, thousands separators dropped; None
    where it is not a number written with a decimal comma."""
    if DECIMAL_COMMA.fullmatch(cell):
        return cell.replace(",", ".")
    grouped = _GROUPED_COMMA.fullmatch(cell)
    if grouped is None:
        return None
    whole, _, fraction, exponent = grouped.groups()
    return re.sub(r"[.' \u00a0\u202f]", "", whole) + "." + fraction[1:] + (exponent or "")


def comma_separated(text: str) -> tuple[str, str | None]:
    """A CSV's text with its cells between commas, and what was changed (None: nothing).

    A spreadsheet saved where the comma is the decimal mark separates cells by ';'
    (or tabs): a header with one of those and no comma marks such a file. Its cells
    are joined by commas again and a number written with a decimal comma (``1,5``)
    gets a point; every line keeps its number, so messages still point into the file.
    """
    lines = text.splitlines()
    header = next(  # the first line with a delimiter: a logger's preamble ("Device: X") has none
        (
            line
            for line in lines[:PREAMBLE_LINES]
            if any(m in line for m in ",;\t") and not line.strip().startswith("#")
        ),
        "",
    )
    mark = next((m for m in (";", "\t") if m in header and "," not in header), None)
    if mark is None:
        return text, None
    decimals = grouped = 0
    out = []
    for line in lines:
        if not line.strip() or line.strip().startswith("#"):
            out.append(line)
            continue
        cells = []
        for cell in line.split(mark):
            cell = cell.strip()
            number = comma_number(cell)
            if number is not None:
                grouped += not DECIMAL_COMMA.fullmatch(cell)
                cell, decimals = number, decimals + 1
            cells.append(cell.replace(",", " "))  # a comma in a name or a label: not a separator
        out.append(",".join(cells))
    word = "';'" if mark == ";" else "tabs"
    how = f"read as cells separated by {word}" + (" with decimal commas" if decimals else "")
    return "\n".join(out), how + (f" ({grouped} with thousands separators, dropped)" if grouped else "")


def commented_header(path: pathlib.Path | str, text: str) -> tuple[str, list[str]]:
    """`text` with a header written as a comment made a header again, and a note saying so (none: [], text
    unchanged).

    numpy's ``savetxt(..., header="t,v_in,w")`` writes ``# t,v_in,w`` (its default
    ``comments="# "``), and numpy's own ``genfromtxt(names=True)`` reads that line as the
    names. So where the first line that is not blank or a comment holds values only, and
    the line right above it (blank lines between) is a comment with as many cells, not
    all values, that comment is the header. Every line keeps its number.
    """
    lines = text.splitlines()
    first = next(
        (i for i, line in enumerate(lines) if line.strip() and not line.strip().startswith("#")), None
    )
    if first is None:
        return text, []
    row = lines[first].strip()
    mark = next((m for m in (",", ";", "\t") if m in row), None)
    cells = row.split(mark)
    above = first - 1
    while above >= 0 and not lines[above].strip():
        above -= 1
    if len(cells) < 2 or not all(is_value(c) for c in cells) or above < 0:
        return text, []
    comment = lines[above].strip()
    names = [n.strip() for n in comment.lstrip("#").strip().split(mark)]
    if not comment.startswith("#") or len(names) != len(cells) or not all(names) or all(map(is_value, names)):
        return text, []
    lines[above] = comment.lstrip("#").strip()
    note = (
        f"recording '{path}': its header is the comment on line {above + 1} ({lines[above]!r}), as numpy's "
        "savetxt writes one"
    )
    return "\n".join(lines), [note]


def header_fields(path: pathlib.Path | str, text: str) -> tuple[str, dict[str, float], list[str]]:
    """`text` with the numbers a units row gives for columns that no data line fills taken out of it,
    those numbers by the header's name, and a note saying so (none: text unchanged, {}, []).

    A Rigol oscilloscope's CSV export::

        X,CH1,CH2,Start,Increment,
        Sequence,Volt,Volt,-6.000000e-03,2.000000e-06
        0,4.72e+01,2.40e+00,

    Its second line is the columns' units, then the values of the header's last names,
    which no data line fills (the first sample's time and the sampling period, s). So
    where a header is followed by such a line and then by a line of values shorter than
    both, the line keeps its units (`units_row` then reads it as one) and the numbers
    after them become fields (`RATE_FIELDS`: ``Increment`` is a sampling period).
    """
    lines = text.splitlines()
    rows = [
        (i, cut_cells(line.split(",")))
        for i, line in enumerate(lines[: PREAMBLE_LINES + 3])
        if line.strip() and not line.strip().startswith("#")
    ]
    for (_, header), (at, units), (_, data) in zip(rows, rows[1:], rows[2:]):
        width = len(data)
        if not (1 < width < len(units) <= len(header)) or not all(is_value(c) for c in data):
            continue
        names, values = header[width : len(units)], units[width:]
        if not all(names) or not all(is_number(v) for v in values) or units_row(units[:width]) is None:
            continue
        lines[at] = ",".join(units[:width])
        fields = {name: float(value) for name, value in zip(names, values)}
        listed = ", ".join(f"{name} = {value:g}" for name, value in fields.items())
        note = (
            f"recording '{path}': line {at + 1} gives the units and {listed}, the values of columns no "
            "data line fills (an oscilloscope's export)"
        )
        return "\n".join(lines), fields, [note]
    return text, {}, []


def cut_cells(cells: Sequence[str]) -> list[str]:
    """A line's cells, unquoted, without the empty ones after the last (a trailing comma)."""
    out = [c.strip().strip('"').strip() for c in cells]
    while out and not out[-1]:
        out.pop()
    return out


def csv_text(path: pathlib.Path) -> tuple[str, list[str], dict[str, float]]:
    """A CSV file's (or a workbook sheet's, `table_text`) text as both CSV readers read it, every line at
    its number: a commented header made a header (`commented_header`), cells between ';' or tabs put
    between commas (`comma_separated`), a units row's fields taken out (`header_fields`); the notes on
    what was done, and those fields."""
    text, notes = table_text(path)
    text, commented = commented_header(path, text)
    text, how = comma_separated(text)
    text, given, read = header_fields(path, text)
    return text, notes + commented + ([] if how is None else [f"recording '{path}': {how}"]) + read, given


def _csv_lines(path: pathlib.Path) -> tuple[list[tuple[int, str]], list[str], dict[str, float]]:
    """Non-blank, non-comment lines with their line numbers (from 1), and `csv_text`'s notes and fields."""
    text, notes, given = csv_text(path)
    lines = []
    for number, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if stripped and not stripped.startswith("#"):
            lines.append((number, stripped))
    return lines, notes, given


#: A unit in a units row that marks its column as a count of the samples, not a time (Rigol's ``X``).
_COUNT_UNITS = frozenset({"sequence", "sample", "samples", "index", "#"})


def _csv_header(
    path: pathlib.Path,
    line: str,
    required: Sequence[str] = REQUIRED,
    following: str = "",
    given: Mapping[str, float] | None = None,
    units: Sequence[str] | None = None,
) -> list[str]:
    """The header's names; `following`: the line after it, and `units` its units where it is a units row;
    `given`: the fields a units row gave (`header_fields`), which, like a column of counts, a refusal's
    example leaves out."""
    _check_delimiter(path, line, following)
    header = cut_cells(line.split(","))  # a trailing comma (a spreadsheet's empty columns): cells empty too
    named = [cell for cell in header if cell]  # an unnamed column (a row index) is left out (`_unnamed_note`)
    given = given or {}
    units = units or []
    counts = {name for name, unit in zip(header, units) if unit.lower() in _COUNT_UNITS}
    timed = [name for name, unit in zip(header, units) if name and is_time_unit(unit)]
    rate_known = any(name.lower() in RATE_FIELDS for name in given)
    # the project's own names keep their roles (a typo'd v_inn beside an exact w: output=w, not a w_true)
    example = mapping_example(header, rate_known, timed[0] if timed else None, {*given, *counts})
    repeated = sorted({c for c in named if named.count(c) > 1})
    if repeated:  # a scope's header of units (Second,Volt,Volt): the columns go by number
        raise InputError(
            f"recording '{path}' names column(s) {', '.join(repeated)} more than once: give each column a "
            f"unique name, or map them by number from 0, e.g. {example}"
        )
    require_names(path, header, "column(s)", required, example=example)
    return header


def spaced_cells_message(path: pathlib.Path | str, header: str, example: str = "") -> str:
    """The message for a .csv whose cells are separated by spaces; `example`: the mapping to give its .txt."""
    how = f": {example}" if example else " the same way"
    return (
        f"recording '{path}' has its cells separated by spaces (header {header.strip()!r}), and a .csv is "
        "read with commas between them: save it comma-separated with '.' decimals, or rename it to .txt "
        f"(a text table, read with spaces between the cells) and map its columns{how}"
    )


def _check_delimiter(path: pathlib.Path, line: str, following: str = "") -> None:
    """Refuse a header split by spaces: its columns would read as missing (';' and tabs: `comma_separated`);
    `following` is the line after it."""
    if "," in line:
        return
    names = line.split()
    data = following.split()
    if len(names) > 1 and len(data) > 1 and not any(m in line + following for m in ",;\t"):
        raise InputError(spaced_cells_message(path, line, mapping_example(names)))
    for mark, word in ((";", "';'"), ("\t", "tabs"), (None, "spaces")):
        cells = [c.strip().strip('"') for c in line.split(mark)]
        if len(cells) > 1 and set(cells) & set(REQUIRED):
            raise InputError(
                f"recording '{path}' uses {word} as its delimiter (header {line.strip()!r}): "
                "save it comma-separated with '.' decimals (t,v_in,w)"
            )


def _csv_column(path: pathlib.Path, column: str, cells: list[str], numbers: np.ndarray) -> np.ndarray:
    """Convert one column of cells, naming the first bad cell, its line and its sample."""
    offer = (
        f" ({FILL_VALUES_HINT})" if column in ("v_in", "w") else ""
    )  # a missing value of the drive or output
    try:
        values = np.array(cells, dtype=np.float64)
    except ValueError:
        values = np.array([_float_or_nan(cell) for cell in cells])
        text = [k for k, cell in enumerate(cells) if cell.strip() and not is_number(cell)]
        if text:  # text where a number belongs: the first, and how many lines have one
            k, cell = text[0], cells[text[0]]
            comma = " (a decimal comma: write '.' decimals)" if DECIMAL_COMMA.fullmatch(cell) else ""
            more = (
                f" ({len(text)} lines have such a cell: {samples_text(text, numbers)})"
                if len(text) > 1
                else ""
            )
            raise InputError(
                f"recording '{path}' has non-numeric cell {cell!r}{comma} in column '{column}' at line "
                f"{numbers[k]} (sample {k}){more}: fix that cell or delete the line"
            ) from None
    # missing values, empty cells and non-finite ones (a tracker's nan) alike: every one, in one message
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise InputError(
            f"recording '{path}' has missing values (empty or non-finite cells) in column '{column}' at "
            f"{samples_text(bad, numbers)}: remove or interpolate them{offer}"
        )
    return values


def _float_or_nan(cell: str) -> float:
    """A cell's number; nan for a cell that holds none (`_csv_column` says which)."""
    try:
        return float(cell)
    except ValueError:
        return math.nan


def _unnamed_note(path: pathlib.Path, i: int, cells: list[str]) -> str:
    """The note for column `i` (from 0), which has no name in the header: nothing reads it.

    pandas' ``to_csv`` writes its row index so, under an empty name; R's ``write.csv`` too.
    """
    try:
        values = np.array(cells, dtype=np.float64)
    except ValueError:
        values = np.array([])
    counts = len(values) > 1 and (values[0] in (0.0, 1.0)) and bool(np.all(np.diff(values) == 1.0))
    what = ": its cells count the rows, a row index (as pandas' to_csv writes one)" if counts else ""
    where = "its first column" if i == 0 else f"its column {i} (from 0)"
    return f"recording '{path}': {where} has no name in the header{what}; left out (name it to keep it)"


def _text_column(cells: list[str]) -> str | None:
    """What the column holds instead of numbers, when most of it does (labels, timestamps, empty
    cells: an event marker set on a few lines), in words; None for a column of numbers."""
    bad = []
    for cell in cells:
        try:
            float(cell)
        except ValueError:
            bad.append(cell)
    if not bad or 2 * len(bad) <= len(cells):
        return None
    text = next((cell for cell in bad if cell), None)
    return f"text (e.g. {text!r})" if text is not None else "mostly empty cells"


def _load_csv(
    path: pathlib.Path, required: Sequence[str] = REQUIRED
) -> tuple[dict[str, np.ndarray], dict, tuple[str, ...], np.ndarray]:
    lines, read_notes, given = _csv_lines(path)
    if not lines:
        raise InputError(
            f"recording '{path}' has no header or data: give a header line t,v_in,w and one line per sample"
        )
    start = find_header([line.split(",") for _, line in lines], required)
    if start:
        notes = [
            f"recording '{path}': the {start} line(s) before its header (line {lines[start][0]}) skipped"
        ]
        lines = lines[start:]
    else:
        notes = []
    row = units_row(lines[1][1].split(",")) if len(lines) > 1 else None
    header = _csv_header(path, lines[0][1], required, lines[1][1] if len(lines) > 1 else "", given, row)
    stated = {name: unit for name, unit in zip(header, row or ()) if unit}
    body = lines[1 + (row is not None) :]
    split = [[cell.strip().strip('"').strip() for cell in line.split(",")] for _, line in body]
    end = footer_start(split, [header.index(c) for c in required])
    if end < len(body):
        notes.append(footer_note(path, body[end:]))
    rows: list[list[str]] = []
    numbers: list[int] = []
    for (number, line), cells in zip(body[:end], split):  # "1.5": an export that quotes
        while len(cells) > len(header) and not cells[-1]:
            cells.pop()  # the trailing empty cells of the header's trailing empty names
        if len(cells) != len(header):
            raise InputError(cell_count_message(path, line, number, len(rows), len(cells), len(header)))
        rows.append(cells)
        numbers.append(number)
    if not rows:
        raise InputError(f"recording '{path}' has a header but no data lines: add one line per sample")
    line_numbers = np.asarray(numbers)
    columns = {}
    notes += read_notes
    start_time = None
    for i, column in enumerate(header):
        cells = [row[i] for row in rows]
        if column == "t" and _text_column(cells) is not None:  # date-times, or text: Clock says which
            clock = Clock()
            times = np.array([clock(cell) for cell in cells])
            if clock.start is not None and np.isfinite(times).all():
                columns[column], start_time = times, clock.start.isoformat()
                notes.append(clock.note(path))
                continue
        if not column:
            notes.append(_unnamed_note(path, i, cells))
            continue
        label = None if column in REQUIRED else _text_column(cells)
        if label is not None:  # nothing reads it: say so, do not refuse the signals beside it
            notes.append(f"recording '{path}': column '{column}' holds {label}, not a signal: left out")
            continue
        columns[column] = _csv_column(path, column, cells, line_numbers)
    meta_path = sidecar(path)
    metadata = {}
    if meta_path.exists():
        metadata = parse_metadata(path, read_text(meta_path), f"'{meta_path.name}'")
    if start_time is not None:
        metadata["start_time"] = start_time
    if row is not None:  # the units under the header travel with the data; a sidecar's units win
        where = f"its units row (line {lines[1][0]})"
        if "t" in stated:
            columns["t"] = columns["t"] * time_factor(path, stated["t"], where)
        units = metadata.get("units")
        declared: dict = units if isinstance(units, dict) else {}
        metadata["units"] = {**UNITS, **{c: stated[c] for c in ("v_in", "w") if c in stated}, **declared}
        metadata["units"]["t"] = declared.get("t", "s")
        listed = ", ".join(f"{c} in {u}" for c, u in stated.items())
        notes.append(f"recording '{path}': read {where} as units ({listed})")
    return columns, metadata, tuple(notes), line_numbers


def quality_notes(path: pathlib.Path | str, quality: np.ndarray | None, offset: int = 0) -> list[str]:
    """A note for samples whose ``quality`` column (rig's: 1 measured, 0 not) is 0, or none.

    `rig record` and `rig track` write w on every row: where the tracker could
    not measure the tip (out of view, a smeared tip, a dropped or repeated
    frame) w is held, interpolated or measured less surely, with quality 0.
    `diagnose` leaves them out of its fits and scores (`DiagnoseSettings.bridge_glitches`), and so
    does every fit and test score (`hybrid.core._problem.series_from_recording`): the user should
    know how many. `offset`: the file's sample of the recording's first (a sample range's start).
    """
    if quality is None or not np.isin(quality, (0.0, 1.0)).all() or not (quality == 0).any():
        return []
    zero = np.flatnonzero(quality == 0)
    in_file = f", the file's {zero[0] + offset}" if offset else ""
    return [
        f"recording '{path}': {len(zero)} of {len(quality)} samples have quality 0 (the first at sample "
        f"{zero[0]}{in_file}): w was not measured there as elsewhere (held, interpolated or less sure: rig's tracker); "
        "diagnose bridges each run of them inside the record by a straight line and leaves them all out of "
        "its fits and scores (unless --keep-glitches); fit leaves them out of every part and a test record's "
        f"score; where there are many, leave a stretch of them out with {range_flag()}, or track the video "
        "again (rig/README.md)"
    ]


def footer_note(path: pathlib.Path | str, footer: Sequence[tuple[int, str]]) -> str:
    """The note for a footer skipped (`footer_start`): its lines ``(number, text)``."""
    first = footer[0][1].strip()
    shown = first if len(first) <= 40 else first[:37] + "..."
    return (
        f"recording '{path}': the {len(footer)} line(s) of text after its data (from line "
        f"{footer[0][0]}, {shown!r}) skipped as a footer"
    )


def cell_count_message(
    path: pathlib.Path | str, line: str, number: int, sample: int, cells: int, width: int, what: str = ""
) -> str:
    """The message for a data line of `cells` cells under a header of `width` columns (or lines of `width`
    cells: `what` says which), with the likely cause."""
    hint = ""
    fragments = [c for c in line.split(",") if re.fullmatch(r"\s*0\d+\s*", c)]  # 0,009428: "009428"
    if cells > width and (fragments or not re.search(r"\d\.\d", line)):
        hint = (
            " (decimal commas? the commas in 0,5 split it into cells: write '.' decimals, or save it "
            "with ';' between the cells)"
        )
    elif cells < width:
        hint = " (a line cut short, or a footer?)"
    elif cells > width:
        hint = " (a cell too many: a value or a delimiter written twice?)"
    return (
        f"recording '{path}' has {cells} cells at line {number} (sample {sample}) but "
        f"{what or f'{width} columns in its header'}{hint}: make every line match the header"
        " (fix or delete that line)"
    )


# ------------------------------------------------------------------- NPZ


def npz_arrays(path: pathlib.Path) -> tuple[dict[str, np.ndarray], dict]:
    """Every array of a ``.npz`` archive as stored, and its ``metadata`` entry parsed."""
    try:
        with np.load(path, allow_pickle=False) as archive:
            arrays = {key: archive[key] for key in archive.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as error:
        raise InputError(
            f"recording '{path}' is not a readable .npz archive ({error}): save it "
            "with numpy.savez or Recording.save"
        ) from None
    metadata = {}
    if "metadata" in arrays:
        metadata = parse_metadata(path, str(arrays.pop("metadata")[()]), "its 'metadata' entry")
    return arrays, metadata


def npy_table(path: pathlib.Path) -> tuple[list[str], np.ndarray]:
    """A ``.npy`` array as a table: its column names and its float64 values, shape (samples, columns).

    ``np.save(file, table)``: a vector is one column; a matrix holds a channel per column
    along its longer side (per row, ``[t; u; y]``, too), named by number from 0 as a
    headerless table's; a structured array's fields are its columns, by name.
    """
    try:
        values = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as error:
        raise InputError(
            f"recording '{path}' is not a readable .npy array ({error}): save it with numpy.save"
        ) from None
    if values.dtype.names:  # a structured (record) array: one column per field
        names = list(values.dtype.names)
        fields = [np.asarray(values[name]).reshape(-1) for name in names]
        if not all(f.dtype.kind in "biuf" for f in fields):
            raise InputError(f"recording '{path}' has fields that are not real numbers: store numbers only")
        return names, np.column_stack(fields).astype(np.float64)
    if values.dtype.kind not in "biuf" or values.ndim not in (1, 2) or values.size == 0:
        raise InputError(
            f"recording '{path}' holds an array of type {values.dtype} and shape {values.shape}: store a "
            "table of real numbers, one channel per column (numpy.save(file, np.column_stack([t, u, y])))"
        )
    table = values.reshape(-1, 1) if values.ndim == 1 else _by_channel(values).T
    return [str(i) for i in range(table.shape[1])], table.astype(np.float64)


def _load_npz(
    path: pathlib.Path, required: Sequence[str] = REQUIRED
) -> tuple[dict[str, np.ndarray], dict, tuple[str, ...]]:
    arrays, metadata = npz_arrays(path)
    _require_stored(path, arrays, "array(s)", required)
    kept = _vectors(path, arrays, required)
    columns = {(key[len(NPZ_EXTRA) :] if key.startswith(NPZ_EXTRA) else key): v for key, v in kept.items()}
    return columns, metadata, _left_out(path, arrays, kept, "array")


def _require_stored(
    path: pathlib.Path, arrays: Mapping[str, np.ndarray], kind: str, required: Sequence[str]
) -> None:
    """`require_names` for a .npz or .mat file; where its signals are one matrix's columns, the mapping for them."""
    try:
        require_names(path, list(arrays), kind, required)
    except InputError:
        example = _matrix_example(arrays) if "w" in required else ""
        if not example:
            raise
        missing = ", ".join(c for c in required if c not in arrays)
        raise MissingName(
            f"recording '{path}' is missing {kind} {missing} (found {', '.join(map(repr, arrays))}): {example}",
            missing.split(", ")[0],
        ) from None


def _vectors(
    path: pathlib.Path, arrays: Mapping[str, np.ndarray], required: Sequence[str]
) -> dict[str, np.ndarray]:
    """The stored vectors; anything else beside the signals (a matrix, text) is left out (`_left_out`)."""
    return {
        key: file_vector(path, key, values)
        for key, values in arrays.items()
        if key in required or _is_vector(values)
    }


def _is_vector(values) -> bool:
    """Whether a stored value is real numbers, at most one side longer than 1 (what `file_vector` takes)."""
    values = np.asarray(values)
    return values.dtype.kind in "biuf" and sum(k > 1 for k in values.shape) <= 1


def _left_out(
    path: pathlib.Path, arrays: Mapping[str, np.ndarray], read: Mapping, kind: str
) -> tuple[str, ...]:
    """A note for each stored value beside the signals that nothing reads: not among `read` (`_vectors`)."""
    notes = []
    for key, values in arrays.items():
        if key in read:
            continue
        values = np.asarray(values)
        what = f"of shape {values.shape}" if values.dtype.kind in "biuf" else f"of type {values.dtype}"
        notes.append(
            f"recording '{path}': {kind} '{key}' {what} is not a signal (one number per sample): left out"
        )
    return tuple(notes)


# ------------------------------------------------------------------- MAT


#: A stored matrix whose shorter side is at most this long holds one channel per column (or row).
MATRIX_CHANNELS = 32


def matrix_columns(arrays: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Each channel of every stored matrix, as ``NAME:K`` (K from 0) → its vector.

    MATLAB's ``data = [t u y]; save run.mat data`` (or numpy's ``savez(data=table)``) stores
    the record as one matrix: a channel per column along its longer side (a per-row layout,
    ``[t; u; y]``, too), at most `MATRIX_CHANNELS` of them, so a mapping can name a column by
    number as in a table (``--columns input=data:1,output=data:2 --time data:0``).
    """
    out = {}
    for key, values in arrays.items():
        values = np.asarray(values)
        if (
            values.ndim != 2
            or values.dtype.kind not in "biuf"
            or not 2 <= min(values.shape) <= MATRIX_CHANNELS
        ):
            continue
        if values.shape[0] == values.shape[1]:
            continue  # which side holds the samples cannot be told
        out.update({f"{key}:{k}": channel for k, channel in enumerate(_by_channel(values))})
    return out


def _by_channel(values: np.ndarray) -> np.ndarray:
    """A stored table, shape (channels, samples): its longer side holds the samples (a square one is read
    as columns of channels)."""
    return values if values.shape[1] > values.shape[0] else values.T


def _matrix_example(arrays: Mapping[str, np.ndarray]) -> str:
    """The mapping of a file whose signals are columns of one matrix (`matrix_columns`), or ""."""
    channels = matrix_columns(arrays)
    matrices = {name.rsplit(":", 1)[0] for name in channels}
    if len(matrices) != 1:
        return ""
    (key,) = matrices
    first = channels[f"{key}:0"]
    timed = len(channels) >= 3 and len(first) > 1 and bool(np.all(np.diff(first) > 0))
    flags = (
        f"--columns input={key}:1,output={key}:2 --time {key}:0"
        if timed
        else f"--columns input={key}:0,output={key}:1 --rate HZ"
    )
    return f"'{key}' is a matrix of {len(channels)} channels: name them by number from 0, e.g. {flags}"


def file_vector(path: pathlib.Path, key: str, values: np.ndarray) -> np.ndarray:
    """Check that a stored variable is a real numeric vector; return it flat."""
    values = np.asarray(values)
    if values.dtype.kind not in "biuf":
        raise InputError(
            f"recording '{path}' has variable '{key}' of type {values.dtype} "
            "rather than real numbers: store numeric vectors only"
        )
    if values.ndim > 1 and sum(k > 1 for k in values.shape) > 1:
        channels = len(matrix_columns({key: values}))
        fix = (
            f", or map one of its channels by number from 0 ({key}:0 to {key}:{channels - 1})"
            if channels
            else ""
        )
        raise InputError(
            f"recording '{path}' has variable '{key}' of shape {values.shape}, "
            f"not a vector: store one value per sample{fix}"
        )
    return values.reshape(-1)


def _is_hdf5(path: pathlib.Path) -> bool:
    """MATLAB v7.3 files are HDF5: a 512-byte MATLAB header, then the HDF5 signature."""
    try:
        with open(path, "rb") as handle:
            head = handle.read(520)
    except OSError:
        return False
    return head[:10] == b"MATLAB 7.3" or head[512:520] == b"\x89HDF\r\n\x1a\n"


def mat_variables(path: pathlib.Path) -> tuple[dict[str, np.ndarray], dict]:
    """Every variable of a ``.mat`` file as stored, and its ``metadata`` variable parsed."""
    import scipy.io

    try:
        variables = _flat_structs(
            {k: v for k, v in scipy.io.loadmat(str(path)).items() if not k.startswith("__")}
        )
    except Exception as error:  # scipy raises many types for broken files
        if not ("7.3" in str(error) or _is_hdf5(path)):
            raise InputError(
                f"recording '{path}' is not a readable .mat file ({error}): save it "
                "with MATLAB's save(file, 't', 'v_in', 'w', '-v7') or Recording.save"
            ) from None
        variables = _mat73_variables(path)
    metadata = {}
    if "metadata" in variables:
        text = variables.pop("metadata")
        if text.dtype.kind != "U" or text.size != 1:
            raise InputError(
                f"recording '{path}' has a 'metadata' variable that is not one "
                "string: store the metadata as a JSON char array"
            )
        metadata = parse_metadata(path, str(text.reshape(-1)[0]), "its 'metadata' variable")
    return variables, metadata


def _mat73_variables(path: pathlib.Path) -> dict[str, np.ndarray]:
    """The variables of a MATLAB v7.3 (HDF5) file, as `scipy.io.loadmat` gives those of a v7 one.

    Read with h5py: a numeric array is a dataset (stored transposed: a vector is a
    vector either way), a char array one of UTF-16 codes (`MATLAB_class` "char"),
    a struct a group whose fields are named with dots as `_flat_structs` does;
    cell arrays, empty arrays and MATLAB's own ``#refs#`` are left out.
    """
    import h5py

    out: dict[str, np.ndarray] = {}

    def visit(group, prefix: str, depth: int) -> None:
        for name, item in group.items():
            if name.startswith("#"):
                continue
            kind = item.attrs.get("MATLAB_class", b"")
            kind = kind.decode() if isinstance(kind, bytes) else str(kind)
            if isinstance(item, h5py.Group):
                if kind == "struct" and depth < _STRUCT_DEPTH:
                    visit(item, f"{prefix}{name}.", depth + 1)
            elif kind == "char":
                out[prefix + name] = np.array(["".join(map(chr, np.asarray(item[()]).reshape(-1)))])
            elif kind != "cell" and not item.attrs.get("MATLAB_empty", 0) and item.dtype.kind in "biuf":
                out[prefix + name] = np.asarray(item[()]).T  # MATLAB's column-major order

    try:
        with h5py.File(path, "r") as handle:
            visit(handle, "", 0)
    except OSError as error:
        raise InputError(
            f"recording '{path}' is a damaged MATLAB v7.3 (HDF5) .mat file ({error}): save it again"
        ) from None
    return out


#: How deep struct fields are read (``run.data.u`` is depth 2).
_STRUCT_DEPTH = 4


def _flat_structs(variables: dict, prefix: str = "", depth: int = 0) -> dict[str, np.ndarray]:
    """A .mat file's variables with each field of a (1x1) struct as a variable of its own, ``data.u``.

    A lab's file often keeps its signals in a struct (``data.u``, ``data.y``,
    ``data.fs``); the struct itself is left out, its fields named with dots.
    """
    out: dict[str, np.ndarray] = {}
    for name, value in variables.items():
        key = prefix + name
        value = np.asarray(value)
        if value.dtype.names and value.size == 1 and depth < _STRUCT_DEPTH:
            record = value.reshape(-1)[0]
            fields = {field: record[field] for field in value.dtype.names}
            out.update(_flat_structs(fields, key + ".", depth + 1))
        elif value.dtype.names is None:
            out[key] = value
    return out


def _load_mat(
    path: pathlib.Path, required: Sequence[str] = REQUIRED
) -> tuple[dict[str, np.ndarray], dict, tuple[str, ...]]:
    variables, metadata = mat_variables(path)
    _require_stored(path, variables, "variable(s)", required)
    columns = _vectors(path, variables, required)
    return columns, metadata, _left_out(path, variables, columns, "variable")
