"""The exact sampled response of a continuous linear system to a zero-order-hold drive.

Generic numerics shared by the physics that have a continuous state-space
realisation ẋ = Ax + Bu, y = Cx + Du: `zoh_response` (the sampled response
from rest), run lifted to blocks of `ZOH_BLOCK` samples by `lifted_response`, on
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
from jaxtyping import Array

from ..core._lifted import lifted_response, matrix_power
from ..core._loop_safe_linalg import dot, zoh_discretise

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


def lifted_blocks(Ad, Bd, C, D, block: int) -> tuple[Array, Array, Array, Array]:
    """(H, O, A^L, C_L) of the discrete system x[n+1] = Ad x[n] + Bd u[n], y = C x + D u, L = `block`.

    H[i, j] = h[i − j], the Markov parameters h[0] = D, h[k] = C Ad^(k−1) Bd
    (zero above the diagonal); O[i] = C Ad^i; A^L = Ad^L; C_L[:, j] = Ad^(L−1−j) Bd.
    O and the powers Ad^k Bd come by doubling: with the first m of each and
    P = Ad^m, the next m are O P and P (Ad^k Bd), and P becomes P². That is
    log₂ L rounds of three matrix products, ~2Ln² + n³ log₂ L multiply-adds
    (for the RC network's n = 46, L = 32: 0.6M, where a scan of L full
    n × (n + L) products took 5.3M), and a chain of log₂ L dependent products
    instead of L vector-by-matrix products one after another: a forward
    derivative multiplies whole matrices in every direction at once.
    """
    rows, cols, power, m = C[None, :], Bd[:, None], Ad, 1  # C Ad^i and Ad^k Bd for i, k < m; Ad^m
    while m < block:
        rows = jnp.concatenate([rows, dot(rows, power)])
        cols = jnp.concatenate([cols, dot(power, cols)], axis=1)
        m *= 2
        if m <= block:
            power = dot(power, power)
    O, powers_b = rows[:block], cols[:, :block]
    A_L = power if m == block else matrix_power(Ad, block)
    markov = jnp.concatenate([jnp.reshape(D, (1,)).astype(Ad.dtype), dot(O[:-1], Bd)])  # h[0..L−1]
    lag = jnp.arange(block)[:, None] - jnp.arange(block)[None, :]
    H = jnp.where(lag >= 0, markov[jnp.clip(lag, 0, block - 1)], 0.0)
    return H, O, A_L, powers_b[:, ::-1]
