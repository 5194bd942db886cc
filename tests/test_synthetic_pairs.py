"""The generator's compound recordings: two hidden effects at once, and effects outside the library.

Fast (no diagnose): the pair path against the single-effect code run one effect
after another, the single-effect path against its original pipeline written out
here, each outside form against an independent numpy computation of its stated
property, and the ground truth the metadata records.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from hybrid import Drive, InputError, make_drive
from hybrid.ipmc._hidden_pairs import (
    HIDDEN_NAMES,
    LIBRARY_EFFECTS,
    PHYSICAL_ORDER,
    canonical,
    compound_recording,
    hidden_effects,
    random_hidden,
    rerecord,
    split_hidden,
    true_noise_variance,
)
from hybrid.ipmc._outside_effects import OUTSIDE_EFFECTS
from hybrid.ipmc._synthetic import (
    HIDDEN_EFFECTS,
    SyntheticStrip,
    apply_hidden,
    discrepancy_drive,
    random_effect,
    random_strip,
    rc_cascade_exact,
    synthetic_recording,
)

RATE, M = 30.0, 8
DT = 1.0 / (RATE * M)
STRIP = SyntheticStrip(xi_rho=20.0, xi_h=2.0, C_clamp=0.02, gain_mm_per_v=-1.5, offset_mm=0.2)


def _drive(seconds=20.0, seed=4):
    return discrepancy_drive(seconds, RATE, seed)


def _camera(w_fine, exposure_fraction=0.5):
    """The camera as the generator had it before pairs: exposure average ending at each stamp, then sample."""
    k = max(1, int(round(exposure_fraction * M)))
    padded = np.concatenate([np.full(k - 1, w_fine[0]), w_fine])
    return np.convolve(padded, np.ones(k) / k, mode="valid")[::M]


def _chain(drive, strip, steps, delay_samples=0):
    """w_true by hand: drive on the fine grid, exact cascade, then each single-effect step in turn."""
    v_fine = np.repeat(np.asarray(drive.v, dtype=float), M)
    if delay_samples:
        shift = delay_samples * M
        v_fine = np.concatenate([np.zeros(shift), v_fine[:-shift]])
    t_fine = np.arange(len(v_fine)) * DT
    s = rc_cascade_exact(strip, v_fine, DT)
    for step in steps:
        s = step(s, t_fine)
    return _camera(strip.gain_mm_per_v * s + strip.offset_mm)


def _single(name, params):
    return lambda s, t: apply_hidden(name, params, s, DT, t)


# --- the single-effect path is the one it was ------------------------------------------------------------


@pytest.mark.parametrize("effect", HIDDEN_EFFECTS)
@pytest.mark.parametrize("seed", [0, 7])
def test_single_effect_path_is_the_original_pipeline(effect, seed):
    rng = np.random.default_rng([seed, len(effect), sum(map(ord, effect))])
    strip, params = random_strip(rng), random_effect(effect, rng, RATE)
    drive = _drive(seed=seed)
    rec = synthetic_recording(drive, strip, effect, params, noise_fraction=0.01, seed=seed)
    # the pipeline before pairs existed, written out
    delay = params["delay_samples"] if effect == "delay" else 0
    w_true = _chain(drive, strip, [_single(effect, params)], delay)
    noise = 0.01 * np.ptp(w_true) * np.random.default_rng(seed).standard_normal(len(w_true))
    assert np.array_equal(rec.extra["w_true"], w_true)
    assert np.array_equal(rec.w, w_true + noise)
    hidden = rec.metadata["hidden"]
    assert hidden["effect"] == effect and hidden["effect_params"] == params
    assert hidden["noise_std"] == pytest.approx(0.01 * np.ptp(w_true), rel=1e-12)


# --- pairs -----------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "pair",
    [
        "back_relaxation+saturation",
        "hysteresis+drift",
        "back_relaxation+hysteresis",
        "delay+back_relaxation",
        "saturation+resonance",
        "delay+resonance",
    ],
)
def test_a_pair_applies_both_effects_one_after_another(pair):
    rng = np.random.default_rng(3)
    params = random_hidden(pair, rng, RATE)
    names = split_hidden(pair)
    assert list(params) == list(names)
    drive = _drive()
    rec = synthetic_recording(drive, STRIP, pair, params, noise_fraction=0.0)
    delay = params["delay"]["delay_samples"] if "delay" in params else 0
    expected = _chain(drive, STRIP, [_single(n, params[n]) for n in names if n != "delay"], delay)
    assert np.array_equal(rec.extra["w_true"], expected)
    # both act: the pair differs from each effect alone
    for name in names:
        alone = synthetic_recording(drive, STRIP, name, params[name], noise_fraction=0.0).extra["w_true"]
        assert np.max(np.abs(alone - expected)) > 1e-3 * np.ptp(expected), name
    # the spec's order does not matter: the effects act in physical order
    swapped = "+".join(reversed(pair.split("+")))
    assert np.array_equal(
        synthetic_recording(drive, STRIP, swapped, params, noise_fraction=0.0).extra["w_true"], expected
    )


def test_pair_parameters_are_drawn_as_the_single_draws():
    for pair in ("back_relaxation+saturation", "resonance+delay", "drift+hysteresis", "saturation+dead_zone"):
        a, b = np.random.default_rng(11), np.random.default_rng(11)
        drawn = random_effect(pair, a, RATE)
        singles = {
            n: (OUTSIDE_EFFECTS[n].draw(b, RATE) if n in OUTSIDE_EFFECTS else random_effect(n, b, RATE))
            for n in split_hidden(pair)
        }
        assert drawn == singles


def test_physical_order_keeps_the_library_stack_order():
    from hybrid.discovery._effect_set import EFFECTS

    mine = [n for n in PHYSICAL_ORDER if n in EFFECTS]
    assert mine == [n for n in EFFECTS if n in PHYSICAL_ORDER]
    assert set(LIBRARY_EFFECTS) <= set(EFFECTS)
    assert not set(OUTSIDE_EFFECTS) & set(EFFECTS)  # outside means outside


def test_specs_are_checked():
    assert (
        split_hidden("none") == () and canonical("saturation+back_relaxation") == "back_relaxation+saturation"
    )
    assert set(HIDDEN_NAMES) == {"none"} | set(LIBRARY_EFFECTS) | set(OUTSIDE_EFFECTS)
    for bad, message in (
        ("creep", "unknown hidden effect"),
        ("saturation+saturation", "twice"),
        ("none+delay", "joins 'none'"),
    ):
        with pytest.raises(InputError, match=message):
            synthetic_recording(_drive(5.0), STRIP, bad, {})
    with pytest.raises(InputError, match="a dict per effect"):
        synthetic_recording(_drive(5.0), STRIP, "delay+drift", {"delay_samples": 2})


# --- effects outside the library: each form's property, computed independently ----------------------------


def _ramp_sweep():
    """s from −1 to 1 and back, slowly: every level visited from both sides."""
    t = np.arange(0.0, 20.0, DT)
    return np.sin(2 * np.pi * t / 20.0), t


def test_electrostatic_has_a_material_even_part():
    s, t = _ramp_sweep()
    out, derived = OUTSIDE_EFFECTS["electrostatic"].apply({"quadratic_fraction": 0.3}, s, DT, t)
    mirrored, _ = OUTSIDE_EFFECTS["electrostatic"].apply({"quadratic_fraction": 0.3}, -s, DT, t)
    even, odd = (out + mirrored) / 2, (out - mirrored) / 2
    np.testing.assert_allclose(even, 0.3 * s**2 / np.abs(s).max(), atol=1e-12)
    np.testing.assert_allclose(odd, s, atol=1e-12)
    assert np.ptp(even) / np.ptp(out) > 0.1  # material: no gain (odd) or offset (constant) absorbs it
    # not a gain and offset: an affine fit in s leaves the square's shape
    X = np.c_[s, np.ones_like(s)]
    rest = out - X @ np.linalg.lstsq(X, out, rcond=None)[0]
    assert np.std(rest) > 0.05 * np.ptp(out)
    assert derived == pytest.approx({"peak_v": 1.0, "quadratic_per_v": 0.3}, rel=1e-6)
    # every draw keeps the square material and the map monotone over the range (κ ≤ ½)
    rng = np.random.default_rng(0)
    assert all(
        0.15 <= OUTSIDE_EFFECTS["electrostatic"].draw(rng, RATE)["quadratic_fraction"] <= 0.5
        for _ in range(100)
    )


def test_dead_zone_is_flat_below_the_threshold():
    s, t = _ramp_sweep()
    out, derived = OUTSIDE_EFFECTS["dead_zone"].apply({"threshold_fraction": 0.1}, s, DT, t)
    delta = 0.1 * (s.max() - s.min())
    assert derived["threshold_v"] == pytest.approx(delta)
    inside = np.abs(s) < delta
    assert inside.sum() > 100 and np.all(out[inside] == 0.0)
    expected = np.where(s > delta, s - delta, np.where(s < -delta, s + delta, 0.0))
    np.testing.assert_allclose(out, expected, atol=1e-15)
    rng = np.random.default_rng(1)
    assert all(
        0.03 <= OUTSIDE_EFFECTS["dead_zone"].draw(rng, RATE)["threshold_fraction"] <= 0.20 for _ in range(100)
    )


def _two_ramps(level=1.0, slow_s=8.0, fast_s=0.2, hold_s=10.0):
    """Rest, a slow ramp to `level`, hold, back down slowly, rest, a fast ramp to `level`, hold."""
    n = lambda seconds: int(round(seconds / DT))
    parts = [
        np.zeros(n(2.0)),
        np.linspace(0, level, n(slow_s)),
        np.full(n(hold_s), level),
        np.linspace(level, 0, n(slow_s)),
        np.zeros(n(hold_s)),
        np.linspace(0, level, n(fast_s)),
        np.full(n(hold_s), level),
    ]
    s = np.concatenate(parts)
    ends = np.cumsum([len(p) for p in parts])
    return s, np.arange(len(s)) * DT, ends[1] - 1, ends[5] - 1  # index where each ramp reaches `level`


def test_rate_dependent_response_differs_at_the_same_level_reached_at_two_rates():
    s, t, slow_end, fast_end = _two_ramps()
    params = {"stiffening": 0.8, "memory_s": 0.3}
    out, derived = OUTSIDE_EFFECTS["rate_dependent"].apply(params, s, DT, t)
    # independently: the strain rate, its first-order memory by an explicit loop, the 95th percentile
    rate = np.abs(np.r_[0.0, np.diff(s)]) / DT
    a, r, mem = math.exp(-DT / 0.3), np.empty_like(s), 0.0
    for i, x in enumerate(rate):
        mem = a * mem + (1 - a) * x
        r[i] = mem
    ref = np.percentile(r, 95)
    np.testing.assert_allclose(out, s / (1 + 0.8 * r / ref), rtol=1e-9)
    assert derived["reference_rate_v_per_s"] == pytest.approx(ref, rel=1e-9)
    assert s[slow_end] == s[fast_end] == 1.0
    assert out[fast_end] < out[slow_end] - 0.05  # stiffer when strained faster: less displacement
    assert out[-1] == pytest.approx(1.0, abs=1e-6) and out[slow_end + 2000] == pytest.approx(1.0, abs=1e-6)


def test_self_heating_gain_follows_the_recent_power():
    s, t, slow_end, fast_end = _two_ramps(hold_s=30.0)
    params = {"gain_change": -0.4, "thermal_time_s": 5.0}
    out, derived = OUTSIDE_EFFECTS["self_heating"].apply(params, s, DT, t)
    a, h, mem = math.exp(-DT / 5.0), np.empty_like(s), 0.0
    for i, x in enumerate(s * s):
        mem = a * mem + (1 - a) * x
        h[i] = mem
    np.testing.assert_allclose(out, s * (1 - 0.4 * h / h.max()), rtol=1e-9)
    assert derived["reference_heat_v2"] == pytest.approx(h.max(), rel=1e-9)
    # at the same level, the strip held hot for 30 s responds less than one just arrived from rest
    assert out[-1] < out[fast_end] - 0.1


def _memory(u, tau):
    """First-order memory from rest, x[n] = a x[n−1] + (1 − a) u[n], by scipy's lfilter."""
    import scipy.signal

    a = math.exp(-DT / tau)
    return scipy.signal.lfilter([1 - a], [1, -a], u)


