"""When a recording cannot tell two causes apart, the report says so (issue 35, item 2).

The test's statistics against an independent reference (scipy's exact
binomial test), and `diagnose` on a constructed confound: a staircase drive
whose level rises with time hides a gain that drifts over time, which a
saturation (a gain that falls with level) explains as well; on random levels
the two are told apart. The plant (a first-order lag) is made here with
scipy's `lfilter`, not by the library.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.signal import lfilter
from scipy.stats import binomtest

import hybrid
from hybrid.discovery._ambiguity import ALPHA, level_time_correlation, paired_difference, power_near, sentence

RATE, N = 30.0, 1800


def test_the_sign_test_over_decorrelated_chunks_is_scipys_binomial_test():
    rng = np.random.default_rng(0)
    named = rng.normal(size=3000)
    slow = np.repeat(rng.normal(size=300), 10)  # errors that stay alike for 10 samples
    for rival, worse in ((named + 0.05 * rng.normal(size=3000), False), (named * 1.3 + 0.1 * slow, True)):
        test = paired_difference(named, rival)
        d = rival**2 - named**2
        reference = binomtest(test["wins"], test["chunks"], 0.5, alternative="greater").pvalue
        assert test["p_value"] == pytest.approx(reference, rel=1e-9)
        assert (test["p_value"] <= ALPHA) == worse
        assert test["chunks"] <= 3000 and test["mean"] == pytest.approx(np.mean(d))
    # correlated differences are compared in chunks of their decorrelation length, not sample by sample
    correlated = paired_difference(named, named + slow)
    assert correlated["chunks"] < 3000 / 5


def test_level_time_and_frequency_evidence():
    t = np.arange(N) / RATE
    staircase = np.repeat(np.linspace(0.2, 2.0, 10), N // 10)
    assert level_time_correlation([staircase]) > 0.95
    random_levels = np.repeat(np.random.default_rng(1).uniform(0, 2, N // 15), 15)
    assert level_time_correlation([random_levels]) < 0.5
    slow = np.sin(2 * np.pi * 0.2 * t)
    assert power_near([slow], RATE, 0.2) > 0.9 and power_near([slow], RATE, 5.0) < 1e-3


def _recording(staircase: bool, seed: int = 0) -> hybrid.Recording:
    """A first-order lag (τ 0.5 s) whose gain decays by 1.2 %/s; the drive a staircase or random levels."""
    rng = np.random.default_rng(seed)
    if staircase:
        u = np.repeat(np.linspace(0.2, 2.0, 10), N // 10)
    else:
        u = np.repeat(rng.uniform(0.0, 2.2, N // 15), 15)
    a = np.exp(-1.0 / (RATE * 0.5))
    w = lfilter([1 - a], [1, -a], u) * np.exp(-0.012 * np.arange(N) / RATE)
    w = w + 0.005 * np.ptp(w) * rng.normal(size=N)
    return hybrid.Recording.from_arrays(v_in=u, w=w, rate=RATE)


def test_a_drift_hidden_by_a_rising_staircase_is_reported_ambiguous_and_random_levels_separate_it(tmp_path):
    effects = ["saturation", "drift"]  # the two rivals of the confound (the search's other effects: other tests)
    confounded = hybrid.diagnose(_recording(staircase=True), simulation=hybrid.LTI(1), effects=effects)
    assert confounded.cause in effects
    (entry,) = confounded.to_dict()["ambiguous"]
    (rival,) = entry["rivals"]
    assert {entry["named"], rival["name"]} == set(effects)
    assert rival["p_value"] > ALPHA and rival["named_wins"] <= rival["chunks"]
    assert any("level and time are correlated" in why for why in entry["why"])
    text = sentence(entry)
    assert "cannot tell" in text and rival["name"] in text and "\n" not in text
    paths = hybrid.write_report(confounded, tmp_path)  # report.md says it in one sentence
    assert f"**Ambiguous.** {text}" in paths["report.md"].read_text()
    assert json.loads(paths["report.json"].read_text())["ambiguous"][0]["rivals"][0]["name"] == rival["name"]

    separated = hybrid.diagnose(_recording(staircase=False), simulation=hybrid.LTI(1), effects=effects)
    assert separated.cause == "drift" and separated.ambiguous == []
