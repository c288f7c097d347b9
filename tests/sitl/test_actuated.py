"""The actuated boat (sitl.world.actuated): what a firmware's IMU senses agrees with how the boat moves."""
from __future__ import annotations

import math

from companion.nav.geo import metres_per_degree
from sitl.sensors import GRAVITY_MPS2, WaveMotion
from sitl.world.actuated import BoatDynamics, frame_of, step_boat
from sitl.world.vehicle import MotionErrors, VehicleState

CALM = WaveMotion(0.0, 8.0, 0.0)


def test_a_steady_turn_is_felt_as_centripetal_force_and_yaw_rate():
    dyn = BoatDynamics()
    state = VehicleState(-38.0, 162.0, course_rad=0.3, speed_mps=dyn.max_speed_mps)
    state, yaw_rate, accel = step_boat(state, 0.01, 1.0, 0.5, dyn)
    frame = frame_of(0.0, state, yaw_rate, accel, CALM)
    assert yaw_rate > 0.0 and abs(accel) < 1e-9
    assert math.isclose(frame.gyro_frd_radps[2], yaw_rate, rel_tol=1e-12)
    # turning right, the water pushes the hull to the right: +y in FRD, speed x yaw rate
    assert math.isclose(frame.accel_frd_mps2[1], dyn.max_speed_mps * yaw_rate, rel_tol=1e-9)
    assert math.isclose(frame.accel_frd_mps2[2], -GRAVITY_MPS2, rel_tol=1e-12)


def test_the_position_moves_with_the_velocity_reported_including_the_current():
    current = MotionErrors((0.4, -0.3), 1.0, 0.0)
    state = VehicleState(-38.0, 162.0, course_rad=1.0, speed_mps=5.0, current_east_mps=0.4, current_north_mps=-0.3)
    frame = frame_of(0.0, state, 0.0, 0.0, CALM)
    later, _, _ = step_boat(state, 10.0, 0.5, 0.0, BoatDynamics(max_speed_mps=10.0), current)
    east_per_deg, north_per_deg = metres_per_degree(-38.0)
    north_m = (later.lat_deg - state.lat_deg) * float(north_per_deg)
    east_m = (later.lon_deg - state.lon_deg) * float(east_per_deg)
    assert math.isclose(north_m, frame.vel_ned_mps[0] * 10.0, rel_tol=1e-3)
    assert math.isclose(east_m, frame.vel_ned_mps[1] * 10.0, rel_tol=1e-3)


def test_bad_outputs_stop_and_hold_the_boat():
    state = VehicleState(0.0, 0.0, course_rad=0.5, speed_mps=4.0)
    later, yaw_rate, _ = step_boat(state, 60.0, float("nan"), float("inf"), BoatDynamics())
    assert yaw_rate == 0.0 and later.speed_mps < 0.01 and later.course_rad == state.course_rad
