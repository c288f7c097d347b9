"""The companion's control step never raises on a period, and never makes an unsendable setpoint (issue 47).

Property (hypothesis): a running companion (the rig: a real CompanionApp over a UDP socket to a
pymavlink stand-in for the flight controller) with the real navigator is given periods whose
averages are random and extreme (D, I, F, the gravity-referenced I and their standard errors,
the magnetic heading, the sample times: NaN, inf, huge, tiny, wrong signs) through
:meth:`ControlStep.step`. No exception escapes; every command it keeps is finite, its speed
within [0, NAV_SPEED]; the setpoint made of it (the course trimmed by the FC's yaw error) passes
the link's last guard (:func:`~companion.io.link.guard_setpoint`) under NAV_SPEED; the
companion reports the navigator's rejections (FC_REJ). A navigation failure the companion itself
judges (an estimate diverged from its fix) may restart the mission: then the next example's
mission is a new one. Periods are the model's field where the simulated vehicle flies its
commands, each value off by a little or, one in twenty, by anything a float can be.
"""
from __future__ import annotations

import math
import warnings

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from companion.app import State
from companion.io.link import guard_setpoint
from companion.nav.field import model_for_setting
from companion.nav.geo import offset_position
from companion.nav.period import PeriodAverage
from companion.nav.mission import Mission
from companion.params import NavConfig, default_values
from tests.companion.process.rig import _sent, make_rig


def _finite(low: float, high: float):
    return st.floats(low, high, allow_nan=False, allow_infinity=False)


def _any(values):
    """Mostly ``values``; one in twenty anything a float can be (NaN, +-inf, +-1e308, 5e-324, -0.0 ...)."""
    return st.one_of(*[values] * 19, st.floats())


NAV = NavConfig.from_values(default_values())
MODEL = model_for_setting(NAV.year, NAV.wmm)

# Offsets from the model's field where the vehicle is (so the plausibility check passes the good
# periods and missions reach their cruise), each one in eight anything a float can be:
# (D, I, F, I_g, D se, I se, F se, I_g se, magnetic heading, sample count, mean-time lag behind the step (s))
SMALL = _finite(-0.003, 0.003)
PERIOD = st.tuples(_any(SMALL), _any(SMALL), _any(_finite(-3.0, 3.0)), _any(SMALL),
                   _any(_finite(0.0, 0.01)), _any(_finite(0.0, 0.01)), _any(_finite(0.0, 5.0)), _any(_finite(0.0, 0.01)),
                   _any(_finite(-2.0, 2.0)), st.integers(1, 3000), _any(_finite(0.0, 60.0)))


def _average(t_k: float, period, where: tuple[float, float], course_rad: float) -> PeriodAverage:
    """The period's average at ``where`` (lat, lon deg) flying ``course_rad``: the model's field and
    magnetic heading there plus the offsets."""
    d_off, i_off, f_off, g_off, d_se, i_se, f_se, g_se, h_off, count, lag = period
    e = MODEL.elements(*where, NAV.alt_m, NAV.year)
    incl = float(e.incl_deg)
    mean = t_k - lag
    return PeriodAverage(float(e.decl_deg) + d_off, incl + i_off, count, mean, mean - 1.0, t_k, f_nt=float(e.f_nt) + f_off,
                      incl_grav_deg=incl + g_off, grav_count=count, decl_se_deg=d_se, incl_se_deg=i_se, f_se_nt=f_se,
                      incl_grav_se_deg=g_se, mag_heading_deg=math.degrees(course_rad) - float(e.decl_deg) + h_off)


def test_no_period_makes_the_companion_step_raise_or_send_an_unsafe_setpoint(tmp_path):
    app, fc = make_rig(tmp_path)
    nav = NAV
    examples: list[int] = []   # periods per example (printed with -s: the long run's count)
    try:
        # 150 in CI (~7 s); a tenth of the profile's count with --hypothesis-profile=long (10,000)
        @settings(deadline=None, suppress_health_check=list(HealthCheck),
                  max_examples=max(150, settings.default.max_examples // 10))
        @given(st.lists(PERIOD, min_size=1, max_size=10))
        def fly(periods):
            examples.append(len(periods))
            app.mission_state.mission, app.mission_state.command, app.machine.state = Mission(nav), None, State.RUNNING
            period, where = nav.period_s, (nav.start_lat_deg, nav.start_lon_deg)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                for k, p in enumerate(periods):
                    if app.mission_state.mission is None or app.state != State.RUNNING:   # restarted (the companion's own
                        break                                                # divergence judgement) or ended
                    course = app.mission_state.command.course_rad if app.mission_state.command is not None else 0.0
                    app.phases.step(app.now, k * period, avg=_average(k * period, p, where, course))
                    cmd = app.mission_state.command
                    if cmd is None:
                        continue
                    assert math.isfinite(cmd.course_rad) and 0.0 <= cmd.speed_mps <= nav.speed_mps * (1 + 1e-9), cmd
                    assert abs(cmd.est_lat_deg) <= 90.0, cmd
                    if not cmd.done:   # the vehicle flies it for the next period
                        flown = cmd.speed_mps * period
                        where = tuple(float(v) for v in offset_position(*where, flown * math.sin(cmd.course_rad),
                                                                         flown * math.cos(cmd.course_rad)))
                        setpoint = guard_setpoint(app.out.course_to_send(cmd), cmd.speed_mps, nav.speed_mps)
                        assert all(map(math.isfinite, (setpoint.vn_mps, setpoint.ve_mps, setpoint.yaw_rad)))
            _sent(fc, quiet_s=0.0, limit_s=0.0)   # (keep the socket's buffer short)

        fly()
        print(f"companion step fuzz: {len(examples)} examples, {sum(examples)} periods")
        assert app.link.stats.setpoints_refused == 0
    finally:
        app.close()
        fc.close()
