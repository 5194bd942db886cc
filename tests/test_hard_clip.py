"""A hard clip is a saturation with a sharp knee: the family, its gradients, and a clipped amplifier found.

The saturation's family sgn(s)·tanh(|κs|ⁿ)^(1/n)/|κ| is checked against tanh (n = 1) and
``np.clip`` (n large), its gradients against central differences. The recording of the command-line
test is made here with scipy (``np.clip`` of a random-step drive into a second-order plant), not by
the effect it is fitted with.
"""

from __future__ import annotations

import json

import equinox as eqx
import helpers as h
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.signal

import hybrid
from hybrid.discovery._effect_set import NAMED_ONLY, searched_places
from hybrid.discovery._unexplained import named_only_hint

Clip, DriveClip = NAMED_ONLY["clip"], NAMED_ONLY["drive_clip"]

DT = 1 / 30


def _saturation(curvature: float, sharpness: float) -> Clip:
    return Clip(clip_pos_curvature=curvature, clip_neg_curvature=curvature, clip_sharpness=sharpness)


def test_the_family_is_tanh_at_sharpness_one_and_a_hard_clip_as_it_grows():
    s = jnp.linspace(-6.0, 6.0, 241)
    level = 2.0
    tanh = np.asarray(_saturation(1 / level, 1.0).apply(s, DT))
    np.testing.assert_allclose(tanh, level * np.tanh(np.asarray(s) / level), rtol=1e-12, atol=1e-15)
    clip = np.asarray(_saturation(1 / level, 400.0).apply(s, DT))
    # within 0.5 % of the level everywhere, and the clip itself a unit of s away from the knees
    np.testing.assert_allclose(clip, np.clip(np.asarray(s), -level, level), atol=0.005 * level)
    away = np.abs(np.abs(np.asarray(s)) - level) >= 1.0
    np.testing.assert_allclose(clip[away], np.clip(np.asarray(s), -level, level)[away], rtol=1e-12)
    # at its level a sharp knee (n = 8) reaches 0.966 of it, a tanh's 0.762
    at_level = float(_saturation(1 / level, 8.0).apply(jnp.asarray([level]), DT)[0])
    assert at_level / level == pytest.approx(np.tanh(1.0) ** (1 / 8), rel=1e-12)
    assert at_level / level > 0.96 and np.tanh(1.0) < 0.77
    # no curvature: the linear response, whatever the sharpness; slope 1 at 0 for any sharpness
    np.testing.assert_array_equal(np.asarray(_saturation(0.0, 5.0).apply(s, DT)), np.asarray(s))
    tiny = jnp.asarray([1e-6])
    for n in (0.6, 1.0, 12.0):
        assert float(_saturation(0.5, n).apply(tiny, DT)[0]) == pytest.approx(1e-6, rel=1e-9)
    # each side its own level, and the drive's saturation the same family
    drive = DriveClip(
        drive_clip_pos_curvature=1 / 5, drive_clip_neg_curvature=1 / 3, drive_clip_sharpness=50.0
    )
    y = np.asarray(drive.apply(jnp.asarray([-8.0, 8.0]), DT))
    np.testing.assert_allclose(y, [-3.0, 5.0], rtol=1e-6)


@pytest.mark.parametrize("sharpness", [0.6, 1.0, 12.0])
def test_the_gradients_in_curvature_and_sharpness_match_central_differences(sharpness):
    s = jnp.linspace(-4.0, 4.0, 81)
    effect = _saturation(0.4, sharpness)

    def y(raw):
        return eqx.tree_at(lambda e: e.raw, effect, raw).apply(s, DT)

    jac = jax.jacfwd(y)(effect.raw)
    for name in ("clip_pos_curvature", "clip_neg_curvature", "clip_sharpness"):
        step = 1e-6
        up = {**effect.raw, name: effect.raw[name] + step}
        down = {**effect.raw, name: effect.raw[name] - step}
        fd = (np.asarray(y(up)) - np.asarray(y(down))) / (2 * step)
        np.testing.assert_allclose(np.asarray(jac[name]), fd, rtol=1e-5, atol=1e-8, err_msg=name)
        assert np.max(np.abs(fd)) > 1e-3, name  # each moves the response on this signal


