"""What the final model leaves above the measurement noise, and where it lives.

`diagnose` names causes from a closed list; measured data has effects no list
names. So after the stepwise search, the final model's held-out error is set
against the noise floor of w, estimated from the recordings alone
(`hybrid.discovery._noise_floor`). When the held-out MSE is more than
`DiagnoseSettings.unexplained_ratio` times the floor (by default: more than
half of the held-out error lies above the noise, counting the floor at the top
of its ±2 standard errors), the answer carries an ``unexplained`` part: how
much of the error lies above the floor, and where it lives
(`hybrid.discovery._remainder`: static or dynamic, even or odd in the drive,
what a flexible extension recovers on held-out data; `hybrid.discovery._level_limit`:
whether the record sits flat at an extreme while the model goes beyond it). Otherwise
``unexplained`` is None: the model is as good as the measurement allows.

When the held-out MSE is more than `FAR_ABOVE_FLOOR` times the floor (its RMS
ten times the floor's σ), ``unexplained`` also carries a ``floor_warning``: the
share "above the noise" then says only that the model misses by far more than
w varies from sample to sample, and on smoothed or oversampled data that
variation is not the measurement error (see `hybrid.discovery._noise_floor`).
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from ..core._level_limit import level_limits, limit_sentence
from ..core._simulation import unit_in
from ..core._state_space import dynamics_of, own_forces
from ._diagnosis import EquallyGoodFits, HeldoutSignals
from ._effect_stack import (
    EffectStack,
    drive_responses,
    force_responses,
    state_trajectories,
)
from ._noise_floor import NoiseFloor, noise_floor
from ._remainder import MAX_STATES, ROLES, UNSTRUCTURED_EXCESS, basis_forces, describe_remainder, state_basis
from ._search import split_signals

#: Held-out MSE over the floor above which ``unexplained`` warns that the floor is far below the error.
FAR_ABOVE_FLOOR = 100.0


#: Share of the excess over the floor that a map of the drive, the model or time recovers held out from
#: which the caveat says the excess is the model's miss rather than doubting the floor.
MISS_RECOVERED = 0.5


def floor_caveat(
    mse: float, floor: NoiseFloor, recovered: float | None = None, concentrated: dict | None = None
) -> str | None:
    """A sentence when a held-out MSE is so far above the floor that the floor tells little, else None.

    `recovered`: the share of the excess that the remainder's best map recovers
    held out (``description["recovered"]["of_excess"]``). Where it is at least
    `MISS_RECOVERED`, the excess is predictable from the drive, the model or
    time, which noise (smoothed or not) is not: it is the model's miss, and the
    sentence says so instead of doubting the floor (a piezo stage read to 0.03
    µm, tried as a new user would, was told "if w was smoothed …" beside a
    creep its model lacked). `concentrated`: the held-out stretch that holds
    most of the excess (``description["concentrated"]``); where it holds
    `MISS_RECOVERED` of it or more, and twice its share of the held-out samples,
    noise, which is spread over the record, is not what the floor misses either (a probe's 20 min drift, right but not
    extrapolating into the last held-out stretch, was told "if w was smoothed …").
    """
    if not (floor.variance > 0 and mse > FAR_ABOVE_FLOOR * floor.variance):
        return None
    what = (  # a fit's floor: its source also says why w's own was not kept
        f"the differences of a fit's held-out residual ({floor.method})"
        if floor.from_fit
        else floor.source or floor.method
    )
    head = (
        f"the held-out error's RMS is {math.sqrt(mse / floor.variance):.3g}× the floor's σ: the floor, from "
        f"{what}, is far below the model's error, so the share above it says only that the "
        "model misses by far more than w varies from sample to sample"
    )
    if recovered is not None and math.isfinite(recovered) and recovered >= MISS_RECOVERED:
        return (
            f"{head}; a map fitted on the training part recovers {recovered:.0%} of that excess held out, which "
            "measurement noise, smoothed or not, would not allow: most of the excess is the model's miss"
        )
    stretch = concentrated or {}
    share = float(stretch.get("share") or 0.0)
    evenly = float(stretch.get("samples_fraction") or 1.0)  # its share were the excess spread
    if share >= max(MISS_RECOVERED, 2.0 * evenly) and stretch.get("t"):
        start, end = stretch["t"]
        return (
            f"{head}; {share:.0%} of that excess lies in one held-out stretch, t = {start:.4g}–{end:.4g} s, "
            "where measurement noise, smoothed or not, is spread over the record: most of the excess is the "
            "model's miss there"
        )
    return (
        f"{head}; if w was smoothed, filtered, interpolated or oversampled, that processing removed the "
        "variation the floor reads, and the measurement error is not known from the data"
    )


def pooled_noise_floor(recordings) -> NoiseFloor:
    """The noise floor of several recordings of one strip: variances pooled by sample count."""
    floors = [noise_floor(r.w, r.v_in, r.rate) for r in recordings]
    if len(floors) == 1:
        return floors[0]
    n = np.array([len(r.w) for r in recordings], float)
    weights = n / n.sum()
    variance = float(np.sum(weights * [f.variance for f in floors]))
    std_error = float(math.sqrt(np.nansum((weights * [f.std_error for f in floors]) ** 2)))
    spread = float(np.var(np.concatenate([np.asarray(r.w, float) for r in recordings])))
    methods = sorted({f.method for f in floors})
    sources = list(dict.fromkeys(f.source for f in floors))
    quanta = [f.quantum for f in floors if np.isfinite(f.quantum)]
    return NoiseFloor(
        variance=variance,
        std_error=std_error,
        method=", ".join(methods),
        estimates={f"recording {i}": f.variance for i, f in enumerate(floors)},
        fraction_of_variance=variance / spread if spread > 0 else float("nan"),
        source=f"{len(floors)} recordings pooled by sample count, each from " + "; ".join(sources),
        quantum=max(quanta) if len(quanta) == len(floors) else float("nan"),
        warnings=tuple(  # a recording's spikes are its own: the sentence says which recording
            dict.fromkeys(
                f"Recording {i + 1}: {w}" if w == f.spike_note else w
                for i, f in enumerate(floors)
                for w in f.warnings
            )
        ),
        spike_note=" ".join(
            f"Recording {i + 1}: {f.spike_note}" for i, f in enumerate(floors) if f.spike_note
        ),
    )


def _part(problem, recordings, candidate, split: str) -> dict:
    """t, v_in, w, ŵ, a segment id and a recording index per sample, for one part of the split (all recordings)."""
    v, w, w_hat = split_signals(problem, candidate.theta, candidate.active, split)
    # as `split_signals` cuts them: the problem's recorded segments (round any sample not measured), each
    # its own segment (the held-out part's, `Diagnosis.heldout`, alike): a tracker's dropped frames cut one
    spans = [(i, a, b) for i, s in enumerate(problem.series) for a, b in s.recorded_segments_of(split)]
    t = np.concatenate([np.asarray(recordings[i].t, float)[a:b] for i, a, b in spans])
    recording = np.concatenate([np.full(b - a, i) for i, a, b in spans])
    return {
        "t": t,
        "v_in": v,
        "w": w,
        "w_hat": w_hat,
        "segment": np.concatenate([np.full(b - a, k) for k, (_, a, b) in enumerate(spans)]),
        "recording": recording,
    }


def _recorded(signal, s, split) -> list:
    """(rows, samples) of a padded series `s` → its recorded samples of `split`, a block per segment."""
    return [signal[..., a:b] for a, b in s.recorded_segments_of(split)]


def _add(parts: dict, key: str, signal, s) -> None:
    """`signal`'s training and held-out samples of series `s`, onto ``parts[key + "train"/"heldout"]``."""
    parts[f"{key}train"] += _recorded(signal, s, "train")
    parts[f"{key}heldout"] += _recorded(signal, s, "test")


