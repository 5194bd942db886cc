"""RC-network simulation (Eqs 4–14, Tustin) against what a user would pick instead.

    python benchmarks/simulate.py [--quick]

Cases, float64, the paper's network (N = 45: 46 first-order sections) at 30 Hz:

- single: one 10⁴-sample PRBS-like drive;
- batch: 1,000 parameter sets (ξρ, C_clamp, α's drawn around the defaults) × the
  same 10⁴-sample drive.

Contenders:

- ``op by op``: `RCNetwork.simulate` called outside jit, as a script calls it in
  a loop, at other parameter values each call (`run_compiled`: one program per
  structure and length; before it, every call compiled its scans again);
- ``hybrid``: `RCNetwork.simulate` (block-lifted cascade, see
  `hybrid.physics._rc_network.cascade_filter`) under `jax.jit`, the parameters as
  arguments, sections computed inside; the batch by `hybrid.simulate_batch`
  (`lax.map` over chunks of 8 `vmap`-ed networks);
- ``stage_major``: the previous implementation (one `lax.scan` per section),
  kept as `cascade_filter_stage_major`;
- ``sosfilt``: `scipy.signal.sosfilt` with the same sections (precomputed, so
  its time is the filter only); the batch is a Python loop over the 1,000 sets;
- ``control``: python-control, the cascade as `control.series` of 46 discrete
  first-order systems, `forced_response` (full run only; batch extrapolated from
  a sub-loop, marked so);
- ``diffrax``: the continuous network ẋ = Ax + Bu with the drive held between
  samples (the same ZOH input as `method="zoh"`), `diffrax.Tsit5` with a PID
  controller (rtol 1e-8), one solve over the whole drive with the sample times
  as jump times (full run only; batch by `vmap` over a sub-batch, extrapolated).

Compile time (first call minus a steady call) is reported apart. Results go to
`benchmarks/results/simulate.json` (full) and the quick numbers to
`benchmarks/results/quick.json` via `benchmarks/quick.py`.
"""

from __future__ import annotations

import argparse
import time

import _common as c
import numpy as np

T = 10_000
BATCH = 1000
DT = 1.0 / 30.0


