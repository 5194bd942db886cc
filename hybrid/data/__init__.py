"""Measured and generated data: `Recording` (a drive and a displacement on one
time grid, with its checks, loaders and splits; `_mapping.load_mapped` reads a
lab's own file by mapping its columns) and the paper's drives (PRBS, sine,
chirp, pulse). Depends only on `hybrid.util`.
"""

from ._drive import Drive as Drive
from ._drives import DRIVES as DRIVES
from ._drives import make_drive as make_drive
from ._mapping import load_mapped as load_mapped
from ._mapping import load_pair as load_pair
from ._recording import Recording as Recording
from ._split import Split as Split
