"""The command line's output paths: checked before any work, never an input, one writer at a time.

A command that computes for minutes must not fail on its ``--out`` at the end,
nor overwrite the recording it read, nor race another process for the same
file. [`prepare_outputs`][] is called by every command before it computes:

- each output file has a suffix the command can write, is not a folder, and
  its folder exists or can be created and is writable (a file is created and
  removed there to make sure);
- each output folder is a folder (or can be created) and is writable;
- no output file, nor its ``<file>.json`` sidecar, is one of the inputs or
  their sidecars (resolved paths and `os.path.samefile`, so links count too);
- an output folder that already holds files of the names the command writes
  holds them because a command of this package wrote them there: each command
  that succeeds lists what it wrote in the folder's ``.hybrid-outputs.json``
  ([`MANIFEST`][]). A name there that no run listed is the user's own (a
  ``report.md`` of theirs, a model they saved by hand): it is refused, never
  replaced; a rerun into a folder of results replaces them;
- then it creates the folders and takes an exclusive lock per output
  (``<file>.lock``, or ``.hybrid.lock`` inside an output folder): a file
  created with ``O_CREAT | O_EXCL`` holding the process id, removed when the
  command ends. A lock whose process is gone is stale and taken over.

Every problem raises one-line [`InputError`][hybrid.InputError]s.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import json
import os
import tempfile
import time
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path

from ._errors import InputError

__all__ = ["OutputFile", "OutputFolder", "lock", "prepare_outputs", "sidecar_of"]

LOCK_SUFFIX = ".lock"
FOLDER_LOCK = ".hybrid.lock"
#: In an output folder: the names this package's commands wrote there (``{"files": [...]}``), the only
#: files of the folder a later command may replace.
MANIFEST = ".hybrid-outputs.json"
#: A lock file younger than this with no readable pid is being written: it is held.
FRESH_LOCK_S = 10.0


@dataclasses.dataclass(frozen=True)
class OutputFile:
    """A file a command writes.

    - `path`: where.
    - `option`: how the user gave it (``"--out"``), for messages.
    - `suffixes`: the suffixes the command can write (lower case, with the dot).
    - `companions`: further files written next to it (e.g. the model's ``.json``);
      by default the sidecar ``<path>.json``.
    """

    path: Path
    option: str
    suffixes: tuple[str, ...]
    companions: tuple[Path, ...] | None = None

    def files(self) -> list[Path]:
        companions = self.companions if self.companions is not None else (sidecar_of(self.path),)
        return [self.path, *companions]


@dataclasses.dataclass(frozen=True)
class OutputFolder:
    """A folder a command writes `names` into (``--out`` of diagnose, sensitivity, table2)."""

    path: Path
    option: str
    names: tuple[str, ...] = ()

    def files(self) -> list[Path]:
        return [self.path / name for name in self.names]


def sidecar_of(path) -> Path:
    """``x.csv`` -> ``x.csv.json``: the metadata sidecar of a recording, the description of a model."""
    path = Path(path)
    return path.with_name(path.name + ".json")


# --------------------------------------------------------------------------- #
# Checks
# --------------------------------------------------------------------------- #


def _existing_ancestor(path: Path) -> Path:
    """The nearest folder of `path` (itself excluded) that exists."""
    parent = path.absolute().parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    return parent


def _check_writable(folder: Path, path: Path, option: str) -> None:
    """Create and remove a file in `folder` (the nearest existing folder of `path`)."""
    if not folder.is_dir():
        raise InputError(
            f"{option} {path}: {folder} is a file, not a folder: choose a path whose folders are folders"
        )
    try:
        fd, name = tempfile.mkstemp(prefix=".hybrid-write-test.", dir=folder)
        os.close(fd)
        os.unlink(name)
    except OSError as error:
        raise InputError(
            f"{option} {path}: cannot write in {folder} ({error.strerror or error}): "
            "choose a folder you can write to"
        ) from None


def _check_file(output: OutputFile) -> None:
    path, option = output.path, output.option
    if str(path).strip() == "":
        raise InputError(f"{option} is empty: give a file name ending in {' or '.join(output.suffixes)}")
    if path.is_dir():
        raise InputError(
            f"{option} {path} is a folder: give a file name inside it, e.g. {path / ('out' + output.suffixes[0])}"
        )
    if path.suffix.lower() not in output.suffixes:
        raise InputError(
            f"{option} {path} has suffix {path.suffix or '(none)'!r} but this command writes "
            f"{' or '.join(output.suffixes)} files: name it e.g. {path.with_suffix(output.suffixes[0]).name}"
        )
    for companion in output.files()[1:]:
        if companion.is_dir():
            raise InputError(
                f"{option} {path}: {companion}, written next to it, is a folder: "
                "remove that folder or choose another name"
            )
    _check_writable(path.parent if path.parent.exists() else _existing_ancestor(path), path, option)


def _check_folder(output: OutputFolder) -> None:
    path, option = output.path, output.option
    if str(path).strip() == "":
        raise InputError(f"{option} is empty: give a folder for the results")
    if path.exists() and not path.is_dir():
        raise InputError(f"{option} {path} is a file, not a folder: give a folder for the results")
    _check_writable(path if path.exists() else _existing_ancestor(path), path, option)
    for file in output.files():
        if file.is_dir():
            raise InputError(
                f"{option} {path}: {file} is a folder but the results need that name: "
                "remove it or choose another folder"
            )
    written = _written(path)
    foreign = [f.name for f in output.files() if f.exists() and f.name not in written]
    if foreign:
        more = f" and {len(foreign) - 3} more" if len(foreign) > 3 else ""
        raise InputError(
            f"{option} {path} already holds {', '.join(foreign[:3])}{more}, which no hybrid command wrote "
            f"there by its record ({MANIFEST} does not list them: your own files, or results of a release "
            "before it kept that list), and this command would replace them: choose a new or empty folder, "
            "or move those files away"
        )


def _written(folder: Path) -> set[str]:
    """The names `MANIFEST` in `folder` lists (none where it is missing or unreadable)."""
    try:
        files = json.loads((folder / MANIFEST).read_text()).get("files", [])
    except (OSError, ValueError, AttributeError):
        return set()
    return {f for f in files if isinstance(f, str)} if isinstance(files, list) else set()


def _record_written(output: OutputFolder) -> None:
    """Add the names of `output` now in its folder to the folder's `MANIFEST` (best effort: a folder
    that cannot take it only makes a later run there refuse those names)."""
    from ._atomic import write_text

    names = sorted(_written(output.path) | {f.name for f in output.files() if f.exists()})
    with contextlib.suppress(OSError, InputError):
        write_text(output.path / MANIFEST, json.dumps({"files": names}, indent=1) + "\n")


def _same(a: Path, b: Path) -> bool:
    if a.resolve() == b.resolve():
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def check_not_inputs(outputs: Sequence[OutputFile | OutputFolder], inputs: Iterable) -> None:
    """Refuse an output file (or the file next to it) that is an input or an input's sidecar."""
    sources = []
    for given in inputs:
        given = Path(given)
        sources += [(given, given), (sidecar_of(given), given)]
    written: list[tuple[Path, OutputFile | OutputFolder]] = []
    for output in outputs:
        for file in output.files():
            for source, given in sources:
                if _same(file, source):
                    subject = "it" if file == output.path else f"{file}, written with it,"
                    target = (
                        f"the input {given}"
                        if source == given
                        else f"{source}, the sidecar of the input {given}"
                    )
                    raise InputError(
                        f"{output.option} {output.path}: {subject} is {target}, which would be "
                        "overwritten: choose another output name"
                    )
            for other, owner in written:
                if _same(file, other):
                    raise InputError(
                        f"{output.option} {output.path} and {owner.option} {owner.path} both write {file}: "
                        "give them different names"
                    )
            written.append((file, output))


