"""The exact sampled response of a continuous linear system to a zero-order-hold drive.

Generic numerics shared by the physics that have a continuous state-space
realisation ẋ = Ax + Bu, y = Cx + Du: `zoh_response` (the sampled response
from rest), run lifted to blocks of `BLOCK` samples by `lifted_response`, on
`hybrid.core._loop_safe_linalg.zoh_discretise` (the exact ZOH discretisation
by one augmented matrix exponential, which the state-space form's exact step
shares). The paper's RC network (``method="zoh"``, and its Tustin
cascade's lifting) and `LTI` use them; neither owns them.

The matrix exponential is `hybrid.core._loop_safe_linalg.expm` (matrix
products only), so all of this is safe inside `diagnose`'s batched compiled loops.
"""

from __future__ import annotations

import functools

import jax.numpy as jnp
from jax import lax

from ..core._loop_safe_linalg import zoh_discretise

BLOCK = 16  # samples per block in `cascade_filter` and `zoh_response`: ~L + 2K + K²/L operations per sample


def lifted_response(H, O, A_L, C, x):
    """Run a linear system lifted to blocks of L samples over `x`, from rest.

    y_j = O x_j + H u_j and x_{j+1} = A^L x_j + C u_j for the blocks u_j of L
    samples (see `hybrid.physics.cascade_filter`, the RC network's Tustin cascade): two matrix products over all blocks and a
    scan of T/L steps.
    """
    block, length = H.shape[0], x.shape[0]
    n_blocks = -(-length // block)
    u = jnp.pad(x, (0, n_blocks * block - length)).reshape(n_blocks, block)
    dot = functools.partial(jnp.matmul, precision=lax.Precision.HIGHEST)  # no TF32 on GPUs
    forced = dot(u, H.T)  # H u_j for every block
    state_input = dot(u, C.T)  # C u_j for every block

    def advance(state, c):
        return dot(A_L, state) + c, state

    _, states = lax.scan(advance, jnp.zeros(A_L.shape[0], x.dtype), state_input)
    return (forced + dot(states, O.T)).reshape(-1)[:length]


def zoh_response(A, B, C, D, v_in, dt, block: int = BLOCK):
    """Exact sampled response of ẋ = Ax + Bu, y = Cx + Du to a ZOH input, from rest.

    The discretised system x[n+1] = A_d x[n] + B_d u[n], y[n] = C x[n] + D u[n]
    runs lifted to blocks of `block` samples (`lifted_response`); its block
    matrices come from `block` steps of the recursion on unit excitations.
    """
    dtype = jnp.result_type(A, v_in)
    Ad, Bd = zoh_discretise(A.astype(dtype), B.astype(dtype), dt)
    n = A.shape[0]
    eye = jnp.eye(block + n, dtype=dtype)

    def step(x, u):
        return Ad @ x + jnp.outer(Bd, u), C @ x + D * u

    # Columns 0..L−1: a unit input at sample i from rest; columns L..L+n−1: unit states, no input.
    final, y = lax.scan(step, eye[block:], eye[:block])
    return lifted_response(y[:, :block], y[:, block:], final[:, block:], final[:, :block], v_in.astype(dtype))
