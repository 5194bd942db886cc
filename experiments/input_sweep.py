"""A sweep of bad inputs and faults through the real command lines (issue 20).

    python experiments/input_sweep.py [--jobs 2] [--only SUBSTRING] [--root CHECKOUT] [--out experiments/results/input_sweep.json]

`--root` runs the cases against another checkout of the project (e.g. a
`git worktree` of an older commit), for before/after counts.

Every case runs `hybrid …` or `rig …` in a fresh process (`python -m
hybrid.cli`, `python -m rig.cli`) in its own folder, with a timeout, and is
judged by what a lab would see:

- **traceback**: "Traceback (most recent call last)" on stderr;
- **hang**: no exit within the timeout;
- **silent wrong result**: exit 0 where the case must be refused (bad input
  accepted), or a refusal that is not one line with exit status 2;
- **half-written file**: after the run, a leftover temporary file, or an output
  that exists but cannot be loaded back (a model by `load_model`, a recording
  by `Recording.load`);
- **input destroyed**: any input file whose bytes changed.

Cases are built from recordings that are wrong in one way each (file
contents), arguments out of range, and outputs that point at inputs,
folders or nowhere. `expect` is "refuse" (exit 2 and one line on stderr),
"accept" (exit 0, outputs loadable) or "either" (a fault in a column the
command does not read). The counts and every case's outcome go
to `--out` (.json and .md).
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import dataclasses
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
_ROOT = {"path": ROOT}  # the checkout whose commands run (--root)


@dataclasses.dataclass
class Case:
    name: str
    argv: list[str]  # after the program name; {dir} is the case folder
    files: dict[str, bytes]  # inputs written into the case folder
    expect: str  # "refuse" or "accept"
    program: str = "hybrid"
    outputs: tuple[str, ...] = ()  # files that must load after an "accept"
    timeout: float = 240.0


# --------------------------------------------------------------------------- #
# Input files
# --------------------------------------------------------------------------- #


def _good_rows(n=600, rate=30.0, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate
    v = np.repeat(rng.choice([-2.0, 2.0], size=n // 30 + 1), 30)[:n]
    w = np.convolve(v, np.exp(-np.arange(60) / 10.0) / 10.0)[:n] + 0.01 * rng.standard_normal(n)
    return t, v, w


def _csv(t, v, w, header="t,v_in,w", fmt="%.6f", delimiter=","):
    lines = [header] + [delimiter.join(fmt % x for x in row) for row in zip(t, v, w)]
    return ("\n".join(lines) + "\n").encode()


def recording_files() -> dict[str, tuple[bytes, str]]:
    """name → (file bytes, suffix) of recordings that are wrong in one way each (and one good one)."""
    t, v, w = _good_rows()
    files = {"good": (_csv(t, v, w), ".csv")}
    bad = {}
    bad["empty"] = b""
    bad["header_only"] = b"t,v_in,w\n"
    bad["one_row"] = _csv(t[:1], v[:1], w[:1])
    bad["two_rows"] = _csv(t[:2], v[:2], w[:2])
    bad["ten_rows"] = _csv(t[:10], v[:10], w[:10])
    bad["no_header"] = _csv(t, v, w).split(b"\n", 1)[1]
    bad["missing_w"] = ("t,v_in\n" + "\n".join(f"{a},{b}" for a, b in zip(t, v)) + "\n").encode()
    bad["missing_v_in"] = ("t,w\n" + "\n".join(f"{a},{b}" for a, b in zip(t, w)) + "\n").encode()
    bad["semicolon"] = _csv(t, v, w, header="t;v_in;w", delimiter=";")
    bad["tab"] = _csv(t, v, w, header="t\tv_in\tw", delimiter="\t")
    bad["comma_decimal"] = _csv(t, v, w, header="t;v_in;w", delimiter=";").replace(b".", b",")
    bad["nan_w"] = _csv(t, v, np.where(np.arange(len(w)) == 100, np.nan, w))
    bad["nan_v"] = _csv(t, np.where(np.arange(len(v)) == 100, np.nan, v), w)
    bad["nan_t"] = _csv(np.where(np.arange(len(t)) == 100, np.nan, t), v, w)
    bad["inf_w"] = _csv(t, v, np.where(np.arange(len(w)) == 5, np.inf, w))
    bad["text_cell"] = _csv(t, v, w).replace(b"\n0.500000,", b"\nabc,", 1)
    bad["t_backwards"] = _csv(t[::-1], v, w)
    bad["t_duplicate"] = _csv(np.where(np.arange(len(t)) == 50, t[49], t), v, w)
    bad["t_gap"] = _csv(np.where(np.arange(len(t)) >= 300, t + 1.0, t), v, w)
    bad["t_nonuniform"] = _csv(t * (1 + 0.3 * np.sin(np.arange(len(t)))), v, w)
    bad["t_milliseconds"] = _csv(t * 1000.0, v, w)
    bad["constant_w"] = _csv(t, v, np.full_like(w, 1.5))
    bad["constant_v"] = _csv(t, np.full_like(v, 2.0), w)
    bad["zero_v"] = _csv(t, np.zeros_like(v), w)
    bad["binary_garbage"] = bytes(np.random.default_rng(1).integers(0, 256, 4000, dtype=np.uint8))
    bad["ragged_row"] = _csv(t, v, w).replace(b"\n1.000000,", b"\n1.000000\n", 1)
    bad["w_1e300"] = _csv(t, v, w * 1e300, fmt="%.6e")
    bad["fake_mat_v73"] = b"\x89HDF\r\n\x1a\n" + b"\0" * 600
    bad["fake_npz"] = b"PK\x03\x04" + b"\0" * 100
    files.update({k: (b, ".csv") for k, b in bad.items() if not k.startswith("fake")})
    files["fake_mat_v73"] = (bad["fake_mat_v73"], ".mat")
    files["fake_npz"] = (bad["fake_npz"], ".npz")
    files["unknown_suffix"] = (_csv(t, v, w), ".txt")
    return files


# --------------------------------------------------------------------------- #
# Cases
# --------------------------------------------------------------------------- #


#: Faults only in w: `rc` and `sensitivity` read just the drive, so accepting or refusing are both right.
W_ONLY = ("missing_w", "constant_w", "w_1e300", "nan_w", "inf_w")
#: A short or constant drive still has a V_o (`rc`): a step or zero response is a right answer.
DRIVE_ONLY = ("two_rows", "ten_rows", "constant_v", "zero_v")
#: w in another unit: `fit` normalises inside the fit, so the recording is fitted (issue 20).
UNITS_ONLY = ("w_1e300",)


def build_cases() -> list[Case]:
    recs = recording_files()
    cases: list[Case] = []
    good, good_suffix = recs["good"]
    # 1. every bad recording through every command that reads one
    for name, (data, suffix) in recs.items():
        if name == "good":
            continue
        inp = f"rec{suffix}"
        files = {inp: data}
        cases += [
            Case(
                f"fit/{name}",
                ["fit", inp, "--model", "physics", "--max-steps", "2", "--quiet", "--out", "m.eqx"],
                files,
                "accept" if name in UNITS_ONLY else "refuse",
            ),
            Case(
                f"fit-hybrid/{name}",
                ["fit", inp, "--model", "hybrid", "--max-steps", "1", "--quiet", "--out", "m.eqx"],
                files,
                "accept" if name in UNITS_ONLY else "refuse",
            ),
            Case(
                f"rc/{name}",
                ["rc", inp, "--out", "vo.csv"],
                files,
                "either" if name in W_ONLY + DRIVE_ONLY else "refuse",
            ),
            Case(
                f"diagnose/{name}",
                ["diagnose", inp, "--out", "diag", "--max-steps", "1", "--quiet"],
                files,
                "refuse",
            ),
            Case(
                f"sensitivity/{name}",
                ["sensitivity", inp, "--out", "sens", "--duration", "5"],
                files,
                "either" if name in W_ONLY else "refuse",
            ),
        ]
    # 2. arguments out of range
    files = {"rec.csv": good}
    bad_args = {
        "simulate": [
            ["--rate", "0"],
            ["--rate", "-30"],
            ["--rate", "1e9"],
            ["--rate", "nan"],
            ["--duration", "0"],
            ["--duration", "-5"],
            ["--duration", "inf"],
            ["--duration", "nan"],
            ["--duration", "1e9"],
            ["--amplitude", "nan"],
            ["--param", "tau_s=-1"],
            ["--param", "nope=1"],
            ["--param", "xi_rho"],
            ["--drive", "square"],
        ],
        "rc": [
            ["--stages", "0"],
            ["--stages", "-1"],
            ["--stages", "100000"],
            ["--stages", "abc"],
            ["--param", "xi_rho=-1"],
            ["--param", "xi_rho=nan"],
            ["--param", "alpha_E=1.5"],
            ["--param", "C_clamp=abc"],
            ["--param", "nope=1"],
            ["--method", "euler"],
        ],
        "fit": [
            ["--max-steps", "0"],
            ["--max-steps", "-1"],
            ["--starts", "0"],
            ["--starts", "-2"],
            ["--window", "0"],
            ["--window", "1000000"],
            ["--depth", "0"],
            ["--width", "0"],
            ["--split", "1,1,1"],
            ["--split", "0.3,0.5"],
            ["--split", "a,b,c"],
            ["--split", "-0.1,0.6,0.5"],
            ["--param", "nope=1"],
            ["--param", "C_clamp=-1"],
            ["--freeze", "nope"],
            ["--free", "nope"],
            ["--model", "nope"],
            ["--solver", "nope"],
            ["--model", "normal", "--param", "xi_rho=5"],
        ],
        "diagnose": [
            ["--max-steps", "0"],
            ["--max-steps", "-3"],
            ["--blocks", "0"],
            ["--blocks", "-1"],
            ["--blocks", "100000"],
        ],
        "sensitivity": [
            ["--stages", "0"],
            ["--stages", "100000"],
            ["--duration", "0"],
            ["--duration", "-1"],
            ["--rate", "0"],
            ["--noise", "-1"],
            ["--sobol", "-5"],
            ["--param", "nope=1"],
            ["--drive", "nope"],
        ],
        "table2": [["--duration", "0"], ["--duration", "-10"], ["--starts", "0"], ["--max-steps", "0"]],
    }
    base = {
        "simulate": ["simulate", "--drive", "prbs", "--duration", "10", "--out", "sim.csv"],
        "rc": ["rc", "rec.csv", "--out", "vo.csv"],
        "fit": ["fit", "rec.csv", "--model", "physics", "--max-steps", "2", "--quiet", "--out", "m.eqx"],
        "diagnose": ["diagnose", "rec.csv", "--out", "diag", "--quiet"],
        "sensitivity": ["sensitivity", "--out", "sens", "--duration", "5"],
        "table2": ["table2", "--out-dir", "t2", "--quiet"],
    }
    for command, variants in bad_args.items():
        for extra in variants:
            argv = list(base[command])
            for i in range(0, len(extra) - 1, 2):  # an option given twice: argparse keeps the last
                if extra[i] in argv and extra[i] not in ("--param", "--freeze", "--free"):
                    j = argv.index(extra[i])
                    del argv[j : j + 2]
            expect = (
                "either" if extra == ["--depth", "0"] else "refuse"
            )  # no hidden layer: a linear window map
            cases.append(Case(f"args/{command}/{' '.join(extra)}", argv + extra, dict(files), expect))
    # 3. outputs: onto an input, a folder, no suffix, a wrong suffix, nowhere writable
    out_cases = {
        "fit --out input": (
            ["fit", "rec.csv", "--model", "physics", "--max-steps", "2", "--quiet", "--out", "rec.csv"],
            "refuse",
        ),
        "fit --out sidecar of input": (
            [
                "fit",
                "rec.csv",
                "--model",
                "physics",
                "--max-steps",
                "2",
                "--quiet",
                "--out",
                "other.eqx",
                "--json",
                "rec.csv",
            ],
            "refuse",
        ),
        "fit --out folder": (
            ["fit", "rec.csv", "--model", "physics", "--max-steps", "2", "--quiet", "--out", "folder"],
            "refuse",
        ),
        "fit --out no suffix": (
            ["fit", "rec.csv", "--model", "physics", "--max-steps", "2", "--quiet", "--out", "out/strip1"],
            "refuse",
        ),
        "fit --out .csv": (
            ["fit", "rec.csv", "--model", "physics", "--max-steps", "2", "--quiet", "--out", "model.csv"],
            "refuse",
        ),
        "fit --out unwritable": (
            [
                "fit",
                "rec.csv",
                "--model",
                "physics",
                "--max-steps",
                "2",
                "--quiet",
                "--out",
                "/proc/hybrid/m.eqx",
            ],
            "refuse",
        ),
        "rc --out input": (["rc", "rec.csv", "--out", "rec.csv"], "refuse"),
        "rc --out folder": (["rc", "rec.csv", "--out", "folder"], "refuse"),
        "rc --out unwritable": (["rc", "rec.csv", "--out", "/proc/hybrid/vo.csv"], "refuse"),
        "simulate --out folder": (
            ["simulate", "--drive", "prbs", "--duration", "10", "--out", "folder"],
            "refuse",
        ),
        "simulate --out bad suffix": (
            ["simulate", "--drive", "prbs", "--duration", "10", "--out", "sim.xlsx"],
            "refuse",
        ),
        "diagnose --out a file": (["diagnose", "rec.csv", "--out", "rec.csv", "--quiet"], "refuse"),
        "diagnose --out unwritable": (
            ["diagnose", "rec.csv", "--out", "/proc/hybrid/diag", "--quiet"],
            "refuse",
        ),
        "sensitivity --out a file": (
            ["sensitivity", "rec.csv", "--out", "rec.csv", "--duration", "5"],
            "refuse",
        ),
        "table2 --out-dir a file": (
            ["table2", "--out-dir", "rec.csv", "--duration", "10", "--quiet"],
            "refuse",
        ),
        "fit missing input": (["fit", "missing.csv", "--model", "physics", "--quiet"], "refuse"),
        "fit folder input": (["fit", "folder", "--model", "physics", "--quiet"], "refuse"),
        "fit good": (
            [
                "fit",
                "rec.csv",
                "--model",
                "physics",
                "--max-steps",
                "3",
                "--quiet",
                "--out",
                "m.eqx",
                "--json",
                "m.json",
            ],
            "accept",
        ),
        "rc good": (["rc", "rec.csv", "--out", "vo.csv"], "accept"),
        "simulate good": (["simulate", "--drive", "prbs", "--duration", "20", "--out", "sim.csv"], "accept"),
    }
    outputs = {"fit good": ("m.eqx",), "simulate good": ("sim.csv",)}
    for name, (argv, expect) in out_cases.items():
        cases.append(
            Case(
                f"outputs/{name}",
                argv,
                {"rec.csv": good, "folder/.keep": b""},
                expect,
                outputs=outputs.get(name, ()),
            )
        )
    # 4. rig: arguments out of range
    for extra in (
        ["--mm-per-px", "0"],
        ["--mm-per-px", "-0.1"],
        ["--mm-per-px", "nan"],
        ["--clamp", "1"],
        ["--clamp", "a,b"],
        ["--axis", "nan"],
        ["--strip-px", "0"],
        ["--length", "0"],
    ):
        argv = ["track", "video.avi", "--clamp", "100,100", "--mm-per-px", "0.1", "--out", "w.csv"]
        j = argv.index(extra[0]) if extra[0] in argv else None
        if j is not None:
            del argv[j : j + 2]
        cases.append(
            Case(
                f"rig/track {' '.join(extra)}",
                argv + extra,
                {"video.avi": b"RIFF" + b"\0" * 64},
                "refuse",
                program="rig",
            )
        )
    cases.append(
        Case(
            "rig/track missing video",
            ["track", "none.avi", "--clamp", "1,1", "--mm-per-px", "0.1", "--out", "w.csv"],
            {},
            "refuse",
            program="rig",
        )
    )
    cases.append(
        Case(
            "rig/track garbage video",
            ["track", "video.avi", "--clamp", "1,1", "--mm-per-px", "0.1", "--out", "w.csv"],
            {"video.avi": b"garbage" * 100},
            "refuse",
            program="rig",
        )
    )
    for extra in (
        ["--fps", "0"],
        ["--fps", "-30"],
        ["--rate", "0"],
        ["--duration", "0"],
        ["--duration", "-1"],
        ["--speed", "0"],
        ["--exposure", "-1"],
    ):
        argv = ["record", "--virtual", "--drive", "prbs", "--duration", "2", "--out", "r.csv"]
        j = argv.index(extra[0]) if extra[0] in argv else None
        if j is not None:
            del argv[j : j + 2]
        cases.append(Case(f"rig/record {' '.join(extra)}", argv + extra, {}, "refuse", program="rig"))
    return cases


# --------------------------------------------------------------------------- #
# Running and judging
# --------------------------------------------------------------------------- #


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _loads(path: Path) -> bool:
    """True if an output file can be read back as what it claims to be (by this checkout's loaders)."""
    import jax

    jax.config.update("jax_enable_x64", True)  # as the CLI that wrote it
    try:
        if path.suffix == ".eqx":
            from hybrid import load_model

            load_model(path)
        elif path.suffix in (".csv", ".npz", ".mat"):
            from hybrid import Recording

            Recording.load(path)
        return True
    except Exception:
        return False


def run_case(case: Case) -> dict:
    folder = Path(tempfile.mkdtemp(prefix="sweep_"))
    try:
        for rel, data in case.files.items():
            (folder / rel).parent.mkdir(parents=True, exist_ok=True)
            (folder / rel).write_bytes(data)
        before = {rel: _digest(folder / rel) for rel in case.files}
        env = {
            **os.environ,
            "HYBRID_JAX_CACHE": str(Path(tempfile.gettempdir()) / "hybrid_sweep_cache"),
            "PYTHONPATH": str(_ROOT["path"]),
        }
        module = "hybrid.cli" if case.program == "hybrid" else "rig.cli"
        start = time.monotonic()
        try:
            proc = subprocess.run(
                [sys.executable, "-m", module, *case.argv],
                cwd=folder,
                env=env,
                capture_output=True,
                text=True,
                timeout=case.timeout,
                stdin=subprocess.DEVNULL,
            )
            code, stderr = proc.returncode, proc.stderr
        except subprocess.TimeoutExpired:
            code, stderr = "hang", ""
        seconds = time.monotonic() - start
        destroyed = [
            rel for rel in case.files if not (folder / rel).exists() or _digest(folder / rel) != before[rel]
        ]
        leftovers = [
            str(p.relative_to(folder))
            for p in folder.rglob("*")
            if p.is_file() and (".tmp" in p.name or p.name.endswith(".part"))
        ]
        unloadable = [out for out in case.outputs if (folder / out).exists() and not _loads(folder / out)]
        if code == 0 and case.expect == "accept":
            unloadable += [out for out in case.outputs if not (folder / out).exists()]
        traceback = "Traceback (most recent call last)" in stderr
        return {
            "name": case.name,
            "program": case.program,
            "argv": case.argv,
            "expect": case.expect,
            "exit": code,
            "seconds": round(seconds, 1),
            "traceback": traceback,
            "hang": code == "hang",
            "half_written": leftovers + unloadable,
            "inputs_destroyed": destroyed,
            "stderr": stderr[-600:],
        }
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def judge(case: Case, result: dict) -> dict:
    """Set `silent_wrong` of a run's `result` from its exit status and stderr, for `case`'s expectation."""
    code, stderr = result["exit"], result["stderr"]
    error_lines = [line for line in stderr.strip().splitlines() if ": error:" in line]
    if case.expect == "refuse":
        wrong = code == 0 or (code == 2 and len(error_lines) != 1)
    elif case.expect == "accept":
        wrong = code not in (0, "hang") and not result["traceback"]
    else:
        wrong = code not in (0, 2, "hang") or (code == 2 and len(error_lines) != 1)
    return {**result, "expect": case.expect, "silent_wrong": bool(wrong and not result["traceback"])}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--only", default=None, help="run the cases whose name contains this")
    parser.add_argument("--root", default=str(ROOT), help="checkout whose hybrid/ and rig/ run")
    parser.add_argument(
        "--rejudge",
        default=None,
        metavar="JSON",
        help="judge the runs saved in JSON again with today's expectations, run nothing",
    )
    parser.add_argument("--out", default="experiments/results/input_sweep.json")
    args = parser.parse_args(argv)
    _ROOT["path"] = Path(args.root).resolve()
    cases = [c for c in build_cases() if args.only is None or args.only in c.name]
    if args.rejudge:
        saved = {r["name"]: r for r in json.loads(Path(args.rejudge).read_text())["cases"]}
        pairs = [(c, saved[c.name]) for c in cases if c.name in saved]
        print(f"{len(pairs)} saved runs judged again", flush=True)
        runs = (judge(c, r) for c, r in pairs)
    else:
        print(f"{len(cases)} cases, {args.jobs} at a time", flush=True)
        pool = cf.ThreadPoolExecutor(args.jobs)
        runs = (judge(c, r) for c, r in zip(cases, pool.map(run_case, cases)))
    results = []
    for result in runs:
        flags = [k for k in ("traceback", "hang", "silent_wrong") if result[k]]
        flags += ["half_written"] * bool(result["half_written"]) + ["input_destroyed"] * bool(
            result["inputs_destroyed"]
        )
        print(f"{result['name']:60s} exit {result['exit']!s:5s} {','.join(flags) or 'ok'}", flush=True)
        results.append(result)
    counts = {
        "cases": len(results),
        "tracebacks": sum(r["traceback"] for r in results),
        "hangs": sum(r["hang"] for r in results),
        "silent_wrong_results": sum(r["silent_wrong"] for r in results),
        "half_written_files": sum(bool(r["half_written"]) for r in results),
        "inputs_destroyed": sum(bool(r["inputs_destroyed"]) for r in results),
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(
        json.dumps(
            {
                "command": "python experiments/input_sweep.py",
                "root": str(_ROOT["path"]),
                "counts": counts,
                "cases": results,
            },
            indent=2,
        )
        + "\n"
    )
    bad = [
        r
        for r in results
        if r["traceback"] or r["hang"] or r["silent_wrong"] or r["half_written"] or r["inputs_destroyed"]
    ]
    md = [
        "# Bad-input sweep (`python experiments/input_sweep.py`)",
        "",
        " | ".join(f"{k} {v}" for k, v in counts.items()),
        "",
        "| case | exit | what went wrong |",
        "|---|---|---|",
    ]
    for r in bad:
        what = [k for k in ("traceback", "hang", "silent_wrong") if r[k]]
        what += [f"half-written {r['half_written']}"] * bool(r["half_written"])
        what += [f"destroyed {r['inputs_destroyed']}"] * bool(r["inputs_destroyed"])
        md.append(f"| {r['name']} | {r['exit']} | {', '.join(what)} |")
    out.with_suffix(".md").write_text("\n".join(md) + "\n")
    print(json.dumps(counts))
    return 0


if __name__ == "__main__":
    sys.exit(main())