def _joined(parts: dict) -> dict:
    """Each part's blocks, joined along the samples."""
    return {key: np.concatenate(blocks, axis=1) for key, blocks in parts.items()}


def _final_stack(problem, final):
    """(`final`'s model, its `EffectStack` with `final`'s switches), or None where it has none."""
    model = problem.model(jnp.asarray(final.theta))
    if not isinstance(model.simulation, EffectStack):
        return None
    return model, model.simulation.with_active(np.asarray(final.active, float))


def _readout_gain(model) -> float | None:
    readout = model.readout.parameters()
    return float(readout["gain"]) if "gain" in readout else None


def feedback_signals(problem, model, stack) -> dict | None:
    """What `_remainder`'s state feedback fits on: each state's map's columns as responses, on train and test.

    For a simulation in state-space form with at most `MAX_STATES` states:
    the final model's state trajectories on each recording, a basis of maps of
    each state from its training values (`state_basis`), and the model's
    output response to each map taken off its drive (`force_responses`, the
    dynamics linearised along the recording), cut to the training and
    held-out samples; and the maps' columns themselves (``direct_train``,
    ``direct_heldout``), a map of a state read on the output. None otherwise. `model` and `stack`: the
    final model and its stack with its switches (`_final_stack`).
    """
    dynamics = dynamics_of(stack.inner)
    if dynamics is None or len(dynamics[0].states) > MAX_STATES:
        return None
    names = dynamics[0].states

    # The search's series, padded to their buckets' lengths: the two programs serve every recording of
    # a bucket, as the search's do (a session that diagnoses many recordings compiles them once).
    series = problem.series
    states = [np.asarray(state_trajectories(stack, s.v_in, s.dt)).T for s in series]  # (states, samples)
    train = np.concatenate(
        [part for x, s in zip(states, series) for part in _recorded(x, s, "train")], axis=1
    )
    bases = {name: state_basis(train[k]) for k, name in enumerate(names)}
    columns: list[tuple[str, str]] = []
    parts: dict[str, list] = {"train": [], "heldout": [], "direct_train": [], "direct_heldout": []}
    for x, s in zip(states, series):
        rows = []
        for k, name in enumerate(names):
            rows.append(basis_forces(bases[name], x[k]))
            if s is series[0]:
                columns += [(name, role) for role in ROLES]
        direct = np.concatenate(rows)
        responses = np.asarray(force_responses(stack, s.v_in, s.dt, jnp.asarray(direct)))
        _add(parts, "", responses, s)
        _add(parts, "direct_", direct, s)  # the maps themselves: read on the output
    return {
        "states": list(names),
        "columns": columns,
        **_joined(parts),
        "bases": bases,
        "values": {name: train[k] for k, name in enumerate(names)},  # on the training part
        "units": {name: unit_in(unit, stack.drive_unit) for name, unit in dynamics[0].state_units.items()},
        "drive_unit": stack.drive_unit,
        "force_unit": stack.force_unit,  # the drive's, or where the simulation puts a force (`forced_rates`)
        "into": "its dynamics (where the plug-in's forced_rates puts a force)"
        if own_forces(dynamics[0])
        else "its drive",
        "gain": _readout_gain(model),
    }