# --------------------------------------------------------------------------- #
# Locks
# --------------------------------------------------------------------------- #


def _lock_path(output: OutputFile | OutputFolder) -> Path:
    if isinstance(output, OutputFolder):
        return output.path / FOLDER_LOCK
    return output.path.with_name(output.path.name + LOCK_SUFFIX)


def _alive(pid: int) -> bool:
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process: alive
        return True
    except OSError:
        return False
    return True


def _holder(path: Path) -> int | None:
    """The pid holding the lock at `path`, or None when the lock is stale (or gone)."""
    try:
        text = path.read_text().strip()
        age = time.time() - path.stat().st_mtime
    except OSError:
        return None
    if not text.isdigit():
        return -1 if age < FRESH_LOCK_S else None  # being written right now, or debris
    pid = int(text)
    return pid if _alive(pid) else None


def _acquire(path: Path, what: Path, option: str) -> None:
    for _ in range(3):
        try:
            fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            pid = _holder(path)
            if pid is not None:
                who = f"pid {pid}" if pid > 0 else "pid unknown"
                raise InputError(
                    f"another hybrid process ({who}) is writing {what}: wait until it ends, or give "
                    f"{option} another name (remove {path} if no such process runs)"
                ) from None
            with contextlib.suppress(FileNotFoundError):  # stale: its process is gone
                os.unlink(path)
            continue
        except OSError as error:
            raise InputError(
                f"{option} {what}: cannot create the lock file {path} "
                f"({error.strerror or error}): choose a folder you can write to"
            ) from None
        try:  # a lock without its pid would block the next run (FRESH_LOCK_S): all of it, or no lock
            data = f"{os.getpid()}\n".encode()
            if os.write(fd, data) != len(data):
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            os.close(fd)
        except OSError as error:
            with contextlib.suppress(OSError):
                os.close(fd)
            with contextlib.suppress(OSError):
                os.unlink(path)
            raise InputError(
                f"{option} {what}: cannot write the lock file {path} "
                f"({error.strerror or error}): free some space or choose another folder; "
                f"nothing was changed at {what}"
            ) from None
        return
    raise InputError(f"{option} {what}: could not take the lock {path}: try again")


