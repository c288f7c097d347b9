"""Tilt compensation, calibration, spike rejection and averaging, against hand computations."""
from __future__ import annotations

import math

import numpy as np
import pytest

from companion.frames import body_to_ned
from companion.nav.magnetometer import (
    AttitudeState, MagCalibration, MagProcessor, SpikeFilter, decl_incl_deg,
    tilt_compensated_di,
)
from companion.nav.period import PeriodAverager


D_TRUE = math.degrees(math.atan2(2000.0, 28000.0))   # 4.0856 deg, of the field used below


def _rot_nb(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """C_nb = Rz(yaw) Ry(pitch) Rx(roll), built from elementary rotations (independent of the code)."""
    cr, sr, cp, sp, cy, sy = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw), \
        math.sin(yaw)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def test_decl_incl_by_hand():
    # N 20000, E 20000, D 40000: D = 45 deg; H = 28284.27, I = atan(40000/28284.27) = 54.7356 deg
    d, i = decl_incl_deg(20000.0, 20000.0, 40000.0)
    assert d == pytest.approx(45.0, abs=1e-12)
    assert i == pytest.approx(math.degrees(math.atan(40000.0 / math.sqrt(2 * 20000.0 ** 2))), abs=1e-12)
    assert i == pytest.approx(54.7356103, abs=1e-6)
    # west of north and pointing up (southern hemisphere): signs per companion/__init__
    d, i = decl_incl_deg(30000.0, -3000.0, -20000.0)
    assert d == pytest.approx(-5.7105931, abs=1e-6) and i < 0.0


def test_body_to_ned_elementary_rotations():
    # nose east (yaw 90): body x is east, body y (right) is south
    assert body_to_ned((1.0, 0.0, 0.0), 0.0, 0.0, math.pi / 2) == pytest.approx((0.0, 1.0, 0.0), abs=1e-12)
    assert body_to_ned((0.0, 1.0, 0.0), 0.0, 0.0, math.pi / 2) == pytest.approx((-1.0, 0.0, 0.0), abs=1e-12)
    # right wing down 90 deg (roll +90): body y points down
    assert body_to_ned((0.0, 1.0, 0.0), math.pi / 2, 0.0, 0.0) == pytest.approx((0.0, 0.0, 1.0), abs=1e-12)
    # nose up 90 deg (pitch +90): body x points up (-down)
    assert body_to_ned((1.0, 0.0, 0.0), 0.0, math.pi / 2, 0.0) == pytest.approx((0.0, 0.0, -1.0), abs=1e-12)


@pytest.mark.parametrize("roll_deg,pitch_deg,yaw_deg", [(0, 0, 0), (3, -2, 130), (-4.5, 2.5, 271), (10, 15, -45)])
def test_tilt_compensation_recovers_the_field(roll_deg, pitch_deg, yaw_deg):
    field_ned = np.array([28000.0, 2000.0, 30000.0])          # D = atan2(2000, 28000) = 4.0856 deg
    r, p, y = (math.radians(a) for a in (roll_deg, pitch_deg, yaw_deg))
    body = _rot_nb(r, p, y).T @ field_ned                        # what the magnetometer reads
    d, i, ned = tilt_compensated_di(tuple(body), r, p, y)
    assert ned == pytest.approx(tuple(field_ned), abs=1e-8)
    assert d == pytest.approx(D_TRUE, abs=1e-9)
    assert i == pytest.approx(math.degrees(math.atan2(30000.0, math.hypot(28000.0, 2000.0))), abs=1e-9)


def test_ignoring_tilt_would_be_wrong():
    """The test above can fail: with 5 deg of roll the untilted reading is off by degrees."""
    field_ned = np.array([28000.0, 2000.0, 30000.0])
    body = _rot_nb(math.radians(5.0), 0.0, 0.0).T @ field_ned
    d_wrong, _, _ = tilt_compensated_di(tuple(body), 0.0, 0.0, 0.0)
    assert abs(d_wrong - D_TRUE) > 1.0


def test_calibration_offset_in_milligauss_then_scale():
    cal = MagCalibration.from_mgauss((10.0, -20.0, 5.0), (1.1, 0.9, 1.0))   # 1 mG = 100 nT
    assert cal.offset_nt == (1000.0, -2000.0, 500.0)
    true_body = (20000.0, -3000.0, 41000.0)
    raw = (true_body[0] / 1.1 + 1000.0, true_body[1] / 0.9 - 2000.0, true_body[2] + 500.0)
    assert cal.apply(raw) == pytest.approx(true_body, abs=1e-9)


