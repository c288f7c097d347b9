"""``python -m sitl.fc``: the same as ``fcmpc-sitl`` (:func:`sitl.fc.cli.main`)."""
from __future__ import annotations

import sys

from sitl.fc.cli import main

sys.exit(main())
