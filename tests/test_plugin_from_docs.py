"""A physics plug-in written only from docs/plugins.md: its one-file example, taken from the page as it
is, imports public names only, and the real command line fits it and diagnoses with it.

The recording is made here by an independent reference (scipy's exact solution of the lag for a drive
held over each sample), not by the plug-in itself; a plug-in that runs a sample ahead of it (as the
page's example once did: τ 25 % long at 10 Hz, a helper's probe) is caught by the check on one step.
"""

from __future__ import annotations

import json
from pathlib import Path

import helpers as h
import numpy as np
import pytest
import scipy.signal

import hybrid

ROOT = Path(__file__).resolve().parents[1]
TAU, RATE, GAIN, OFFSET = 0.8, 20.0, 1.5, 0.2


def _docs_plugin() -> str:
    return h.docs_python_block("plugins.md", "## A plug-in in one file", "## The interface")


def test_the_docs_plugin_imports_only_public_names():
    h.assert_public_imports_only(_docs_plugin())


def _lag(u):
    """τ dy/dt = u − y from y = u[0] (settled at the first drive), u held over each sample: scipy's ZOH."""
    t = np.arange(u.size) / RATE
    _, y, _ = scipy.signal.lsim(([1.0], [TAU, 1.0]), u, t, X0=[u[0] * TAU], interp=False)
    return y


def test_the_docs_plugin_steps_as_the_exact_solution_does(tmp_path, monkeypatch):
    """The page's plug-in on a step: its output at every sample equals scipy's (a sample early fails)."""
    (tmp_path / "lag.py").write_text(_docs_plugin())
    monkeypatch.syspath_prepend(str(tmp_path))
    import lag

    u = np.r_[np.zeros(3), np.ones(40)]
    y = np.asarray(lag.Lag(tau=TAU).simulate(u, 1.0 / RATE))
    np.testing.assert_allclose(y, _lag(u), atol=1e-9)
    assert y[3] == 0.0 and y[4] > 0.05  # the step at sample 3 shows from sample 4 on


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    folder = tmp_path_factory.mktemp("lab")
    (folder / "lag.py").write_text(_docs_plugin())
    rng = np.random.default_rng(3)
    u = np.repeat(rng.uniform(-1.0, 1.0, 60), 10)  # 600 samples, levels held 0.5 s
    y = _lag(u)
    w = GAIN * y + OFFSET + 0.002 * rng.normal(size=u.size)
    hybrid.Recording.from_arrays(v_in=u, w=w, rate=RATE).save(folder / "lab.csv")
    return folder


def _hybrid(folder, *args):
    return h.run_hybrid(folder, *args)


def test_the_cli_fits_the_docs_plugin_and_diagnoses_with_it(lab):
    fit = _hybrid(
        lab,
        "fit",
        "lab.csv",
        "--model",
        "physics",
        "--physics",
        "lag.py:Lag",
        "--out",
        "lag.eqx",
        "--json",
        "fit.json",
        "--quiet",
    )
    assert fit.returncode == 0, fit.stderr[-2000:]
    parameters = json.loads((lab / "fit.json").read_text())["parameters"]
    assert parameters["tau"] == pytest.approx(TAU, rel=0.02)  # the noise is 0.1 % of the output's range

    diagnosis = _hybrid(
        lab, "diagnose", "lab.csv", "--physics", "lag.py:Lag", "--out", "diag", "--max-steps", "5"
    )
    assert diagnosis.returncode == 0, diagnosis.stderr[-2000:]
    report = json.loads((lab / "diag" / "report.json").read_text())
    assert report["cause"] == "none", report["cause"]  # the plug-in is the right physics: nothing to add
    assert report["parameters"]["tau"]["unit"] == "s"
    assert report["parameters"]["tau"]["value"] == pytest.approx(TAU, rel=0.02)
