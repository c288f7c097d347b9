"""fcmpc-fit-storms: the navigator's storm-time parameters fitted on named storms, as a .parm.

The same as the console script; the code is :mod:`fcmpc.montecarlo.fit_storms` (``python scripts/fit_storms.py --help``).
"""
import sys

from fcmpc.montecarlo.fit_storms import main

if __name__ == "__main__":
    sys.exit(main())