def test_spike_filter_rejects_a_spike_and_adopts_a_lasting_step():
    f = SpikeFilter(5000.0, window=15, min_samples=5, refresh=1)
    base = (28000.0, 2000.0, 30000.0)
    assert all(f.accept((base[0] + 50 * (k % 3), base[1], base[2])) for k in range(10))
    assert not f.accept((base[0] + 8000.0, base[1], base[2]))          # 8000 nT off: a spike
    assert f.accept((base[0] + 4000.0, base[1], base[2]))              # below the threshold
    stepped = (base[0], base[1] - 9000.0, base[2])
    results = [f.accept(stepped) for _ in range(12)]
    assert not results[0] and results[-1]                                # a step becomes the new level
    assert results.index(True) <= 8                                      # after about half a window


def test_averager_unwraps_declination_across_180():
    avg = PeriodAverager()
    for k, d in enumerate((179.0, -179.0, 179.5, -179.5)):
        avg.add(float(k), d, 10.0)
    result = avg.take(10.0)
    assert result.count == 4
    assert abs(abs(result.decl_deg) - 180.0) < 1e-9                    # not 0
    assert result.incl_deg == pytest.approx(10.0)


def test_averager_splits_by_time_and_reports_the_window():
    avg = PeriodAverager()
    for k in range(1, 101):                # samples at 0.1 .. 10.0 s, D = t
        avg.add(k * 0.1, k * 0.1, 50.0)
    first = avg.take(5.0)
    assert first.count == 50 and first.decl_deg == pytest.approx(2.55)
    assert first.mean_time_s == pytest.approx(2.55)
    assert first.window_s(5.0, 360.0) == pytest.approx(4.9)           # reference time 2.55 = 5 - 4.9/2
    second = avg.take(10.0)
    assert second.count == 50 and second.decl_deg == pytest.approx(7.55)
    assert not avg.take(20.0).valid


def test_averager_keeps_a_long_periods_later_samples_in_order_across_takes():
    """Thousands of samples (the buffer grows many times), taken in uneven pieces, with the
    declination wrapping across 180 deg in the part kept for the next period."""
    avg = PeriodAverager()
    times = np.arange(1, 5001) * 0.1                       # 0.1 .. 500 s
    decl = (175.0 + times * 0.004 + 180.0) % 360.0 - 180.0   # 175 deg -> -165 deg, through 180
    for t, d in zip(times, decl):
        avg.add(float(t), float(d), 40.0 + 0.001 * float(t))
    previous = 0.0
    for end in (123.45, 300.0, 500.0):
        piece = avg.take(end)
        in_piece = (times > previous) & (times <= end)
        assert piece.count == int(in_piece.sum())
        assert (piece.first_time_s, piece.last_time_s) == (times[in_piece][0], times[in_piece][-1])
        assert piece.mean_time_s == pytest.approx(times[in_piece].mean(), abs=1e-9)
        unwrapped = (175.0 + times[in_piece] * 0.004).mean()           # the true mean, before wrapping
        assert (piece.decl_deg - unwrapped + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=1e-9)
        assert piece.incl_deg == pytest.approx((40.0 + 0.001 * times[in_piece]).mean(), abs=1e-12)
        assert len(avg) == int((times > end).sum())
        previous = end
    assert not avg.take(600.0).valid


