"""A dead band on the output: the effect's form, and a sensor's dead band told from the drive's dead zone.

A probe's sensor dead band on a 1 Hz oscillator (w = sign(x)·max(|x| − 0.8, 0)) was named
`drive_dead_zone` (gain 3.2) with 79 % of the rest "static on the model's output": the library had no
dead band of the output. The command-line test's recording is made here with scipy (a second-order
plant under random steps, its output put through ``np.sign(x) * np.maximum(np.abs(x) - d, 0)``), not
by the effect it is fitted with.
"""

from __future__ import annotations

import json

import helpers as h
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.signal

from hybrid.discovery._effect_set import EFFECTS, NAMED_ONLY

DeadBand = NAMED_ONLY["dead_band"]
WIDTH = 0.8  # the band's half-width, in the plant's output (the drive's unit: a unit DC gain)


def test_the_dead_band_is_the_output_s_dead_zone_and_says_its_size():
    s = np.linspace(-3.0, 3.0, 121)
    band = DeadBand(dead_band_width=WIDTH)
    y = np.asarray(band.apply(jnp.asarray(s), 1 / 30))
    np.testing.assert_allclose(y, np.sign(s) * np.maximum(np.abs(s) - WIDTH, 0.0), atol=1e-15)
    assert band.place == "output" and EFFECTS["drive_dead_zone"].place == "drive"
    size = band.derived(jnp.asarray(s), 1 / 30)["dead_band_percent"]
    assert size == pytest.approx(100 * WIDTH / 3.0)
    assert band.material({"dead_band_percent": size}, {}, DeadBand.thresholds)[0]
    assert not band.material({"dead_band_percent": 2.0}, {}, DeadBand.thresholds)[0]
    # searched only when named, and tried where the drive's dead zone is named with something left
    assert "dead_band" not in EFFECTS and EFFECTS["drive_dead_zone"].refinement == "dead_band"


def _oscillator_behind_a_dead_band(path, seed: int = 3) -> None:
    """60 s at 30 Hz: random steps of ±3 V held 0.3–3 s into a 1 Hz, ζ 0.35 plant of unit DC gain; the
    sensor reads nothing while |x| ≤ `WIDTH`; noise 1 % of the range."""
    rng = np.random.default_rng(seed)
    rate, n = 30.0, 1800
    t = np.arange(n) / rate
    v = h.held_levels(rng, t, -3.0, 3.0, 0.3, 3.0, count=400)
    wn, zeta = 2 * np.pi * 1.0, 0.35
    plant = scipy.signal.lti([wn**2], [1.0, 2 * zeta * wn, wn**2])
    _, x, _ = scipy.signal.lsim(plant, v, t, interp=False)  # the drive held over each sample
    w = np.sign(x) * np.maximum(np.abs(x) - WIDTH, 0.0)
    w = w + 0.01 * np.ptp(w) * rng.normal(size=n)
    np.savetxt(path, np.c_[t, v, w], delimiter=",", header="t,v_in,w\ns,V,mm", comments="")


def test_a_sensor_dead_band_is_named_on_the_output_not_the_drive(tmp_path):
    _oscillator_behind_a_dead_band(tmp_path / "band.csv")
    run = h.run_hybrid(tmp_path, "diagnose", "band.csv", "--physics", "lti:2", "--out", "d", "--quiet")
    assert run.returncode == 0, run.stderr[-2000:]
    report = json.loads((tmp_path / "d" / "report.json").read_text())
    assert [c["name"] for c in report["causes"]] == ["dead_band"], report["verdict"]
    assert report["places"]["output"]["effects"], report["places"]
    width = report["parameters"]["dead_band_width"]
    assert width["value"] == pytest.approx(WIDTH, rel=0.03), width
    assert width["unit"] == "V"  # the unit of the signal it acts on: lti:2's output, in the drive's unit
    assert report["unexplained"] is None, report["verdict"]
    # the default set's own answer was the drive's dead zone (or nothing), and the band came from trying it
    # in that place
    refined = report["evidence"]["refined"]
    assert refined["kept"] and refined["swaps"]["drive_dead_zone"] == "dead_band", refined
    assert "dead_band" not in refined["first_causes"]