# --- the ground truth recorded -----------------------------------------------------------------------------


@pytest.mark.parametrize("spec", list(OUTSIDE_EFFECTS) + ["saturation+dead_zone", "delay+electrostatic"])
def test_outside_recordings_record_their_ground_truth(spec):
    rng = np.random.default_rng(5)
    params = random_effect(spec, rng, RATE)
    drive = make_drive("prbs", 60.0, rate=RATE, seed=2, amplitude=2.0)
    rec = synthetic_recording(drive, STRIP, spec, params, noise_fraction=0.02, seed=9)
    hidden = rec.metadata["hidden"]
    names = split_hidden(spec)
    assert hidden["effect"] == canonical(spec) and hidden["effects"] == list(names) == list(
        hidden_effects(rec)
    )
    assert hidden["outside"] == [n for n in names if n in OUTSIDE_EFFECTS]
    assert hidden["effect_params"] == params and hidden["strip"]["gain_mm_per_v"] == STRIP.gain_mm_per_v
    by_name = params if len(names) > 1 else {names[0]: params}
    # the whole recording by hand, each outside form from its numpy formula with the recorded truth
    steps = []
    for name in names:
        if name == "delay":
            continue
        if name not in OUTSIDE_EFFECTS:
            steps.append(_single(name, by_name[name]))
            continue
        truth = {**by_name[name], **hidden["derived"][name]}
        steps.append(
            {
                "electrostatic": lambda s, t, p=truth: s + p["quadratic_per_v"] * s**2,
                "dead_zone": lambda s, t, p=truth: (
                    np.sign(s) * np.clip(np.abs(s) - p["threshold_v"], 0, None)
                ),
                "rate_dependent": lambda s, t, p=truth: (
                    s
                    / (
                        1
                        + p["stiffening"]
                        * _memory(np.abs(np.r_[0.0, np.diff(s)]) / DT, p["memory_s"])
                        / p["reference_rate_v_per_s"]
                    )
                ),
                "self_heating": lambda s, t, p=truth: (
                    s * (1 + p["gain_change"] * _memory(s * s, p["thermal_time_s"]) / p["reference_heat_v2"])
                ),
            }[name]
        )
    delay = by_name["delay"]["delay_samples"] if "delay" in by_name else 0
    np.testing.assert_allclose(
        rec.extra["w_true"], _chain(drive, STRIP, steps, delay), rtol=1e-12, atol=1e-12
    )
    # the noise the generator knows
    assert hidden["noise_variance"] == pytest.approx(true_noise_variance(rec), rel=1e-12)
    assert np.var(rec.w - rec.extra["w_true"]) == pytest.approx(hidden["noise_variance"], rel=0.1)
    # a library-only recording answers the same helpers
    plain = synthetic_recording(drive, STRIP, "drift", {"change": 0.3, "shape": "linear"})
    assert hidden_effects(plain) == ("drift",) and true_noise_variance(plain) > 0


