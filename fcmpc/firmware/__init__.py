"""Real flight-controller firmware in software-in-the-loop: ArduPilot Rover SITL and PX4 SIH.

Our own stand-in (:mod:`sitl.fc`) is fast and injects faults; these are the programs a
vehicle runs, and they decide whether the companion works. Each runs in its own temporary
working directory with its own instance number (ports shift with it), is started with
:class:`subprocess.Popen`, waited on by events (its TCP port accepting, its heartbeat), and
stopped by PID.
"""
from __future__ import annotations

from sitl.firmware.ardupilot import ArduPilotSitl, FirmwareMissing, ardupilot_binary

__all__ = ["ArduPilotSitl", "FirmwareMissing", "ardupilot_binary"]
