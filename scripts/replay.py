"""fcmpc-replay: a recorded flight log evaluated against its own GPS (the paper's Table 8).

The same as the console script; the code is :mod:`fcmpc.replay.cli` (``python scripts/replay.py --help``).
"""
import sys

from fcmpc.replay.cli import main

if __name__ == "__main__":
    sys.exit(main())
