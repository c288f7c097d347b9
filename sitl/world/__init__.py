"""Pure truth models of the simulated world (no I/O beyond coefficient files and the crust's
grid cache, no clocks).

``magnetic`` (the true field: main field + crust + storm), ``igrf`` (IGRF-14, the realistic
world's main field), ``emm`` (the real crust, EMM2017 degrees 16-790 on the route's grid),
``anomaly`` (the crust and the map's error along a route, and its plot), ``crustal`` (the
seeded anomaly field), ``ins`` (the 15-state INS error
model), ``attitude`` (heading sources and attitude errors), ``magerrors`` (magnetometer
calibration residuals), ``sampling`` (one control period of samples, vectorised),
``vehicle`` (kinematics) and ``build`` (a scenario's truth field). Shared by the in-process
Monte Carlo and the MAVLink simulator (``sitl.fc``).
"""
