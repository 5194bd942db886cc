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
from typing import ClassVar

import helpers as h
import numpy as np
import pytest

from hybrid import LTI, AbstractSimulation, InputError, LinearReadout, Model, Real, encode, sensitivity as S
from hybrid.cli import main
from hybrid.sensitivity._study import simulation_study

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
    assert len(result["singular_values"]) == 6 and result["physics"] == "lti:2"  # gain and offset included
    assert "xi_h" not in json.dumps(result) and "frequency_peaks" not in result  # no IPMC views
    for name in ("sensitivity.md", "sensitivity_time.png", "singular_values.png"):
        assert (out / name).stat().st_size > 500
    assert "f_1 = 0.08 ±" in proc.stdout
    assert result["warnings"] == [] and "warning" not in proc.stderr  # steps: many frequencies, f_1 < 1 Hz


def test_a_one_sine_drive_and_a_frequency_above_nyquist_are_said(tmp_path, capsys):
    """A probe's study on one steady sine gave tight bounds without a word, which `fit` on the same record
    warns of; nor was a frequency above the Nyquist frequency said. Both now are, on stderr and in the
    files; the drive at 2 Hz has its Nyquist frequency at 1 Hz."""
    u = np.sin(2 * np.pi * 0.1 * DT * np.arange(N))  # 15 periods
    path = tmp_path / "sine.csv"
    path.write_text(
        "u,y,Ts\n" + "".join(f"{a:.12g},{a:.12g},{DT if i == 0 else ''}\n" for i, a in enumerate(u))
    )
    out = tmp_path / "sens"
    params = [f"--param={k}={v}" for k, v in {**NOMINAL, "f_1": 1.3}.items()]
    argv = ["sensitivity", path, "--input", "u", "--output", "y", "--physics", "lti:2", *params, "--out", out]
    assert main([str(a) for a in argv]) == 0
    err = capsys.readouterr().err
    result = json.loads((out / "sensitivity.json").read_text())
    sine, alias = result["warnings"]
    assert sine.startswith("the drive is one sinusoid (0.1 Hz") and "standard errors" in sine
    assert alias.startswith("f_1 = 1.3 Hz is at or above the Nyquist frequency (1 Hz") and "0.7 Hz" in alias
    assert "study a value below the Nyquist frequency" in alias and "fit again" not in alias
    assert err.count("hybrid: warning: ") == 2 and sine in err and alias in err
    assert sine in (out / "sensitivity.md").read_text()


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
            "--stages belongs to the RC network's study",
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


# ----------------------------------------------------------------- parameters at 0, and the readout in the SVD
class _Sum(AbstractSimulation):
    """y = (a + b)·v + c·v²: a and b are one parameter twice (a genuinely redundant pair); c is not."""

    raw: dict
    constraints: ClassVar = {"a": Real(), "b": Real(), "c": Real()}
    units: ClassVar = {"a": "1", "b": "1", "c": "1/{drive}"}
    typical: ClassVar = {"a": (-1.0, 1.0)}  # c has no typical range

    def __init__(self, a=0.0, b=2.0, c=0.0):
        self.raw = encode({"a": a, "b": b, "c": c}, self.constraints, "Sum")

    def simulate(self, v_in, dt):
        p = self.parameters()
        return (p["a"] + p["b"]) * v_in + p["c"] * v_in**2


def test_a_parameter_at_0_that_acts_on_the_output_is_not_a_null_direction(lab_csv):
    """LTI(2) with bandpass_1 and direct at their default 0: both change y, neither is null."""
    _, u = lab_csv
    simulation = LTI(2, f_1=0.08, zeta_1=0.9)
    sens = S.local_sensitivities(simulation, u, DT)
    for name in ("bandpass_1", "direct"):  # at 0, and each changes y
        column = sens.jacobian[:, sens.names.index(name)]
        assert sens.values[name] == 0 and np.sqrt(np.mean(column**2)) > 0.1, name
    ident = sens.identifiability()  # it used to call each of them a null direction
    assert ident.null_directions == [] and ident.singular_values[-1] > 1e-3 * ident.singular_values[0]
    # scaled by the half-width of the typical range: (-10, 10) and (-1, 1)
    assert sens.scales == pytest.approx({"f_1": 0.08, "zeta_1": 0.9, "bandpass_1": 10.0, "direct": 1.0})
    # the Python analysis of w = gain·y + offset is the command's own (it used to add {'offset': 1}, at 0)
    result, _ = simulation_study(simulation, u, DT)
    w_ident = S.local_sensitivities(Model(simulation, LinearReadout()), u, DT).identifiability()
    np.testing.assert_allclose(w_ident.singular_values, result["singular_values"], rtol=1e-12)
    assert w_ident.null_directions == result["null_directions"] == []
    assert result["scales"] == pytest.approx(sens.scales | {"gain": 1.0, "offset": sens.output_rms})


