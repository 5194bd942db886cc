"""The paper's IPMC: the virtual IPMC (an independent strip simulator that
stands in for a lab), synthetic strips with hidden effects, the Table 2
reproduction, the Cramér–Rao sensitivity study, and the paper's defaults
(the RC network as the physics of `make_model` and `diagnose`).
"""

from ._hidden_pairs import (
    HIDDEN_NAMES as HIDDEN_NAMES,
    canonical as canonical,
    hidden_effects as hidden_effects,
    rerecord as rerecord,
    true_noise_variance as true_noise_variance,
)
from ._sensitivity_study import (
    SensitivityStudySettings as SensitivityStudySettings,
    run_sensitivity_study as run_sensitivity_study,
)
from ._synthetic import (
    HIDDEN_EFFECTS as HIDDEN_EFFECTS,
    SyntheticStrip as SyntheticStrip,
    apply_hidden as apply_hidden,
    discrepancy_drive as discrepancy_drive,
    random_effect as random_effect,
    random_strip as random_strip,
    rc_cascade_exact as rc_cascade_exact,
    synthetic_recording as synthetic_recording,
)
from ._table2 import ROWS as TABLE2_ROWS, Table2Settings as Table2Settings
from ._virtual_ipmc import (
    simulate_virtual_ipmc as simulate_virtual_ipmc,
    virtual_recording as virtual_recording,
)
from ._virtual_parameters import VirtualIPMCParameters as VirtualIPMCParameters
