"""Our world as the physics of real flight-controller firmware, in lockstep.

:mod:`sitl.physics.ardupilot_json`: ArduPilot SITL's JSON backend (``--model JSON``).
"""
