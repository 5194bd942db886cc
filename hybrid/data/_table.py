"""Reading the columns of a lab's own file, whatever they are called, for
[`load_mapped`][hybrid.data._mapping.load_mapped].

`read_columns` returns the columns asked for by name (a role such as ``v_in``
-> the file's name for it, such as ``uEst``), the file's rate or period fields
(`RATE_FIELDS`) and its metadata.

* ``.csv``: the header is the first line that is neither blank nor a ``#``
  comment; its names may be quoted, and empty names at its end (a trailing
  comma on every line, as in the Cascaded Tanks and Silverbox files) are
  dropped; a logger's preamble before it is skipped (the header is the first of
  the first `PREAMBLE_LINES` lines that names every column wanted, or, with
  none named, the line above the numbers: `table_start`), with a note.
  A first line of numbers (or date-times) only is no header but the first
  sample: the columns go by number from 0, with a note.
  Every data line must have the header's number of cells (or every one the same
  fewer, none of them read: LabVIEW's Comment column); a footer of text lines
  after the data (`footer_start`) is skipped with a note. Only the mapped columns
  and the rate fields are converted, by
  numpy's C reader (`numpy.loadtxt` with ``usecols``): 10⁶ rows of three
  columns take about a second and tens of MB. Other columns may hold anything,
  empty cells included. Blank lines and ``#`` comments are skipped. The
  metadata comes from the ``<file>.csv.json`` sidecar when there is one.
* ``.txt`` / ``.dat`` / ``.tsv`` / ``.lvm`` (`TEXT_SUFFIXES`): a plain text table, as a logger,
  LabVIEW or MATLAB's ``save -ascii`` writes it: numbers separated by commas, semicolons,
  tabs or spaces (the first data line decides), ``#`` comments and blank lines
  skipped, an optional header line (a first line that is not all numbers; below a
  preamble and above a footer, as in a ``.csv``) and a units row under it, as in a ``.csv``. A
  table without a header names its columns by number from 0 (``"0"``, ``"1"``). A LabVIEW ``.lvm``
  that writes no time column gives its channels' sample period, ``Delta_X`` (`lvm_period`), as a field.
  Every column is read, so every cell must be a number.
* ``.npz`` / ``.mat``: the arrays or variables named; only those must be real
  numeric vectors, or a channel of a stored matrix, ``data:1`` (`matrix_columns`).
  The metadata is the ``metadata`` entry, as for `Recording.load`.
* ``.npy``: one array saved by ``numpy.save`` (`npy_table`): a table's columns by number
  from 0 (a matrix's channels along its longer side), a structured array's fields by name.

A name that is not in a ``.csv`` or text table's header may be a column number
from 0 (``"0"``, ``"2"``): the header's names come first.

Every bad mapping or cell raises one [`InputError`][hybrid.InputError]: a name
the file lacks (with the file's names listed), a name the header holds twice,
and a missing, empty, non-numeric or non-finite cell in a mapped column (with
its column, its line in the file, from 1, and its sample, from 0): the first is
named and the lines (samples, in a file without lines) that have one are counted,
in one message whatever the format (`_refusal`).
"""

from __future__ import annotations

import array
import collections
import csv
import difflib
import io
import math
import pathlib
import shlex
import warnings
from collections.abc import Callable, Mapping, Sequence
from typing import NamedTuple

import numpy as np

from ..util._errors import InputError
from ._loaders import (
    CSV_SUFFIXES,
    DECIMAL_COMMA,
    FOOTER_LINES,
    PREAMBLE_LINES,
    RATE_FIELDS,
    SHEET_SUFFIXES,
    TEXT_SUFFIXES,
    Clock,
    MissingName,
    cell_count_message,
    commented_header,
    csv_text,
    cut_cells,
    decode_text,
    file_vector,
    find_header,
    footer_note,
    footer_start,
    is_number,
    is_value,
    mapping_example,
    mat_variables,
    matrix_columns,
    npy_table,
    npz_arrays,
    parse_metadata,
    read_text,
    sidecar,
    spaced_cells_message,
    units_row,
)
from ._recording_checks import FILL_VALUES_HINT, columns_flag, range_flag

__all__ = [
    "MAPPED_SUFFIXES",
    "OPTION",
    "TableNotes",
    "only_column",
    "rate_field",
    "read_columns",
    "lvm_period",
    "text_columns",
    "read_text_table",
    "unknown_name",
]

#: How each role is asked for: the keyword of `load_mapped` (and the command-line flag).
OPTION: dict[str, str] = {"t": "time", "v_in": "input", "w": "output"}

#: Every suffix the mapped reader understands.
MAPPED_SUFFIXES: tuple[str, ...] = (".csv", ".npz", ".mat", ".npy", *SHEET_SUFFIXES, *TEXT_SUFFIXES)

_SHOW_NAMES = 20


class TableNotes(NamedTuple):
    """What reading a table learnt besides its columns, for `load_mapped`."""

    #: The file line (from 1) of each sample, for messages; None where the file has no lines (.npz, .mat).
    lines: np.ndarray | None = None
    #: What was done to the file (a preamble or footer skipped, ';' cells read), one sentence each.
    notes: tuple[str, ...] = ()
    #: The file's column (or array, variable) names, for a message that suggests one.
    columns: tuple[str, ...] = ()
    #: A text table's units row under its header, by column name (`units_row`); empty without one.
    units: tuple[tuple[str, str], ...] = ()
    #: The sample period of each column, s, that a LabVIEW file's header gives where it writes no time
    #: column (`lvm_period`); empty otherwise.
    period: tuple[float, ...] = ()


