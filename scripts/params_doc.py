"""fcmpc-params: the parameter reference generated from companion/registry.py.

The same as the console script; the code is :mod:`fcmpc.paramdoc` (``python scripts/params_doc.py --help``).
"""
import sys

from fcmpc.paramdoc import main

if __name__ == "__main__":
    sys.exit(main())
