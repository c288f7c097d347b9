"""fcmpc-results: the published results tables (docs/results.md) from their runs.

The same as the console script; the code is :mod:`fcmpc.montecarlo.results` (``python scripts/results.py --help``).
"""
import sys

from fcmpc.montecarlo.results import main

if __name__ == "__main__":
    sys.exit(main())
