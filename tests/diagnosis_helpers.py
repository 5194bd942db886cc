"""A `hybrid.Diagnosis` built from hand-made search steps, for tests of what a diagnosis reports."""

from __future__ import annotations

import numpy as np

import hybrid
from hybrid.discovery._diagnosis import HeldoutSignals
from hybrid.discovery._redundant import NO_BAR
from hybrid.discovery._step import Step


def step(current, chosen) -> Step:
    """A search step that extended `current` by `chosen` (its one candidate), with no effect-free bar."""
    return Step(current, [chosen], chosen, 0.0, [], NO_BAR, [])


def diagnosis_of(search, steps, *, cause: str, baseline, extended, candidates, **fields) -> hybrid.Diagnosis:
    """The diagnosis of `search` (`prepare_search`) whose `steps` named `cause`: no evidence, three held-out
    samples, `fields` (e.g. ``dropped``) as given."""
    three = np.arange(3.0)
    return hybrid.Diagnosis(
        cause=cause,
        baseline=baseline,
        extended=extended,
        candidates=candidates,
        uncertainties={},
        evidence={},
        hybrid=None,
        settings=search.settings,
        recordings=["r"],
        seconds=0.0,
        heldout=HeldoutSignals(three, three, three, three, three, np.zeros(3), np.zeros(3)),
        steps=steps,
        effects=search.effects,
        **fields,
    )
