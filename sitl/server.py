"""fcmpc-sitl: a MAVLink 2 flight-controller stand-in that flies a scenario faster than real time.

The implementation lives in :mod:`sitl.fc` (one module per part); this module keeps the
names today's importers use (``from sitl.server import SitlServer, ServerConfig, main``) and
is what ``python -m sitl.server`` runs.

Quick start::

    fcmpc-sitl                                   # pacific, udp to 127.0.0.1:14550, 1x real time
    fcmpc-sitl --speedup 1000 --duration 3600    # an hour of mission in about 3 s
    fcmpc-sitl --master tcp:127.0.0.1:5760       # listen like ArduPilot SITL (MAVProxy --master tcp:...)
    fcmpc-sitl --lockstep --out udp:127.0.0.1:14550   # time advances only when the companion answers
    fcmpc-sitl --fault mag_off:600:30 --fault link_loss:0:inf:0.2

Identity: system 1, component 1, HEARTBEAT type MAV_TYPE_SURFACE_BOAT. Every time field of
every message carries *simulated* time: ``time_boot_ms``/``time_usec`` since boot,
SYSTEM_TIME.time_unix_usec = scenario ``start_utc`` + simulated time. See README
"Simulator" and :mod:`sitl.clock` for pacing and the lockstep protocol.
"""
from __future__ import annotations

import os
import sys

# Before numpy: small-matrix BLAS calls (the INS's expm) are ~100x slower with OpenBLAS
# threads on a 2-core machine, and the simulator is single-threaded by design.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
os.environ.setdefault("MAVLINK20", "1")

from sitl.fc import (DEFAULT_RATES_HZ, ServerConfig, SitlServer, benchmark, build_parser,  # noqa: E402
                     config_from_args, format_summary, main, parse_fault)

__all__ = ["ServerConfig", "SitlServer", "DEFAULT_RATES_HZ", "parse_fault", "build_parser", "config_from_args",
           "main", "benchmark", "format_summary"]

if __name__ == "__main__":
    sys.exit(main())
