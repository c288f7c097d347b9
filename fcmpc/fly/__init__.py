"""fcmpc-fly as a library: run one closed-loop mission and report what happened.

``mission``  the one mission runner: any flight controller (a small interface), the companion as
             a process, the watch, interrupts, stop by PID; ``fcmpc-soak`` and ``fcmpc-montecarlo
             --fc`` use it too
``standin``  our stand-in (``sitl.fc``) as a flight controller of the runner
``firmware`` ArduPilot and PX4 SITL (their own physics or ours, in lockstep) as flight controllers
``runner``   fcmpc-fly's options turned into a flight of the runner; progress; evaluation
``results``  the three distances to the destination, ``result.json``, the summary lines
``plots``    the four-panel track plot

``results`` and ``plots`` take a truth track of (time, lat, lon) and the companion's
``steps.csv``, whichever simulator or firmware produced them. This package imports
``companion`` and ``sitl``; neither imports it.
"""
from __future__ import annotations

import os

# before numpy and pymavlink load: one BLAS thread (tiny matrices), MAVLink 2
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
os.environ.setdefault("MAVLINK20", "1")

from fcmpc.fly.results import FlyResult, TruthTrack, distances, summary_lines, write_result  # noqa: E402
from fcmpc.fly.runner import FlyOptions, fly, fly_in_process_alike  # noqa: E402

__all__ = ["FlyOptions", "FlyResult", "TruthTrack", "distances", "fly", "fly_in_process_alike", "summary_lines", "write_result"]
