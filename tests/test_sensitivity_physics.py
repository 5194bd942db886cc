"""`hybrid sensitivity --physics SPEC`: any simulation's sensitivities and Cramér–Rao bounds on a recording's drive.

The reference is independent of the library: the LTI(2)'s transfer function written out by hand,
scipy's ZOH discretisation, central finite differences and σ²(JᵀJ)⁻¹ in numpy. `--physics rc`
(the default) is covered by tests/test_sensitivity.py.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import helpers as h
import numpy as np
import pytest

from hybrid.cli import main

ROOT = Path(__file__).resolve().parents[1]
NOMINAL = {"f_1": 0.08, "zeta_1": 0.9, "bandpass_1": 0.3, "direct": 0.1}
DT, N, NOISE = 0.5, 300, 0.02
#: Central differences (step 1e-5 of each value) and a plain inverse against forward mode and an
#: SVD: measured agreement ~4e-10 relative; 1e-4 leaves room for other machines' rounding.
RTOL = 1e-4


@pytest.fixture(scope="module")
def lab_csv(tmp_path_factory):
    """A lab's file: drive 'u', output 'y', a period column Ts in the first row (2 Hz)."""
    u = h.step_drive(N, seed=3, low=4, high=30)
    y = 1.5 * h.lti2_zoh_response(NOMINAL, u, DT) + 0.01 * np.random.default_rng(0).normal(size=N)
    path = tmp_path_factory.mktemp("sens") / "lab.csv"
    rows = [f"{a:.12g},{b:.12g},{DT if i == 0 else ''}" for i, (a, b) in enumerate(zip(u, y))]
    path.write_text("u,y,Ts\n" + "\n".join(rows) + "\n")
    return path, u


def _cramer_rao_by_differences(u):
    """Standard errors of f_1, zeta_1, bandpass_1, direct, gain, offset for w = gain·y + offset + noise."""
    y = h.lti2_zoh_response(NOMINAL, u, DT)
    columns = []
    for name, value in NOMINAL.items():
        step = 1e-5 * abs(value)
        up = h.lti2_zoh_response({**NOMINAL, name: value + step}, u, DT)
        down = h.lti2_zoh_response({**NOMINAL, name: value - step}, u, DT)
        columns.append((up - down) / (2 * step))
    J = np.column_stack(columns + [y, np.ones_like(y)])  # gain 1, offset 0
    sigma = NOISE * np.sqrt(np.mean(y**2))
    se = np.sqrt(np.diag(sigma**2 * np.linalg.inv(J.T @ J)))
    return dict(zip([*NOMINAL, "gain", "offset"], se))


def test_lti_standard_errors_match_finite_differences(lab_csv, tmp_path):
    """The real entry point in a subprocess (a timeout instead of a hang), a lab's columns for the drive."""
    path, u = lab_csv
    out = tmp_path / "sens"
    params = [f"--param={k}={v}" for k, v in NOMINAL.items()]
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "hybrid.cli",
            "sensitivity",
            str(path),
            "--input",
            "u",
            "--output",
            "y",
            "--physics",
            "lti:2",
            *params,
            "--noise",
            str(NOISE),
            "--out",
            str(out),
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    result = json.loads((out / "sensitivity.json").read_text())
    expected = _cramer_rao_by_differences(u)
    assert set(result["std_error"]) == set(expected)
    for name, se in expected.items():
        assert result["std_error"][name] == pytest.approx(se, rel=RTOL), name
    for name, value in NOMINAL.items():
        assert result["relative_std_error"][name] == pytest.approx(expected[name] / value, rel=RTOL)
        assert result["nominal"][name] == pytest.approx(value)
    assert result["relative_std_error"]["offset"] is None  # at 0: no relative error
    assert result["names"] == list(NOMINAL) and result["frozen"] == {} and result["samples"] == N
    assert len(result["singular_values"]) == 4 and result["physics"] == "lti:2"
    assert "xi_h" not in json.dumps(result) and "frequency_peaks" not in result  # no IPMC views
    for name in ("sensitivity.md", "sensitivity_time.png", "singular_values.png"):
        assert (out / name).stat().st_size > 500
    assert "f_1 = 0.08 ±" in proc.stdout