@pytest.mark.parametrize("seed", range(12))
def test_a_period_read_through_views_is_the_plain_definition_bit_for_bit(seed):
    """``take`` reads the usual period (time-ordered, every sample a gravity and heading sample)
    through views of its rows and any other through masked copies: both must give exactly the
    numbers of the plain definition (the due rows selected by a mask, each average over them),
    whatever mix of sample kinds and out-of-order times the period holds."""
    from companion.nav.heading import levelled_heading_deg
    from companion.nav.inclination import mad_standard_errors, ratio_inclination_deg
    rng = np.random.default_rng(seed)
    kinds = ("full", "mixed", "jittered", "no_gravity")[seed % 4]
    avg, rows = PeriodAverager(), []
    for k in range(int(rng.integers(2, 900))):
        t = 0.1 * k + (float(rng.normal(0.0, 0.3)) if kinds == "jittered" else 0.0)
        ned = tuple(float(v) for v in np.array([25000.0, -2000.0, 35000.0]) + rng.normal(0.0, 30.0, 3))
        kind = {"full": 2, "no_gravity": 0}.get(kinds, int(rng.integers(0, 3)))
        dot, force = (-343000.0 + float(rng.normal(0.0, 100.0)), (0.01, 0.02, -9.8)) if kind else (math.nan, (math.nan,) * 3)
        body = ((20000.0 + float(rng.normal(0.0, 30.0)), 3000.0, 35000.0), (0.1, 0.0, -9.8)) if kind == 2 else \
            ((math.nan,) * 3, (math.nan,) * 3)
        d, i = -5.0 + float(rng.normal(0.0, 0.1)), 54.0 + float(rng.normal(0.0, 0.1))
        avg.add(t, d, i, ned, dot, force, *body)
        unwrapped = rows[0][1] + ((d - rows[0][1] + 180.0) % 360.0 - 180.0) if rows else d   # about the first D
        rows.append((t, unwrapped, i, *ned, math.sqrt(sum(v * v for v in ned)), dot, *force, *body[0], *body[1]))
    rows = np.array(rows)
    end = float(np.median(rows[:, 0]))
    got = avg.take(end)
    a = rows[rows[:, 0] <= end]
    means = a[:, :7].mean(axis=0)
    grav = np.isfinite(a[:, 7]) & np.all(np.isfinite(a[:, 8:11]), axis=1)
    body = grav & np.all(np.isfinite(a[:, 11:17]), axis=1)
    incl_grav, incl_grav_se = ratio_inclination_deg(a[grav, 7], a[grav, 3:6], a[grav, 8:11])
    heading = levelled_heading_deg(a[body, 11:14].mean(axis=0), a[body, 14:17].mean(axis=0)) if body.any() else math.nan
    se = mad_standard_errors(a[:, (1, 2, 6)].T).tolist()
    expected = (float((means[1] + 180.0) % 360.0 - 180.0), float(means[2]), len(a), float(means[0]), float(a[0, 0]),
                float(a[-1, 0]), tuple(float(v) for v in means[3:6]), float(means[6]), incl_grav, int(grav.sum()),
                *se, incl_grav_se, heading)
    actual = (got.decl_deg, got.incl_deg, got.count, got.mean_time_s, got.first_time_s, got.last_time_s,
              got.field_ned_nt, got.f_nt, got.incl_grav_deg, got.grav_count, got.decl_se_deg, got.incl_se_deg,
              got.f_se_nt, got.incl_grav_se_deg, got.mag_heading_deg)
    assert repr(actual) == repr(expected)        # bit for bit, NaN where the definition gives NaN
    assert len(avg) == int((rows[:, 0] > end).sum())


def test_attitude_propagation_with_body_rates():
    att = AttitudeState.from_body_rates(10.0, 0.0, 0.0, math.radians(90.0), 0.0, 0.0, math.radians(6.0))
    assert att.yaw_rate_radps == pytest.approx(math.radians(6.0))       # level: Euler rate = body rate
    assert math.degrees(att.at(10.1)[2]) == pytest.approx(90.6)
    assert math.degrees(att.at(20.0, max_dt_s=0.5)[2]) == pytest.approx(93.0)   # bounded extrapolation
    assert not AttitudeState(0.0, math.nan, 0.0, 0.0).finite


def _body(field_ned, roll, pitch, yaw):
    return tuple(_rot_nb(roll, pitch, yaw).T @ np.asarray(field_ned))


def test_processor_pairs_each_sample_with_the_attitude_of_its_time():
    """IMU before ATTITUDE at the same instant (as flight controllers send them): exact pairing."""
    field_ned = (28000.0, 2000.0, 30000.0)
    proc = MagProcessor(spike_nt=5000.0)
    for k in range(50):
        t = 0.1 * k
        yaw = math.radians(30.0 + 6.0 * t)                             # turning at 6 deg/s
        proc.add_mag(t, _body(field_ned, 0.0, 0.0, yaw))
        proc.add_attitude(AttitudeState(t, 0.0, 0.0, yaw))             # no rates: pairing must be exact
    result = proc.take(10.0)
    assert result.count == 50
    assert result.decl_deg == pytest.approx(D_TRUE, abs=1e-9)


def test_processor_rejects_spikes_non_finite_and_paused_samples():
    field_ned = (28000.0, 2000.0, 30000.0)
    proc = MagProcessor(spike_nt=3000.0)
    body = _body(field_ned, 0.0, 0.0, 0.0)
    proc.add_attitude(AttitudeState(0.0, 0.0, 0.0, 0.0))
    for k in range(10):
        proc.add_attitude(AttitudeState(0.1 * k, 0.0, 0.0, 0.0))
        proc.add_mag(0.1 * k, body)
    proc.add_attitude(AttitudeState(1.0, 0.0, 0.0, 0.0))
    proc.add_mag(1.0, (body[0] + 20000.0, body[1], body[2]))        # spike
    proc.add_mag(1.0, (math.nan, body[1], body[2]))                   # NaN
    proc.paused = True
    proc.add_mag(1.0, body)
    proc.flush()
    assert (proc.stats.spikes, proc.stats.non_finite, proc.stats.paused, proc.stats.accepted) == (1, 1, 1, 10)
    result = proc.take(5.0)
    assert result.count == 10 and result.decl_deg == pytest.approx(D_TRUE, abs=1e-9)