def drive(n=T, seed=0):
    rng = np.random.default_rng(seed)
    holds = rng.integers(6, 120, size=n // 6 + 1)
    levels = rng.uniform(-2, 2, size=holds.size)
    return np.repeat(levels, holds)[:n]


def networks(n=BATCH, seed=1):
    import hybrid as hy

    rng = np.random.default_rng(seed)
    return [
        hy.RCNetwork(
            xi_rho=float(10 * np.exp(0.5 * rng.normal())),
            alpha_E=float(rng.uniform(0.3, 0.7)),
            alpha_I=float(rng.uniform(0.3, 0.7)),
            alpha_C=float(rng.uniform(0.3, 0.7)),
            C_clamp=float(0.05 * np.exp(0.5 * rng.normal())),
        )
        for _ in range(n)
    ]


def single(repeats=20):
    """One 10⁴-sample series: hybrid, stage-major scan and sosfilt (the quick part)."""
    jax = c.setup_jax()
    import jax.numpy as jnp
    import scipy.signal

    import hybrid as hy
    from hybrid.physics import BLOCK, block_matrices, cascade_filter_stage_major, tustin_sections

    x = drive()
    xj = jnp.asarray(x)
    net = hy.RCNetwork()
    sos = c.sos_sections(net, DT)
    ours = jax.jit(lambda net, v: net.simulate(v, DT))
    old = jax.jit(lambda net, v: cascade_filter_stage_major(*tustin_sections(*net.stage_zpk(), DT), v))
    first, y = c.first_call(ours, net, xj)
    t_ours, y = c.best_of(ours, net, xj, repeats=repeats)
    first_old, _ = c.first_call(old, net, xj)
    t_old, y_old = c.best_of(old, net, xj, repeats=repeats)
    t_sos, ref = c.best_of(lambda v: scipy.signal.sosfilt(sos, v), x, repeats=repeats)
    # where our time goes: building the block matrices H, O, A^L, C alone
    setup = jax.jit(lambda net: block_matrices(*tustin_sections(*net.stage_zpk(), DT), BLOCK))
    c.first_call(setup, net)
    t_setup, _ = c.best_of(setup, net, repeats=repeats)
    # op by op, as a script calls it in a Python loop: other parameter values at every call
    eager = []
    for k in range(6):
        moved = net.replace(xi_rho=10.0 + 0.5 * k)
        start = time.perf_counter()
        np.asarray(moved.simulate(x, DT))
        eager.append(time.perf_counter() - start)
    # interleave a second round so that a load spike on the shared machine hits all alike
    t_ours = min(t_ours, c.best_of(ours, net, xj, repeats=repeats)[0])
    t_sos = min(t_sos, c.best_of(lambda v: scipy.signal.sosfilt(sos, v), x, repeats=repeats)[0])
    return {
        "samples": T,
        "sections": int(sos.shape[0]),
        "hybrid_s": t_ours,
        "hybrid_compile_s": first - t_ours,
        "hybrid_block_matrices_only_s": t_setup,
        "op_by_op_first_call_s": eager[0],
        "op_by_op_later_calls_median_s": float(np.median(eager[1:])),
        "ratio_op_by_op_later_over_jit": float(np.median(eager[1:])) / t_ours,
        "stage_major_s": t_old,
        "stage_major_compile_s": first_old - t_old,
        "sosfilt_s": t_sos,
        "ratio_hybrid_over_sosfilt": t_ours / t_sos,
        "ratio_stage_major_over_sosfilt": t_old / t_sos,
        "relative_error_vs_sosfilt": c.relative_error(y, ref),
        "relative_error_stage_major_vs_sosfilt": c.relative_error(y_old, ref),
    }


def batch(repeats=3, batch_size=8):
    """1,000 parameter sets × 10⁴ samples: hybrid.simulate_batch vs a loop of sosfilt."""
    jax = c.setup_jax()
    import jax.numpy as jnp
    import scipy.signal

    import hybrid as hy
    from hybrid.physics import BLOCK, block_matrices, tustin_sections

    x = drive()
    xj = jnp.asarray(x)
    nets = networks()
    stacked = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *nets)
    soss = [c.sos_sections(n, DT) for n in nets]

    def loop(v):
        return [scipy.signal.sosfilt(s, v) for s in soss]

    run = lambda s, v: hy.simulate_batch(s, v, DT, batch_size=batch_size)
    first, y = c.first_call(run, stacked, xj)
    t_ours, y = c.best_of(run, stacked, xj, repeats=repeats)
    t_loop, refs = c.best_of(loop, x, repeats=repeats)
    t_ours = min(t_ours, c.best_of(run, stacked, xj, repeats=repeats)[0])
    y = np.asarray(y)
    error = max(c.relative_error(y[i], refs[i]) for i in range(0, BATCH, 37))
    out = {
        "parameter_sets": BATCH,
        "samples": T,
        "batch_size": batch_size,
        "hybrid_s": t_ours,
        "hybrid_compile_s": first - t_ours,
        "sosfilt_loop_s": t_loop,
        "speedup_vs_sosfilt_loop": t_loop / t_ours,
        "relative_error_vs_sosfilt_max_of_28": error,
    }
    # the same batch vmapped all at once (memory-bound: every stage touches B × T)
    run_all = lambda s, v: hy.simulate_batch(s, v, DT, batch_size=None)
    first_all, _ = c.first_call(run_all, stacked, xj)
    t_all, _ = c.best_of(run_all, stacked, xj, repeats=2)
    out.update(hybrid_vmap_all_s=t_all, speedup_vmap_all_vs_sosfilt_loop=t_loop / t_all)
    setup = jax.jit(
        lambda s: jax.lax.map(
            lambda n: block_matrices(*tustin_sections(*n.stage_zpk(), DT), BLOCK), s, batch_size=batch_size
        )
    )
    c.first_call(setup, stacked)
    out["hybrid_block_matrices_only_s"] = c.best_of(setup, stacked, repeats=repeats)[0]
    return out


