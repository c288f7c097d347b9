"""fcmpc-replay: evaluate a recorded flight log against its own GPS (like the paper's Table 8).

    fcmpc-replay ../shared/data/logs/log171.bin

A thin entry point: the evaluation lives in the :mod:`replay` package (see its docstring).
"""
from __future__ import annotations

import sys

from replay import evaluate, format_report, write_outputs
from replay.cli import main

__all__ = ["evaluate", "format_report", "main", "write_outputs"]

if __name__ == "__main__":
    sys.exit(main())
