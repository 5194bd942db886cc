"""The effects' recurrences as a sequential `lax.scan` against a parallel `lax.associative_scan`.

    python benchmarks/scan_forms.py [--lengths 9000,36000]

A first-order low-pass (back_relaxation's state) and a 2 × 2 linear recurrence
(resonance's), each as `diagnose` uses them: forward-mode Jacobians in the
effect's parameters (`jax.jacfwd`) of 16 lanes under `vmap`, in one
`jax.jit`. For each form: the first call (trace, compile, run) and the best
of 5 steady calls, and the ratios parallel ÷ sequential. The sequential form is
the library's (`hybrid.discovery._effects`); the parallel one is written here,
as the library had it before. Writes `benchmarks/results/scan_forms.json`.
"""

from __future__ import annotations

import argparse

import numpy as np
from _common import best_of, first_call, machine, setup_jax, write

LANES = 16


def _parallel_lowpass(a, s):
    import jax.numpy as jnp
    from jax import lax

    def compose(first, second):
        a1, b1 = first
        a2, b2 = second
        return a2 * a1, a2 * b1 + b2

    return lax.associative_scan(compose, (jnp.broadcast_to(a, s.shape), (1 - a) * s))[1]


def _parallel_linear(phi, forcing):
    import jax.numpy as jnp
    from jax import lax

    def compose(first, second):
        a1, b1 = first
        a2, b2 = second
        return a2 @ a1, jnp.einsum("...ij,...j->...i", a2, b1) + b2

    phis = jnp.broadcast_to(phi, (forcing.shape[0], 2, 2))
    return lax.associative_scan(compose, (phis, forcing))[1]


def _sequential_linear(phi, forcing):
    import jax.numpy as jnp
    from jax import lax

    def step(x, f):
        x = phi @ x + f
        return x, x

    return lax.scan(step, jnp.zeros(2, forcing.dtype), forcing)[1]


def _cases(s, dt):
    """(name, form, function of a 2-vector of parameters) for each recurrence and form."""
    import jax.numpy as jnp

    from hybrid.discovery import affine_recurrence, foh_matrices

    def lowpass(form):
        def run(p):
            a = jnp.exp(-dt / jnp.exp(p[0]))
            y = affine_recurrence(a, (1 - a) * s) if form == "sequential" else _parallel_lowpass(a, s)
            return p[1] * y

        return run

    def linear(form):
        def run(p):
            w, z = 2 * jnp.pi * jnp.exp(p[0]), p[1]
            a = jnp.array([[0.0, 1.0], [-w * w, -2 * z * w]], s.dtype)
            b = jnp.array([0.0, 1.0], s.dtype) * w * w
            phi, g0, _ = foh_matrices(a, b, dt)
            forcing = g0[None, :] * s[:, None]
            x = _sequential_linear(phi, forcing) if form == "sequential" else _parallel_linear(phi, forcing)
            return x[:, 0]

        return run

    for form in ("sequential", "parallel"):
        yield "first_order", form, lowpass(form)
        yield "second_order", form, linear(form)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lengths", default="9000,36000", help="samples, comma-separated")
    args = parser.parse_args(argv)
    jax = setup_jax()
    import jax.numpy as jnp

    dt = 1.0 / 30.0
    rows = []
    for n in (int(x) for x in args.lengths.split(",")):
        s = jnp.asarray(np.cumsum(np.random.default_rng(0).standard_normal(n)) * 0.01)
        lanes = jnp.tile(jnp.array([0.5, 0.2]), (LANES, 1)) + 0.01 * jnp.arange(LANES)[:, None]
        for recurrence, form, run in _cases(s, dt):
            jacobians = jax.jit(jax.vmap(jax.jacfwd(run)))
            first, _ = first_call(jacobians, lanes)
            steady, _ = best_of(jacobians, lanes)
            rows.append(
                {"samples": n, "recurrence": recurrence, "form": form, "first_call_s": first, "run_s": steady}
            )
            print(f"{n:6d} {recurrence:12s} {form:10s} first call {first:6.2f} s, run {1e3 * steady:7.1f} ms")
    ratios = []
    for row in rows:
        if row["form"] == "parallel":
            (seq,) = [
                r
                for r in rows
                if r["form"] == "sequential"
                and r["samples"] == row["samples"]
                and r["recurrence"] == row["recurrence"]
            ]
            ratios.append(
                {
                    "samples": row["samples"],
                    "recurrence": row["recurrence"],
                    "first_call_parallel_over_sequential": row["first_call_s"] / seq["first_call_s"],
                    "run_parallel_over_sequential": row["run_s"] / seq["run_s"],
                }
            )
    for r in ratios:
        print(
            f"{r['samples']:6d} {r['recurrence']:12s} parallel ÷ sequential: first call "
            f"{r['first_call_parallel_over_sequential']:.2f}×, run {r['run_parallel_over_sequential']:.2f}×"
        )
    write("scan_forms.json", {"machine": machine(), "lanes": LANES, "rows": rows, "ratios": ratios})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