#: The drive's training quantiles at which a clip of its top is tried (`drive_map_signals`; the bottom's at
#: one less each): a level the drive stops at, where the free map's hats, 7 quantiles apart, blur a knee.
CLIP_QUANTILES = (0.5, 0.6, 0.7, 0.75, 0.8, 0.85, 0.9, 0.95)


def drive_map_signals(problem, model, stack, settings) -> dict:
    """What `_remainder`'s map of the drive fits on: each map's column as the model's response, train and test.

    A static map φ(u) of the drive before the dynamics (a clip, a dead zone, a
    pump's curve) moves the output by the model's response to φ(u) − u. For any
    simulation (no state-space form needed) the final model is linearised along
    each recording (`drive_responses`) and fed each column of a map of the drive
    level (`state_basis` on the drive's training values, `basis_forces`): the
    columns' responses (``train``, ``heldout``; ``roles``: the columns' names in `ROLES`, the hats and,
    for a two-signed drive, a step at zero), cut to the training and held-out samples.
    ``retune_train``/``retune_heldout``: the output's derivatives in the simulation's free parameters
    (those `settings` does not freeze): a map of the drive comes with the simulation retuned to first
    order, as a fit of it would (a lag fitted to a clipped drive has bent its time constant and gain to
    it). ``clips``: (end, level) of a cut of the drive beyond each of `CLIP_QUANTILES` of it, top and
    bottom, with their responses (``clip_train``, ``clip_heldout``). `model` and `stack`: the final
    model and its stack with its switches (`_final_stack`).
    """
    series = problem.series  # padded to their buckets, as the search's (see `feedback_signals`)

    drive = np.concatenate([part for s in series for part in _recorded(np.asarray(s.v_in), s, "train")])
    basis = state_basis(drive)
    roles = [f"hat_{k}" for k in range(len(basis["knots"]))] + (["step"] if basis["step"] else [])
    rows = [ROLES.index(role) for role in roles]  # the free map's columns: one derivative each
    frozen = set(settings.frozen_for(stack.inner))
    free = [name for name in stack.inner.parameter_names() if name not in frozen]
    # A clip of the drive at each of a few levels, a form the free map is read against (its level told)
    clips = [("top", float(level)) for level in np.quantile(drive, CLIP_QUANTILES)] + [
        ("bottom", float(level)) for level in np.quantile(drive, [1.0 - q for q in CLIP_QUANTILES])
    ]
    parts: dict[str, list] = {
        f"{key}{split}": [] for key in ("", "clip_", "retune_") for split in ("train", "heldout")
    }
    for s in series:
        u = np.asarray(s.v_in)
        columns = np.concatenate(
            [
                basis_forces(basis, u)[rows],
                [
                    np.minimum(u, level) - u if end == "top" else np.maximum(u, level) - u
                    for end, level in clips
                ],
            ]
        )
        responses, retune = (
            np.asarray(x) for x in drive_responses(stack, s.v_in, s.dt, jnp.asarray(columns), tuple(free))
        )
        _add(parts, "", responses[: len(rows)], s)
        _add(parts, "clip_", responses[len(rows) :], s)
        _add(parts, "retune_", retune, s)
    return {
        "basis": basis,
        "roles": roles,
        **_joined(parts),
        "clips": clips,
        "drive_unit": stack.drive_unit,
        "gain": _readout_gain(model),
    }


