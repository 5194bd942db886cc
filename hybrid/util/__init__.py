"""Plumbing every room uses, knowing nothing of models or physics.

One error type for bad input (`InputError`), atomic file writes, checks that an
output path never overwrites an input, the watchdog that turns a stalled command
into an exit, the command line's bounds, and figure saving.
"""

# Names hybrid's front exports (hybrid/__init__.py) are exported there once; here, what
# experiments and benchmarks use beyond them.
from ._atomic import (
    atomic_open as atomic_open,
    describe_targets as describe_targets,
    partial_path as partial_path,
    staged as staged,
    write_bytes as write_bytes,
    write_text as write_text,
    write_texts as write_texts,
)
from ._figures import pyplot as pyplot, save_png as save_png
from ._outputs import OutputFile as OutputFile, prepare_outputs as prepare_outputs
from ._programs import (
    DIAGNOSE_PROGRAMS as DIAGNOSE_PROGRAMS,
    ProgramBudget as ProgramBudget,
    compile_counter as compile_counter,
    map_limit as map_limit,
    memory_maps as memory_maps,
    release_programs as release_programs,
)
from ._stdout import reader_may_leave as reader_may_leave
from ._watchdog import Watchdog as Watchdog, stage as stage
