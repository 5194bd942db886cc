"""Reading the columns of a lab's own file, whatever they are called, for
[`load_mapped`][hybrid.data._mapping.load_mapped].

`read_columns` returns the columns asked for by name (a role such as ``v_in``
-> the file's name for it, such as ``uEst``), the file's rate or period fields
(`RATE_FIELDS`) and its metadata.

* ``.csv``: the header is the first line that is neither blank nor a ``#``
  comment; its names may be quoted, and empty names at its end (a trailing
  comma on every line, as in the Cascaded Tanks and Silverbox files) are
  dropped. Only the mapped columns and the rate fields are converted, by
  numpy's C reader (`numpy.loadtxt` with ``usecols``): 10⁶ rows of three
  columns take about a second and tens of MB. Other columns may hold anything,
  empty cells included. Blank lines and ``#`` comments are skipped. The
  metadata comes from the ``<file>.csv.json`` sidecar when there is one.
* ``.npz`` / ``.mat``: the arrays or variables named; only those must be real
  numeric vectors. The metadata is the ``metadata`` entry, as for
  `Recording.load`.

Every bad mapping or cell raises one [`InputError`][hybrid.InputError]: a name
the file lacks (with the file's names listed), a name the header holds twice,
and a missing, empty, non-numeric or non-finite cell in a mapped column (with
its column, its line in the file, from 1, and its sample, from 0).
"""

from __future__ import annotations

import csv
import difflib
import math
import pathlib
import warnings
from collections.abc import Mapping, Sequence

import numpy as np

from ..util._errors import InputError
from ._loaders import _file_vector, _parse_metadata, _read_text, mat_variables, npz_arrays, sidecar

__all__ = ["OPTION", "RATE_FIELDS", "rate_field", "read_columns"]

#: How each role is asked for: the keyword of `load_mapped` (and the command-line flag).
OPTION: dict[str, str] = {"t": "time", "v_in": "input", "w": "output"}

#: Column, array or metadata names (any case) read as the sampling rate (Hz) or the
#: sampling period (s) when they are not mapped: a single positive number, or a column
#: whose first row holds it and whose other rows are empty, NaN or the same number
#: (the Cascaded Tanks file's ``Ts``). Anything else under these names is ignored.
RATE_FIELDS: dict[str, str] = {
    "fs": "Hz", "rate": "Hz", "rate_hz": "Hz", "sample_rate": "Hz", "sampling_rate": "Hz",
    "ts": "s", "dt": "s", "dt_s": "s", "sample_time": "s", "sampling_time": "s",
}

_SHOW_NAMES = 20


def read_columns(
    path: pathlib.Path, suffix: str, wanted: Mapping[str, str]
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict]:
    """The mapped columns of a file, its rate fields and its metadata.

    Arguments:
        path: the file (already checked to exist, with a known suffix).
        suffix: ``".csv"``, ``".npz"`` or ``".mat"``.
        wanted: role (``t``, ``v_in``, ``w``) -> the file's name for it; distinct names.

    Returns:
        ``(columns, fields, metadata)``: role -> float64 vector (all of one length for
        a CSV file), rate-field name -> its values, and the file's metadata.
    """
    if suffix == ".csv":
        return _read_csv(path, wanted)
    arrays, metadata = npz_arrays(path) if suffix == ".npz" else mat_variables(path)
    kind = "array" if suffix == ".npz" else "variable"
    columns = {}
    for role, name in wanted.items():
        if name not in arrays:
            raise InputError(_unknown(path, name, role, list(arrays), kind))
        columns[role] = _file_vector(path, name, arrays[name]).astype(np.float64)
    fields = {
        key: np.asarray(values, dtype=np.float64).reshape(-1)
        for key, values in arrays.items()
        if key.lower() in RATE_FIELDS and key not in wanted.values()
        and np.asarray(values).dtype.kind in "biuf"
    }
    return columns, fields, metadata


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


def _open(path: pathlib.Path):
    return open(path, encoding="utf-8-sig", newline=None)  # -sig: Excel's byte-order mark


