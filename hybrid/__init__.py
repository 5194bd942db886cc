"""hybrid: differentiable physics-ML identification of IPMC soft actuators.

The paper's hybrid model (an RC network turning the drive V_i into a tip
voltage V_o, Eqs 4–14, and a windowed D-MLP mapping V_o to the tip displacement
w) as one JAX program, fitted end to end.

The library never changes `jax.config`: call
``jax.config.update("jax_enable_x64", True)`` in your entry point for float64
(the product of 46 RC sections needs it; the CLI and the tests do this).
"""

from .core._arguments import check_drive as check_drive
from .core._batch import (
    BatchFitResult as BatchFitResult,
    fit_batch as fit_batch,
    simulate_batch as simulate_batch,
)
from .core._fit import fit as fit
from .core._held_start import HeldStart as HeldStart, refit_initial_drive as refit_initial_drive
from .core._loop_safe_linalg import expm as expm, lstsq as lstsq
from .core._metrics import (
    fitting as fitting,
    metrics as metrics,
    nmse as nmse,
    nmse_target as nmse_target,
    nmse_variance as nmse_variance,
)
from .core._models import MODEL_KINDS as MODEL_KINDS, Model as Model
from .core._parameters import (
    Constraint as Constraint,
    Positive as Positive,
    Real as Real,
    SignedUnitInterval as SignedUnitInterval,
    UnitInterval as UnitInterval,
    decode as decode,
    encode as encode,
)
from .core._readout import (
    AbstractReadout as AbstractReadout,
    LinearReadout as LinearReadout,
    WindowedMLP as WindowedMLP,
)
from .core._result import FitResult as FitResult
from .core._serialise import load_model as load_model, save_model as save_model
from .core._simulation import AbstractSimulation as AbstractSimulation, Passthrough as Passthrough
from .core._solvers import (
    SOLVERS as SOLVERS,
    Adam as Adam,
    LevenbergMarquardt as LevenbergMarquardt,
    OptimistixLM as OptimistixLM,
)
from .core._state_space import (
    AbstractLinearStateSpace as AbstractLinearStateSpace,
    AbstractStateSpace as AbstractStateSpace,
)
from .core._windows import sliding_windows as sliding_windows
from .data._drive import Drive as Drive
from .data._drives import DRIVES as DRIVES, load_drive as load_drive, make_drive as make_drive
from .data._mapping import load_mapped as load_mapped, load_pair as load_pair
from .data._recording import Recording as Recording
from .data._split import Split as Split
from .discovery._design import (
    DriveDesign as DriveDesign,
    design_drive as design_drive,
    rich_drive as rich_drive,
)
from .discovery._diagnosis import (
    CAUSES as CAUSES,
    DiagnoseSettings as DiagnoseSettings,
    Diagnosis as Diagnosis,
)
from .discovery._effect_set import EFFECTS as EFFECTS, resolve_effects as resolve_effects
from .discovery._effect_stack import EffectStack as EffectStack, extend as extend
from .discovery._effects import (
    AbstractEffect as AbstractEffect,
    FrameTiming as FrameTiming,
    StartContext as StartContext,
)
from .discovery._inside_effects import (
    Friction as Friction,
    PolynomialStiffness as PolynomialStiffness,
    StateLimit as StateLimit,
    StateWindow as StateWindow,
)
from .discovery._report import write_report as write_report
from .discovery._starts import joint_starts as joint_starts
from .ipmc._defaults import diagnose as diagnose, make_model as make_model
from .physics._lti import LTI as LTI
from .physics._plugins import resolve_physics as resolve_physics
from .physics._rc_network import RCNetwork as RCNetwork
from .physics._reference import reference_response as reference_response
from .physics._strip import Strip as Strip
from .util._cores import (
    use_compilation_cache as use_compilation_cache,
    use_cpu_cores as use_cpu_cores,
    use_quick_compiles as use_quick_compiles,
)
from .util._errors import InputError as InputError

__version__ = "0.1.0"
