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

import jax
import jax.numpy as jnp
from jax import lax
from jaxtyping import Array

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


@functools.partial(jax.jit, static_argnames="block")
def zoh_response(A, B, C, D, v_in, dt, block: int = BLOCK):
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


def lifted_blocks(Ad, Bd, C, D, block: int) -> tuple[Array, Array, Array, Array]:
    """(H, O, A^L, C_L) of the discrete system x[n+1] = Ad x[n] + Bd u[n], y = C x + D u, L = `block`.

    H[i, j] = h[i − j], the Markov parameters h[0] = D, h[k] = C Ad^(k−1) Bd
    (zero above the diagonal); O[i] = C Ad^i; A^L = Ad^L by repeated squaring;
    C_L[:, j] = Ad^(L−1−j) Bd. Only O and the columns of C_L take a product
    per sample (a vector by a matrix); A^L takes log₂ L matrix products:
    ~2Ln² + n³ log₂ L multiply-adds, where a scan of L full n × (n + L)
    products took Ln²(n + L) (for the RC network's n = 46, L = 16: 0.5M
    against 2.1M, paid again in every direction of a forward derivative).
    """
    dot = functools.partial(jnp.matmul, precision=lax.Precision.HIGHEST)

    def observe(row, _):
        return dot(row, Ad), row

    def excite(col, _):
        return dot(Ad, col), col

    _, O = lax.scan(observe, C, None, length=block)  # C Ad^i, i = 0..L−1
    _, powers_b = lax.scan(excite, Bd, None, length=block)  # Ad^k Bd, k = 0..L−1
    markov = jnp.concatenate([jnp.reshape(D, (1,)).astype(Ad.dtype), dot(O[:-1], Bd)])  # h[0..L−1]
    lag = jnp.arange(block)[:, None] - jnp.arange(block)[None, :]
    H = jnp.where(lag >= 0, markov[jnp.clip(lag, 0, block - 1)], 0.0)
    return H, O, _matrix_power(Ad, block, dot), powers_b[::-1].T


def _matrix_power(a, k: int, dot):
    """a^k (k ≥ 1, static) by binary powering: matrix products only."""
    result, base = None, a
    while k:
        if k & 1:
            result = base if result is None else dot(result, base)
        k >>= 1
        if k:
            base = dot(base, base)
    return result
