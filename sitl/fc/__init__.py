"""The flight-controller stand-in (``fcmpc-sitl``): the simulated world wrapped in MAVLink 2.

It sends what an ArduPilot Rover (or, with ``--autopilot px4``, a PX4) boat sends and obeys
what a companion or a ground station sends back, faster than real time or in lockstep. One
module per part; :class:`~sitl.fc.server.SitlServer` wires them:

    config      ServerConfig and the fault syntax (what a run is started with)
    vehicle     true motion, field, sensor samples and the FC's own navigation solution
    faults      the fault schedule -> flags the other parts read
    telemetry   one method per message sent
    streams     which message how often (SET_MESSAGE_INTERVAL, REQUEST_DATA_STREAM)
    commands    COMMAND_LONG/INT, modes, setpoints, TIMESYNC, PING, ODOMETRY
    params      the FC's own parameters (PARAM_REQUEST_LIST/_READ, PARAM_SET)
    param_table their names, types, ranges and defaults (ArduPilot or PX4)
    router      input from the links, frame splitting, routing between links, dispatch
    outbox      output: queue, link faults, tlog, datagrams
    lockstep    pacing against wall time and the lockstep wait
    records     truth.csv, tlog, summary
    server      SitlServer: the wiring and the simulation loop
    cli         the fcmpc-sitl command line (``python -m sitl.fc``)

Arrows: ``cli`` -> ``server`` -> the parts; the parts import only ``sitl.clock``,
``sitl.guidance``, ``sitl.links``, ``sitl.mavframe``, ``sitl.truthlog``, ``sitl.world``,
``sitl.sensors``, ``sitl.scenario`` and ``companion.nav``/``companion`` conventions, never
each other's callers (no circle; ``tests/test_architecture.py`` checks it).
"""
from __future__ import annotations

import os

# Before numpy: small-matrix BLAS calls (the INS's expm) are ~100x slower with OpenBLAS
# threads on a 2-core machine, and the simulator is single-threaded by design. Here, so the
# console script (sitl.fc.cli:main) gets it as well as ``python -m sitl.fc``.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
os.environ.setdefault("MAVLINK20", "1")

from sitl.fc.cli import build_parser, config_from_args, main  # noqa: E402
from sitl.fc.config import DEFAULT_OUT, DEFAULT_SPEEDUP, ServerConfig, parse_fault  # noqa: E402
from sitl.fc.records import format_summary  # noqa: E402
from sitl.fc.server import SitlServer  # noqa: E402
from sitl.fc.streams import DEFAULT_RATES_HZ  # noqa: E402

__all__ = ["DEFAULT_OUT", "DEFAULT_RATES_HZ", "DEFAULT_SPEEDUP", "ServerConfig", "SitlServer",
           "build_parser", "config_from_args", "format_summary", "main", "parse_fault"]
