"""Simulations of a physics: implementations of `hybrid.core`'s `AbstractSimulation`.

The paper's distributed RC network (Eqs 4–14) with its Table 1 strip, the
continuous-time reference that checks its discretisation (diffrax), a generic
stable linear system of order N (`LTI`, ``--physics lti:N``), and
`resolve_physics`, which turns a command line's ``--physics`` into a
simulation (``rc``, ``lti:N``, ``file.py:Class``, ``module:Class``).
"""

# Names hybrid's front exports (hybrid/__init__.py) are exported there once; here, what
# experiments and benchmarks use beyond them.
from ._rc_network import (
    block_matrices as block_matrices,
    cascade_filter as cascade_filter,
    cascade_filter_stage_major as cascade_filter_stage_major,
    tustin_sections as tustin_sections,
)
from ._zoh import BLOCK as BLOCK