# --- another drive, the same strip (rerecord) --------------------------------------------------------------


def test_rerecord_under_the_same_drive_and_seed_is_the_recording():
    params = random_hidden("saturation+hysteresis+electrostatic", np.random.default_rng(3), RATE)
    rec = synthetic_recording(_drive(), STRIP, "saturation+hysteresis+electrostatic", params, seed=5)
    again = rerecord(rec, _drive(), seed=5)
    assert np.array_equal(again.w, rec.w) and again.metadata["hidden"] == rec.metadata["hidden"]


def test_rerecord_keeps_the_saturation_level_and_the_noise_when_the_drive_shrinks():
    """Half the drive meets the first recording's σ± in volts (not σ rescaled to its own peaks), and its noise std."""
    params = {"shortfall_pos": 0.4, "shortfall_neg": 0.2}
    drive = _drive()
    rec = synthetic_recording(drive, STRIP, "saturation", params, noise_fraction=0.02, seed=1)
    half = Drive(drive.t, 0.5 * np.asarray(drive.v), "half", {"rate": RATE})
    again = rerecord(rec, half, seed=2)
    # σ from the definition: the shortfall at the first recording's peak of the drive-side signal s
    s = rc_cascade_exact(STRIP, np.repeat(np.asarray(drive.v, float), M), DT)
    sigma = {}
    for side, sign, f in (("pos", 1.0, 0.4), ("neg", -1.0, 0.2)):
        peak = np.max(sign * s)
        sigma[side] = peak / math.sqrt(1.0 / (1.0 - f) ** 2 - 1.0)
        assert 1.0 - 1.0 / math.sqrt(1.0 + (peak / sigma[side]) ** 2) == pytest.approx(f, rel=1e-12)
    s_half = 0.5 * s  # the cascade is linear
    sat = np.where(s_half > 0, s_half / np.sqrt(1 + (s_half / sigma["pos"]) ** 2), s_half)
    sat = np.where(s_half < 0, s_half / np.sqrt(1 + (s_half / sigma["neg"]) ** 2), sat)
    np.testing.assert_allclose(
        again.extra["w_true"], _camera(STRIP.gain_mm_per_v * sat + STRIP.offset_mm), atol=1e-12
    )
    # rescaled to its own peaks, the half drive would lose 40 % at its own peak: a different strip
    fresh = synthetic_recording(half, STRIP, "saturation", params, noise_fraction=0.02, seed=2)
    assert np.max(np.abs(fresh.extra["w_true"] - again.extra["w_true"])) > 0.05 * np.ptp(
        again.extra["w_true"]
    )
    std = rec.metadata["hidden"]["noise_std"]
    assert again.metadata["hidden"]["noise_std"] == std == pytest.approx(0.02 * np.ptp(rec.extra["w_true"]))
    assert np.std(again.w - again.extra["w_true"]) == pytest.approx(std, rel=0.1)  # 600 samples
    assert true_noise_variance(again) == pytest.approx(std**2)


@pytest.mark.parametrize("name", sorted(OUTSIDE_EFFECTS))
def test_rerecord_keeps_what_an_outside_form_took_from_the_first_signal(name):
    params = {name: OUTSIDE_EFFECTS[name].draw(np.random.default_rng(0), RATE)}
    rec = compound_recording(_drive(), STRIP, name, params[name], seed=0)
    other = rerecord(rec, _drive(seed=9), seed=1)
    assert other.metadata["hidden"]["derived"] == rec.metadata["hidden"]["derived"]
    own = compound_recording(_drive(seed=9), STRIP, name, params[name], seed=1)
    assert own.metadata["hidden"]["derived"] != rec.metadata["hidden"]["derived"]  # the drive would move it


def test_rerecord_refuses_a_recording_it_did_not_make():
    from hybrid import Recording

    t = np.arange(100) / RATE
    plain = Recording(t=t, v_in=np.sin(t), w=np.cos(t), name="lab.csv")
    with pytest.raises(InputError, match="not a synthetic recording"):
        rerecord(plain, _drive(), seed=0)
