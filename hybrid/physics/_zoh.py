"""The exact sampled response of a continuous linear system to a zero-order-hold drive.

`zoh_response` (the sampled response from rest) of any continuous realisation
ẋ = Ax + Bu, y = Cx + Du: `hybrid.core._loop_safe_linalg.zoh_discretise` (the
exact ZOH discretisation by one augmented matrix exponential, which the
state-space form's exact step shares), then the discrete system run in blocks
of `ZOH_BLOCK` samples by the core's `lifted_blocks` and `lifted_response`.
The paper's RC network (``method="zoh"``) and `LTI` use it; `BLOCK` is the
block of the RC network's Tustin cascade, which builds its own block matrices.

Matrix products only (`expm` included), so all of this is safe inside
`diagnose`'s batched compiled loops.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from ..core._lifted import lifted_blocks, lifted_response
from ..core._loop_safe_linalg import zoh_discretise

#: Samples per block in `cascade_filter` (the Tustin cascade): ~L + 2K + K²/L multiply-adds per
#: sample for K states, and T/L steps of the block loop. Its block matrices come from running the
#: sections for L samples on L + K excitations, which grows with L (`make bench-quick`).
BLOCK = 16
#: Samples per block in `zoh_response`, whose block matrices come from log₂ L products
#: (`lifted_blocks`): 32, where the block loop's T/L steps, run again in every direction of a
#: forward derivative, are what a longer block saves. The RC network's (46 states) search
#: Jacobians are faster with it (`python benchmarks/stack_jacobian.py`); `LTI(2)`'s barely move.
ZOH_BLOCK = 32


@functools.partial(jax.jit, static_argnames="block")
def zoh_response(A, B, C, D, v_in, dt, block: int = ZOH_BLOCK):
    """Exact sampled response of ẋ = Ax + Bu, y = Cx + Du to a ZOH input, from rest.

    The discretised system x[n+1] = A_d x[n] + B_d u[n], y[n] = C x[n] + D u[n]
    runs lifted to blocks of `block` samples (`lifted_response`) with the
    block matrices of `lifted_blocks`. Compiled as one program: called
    outside `jit` (a simulation run eagerly, a start's check), its few dozen
    operations would each be compiled and dispatched on their own.
    """
    dtype = jnp.result_type(A, v_in)
    Ad, Bd = zoh_discretise(A.astype(dtype), B.astype(dtype), dt)
    return lifted_response(*lifted_blocks(Ad, Bd, C.astype(dtype), D, block), v_in.astype(dtype))
