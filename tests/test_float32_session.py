"""A script that leaves jax's float64 off (the library never turns it on): `diagnose` refuses in one line
that says how to turn it on, where it failed with a NaN blamed on the built-in Hysteresis effect's start;
`fit` runs in float32 and says so in its warnings, where the RC network's parameters moved in silence.

The session runs in a subprocess: the suite's own process has float64 on (conftest.py).
"""

from __future__ import annotations

import json
import subprocess
import sys

_SCRIPT = """
import json
import jax
import numpy as np
import hybrid as hy

assert not jax.config.read("jax_enable_x64")
rng = np.random.default_rng(0)
n, rate = 240, 30.0
u = np.repeat(rng.uniform(-1, 1, n // 8), 8)
y = np.convolve(u, np.exp(-np.arange(30) / 6.0) / 6.0)[:n] + 0.01 * rng.normal(size=n)
rec = hy.Recording(t=np.arange(n) / rate, v_in=u, w=y)
out = {}
try:
    hy.diagnose(rec, simulation=hy.LTI(1))
    out["diagnose"] = "ran"
except hy.InputError as error:
    out["diagnose"] = str(error)
result = hy.fit(hy.make_model("physics", simulation=hy.LTI(1)), rec, solver=hy.LevenbergMarquardt(max_steps=5))
out["fit"] = result.warnings
out["dtype"] = str(result.model.simulation.parameters()["tau_1"].dtype)
print("RESULT " + json.dumps(out))
"""


def test_a_float32_session_is_refused_by_diagnose_and_warned_by_fit():
    proc = subprocess.run([sys.executable, "-c", _SCRIPT], capture_output=True, text=True, check=False)
    lines = [line for line in proc.stdout.splitlines() if line.startswith("RESULT ")]
    assert proc.returncode == 0 and lines, proc.stderr[-3000:]
    out = json.loads(lines[-1][len("RESULT ") :])
    assert out["diagnose"].startswith("diagnose needs float64"), out["diagnose"]
    assert "jax.config.update('jax_enable_x64', True)" in out["diagnose"] and "\n" not in out["diagnose"]
    assert out["dtype"] == "float32"  # the fit did run, in float32
    assert any(w.startswith("fitted in float32") for w in out["fit"]), out["fit"]
