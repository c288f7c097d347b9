"""What a world hands the navigator that a vehicle would not have, read from its configuration.

The paper's idealised worlds (the ``paper_*`` presets) give the navigator things no vehicle has: the
true heading, its own field model as the truth, the exact start. :func:`gifts` lists them for any
:class:`~sitl.scenario.Scenario`, from its tables (not from its name), so a run of such a world can
say what its figures owe to them (:func:`gift_line`); a realistic preset has none of the first three.

>>> from sitl.scenario import load_scenario
>>> gifts(load_scenario("paper_pacific"))[:2]
('the true heading (white noise only)', 'the true roll and pitch (white noise only)')
>>> gift_line(load_scenario("pacific")) == ""
True
"""
from __future__ import annotations

from sitl.scenario import Scenario

__all__ = ["gifts", "gift_line"]


def gifts(scenario: Scenario) -> tuple[str, ...]:
    """The gifts of ``scenario``'s world to the navigator, in words; empty for an honest world.

    Listed: a true heading (``[attitude] heading_source = "true"``), a tilt with white noise only,
    the truth's main field being the navigator's own model (``[field] main = "wmm"``, with or without
    a crust), the exact start (``[mission] exact_start``), a perfectly calibrated magnetometer (no
    calibration residual in ``[sensors]``) and a vehicle that goes exactly where it is commanded (no
    motion error in ``[vehicle]``).
    """
    att, sensors, field = scenario.attitude, scenario.sensors, scenario.field_model
    found: list[str] = []
    if att.heading_source == "true":
        drift = att.heading_bias_deg or att.heading_drift_deg
        found.append("a true-heading sensor through the GPS outage" if drift else "the true heading (white noise only)")
    if not att.tilt_bias_deg and not att.tilt_from_ins:
        found.append("the true roll and pitch (white noise only)")
    if field.main == "wmm":
        found.append("its own map (WMM) as the truth's main field" if field.crustal.enabled
                     else "its own map (WMM) as the truth field (no crust)")
    if scenario.exact_start:
        found.append("the exact start (no GPS error)")
    if not (sensors.mag_errors.active or any(sensors.mag_bias_nt)):
        found.append("a perfectly calibrated magnetometer")
    if not scenario.motion.active:
        found.append("a vehicle that goes exactly where it is commanded (no current, speed or course error)")
    return tuple(found)


def gift_line(scenario: Scenario) -> str:
    """One line saying the world's gifts (:func:`gifts`), or "" when it has none."""
    found = gifts(scenario)
    if not found:
        return ""
    return (f"{scenario.name} hands the navigator what a vehicle would not have: "
            + "; ".join(found))