def remainder(
    problem,
    recordings,
    final,
    heldout: HeldoutSignals,
    floor: NoiseFloor,
    settings,
    rate: float,
    equally_good: EquallyGoodFits | None = None,
    places: dict | None = None,
    w_unit: str = "",
    loose: tuple[str, ...] = (),
    v_unit: str = "",
) -> dict | None:
    """None when `final`'s held-out error is consistent with the noise floor, else what lies above it.

    `heldout` is `Diagnosis.heldout` (its ``extended`` is `final`'s prediction); the
    training part is predicted here only when there is something to describe. `w_unit`
    labels the levels a limit clause quotes (the report's unit of w), `v_unit` the drive's. `loose`: the
    simulation's parameters the recording does not pin; where the remainder is
    placed on a state, the sentence says the state is the fitted model's.
    """
    held = {
        "t": heldout.t,
        "v_in": heldout.v_in,
        "w": heldout.w,
        "w_hat": heldout.extended,
        "segment": heldout.segment,
        "recording": heldout.recording,
    }
    residual = held["w"] - held["w_hat"]
    mse = float(np.mean(residual**2))
    var_w = float(np.var(held["w"]))
    top = floor.variance + 2.0 * (floor.std_error if np.isfinite(floor.std_error) else 0.0)
    if mse <= settings.unexplained_ratio * top:
        return None
    train = _part(problem, recordings, final, "train")
    if floor.spikes and len(recordings) == 1:  # the floor's spikes and glitches, by held-out sample
        at = (
            heldout.sample
            if heldout.sample is not None
            else np.concatenate([np.arange(a, b) for a, b in problem.series[0].recorded_segments_of("test")])
        )
        held["spike"] = np.isin(at, floor.spikes)
    final_stack = _final_stack(problem, final)
    feedback = drive_map = None
    if final_stack is not None:
        model, stack = final_stack
        feedback = feedback_signals(problem, model, stack)
        drive_map = drive_map_signals(problem, model, stack, settings)
    if feedback is not None and (
        feedback["train"].shape[1] != len(train["w"]) or feedback["heldout"].shape[1] != len(held["w"])
    ):
        feedback = None  # (the recorded samples of both are the split's: a guard, not a case met)
    if drive_map is not None and (
        drive_map["train"].shape[1] != len(train["w"]) or drive_map["heldout"].shape[1] != len(held["w"])
    ):
        drive_map = None  # (as the feedback's: a guard)
    description = describe_remainder(
        train,
        held,
        rate,
        floor.variance,
        feedback,
        w_unit,
        spiky=floor.spike_words,
        v_unit=v_unit,
        drive_map=drive_map,
    )
    # A hard limit of the level shows where the record sits flat and the model goes on, in either part.
    description["level_limit"] = level_limits([train, held], floor.variance)
    clause = limit_sentence(description["level_limit"], len(train["w"]) + len(held["w"]), w_unit)
    if clause:
        description["summary"] += f"; {clause}"
    if loose and (description.get("recovered") or {}).get("named") == "state_map":
        description["summary"] += (
            f"; the states are the fitted model's, whose {', '.join(loose)} this recording does not pin: the "
            "force may act on another state that moves as this one does in the system"
        )
    hint = place_hint(description, places or {})
    if hint:
        description["place"] = "inside"
        description["summary"] += f"; {hint}"
    elif hint := named_only_hint(description, places or {}):
        description["summary"] += f"; {hint}"
        description["named_only"] = named_only_effect(description, places or {})
    if "named_only" not in description and (band := band_beside(description, places or {})):
        description["summary"] += f"; {band}"
        description["named_only"] = _DEAD_BAND[0]
    out = {
        "fraction_above_floor": 1.0 - floor.variance / mse,
        "heldout_nmse": mse / var_w,
        "floor_nmse": floor.variance / var_w,
        "excess_nmse": (mse - floor.variance) / var_w,
        "ratio_to_floor": mse / floor.variance,
        "description": description,
    }
    caveat = floor_caveat(
        mse, floor, (description.get("recovered") or {}).get("of_excess"), description.get("concentrated")
    )
    if caveat:
        out["floor_warning"] = caveat
    if equally_good is not None and np.isfinite(equally_good.heldout_nmse_min):
        best = equally_good.heldout_nmse_min * var_w
        if best <= settings.unexplained_ratio * top:
            out["underdetermined"] = (
                f"a fit of the same model as good on training data reaches {best / floor.variance:.2f}× the noise "
                "floor held out: the recording does not pin the model (record longer, or drive it harder)"
            )
    return out


