"""``fcmpc-params``: the parameter reference generated from companion/registry.py
(params/defaults.parm, docs/parameters.md, docs/parameters.json; :mod:`companion.paramdoc`).

    fcmpc-params --write        # regenerate the files that are stale
    fcmpc-params --check        # exit 1 naming the stale ones
    python scripts/params_doc.py --write
"""
from __future__ import annotations

import sys

from companion.paramdoc import main

if __name__ == "__main__":
    sys.exit(main())
