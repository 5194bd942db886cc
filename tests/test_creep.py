"""Creep, the built-in searched when named: pointed at from a remainder, found when searched.

The recording is made here with scipy (a first-order lag whose response creeps on through a
slower low-pass), independently of the effect fitted to it.
"""

from __future__ import annotations

import json
import math

import helpers as h
import numpy as np
import pytest
import scipy.signal


def test_a_creep_is_pointed_at_where_not_searched_and_named_where_it_is(tmp_path):
    """A first-order plant whose response creeps on by 8 % with τ = 3 s (scipy), 40 s at 25 Hz.

    back_relaxation gives response back and cannot take it: the remainder (a linear filter of the
    drive) points at the built-in creep, searched only when named; named, it is found with its size.
    """
    rng = np.random.default_rng(1)
    rate, n = 25.0, 1000
    v = np.repeat(rng.uniform(-10, 10, n // 25 + 1), 25)[:n]
    fall, slow = math.exp(-1 / (0.3 * rate)), math.exp(-1 / (3 * rate))
    y = scipy.signal.lfilter([2 * (1 - fall)], [1, -fall], v)
    w = y + 0.08 * scipy.signal.lfilter([1 - slow], [1, -slow], y) + 0.004 * rng.normal(size=n)
    table = np.c_[np.arange(n) / rate, v, w]
    np.savetxt(tmp_path / "rec.csv", table, delimiter=",", header="t,v_in,w\ns,V,mm", comments="")
    common = ("diagnose", "rec.csv", "--physics", "lti:1", "--quiet")
    run = h.run_hybrid(tmp_path, *common, "--effects", "back_relaxation", "--out", "a")
    assert run.returncode == 0, run.stderr[-2000:]
    report = json.loads((tmp_path / "a" / "report.json").read_text())
    assert report["causes"] == [] and report["unexplained"] is not None, report["verdict"]
    assert "--effects builtins,creep" in report["unexplained"]["description"]["summary"]

    run = h.run_hybrid(tmp_path, *common, "--effects", "back_relaxation,creep", "--out", "b")
    assert run.returncode == 0, run.stderr[-2000:]
    report = json.loads((tmp_path / "b" / "report.json").read_text())
    assert report["cause"] == "creep" and report["unexplained"] is None, report["verdict"]
    assert report["parameters"]["creep_fraction"]["value"] == pytest.approx(0.08, rel=0.05)
    assert report["parameters"]["creep_time_s"]["value"] == pytest.approx(3.0, rel=0.1)
    assert report["parameters"]["creep_time_s"]["unit"] == "s"