PLUGIN = '''
from typing import ClassVar
import jax.numpy as jnp
from jax import lax
from hybrid import AbstractSimulation, Positive
from hybrid import encode

class Lag(AbstractSimulation):
    """k · first-order lag; k is the readout's gain all over again, so it is frozen by default."""
    raw: dict
    constraints: ClassVar[dict] = {"tau": Positive(), "k": Positive()}
    units: ClassVar[dict] = {"tau": "s", "k": "1"}
    output_unit: ClassVar[str] = "{drive}"  # a lag of the drive, in its unit
    frozen_by_default: ClassVar[dict] = {"k": "the readout's gain carries the scale"}

    def __init__(self, tau=2.0, k=1.0):
        self.raw = encode({"tau": tau, "k": k}, self.constraints, "Lag")

    def simulate(self, v_in, dt):
        p = self.parameters()
        a = jnp.exp(-dt / p["tau"])
        return p["k"] * lax.scan(lambda y, u: (a * y + (1 - a) * u,) * 2, 0.0, jnp.asarray(v_in))[1]
'''


def test_a_plugin_s_default_frozen_parameters_are_left_out(lab_csv, tmp_path, capsys):
    path, u = lab_csv
    plugin = tmp_path / "lag.py"
    plugin.write_text(PLUGIN)
    out = tmp_path / "sens"
    code = main(
        [
            "sensitivity",
            str(path),
            "--columns",
            "input=u,output=y",
            "--units",
            "v_in=mV,w=mm",
            "--physics",
            f"{plugin}:Lag",
            "--out",
            str(out),
        ]
    )
    assert code == 0, capsys.readouterr().err
    result = json.loads((out / "sensitivity.json").read_text())
    assert result["frozen"] == {"k": "the readout's gain carries the scale"}
    assert result["names"] == ["tau"] and set(result["std_error"]) == {"tau", "gain", "offset"}
    assert result["unidentifiable"] == []
    # units follow the signals: the offset is in the simulation's output's, here the drive's (it said "(y)")
    assert result["units"] == {"tau": "s", "gain": "1", "offset": "mV"}
    offset = next(
        line for line in capsys.readouterr().out.splitlines() if line.strip().startswith("offset =")
    )
    assert offset.endswith(" mV"), offset


@pytest.mark.parametrize(
    "argv,phrase",
    [
        (["sensitivity", "--physics", "lti:2", "--out", "X"], "give a recording of your system"),
        (
            [
                "sensitivity",
                "{path}",
                "--input",
                "u",
                "--output",
                "y",
                "--physics",
                "lti:2",
                "--stages",
                "10",
                "--out",
                "X",
            ],
            "--stages belong to the RC network's study",
        ),
        (
            [
                "sensitivity",
                "{path}",
                "--input",
                "u",
                "--output",
                "y",
                "--physics",
                "lti:2",
                "--param",
                "xi_rho=3",
                "--out",
                "X",
            ],
            "no parameter(s) ['xi_rho']",
        ),
        (
            ["sensitivity", "{path}", "--input", "u", "--output", "yy", "--physics", "lti:2", "--out", "X"],
            "no column 'yy'",
        ),
        (
            [
                "sensitivity",
                "{path}",
                "--input",
                "u",
                "--output",
                "y",
                "--range",
                "0:5",
                "--physics",
                "lti:2",
                "--out",
                "X",
            ],
            "needs at least 12",
        ),
    ],
)
def test_bad_input_exits_2_with_one_line(lab_csv, tmp_path, capsys, monkeypatch, argv, phrase):
    path, _ = lab_csv
    monkeypatch.chdir(tmp_path)
    assert main([a.format(path=path) for a in argv]) == 2
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("hybrid: error:") and phrase in lines[0], err
    assert not (tmp_path / "X" / "sensitivity.json").exists()
