"""The live configuration: NavConfig and CompanionConfig rebuilt from the parameter server's values.

A parameter set over the link marks the settings ``dirty``; they are rebuilt at once outside a
mission and at the next control step during one (:meth:`Settings.apply`), where a running
mission takes what may change in flight (:meth:`Mission.reconfigure`) and names the rest.
"""
from __future__ import annotations

from companion.failsafe import Health, HealthLimits
from companion.fc_view import FcView
from companion.io.param_server import ParamServer
from companion.nav.alignment import aligned
from companion.nav.magnetometer import MagCalibration, MagProcessor
from companion.nav.mission import Mission
from companion.params import CompanionConfig, NavConfig

__all__ = ["Settings", "apply_live_config", "health_limits", "mag_calibration"]


def apply_live_config(mission: Mission, new: NavConfig) -> list[str]:
    """Apply a changed NavConfig to a running mission (:meth:`Mission.reconfigure`): the names
    that apply to the next mission only."""
    return mission.reconfigure(new)


def health_limits(c: CompanionConfig) -> HealthLimits:
    return HealthLimits(c.mag_timeout_s, c.att_timeout_s, c.heartbeat_timeout_s)


def mag_calibration(c: CompanionConfig) -> MagCalibration:
    """MAG_OFS/SCALE/SOFT_*, then the alignment MAG_ROT_* (:mod:`companion.nav.alignment`)."""
    return aligned(MagCalibration.from_mgauss(c.mag_offset_mgauss, c.mag_scale, c.mag_soft_xy_xz_yz),
                   c.mag_rotation_deg)


class Settings:
    """``nav`` and ``comp``: the configurations in force; ``dirty`` once a parameter changed."""

    def __init__(self, params: ParamServer, mag: MagProcessor, health: Health, fc_view: FcView,
                 nav: NavConfig, comp: CompanionConfig) -> None:
        self.params = params
        self.mag = mag
        self.health = health
        self.fc_view = fc_view
        self.nav = nav
        self.comp = comp
        self.dirty = False

    def apply(self, running: Mission | None = None) -> list[str]:
        """Rebuild the configurations from the parameter values and hand them to the parts that
        hold a copy; ``running``: the running mission, reconfigured. The names that apply to the
        next mission only."""
        self.dirty = False
        values = self.params.values
        self.comp = comp = CompanionConfig.from_values(values)
        self.mag.configure(mag_calibration(comp), comp.spike_nt)
        self.mag.track_yaw_offset = comp.trim_max_deg > 0.0
        self.health.limits = health_limits(comp)
        self.fc_view.position_publish = comp.position_publish
        self.fc_view.feed.blend_mps = comp.feed_blend_mps
        self.fc_view.feed.accel_mps2 = comp.feed_accel_limit_mps2
        self.nav = NavConfig.from_values(values)
        return apply_live_config(running, self.nav) if running is not None else []
