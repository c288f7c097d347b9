"""fcmpc-fly as a library: run one closed-loop mission and report what happened.

``runner``  starts the companion and the simulator as processes, progress, interrupts
``results`` the three distances to the destination, ``result.json``, the summary lines
``plots``   the four-panel track plot

``results`` and ``plots`` take a truth track of (time, lat, lon) and the companion's
``steps.csv``, whichever simulator or firmware produced them. This package imports
``companion`` and ``sitl``; neither imports it.
"""
from __future__ import annotations

from fcmpc_fly.results import FlyResult, TruthTrack, distances, summary_lines, write_result
from fcmpc_fly.runner import FlyOptions, fly, fly_in_process_alike

__all__ = ["FlyOptions", "FlyResult", "TruthTrack", "distances", "fly", "fly_in_process_alike", "summary_lines", "write_result"]
