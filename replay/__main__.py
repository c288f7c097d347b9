"""``python -m replay LOG``: the same as ``fcmpc-replay``."""
from __future__ import annotations

import sys

from replay.cli import main

sys.exit(main())
