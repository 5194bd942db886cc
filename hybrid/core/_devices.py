"""Independent rows of work on every device at once: `spread_devices`, `device_mesh`, `map_rows`.

On a CPU, JAX has several devices only where an entry point asked for them
(`hybrid.use_cpu_cores`, called by the `hybrid` command); with one device
everything here is what it was, `jax.lax.map`. The search of `diagnose` uses
it for its screens (`hybrid.discovery._starts`: one simulation per design
point) and, dealing lanes out in turn, for its LM lanes
(`hybrid.discovery.fit_lanes`); `hybrid.fit_batch` shards its fits on
`device_mesh` with rows filled by `repeat_last`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, PartitionSpec


def spread_devices() -> list:
    """The devices independent work is spread over: the default backend's local devices."""
    return jax.local_devices()


def device_mesh(axis: str, devices=None) -> Mesh:
    """A one-axis mesh of `devices` (default: `spread_devices()`)."""
    return Mesh(np.array(spread_devices() if devices is None else list(devices)), (axis,))


def repeat_last(x, n: int):
    """`x` with its last row repeated until it has `n` rows: every device gets a full share."""
    return jnp.concatenate([x, jnp.repeat(x[-1:], n - x.shape[0], axis=0)])


def map_rows(one, rows, batch_size: int):
    """``jax.lax.map(one, rows, batch_size=batch_size)``, the rows split among the devices.

    For use inside a traced function (`one` may close over its values). Each
    device maps its own block of rows (consecutive rows; the last row repeated
    to fill the blocks, its copies dropped) with the same `lax.map`, so a row's
    arithmetic is the one it has on a single device.
    """
    devices = spread_devices()
    if len(devices) < 2:
        return jax.lax.map(one, rows, batch_size=batch_size)
    n = jax.tree_util.tree_leaves(rows)[0].shape[0]
    d = len(devices)
    padded = -(-n // d) * d
    rows = jax.tree_util.tree_map(lambda x: repeat_last(x, padded), rows)

    def local(block):
        return jax.lax.map(one, block, batch_size=batch_size)

    spec = PartitionSpec("rows")
    out = jax.shard_map(local, mesh=device_mesh("rows"), in_specs=spec, out_specs=spec, check_vma=False)(rows)
    return jax.tree_util.tree_map(lambda x: x[:n], out)