def test_processor_mission_offset_shifts_sample_times():
    proc = MagProcessor()
    proc.add_attitude(AttitudeState(100.0, 0.0, 0.0, 0.0))
    proc.mission_offset_s = 40.0
    proc.add_mag(100.0, (28000.0, 0.0, 30000.0))
    assert proc.take(59.0).count == 0
    assert proc.take(60.0).count == 1


@pytest.mark.parametrize("jitter", [0.0, 0.3])
def test_a_sliding_window_gives_the_average_of_a_fresh_averager_bit_for_bit(jitter):
    """``drop_before`` every 0.4 s over a 300 s window (as the companion does while it waits),
    samples in time order (the window's front moves, no copy) or jittered out of order (a masked
    copy): each later period is exactly the period of an averager given only the samples kept,
    the declination wrapping across 180 deg on the way."""
    rng = np.random.default_rng(7)
    times = np.arange(1, 4001) * 0.1 + rng.normal(0.0, jitter, 4000)
    decl = (175.0 + np.arange(4000) * 0.004 + rng.normal(0.0, 0.2, 4000) + 180.0) % 360.0 - 180.0
    sliding = PeriodAverager()
    for k, (t, d) in enumerate(zip(times, decl)):
        sliding.add(float(t), float(d), 40.0 + 0.001 * k, (25000.0 + k, -2000.0, 35000.0))
        if k % 4 == 3:
            sliding.drop_before(float(t) - 300.0)
    start = float(times[-1]) - 300.0
    fresh = PeriodAverager()
    for k in np.flatnonzero(times >= start):
        fresh.add(float(times[k]), float(decl[k]), 40.0 + 0.001 * k, (25000.0 + k, -2000.0, 35000.0))
    assert len(sliding) == len(fresh) and len(fresh) > 2000
    end = start + 150.0
    assert repr(sliding.take(end)) == repr(fresh.take(end)) and len(sliding) == len(fresh)
    sliding.drop_before(1e9)
    assert len(sliding) == 0 and not sliding.take(1e9).valid


def test_calibration_is_the_soft_iron_product_of_the_offset_field_bit_for_bit():
    """``MagCalibration.apply`` written out per row (the 10 Hz pipeline's cost) is ``soft_iron @
    (m - offset)`` summed in the matrix's column order, bit for bit, on random full matrices."""
    rng = np.random.default_rng(7)
    for _ in range(500):
        offset = tuple(float(v) for v in rng.normal(0.0, 3000.0, 3))
        soft = tuple(tuple(float(v) for v in row) for row in rng.normal(1.0, 0.2, (3, 3)))
        field = tuple(float(v) for v in rng.normal(0.0, 40000.0, 3))
        delta = [field[j] - offset[j] for j in range(3)]
        expected = tuple(sum(soft[i][j] * delta[j] for j in range(3)) for i in range(3))
        assert MagCalibration(offset, soft).apply(field) == expected


@pytest.mark.parametrize("seed", range(4))
def test_rows_kept_as_tuples_until_read_give_the_periods_of_rows_written_one_by_one(seed, monkeypatch):
    """The averager keeps added rows as tuples until a read (``take``, ``drop_before``, ``len``
    is not one) or ``PENDING_ROWS`` of them: the periods it gives, through buffer growth, sliding
    drops (in order and jittered) and takes at uneven points, are exactly those of an averager
    writing each row to its array as it comes (``PENDING_ROWS`` 1)."""
    import companion.nav.period as period
    rng = np.random.default_rng(seed)
    actions = []
    for k in range(3000):
        t = 0.1 * k + float(rng.normal(0.0, 0.3 if seed % 2 else 0.0))
        ned = tuple(float(v) for v in np.array([25000.0, -2000.0, 35000.0]) + rng.normal(0.0, 30.0, 3))
        gravity = rng.random() < 0.8
        actions.append(("add", t, float(rng.normal(179.0, 2.0)), 54.0 + float(rng.normal(0.0, 0.1)), ned,
                        -343000.0 if gravity else math.nan, (0.01, 0.02, -9.8) if gravity else (math.nan,) * 3))
        roll = rng.random()
        if roll < 0.003:
            actions.append(("drop", t - float(rng.uniform(10.0, 100.0))))
        elif roll < 0.005:
            actions.append(("take", t - float(rng.uniform(0.0, 5.0))))

    def run(pending_rows: int) -> list[str]:
        monkeypatch.setattr(period, "PENDING_ROWS", pending_rows)
        avg, out = PeriodAverager(), []
        for action in actions:
            if action[0] == "add":
                avg.add(*action[1:])
            elif action[0] == "drop":
                avg.drop_before(action[1])
            else:
                out.append(repr(avg.take(action[1])))
            out.append(str(len(avg)))
        return out + [repr(avg.take(1e9))]

    assert run(period.PENDING_ROWS) == run(1)