#: What a remainder recovered best by each of these maps may be, and the built-in searched only when named
#: (`NAMED_ONLY`) that would take it: (the effect, what it is in a lab's words).
_CREEP = ("creep", "a slow response to the drive that the simulation lacks (a creep, a second time constant)")
_NAMED_ONLY_HINTS = {
    "periodic": ("line", "a sinusoid added to the output at that frequency (a vibration, a pick-up)"),
    "filter_drive": _CREEP,
    "time": _CREEP,
    "static_drive": (
        "drive_clip",
        "a drive that stops at its levels more sharply than a tanh bends (an amplifier's rails, a DAC's range, a "
        "valve's stops)",
    ),
    "drive_map": (
        "drive_clip",
        "a drive that stops at its levels more sharply than a tanh bends (an amplifier's rails, a DAC's range, a "
        "valve's stops, a heater's or a pump's limit)",
    ),
    "static_output_monotone": (
        "clip",
        "an output that stops at its levels more sharply than a tanh bends (a sensor's full scale, an ADC's range)",
    ),
}


#: The maps a slow response reads as, and the share of the excess the best of them recovers for a remainder
#: read as unstructured to be pointed at creep: half of what a remainder needs to be read as one of them
#: (`UNSTRUCTURED_EXCESS`). tests/test_creep.py's creep (τ = 3 s, 40 s at 25 Hz) left 18 % to a trend once
#: the search held the readout in w's scale, 23 % before.
_SLOW = tuple(kind for kind, hint in _NAMED_ONLY_HINTS.items() if hint is _CREEP)
_SLOW_SHARE = UNSTRUCTURED_EXCESS / 2


