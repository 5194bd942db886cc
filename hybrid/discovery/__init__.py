"""What a simulation gets wrong, and why: effects, `diagnose` and its report.

Physical effects that extend any simulation (`EffectStack`), the screened
search that fits each of them, the held-out evidence and decision, residual
tests, and the report. Works with any `AbstractSimulation`; it never imports
a particular physics.
"""

from ._decision import derived_quantities as derived_quantities
from ._decision import lane_effect as lane_effect
from ._diagnosis import SPLIT_ORDER as SPLIT_ORDER
from ._diagnosis import DiagnoseSettings as DiagnoseSettings
from ._diagnosis import Diagnosis as Diagnosis
from ._diagnosis import EquallyGoodFits as EquallyGoodFits
from ._diagnosis import HeldoutMetrics as HeldoutMetrics
from ._diagnosis import HeldoutSignals as HeldoutSignals
from ._diagnosis import Lane as Lane
from ._diagnosis import ParameterUncertainty as ParameterUncertainty
from ._effects import EFFECTS as EFFECTS
from ._effects import AbstractEffect as AbstractEffect
from ._hysteresis import bouc_wen_and_memory as bouc_wen_and_memory
from ._search import (
    fit_lanes as fit_lanes,
)
from ._search import (
    initial_theta as initial_theta,
)
from ._search import (
    lane_tangents as lane_tangents,
)
from ._search import (
    lanes_problem as lanes_problem,
)
from ._search import (
    predictions as predictions,
)
from ._search import (
    search_problem as search_problem,
)
from ._search import (
    split_signals as split_signals,
)
from ._search import (
    universal_model as universal_model,
)
from ._starts import hysteresis_starts as hysteresis_starts