def test_a_sharp_or_soft_knee_is_read_and_a_knee_never_reached_leaves_the_sharpness_unpinned():
    effect = _saturation(0.2, 1.0)
    assert "close to a hard clip" in effect.reading({"clip_sharpness": 30.0}, "mm")
    assert "soft knee" in effect.reading({"clip_sharpness": 0.5}, "mm")
    assert effect.reading({"clip_sharpness": 1.0}, "mm") == ""
    quiet = np.linspace(-1.0, 1.0, 50)  # |κ s| ≤ 0.2: below the knee, where every sharpness bends alike
    assert "below the knee" in effect.unpinned_reason("clip_sharpness", quiet)
    assert effect.unpinned_reason("clip_sharpness", 10 * quiet) is None


def _clipped(path, seed: int = 3) -> None:
    """±5 kV rails clip random steps of ±8 kV into a 1.2 Hz, ζ 0.4 plant of gain 4 (scipy), 60 s at 30 Hz.

    Not shorter: at 30 s the tanh-only remainder points at the output's clip, not the drive's.
    """
    rng = np.random.default_rng(seed)
    rate, n = 30.0, 1800
    holds = rng.uniform(0.5, 3.0, 200)
    levels = rng.uniform(-8.0, 8.0, 200)
    t = np.arange(n) / rate
    v = levels[np.searchsorted(np.cumsum(holds), t, side="right")]
    w0 = 2 * np.pi * 1.2
    plant = scipy.signal.lti([4 * w0**2], [1.0, 2 * 0.4 * w0, w0**2])
    _, y, _ = scipy.signal.lsim(plant, np.clip(v, -5.0, 5.0), t)
    w = y + 0.005 * np.ptp(y) * rng.normal(size=n)
    np.savetxt(path, np.c_[t, v, w], delimiter=",", header="t,v_in,w\ns,kV,mm", comments="")  # a kV drive


def test_a_clipping_amplifier_is_pointed_at_by_the_saturations_and_named_with_its_rails_when_searched(
    tmp_path,
):
    """A tanh's knee bends over the whole range, so the saturations leave the clip's corners: the remainder
    points at the named-only clips, and searched, the drive's clip is named with its rails and a sharp knee."""
    _clipped(tmp_path / "rec.csv")
    common = ("diagnose", "rec.csv", "--physics", "lti:2", "--quiet")
    run = h.run_hybrid(tmp_path, *common, "--effects", "drive_saturation,saturation", "--out", "tanh")
    assert run.returncode == 0, run.stderr[-2000:]
    report = json.loads((tmp_path / "tanh" / "report.json").read_text())
    assert report["unexplained"] is not None, report["verdict"]
    assert "--effects builtins,drive_clip" in report["unexplained"]["description"]["summary"]

    run = h.run_hybrid(
        tmp_path, *common, "--effects", "drive_saturation,saturation,drive_clip,clip", "--out", "d"
    )
    assert run.returncode == 0, run.stderr[-2000:]
    report = json.loads((tmp_path / "d" / "report.json").read_text())
    assert report["cause"] == "drive_clip" and report["unexplained"] is None, report["verdict"]
    p = report["parameters"]
    for side in ("pos", "neg"):
        assert 1 / abs(p[f"drive_clip_{side}_curvature"]["value"]) == pytest.approx(5.0, rel=0.01)
        assert p[f"drive_clip_{side}_curvature"]["unit"] == "1/kV"  # the units of the recording's drive
    assert p["drive_clip_sharpness"]["value"] >= 8.0
    assert "close to a hard clip" in report["causes"][0]["reading"]
    # the levels in the drive's unit too, in report.json and in report.md's size column; on the drive,
    # no readout stands between them and the recording
    assert report["causes"][0]["derived_units"] == {"level_pos": "kV", "level_neg": "kV"}
    assert "as_recorded" not in report["causes"][0]
    level = report["causes"][0]["derived"]["level_pos"]
    assert f"level pos {level:.4g} kV" in (tmp_path / "d" / "report.md").read_text()


