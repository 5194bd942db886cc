"""Plumbing every room uses, knowing nothing of models or physics.

One error type for bad input (`InputError`), atomic file writes, checks that an
output path never overwrites an input, the watchdog that turns a stalled command
into an exit, the command line's bounds, and figure saving.
"""

from ._atomic import (
    atomic_open as atomic_open,
)
from ._atomic import (
    describe_targets as describe_targets,
)
from ._atomic import (
    partial_path as partial_path,
)
from ._atomic import (
    staged as staged,
)
from ._atomic import (
    write_bytes as write_bytes,
)
from ._atomic import (
    write_text as write_text,
)
from ._atomic import (
    write_texts as write_texts,
)
from ._errors import InputError as InputError
from ._figures import pyplot as pyplot
from ._figures import save_png as save_png
from ._programs import (
    DIAGNOSE_PROGRAMS as DIAGNOSE_PROGRAMS,
)
from ._programs import (
    ProgramBudget as ProgramBudget,
)
from ._programs import (
    map_limit as map_limit,
)
from ._programs import (
    memory_maps as memory_maps,
)
from ._programs import (
    release_programs as release_programs,
)
