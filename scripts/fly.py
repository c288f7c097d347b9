"""fcmpc-fly: one closed-loop mission, the simulator (or ArduPilot/PX4 SITL) and the companion as processes.

The same as the console script; the code is :mod:`fcmpc.fly.cli` (``python scripts/fly.py --help``).
"""
import sys

from fcmpc.fly.cli import main

if __name__ == "__main__":
    sys.exit(main())
