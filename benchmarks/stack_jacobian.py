"""The Jacobian a `diagnose` lane takes: an EffectStack's, against the same maths composed by hand.

    python benchmarks/stack_jacobian.py [--repeats 5]

A search lane differentiates the simulation in every direction it fits at
once: the inner simulation's parameters, the effects' and the frame timing's.
`EffectStack` differentiates its inner simulation once per parameter of its
own and multiplies (`inner_response`); the peer is the same function written
by hand from public pieces (the drive-side effects' `apply`, then
`inner.simulate`, then the output-side effects' `apply`), which JAX
differentiates along every direction. Both are `jax.jacfwd` in all the
stack's parameters under one `jax.jit`; compile apart, best of `--repeats`.
The RC network (ZOH, 46 states) and `LTI(2)`, records of 2,048 and 9,216
samples (`diagnose`'s buckets for 60 s and 5 min at 30 Hz). Reports both
times, their ratio and the largest difference relative to max |J|. Writes
`benchmarks/results/stack_jacobian.json`.
"""

from __future__ import annotations

import argparse

import _common as c
import numpy as np

SETS = (("saturation", "delay"), ("drive_saturation", "hysteresis"), ("backlash", "resonance"))
LENGTHS = (2048, 9216)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    jax = c.setup_jax()
    import jax.numpy as jnp

    from hybrid import LTI, RCNetwork, extend, make_drive

    dt = 1 / 30
    rows = []
    for simulation in (RCNetwork(method="zoh"), LTI(2)):
        for effects in SETS:
            flat, by_stack, by_hand = _functions(extend(simulation, *effects), dt)
            for length in LENGTHS:
                v = jnp.asarray(make_drive("prbs", (length + 1) * dt, seed=3).v[:length])
                out = {}
                for label, fn in (("stack", by_stack), ("by_hand", by_hand)):
                    jac = jax.jit(jax.jacfwd(fn))
                    first, J = c.first_call(jac, flat, v)
                    steady, J = c.best_of(jac, flat, v, repeats=args.repeats)
                    out[label] = {"first_call_s": first, "steady_s": steady, "J": np.asarray(J)}
                difference = c.relative_error(out["stack"]["J"], out["by_hand"]["J"])
                row = {
                    "simulation": type(simulation).__name__,
                    "effects": list(effects),
                    "samples": length,
                    "directions": int(flat.size),
                    "stack_ms": 1e3 * out["stack"]["steady_s"],
                    "by_hand_ms": 1e3 * out["by_hand"]["steady_s"],
                    "stack_over_by_hand": out["stack"]["steady_s"] / out["by_hand"]["steady_s"],
                    "stack_first_call_s": out["stack"]["first_call_s"],
                    "by_hand_first_call_s": out["by_hand"]["first_call_s"],
                    "largest_difference_relative": difference,
                }
                rows.append(row)
                print(
                    f"{row['simulation']:10s} {'+'.join(effects):28s} {length:5d} samples, "
                    f"{row['directions']:2d} directions: stack {row['stack_ms']:7.2f} ms, by hand "
                    f"{row['by_hand_ms']:7.2f} ms ({row['stack_over_by_hand']:.2f}x), "
                    f"difference {difference:.1e}",
                    flush=True,
                )
    path = c.write(
        "stack_jacobian.json",
        {"machine": c.machine(), "rows": rows, "command": "python benchmarks/stack_jacobian.py"},
    )
    print(f"wrote {path}")


def _functions(stack, dt):
    """(θ, the stack's output at θ, the same composed by hand): θ is every parameter, flat."""
    import equinox as eqx
    from jax.flatten_util import ravel_pytree

    params, static = eqx.partition(stack, stack.trainable(frozenset()))
    flat, unravel = ravel_pytree(params)

    def by_stack(x, v):
        return eqx.combine(unravel(x), static).simulate(v, dt)

    def by_hand(x, v):
        s = eqx.combine(unravel(x), static)
        u = v
        for e in s.effects:
            if e.place == "drive":
                u = e.apply(u, dt)
        y = s.inner.simulate(u, dt)
        for e in s.effects:
            if e.place == "output":
                y = e.apply(y, dt)
        return y

    return flat, by_stack, by_hand


if __name__ == "__main__":
    main()