def read_columns(
    path: pathlib.Path, suffix: str, wanted: Mapping[str, str], flag_prefix: str = "", fill: bool = False
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict, TableNotes]:
    """The mapped columns of a file, its rate fields and its metadata.

    Arguments:
        path: the file (already checked to exist, with a known suffix).
        suffix: ``".csv"``, ``".npz"`` or ``".mat"``.
        wanted: role (``t``, ``v_in``, ``w``) -> the file's name for it; distinct names.
        flag_prefix: what a message's example puts before a name (``"u.txt:"`` for a file
            joined by ``columns``; see `unknown_name`).
        fill: read a missing value (an empty or non-finite cell) of the drive or the output as NaN,
            for `fill_values` to fill, instead of refusing it.

    Returns:
        ``(columns, fields, metadata, notes)``: role -> float64 vector (all of one length for
        a CSV file), rate-field name -> its values, the file's metadata, and `TableNotes`.
    """
    if suffix in CSV_SUFFIXES:
        return _read_csv(path, wanted, flag_prefix, fill)
    if suffix == ".npy" or suffix in TEXT_SUFFIXES:
        if suffix == ".npy":
            (names, table), notes = npy_table(path), TableNotes()
        else:
            names, table, notes = read_text_table(path, wanted, flag_prefix, fill)
        index = {role: _column_index(path, names, name, role, flag_prefix) for role, name in wanted.items()}
        columns = {role: table[:, i] for role, i in index.items()}
        if suffix == ".npy":
            _refuse_non_finite(path, columns, wanted, "column", fill)
        metadata = {"units": dict(notes.units)} if notes.units else {}
        # a LabVIEW file's Delta_X: the mapped channels' period, a rate field (channels of two periods: none)
        period = [notes.period[i] for role, i in index.items() if role != "t" and i < len(notes.period)]
        fields = {"Delta_X": np.array(period)} if period else {}
        if period and "t" not in wanted and rate_field(fields["Delta_X"]) is not None:
            said = (
                f"recording '{path}': its header writes no time column (X_Columns No) and gives the sample "
                f"period Delta_X = {period[0]:g} s: read as {1 / period[0]:.6g} Hz, as a rate given would be "
                "(--rate HZ checks it)"
            )
            notes = notes._replace(notes=(*notes.notes, said))
        return columns, fields, metadata, notes._replace(columns=tuple(names))
    arrays, metadata = npz_arrays(path) if suffix == ".npz" else mat_variables(path)
    arrays = {**arrays, **matrix_columns(arrays)}  # data:1, a column of a stored matrix
    kind = "array" if suffix == ".npz" else "variable"
    columns = {}
    for role, name in wanted.items():
        if name not in arrays:
            raise MissingName(unknown_name(path, name, role, list(arrays), kind, flag_prefix), role)
        columns[role] = file_vector(path, name, arrays[name]).astype(np.float64)
    _refuse_non_finite(path, columns, wanted, kind, fill)
    fields = {
        key: np.asarray(values, dtype=np.float64).reshape(-1)
        for key, values in arrays.items()
        if key.rsplit(".", 1)[-1].lower() in RATE_FIELDS  # data.fs: a struct's field counts too
        and key not in wanted.values()
        and np.asarray(values).dtype.kind in "biuf"
    }
    return columns, fields, metadata, TableNotes(columns=tuple(arrays))


def rate_field(values: np.ndarray) -> float | None:
    """The number a rate or period field holds, or None when it does not look like one.

    A field is one positive finite number, or a vector whose first value is one and whose
    other values are NaN (empty cells) or equal to it.
    """
    values = np.asarray(values, dtype=np.float64).reshape(-1)
    if values.size == 0 or not (math.isfinite(values[0]) and values[0] > 0):
        return None
    rest = values[1:]
    return float(values[0]) if bool(np.all(np.isnan(rest) | (rest == values[0]))) else None


# --------------------------------------------------------------------------- #
# CSV
# --------------------------------------------------------------------------- #


_CSV_FIX = "save it as CSV UTF-8 (Excel: Save As, 'CSV UTF-8 (Comma delimited)')"


