"""The generic framework: a model is a simulation followed by a readout.

The simulation interface (`AbstractSimulation`: named, constrained parameters
with units, plausible and typical ranges, parameters frozen by default), the
readouts (linear, windowed D-MLP), the least-squares problem with its
structured Jacobian, Levenberg–Marquardt, `fit`, `fit_batch`, metrics and
serialisation. Nothing here knows a particular physics.
"""

# What hybrid's front (hybrid/__init__.py) exports is exported there once; here, the pieces that
# experiments and benchmarks use below fit(): the least-squares problem and LM's steps.
from ._fit import lm_init_batch as lm_init_batch, lm_run_batch as lm_run_batch, start_model as start_model
from ._levenberg_marquardt import LMSettings as LMSettings, lm_init as lm_init, lm_step as lm_step
from ._problem import (
    Problem as Problem,
    Series as Series,
    bucket_length as bucket_length,
    series_from_recording as series_from_recording,
)
