"""The remainder's level-limit check: a record flat at its extreme while the simulation goes beyond.

Records are a first-order lag's response (numpy) to a slow random drive, with
the limit applied the way a lab meets it: a sensor clipped at the top of its
range after the noise (flat, noise-free samples), a tank that cannot go below
empty. The "simulation" is the same lag without the limit, so the check must
find the clipped side and only it; records without a limit, a plateau the
model follows, a smooth noisy peak and a quantised record must raise no flag.
"""

from __future__ import annotations

import numpy as np
import pytest

from hybrid.core._level_limit import level_limits, limit_sentence

NOISE = 0.02


def lag_response(n=1200, seed=0, tau=15.0):
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.uniform(-1.0, 1.0, n // 60 + 1), 60)[:n]
    a, y, state = np.exp(-1.0 / tau), np.empty(n), 0.0
    for k in range(n):
        y[k] = state
        state = a * state + (1 - a) * u[k]
    return y, rng


def parts(w, w_hat, n_train):
    """A training part and a held-out part, each one segment, as diagnose hands them over."""
    seg = np.zeros(len(w))
    return [
        {"w": w[:n_train], "w_hat": w_hat[:n_train], "segment": seg[:n_train]},
        {"w": w[n_train:], "w_hat": w_hat[n_train:], "segment": seg[n_train:]},
    ]


def test_a_sensor_clipped_at_the_top_is_found_on_that_side_only():
    y, rng = lag_response()
    top = np.quantile(y, 0.93)
    w = np.minimum(y + NOISE * rng.normal(size=y.size), top)
    found = level_limits(parts(w, y, 800), NOISE**2)
    assert found["top"]["flag"] and not found["bottom"]["flag"]
    assert found["top"]["level"] == pytest.approx(top, abs=1e-12)
    clipped, near = int(np.sum(w >= top)), int(np.sum(w >= top - 0.5 * NOISE))  # "at" the top: within ½ sd
    assert 0.7 * clipped <= found["top"]["samples"] <= near  # runs shorter than 5 samples do not count
    assert found["top"]["model_extreme"] == pytest.approx(y.max(), abs=1e-12)
    text = limit_sentence(found, len(w))
    assert "flat at its largest value" in text and "smallest" not in text


def test_an_empty_tank_is_a_limit_at_the_bottom():
    y, rng = lag_response(seed=3)
    w = np.maximum(y + NOISE * rng.normal(size=y.size), 0.0) + 2.0  # empty below 0, sensor offset 2
    found = level_limits(parts(w, y + 2.0, 700), NOISE**2)
    assert found["bottom"]["flag"] and not found["top"]["flag"]
    assert found["bottom"]["level"] == pytest.approx(2.0, abs=1e-12)
    assert "flat at its smallest value (2)" in limit_sentence(found, len(w))
    text = limit_sentence(found, len(w), "cm")  # the levels in w's unit, as the recording declares it
    assert (
        "flat at its smallest value (2 cm)" in text
        and f"falls to {found['bottom']['model_extreme']:.4g} cm" in text
    )


@pytest.mark.parametrize(
    "case",
    [
        "no limit",
        "plateau the model follows",
        "a level error on a held plateau",
        "smooth noisy peak",
        "quantised",
    ],
)
def test_no_flag_without_a_limit(case):
    y, rng = lag_response(seed=5)
    noise = NOISE * rng.normal(size=y.size)
    floor = NOISE**2
    if case == "no limit":
        w, w_hat = y + noise, y
    elif (
        case == "plateau the model follows"
    ):  # held at the top, noise-free (e.g. a record rounded to the level)
        y = np.r_[y, np.full(200, y.max() + 0.3)]
        w, w_hat = np.r_[y[:-200] + noise, y[-200:]], y
    elif case == "smooth noisy peak":
        t = np.linspace(0.0, 12.0, y.size)
        w_hat = np.sin(t)
        w = w_hat + noise
    elif (
        case == "a level error on a held plateau"
    ):  # the model flat too, only higher: a gain error, not a limit
        y = np.r_[y, np.full(200, y.max() + 0.3)]
        w, w_hat = np.r_[y[:-200] + noise, y[-200:]], y + 0.2 * (y > y.max() - 1e-9)
    else:  # steps of 0.05, 25× the noise floor given: the unquantised model moves within one step of them
        w, w_hat, floor = np.round(y / 0.05) * 0.05, y, 0.002**2
    found = level_limits(parts(w, w_hat, 800), floor)
    assert not found["top"]["flag"] and not found["bottom"]["flag"], found
    assert limit_sentence(found, len(w)) is None


def test_runs_never_cross_a_segment():
    y, rng = lag_response()
    top = np.quantile(y, 0.9)
    w = np.minimum(y + NOISE * rng.normal(size=y.size), top)
    seg = np.arange(y.size) % 4  # every sample its own segment: no run of 5 inside one
    found = level_limits([{"w": w, "w_hat": y, "segment": seg}], NOISE**2)
    assert found["top"]["samples"] == 0 and not found["top"]["flag"]


def _recording(w):
    from hybrid import Recording

    return Recording.from_arrays(v_in=np.zeros_like(w), w=w, rate=30.0)


def _held_out(recording, blocks):
    from hybrid.core._problem import split_segments
    from hybrid.discovery._diagnosis import SPLIT_ORDER, DiagnoseSettings

    mask = np.zeros(recording.n, bool)
    for a, b in dict(split_segments(recording, DiagnoseSettings().split, SPLIT_ORDER, blocks))["test"]:
        mask[a:b] = True
    return mask


def test_the_held_out_parts_see_where_the_record_sits_flat_at_its_top():
    """A clipped stretch that 3 blocks leave in training: the fewest blocks whose held-out parts see it."""
    import dataclasses

    from hybrid.discovery._diagnosis import DiagnoseSettings, _split_description
    from hybrid.discovery._search import held_out_blocks

    y, rng = lag_response(seed=5)
    w = y + NOISE * rng.normal(size=y.size)
    settings = DiagnoseSettings()
    assert held_out_blocks([_recording(w)], settings) == (3, True)  # no flat extreme: as asked

    clipped = w.copy()
    clipped[160:200] = w.max() + 0.05  # a sensor at the top of its range, in block 1's training part
    recording = _recording(clipped)
    assert not _held_out(recording, 3)[160:200].any()
    blocks, reached = held_out_blocks([recording], settings)
    assert reached and blocks > 3
    assert _held_out(recording, blocks)[160:200].any()
    assert not any(_held_out(recording, b)[160:200].any() for b in range(3, blocks))  # the fewest
    assert held_out_blocks([recording], dataclasses.replace(settings, held_out_limits=False)) == (3, True)
    said = _split_description(dataclasses.replace(settings, blocks_used=blocks, extremes_held_out=True))
    assert f"each recording in {blocks} equal blocks (3 asked: {blocks} are the fewest" in said

    early = w.copy()
    early[:10] = w.min() - 0.05  # flat at the bottom in the first samples: training for every count
    assert held_out_blocks([_recording(early)], settings) == (3, False)
    said = _split_description(dataclasses.replace(settings, blocks_used=3, extremes_held_out=False))
    assert "a limit there is tested on training data alone" in said
