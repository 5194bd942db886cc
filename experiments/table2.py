"""Reproduce the paper's Table 2 and Figs 3, 10–13 on the virtual IPMC (what `make demo` runs).

    python experiments/table2.py [--duration S] [--starts K] [--max-steps M] [--out-dir DIR]

Writes experiments/results/table2.{md,json} and the figures; see hybrid/_table2.py.
"""

import sys

from hybrid.cli import main

if __name__ == "__main__":
    sys.exit(main(["table2", *sys.argv[1:]]))