def _dead_band(description: dict) -> bool:
    """The output's monotone map flat in the middle and rising at its ends: the opposite of a clip."""
    shape = ((description.get("static") or {}).get("output_monotone") or {}).get("shape") or {}
    return bool(
        (shape.get("flat_middle") or {}).get("flag") and not (shape.get("levels_off") or {}).get("flag")
    )


#: What an output map flat in the middle and rising at its ends (`_dead_band`) may be: the built-in that takes it.
_DEAD_BAND = (
    "dead_band",
    "an output that stays at rest until the simulation's output passes a width (a sensor's or a linkage's dead "
    "band, stiction at a clamp)",
)


#: A reading whose own form rules its hint out (`_NAMED_ONLY_HINTS`): a change at one time, or a wander, is no creep; a
#: curve of the drive that stops at no level, and a dead band of the output, are no clip (the latter is `_DEAD_BAND`).
_NOT_THE_HINT = {
    "time": lambda description: (description.get("time") or {}).get("form") in ("step", "wander", "gain"),
    "drive_map": lambda description: not (description.get("drive_map") or {}).get("levels_off"),
    "static_output_monotone": _dead_band,
}


def named_only_hint(description: dict, places: dict) -> str | None:
    """The built-in searched only when named (`NAMED_ONLY`) that may take a remainder, where it was not searched.

    A piezo's creep read "a linear filter of the drive" at 50 Hz; a creep slower than the remainder's
    filters (τ = 3 s at 25 Hz: 75 samples, the filters' 25 lags) reads "a trend in time". An amplifier
    that clips at ±5 V read "static and odd in the drive … it bends at the largest drive levels" beside
    the drive's tanh saturation, whose knee bends over the whole range (gain 2.7; its clip, named, left
    nothing unexplained: `tests/test_hard_clip.py`). A remainder read as unstructured whose best map is
    one of those (`_SLOW`) gets the creep's pointer too.
    """
    pointer = _pointer(description, places)
    if pointer is None:
        return None
    effect, what = pointer
    hint = f"{what} may also explain it: the built-in {effect} {_asked(effect)}"
    windows = (places.get("inside") or {}).get("windows") or []
    if effect == "drive_clip" and windows:
        # a limit of either sign on every state of a group reads from outside as a clip of the drive (an
        # electrolyte's window on the RC network's compartments: `tests/test_inside_effects.py -k window`)
        hint += (
            f"; so may a window of either sign on every state of {windows[0].removeprefix('window_')} inside "
            f"the dynamics, which reads alike from outside (the built-in {windows[0]}, searched when named)"
        )
    return hint


def _asked(effect: str) -> str:
    """How a hint asks for a built-in searched only when named (`tried_hint` takes it back)."""
    return f"is searched when named (--effects builtins,{effect})"


def tried_hint(description: dict) -> None:
    """`description`'s hint (`named_only_hint`) where its effect was tried in its parent's place and not kept:
    the summary says so instead of asking for it (a verifier's asymmetric dead band: dead_band tried and
    refused, then "the built-in dead_band is searched when named")."""
    effect = description.get("named_only")
    if not effect:
        return
    description["summary"] = description.get("summary", "").replace(
        _asked(effect), "was tried in its place, and did not take it (evidence.refined)"
    )


