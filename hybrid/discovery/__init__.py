"""What a simulation gets wrong, and why: effects, `diagnose` and its report.

Physical effects that extend any simulation (`EffectStack`), the screened
search that fits each of them, the held-out evidence and decision, residual
tests, and the report. Works with any `AbstractSimulation`; it never imports
a particular physics.
"""

# Names hybrid's front exports (hybrid/__init__.py) are exported there once; here, what
# experiments and benchmarks use beyond them.
from ._ambiguity import paired_difference as paired_difference
from ._decision import derived_quantities as derived_quantities, lane_effect as lane_effect
from ._diagnosis import (
    RENAMED_IN_SCHEMA_3 as RENAMED_IN_SCHEMA_3,
    RENAMED_IN_SCHEMA_4 as RENAMED_IN_SCHEMA_4,
    REPORT_SCHEMA as REPORT_SCHEMA,
    SPLIT_ORDER as SPLIT_ORDER,
    EquallyGoodFits as EquallyGoodFits,
    HeldoutMetrics as HeldoutMetrics,
    HeldoutSignals as HeldoutSignals,
    Lane as Lane,
    ParameterUncertainty as ParameterUncertainty,
)
from ._effects import affine_recurrence as affine_recurrence, foh_matrices as foh_matrices
from ._hysteresis import bouc_wen_and_memory as bouc_wen_and_memory
from ._search import (
    fit_lanes as fit_lanes,
    initial_theta as initial_theta,
    lane_tangents as lane_tangents,
    lanes_problem as lanes_problem,
    predictions as predictions,
    search_problem as search_problem,
    split_signals as split_signals,
    universal_model as universal_model,
)
from ._starts import hysteresis_starts as hysteresis_starts
