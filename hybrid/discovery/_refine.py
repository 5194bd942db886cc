"""A named effect's refinement tried in its place: a saturation's tanh knee against a clip's.

A heater that stops sharply at 13 W, driven over 0–20 W into a first-order
block (`tests/test_refine.py`; `--no-refine` gives the default set's own
answer): the default set named `drive_even`, a concave quadratic of the drive,
with `drive_saturation` its rival (a tanh's knee bends over the whole range),
and left most of what remained above the noise; its remainder read "static in
the drive … a clip of the drive recovers as much" and pointed at `drive_clip`.
A probe's heated block (0–20 W, 13 W) got `drive_saturation` with a wrong
`drive_even` beside it; `drive_clip`, named by hand, left nothing. A clip's
knee of any sharpness contains the tanh's (sharpness 1), so it fits at least
as well; but it is searched only when named (`NAMED_ONLY`): in the default set
its third parameter stood in for effects of other shapes.

So where a diagnosis of the default set names an effect with a
`refinement` and leaves at least `min_gain` times the noise floor, or names it
beside two other causes (`CROWDED`), or its remainder or a named cause's fit
(`AbstractEffect.points_at`: a probe's heater clipped at 6 V read `drive_even`
turning down over the last 16 % of the drive) points at one,
`diagnose` runs again with every refinement in its parent's place (the clip of
the drive and of the output both: a probe's drive clip, read as the output's
tanh, was refined to the output's clip alone and left 1.6–2× the floor), and
keeps the second diagnosis only where it names the refinement and its
extended model's held-out NMSE is `min_gain` times lower than the first's (the
step's own rule for a cause), or no higher with fewer causes named. Either way ``evidence.refined`` says what was
tried and what came of it.
"""

from __future__ import annotations

import math
from typing import Any

from ._unexplained import tried_hint

#: How many named causes, one with a refinement among them (a saturation), make a refinement worth trying even
#: at the noise floor: a clip's sharp knee may be what they fake together (a probe's drive clip beside a Coulomb friction, in
#: its own plug-in, read as drive_saturation, the friction and a dead zone never hidden, "measurement noise").
CROWDED = 3
#: Why a refinement is tried, as its sentence says it.
LEFT_ABOVE = "something was left above the noise"
CROWDED_WHY = "{cause} was named beside {others} other causes, which {target} in its place may stand for"
POINTED_WHY = "{cause}'s fit reads as {target}"


def refinable(
    effects, kept, unexplained: dict | None, builtins, room: float, min_gain: float, pointers=None
) -> dict[str, str]:
    """The refinements to try, by the name of the searched effect each takes the place of.

    Each named cause's `refinement`, where the final model's held-out error
    is still `room` ≥ `min_gain` times the noise floor (below that not even a
    perfect refinement could gain the `min_gain` its rule asks: a sensor that
    clipped a quarter of the time left a tanh's fit at 1.8× the floor, under
    the 2× called unexplained), or where `CROWDED` causes are named (a clip and
    one other may then explain as much: `refined` keeps the fewer); and the named-only effect the remainder points
    at (``description.named_only``: a drive that stops sharply read as "static
    in the drive … a clip of the drive recovers as much") where it is the
    refinement of a searched effect, or that a named cause's fit points at
    (`pointers`: the cause's name → `AbstractEffect.points_at`). Where either holds, every searched effect's refinement is tried
    in its place, the other places' too. None already searched, and {} unless
    every one of `builtins` (the default set's effects for this simulation)
    was searched: a list without them is the caller's choice, and is not
    changed.
    """
    by_name = {e.name: e for e in effects}
    if not {e.name for e in builtins} <= by_name.keys():
        return {}
    swaps = {e.name: e.refinement for e in effects if e.refinement and e.refinement not in by_name}
    saturated = any(name in swaps for name in kept)
    named = saturated and (room >= min_gain or len(kept) >= CROWDED)
    pointed = ((unexplained or {}).get("description") or {}).get("named_only") in swaps.values()
    pointed = pointed or any(target in swaps.values() for target in (pointers or {}).values())
    # every refinement at once: a clip of the drive read through the dynamics as a tanh on the output (a
    # probe's ±1.5 V drive clip: `saturation` refined to `clip`, 1.6–2× the floor left; `drive_clip` named
    # by hand, 1.497 V and nothing left), so the second run searches the clip in each place
    return swaps if named or pointed else {}


