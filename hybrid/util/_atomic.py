"""Atomic file writes: a file is either its old self or wholly the new one, never half.

Every file the package writes goes through [`staged`][]: the content goes to a
temporary file in the same folder, is flushed and fsync-ed, and only then
renamed over the target with `os.replace` (atomic on POSIX and Windows). A full
disk, a killed process or any other error leaves the previous file at the
target byte for byte and removes the temporary; the error becomes one
[`InputError`][hybrid.InputError] line, e.g.

    cannot write fit.eqx: No space left on device; nothing was changed at fit.eqx

Files that belong together (a model and its ``.json`` description, a CSV
recording and its sidecar) are staged together: every temporary is written
first and only then are all renamed, so a failure while writing changes none.

A command that fails after reading something worth keeping (``rig track`` on a
damaged video) writes it under `partial_path`'s name (``w.partial.csv``),
never over the output the user had: no command replaces a file unless it
succeeded.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

from ._errors import InputError

__all__ = [
    "PARTIAL",
    "atomic_open",
    "describe_targets",
    "partial_path",
    "staged",
    "write_bytes",
    "write_text",
    "write_texts",
]

TEMPORARY_SUFFIX = ".tmp"
#: What a failed command's output is called instead: ``w.csv`` -> ``w.partial.csv``.
PARTIAL = ".partial"
_umask: int | None = None


def _default_mode() -> int:
    """Permissions a new file would get from ``open`` (0o666 less the umask)."""
    global _umask
    if _umask is None:
        _umask = os.umask(0o022)
        os.umask(_umask)
    return 0o666 & ~_umask


def _mode(target: Path) -> int:
    """Keep an existing file's permissions; give a new one the usual ones (mkstemp's are 0600)."""
    try:
        return target.stat().st_mode & 0o7777
    except OSError:
        return _default_mode()


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_folder(folder: Path) -> None:
    """Make the renames durable too (not possible, nor needed, on Windows)."""
    if os.name != "posix":
        return
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _remove(paths) -> None:
    for path in paths:
        with contextlib.suppress(OSError):
            os.unlink(path)


def describe_targets(targets) -> str:
    """``a`` or ``a (and b, c)``: the files a staged write was for, for a message."""
    targets = [Path(t) for t in targets]
    first = str(targets[0])
    rest = [str(t) for t in targets[1:]]
    return first + (f" (and {', '.join(rest)})" if rest else "")


@contextlib.contextmanager
def staged(*targets) -> Iterator[list[Path]]:
    """Temporary paths for `targets`; renamed over them, all together, when the block succeeds.

    Write each target's content to the matching temporary path (it is an empty
    file in the target's folder, ending in the target's own suffix so that
    writers that pick a format by suffix still do). On success every temporary
    is fsync-ed and then renamed over its target; on any error every temporary
    is removed and the targets are left as they were. An `OSError` (full disk,
    no permission, missing folder) becomes one `InputError` line.

    **Arguments:** `targets`: the paths to write (their folders must exist).

    **Yields:** a list of temporary paths, one per target.
    """
    paths = [Path(t) for t in targets]
    temporaries: list[Path] = []
    try:
        for target in paths:
            fd, name = tempfile.mkstemp(
                prefix=f".{target.name}.", suffix=TEMPORARY_SUFFIX + target.suffix, dir=target.parent
            )
            os.close(fd)
            temporaries.append(Path(name))
        yield temporaries
        for temporary, target in zip(temporaries, paths):
            _fsync(temporary)
            os.chmod(temporary, _mode(target))
        for temporary, target in zip(temporaries, paths):
            os.replace(temporary, target)
        for folder in {t.parent for t in paths}:
            _fsync_folder(folder)
    except OSError as error:
        _remove(temporaries)
        reason = error.strerror or str(error)
        raise InputError(
            f"cannot write {describe_targets(paths)}: {reason}; nothing was changed at {paths[0]} "
            "(free some space or choose another folder with write permission)"
        ) from None
    except BaseException:
        _remove(temporaries)
        raise


@contextlib.contextmanager
def atomic_open(target, mode: str = "w", *, encoding: str = "utf-8", newline: str | None = None):
    """A file handle whose content replaces `target` only once it is written whole (see [`staged`][])."""
    binary = "b" in mode  # binary files take no encoding and no newline
    with staged(target) as (temporary,):
        with open(
            temporary, mode, encoding=None if binary else encoding, newline=None if binary else newline
        ) as handle:
            yield handle


def write_text(target, text: str, *, encoding: str = "utf-8") -> Path:
    """Write `text` to `target` atomically; returns the path."""
    with atomic_open(target, "w", encoding=encoding) as handle:
        handle.write(text)
    return Path(target)


def write_bytes(target, data: bytes) -> Path:
    """Write `data` to `target` atomically; returns the path."""
    with atomic_open(target, "wb") as handle:
        handle.write(data)
    return Path(target)


def write_texts(files: dict, *, encoding: str = "utf-8") -> list[Path]:
    """Write several files, each path -> its text, staged together (all or none); returns the paths."""
    targets = list(files)
    with staged(*targets) as temporaries:
        for temporary, target in zip(temporaries, targets):
            with open(temporary, "w", encoding=encoding, newline="") as handle:
                handle.write(files[target])
    return [Path(t) for t in targets]


def partial_path(target, *, taken=()) -> Path:
    """Where a failed command keeps what it read instead of `target`: ``w.csv`` -> ``w.partial.csv``.

    A name that exists already (or whose ``.json`` sidecar does), or is in
    `taken`, is skipped for ``w.partial-2.csv``, ``-3``, ...: a file the
    user had is never replaced, a previous partial output included.
    """
    target = Path(target)
    stem, suffix = (target.stem, target.suffix) if target.suffix else (target.name, "")
    taken = {Path(t) for t in taken}
    for k in range(1, 10_000):
        name = f"{stem}{PARTIAL}{'' if k == 1 else f'-{k}'}{suffix}"
        candidate = target.with_name(name)
        sidecar = candidate.with_name(candidate.name + ".json")
        if candidate not in taken and not candidate.exists() and not sidecar.exists():
            return candidate
    raise InputError(
        f"cannot find a free name for the partial output next to {target}: "
        f"remove old {stem}{PARTIAL}*{suffix} files"
    )
