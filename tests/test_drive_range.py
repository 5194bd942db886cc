"""A drive far outside the levels a simulation is written for is said, in one warning (`drive_range`).

Cascaded Tanks' pump drive (0–10 V) written in mV in a file without units: the
`TwoTank` example's frozen pump flow is per volt, so the fit goes nowhere, and
before this check nothing in the output pointed at the drive's unit.
"""

from __future__ import annotations

import csv
import json
import pathlib

import helpers as h
import numpy as np
import pytest

import hybrid
from hybrid.core._result import DRIVE_RANGE_FACTOR, drive_outside_range

ROOT = pathlib.Path(__file__).resolve().parents[1]
TANKS = ROOT.parent / "shared" / "data" / "cascaded-tanks" / "dataBenchmark.csv"
TwoTank = type(hybrid.resolve_physics(f"{ROOT}/examples/two_tank.py:TwoTank"))


def test_a_drive_far_outside_the_written_for_levels_is_said_and_one_within_is_not():
    tanks = TwoTank()
    assert tanks.drive_range == (0.0, 10.0)
    u = np.linspace(0.0, 6.5, 100)
    assert drive_outside_range(tanks, [u], "V") == []
    # the same drive in mV: 650× the largest level, near a unit's step
    (said,) = drive_outside_range(tanks, [1000 * u], "")
    assert said.startswith("the drive reaches 6500, 650× the largest level TwoTank is written for (0 to 10")
    assert "near 10^3, the step between units" in said
    # in kV: far below; the factor's edges: just inside is quiet, just outside is said
    (small,) = drive_outside_range(tanks, [u / 1000], "kV")
    assert "1/1.54e+03 of the largest level" in small and "near 10^-3" in small
    assert "(kV and V)" in small  # the drive's own unit (a probe's drive in mW was told "mV and V")
    (watts,) = drive_outside_range(tanks, [1000 * u], "mW")
    assert "the step between units (mW and W)" in watts
    top = 10.0 * DRIVE_RANGE_FACTOR
    assert drive_outside_range(tanks, [np.array([0.0, 0.99 * top])]) == []
    assert drive_outside_range(tanks, [np.array([0.0, 1.01 * top])]) != []
    assert (
        "near 10^" not in drive_outside_range(tanks, [np.array([0.0, 1.01 * top])])[0]
    )  # 20×: no unit's step
    # the largest of several recordings counts; an all-zero drive and a simulation that states no range say nothing
    assert drive_outside_range(tanks, [u, 1000 * u]) != []
    assert drive_outside_range(tanks, [np.zeros(10)]) == []
    assert drive_outside_range(hybrid.LTI(1), [1000 * u]) == []
    # a wrapper (a held start, the effects' stack) states its inner simulation's range, and names it
    held = hybrid.EffectStack(hybrid.HeldStart(tanks, 10), [hybrid.StateLimit("h1")])
    assert held.drive_range == (0.0, 10.0)
    assert "largest level TwoTank is written for" in drive_outside_range(held, [1000 * u])[0]


@pytest.mark.skipif(not TANKS.is_file(), reason=f"the benchmark file is not in {TANKS.parent}")
def test_hybrid_fit_says_when_the_tanks_pump_drive_is_in_millivolts(tmp_path):
    with open(TANKS, newline="") as handle:
        rows = list(csv.reader(handle))
    column = rows[0].index("uEst")
    for name, scale in (("volts.csv", 1.0), ("millivolts.csv", 1000.0)):
        scaled = [rows[0]] + [
            [f"{float(cell) * scale!r}" if j == column else cell for j, cell in enumerate(row)]
            for row in rows[1:]
        ]
        with open(tmp_path / name, "w", newline="") as handle:
            csv.writer(handle).writerows(scaled)
    common = ("--columns", "input=uEst,output=yEst", "--rate", "0.25", "--model", "physics")
    physics = ("--physics", f"{ROOT}/examples/two_tank.py:TwoTank", "--quiet")
    said = {}
    for name in ("volts", "millivolts"):
        out = ("--out", f"{name}.eqx", "--json", f"{name}.json")
        run = h.run_hybrid(tmp_path, "fit", f"{name}.csv", *common, *physics, *out)
        assert run.returncode == 0, run.stderr[-2000:]
        warnings = json.loads((tmp_path / f"{name}.json").read_text())["warnings"]
        said[name] = [w for w in warnings if w.startswith("the drive reaches")]
        assert len(said[name]) == run.stdout.count("warning: the drive reaches")  # printed as it is saved
    assert said["volts"] == []
    (line,) = said["millivolts"]
    assert "647× the largest level TwoTank is written for" in line and "(mV and V)" in line
