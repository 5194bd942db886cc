"""Writing output files safely: whole or not at all, and never over an input.

`write_atomic` writes to a temporary file in the same folder and renames
it over the target (``os.replace`` is atomic on one file system), so a reader
or a crash never sees half a file; `write_together` does so for files that
belong together (a CSV and its sidecar: both or neither). Both are
`hybrid`'s staged writes (`hybrid.util._atomic`): a full disk names the file,
leaves the previous one byte for byte and no temporary. `partial_path` is
where a failed command keeps what it read (``w.partial.csv``), never over the
user's file; `rename_together` moves a file streamed there (``rig record``'s
CSV and sidecar) onto the output once the command has succeeded, both or
neither. `check_outputs` refuses outputs that are the input itself
(``rig track v.avi --out v.avi``).
"""

from __future__ import annotations

import contextlib
import json
import os
import pathlib

import numpy as np

from hybrid.util import atomic_open, describe_targets, partial_path, write_texts

from ._errors import RigError

__all__ = [
    "check_csv_out",
    "check_outputs",
    "jsonable",
    "partial_path",
    "rename_together",
    "write_atomic",
    "write_json_atomic",
    "write_together",
]


def _folder(path: pathlib.Path) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        in_way = _file_in_way(path)
        if in_way is not None:  # mkdir says only "File exists"
            raise RigError(f"cannot write '{path}': '{in_way}' is a file, not a folder") from None
        raise RigError(f"cannot write '{path}' ({error.strerror or error})") from None


def _file_in_way(path: pathlib.Path) -> pathlib.Path | None:
    """The first of ``path``'s folders that exists as something other than a folder, or None."""
    for folder in reversed(path.parents):
        if folder.exists() and not folder.is_dir():
            return folder
    return None


def write_atomic(path, text: str) -> None:
    """Write ``text`` to ``path`` atomically, with `hybrid`'s writer (temporary file, fsync, ``os.replace``)."""
    path = pathlib.Path(path)
    _folder(path)
    with atomic_open(path, "w", newline="") as out:  # an OSError becomes one InputError line
        out.write(text)


def write_together(files: dict) -> None:
    """Write each path's text, staged together: every file is replaced, or none (`hybrid`'s `write_texts`)."""
    files = {pathlib.Path(path): text for path, text in files.items()}
    for path in files:
        _folder(path)
    write_texts(files)  # an OSError becomes one InputError line naming the files


def _sync(path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def rename_together(moves: dict) -> None:
    """Rename each source (a finished file, streamed elsewhere) onto its target, as `staged` does.

    Every source is fsync-ed and given the permissions of the file it replaces
    before any is renamed, so an error (a full disk, no permission) renames none:
    the sources stay where they are, the targets as they were, and the error is
    one `RigError` line naming the targets. The renames are in one folder
    (``os.replace``, atomic each); the CSV goes first, as in `staged`.
    """
    moves = {pathlib.Path(source): pathlib.Path(target) for source, target in moves.items()}
    folders = [target for target in moves.values() if target.is_dir()]
    if folders:  # os.replace would fail there after the targets before it were replaced
        raise RigError(f"cannot write {describe_targets(list(moves.values()))}: {folders[0]} is a folder")
    try:
        for source, target in moves.items():
            _sync(source)
            if target.exists():
                os.chmod(source, target.stat().st_mode & 0o7777)
        for source, target in moves.items():
            os.replace(source, target)
    except OSError as error:
        raise RigError(
            f"cannot write {describe_targets(list(moves.values()))}: {error.strerror or error}"
        ) from None
    with contextlib.suppress(OSError):  # the renames made durable (POSIX)
        fd = os.open(next(iter(moves.values())).parent, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def jsonable(value):
    """``json.dumps`` default for numpy scalars."""
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"{type(value).__name__} is not JSON-able")


def write_json_atomic(path, data: dict) -> None:
    """Write ``data`` as indented JSON, atomically (`write_atomic`)."""
    write_atomic(path, json.dumps(data, indent=2, default=jsonable) + "\n")


def check_csv_out(out, command: str) -> None:
    """Raise `RigError` unless ``out`` names a CSV file to write (not a folder, not a video or other file type)."""
    if not str(out):
        raise RigError(f"--out is empty: give the CSV file to write, e.g. --out w.csv ({command})")
    out = pathlib.Path(out)
    if out.is_dir() or not out.name:  # `--out .`, `--out /`: no file name to write
        raise RigError(f"--out {out} is a folder: give the CSV file to write, e.g. {out / 'w.csv'}")
    in_way = _file_in_way(out)
    if in_way is not None:
        raise RigError(f"--out {out}: '{in_way}' is a file, not a folder: choose another --out")
    sidecar = out.with_name(out.name + ".json")
    if sidecar.is_dir():  # found only after the recording, with the CSV already renamed onto --out
        raise RigError(
            f"--out {out}: its metadata sidecar {sidecar} is a folder: move it away or choose another --out"
        )
    if out.suffix.lower() != ".csv":
        raise RigError(
            f"--out {out} has suffix '{out.suffix or '(none)'}', but {command} writes a CSV: "
            f"name it e.g. {out.with_suffix('.csv').name}"
        )


def check_outputs(outputs, inputs) -> None:
    """Raise `RigError` if an output path is one of the inputs (the same file, however named)."""
    for out in outputs:
        out = pathlib.Path(out)
        for source in inputs:
            source = pathlib.Path(source)
            same = out.resolve() == source.resolve()
            if not same and out.exists() and source.exists():
                same = os.path.samefile(out, source)
            if same:
                raise RigError(f"output '{out}' is the input '{source}': choose another --out")
