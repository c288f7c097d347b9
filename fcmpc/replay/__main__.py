"""``python -m fcmpc.replay LOG``: the same as ``fcmpc-replay``."""
from __future__ import annotations

import sys

from fcmpc.replay.cli import main

sys.exit(main())