def _read_csv(
    path: pathlib.Path, wanted: Mapping[str, str], flag_prefix: str = "", fill: bool = False
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict, TableNotes]:
    text, notes, given = csv_text(path)  # given: a scope's Start and Increment under their names
    try:
        with io.StringIO(text) as handle:
            names_wanted = [n for n in wanted.values() if not n.isdigit()]
            numbers = [int(n) for n in wanted.values() if n.isdigit()] if not names_wanted else []
            header, header_line, skipped = _header(path, handle, names_wanted, numbers)
            if skipped:
                notes.append(
                    f"recording '{path}': the {skipped} line(s) before its header (line {header_line}) skipped"
                )
            if header == [str(i) for i in range(len(header))]:
                notes.append(
                    f"recording '{path}': no header (its first line holds numbers in the columns read): "
                    "columns by number from 0"
                )
            stated, units_line = _stated_units(handle, header, header_line)
            index = {
                role: _column_index(path, header, name, role, flag_prefix) for role, name in wanted.items()
            }
            fields = {
                name: i
                for i, name in enumerate(header)
                if name.lower() in RATE_FIELDS
                and i not in index.values()
                and header.count(name) == 1
                and name not in given
            }
            usecols = [*index.values(), *fields.values()]
            lines, footer = _data_lines(
                path, text, header_line, units_line, len(header), usecols, list(index.values())
            )
            if footer:
                notes.append(footer_note(path, footer))
            position = handle.tell()

            def load(missing: Sequence[int] = ()) -> tuple[np.ndarray, Clock]:
                """The columns read from the data lines on (`missing`: columns whose empty cells are NaN)."""
                handle.seek(position)
                clock = Clock()  # a time column of date-times: seconds after the first
                lenient: dict[int | str, Callable[[str], float]] | None = {
                    **{i: _lenient for i in fields.values()},
                    **({index["t"]: clock} if "t" in index else {}),
                    **{i: _missing_as_nan for i in missing},
                } or None
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", UserWarning)  # "input contained no data"
                    table = np.loadtxt(
                        handle,
                        dtype=np.float64,
                        delimiter=",",
                        usecols=usecols,
                        ndmin=2,
                        comments="#",
                        quotechar='"',
                        converters=lenient,
                        max_rows=len(lines) or None,  # a footer's lines are not read
                    )
                return table, clock

            try:
                table, clock = load()
            except ValueError:
                short: tuple[np.ndarray, Clock] | None = None
                try:  # a record shorter than the file: its columns' last cells empty (`shorter_record`)
                    short = load([i for role, i in index.items() if role != "t"])
                except ValueError:
                    pass
                if short is not None:
                    at = np.frombuffer(lines, dtype=np.int64)
                    refuse_ends_apart(
                        path, short[0], dict(enumerate(index)), dict(enumerate(wanted.values())), at
                    )
                if short is not None and shorter_record(short[0], dict(enumerate(index))) is not None:
                    table, clock = short
                else:
                    if not fill:
                        raise
                    # every bad cell is a missing value of the drive or output, else refused here: read as NaN
                    _diagnose(path, text, header_line, units_line, wanted, index, fill)
                    table, clock = load([i for role, i in index.items() if role != "t"])
    except InputError:
        raise
    except csv.Error as error:  # a NUL byte in the header
        raise InputError(f"recording '{path}' is not a text table ({error}): {_CSV_FIX}") from None
    except ValueError as error:
        _diagnose(path, text, header_line, units_line, wanted, index, fill)
        raise InputError(
            f"recording '{path}' cannot be read as a comma-separated table ({error}): save it "
            "comma-separated with '.' decimals, one header line and one line per sample"
        ) from None
    if table.shape[0] == 0:
        raise InputError(f"recording '{path}' has a header but no data lines: add one line per sample")
    k = len(index)
    line_of = np.frombuffer(lines, dtype=np.int64).copy()  # the file line of each row
    end = shorter_record(table, dict(enumerate(index)))
    if end is not None:
        notes.append(_shorter_note(path, [wanted[role] for role in index if role != "t"], line_of, end))
        table, line_of = table[:end], line_of[:end]
    bad = ~np.isfinite(table[:, :k])
    if fill:  # the drive's and the output's are filled (`fill_values`)
        bad[:, [j for j, role in enumerate(index) if role != "t"]] = False
    if bad.any():  # within the record (a shorter one's tail is cut above)
        _diagnose(path, text, header_line, units_line, wanted, index, fill, int(line_of[-1]))
    columns = {role: table[:, j] for j, role in enumerate(index)}
    rates = {name: table[:, k + j] for j, name in enumerate(fields)}
    rates.update({name: np.array([value]) for name, value in given.items() if name.lower() in RATE_FIELDS})
    metadata = {}
    meta_path = sidecar(path)
    if meta_path.exists():
        metadata = parse_metadata(path, read_text(meta_path), f"'{meta_path.name}'")
    if clock.start is not None:
        metadata["start_time"] = clock.start.isoformat()
        notes.append(clock.note(path))
    if stated:  # a units row under the header, by column name; a sidecar's units win
        units = metadata.get("units")
        declared: dict = units if isinstance(units, dict) else {}
        metadata["units"] = {**stated, **declared}
    return (
        columns,
        rates,
        metadata,
        TableNotes(line_of, tuple(notes), tuple(header)),
    )


def record_ends(table: np.ndarray, roles: Mapping[int, str]) -> dict[int, int]:
    """The row after the last finite value of each of the drive's and the output's columns (`roles`: a
    column of `table` -> its role): the table's length where its last cell is a number."""
    ends = {}
    for j, role in roles.items():
        if role != "t":
            finite = np.flatnonzero(np.isfinite(table[:, j]))
            ends[j] = int(finite[-1]) + 1 if finite.size else 0
    return ends


def shorter_record(table: np.ndarray, roles: Mapping[int, str]) -> int | None:
    """The rows of a record shorter than its file, or None: where the drive's and the output's columns
    (`roles`: a column of `table` -> its role) both end in missing values from one row to the file's last,
    and the time column is finite up to there (a validation record beside a longer estimation record, as a
    spreadsheet writes them side by side). A missing value before that row is the record's own: refused,
    or filled, where it is."""
    ends = set(record_ends(table, roles).values())
    if len(ends) != 1 or (end := ends.pop()) < 2 or end == table.shape[0]:
        return None
    times = [j for j, role in roles.items() if role == "t"]
    return end if all(np.isfinite(table[:end, j]).all() for j in times) else None


