"""fcmpc-calibrate: the magnetometer's hard and soft iron fitted from a recorded log.

The same as the console script; the code is :mod:`fcmpc.replay.calibrate` (``python scripts/calibrate.py --help``).
"""
import sys

from fcmpc.replay.calibrate import main

if __name__ == "__main__":
    sys.exit(main())
