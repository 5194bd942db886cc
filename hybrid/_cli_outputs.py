"""Where the `hybrid` commands write: every output checked before any work, written only once whole.

Shared by `hybrid.cli` and `hybrid._cli_sensitivity`; the checks themselves live in `hybrid.util._outputs`.
"""

from __future__ import annotations

from pathlib import Path


def out_file(path, option="--out", suffixes=(".csv",), companions=None):
    from .util._outputs import OutputFile

    return OutputFile(Path(path), option, tuple(suffixes), companions)


def out_folder(path, names, option="--out"):
    from .util._outputs import OutputFolder

    return OutputFolder(Path(path), option, tuple(names))


def check_outputs(outputs, inputs=()):
    """Check every output before any work (see hybrid.util._outputs); returns the lock to hold meanwhile."""
    from .util._outputs import prepare_outputs

    return prepare_outputs([o for o in outputs if o is not None], inputs)
