"""The generic framework: a model is a simulation followed by a readout.

The simulation interface (`AbstractSimulation`: named, constrained parameters
with units, plausible and typical ranges, parameters frozen by default), the
readouts (linear, windowed D-MLP), the least-squares problem with its
structured Jacobian, Levenberg–Marquardt, `fit`, `fit_batch`, metrics and
serialisation. Nothing here knows a particular physics.
"""

from ._arguments import check_drive as check_drive
from ._fit import fit as fit
from ._fit import lm_init_batch as lm_init_batch
from ._fit import lm_run_batch as lm_run_batch
from ._fit import start_model as start_model
from ._levenberg_marquardt import LMSettings as LMSettings
from ._levenberg_marquardt import lm_init as lm_init
from ._levenberg_marquardt import lm_step as lm_step
from ._loop_safe_linalg import expm as expm
from ._loop_safe_linalg import lstsq as lstsq
from ._models import Model as Model
from ._parameters import (
    Constraint as Constraint,
)
from ._parameters import (
    Positive as Positive,
)
from ._parameters import (
    Real as Real,
)
from ._parameters import (
    SignedUnitInterval as SignedUnitInterval,
)
from ._parameters import (
    UnitInterval as UnitInterval,
)
from ._parameters import (
    decode as decode,
)
from ._parameters import (
    encode as encode,
)
from ._problem import (
    Problem as Problem,
)
from ._problem import (
    Series as Series,
)
from ._problem import (
    bucket_length as bucket_length,
)
from ._problem import (
    series_from_recording as series_from_recording,
)
from ._simulation import AbstractSimulation as AbstractSimulation
from ._solvers import Adam as Adam
from ._solvers import LevenbergMarquardt as LevenbergMarquardt
from ._solvers import OptimistixLM as OptimistixLM
