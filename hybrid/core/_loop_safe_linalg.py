"""Dense linear algebra from matrix products and reductions only: safe in batched loops.

Why this module exists (issue 20, `experiments/xla_cpu_deadlock.py`): on
jaxlib 0.10.0–0.10.2, a *batched* LAPACK call — the LU solve inside
`jax.scipy.linalg.expm`'s Padé step, `jnp.linalg.solve`, `cho_solve`,
`jnp.linalg.lstsq` — in the body of a compiled loop (`lax.map(...,
batch_size=16)`, a vmapped `while_loop`) that runs beside other multi-threaded
work (matrix products) deadlocks XLA:CPU's intra-op thread pool on a 2-core
machine: every worker parks on a futex and the call never returns. jaxlib
0.4.35–0.9.2 run the same program; pinning the process to one core (a pool of
one thread) avoids it. `hybrid diagnose` on two recordings hung in exactly this
construct (the screens of `hybrid.discovery._starts`, 512 RC networks in batches of 16,
two ZOH discretisations each).

Nothing here calls LAPACK: [`expm`][] is a Taylor polynomial with scaling and
squaring, [`lstsq`][] is modified Gram–Schmidt on the augmented matrix, both
written with `jnp` products and reductions that XLA compiles into plain
kernels. Both are differentiable (forward and reverse) and vmappable.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
from jax import lax

#: Taylor degree of `expm`: with ‖X‖₁ ≤ 1 the truncation error is ≤ 1/19! ≈ 8e-18 (below float64's ε).
TAYLOR_DEGREE = 18
#: Largest 1-norm reached by scaling before the polynomial.
_THETA = 1.0
#: Default cap on squarings: ‖AΔt‖₁ up to 2^30 ≈ 1e9 (beyond it `expm` returns NaN, as jax.scipy's does).
MAX_SQUARINGS = 30


def expm(a, max_squarings: int = MAX_SQUARINGS):
    """e^A of a square matrix by scaling and squaring a degree-18 Taylor polynomial.

    A is scaled by 2^-s so that ‖A/2^s‖₁ ≤ 1, the polynomial is evaluated by
    Paterson–Stockmeyer (8 products: X²…X⁶, then Horner in X⁶), and the
    result squared s times. The squarings are a `lax.scan` of `max_squarings`
    steps, each a `lax.cond` on i < s (a select when vmapped). Agrees with
    `scipy.linalg.expm` within 1e-12 relative on the RC network's stiff, lower
    triangular matrices (`tests/test_loop_safe_linalg.py`). NaN when
    ‖A‖₁ > 2^max_squarings.
    """
    a = jnp.asarray(a)
    n = a.shape[-1]
    norm = jnp.max(jnp.sum(jnp.abs(a), axis=-2), axis=-1)
    s = jnp.clip(jnp.ceil(jnp.log2(jnp.maximum(norm, 1e-300) / _THETA)), 0, None)
    x = a * jnp.exp2(-s).astype(a.dtype)
    eye = jnp.eye(n, dtype=a.dtype)
    powers = [eye, x]
    for _ in range(5):
        powers.append(dot(powers[-1], x))  # X², …, X⁶
    coeffs = [1.0 / math.factorial(k) for k in range(TAYLOR_DEGREE + 1)]
    chunks = [
        sum(coeffs[6 * j + i] * powers[i] for i in range(6) if 6 * j + i <= TAYLOR_DEGREE) for j in range(4)
    ]  # B_j = Σ_i c_{6j+i} X^i
    x6 = powers[6]
    result = chunks[3]
    for j in (2, 1, 0):
        result = dot(result, x6) + chunks[j]

    def square(r, i):
        return lax.cond(i < s, lambda m: dot(m, m), lambda m: m, r), None

    result, _ = lax.scan(square, result, jnp.arange(max_squarings, dtype=s.dtype))
    return jnp.where(s > max_squarings, jnp.nan, result)


def lstsq(design, target, rtol: float = 1e-10):
    """(coefficients, residual sum of squares) of min ‖design·c − target‖ for a few columns.

    Modified Gram–Schmidt on the augmented matrix [design | target] (backward
    stable for least squares, Björck 1967), then back substitution. A column
    whose remaining norm is below `rtol` × its own norm is dependent on the
    ones before it: its coefficient is 0 (like a rank-revealing solve; numpy's
    minimum-norm answer differs only along that null direction, with the same
    residual). For tall designs with a handful of columns (the screens' 2–4).
    """
    design, target = jnp.asarray(design), jnp.asarray(target)
    k = design.shape[1]
    columns = [design[:, j] for j in range(k)] + [target]
    scale = [jnp.sqrt(jnp.sum(c * c)) for c in columns]
    r = [[jnp.zeros((), design.dtype)] * (k + 1) for _ in range(k + 1)]
    keep = []
    for j in range(k):
        norm = jnp.sqrt(jnp.sum(columns[j] * columns[j]))
        ok = norm > rtol * jnp.maximum(scale[j], jnp.finfo(design.dtype).tiny)
        keep.append(ok)
        q = jnp.where(ok, columns[j] / jnp.where(ok, norm, 1.0), 0.0)
        r[j][j] = jnp.where(ok, norm, 1.0)
        for i in range(j + 1, k + 1):
            r[j][i] = jnp.sum(q * columns[i])
            columns[i] = columns[i] - r[j][i] * q
    coef = [jnp.zeros((), design.dtype)] * k
    for j in reversed(range(k)):
        value = (
            r[j][k] - sum((r[j][i] * coef[i] for i in range(j + 1, k)), jnp.zeros((), design.dtype))
        ) / r[j][j]
        coef[j] = jnp.where(keep[j], value, 0.0)
    residual = columns[k]
    return jnp.stack(coef), jnp.sum(residual * residual)


def dot(a, b):
    """a @ b at float64's precision everywhere (no TF32 on GPUs)."""
    return jnp.matmul(a, b, precision=lax.Precision.HIGHEST)


def zoh_discretise(A, B, dt):
    """Exact ZOH discretisation: Ad = e^{AΔt}, Bd = ∫₀^Δt e^{Aτ} dτ B (augmented expm).

    The exponential is `expm` (matrix products only): `jax.scipy.linalg.expm`'s
    LU solve deadlocks jaxlib 0.10's CPU runtime when batched inside a compiled
    loop, as `diagnose`'s screens run it.
    """
    n = A.shape[0]
    M = jnp.zeros((n + 1, n + 1), A.dtype)
    M = M.at[:n, :n].set(A).at[:n, n].set(B)
    E = expm(M * dt)
    return E[:n, :n], E[:n, n]
