"""``fcmpc-fit-storms``: the navigator's storm-time parameters fitted on named storms of the library,
written as a ``.parm`` whose header names them (:mod:`montecarlo.fit_storms`).

    fcmpc-fit-storms --train halloween2003,stpatrick2015,march2011
    fcmpc-fit-storms --loo may2024 --out out/storms-loo-may2024.parm
"""
from __future__ import annotations

import sys

from montecarlo.fit_storms import main

__all__ = ["main"]

if __name__ == "__main__":
    sys.exit(main())
