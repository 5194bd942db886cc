"""Linear recurrences run in blocks of L samples: matrix products over all blocks and a loop of T/L steps.

Generic numerics (no physics): `lifted_response` runs a single-input linear
system given its lifted block matrices (the RC network's Tustin cascade, every
ZOH response of `hybrid.physics._zoh`, the `resonance` effect's mode);
`lifted_blocks` builds them for a discrete system x[n+1] = Ad x[n] + Bd u[n],
y = C x + D u. The loop runs over the blocks' start states only
(`_block_states`), whose derivative is written out so that a forward
derivative's directions multiply whole matrices. Matrix products only: safe in
`diagnose`'s batched compiled loops (see `hybrid.core._loop_safe_linalg`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax
from jaxtyping import Array

from ._loop_safe_linalg import dot


def lifted_response(H, O, A_L, C, x):
    """Run a linear system lifted to blocks of L samples over `x`, from rest.

    y_j = O x_j + H u_j and x_{j+1} = A^L x_j + C u_j for the blocks u_j of L
    samples (see `hybrid.physics.cascade_filter`, the RC network's Tustin
    cascade): two matrix products over all blocks and a scan of T/L steps
    (`_block_states`).
    """
    block, length = H.shape[0], x.shape[0]
    n_blocks = -(-length // block)
    u = jnp.pad(x, (0, n_blocks * block - length)).reshape(n_blocks, block)
    forced = dot(u, H.T)  # H u_j for every block
    states = _block_states(A_L, dot(u, C.T))  # C u_j for every block drives the states
    return (forced + dot(states, O.T)).reshape(-1)[:length]


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
    A_L = power if m == block else _matrix_power(Ad, block)
    markov = jnp.concatenate([jnp.reshape(D, (1,)).astype(Ad.dtype), dot(O[:-1], Bd)])  # h[0..L−1]
    lag = jnp.arange(block)[:, None] - jnp.arange(block)[None, :]
    H = jnp.where(lag >= 0, markov[jnp.clip(lag, 0, block - 1)], 0.0)
    return H, O, A_L, powers_b[:, ::-1]


@jax.custom_jvp
def _block_states(M, c):
    """The states x_0 = 0, x_{j+1} = M x_j + c_j, one row per j (as many as `c` has rows).

    Its derivative is the same recursion driven by dM x_j + dc_j (`_block_states_jvp`):
    the tangents' forcing is one matrix product over every block, outside the loop, and
    the loop carries only M times the tangents' states. Differentiated as it stands, the
    loop would also multiply each direction's own dM by x_j, one block at a time. With
    the doubling of `lifted_blocks` and 32-sample blocks, a search lane's Jacobian (RC
    network, saturation and delay, 9 directions, 9,216 samples) went from 5.1 ms to
    3.3 ms (`python benchmarks/stack_jacobian.py`, before and after 289ac23).
    """

    def advance(state, cj):
        return dot(M, state) + cj, state

    _, states = lax.scan(advance, jnp.zeros(M.shape[0], c.dtype), c)
    return states


@_block_states.defjvp
def _block_states_jvp(primals, tangents):
    M, c = primals
    dM, dc = tangents
    states = _block_states(M, c)
    # Linear in (dM, dc): reverse mode transposes it (the loop runs backwards).
    return states, _block_states(M, dot(states, dM.T) + dc)


def _matrix_power(a, k: int):
    """a^k (k ≥ 1, static) by binary powering: matrix products only."""
    result, base = None, a
    while k:
        if k & 1:
            result = base if result is None else dot(result, base)
        k >>= 1
        if k:
            base = dot(base, base)
    return result
