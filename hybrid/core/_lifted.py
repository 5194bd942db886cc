"""Linear recurrences run in blocks of L samples: matrix products over all blocks and a loop of T/L steps.

Generic numerics (no physics): `lifted_response` runs a single-input linear
system given its lifted block matrices (the RC network's Tustin cascade and
every ZOH response, `hybrid.physics._zoh`); `lifted_states` runs the states of
x_{t+1} = Φ x_t + f_t (the `resonance` effect's mode). Both loop over the
blocks' start states only (`block_states`), whose derivative is written out
so that a forward derivative's directions multiply whole matrices. Matrix
products only: safe in `diagnose`'s batched compiled loops (see
`hybrid.core._loop_safe_linalg`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax

from ._loop_safe_linalg import dot


def lifted_response(H, O, A_L, C, x):
    """Run a linear system lifted to blocks of L samples over `x`, from rest.

    y_j = O x_j + H u_j and x_{j+1} = A^L x_j + C u_j for the blocks u_j of L
    samples (see `hybrid.physics.cascade_filter`, the RC network's Tustin cascade): two matrix products over all blocks and a
    scan of T/L steps (`block_states`).
    """
    block, length = H.shape[0], x.shape[0]
    n_blocks = -(-length // block)
    u = jnp.pad(x, (0, n_blocks * block - length)).reshape(n_blocks, block)
    forced = dot(u, H.T)  # H u_j for every block
    states = block_states(A_L, dot(u, C.T))  # C u_j for every block drives the states
    return (forced + dot(states, O.T)).reshape(-1)[:length]


def lifted_states(Phi, forcing, block: int):
    """The states x_1 … x_T of x_{t+1} = Φ x_t + f_t from x_0 = 0, one row per t (`forcing` is T × n).

    The same numbers as a `lax.scan` of the recurrence, to rounding, computed in
    blocks of L = `block` samples: within a block the states from its own forcing
    are one product with the block-lower-triangular Toeplitz matrix of Φ⁰ … Φ^(L−1)
    (Ln × Ln) for every block at once, the states at the blocks' starts are a loop
    of T/L steps (`block_states`), and each block adds Φ^(m+1) times its start
    state. A forward derivative then runs matrix products and T/L loop steps in
    every direction, where the plain scan ran T steps of small products: for a
    mode of two states (`Resonance`) on 9,216 samples, the whole loop of small
    operations was most of a search lane's Jacobian.
    """
    length, n = forcing.shape
    n_blocks = -(-length // block)
    f = jnp.pad(forcing, ((0, n_blocks * block - length), (0, 0))).reshape(n_blocks, block * n)
    listed, power, m = [jnp.eye(n, dtype=Phi.dtype)], Phi, 1  # Φ^0 … Φ^(L−1), then Φ^L, by doubling
    while m < block:
        listed += [dot(q, power) for q in listed]
        m *= 2
        power = dot(power, power)
    powers = jnp.stack(listed[:block])  # (L, n, n)
    step = matrix_power(Phi, block) if m != block else power  # Φ^L
    lag = jnp.arange(block)[:, None] - jnp.arange(block)[None, :]  # row m (state x_{m+1}), column i (f_i)
    toeplitz = jnp.where((lag >= 0)[:, :, None, None], powers[jnp.clip(lag, 0, block - 1)], 0.0)
    toeplitz = toeplitz.transpose(0, 2, 1, 3).reshape(block * n, block * n)
    within = dot(f, toeplitz.T).reshape(n_blocks, block, n)  # each block's states from its own forcing
    starts = block_states(step, within[:, -1])  # x at each block's start
    carried = jnp.einsum(
        "mij,bj->bmi", jnp.concatenate([powers[1:], step[None]]), starts, precision="highest"
    )
    return (within + carried).reshape(n_blocks * block, n)[:length]


@jax.custom_jvp
def block_states(M, c):
    """The states x_0 = 0, x_{j+1} = M x_j + c_j, one row per j (as many as `c` has rows).

    Its derivative is the same recursion driven by dM x_j + dc_j (`_block_states_jvp`):
    the tangents' forcing is one matrix product over every block, outside the loop, and
    the loop carries only M times the tangents' states. Differentiated as it stands, the
    loop would also multiply each direction's own dM by x_j, one block at a time. With
    the doubling of `lifted_blocks` and 32-sample blocks, a search lane's Jacobian (RC
    network, saturation and delay, 9 directions, 9,216 samples) went from 5.1 ms to
    3.4 ms (`python benchmarks/stack_jacobian.py`).
    """

    def advance(state, cj):
        return dot(M, state) + cj, state

    _, states = lax.scan(advance, jnp.zeros(M.shape[0], c.dtype), c)
    return states


@block_states.defjvp
def _block_states_jvp(primals, tangents):
    M, c = primals
    dM, dc = tangents
    states = block_states(M, c)
    # Linear in (dM, dc): reverse mode transposes it (the loop runs backwards).
    return states, block_states(M, dot(states, dM.T) + dc)


def matrix_power(a, k: int):
    """a^k (k ≥ 1, static) by binary powering: matrix products only."""
    result, base = None, a
    while k:
        if k & 1:
            result = base if result is None else dot(result, base)
        k >>= 1
        if k:
            base = dot(base, base)
    return result