def control_peer(sub=20):
    """python-control: forced_response of the cascade built by control.series."""
    import control
    import scipy.signal

    c.setup_jax()
    x = drive()
    nets = networks()[:sub]
    t_in = np.arange(T) * DT

    def system(net):
        G, Z, P = (np.asarray(a) for a in net.stage_zpk())
        sys = None
        for g, z, p in zip(G, Z, P):
            zd, pd, kd = scipy.signal.bilinear_zpk([-z], [-p], g, fs=1.0 / DT)
            section = control.tf([kd, -kd * zd[0]], [1.0, -pd[0]], DT)
            section = control.tf2ss(section)
            sys = section if sys is None else control.series(sys, section)
        return sys

    build = time.perf_counter()
    systems = [system(n) for n in nets]
    build = (time.perf_counter() - build) / sub
    t0 = time.perf_counter()
    outs = [control.forced_response(s, T=t_in, U=x).outputs for s in systems]
    per = (time.perf_counter() - t0) / sub
    ref = scipy.signal.sosfilt(c.sos_sections(nets[0], DT), x)
    return {
        "single_s": per,
        "build_system_s": build,
        "batch_s_extrapolated": per * BATCH,
        "batch_measured_on": sub,
        "relative_error_vs_sosfilt": c.relative_error(outs[0], ref),
    }


def diffrax_peer(sub=8, rtol=1e-8):
    """diffrax: the continuous network with the drive held between samples (ZOH)."""
    jax = c.setup_jax()
    import diffrax
    import jax.numpy as jnp

    import hybrid as hy

    x = jnp.asarray(drive())
    t_samples = jnp.arange(T) * DT
    nets = networks()[:sub]

    def solve(net, v):
        A, B, C, D = net.state_space()

        def field(t, state, args):
            k = jnp.clip(jnp.floor(t / DT + 1e-9).astype(int), 0, T - 1)
            return A @ state + B * v[k]

        sol = diffrax.diffeqsolve(
            diffrax.ODETerm(field),
            diffrax.Tsit5(),
            0.0,
            (T - 1) * DT,
            DT / 2,
            jnp.zeros(A.shape[0]),
            saveat=diffrax.SaveAt(ts=t_samples),
            stepsize_controller=diffrax.PIDController(rtol=rtol, atol=rtol * 1e-2, jump_ts=t_samples),
            max_steps=20 * T,
        )
        return sol.ys @ C + D * v

    one = jax.jit(solve)
    first, y = c.first_call(one, nets[0], x)
    t_one, y = c.best_of(one, nets[0], x, repeats=2)
    zoh = hy.RCNetwork(**{k: float(v) for k, v in nets[0].parameters().items()}, method="zoh")
    reference = np.asarray(zoh.simulate(x, DT))
    stacked = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *nets)
    many = jax.jit(jax.vmap(solve, (0, None)))
    first_many, _ = c.first_call(many, stacked, x)
    t_many, _ = c.best_of(many, stacked, x, repeats=1)
    return {
        "single_s": t_one,
        "compile_s": first - t_one,
        "rtol": rtol,
        "relative_error_vs_exact_zoh": c.relative_error(y, reference),
        "batch_vmap_s_extrapolated": t_many / sub * BATCH,
        "batch_measured_on": sub,
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="single + batch vs sosfilt only")
    args = parser.parse_args()
    c.setup_jax()  # before c.machine(), which records x64
    out = {"command": "python benchmarks/simulate.py", "machine": c.machine()}
    out["single"] = single()
    print("single", out["single"], flush=True)
    out["batch"] = batch()
    print("batch", out["batch"], flush=True)
    if not args.quick:
        out["control"] = control_peer()
        print("control", out["control"], flush=True)
        out["diffrax"] = diffrax_peer()
        print("diffrax", out["diffrax"], flush=True)
    out["machine_after"] = c.machine()["load_average_1_5_15"]
    c.write("simulate.json", out)


if __name__ == "__main__":
    main()
