"""Hardware for IPMC experiments: DAC streaming over serial, camera capture and tip tracking.

The public names are re-exported here once; the modules are free to move.
"""

from ._board import BAUD as BAUD, Board as Board, PlayReport as PlayReport, Timing as Timing
from ._board import sample_timing as sample_timing
from ._calibration import Calibration as Calibration, fit_calibration as fit_calibration
from ._errors import RigError as RigError
