"""Writing recording files that `read_file` reads
back exactly: ``.csv`` (every channel at 17 significant digits, plus a
``<file>.csv.json`` metadata sidecar), ``.npz`` and ``.mat``.

`write_file` (behind `Recording.save
<hybrid.data._recording.Recording.save>`) writes to temporaries and renames
them over the targets once complete (`hybrid.util._atomic`), so a failed
write leaves what was there unchanged.
"""

from __future__ import annotations

import json
import pathlib
import re
from typing import TYPE_CHECKING, Any

import numpy as np

from ..util._errors import InputError
from ._loaders import NPZ_EXTRA, file_suffix, sidecar

if TYPE_CHECKING:
    from ._recording import Recording

__all__ = ["write_file"]

_MAT_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,62}")


def write_file(recording: Recording, path: pathlib.Path) -> None:
    """Write ``recording`` to ``path`` in the format its suffix names; see `Recording.save`."""
    from ..util._atomic import staged

    writer = {".csv": _save_csv, ".npz": _save_npz, ".mat": _save_mat}[file_suffix(path)]
    targets = (path, sidecar(path)) if writer is _save_csv else (path,)
    with staged(*targets) as temporaries:
        writer(recording, *temporaries)


def _save_csv(recording: Recording, path: pathlib.Path, meta_path: pathlib.Path | None = None) -> None:
    channels = recording.channels
    table = np.column_stack(list(channels.values()))
    np.savetxt(path, table, fmt="%.17g", delimiter=",", header=",".join(channels), comments="")
    meta_path = sidecar(path) if meta_path is None else meta_path
    meta_path.write_text(json.dumps(recording.metadata, indent=2) + "\n", encoding="utf-8")


def _save_npz(recording: Recording, path: pathlib.Path) -> None:
    # Any: numpy's stub checks **arrays against savez's `allow_pickle: bool` too
    arrays: dict[str, Any] = {"t": recording.t, "v_in": recording.v_in, "w": recording.w}
    arrays |= {NPZ_EXTRA + c: v for c, v in recording.extra.items()}
    arrays["metadata"] = np.array(json.dumps(recording.metadata))
    with open(path, "wb") as handle:  # an open file stops numpy appending .npz
        np.savez(handle, **arrays)


def _save_mat(recording: Recording, path: pathlib.Path) -> None:
    import scipy.io

    bad = [c for c in recording.extra if not _MAT_NAME.fullmatch(c)]
    if bad:
        raise InputError(
            f"recording '{recording.name}' has extra channel(s) {', '.join(bad)} "
            "that are not MATLAB variable names: rename them (letter first, then "
            "letters, digits or _, at most 63) or save as .csv or .npz"
        )
    variables: dict[str, Any] = dict(recording.channels)
    variables["metadata"] = json.dumps(recording.metadata)  # ASCII: MATLAB-safe
    scipy.io.savemat(str(path), variables, oned_as="column")