def test_a_remainder_static_in_the_drive_or_monotone_in_the_output_names_the_clip_of_its_place():
    def described(named):
        return {"recovered": {"named": named}}

    places = {"drive": {"effects": ["drive_saturation"]}, "output": {"effects": ["saturation", "creep"]}}
    assert "--effects builtins,drive_clip" in named_only_hint(described("static_drive"), places)
    assert "--effects builtins,clip" in named_only_hint(described("static_output_monotone"), places)
    assert named_only_hint(described("filter_drive"), places) is None  # creep was searched
    searched = {**places, "drive": {"effects": ["drive_saturation", "drive_clip"]}}
    assert named_only_hint(described("static_drive"), searched) is None
    assert named_only_hint(described("state_map"), places) is None
    # a simulation with a group of states (the RC network's double-layer voltages): a window on all of them
    # reads from outside as a clip of the drive, and is pointed at beside it where it was not searched
    network = searched_places(hybrid.resolve_effects(None, hybrid.RCNetwork()), hybrid.RCNetwork())
    assert network["inside"]["windows"] == ["window_vc"]
    assert "the built-in window_vc, searched when named" in named_only_hint(
        described("static_drive"), network
    )
    assert "window" not in named_only_hint(described("static_output_monotone"), network)
    assert "window" not in named_only_hint(described("static_drive"), places)  # no group: no window
    tried = searched_places(
        hybrid.resolve_effects(["builtins", "window_vc"], hybrid.RCNetwork()), hybrid.RCNetwork()
    )
    assert tried["inside"]["windows"] == [] and "window" not in named_only_hint(
        described("static_drive"), tried
    )


def test_a_sensors_full_scale_is_given_as_recorded_through_the_readout(tmp_path):
    """An output clip acts before the readout (w = gain·y + offset), so its level is in the simulation's
    unit; the report gives where w itself levels off too. A first-order plant read by a sensor whose full
    scale is 2 mm with a 0.3 mm offset (numpy, 60 s at 20 Hz); only the clip searched, to keep it short."""
    rng = np.random.default_rng(0)
    rate, n = 20.0, 1200
    v = np.repeat(rng.uniform(-2.0, 2.0, n // 20), 20)
    y, a = np.zeros(n), np.exp(-1 / (rate * 0.5))
    for k in range(1, n):
        y[k] = a * y[k - 1] + (1 - a) * 1.5 * v[k - 1]
    w = np.minimum(y + 0.3, 2.0) + 0.04 * rng.normal(size=n)
    t = np.arange(n) / rate
    np.savetxt(tmp_path / "rec.csv", np.c_[t, v, w], delimiter=",", header="t,v_in,w\ns,V,mm", comments="")
    run = h.run_hybrid(
        tmp_path, "diagnose", "rec.csv", "--physics", "lti:1", "--effects", "clip", "--out", "d"
    )
    assert run.returncode == 0, run.stderr[-2000:]
    report = json.loads((tmp_path / "d" / "report.json").read_text())
    assert report["cause"] == "clip", report["verdict"]
    cause = report["causes"][0]
    recorded, gain = cause["as_recorded"]["level_pos"], report["parameters"]["gain"]["value"]
    offset = report["parameters"]["offset"]["value"]
    assert cause["as_recorded_unit"] == "mm"
    assert recorded == pytest.approx(2.0, abs=0.02)  # the sensor's full scale, within half the noise
    assert recorded == pytest.approx(offset + gain * cause["derived"]["level_pos"], rel=1e-12)
    assert abs(cause["derived"]["level_pos"] - 2.0) > 0.1  # the simulation's unit: not where w levels off
    assert "level_neg" not in cause["derived"]  # the negative side is never reached: no level to give
    assert f"({recorded:.4g} mm as recorded)" in (tmp_path / "d" / "report.md").read_text()
    assert f"as recorded: level pos {recorded:.4g} mm" in run.stdout
