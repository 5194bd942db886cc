"""The paper's choices as defaults: its RC network is the physics unless one is given.

The generic rooms take any simulation (`hybrid.core.make_model`,
`hybrid.discovery.diagnose`) and name none. The package's front,
`hybrid.make_model` and `hybrid.diagnose`, are these two functions: the same,
with the paper's distributed RC network (Eqs 4–14, Table 1 strip, N = 45) in
place of a missing simulation.
"""

from __future__ import annotations

from ..core._arguments import as_recordings
from ..core._models import make_model as make_any_model
from ..discovery._diagnose import diagnose as diagnose_any
from ..discovery._diagnosis import DiagnoseSettings
from ..physics._plugins import ZOH_C_CLAMP, resolve_physics
from ..physics._rc_network import RCNetwork

#: C_clamp (F) of the network `hybrid.diagnose` starts from (``--physics rc:zoh``).
DIAGNOSE_C_CLAMP = ZOH_C_CLAMP


def make_model(
    kind="hybrid", *, simulation=None, window: int = 60, depth: int = 11, width: int = 10, key=None
):
    """The paper's Hybrid, Normal or physics-only model (Fig. 2).

    As `hybrid.core._models.make_model` (every argument is described there),
    with `simulation` defaulting to the paper's [`RCNetwork`][hybrid.RCNetwork]
    with its default parameters (Tustin sections); a string is a ``--physics`` spec
    (`hybrid.resolve_physics`). The Normal model has no simulation.
    """
    if simulation is None and kind != "normal":
        simulation = RCNetwork()
    elif isinstance(simulation, str):  # a --physics spec, resolved as the command line does
        simulation = resolve_physics(simulation)
    return make_any_model(kind, simulation=simulation, window=window, depth=depth, width=width, key=key)


def diagnose_simulation() -> RCNetwork:
    """The RC network `diagnose` starts from, ``--physics rc:zoh``: exact ZOH, C_clamp at `DIAGNOSE_C_CLAMP`."""
    network = resolve_physics("rc:zoh")
    assert isinstance(network, RCNetwork)
    return network


def diagnose(
    recordings,
    *,
    simulation=None,
    effects=None,
    hybrid: bool = False,
    settings: DiagnoseSettings = DiagnoseSettings(),
    hybrid_max_steps: int = 150,
    progress: bool = False,
):
    """What the simulation gets wrong on `recordings`, which effect causes it, and the gain.

    As `hybrid.discovery._diagnose.diagnose` (every argument is described there), with `simulation`
    defaulting to the paper's [`RCNetwork`][hybrid.RCNetwork] discretised
    exactly (``method="zoh"``: the drive is held between samples), starting
    from `DIAGNOSE_C_CLAMP` (the first point of the screened design). A string is a
    ``--physics`` spec, resolved with the recordings as the command line resolves it
    (`hybrid.resolve_physics`: an ``lti:N`` starts on their time scales). Returns a
    `Diagnosis`; ``Diagnosis.to_dict()`` is ``report.json``.
    """
    if simulation is None:
        simulation = diagnose_simulation()
    elif isinstance(simulation, str):  # a --physics spec, resolved as the command line does
        recordings = as_recordings(recordings, "diagnose")  # a path loaded once, for both
        simulation = resolve_physics(simulation, recordings)
    return diagnose_any(
        recordings,
        simulation=simulation,
        effects=effects,
        hybrid=hybrid,
        settings=settings,
        hybrid_max_steps=hybrid_max_steps,
        progress=progress,
    )