def _read_csv(
    path: pathlib.Path, wanted: Mapping[str, str]
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict]:
    try:
        with _open(path) as handle:
            header, header_line = _header(path, handle)
            index = {role: _column_index(path, header, name, role) for role, name in wanted.items()}
            fields = {
                name: i for i, name in enumerate(header)
                if name.lower() in RATE_FIELDS and i not in index.values() and header.count(name) == 1
            }
            usecols = [*index.values(), *fields.values()]
            lenient = {i: _lenient for i in fields.values()} or None
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)  # "input contained no data"
                table = np.loadtxt(
                    handle, dtype=np.float64, delimiter=",", usecols=usecols, ndmin=2,
                    comments="#", quotechar='"', converters=lenient,
                )
    except InputError:
        raise
    except UnicodeDecodeError:
        raise InputError(f"recording '{path}' is not UTF-8 text: save it as a plain CSV file") from None
    except csv.Error as error:  # a NUL byte in the header
        raise InputError(f"recording '{path}' is not a text table ({error}): save it as a plain CSV file") from None
    except OSError as error:
        raise InputError(
            f"recording '{path}' cannot be read ({error.strerror or error}): check its permissions"
        ) from None
    except ValueError as error:
        _diagnose(path, header_line, wanted, index)
        raise InputError(
            f"recording '{path}' cannot be read as a comma-separated table ({error}): save it "
            "comma-separated with '.' decimals, one header line and one line per sample"
        ) from None
    if table.shape[0] == 0:
        raise InputError(
            f"recording '{path}' has a header but no data lines: add one line per sample"
        )
    k = len(index)
    if not np.isfinite(table[:, :k]).all():
        _diagnose(path, header_line, wanted, index)
    columns = {role: table[:, j] for j, role in enumerate(index)}
    rates = {name: table[:, k + j] for j, name in enumerate(fields)}
    metadata = {}
    meta_path = sidecar(path)
    if meta_path.exists():
        metadata = _parse_metadata(path, _read_text(meta_path), f"'{meta_path.name}'")
    return columns, rates, metadata


def _lenient(cell: str) -> float:
    """A rate field's cell: its number, NaN when empty or not a number."""
    try:
        return float(cell.strip().strip('"') or "nan")
    except ValueError:
        return math.nan


def _header(path: pathlib.Path, handle) -> tuple[list[str], int]:
    """The header's names and its line number; the handle is left after it."""
    for number, line in enumerate(iter(handle.readline, ""), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        names = [cell.strip().strip('"').strip() for cell in next(csv.reader([stripped]))]
        while names and not names[-1]:
            names.pop()  # a trailing comma on every line
        if len(names) < 2:
            for mark, word in ((";", "';'"), ("\t", "tabs")):
                if mark in stripped:
                    raise InputError(
                        f"recording '{path}' uses {word} as its delimiter (header {stripped!r}): "
                        "save it comma-separated with '.' decimals"
                    )
        return names, number
    raise InputError(
        f"recording '{path}' has no header or data: give a header line naming the "
        "columns and one line per sample"
    )


def _column_index(path: pathlib.Path, header: Sequence[str], name: str, role: str) -> int:
    hits = [i for i, column in enumerate(header) if column == name]
    if len(hits) > 1:
        raise InputError(
            f"recording '{path}' has {len(hits)} columns named '{name}' (columns "
            f"{', '.join(str(i + 1) for i in hits)}), so the {OPTION[role]} column is "
            "ambiguous: rename all but one in the header"
        )
    if not hits:
        raise InputError(_unknown(path, name, role, [c for c in header if c], "column"))
    return hits[0]


def _unknown(path: pathlib.Path, name: str, role: str, names: Sequence[str], kind: str) -> str:
    """The message for a mapped name the file lacks: the file's names, and a likely one."""
    shown = ", ".join(names[:_SHOW_NAMES]) or "none"
    if len(names) > _SHOW_NAMES:
        shown += f", ... ({len(names)} in all)"
    same = [n for n in names if n.lower() == name.lower()]
    close = same or difflib.get_close_matches(name, list(names), n=1)
    hint = f"; did you mean '{close[0]}'?" if close else ""
    return (
        f"recording '{path}' has no {kind} '{name}' for the {OPTION[role]} (its {kind}s: "
        f"{shown}): give one of those names exactly (names are case-sensitive{hint})"
    )


def _diagnose(
    path: pathlib.Path, header_line: int, wanted: Mapping[str, str], index: Mapping[str, int]
) -> None:
    """Find the first bad cell of a mapped column and raise about it (line from 1, sample from 0)."""
    sample = -1
    with _open(path) as handle:
        for number, line in enumerate(handle, start=1):
            content = line.split("#", 1)[0].rstrip("\r\n")
            if number <= header_line or not content:
                continue  # numpy skips empty and comment lines too
            sample += 1
            try:
                cells = next(csv.reader([content]), [""])
            except csv.Error as error:
                raise InputError(
                    f"recording '{path}' cannot be read at line {number} ({error}): save it as a plain CSV file"
                ) from None
            for role, i in index.items():
                problem = _cell_problem(cells, i)
                if problem:
                    raise InputError(
                        f"recording '{path}' has {problem} in column '{wanted[role]}' (mapped as "
                        f"{OPTION[role]}) at line {number} (sample {sample}): every value of a "
                        "mapped column must be a finite number; fix that cell or delete the line"
                    )


def _cell_problem(cells: Sequence[str], i: int) -> str:
    if i >= len(cells):
        return f"no cell (the line has {len(cells)} cell(s), the column is number {i + 1})"
    cell = cells[i].strip()
    if not cell:
        return "an empty cell (a missing value)"
    try:
        value = float(cell)
    except ValueError:
        return f"a non-numeric cell {cell!r}"
    return "" if math.isfinite(value) else f"a non-finite value {cell!r}"
