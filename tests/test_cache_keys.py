"""A diagnosis's programs have the same persistent-cache keys in every process.

The command line keeps compiled programs on disk (`HYBRID_JAX_CACHE`), keyed
by the traced program. A trace that iterated a set of strings followed the
process's hash seed (`PYTHONHASHSEED`, random per process): the lanes' LM
program came out in one of two orders, so about every other `hybrid diagnose`
compiled it again (seconds, on every fresh process) though the cache held it. Two processes with hash seeds 1 and 3 (which order {"train",
"validation"} differently on CPython) diagnose the same recording with one
cache: the second must find every program there.
"""

import os
import subprocess
import sys
import textwrap

SCRIPT = textwrap.dedent("""
    import sys
    import hybrid
    hybrid.use_cpu_cores()
    hybrid.use_quick_compiles()
    import jax
    jax.config.update("jax_enable_x64", True)
    jax.config.update("jax_compilation_cache_dir", sys.argv[1])
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    import numpy as np
    rng = np.random.default_rng(3)
    n, dt = 600, 1 / 30
    v = np.repeat(rng.uniform(-1, 1, n // 20), 20)
    y = np.zeros(n)
    for k in range(1, n):  # a first-order lag with a saturating output, made here in numpy
        y[k] = 0.8 * y[k - 1] + 0.2 * v[k - 1]
    w = 2.0 * np.tanh(y) + 0.01 * rng.standard_normal(n)
    recording = hybrid.Recording.from_arrays(np.arange(n) * dt, v, w)
    found = hybrid.diagnose(recording, simulation=hybrid.LTI(1), effects=["saturation"], progress=False)
    print("CAUSE", found.cause)
""")


def test_a_second_process_finds_every_program_in_the_cache(tmp_path):
    cache = tmp_path / "cache"
    entries = []
    for seed in ("1", "3"):
        env = {k: v for k, v in os.environ.items() if k not in ("JAX_NUM_CPU_DEVICES", "XLA_FLAGS")}
        proc = subprocess.run(
            [sys.executable, "-c", SCRIPT, str(cache)],
            capture_output=True,
            text=True,
            timeout=900,
            env={**env, "PYTHONHASHSEED": seed, "JAX_PLATFORMS": "cpu"},
        )
        assert proc.returncode == 0, proc.stderr[-3000:]
        assert "CAUSE saturation" in proc.stdout  # a real diagnosis, not an early exit
        entries.append(sorted(p.name for p in cache.iterdir()))
    assert len(entries[0]) > 20  # the first process filled the cache
    assert entries[1] == entries[0], sorted(set(entries[1]) - set(entries[0]))  # nothing compiled again