def refuse_ends_apart(
    path, table: np.ndarray, roles: Mapping[int, str], names: Mapping[int, str], lines
) -> None:
    """Refuse, in one line, a record whose drive and output both stop before the file's last line, on
    different lines (a validation drive one cell shorter than its output read as 1,501 bad lines)."""
    ends = record_ends(table, roles)
    if len(set(ends.values())) < 2 or max(ends.values()) == table.shape[0] or min(ends.values()) < 1:
        return
    said = " and ".join(
        f"{names[j]!r} (mapped as {OPTION[roles[j]]}) at line {int(lines[end - 1])}"
        for j, end in ends.items()
    )
    raise InputError(
        f"recording '{path}' has columns that end on different lines, {said}: a record's drive and output "
        f"must end together; fill the shorter column's last value, or keep the samples both have ({range_flag()})"
    )


def _shorter_note(path: pathlib.Path, names: Sequence[str], lines: np.ndarray, end: int) -> str:
    said = " and ".join(repr(n) for n in names)
    return (
        f"recording '{path}': its column{'s' if len(names) > 1 else ''} {said} end at line {lines[end - 1]} "
        f"({end} samples); the {lines.size - end} line(s) after it hold no value of "
        f"{'them' if len(names) > 1 else 'it'} (a shorter record beside a longer one): read up to there"
    )


def _data_lines(
    path: pathlib.Path,
    text: str,
    header_line: int,
    units_line: int,
    width: int,
    usecols: Sequence[int],
    mapped: Sequence[int],
) -> tuple[array.array, list[tuple[int, str]]]:
    """The line number (from 1) of each data line of a CSV's `text` (cells between commas), and its footer.

    Every data line must have the header's `width` cells (empty cells after the last
    column, a trailing comma, do not count), or every one the same fewer cells, none
    of them read (`usecols`; LabVIEW leaves its Comment column out); anything else
    (decimal commas in a comma-separated file, a cell too many or too few) is refused
    at its line. A footer (`footer_start`, judged on the `mapped` columns) is left out
    and returned, ``(number, text)`` per line.
    """
    numbers = array.array("q")  # 8 bytes a line: 10⁶ lines are 8 MB, not the 30 MB of a list
    counts = array.array("q")
    tail: collections.deque[tuple[int, str]] = collections.deque(maxlen=FOOTER_LINES + 1)
    with io.StringIO(text) as handle:
        for number, line in enumerate(handle, start=1):
            if number <= header_line or number == units_line:
                continue
            content = line.split("#", 1)[0].strip() if "#" in line else line.strip()
            if not content:
                continue  # numpy skips blank and comment lines too
            numbers.append(number)
            counts.append(_cell_count(content, width))
            tail.append((number, content))
    rows = list(tail)
    end = len(numbers) - len(rows) + footer_start([next(csv.reader([c]), []) for _, c in rows], mapped)
    footer = [(n, c) for n, c in rows if n > (numbers[end - 1] if end else 0)]
    numbers, counts = numbers[:end], counts[:end]
    if not counts:
        return numbers, footer
    first = counts[0]
    allowed = first if first < width and max(usecols, default=0) < first else width
    for k, count in enumerate(counts):
        if count != allowed:
            line = (
                next(c for n, c in rows if n == numbers[k])
                if numbers[k] >= rows[0][0]
                else _line(text, numbers[k])
            )
            what = f"{allowed} on the lines above" if allowed != width else ""
            raise InputError(cell_count_message(path, line, numbers[k], k, count, width, what))
    return numbers, footer


def _cell_count(content: str, width: int) -> int:
    """The cells of a CSV line, those after the header's `width` columns left out when empty (a trailing comma)."""
    if '"' in content:
        cells = next(csv.reader([content]), [])
        count = len(cells)
        while count > width and not cells[count - 1].strip():
            count -= 1
        return count
    count = content.count(",") + 1
    if count > width:
        stripped = content.rstrip()
        while count > width and stripped.endswith(","):
            stripped = stripped[:-1].rstrip()
            count -= 1
    return count


def _line(text: str, number: int) -> str:
    """Line `number` (from 1) of `text`."""
    with io.StringIO(text) as handle:
        for n, line in enumerate(handle, start=1):
            if n == number:
                return line.strip()
    return ""


