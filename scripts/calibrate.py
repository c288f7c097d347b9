"""fcmpc-calibrate: fit the magnetometer's hard and soft iron from a recorded log.

    fcmpc-calibrate ../shared/data/logs/log171.bin

A thin entry point: the fit is :mod:`companion.nav.calibration`, the log side :mod:`replay.calibrate`.
"""
from __future__ import annotations

import sys

from replay.calibrate import main

__all__ = ["main"]

if __name__ == "__main__":
    sys.exit(main())
