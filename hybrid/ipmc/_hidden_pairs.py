"""Several hidden effects at once, and effects outside the library: the generator's compound recordings.

A *hidden spec* names what a synthetic recording hides: ``"none"``, one name, or
names joined by ``+`` (``"back_relaxation+saturation"``). The names are the
library's hidden effects (`hybrid.ipmc._synthetic.HIDDEN_EFFECTS`, made by the
forms there) and the effects outside the library
(`hybrid.ipmc._outside_effects.OUTSIDE_EFFECTS`). A recording is made as in
`synthetic_recording` — drive on the fine grid, the cascade discretised exactly,
the effects, gain and offset, the camera and its noise, with the same code — and
the effects act in `PHYSICAL_ORDER` whatever the order of the spec:

1. ``delay``: the electronics' dead time, on the drive (before the cascade);
2. the cascade (charge), then ``electrostatic``: charge → stress, with a square part;
3. ``back_relaxation``: water and ions redistribute and relax the stress;
4. ``saturation``: the stress the polymer can make is limited;
5. ``rate_dependent``: stress → strain through a stiffness that rises with the strain rate;
6. ``hysteresis``, ``dead_zone``: friction and stiction in the bending;
7. ``self_heating``, ``drift``: slow states of the whole strip (temperature, hydration) scale its response;
8. ``resonance``: the beam's mechanics, last, filter everything before it.

The library's effects keep the order in which `hybrid.discovery`'s stack applies
them (delay, back-relaxation, saturation, hysteresis, drift, resonance). Each
effect's parameters are drawn as its single-effect draw does
(`random_effect`), one effect after another in physical order.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..util._errors import InputError
from ._outside_effects import OUTSIDE_EFFECTS
from ._synthetic import (
    HIDDEN_EFFECTS,
    SyntheticStrip,
    apply_hidden,
    camera,
    fine_drive,
    hidden_derived,
    random_effect,
    rc_cascade_exact,
)

#: The library's hidden effects (those an extension is meant to find).
LIBRARY_EFFECTS = tuple(e for e in HIDDEN_EFFECTS if e != "none")

#: Every hidden effect, in the order it acts on the signal.
PHYSICAL_ORDER = (
    "delay",
    "electrostatic",
    "back_relaxation",
    "saturation",
    "rate_dependent",
    "hysteresis",
    "dead_zone",
    "self_heating",
    "drift",
    "resonance",
)

#: The registry: every name a hidden spec may use ("none" alone).
HIDDEN_NAMES = ("none",) + PHYSICAL_ORDER

assert set(PHYSICAL_ORDER) == set(LIBRARY_EFFECTS) | set(OUTSIDE_EFFECTS)


def is_outside(name: str) -> bool:
    """Whether `name` is an effect outside the library."""
    return name in OUTSIDE_EFFECTS


def split_hidden(spec) -> tuple[str, ...]:
    """The effects of a hidden spec (``"a+b"``, a name, or a sequence of names) in physical order; () for none."""
    names = [n.strip() for n in (spec.split("+") if isinstance(spec, str) else spec)]
    unknown = [n for n in names if n not in HIDDEN_NAMES]
    if unknown:
        raise InputError(
            f"unknown hidden effect {unknown[0]!r}: choose from {', '.join(HIDDEN_NAMES)}, "
            "or join several with '+'"
        )
    if len(set(names)) != len(names):
        raise InputError(f"hidden spec {spec!r} names an effect twice")
    if "none" in names:
        if len(names) > 1:
            raise InputError(f"hidden spec {spec!r} joins 'none' with an effect")
        return ()
    return tuple(sorted(names, key=PHYSICAL_ORDER.index))


def canonical(spec) -> str:
    """The spec's name: its effects in physical order joined by '+', or "none"."""
    return "+".join(split_hidden(spec)) or "none"


def _draw(name: str, rng: np.random.Generator, rate: float) -> dict:
    return OUTSIDE_EFFECTS[name].draw(rng, rate) if is_outside(name) else random_effect(name, rng, rate)


def random_hidden(spec, rng: np.random.Generator, rate: float) -> dict:
    """Parameters for a hidden spec: flat for one effect (as `random_effect`), else a dict per effect.

    Effects are drawn one after another in physical order, each as its single draw.
    """
    names = split_hidden(spec)
    if len(names) <= 1:
        return _draw(names[0], rng, rate) if names else {}
    return {name: _draw(name, rng, rate) for name in names}


def parameters_by_effect(spec, params: dict | None) -> dict[str, dict]:
    """`params` of a spec as a dict per effect (a flat dict for a single effect is accepted)."""
    names = split_hidden(spec)
    params = dict(params or {})
    if set(params) == set(names) and all(isinstance(v, dict) for v in params.values()):
        return {n: dict(params[n]) for n in names}
    if len(names) == 1:
        return {names[0]: params}
    if not names and not params:
        return {}
    raise InputError(
        f"parameters for {canonical(spec)!r} must be a dict per effect ({', '.join(names)}), "
        f"got keys {sorted(params)}"
    )


