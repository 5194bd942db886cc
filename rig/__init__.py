"""Hardware for IPMC experiments: DAC streaming over serial, camera capture and tip tracking.

The public names are re-exported here once; the modules are free to move.
"""

from ._board import Board as Board
from ._calibration import Calibration as Calibration, fit_calibration as fit_calibration
from ._errors import RigError as RigError
from ._link import BAUD as BAUD
from ._playback import PlayReport as PlayReport, Timing as Timing, sample_timing as sample_timing
from ._scene import Scene as Scene
