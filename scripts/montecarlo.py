"""fcmpc-montecarlo: the paper's tables and sweeps, the navigation core against the simulated world.

The same as the console script; the code is :mod:`fcmpc.montecarlo.cli` (``python scripts/montecarlo.py --help``).
"""
import sys

from fcmpc.montecarlo.cli import main

if __name__ == "__main__":
    sys.exit(main())