def refined_effects(effects, swaps: dict[str, str]) -> list:
    """The searched effects with each refinement in its parent's place."""
    return [e for e in effects if e.name not in swaps] + list(swaps.values())


def refinement_reason(
    kept, room: float, min_gain: float, unexplained: dict | None, pointers=None, swaps=None
) -> str:
    """Why `refinable`'s `swaps` are tried, as `refined`'s sentence and the progress line say it."""
    if room >= min_gain or unexplained is not None:
        return LEFT_ABOVE
    if pointers:
        cause, target = next(iter(pointers.items()))
        return POINTED_WHY.format(cause=cause, target=target)
    swaps = swaps or {}
    cause = next((name for name in kept if name in swaps), None)
    if len(kept) < CROWDED or cause is None:
        return LEFT_ABOVE
    return CROWDED_WHY.format(cause=cause, others=len(kept) - 1, target=swaps[cause])


def refined(first, again, swaps: dict[str, str], min_gain: float, why: str = LEFT_ABOVE) -> tuple[Any, dict]:
    """The diagnosis to keep, `first` or `again` (run with `swaps` made), and ``evidence.refined``."""
    first_causes, again_causes = _names(first), _names(again)
    named = [to for to in swaps.values() if to in again_causes]
    ratio = first.extended.heldout.nmse / max(again.extended.heldout.nmse, 1e-300)
    ratio = ratio if math.isfinite(ratio) else 0.0  # a second fit that is not finite gains nothing
    # fewer causes, as good held out: a probe's drive clip beside a Coulomb friction read as a tanh, the
    # friction and a dead zone never hidden (the three faking the clip's sharp knee); refined, the clip and
    # the friction alone, 1.12× lower, which the min_gain rule let the three-cause diagnosis keep
    simpler = bool(named) and len(again_causes) < len(first_causes) and ratio >= 1.0
    keep = (bool(named) and ratio >= min_gain) or simpler
    tried = _tried(swaps)
    said = f"diagnosed again with {tried}, as {why}: "
    if keep and ratio < min_gain:
        said += (
            f"it names {', '.join(again_causes)}, fewer causes than {', '.join(first_causes)}, and its extended "
            f"model's held-out NMSE is {ratio:.2f}× lower: as good held out with fewer causes, that diagnosis "
            "is the one reported"
        )
    elif keep:
        said += (
            f"it names {', '.join(again_causes)}, and its extended model's held-out NMSE is {ratio:.2f}× lower "
            f"than with {', '.join(first_causes) or 'no cause'}: that diagnosis is the one reported"
        )
    elif named:
        lower = (
            f"is only {ratio:.2f}× lower (needs {min_gain})"
            if ratio >= 1
            else f"is {1 / ratio:.2f}× higher"
            if ratio > 0
            else "is not finite"
        )
        said += f"it names {', '.join(named)}, but its held-out NMSE {lower}: the first diagnosis stands"
    else:
        said += f"it does not name {' or '.join(swaps.values())}: the first diagnosis stands"
    evidence = {
        "swaps": dict(swaps),
        "causes": again_causes,
        "heldout_nmse": again.extended.heldout.nmse,
        "gain_over_first": ratio,
        "kept": keep,
        "first_causes": first_causes,
        "sentence": said,
    }
    description = (getattr(first, "unexplained", None) or {}).get("description") or {}
    if not keep and description.get("named_only") in swaps.values():
        tried_hint(description)  # the first stands: its remainder no longer asks for what was just tried
    return (again if keep else first), evidence


def _names(diagnosis) -> list[str]:
    return [cause["name"] for cause in diagnosis.causes]


def _tried(swaps: dict[str, str]) -> str:
    each = [f"{to} in place of {name}" for name, to in swaps.items()]
    return " and ".join([", ".join(each[:-1]), each[-1]] if len(each) > 2 else each)


def refused(swaps: dict[str, str], error: Exception) -> dict:
    """``evidence.refined`` where the second diagnosis could not be made: the first stands, and says why."""
    tried = _tried(swaps)
    return {
        "swaps": dict(swaps),
        "kept": False,
        "error": str(error),
        "sentence": f"a diagnosis with {tried} could not be made ({error}): this one stands",
    }
