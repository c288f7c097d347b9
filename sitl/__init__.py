"""The simulated world and the flight-controller stand-in.

``sitl.world`` holds the pure truth models (field = WMM + storm, INS errors, vehicle
kinematics) shared by the in-process Monte Carlo and the MAVLink simulator
(``sitl.fc``). ``sitl`` may import ``companion.nav`` (the field model) but never
``companion.io``; ``companion`` never imports ``sitl``.
"""
