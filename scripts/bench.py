"""fcmpc-bench: each part of the system timed beside its anchors.

The same as the console script; the code is :mod:`fcmpc.bench.cli` (``python scripts/bench.py --help``).
"""
import sys

from fcmpc.bench.cli import main

if __name__ == "__main__":
    sys.exit(main())
