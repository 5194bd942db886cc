"""Sliding input windows for the D-MLP (paper Sec. II-B).

The sample at time t is predicted from the τ most recent samples of the
mediatory signal, x[t−τ+1 .. t] (τ = 60 at 30 fps: 2 s). Windows are formed
inside one contiguous segment and never reach across its start: a split
boundary is treated like the start of a recording.

Rule for the first τ−1 samples of a segment: the signal is taken to have held
its first value before the segment began (edge padding). For a recording that
starts from rest this is exact; for a segment cut from the middle of a
recording it is the least-informative assumption that uses no sample outside
the segment.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from ._arguments import run_compiled


def sliding_windows(x: Float[Array, " time"], window: int) -> Float[Array, "time window"]:
    """Windows ``out[t] = x[t−window+1 .. t]`` (oldest first), edge-padded at the start."""
    x = jnp.asarray(x)
    padded = jnp.concatenate([jnp.full((window - 1,), x[0], x.dtype), x])
    index = jnp.arange(x.shape[0])[:, None] + jnp.arange(window)[None, :]
    return padded[index]


def segment_windows(
    x: Float[Array, " time"], window: int, segments: tuple[tuple[int, int], ...]
) -> Float[Array, "samples window"]:
    """Windows for each `(start, stop)` segment of `x`, concatenated in order."""
    segments = tuple((int(a), int(b)) for a, b in segments)
    return run_compiled(_segment_windows, x, int(window), segments)


def _segment_windows(x, window, segments):
    return jnp.concatenate([sliding_windows(x[a:b], window) for a, b in segments])