def _release(path: Path) -> None:
    try:
        if path.read_text().strip() == str(os.getpid()):
            path.unlink()
    except OSError:
        pass


def _missing_folders(folder: Path) -> list[Path]:
    """`folder` and those of its parents that do not exist yet, deepest first."""
    missing = []
    folder = folder.absolute()
    while not folder.exists() and folder != folder.parent:
        missing.append(folder)
        folder = folder.parent
    return missing


@contextlib.contextmanager
def lock(outputs: Sequence[OutputFile | OutputFolder]) -> Iterator[None]:
    """Create the outputs' folders and hold an exclusive lock on each output while the block runs.

    When the block fails, the folders created here are removed again if still empty.
    """
    held: list[Path] = []
    created: list[Path] = []
    try:
        for output in outputs:
            folder = output.path if isinstance(output, OutputFolder) else output.path.parent
            try:
                created += _missing_folders(folder)
                folder.mkdir(parents=True, exist_ok=True)
            except OSError as error:
                raise InputError(
                    f"{output.option} {output.path}: cannot create the folder {folder} "
                    f"({error.strerror or error}): create it or choose another"
                ) from None
            path = _lock_path(output)
            _acquire(path, output.path, output.option)
            held.append(path)
        yield
        for output in outputs:  # the command succeeded: what it wrote may be replaced by its next run
            if isinstance(output, OutputFolder):
                _record_written(output)
    except BaseException:
        for path in reversed(held):
            _release(path)
        held = []
        for folder in created:  # deepest first
            with contextlib.suppress(OSError):
                folder.rmdir()
        raise
    finally:
        for path in reversed(held):
            _release(path)


def prepare_outputs(outputs: Sequence[OutputFile | OutputFolder], inputs: Iterable = ()):
    """Check `outputs` against themselves and `inputs`; return the lock to hold while the command runs.

    Use as ``with prepare_outputs([...], inputs): compute and write``.
    """
    check_not_inputs(outputs, inputs)  # first: the gravest mistake gets the message
    for output in outputs:
        if isinstance(output, OutputFolder):
            _check_folder(output)
        else:
            _check_file(output)
    return lock(outputs)
