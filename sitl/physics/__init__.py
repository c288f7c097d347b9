"""Our world as the physics of real flight-controller firmware, in lockstep (the world's side).

:mod:`sitl.physics.ardupilot_json`: ArduPilot SITL's JSON backend (``--model JSON``), with
:mod:`sitl.physics.relay` for the companion's link; :mod:`sitl.physics.px4_hil`: PX4's MAVLink
simulator interface (HIL_SENSOR / HIL_GPS in, HIL_ACTUATOR_CONTROLS out). The rigs that start the
firmware and these worlds are the tools' (:mod:`fcmpc.firmware`).
"""
