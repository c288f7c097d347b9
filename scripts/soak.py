"""fcmpc-soak: hostile MAVLink thrown at a running companion; the harm table.

The same as the console script; the code is :mod:`fcmpc.soak.cli` (``python scripts/soak.py --help``).
"""
import sys

from fcmpc.soak.cli import main

if __name__ == "__main__":
    sys.exit(main())
