"""Effects refused for their size alone: said in the report, and counted with --materiality.

The recording is made here with scipy (a first-order lag and a baseline wander), independently of the
effects fitted to it.
"""

from __future__ import annotations

import json
import math

import helpers as h
import numpy as np
import pytest
import scipy.signal

from hybrid.cli import main
from hybrid.discovery._effect_set import EFFECTS


def test_an_effect_refused_for_its_size_alone_is_said_and_counted_with_materiality(
    tmp_path, capsys, monkeypatch
):
    """A baseline wander of 0.08 mm on a 39 mm swing, 20× the noise: 0.3 % of the range, under the 5 % asked.

    It gains far more than the rules ask held out; the report must say it was refused for its size alone
    (not point at a weaker rival or nothing), and --materiality must count it.
    """
    rng = np.random.default_rng(0)
    rate, n = 25.0, 1000
    v = np.repeat(rng.uniform(-10, 10, n // 25 + 1), 25)[:n]
    t = np.arange(n) / rate
    fall = math.exp(-1 / (0.3 * rate))
    w = scipy.signal.lfilter([2 * (1 - fall)], [1, -fall], v) + 0.08 * np.sin(2 * math.pi * t / 50 + 0.3)
    w = w + 0.004 * rng.normal(size=n)
    np.savetxt(tmp_path / "rec.csv", np.c_[t, v, w], delimiter=",", header="t,v_in,w\ns,V,mm", comments="")
    common = ("diagnose", "rec.csv", "--physics", "lti:1", "--effects", "baseline_drift", "--quiet")
    run = h.run_hybrid(tmp_path, *common, "--out", "a")
    assert run.returncode == 0, run.stderr[-2000:]
    report = json.loads((tmp_path / "a" / "report.json").read_text())
    assert report["causes"] == []
    (small,) = report["too_small"]
    assert small["name"] == "baseline_drift" and small["gain"] > 10
    assert small["thresholds"] == {"baseline_percent_of_range": 5.0}
    assert "baseline_drift gains" in report["verdict"] and "--materiality" in report["verdict"]
    assert "too small: baseline_drift" in run.stdout
    assert "**Too small to count.**" in (tmp_path / "a" / "report.md").read_text()

    run = h.run_hybrid(tmp_path, *common, "--materiality", "baseline_percent_of_range=0.1", "--out", "b")
    assert run.returncode == 0, run.stderr[-2000:]
    report = json.loads((tmp_path / "b" / "report.json").read_text())
    assert report["cause"] == "baseline_drift" and report["too_small"] == []
    assert report["settings"]["materiality"]["baseline_percent_of_range"] == 0.1

    # refusals through the same command line in this process (`hybrid.cli.main`)
    monkeypatch.chdir(tmp_path)
    for bad, words in (("nosuch=1", "nosuch"), ("baseline_percent_of_range=-1", "≥ 0")):
        code = main([*common, "--materiality", bad, "--out", "c"])
        err = capsys.readouterr().err
        assert code == 2 and words in err and "Traceback" not in err
        assert not (tmp_path / "c").exists()


def test_the_too_small_sentence_sets_a_threshold_either_way():
    """A well damped mode falls short of a resonance's ceiling on damping, which must be raised to admit
    it: the sentence says "set", never "lower" (it read "if an effect that small matters here, lower
    max_damping (now 0.35)" for a mode of ζ 0.981, which is now no resonance at all: below)."""
    from hybrid.discovery._verdict import too_small_sentence

    entry = {
        "name": "resonance",
        "gain": 1.54,
        "materiality": "mode 0.03 Hz, ζ 0.520 (needs ζ ≤ 0.35, f ≥ 0.5 Hz)",
        "thresholds": {"max_damping": 0.35, "min_frequency_hz": 0.5},
    }
    said = too_small_sentence(entry)
    assert "set max_damping (now 0.35) and min_frequency_hz (now 0.5) to admit it" in said
    assert "lower" not in said and "that small" not in said


def test_a_mode_with_no_peak_is_not_offered_as_a_resonance_too_small_to_count():
    """A probe's lag behind a dead time: a 0.13 Hz "mode" of ζ 1.000 gained 246× held out, above the named
    lag's 191×, and the report called it too small, with max_damping to raise; from ζ 1/√2 on a second-order
    response has no peak: its poles act as lags. A mode of ζ 0.5 is still offered."""
    from types import SimpleNamespace

    import hybrid
    from hybrid.discovery._diagnosis import DiagnoseSettings, Diagnosis

    resonance = hybrid.EFFECTS["resonance"]()
    assert "has no resonant peak" in resonance.unlike({"resonance_damping": 1.0})
    assert resonance.unlike({"resonance_damping": 0.70}) is None
    refused = "not material: mode 0.13 Hz, ζ {z} (needs ζ ≤ 0.35, f ≥ 0.5 Hz)"

    def candidate(z):
        return SimpleNamespace(
            name="resonance",
            gain=246.0,
            refused_for_size=True,
            reasons=[refused.format(z=z)],
            materiality=refused.format(z=z)[len("not material: ") :],
            parameters={"resonance_frequency_hz": 0.13, "resonance_damping": z},
            derived={},
        )

    def too_small(z):
        fake = SimpleNamespace(
            causes=[{"name": "lag"}],
            steps=[SimpleNamespace(candidates=[candidate(z)])],
            settings=DiagnoseSettings(),
            _effect=lambda name: resonance,
        )
        return Diagnosis.too_small.fget(fake)

    assert too_small(1.0) == []
    (offered,) = too_small(0.5)
    assert offered["name"] == "resonance" and offered["gain"] == 246.0


def test_an_effect_a_later_step_refuses_for_more_than_its_size_is_not_too_small():
    """A probe's backlash gained 6.22× at step 1, refused for its size beside the stiffness named there, and
    0.99× at step 2 on top of it; the report still offered it ("set play_percent_of_range to admit it").
    The latest step that weighed it decides: refused there for its gain, it is not listed."""
    from types import SimpleNamespace

    import hybrid
    from hybrid.discovery._diagnosis import DiagnoseSettings, Diagnosis

    backlash = hybrid.EFFECTS["backlash"]()

    def candidate(gain, for_size):
        return SimpleNamespace(
            name="backlash",
            gain=gain,
            refused_for_size=for_size,
            materiality="play 1 %",
            parameters={},
            derived={},
        )

    def too_small(*steps):
        fake = SimpleNamespace(
            causes=[{"name": "stiffness"}],
            steps=[SimpleNamespace(candidates=[c]) for c in steps],
            settings=DiagnoseSettings(),
            _effect=lambda name: backlash,
        )
        return Diagnosis.too_small.fget(fake)

    assert too_small(candidate(6.22, True), candidate(0.99, False)) == []
    (offered,) = too_small(candidate(6.22, True), candidate(3.0, True))  # still refused for its size
    assert offered["step"] == 2 and offered["gain"] == 3.0
    assert too_small(candidate(6.22, True))[0]["step"] == 1


def test_two_recordings_give_the_same_sizes_in_either_order():
    """A drive clipped at ±1.5 V into a first-order plant (scipy), recorded twice: a ±0.9 V PRBS that never
    reaches the clip and a ±3 V staircase that does. Sizes were read off the first recording: the clip's
    shortfall was 9 % behind the PRBS and 49 % behind the staircase (a probe's order made it 'not
    material' and named another effect first). They come from the widest drive now, in either order."""
    import hybrid

    rate = 30.0

    def recording(u, seed):
        a = math.exp(-1.0 / (rate * 0.4))
        y = scipy.signal.lfilter([1 - a], [1, -a], np.clip(u, -1.5, 1.5))
        w = 2.0 * y + 0.01 * np.random.default_rng(seed).normal(size=u.size)
        return hybrid.Recording.from_arrays(v_in=u, w=w, rate=rate)

    small = recording(np.repeat(np.random.default_rng(0).uniform(-0.9, 0.9, 90), 20), 1)
    big = recording(np.repeat(np.linspace(-3.0, 3.0, 12), 150), 2)
    found = [
        hybrid.diagnose(pair, simulation=hybrid.LTI(1), effects=["drive_saturation"]).causes[0]["derived"]
        for pair in ([small, big], [big, small])
    ]
    assert found[0] == pytest.approx(found[1], rel=1e-9)
    assert min(found[0]["shortfall_pos_percent"], found[0]["shortfall_neg_percent"]) > 40  # the staircase's


def test_a_size_refused_just_below_its_threshold_is_not_printed_at_it():
    """A probe's "drift … gain change 5.0 % (needs ≥ 5.0 %)" refused a 4.97 % change: a refusal shows the
    digits that tell the size from the threshold, and a size that passes keeps its one decimal."""
    drift = EFFECTS["drift"]()
    need = drift.thresholds["gain_change_percent"]
    refused, said = drift.material({"gain_change_percent": need - 0.03}, {}, drift.thresholds)
    assert not refused and f"gain change {need - 0.03:.2f} % (needs ≥ {need} %)" in said
    kept, said = drift.material({"gain_change_percent": need + 0.03}, {}, drift.thresholds)
    assert kept and f"gain change {need + 0.03:.1f} %" in said

    # every built-in's refusal line so: a delay and frame lag summing to just under a sample, a loop rate
    delay = EFFECTS["delay"]()
    kept, said = delay.material({"delay_samples": 0.497}, {"frame_lag": 0.5}, delay.thresholds)
    assert not kept and "= 0.997 samples (needs ≥ 1.0 in all)" in said, said
