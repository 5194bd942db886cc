"""Long records: seconds per LM step of the hybrid models, and a lab's long file through the command line.

    python benchmarks/long_record.py --per-step [--sizes 100000 1000000] [--physics rc lti:2] [--steps 3]
    python benchmarks/long_record.py [--samples 1000000] [--steps 40]

``--per-step`` (writes `benchmarks/results/long_record_steps.json`): for each
physics (``rc``: the paper's RC network on the virtual IPMC at 30 Hz, a PRBS
drive; ``lti:2``: a second-order LTI on the 100 kHz lab signal below) with the
paper's D-MLP (11 × 10 tanh, window 60; 1,726 weights), and each record length,
a child process builds the least-squares problem the way `hybrid.fit` does (the
default 30/50/20 split: J has m = 0.3 n rows) and times, compile excluded
(``lower().compile()`` first), the LM programs `fit` runs: one `lm_init` (one
JᵀJ), two untimed steps, then `--steps` LM iterations one call each, with the
damping λ raised 10⁶-fold first so that they are accepted steps (each forms
one new JᵀJ: the costly kind; a rejected step only solves again). It reports the median wall
and CPU seconds per step and how many were accepted. Beside it, the same child measures the
machine's float64 matrix-product rate on a block of J's shape: numpy's ``A.T @
A`` (OpenBLAS's symmetric rank-k update, m n²/2 multiply-adds) and XLA's
``J.T @ J`` (m n², a general product), and reports how a step compares with
``m n² / (XLA's rate)``, the time of one full JᵀJ product in XLA.

Without ``--per-step``, a lab's long file through the real command line
(10⁶ samples at 100 kHz, target: within 4 GB):

Writes a CSV the way a lab's logger does (columns ``u_cmd,y_meas``, no time
column, 7 significant digits): the response of a lightly damped second-order
system to band-limited noise, sampled at 100 kHz (the top of the rates the
loader accepts). Then, each in its own process so that each peak is its own:

- ``load``: `hybrid.load_mapped` alone (`--columns`, `--rate`);
- ``fit lti:2``: ``hybrid fit FILE --columns input=u_cmd,output=y_meas --rate
  100000 --physics lti:2 --model physics --max-steps STEPS``;
- ``fit hybrid``: the same with ``--model hybrid`` (lti:2 + the paper's D-MLP,
  1,726 network weights) and 3 LM steps. Its Jacobian is 1,726 columns wide;
  `Problem.normal_equations` folds them into JᵀJ a chunk of rows at a time
  (before it did, this case peaked at 9.1 GB on 10⁶ samples).

Reports each one's wall time and peak resident set size (the child's
``ru_maxrss``, which includes Python, JAX and XLA), against the same command
on a 10× shorter file as the peer, and writes `benchmarks/results/long_record.json`.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import _common as c
import numpy as np
import scipy.signal

RATE = 100_000.0
HYBRID_STEPS = 3  # each LM step of the hybrid model folds 1,726 columns of J over the record
ROOT = Path(__file__).resolve().parents[1]


def write_csv(path: Path, n: int, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    b, a = scipy.signal.butter(4, 2_000.0, fs=RATE)
    u = scipy.signal.lfilter(b, a, rng.normal(size=n))
    u /= np.std(u)
    w0, zeta = 2 * np.pi * 800.0, 0.1  # a mode at 800 Hz
    ad, bd, cd, dd, _ = scipy.signal.cont2discrete(
        scipy.signal.tf2ss([w0**2], [1.0, 2 * zeta * w0, w0**2]), 1.0 / RATE, method="zoh"
    )
    y = scipy.signal.dlsim((ad, bd, cd, dd, 1.0 / RATE), u)[1][:, 0] + 0.01 * rng.normal(size=n)
    with open(path, "w") as f:
        f.write("u_cmd,y_meas\n")
        np.savetxt(f, np.column_stack([u, y]), fmt="%.7g", delimiter=",")


#: Runs argv[1:] and prints that one child's peak RSS (kB) last on stderr: a peak of its own.
_PEAK = (
    "import resource, subprocess, sys; p = subprocess.run(sys.argv[1:]); "
    "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, file=sys.stderr); sys.exit(p.returncode)"
)


def child_peak(argv: list[str]) -> dict:
    """Run argv in its own process: exit status, wall seconds and its peak resident set size (GB)."""
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", _PEAK, *argv], cwd=ROOT, capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    lines = proc.stderr.strip().splitlines()
    out = {"returncode": proc.returncode, "seconds": seconds, "peak_gb": int(lines[-1]) / 1024**2}
    if proc.returncode:
        out["stderr"] = lines[-2:-1]
    return out


def measure(n: int, steps: int, folder: Path) -> dict:
    path = folder / f"long_{n}.csv"
    t0 = time.perf_counter()
    write_csv(path, n)
    cases = {"csv_mb": path.stat().st_size / 1e6, "write_seconds": time.perf_counter() - t0}
    load = (
        "import hybrid, sys; r = hybrid.load_mapped(sys.argv[1], columns='input=u_cmd,output=y_meas', "
        "rate=100000); print(r.n)"
    )
    cases["load"] = child_peak([sys.executable, "-c", load, str(path)])

    def fit(kind: str, max_steps: int, out: Path, *extra: str) -> list[str]:
        """`hybrid fit` of this file with lti:2 and a `kind` model, in a child process."""
        return [sys.executable, "-m", "hybrid.cli", "fit", str(path), "--columns", "input=u_cmd,output=y_meas",
                "--rate", "100000", "--physics", "lti:2", "--model", kind, "--max-steps", str(max_steps),
                "--quiet", "--out", str(out), *extra]  # fmt: skip

    cases["fit lti:2"] = child_peak(
        fit("physics", steps, folder / f"m_{n}.eqx", "--json", str(folder / f"fit_{n}.json"))
    )
    cases["fit hybrid"] = child_peak(fit("hybrid", HYBRID_STEPS, folder / f"h_{n}.eqx"))
    report = folder / f"fit_{n}.json"
    if report.exists():
        fitted = json.loads(report.read_text())
        cases["fit lti:2"]["parameters"] = fitted.get("parameters")
    return cases


# --------------------------------------------------------------------------- seconds per LM step
PER_STEP_OUT = "long_record_steps.json"


def _recording(physics: str, n: int):
    """n samples: the virtual IPMC at 30 Hz under a PRBS drive (``rc``), or the 100 kHz lab signal."""
    import hybrid as hy

    if physics == "rc":
        from hybrid import make_drive
        from hybrid.ipmc import virtual_recording

        return virtual_recording(make_drive("prbs", n / 30.0, rate=30.0, seed=0), seed=0)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "long.csv"
        write_csv(path, n)
        return hy.load_mapped(path, columns="input=u_cmd,output=y_meas", rate=RATE)


def _gemm_rates(m: int, n: int) -> dict:
    """float64 multiply-adds per wall second and per CPU second of AᵀA on a (rows × n) block.

    numpy's ``a.T @ a`` is OpenBLAS's ``dsyrk`` (rows n²/2 multiply-adds); XLA's ``J.T @ J``
    a general product (rows n²). Per CPU second (all threads) is what a loaded machine
    does not change much; per wall second is what a quiet one gives.
    """
    import jax
    import jax.numpy as jnp

    rows = min(m, 8192)
    A = np.random.default_rng(0).normal(size=(rows, n))
    J = jnp.asarray(A)
    product = jax.jit(lambda J: J.T @ J)

    def best(fn, arg):
        jax.block_until_ready(fn(arg))
        walls, cpus = [], []
        for _ in range(3):
            cpu0, t0 = time.process_time(), time.perf_counter()
            jax.block_until_ready(fn(arg))
            walls.append(time.perf_counter() - t0)
            cpus.append(time.process_time() - cpu0)
        return min(walls), min(cpus)

    numpy_s, numpy_cpu = best(lambda a: a.T @ a, A)
    xla_s, xla_cpu = best(product, J)
    return {
        "rows": rows,
        "n": n,
        "numpy_syrk_macs_per_s": rows * n * n / 2 / numpy_s,
        "numpy_syrk_macs_per_cpu_s": rows * n * n / 2 / numpy_cpu,
        "xla_gemm_macs_per_s": rows * n * n / xla_s,
        "xla_gemm_macs_per_cpu_s": rows * n * n / xla_cpu,
    }


def _lm_programs():
    """The batched LM init and run `hybrid.fit` compiles."""
    from hybrid.core import lm_init_batch, lm_run_batch

    return lm_init_batch, lm_run_batch


def per_step_case(physics: str, n: int, steps: int) -> dict:
    """One case in this process: the problem `fit` builds, its LM program compiled, then timed."""
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    import hybrid as hy
    from hybrid import Model
    from hybrid.core import LMSettings, Problem, series_from_recording

    c.setup_jax()
    t0 = time.perf_counter()
    recording = _recording(physics, n)
    simulation = hy.RCNetwork() if physics == "rc" else hy.resolve_physics(physics, [recording])
    model = hy.make_model("hybrid", simulation=simulation, key=jax.random.key(0))
    frozen = frozenset(model.simulation.frozen_by_default)
    series = [series_from_recording(recording)]
    signal = model.mediatory(series[0].v_in, series[0].dt)  # the D-MLP's fixed scalings, as `fit` sets them
    signal = jnp.concatenate([signal[a:b] for a, b in series[0].segments_of("train")])
    model = Model(model.simulation, model.readout.initialise(signal, series[0].target("train")), model.kind)
    problem = Problem(model, series, frozen)
    thetas = problem.flatten(model, frozen)[None]
    settings = LMSettings(max_steps=10_000, patience=40)
    init, run = _lm_programs()
    prepare_s = time.perf_counter() - t0
    out = {
        "physics": physics,
        "samples": n,
        "rows": int(problem.target("train").shape[0]),
        "parameters": int(thetas.shape[1]),
        "prepare_s": prepare_s,
    }

    t0 = time.perf_counter()
    init_c = init.lower(problem, thetas, settings).compile()
    out["compile_init_s"] = time.perf_counter() - t0
    cpu0, t0 = time.process_time(), time.perf_counter()
    states = jax.block_until_ready(init_c(problem, thetas, settings))
    out["init_s"], out["init_cpu_s"] = time.perf_counter() - t0, time.process_time() - cpu0
    # λ × 10⁶: the steps timed are accepted ones (a short step along −g that lowers the cost as
    # predicted), each forming a new JᵀJ — the costly kind; a rejected step only solves again.
    t0 = time.perf_counter()
    run_c = run.lower(problem, states, settings, 1).compile()  # one step per call
    out["compile_run_s"] = time.perf_counter() - t0
    # Two steps first, untimed: after the first, an LM that forms JᵀJ lazily (at the start of the
    # step after an accepted one) has set λ; the second, with λ raised, is accepted. From there
    # every timed step is accepted and forms one JᵀJ, in either design.
    states = jax.block_until_ready(run_c(problem, states, settings, 1))
    states = eqx.tree_at(lambda s: s.lam, states, states.lam * 1e6)
    states = jax.block_until_ready(run_c(problem, states, settings, 1))
    walls, cpus, accepted = [], [], []
    for _ in range(steps):
        cpu0, t0 = time.process_time(), time.perf_counter()
        after = jax.block_until_ready(run_c(problem, states, settings, 1))
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - cpu0)
        accepted.append(bool(after.accepted[0] > states.accepted[0]))
        states = after
    out.update(
        steps=steps,
        accepted=sum(accepted),
        step_wall_s=walls,
        step_cpu_s=cpus,
        seconds_per_step=float(np.median(walls)),
        cpu_seconds_per_step=float(np.median(cpus)),
        cost_after=float(states.cost[0]),
    )
    out["gemm"] = rates = _gemm_rates(out["rows"], out["parameters"])
    full = out["rows"] * out["parameters"] ** 2
    out["jtj_macs"] = full
    out["xla_gemm_jtj_s"] = full / rates["xla_gemm_macs_per_s"]
    out["numpy_syrk_jtj_s"] = full / 2 / rates["numpy_syrk_macs_per_s"]
    out["step_over_xla_gemm_jtj"] = out["seconds_per_step"] / out["xla_gemm_jtj_s"]
    out["step_over_numpy_syrk_jtj"] = out["seconds_per_step"] / out["numpy_syrk_jtj_s"]
    out["xla_gemm_jtj_cpu_s"] = full / rates["xla_gemm_macs_per_cpu_s"]
    out["step_cpu_over_xla_gemm_jtj_cpu"] = out["cpu_seconds_per_step"] / out["xla_gemm_jtj_cpu_s"]
    out["load_average_1_5_15"] = list(os.getloadavg())
    return out


def per_step(args) -> None:
    c.setup_jax()
    results = {
        "command": "python benchmarks/long_record.py --per-step "
        + " ".join(
            [
                f"--sizes {' '.join(map(str, args.sizes))}",
                f"--physics {' '.join(args.physics)}",
                f"--steps {args.steps}",
            ]
        ),
        "machine": c.machine(),
        "cases": [],
    }
    for n in args.sizes:
        for physics in args.physics:
            proc = subprocess.run(
                [sys.executable, __file__, "--case", physics, str(n), "--steps", str(args.steps)],
                cwd=ROOT,
                capture_output=True,
                text=True,
            )
            lines = proc.stdout.strip().splitlines()
            if proc.returncode or not lines:
                case = {
                    "physics": physics,
                    "samples": n,
                    "returncode": proc.returncode,
                    "stderr": proc.stderr.strip().splitlines()[-3:],
                }
            else:
                case = json.loads(lines[-1])
            results["cases"].append(case)
            print(json.dumps(case), flush=True)
    c.write(args.out or PER_STEP_OUT, results)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=1_000_000)
    parser.add_argument(
        "--steps",
        type=int,
        default=None,
        help="LM steps: of the lti:2 fit (default 40), or timed per case with --per-step (default 3)",
    )
    parser.add_argument("--per-step", action="store_true", help="seconds per LM step of the hybrid models")
    parser.add_argument("--sizes", type=int, nargs="+", default=[100_000, 1_000_000])
    parser.add_argument("--physics", nargs="+", default=["rc", "lti:2"])
    parser.add_argument("--out", default=None, help="results file name under benchmarks/results")
    parser.add_argument("--case", nargs=2, metavar=("PHYSICS", "SAMPLES"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.case:
        print(json.dumps(per_step_case(args.case[0], int(args.case[1]), args.steps or 3)), flush=True)
        return
    if args.per_step:
        args.steps = args.steps or 3
        per_step(args)
        return
    args.steps = args.steps or 40
    out = {
        "command": "python benchmarks/long_record.py",
        "machine": c.machine(),
        "target_gb": 4.0,
        "rate_hz": RATE,
    }
    with tempfile.TemporaryDirectory() as tmp:
        for n in (args.samples // 10, args.samples):
            out[str(n)] = measure(n, args.steps, Path(tmp))
            print(n, json.dumps(out[str(n)]), flush=True)
    big = out[str(args.samples)]
    out["within_target"] = all(
        big[k]["returncode"] == 0 and big[k]["peak_gb"] <= 4.0 for k in ("load", "fit lti:2", "fit hybrid")
    )
    c.write("long_record.json", out)


if __name__ == "__main__":
    main()
