"""A readout that bends with a state the model has: a cell's open-circuit voltage over its charge.

A new user's lithium cell (a Thevenin plug-in: charge, one RC pair, R0, an open-circuit voltage
straight in the charge) read "a trend in time" for a curved open-circuit voltage: no map of the drive,
the output or a force fed back finds a function of a state added to the output. Here the user's
plug-in is written as a user would (a file, `AbstractLinearStateSpace`) and the recordings are made
with numpy and scipy (the charge summed from the held current, the RC pair by `lfilter`), not with
the library's simulation; `hybrid diagnose` runs from the command line.
"""

from __future__ import annotations

import json
import textwrap

import helpers as h
import numpy as np
import pytest
import scipy.signal

CELL = textwrap.dedent(
    '''
    from typing import ClassVar

    import jax.numpy as jnp

    from hybrid import AbstractLinearStateSpace, Positive, encode


    class Cell(AbstractLinearStateSpace):
        """A cell: charge (a fraction of the capacity), one RC pair, R0, an open-circuit voltage straight in charge."""

        raw: dict
        constraints: ClassVar[dict] = {
            "capacity": Positive(), "r0": Positive(), "r1": Positive(), "tau1": Positive(), "ocv_slope": Positive()
        }
        units: ClassVar[dict] = {"capacity": "A s", "r0": "V/A", "r1": "V/A", "tau1": "s", "ocv_slope": "V"}
        states: ClassVar[tuple] = ("charge", "v1")
        state_units: ClassVar[dict] = {"charge": "1", "v1": "V"}
        output_unit: ClassVar[str] = "V"
        frozen_by_default: ClassVar[dict] = {"capacity": "measured by a full discharge"}
        linear_in_drive: ClassVar[bool] = True

        def __init__(self, capacity=2000.0, r0=0.05, r1=0.03, tau1=40.0, ocv_slope=0.6):
            values = dict(capacity=capacity, r0=r0, r1=r1, tau1=tau1, ocv_slope=ocv_slope)
            self.raw = encode(values, self.constraints, "Cell")

        def realisation(self, p):
            a = jnp.array([[0.0, 0.0], [0.0, -1.0 / p["tau1"]]])
            b = jnp.array([1.0 / p["capacity"], p["r1"] / p["tau1"]])
            return a, b, jnp.array([p["ocv_slope"], 1.0]), p["r0"]
    '''
)


def _cycled(path, knee: float, seed: int = 0, n: int = 3600):
    """An hour at 1 Hz: a current of ±1 or ±2 A held 40–200 s, turned back at 20 % and 80 % charge; 1 mV noise."""
    rng = np.random.default_rng(seed)
    current, charge = h.cycled_current(rng, n)  # 2000 A s at 1 Hz, the current held over each second
    fall = np.exp(-1.0 / 40.0)
    v1 = scipy.signal.lfilter([0.0, 0.03 * (1.0 - fall)], [1.0, -fall], current)
    ocv = 3.4 + 0.6 * charge + knee * np.tanh(8.0 * (charge - 0.5))
    w = ocv + v1 + 0.05 * current + 0.001 * rng.normal(size=n)
    np.savetxt(path, np.c_[np.arange(n), current, w], delimiter=",", header="t,v_in,w\ns,A,V", comments="")


@pytest.mark.parametrize("knee", [0.12, 0.0])
def test_an_open_circuit_voltage_that_bends_with_the_charge_is_placed_on_the_charge(tmp_path, knee):
    (tmp_path / "cell.py").write_text(CELL)
    _cycled(tmp_path / "cell.csv", knee)
    run = h.run_hybrid(
        tmp_path,
        *("diagnose", "cell.csv", "--physics", "cell.py:Cell", "--effects", "saturation"),
        *("--out", "report", "--quiet"),
    )
    assert run.returncode == 0, run.stderr[-2000:]
    report = json.loads((tmp_path / "report" / "report.json").read_text())
    left = report["unexplained"]
    if knee == 0.0:  # the plug-in's own physics: nothing is missing
        assert left is None, left["description"]["summary"]
        return
    assert left is not None and left["fraction_above_floor"] > 0.9, report["verdict"]
    description = left["description"]
    assert description["summary"].startswith("static in the simulation's state charge, on its output"), (
        description["summary"]
    )
    # Most of the excess, and the bend, not a straight line. How much of it the charge's map takes depends
    # on where the baseline fit ends: 0.78 here (0.91 before the search held the readout in w's scale,
    # whose baseline fits this draw better held out, NMSE 0.068 against 0.083); on seeds 1–3 of `_cycled`
    # 0.45, 0.65, 0.98 (0.43, 0.73, 0.85 before), the summary placing it on the charge on all of them.
    best = description["state_output"]["states"]["charge"]
    assert best["of_excess"] > 0.5 and best["linear"]["of_excess"] < 0.2 * best["of_excess"]
    assert "trend in time" not in report["verdict"]