def band_beside(description: dict, places: dict) -> str | None:
    """The dead band's hint where the output's monotone map is flat in the middle (`_dead_band`) and recovers
    at least `UNSTRUCTURED_EXCESS` of the excess, though another reading recovers more, else None.

    A verifier's band of 30 % of the output's range on a 1.5 Hz oscillator read "the cube of the model's
    output through a linear filter … 60 %" (the band's kink through the dynamics' fit), its monotone map
    flat in the middle at 47 %; the band was not pointed at, nor tried, and named by hand it took the rest.
    """
    share = float(((description.get("static") or {}).get("output_monotone") or {}).get("of_excess") or 0.0)
    searched = {e for place in places.values() for e in place.get("effects", ())}
    if not places or _DEAD_BAND[0] in searched or share < UNSTRUCTURED_EXCESS or not _dead_band(description):
        return None
    return (
        f"{_DEAD_BAND[1]} may also explain it (a map of the output flat in the middle recovers {share:.0%} of the "
        f"excess): the built-in {_DEAD_BAND[0]} {_asked(_DEAD_BAND[0])}"
    )


def named_only_effect(description: dict, places: dict) -> str | None:
    """The name of the built-in that `named_only_hint` points at, or None."""
    pointer = _pointer(description, places)
    return None if pointer is None else pointer[0]


def _pointer(description: dict, places: dict) -> tuple[str, str] | None:
    """(the named-only built-in, what it is in a lab's words) that `named_only_hint` points at."""
    recovered = description.get("recovered") or {}
    named = recovered.get("named")
    if (
        named is None
        and recovered.get("best") in _SLOW
        and (recovered.get("of_excess") or 0.0) >= _SLOW_SHARE
    ):
        named = recovered["best"]  # unstructured, its best map a slow one: how a creep the filters miss reads
    searched = {e for place in places.values() for e in place.get("effects", ())}
    if named not in _NAMED_ONLY_HINTS or not places:
        return None
    if named == "static_output_monotone" and _dead_band(description):
        effect, what = _DEAD_BAND
    elif named in _NOT_THE_HINT and _NOT_THE_HINT[named](description):
        return None
    else:
        effect, what = _NAMED_ONLY_HINTS[named]
    return None if effect in searched else (effect, what)


def place_hint(description: dict, places: dict) -> str | None:
    """Where an effect that explains the rest would act, when that is inside the dynamics, and what was searched.

    A nonlinearity fed back through the dynamics, a force proportional to the
    simulation's states fed back into its drive, or a level the record sits
    flat at, points inside; the sentence says whether `diagnose` searched there
    (it needs a simulation in state-space form) and, if it did, that a plug-in
    effect of the user's own is what is left; where the best state's map reads
    as a step at zero (a dry friction's), the built-in ``friction_<state>``
    instead, when it was not searched (by default it is only on the
    simulation's velocities, `velocities`).
    """
    inside = places.get("inside")
    limit = description.get("level_limit") or {}
    flat = any(
        isinstance(side, dict) and side.get("flag") for side in (limit.get("top"), limit.get("bottom"))
    )
    # (the level test runs on every remainder: a level the record sits flat at is one it flagged; a
    # quantised output, static on the output, was sent inside because the test's dict was there)
    named = (description.get("recovered") or {}).get("named")
    if inside is None or not (
        description.get("kind") == "nonlinear_dynamic" or named == "state_linear" or flat
    ):
        return None
    if inside["not_searched"]:
        return f"an effect inside the dynamics may explain it, but {inside['not_searched']}"
    fed = description.get("state_feedback") or {}
    # the state named only where its map carries most of the rest, as its form is (`_state_feedback`)
    best = (fed.get("states") or {}).get(fed.get("best")) or {}
    strong = bool(best.get("carries"))
    alike = "".join(f" or {other}" for other in fed.get("alike") or {})
    on = f" on its state {fed['best']}{alike}" if named == "state_map" and strong else ""
    searched = f"of the effects searched inside the dynamics ({', '.join(inside['effects'])}), none explains the rest"
    friction = f"friction_{fed.get('best')}"
    if on and best.get("form") == "step" and friction not in inside["effects"]:
        # a step at zero is a dry friction's, and the built-in takes one: point at it before a user writes it
        return (
            f"{searched}: a dry friction{on} may; the built-in {friction} takes one, searched when named "
            f"(--effects builtins,{friction})"
        )
    return f"{searched}: an effect of your own there{on} may (docs/effects.md)"