def compound_recording(
    drive,
    strip: SyntheticStrip = SyntheticStrip(),
    effect="none",
    effect_params=None,
    *,
    noise_fraction: float = 0.01,
    oversample: int = 8,
    exposure_fraction: float = 0.5,
    seed: int = 0,
    derived: dict | None = None,
    noise_std: float | None = None,
):
    """A Recording of `strip` under `drive` hiding every effect of the spec `effect`, in physical order.

    Arguments as `synthetic_recording` (which sends every spec here);
    `effect_params` as from `random_hidden`. `derived` (per effect) and
    `noise_std` (mm): the values an earlier recording of the strip took from its
    signal, kept so that another drive meets the same strip (`rerecord`); None
    takes them from this recording's signal. The truth is in
    ``metadata["hidden"]``: ``effect`` (the canonical spec), ``effects`` (in
    physical order), ``outside`` (those outside the library), ``effect_params``
    (flat for one effect, else per effect), ``derived`` (per effect, the values
    its form took from the signal: a saturation's σ±, a loop's span, an outside
    form's reference), ``noise_std`` and ``noise_variance``; and ``extra["w_true"]``.
    """
    from ..data._recording import Recording

    names = split_hidden(effect)
    params = parameters_by_effect(names, effect_params)
    rate, v = float(drive.rate), np.asarray(drive.v, dtype=float)
    m = int(oversample)
    dt_fine = 1.0 / (rate * m)
    v_fine = fine_drive(v, m, params["delay"]["delay_samples"] if "delay" in params else 0)
    t_fine = np.arange(len(v_fine)) * dt_fine
    s = rc_cascade_exact(strip, v_fine, dt_fine)
    given = dict(derived or {})
    derived = {}
    for name in names:
        if is_outside(name):
            s, derived[name] = OUTSIDE_EFFECTS[name].apply(params[name], s, dt_fine, t_fine, given.get(name))
        elif name != "delay":
            derived[name] = given.get(name) or hidden_derived(name, params[name], s)
            s = apply_hidden(name, params[name], s, dt_fine, t_fine, derived[name])
    w_fine = strip.gain_mm_per_v * s + strip.offset_mm
    w_true, noise, std = camera(w_fine, m, exposure_fraction, noise_fraction, seed, noise_std)
    spec = "+".join(names) or "none"
    hidden = {
        "effect": spec,
        "effects": list(names),
        "outside": [n for n in names if is_outside(n)],
        "effect_params": params[names[0]] if len(names) == 1 else params,
        "derived": derived,
        "strip": dataclasses.asdict(strip),
        "noise_fraction": noise_fraction,
        "noise_std": std,
        "noise_variance": std**2,
        "oversample": m,
        "exposure_fraction": exposure_fraction,
        "seed": seed,
    }
    return Recording(
        t=np.asarray(drive.t, dtype=float),
        v_in=v,
        w=w_true + noise,
        extra={"w_true": w_true},
        metadata={"source": "hybrid.ipmc._synthetic", "drive": drive.metadata, "hidden": hidden},
        name=f"synthetic {spec} ({drive.name}, seed {seed})",
    )


def hidden_effects(recording) -> tuple[str, ...]:
    """The effects a synthetic recording hides, in physical order (() for none); any generator's recording."""
    return split_hidden(recording.metadata["hidden"]["effect"])


def true_noise_variance(recording) -> float:
    """The variance of the Gaussian noise the generator added (its std: ``metadata["hidden"]["noise_std"]``)."""
    return float(recording.metadata["hidden"]["noise_std"]) ** 2


def rerecord(recording, drive, *, seed: int):
    """The strip of a synthetic `recording`, with its hidden effects and camera, under another `drive`.

    Everything the generator drew or took from the first recording's signal is
    kept: the strip, the effects' parameters, the values their forms derived from
    the signal (a saturation's σ± in V, a Preisach loop's span, an outside form's
    reference) and the noise std in mm. So the two recordings are of one physical
    strip, as two runs on a rig are, and `diagnose([recording, rerecord(...)])`
    can fit them jointly; a new drive with a smaller range meets the same
    saturation, not one rescaled to it. A ``drift`` is each recording's own (its
    change over the recording, as drawn). `seed` seeds the new noise.
    """
    hidden = recording.metadata.get("hidden") if isinstance(recording.metadata, dict) else None
    if not hidden or "noise_std" not in hidden or "derived" not in hidden:
        raise InputError(
            f"rerecord: {recording.name!r} is not a synthetic recording of this generator "
            "(metadata['hidden'] with 'derived' and 'noise_std'): make it with hybrid.ipmc.synthetic_recording"
        )
    return compound_recording(
        drive,
        SyntheticStrip(**hidden["strip"]),
        hidden["effect"],
        hidden["effect_params"],
        noise_fraction=hidden["noise_fraction"],
        oversample=hidden["oversample"],
        exposure_fraction=hidden["exposure_fraction"],
        seed=seed,
        derived=hidden["derived"],
        noise_std=hidden["noise_std"],
    )
