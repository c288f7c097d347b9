"""Real flight-controller firmware in software-in-the-loop: ArduPilot Rover SITL and PX4 SITL.

Our own stand-in (:mod:`sitl.fc`) is fast and injects faults; these are the programs a
vehicle runs, and they decide whether the companion works. What is each firmware's own lives
here: how to start it (:mod:`~fcmpc.firmware.ardupilot`, :mod:`~fcmpc.firmware.px4`), its
parameters and compass (:mod:`~fcmpc.firmware.compass`), its physics (its own, or our world's
from :mod:`sitl.physics`), gathered per flight in a rig (:mod:`~fcmpc.firmware.ardupilot_rig`,
:mod:`~fcmpc.firmware.ardupilot_json_rig`, :mod:`~fcmpc.firmware.px4_rig`); the mission they
fly is the one runner's (:mod:`fcmpc.fly.mission`, through :class:`fcmpc.fly.firmware.FirmwareFC`).
Each runs in its own temporary working directory with its own instance number (ports shift
with it), is started with :class:`subprocess.Popen`, waited on by events (its TCP port
accepting, its heartbeat), and stopped by PID.
"""
from __future__ import annotations

from fcmpc.firmware.ardupilot import ArduPilotSitl, FirmwareMissing, ardupilot_binary

__all__ = ["ArduPilotSitl", "FirmwareMissing", "ardupilot_binary"]