def _stated_units(handle, header: Sequence[str], header_line: int) -> tuple[dict[str, str], int]:
    """The units row right under the header (`units_row`), by column name, and its line number (0: none).

    The handle is left after it; where the next line holds data, it goes back to its start.
    """
    position = handle.tell()
    for number, line in enumerate(iter(handle.readline, ""), start=header_line + 1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        row = units_row(next(csv.reader([stripped])))
        if row is None:
            break
        return {name: unit for name, unit in zip(header, row) if unit and name}, number
    handle.seek(position)
    return {}, 0


def _missing_as_nan(cell: str) -> float:
    """A drive's or output's cell where missing values are filled: its number, NaN where it is empty."""
    text = cell.strip().strip('"').strip()
    return float(text) if text else math.nan


def _lenient(cell: str) -> float:
    """A rate field's cell: its number, NaN when empty or not a number."""
    try:
        return float(cell.strip().strip('"') or "nan")
    except ValueError:
        return math.nan


def _header(
    path: pathlib.Path, handle, names_wanted: Sequence[str] = (), numbers: Sequence[int] = ()
) -> tuple[list[str], int, int]:
    """The header's names, its line number and how many lines of a preamble came before it; the handle is
    left after it.

    The header is the first line that names every one of `names_wanted` (a
    logger's preamble comes before it), else the line above the numbers (both
    `find_header`; the first line where the numbers start there). Columns mapped by
    their `numbers` alone: where the first line holds a number in each of them, it is
    the first sample, whatever the other columns hold (a Tektronix scope's export
    writes its settings in the first columns of its first lines, beside the samples).
    """
    position = handle.tell()
    lines = [line for line in (handle.readline() for _ in range(PREAMBLE_LINES)) if line]
    rows = [
        next(csv.reader([line.strip()]), []) if line.strip() and not line.strip().startswith("#") else []
        for line in lines
    ]
    at = next((k for k, row in enumerate(rows) if row), None)
    if at is not None and numbers and all(i < len(rows[at]) and is_number(rows[at][i]) for i in numbers):
        handle.seek(position)
        for _ in range(at):  # left before the first sample: no header
            handle.readline()
        return [str(i) for i in range(len(cut_cells(rows[at])))], at, 0
    skip = find_header(rows, names_wanted)
    skipped = sum(1 for row in rows[:skip] if row)
    handle.seek(position)
    number = 0
    while True:
        start = handle.tell()
        line = handle.readline()
        if not line:
            break
        number += 1
        stripped = line.strip()
        if not stripped or stripped.startswith("#") or number <= skip:
            continue
        names = [cell.strip().strip('"').strip() for cell in next(csv.reader([stripped]))]
        while names and not names[-1]:
            names.pop()  # a trailing comma on every line
        if len(names) > 1 and all(is_value(name) for name in names):
            # no header: the first line is the first sample, its columns go by number from 0
            # (read as a header, it was lost without a word)
            handle.seek(start)
            return [str(i) for i in range(len(names))], number - 1, skipped
        if len(names) < 2:
            for mark, word in ((";", "';'"), ("\t", "tabs")):
                if mark in stripped:
                    raise InputError(
                        f"recording '{path}' uses {word} as its delimiter (header {stripped!r}): "
                        "save it comma-separated with '.' decimals"
                    )
            if len(stripped.split()) > 1 and _spaced(handle):
                raise InputError(spaced_cells_message(path, stripped))
        return names, number, skipped
    raise InputError(
        f"recording '{path}' has no header or data: give a header line naming the "
        "columns and one line per sample"
    )


def _spaced(handle) -> bool:
    """Whether the next data line of `handle` (left where it was) holds several cells between spaces."""
    position = handle.tell()
    try:
        for line in iter(handle.readline, ""):
            stripped = line.split("#", 1)[0].strip()
            if stripped:
                return "," not in stripped and len(stripped.split()) > 1
        return False
    finally:
        handle.seek(position)


def _column_index(
    path: pathlib.Path, header: Sequence[str], name: str, role: str, flag_prefix: str = ""
) -> int:
    hits = [i for i, column in enumerate(header) if column == name]
    if not hits and name.isdigit() and int(name) < len(header):
        return int(name)  # a column number from 0
    if len(hits) > 1:
        raise InputError(
            f"recording '{path}' has {len(hits)} columns named '{name}' (columns "
            f"{', '.join(str(i) for i in hits)}, counting from 0), so the {OPTION[role]} column is "
            "ambiguous: rename all but one in the header, or name it by number (--"
            f"{OPTION[role]} {hits[0]})"
        )
    if not hits:
        raise MissingName(
            unknown_name(path, name, role, [c for c in header if c], "column", flag_prefix), role
        )
    return hits[0]


def unknown_name(
    path: pathlib.Path, name: str, role: str, names: Sequence[str], kind: str, prefix: str = ""
) -> str:
    """The message for a mapped name the file lacks: the file's names, a likely one, and the flag to use.

    `prefix` goes before the name in the flag shown (``"u.txt:"`` for a file joined by ``columns``).
    """
    shown = ", ".join(names[:_SHOW_NAMES]) or "none"
    if len(names) > _SHOW_NAMES:
        shown += f", ... ({len(names)} in all)"
    close = likely_names(name, names)[:1]
    hint = f"; did you mean '{close[0]}'?" if close else ""
    # Without a likely name, the column a lab's file usually has in that place (time first, drive
    # second, output last), not the first column whatever the role: that is the time as a rule.
    usual = {"t": 0, "v_in": min(1, len(names) - 1), "w": -1}[role] if names else None
    example = close[0] if close else (names[usual] if usual is not None else "NAME")
    option = OPTION[role]
    # quoted as a shell needs it: a logger's 'Heizspannung [V]' pasted bare is two arguments and a glob
    columns = columns_flag()
    if columns != "--columns" and not prefix:
        # a --test record's names, all of them in --test-columns at once, as its own names suggest
        # (a probe's mapped record took three runs, one role each, and was offered its drive as the time)
        flag = mapping_example(names)
    else:
        flag = (
            f"{columns} {shlex.quote(f'{option}={prefix}{example}')}"
            if prefix or columns != "--columns"
            else f"--{option} {shlex.quote(example)} (or {option}={example} in --columns; in Python "
            f"{option}={example!r})"
        )
    return (
        f"recording '{path}' has no {kind} '{name}' for the {option} (its {kind}s: "
        f"{shown}): give one of those names exactly (names are case-sensitive{hint}), e.g. {flag}"
    )


def likely_names(name: str, names: Sequence[str]) -> list[str]:
    """The names of `names` a user most likely meant by `name`, best first (none may be).

    The same name in another case; a struct's field (``data.u`` for ``u``); a
    name that begins with it or holds it, in any case (``position`` for
    ``pos``); else one within `difflib`'s default similarity.
    """
    low = name.lower()
    same = [n for n in names if n.lower() == low]
    field = [n for n in names if n.rsplit(".", 1)[-1].lower() == low]  # a struct's field, data.u
    starts = [n for n in names if low and n.lower().startswith(low)]
    holds = [n for n in names if low and low in n.lower()]
    lowered = {n.lower(): n for n in names}
    similar = [lowered[n] for n in difflib.get_close_matches(low, list(lowered), n=1)]
    return list(dict.fromkeys(same + field + starts + holds + similar))


def only_column(
    path: pathlib.Path, suffix: str, role: str, reference: str, fill: bool = False
) -> tuple[np.ndarray, tuple[str, ...]]:
    """The one column (array, variable) of a file named whole in ``columns``, and the notes of reading it (a
    preamble skipped); `reference` is how it was named, `fill` as `read_columns`'s."""
    if suffix in (".npz", ".mat"):
        arrays = (npz_arrays(path) if suffix == ".npz" else mat_variables(path))[0]
        names = list(arrays)
        if len(names) == 1:
            column = file_vector(path, names[0], arrays[names[0]]).astype(np.float64)
            kind = "array" if suffix == ".npz" else "variable"
            _refuse_non_finite(path, {role: column}, {role: names[0]}, kind, fill)
            return column, ()
    else:
        names, table, notes = (
            (*npy_table(path), TableNotes())
            if suffix == ".npy"
            else read_text_table(path, {role: "0"}, fill=fill)
        )
        if table.shape[1] == 1:
            _refuse_non_finite(path, {role: table[:, 0]}, {role: names[0]}, "column", fill)
            return table[:, 0], notes.notes
    shown = ", ".join(names[:_SHOW_NAMES]) or "none"
    example = names[0] if names else "NAME"
    return_hint = (
        f"--columns {OPTION[role]}={reference}:{example}" if names else "a file with one column of numbers"
    )
    raise InputError(
        f"recording '{path}' has {len(names)} columns ({shown}), so '{reference}' does not say which is the "
        f"{OPTION[role]}: name the column after a ':', e.g. {return_hint} (columns by name, or by number from 0)"
    )


def read_text_table(
    path: pathlib.Path, wanted: Mapping[str, str] | None = None, flag_prefix: str = "", fill: bool = False
) -> tuple[list[str], np.ndarray, TableNotes]:
    """A plain text table: its column names (the header's, or "0", "1", ... without one) and its numbers.

    The header is found as in a CSV file: the first of the first `PREAMBLE_LINES` lines that
    names every one of `wanted`'s names (role -> column, as `read_columns`; the lines before
    it, a logger's preamble, skipped with a note), else the first line. A footer
    (`footer_start`) is skipped with a note. Every cell must be a finite number: the bad
    ones are refused in one message (the first, its column and role, and how many lines have one);
    with `fill`, a missing value (empty, non-finite) of the drive or output is NaN (`read_columns`).

    Returns:
        ``(names, table, notes)``, ``table`` of shape (rows, len(names)), float64, every cell
        finite (but those `fill` leaves), and `TableNotes` (the line of each row, what was skipped, a
        units row's units).
    """
    names_wanted = [n for n in (wanted or {}).values() if not n.isdigit()]
    lines, notes = _text_lines(path)
    if not lines:
        raise InputError(
            f"recording '{path}' has no numbers: give one line per sample, one column per channel"
        )
    start = _first_line(lines, names_wanted)
    period = lvm_period(lines[:start]) if path.suffix.lower() == ".lvm" else ()
    if start:
        notes.append(
            f"recording '{path}': the {start} line(s) before its header (line {lines[start][0]}) skipped"
        )
        lines = lines[start:]
    names, header, delimiter = _header_of(lines)
    if header and not names[0]:
        notes.append(
            f"recording '{path}': its first column has no name in the header (a row index, as pandas' "
            "to_csv writes one): it is column 0"
        )
    data = lines[1:] if header else lines
    stated: tuple[tuple[str, str], ...] = ()
    units = units_row(_cells(data[0][1], delimiter)) if header and data else None
    if units is not None:  # a logger's second header line (s, V, mm): the columns' units
        stated = tuple((name, unit) for name, unit in zip(names, units) if unit)
        data = data[1:]
    rows = [_cells(line, delimiter) for _, line in data]
    end = footer_start(rows, range(len(names))) if rows else 0
    if end < len(rows):
        notes.append(footer_note(path, data[end:]))
        data, rows = data[:end], rows[:end]
    if not data:
        raise InputError(f"recording '{path}' has a header but no numbers: add one line per sample")
    width = len(rows[0]) if header and all(len(r) == len(rows[0]) < len(names) for r in rows) else len(names)
    names = names[:width]  # LabVIEW leaves its last column (Comment) out of every line
    mapped = {
        _column_index(path, names, name, role, flag_prefix): role for role, name in (wanted or {}).items()
    }
    table = np.empty((len(data), width))
    first: str | None = None  # the first bad cell, what and where
    refused: list[int] = []  # the lines that have one
    missing = False  # whether one is a missing value of the drive or output (--fill-gaps fills it)
    texts = False  # whether one is text, not a missing value
    unread: dict[str, int] = {}  # columns not mapped: how many of their cells are not finite numbers
    for row, ((number, line), values) in enumerate(zip(data, rows)):
        if len(values) < width and delimiter is not None:  # the last cells empty: missing, not cut off
            cells = [c.strip() for c in line.split(delimiter)]
            values = cells[:width] if len(cells) >= width and not any(cells[width:]) else values
        if len(values) != width:
            what = f"{len(names)} names in its header" if header else f"{width} cells on its first line"
            raise InputError(cell_count_message(path, line, number, row, len(values), width, what))
        for col, cell in enumerate(values):
            try:
                value = float(cell) if cell else math.nan
            except ValueError:
                value = None
            if value is not None and math.isfinite(value):
                table[row, col] = value
                continue
            table[row, col] = math.nan
            if col not in mapped:  # a column nothing reads (a comment, a sensor not asked for): left as NaN
                if cell:  # an empty one is said by nothing (another record's, shorter, beside this one)
                    unread[names[col]] = unread.get(names[col], 0) + 1
                continue
            if value is None:
                texts = True
            if value is not None and mapped[col] != "t":  # a missing value of the drive or output
                if fill:
                    continue
                missing = True
            if refused[-1:] != [number]:
                refused.append(number)
            as_role = f" (mapped as {OPTION[mapped[col]]})" if col in mapped else ""
            first = first or (
                f"recording '{path}' has {_cell_problem(values, col)} in column {names[col]!r}{as_role} at "
                f"line {number} (sample {row})"
            )
    at = np.array([n for n, _ in data], dtype=np.int64)  # the file line of each row
    signals = [c for c, r in mapped.items() if r != "t"]
    if not texts and signals and not np.isfinite(table[:, signals]).all():
        refuse_ends_apart(path, table, mapped, {c: names[c] for c in mapped}, at)
        shorter = shorter_record(table, mapped)
        if shorter is not None:  # its tail is no missing value; one before it is the record's own
            notes.append(_shorter_note(path, [names[c] for c in signals], at, shorter))
            table, at = table[:shorter], at[:shorter]
            refused = [k for k in refused if k <= int(at[-1])]
            first = first if refused else None
    if first is not None:
        raise _refusal(first, refused, "every value of a mapped column", missing)
    if unread:
        notes.append(
            f"recording '{path}': "
            + ", ".join(f"column {name!r} has {count} cell(s)" for name, count in unread.items())
            + " that are not finite numbers; not read, as no role maps it"
        )
    return (
        names,
        table,
        TableNotes(at, tuple(notes), units=stated, period=period),
    )


def lvm_period(preamble: Sequence[tuple[int, str]]) -> tuple[float, ...]:
    """The sample period of each channel, s, that a LabVIEW measurement file's header blocks (its `preamble`
    lines) give as ``Delta_X`` where ``X_Columns`` says it writes no time column (``No``): its rows are then
    evenly spaced samples at that period. () where it writes one, or gives no period."""
    keys: dict[str, list[str]] = {}
    for _, line in preamble:
        cells = _cells(line, _delimiter(line))
        keys.setdefault(cells[0].lower(), cells[1:])  # the first segment's
    values = keys.get("delta_x", [])
    if (
        [c.lower() for c in keys.get("x_columns", [])] != ["no"]
        or not values
        or not all(map(is_number, values))
    ):
        return ()
    return tuple(float(v) for v in values)


def text_columns(path: pathlib.Path) -> list[str]:
    """A text table's column names as `read_text_table` gives them (a header's, or "0", "1", … without one),
    read without converting its numbers; [] for a file with no line to read."""
    lines, _ = _text_lines(path)
    return _header_of(lines[_first_line(lines) :])[0] if lines else []


def _first_line(lines: list[tuple[int, str]], names_wanted: Sequence[str] = ()) -> int:
    """The index of a text table's header (or first row) among its `lines`: the first of the first
    `PREAMBLE_LINES` that names every one of `names_wanted`, else the line above its numbers
    (`find_header`, `table_start`: a preamble before it, LabVIEW's header blocks)."""
    rows = [_cells(line, _delimiter(line)) for _, line in lines[: PREAMBLE_LINES + 2]]
    return find_header(rows, names_wanted)


def _header_of(lines: list[tuple[int, str]]) -> tuple[list[str], bool, str | None]:
    """(the column names, whether the first line is a header, the cells' delimiter) of a table's lines."""
    first = lines[0][1]
    delimiter = _delimiter(first if len(lines) == 1 else lines[1][1])
    cells = _cells(first, delimiter)
    header = not all(is_number(c) for c in cells)
    names = [c.strip('"').strip() for c in cells] if header else [str(i) for i in range(len(cells))]
    if (
        header
        and delimiter is not None
        and len(lines) > 1
        and len(_cells(lines[1][1], delimiter)) == len(cells) + 1
    ):
        names = [
            "",
            *names,
        ]  # pandas' to_csv: a row index under an empty name, the line's leading tab stripped
    return names, header, delimiter


def _text_lines(path: pathlib.Path) -> tuple[list[tuple[int, str]], list[str]]:
    """Non-blank, non-comment lines of a text table with their line numbers (from 1), and notes on how the
    text was read (`commented_header`)."""
    text, notes = commented_header(path, decode_text(path, "save it as UTF-8 text"))
    lines = []
    for number, line in enumerate(text.splitlines(), start=1):
        content = line.split("#", 1)[0]
        if content.strip():  # a trailing tab kept: the empty last cell of a tab-separated line
            lines.append((number, content.lstrip().rstrip(" \r\n")))
    return lines, notes


def _delimiter(line: str) -> str | None:
    for mark in (",", ";", "\t"):
        if mark in line:
            return mark
    return None  # spaces


def _cells(line: str, delimiter: str | None) -> list[str]:
    cells = [c.strip() for c in line.split(delimiter)]
    while len(cells) > 1 and not cells[-1] and delimiter is not None:
        cells.pop()  # a trailing delimiter
    return cells


def _diagnose(
    path: pathlib.Path,
    text: str,
    header_line: int,
    units_line: int,
    wanted: Mapping[str, str],
    index: Mapping[str, int],
    fill: bool = False,
    last_line: int | None = None,
) -> None:
    """Find the first bad cell of a mapped column in the file's `text` (commas between cells) and raise
    about it (line from 1, sample from 0), saying how many lines in all have one (`_refusal`). With
    `fill`, a missing value of the drive or output is none (`read_columns`): with no other, no raise.
    `last_line`: the record's last (a shorter record's: `shorter_record`); the lines after it are not read."""
    sample = -1
    first: str | None = None
    lines: list[int] = []
    missing = False  # whether one is a missing value of the drive or output (--fill-gaps fills it)
    with io.StringIO(text) as handle:
        for number, line in enumerate(handle, start=1):
            content = line.split("#", 1)[0].rstrip("\r\n")
            if last_line is not None and number > last_line:
                break
            if number <= header_line or number == units_line or not content:
                continue  # numpy skips empty and comment lines too
            sample += 1
            try:
                cells = next(csv.reader([content]), [""])
            except csv.Error as error:
                raise InputError(
                    f"recording '{path}' cannot be read at line {number} ({error}): save it as a plain CSV file"
                ) from None
            for role, i in index.items():
                problem = _cell_problem(cells, i, dates=role == "t")
                if problem and role != "t" and i < len(cells) and _is_missing(cells[i]):
                    if fill:
                        continue
                    missing = True
                if problem:
                    first = first or (
                        f"recording '{path}' has {problem} in column '{wanted[role]}' (mapped as "
                        f"{OPTION[role]}) at line {number} (sample {sample})"
                    )
                    lines.append(number)
                    break
    if first is not None:
        raise _refusal(first, lines, "every value of a mapped column", missing)


def _refusal(
    first: str, places: Sequence[int], rule: str, missing: bool, samples: bool = False
) -> InputError:
    """One refusal of a table's bad cells, however many: `first` (what the first is, its column and line),
    the lines (or, where the file has none, the `samples`) that have one, the first few of them, and
    the fix. `rule`: the cells that must be finite numbers; `missing`: some are missing values (empty,
    non-finite) of the drive or output, and --fill-gaps is offered (a tracker that lost the tip writes
    many: one message each would take as many tries)."""
    noun, what = ("sample", "value") if samples else ("line", "cell")
    shown = ", ".join(map(str, places[:5])) + (", ..." if len(places) > 5 else "")
    more = f" ({noun}s {shown}: {len(places)} {noun}s have such a {what})" if len(places) > 1 else ""
    fix = (
        f"fix those values, or keep the samples before or after them ({range_flag()} A:B)"
        if samples
        else "fix those cells or delete those lines"
    )
    offer = f" ({FILL_VALUES_HINT})" if missing else ""
    return InputError(f"{first}{more}: {rule} must be a finite number; {fix}{offer}")


def _refuse_non_finite(
    path: pathlib.Path, columns: Mapping[str, np.ndarray], wanted: Mapping[str, str], kind: str, fill: bool
) -> None:
    """Refuse the non-finite values of arrays (an ``.npz``'s, a ``.mat``'s, an ``.npy``'s columns), all in one
    message (`_refusal`), but those of the drive and output with `fill`; `kind` is what the file calls a
    column (array, variable)."""
    found = {role: np.flatnonzero(~np.isfinite(values)) for role, values in columns.items()}
    found = {role: k for role, k in found.items() if k.size and not (fill and role != "t")}
    if not found:
        return
    samples = np.unique(np.concatenate(list(found.values())))
    k = int(samples[0])
    role = next(r for r, bad in found.items() if k in bad)
    first = (
        f"recording '{path}' has a non-finite value ({columns[role][k]}) in {kind} '{wanted[role]}' (mapped as "
        f"{OPTION[role]}) at sample {k}"
    )
    missing = any(r != "t" for r in found)
    raise _refusal(first, [int(j) for j in samples], "every value of a mapped column", missing, samples=True)


def _is_missing(cell: str) -> bool:
    """Whether a cell is a missing value, empty or a non-finite number (a tracker's NaN), not text."""
    try:
        return not math.isfinite(_missing_as_nan(cell))
    except ValueError:
        return False


def _cell_problem(cells: Sequence[str], i: int, dates: bool = False) -> str:
    if i >= len(cells):
        return f"no cell (the line has {len(cells)} cell(s), the column is number {i} counting from 0)"
    cell = cells[i].strip()
    if not cell:
        return "an empty cell (a missing value)"
    try:
        value = float(cell)
    except ValueError:
        if dates and math.isfinite(Clock()(cell)):
            return ""  # a date-time in the time column
        if DECIMAL_COMMA.fullmatch(cell.strip('"')):
            return f"a number with a decimal comma {cell!r} (write '.' decimals, or save with ';' between the cells)"
        return f"a non-numeric cell {cell!r}"
    return "" if math.isfinite(value) else f"a non-finite value {cell!r}"
