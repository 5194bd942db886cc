"""How long a command takes before it does anything: `hybrid --help` against importing what it is built on.

    python benchmarks/startup.py [--repeats 7]

Every `hybrid` command, and every process of a script or a test that imports
the library, pays its import first. Measured in this one run, on this machine,
each process started afresh and the kinds interleaved (so that a drift of the
machine's speed reaches all of them alike); the median over the repeats:

- ``import_jax_s``: ``python -c "import jax"``: what any JAX program pays;
- ``import_jax_equinox_s``: ``python -c "import jax, equinox"``, the peer: the two libraries
  `import hybrid` needs (optimistix, diffrax, optax and scipy's modules are imported where used);
- ``import_hybrid_s``: ``python -c "import hybrid"``;
- ``cli_help_s``: ``python -m hybrid.cli --help`` (the command's own start);
- ``cli_help_over_import_jax_equinox``: target ≤ 1.3 (the project's own modules add at most 30 %).

Before scipy.signal, scipy.stats, scipy.optimize, scipy.linalg and optax were
imported only where they are used, ``hybrid --help`` took 1.99 s (2.33× the peer)
against 1.07 s (1.21×) after: this script on both commits, docs/benchmarks.md;
`tests/test_architecture.py` checks that the import stays without them. Writes
`benchmarks/results/startup.json`.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time

import _common as c

COMMANDS = {
    "import_jax_s": [sys.executable, "-c", "import jax"],
    "import_jax_equinox_s": [sys.executable, "-c", "import jax, equinox"],
    "import_hybrid_s": [sys.executable, "-c", "import hybrid"],
    "cli_help_s": [sys.executable, "-m", "hybrid.cli", "--help"],
}


#: Python may keep each module's compiled bytecode (`__pycache__`), as an installed package has it: a
#: shell that sets PYTHONDONTWRITEBYTECODE (this project's sandbox does) would otherwise have every
#: process compile all the sources again (~0.2 s of hybrid's import, measured with cProfile).
ENV = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}


def _seconds(command) -> float:
    t0 = time.perf_counter()
    subprocess.run(command, check=True, capture_output=True, env=ENV)
    return time.perf_counter() - t0


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args(argv)
    c.setup_jax()
    for command in COMMANDS.values():  # one run each first: files cached, bytecode written, as a user's are
        _seconds(command)
    times: dict[str, list[float]] = {key: [] for key in COMMANDS}
    for _ in range(args.repeats):
        for key, command in COMMANDS.items():
            times[key].append(_seconds(command))
    out = {"command": "python benchmarks/startup.py", "machine": c.machine(), "repeats": args.repeats}
    out.update({key: statistics.median(values) for key, values in times.items()})
    out["all_s"] = times
    out["cli_help_over_import_jax_equinox"] = out["cli_help_s"] / out["import_jax_equinox_s"]
    out["import_hybrid_over_import_jax_equinox"] = out["import_hybrid_s"] / out["import_jax_equinox_s"]
    out["cli_help_over_import_jax"] = out["cli_help_s"] / out["import_jax_s"]
    out["targets"] = {"cli_help_le_1.3x_import_jax_equinox": out["cli_help_over_import_jax_equinox"] <= 1.3}
    out["load_after"] = c.machine()["load_average_1_5_15"]
    c.write(
        "startup.json",
        out,
        show=(
            "import_jax_s",
            "import_jax_equinox_s",
            "import_hybrid_s",
            "cli_help_s",
            "cli_help_over_import_jax_equinox",
            "targets",
        ),
    )


if __name__ == "__main__":
    main()
