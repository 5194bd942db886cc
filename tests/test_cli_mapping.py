"""The command line reads a lab's own file: --input/--output/--columns, --rate, --range, --units.

The loader itself is tested in tests/test_loader_mapping.py; here the flags reach
it from `hybrid fit` and `hybrid diagnose`, and every bad mapping ends with exit 2
and one line on stderr.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from hybrid.cli import main


def run(argv, capsys):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def lab_csv(tmp_path_factory):
    """A lab's file: drive 'u_cmd', output 'level', a period column Ts in the first row only, no time."""
    rng = np.random.default_rng(0)
    u = np.repeat(rng.uniform(-1.0, 1.0, 40), 15)
    y = np.convolve(u, np.exp(-np.arange(30) / 6.0) / 6.0)[: u.size] + 0.001 * rng.normal(size=u.size)
    path = tmp_path_factory.mktemp("lab") / "lab.csv"
    lines = ["u_cmd,level,Ts"] + [
        f"{a:.9g},{b:.9g},{'0.5' if i == 0 else ''}" for i, (a, b) in enumerate(zip(u, y))
    ]
    path.write_text("\n".join(lines) + "\n")
    return path, u, y


def test_fit_maps_the_columns_takes_ts_and_a_range(lab_csv, tmp_path, capsys):
    path, u, y = lab_csv
    model, report = tmp_path / "m.eqx", tmp_path / "fit.json"
    code, out, err = run(
        [
            "fit",
            path,
            "--input",
            "u_cmd",
            "--output",
            "level",
            "--range",
            "100:",
            "--units",
            "v_in=V,w=cm",
            "--model",
            "physics",
            "--max-steps",
            "3",
            "--quiet",
            "--out",
            model,
            "--json",
            report,
        ],
        capsys,
    )
    assert code == 0, err
    assert model.is_file()
    data = json.loads(report.read_text())
    assert data["units"]["gain"] == "cm/V"  # units are labels that reach the fit's report
    assert "saved model" in out


def test_columns_in_one_flag_equal_the_two_flags(lab_csv, tmp_path, capsys):
    path, *_ = lab_csv
    outs = []
    for flags in (["--input", "u_cmd", "--output", "level"], ["--columns", "input=u_cmd,output=level"]):
        report = tmp_path / f"{len(outs)}.json"
        code, _, err = run(
            [
                "fit",
                path,
                *flags,
                "--model",
                "physics",
                "--max-steps",
                "2",
                "--quiet",
                "--out",
                tmp_path / f"{len(outs)}.eqx",
                "--json",
                report,
            ],
            capsys,
        )
        assert code == 0, err
        outs.append(json.loads(report.read_text())["parameters"])
    assert outs[0] == outs[1]


@pytest.mark.parametrize(
    "flags,phrase",
    [
        (["--input", "u_cmd", "--output", "levl"], "no column 'levl'"),
        (["--input", "u_cmd", "--output", "u_cmd"], "u_cmd"),
        (["--columns", "input=u_cmd;output=level"], ","),
        (["--input", "u_cmd", "--output", "level", "--range", "900:100"], "range"),
        (
            ["--input", "u_cmd", "--output", "level", "--rate", "3"],
            "rate",
        ),  # disagrees with Ts = 0.5 s (2 Hz)
        (["--input", "u_cmd", "--output", "level", "--rate", "0"], "rate"),
    ],
)
def test_bad_mappings_exit_2_with_one_line(lab_csv, tmp_path, capsys, flags, phrase):
    path, *_ = lab_csv
    code, _, err = run(["diagnose", path, *flags, "--out", tmp_path / "d"], capsys)
    assert code == 2
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("hybrid: error:") and phrase in lines[0], err
    assert not (tmp_path / "d" / "report.json").exists()


def test_fit_takes_a_plug_in_physics_from_a_file_and_lti(lab_csv, tmp_path, capsys):
    """--physics lti:2 and --physics file.py:Class reach fit; the saved model loads back as that class."""
    path, *_ = lab_csv
    plugin = tmp_path / "lag.py"
    plugin.write_text(
        "from typing import ClassVar\n"
        "import jax.numpy as jnp\n"
        "from jax import lax\n"
        "from hybrid import AbstractSimulation, Positive\n"
        "from hybrid import encode\n\n"
        "class Lag(AbstractSimulation):\n"
        "    raw: dict\n"
        "    constraints: ClassVar[dict] = {'tau_s': Positive()}\n"
        "    units: ClassVar[dict] = {'tau_s': 's'}\n"
        "    linear_in_drive: ClassVar[bool] = True\n\n"
        "    def __init__(self, tau_s=2.0):\n"
        "        self.raw = encode({'tau_s': tau_s}, self.constraints, 'Lag')\n\n"
        "    def simulate(self, v_in, dt):\n"
        "        a = jnp.exp(-dt / self.parameters()['tau_s'])\n"
        "        return lax.scan(lambda y, u: (a * y + (1 - a) * u,) * 2, 0.0, jnp.asarray(v_in))[1]\n"
    )
    for spec, name in (("lti:2", "f_1"), (f"{plugin}:Lag", "tau_s")):
        report = tmp_path / "fit.json"
        code, out, err = run(
            [
                "fit",
                path,
                "--columns",
                "input=u_cmd,output=level",
                "--physics",
                spec,
                "--model",
                "physics",
                "--max-steps",
                "20",
                "--quiet",
                "--out",
                tmp_path / "m.eqx",
                "--json",
                report,
            ],
            capsys,
        )
        assert code == 0, err
        assert name in json.loads(report.read_text())["parameters"], spec
    # the lag's time constant: the data's exponential kernel has tau = 6 samples = 3 s at Ts = 0.5 s
    assert json.loads(report.read_text())["parameters"]["tau_s"] == pytest.approx(3.0, rel=0.2)


@pytest.mark.parametrize(
    "spec,phrase",
    [
        ("lti:0", "lti"),
        ("nothere.py:X", "no file"),
        ("rc:3", "physics"),
        ("hybrid.core._models:Model", "AbstractSimulation"),
    ],
)
def test_a_bad_physics_spec_exits_2_with_one_line(lab_csv, tmp_path, capsys, spec, phrase):
    path, *_ = lab_csv
    code, _, err = run(
        [
            "fit",
            path,
            "--columns",
            "input=u_cmd,output=level",
            "--physics",
            spec,
            "--model",
            "physics",
            "--out",
            tmp_path / "m.eqx",
        ],
        capsys,
    )
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and phrase in lines[0], err