def test_a_redundant_pair_with_a_parameter_at_0_is_still_a_null_direction():
    v = np.sin(np.linspace(0.0, 6.0, 200)) + 0.5
    ident = S.local_sensitivities(_Sum(), v, 0.1).identifiability()
    # columns s_a·v and s_b·v (s_a = 1, the half-width of a's range; s_b = |b| = 2): null along (1, −1/2)
    (null,) = ident.null_directions
    assert null == {"a": pytest.approx(2 / 5**0.5, abs=1e-8), "b": pytest.approx(-1 / 5**0.5, abs=1e-8)}
    assert ident.near_null_directions == []  # c, at 0 with no range, is scaled to move y by its rms


SCALED_LAG = PLUGIN.replace(
    '    frozen_by_default: ClassVar[dict] = {"k": "the readout\'s gain carries the scale"}\n', ""
)


def test_a_direction_that_makes_the_errors_infinite_is_named(lab_csv, tmp_path, capsys):
    """k scales y exactly as the readout's gain does: k·gain is all w fixes, and the study says so."""
    path, _ = lab_csv
    plugin = tmp_path / "scaled_lag.py"
    plugin.write_text(SCALED_LAG)
    out = tmp_path / "sens"
    argv = ["sensitivity", str(path), "--columns", "input=u,output=y", "--physics", f"{plugin}:Lag"]
    assert main([*argv, "--out", str(out)]) == 0, capsys.readouterr().err
    printed = capsys.readouterr().out
    result = json.loads((out / "sensitivity.json").read_text())
    assert result["frozen"] == {} and result["unidentifiable"] == ["k", "gain"]
    assert result["std_error"]["k"] == result["std_error"]["gain"] == "inf"
    # the SVD sees the gain the covariance has: log k + log gain is fixed, log k − log gain is null
    assert result["null_directions"] == [
        {"k": pytest.approx(2**-0.5, abs=1e-8), "gain": pytest.approx(-(2**-0.5), abs=1e-8)}
    ]
    named = {name for direction in result["null_directions"] for name in direction}
    assert set(result["unidentifiable"]) <= named  # every infinite error has its null direction
    assert (
        "Null directions (scaled coordinates): +0.7071·k -0.7071·gain" in (out / "sensitivity.md").read_text()
    )
    assert "null direction (w does not change along it): +0.7071·k -0.7071·gain" in printed


class _NaNBeyondFive(AbstractSimulation):
    """A first-order lag whose output is NaN for a time constant beyond 5 s (a plug-in defined only below it)."""

    raw: dict
    constraints: ClassVar[dict] = {"tau": Real()}
    units: ClassVar[dict] = {"tau": "s"}
    output_unit: ClassVar[str] = "{drive}"

    def __init__(self, tau=1.0):
        self.raw = encode({"tau": tau}, self.constraints, "_NaNBeyondFive")

    def simulate(self, v_in, dt):
        import jax
        import jax.numpy as jnp

        tau = self.parameters()["tau"]
        a = jnp.exp(-dt / tau)
        y = jax.lax.scan(lambda x, u: (a * x + (1 - a) * u, x), jnp.zeros(()), jnp.asarray(v_in))[1]
        return jnp.where(tau > 5.0, jnp.nan, y)


def test_local_sensitivities_refuse_an_output_that_is_not_finite_in_one_line():
    """A probe's plug-in at τ = 6 s gave an output NaN at every sample and a Jacobian of zeros, silently."""
    drive = np.repeat([0.0, 1.0, -1.0, 0.5], 50)
    fine = S.local_sensitivities(_NaNBeyondFive(tau=2.0), drive, 0.1)
    # the lag's own derivative, by hand: y_k = Σ (1 − a) a^j u_{k−1−j}, a = e^(−dt/τ), checked by differences
    step = 1e-6
    plus = np.asarray(_NaNBeyondFive(tau=2.0 + step).simulate(drive, 0.1))
    minus = np.asarray(_NaNBeyondFive(tau=2.0 - step).simulate(drive, 0.1))
    np.testing.assert_allclose(fine.jacobian[:, 0], (plus - minus) / (2 * step), rtol=1e-6, atol=1e-9)
    with pytest.raises(
        InputError,
        match=r"_NaNBeyondFive at tau=6: its output is not finite \(NaN or inf\) at 200 of 200 samples",
    ):
        S.local_sensitivities(_NaNBeyondFive(tau=6.0), drive, 0.1)
