"""Telemetry core: REP-103 conversions, validation, buffer, geodesy, trajectories."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from subpix_ros.core.telemetry import (
    TelemetryBuffer,
    TelemetrySample,
    attitude_quaternion_enu,
    course_from_velocity,
    enu_offset_m,
    enu_to_latlon,
    ned_to_enu,
    timing_usable,
    trajectory_straight,
    trajectory_through_fixes,
    validate_sample,
)
from subpix_ros.data import data_root
from subpix_ros.io.frame_metadata import trajectory_from_frames_csv

R_MEAN = 6371008.8  # IUGG mean Earth radius, m (for the hand haversine)
# The module uses WGS-84 radii of curvature; at 41 deg N they differ from the
# mean sphere by -0.13 % (meridian) and +0.26 % (prime vertical), so a
# haversine distance agrees with it to within 0.3 %.
SPHERE_VS_ELLIPSOID = 0.003
# Same cause for directions: the ratio of the two radii (1.0038) turns a
# bearing by up to 0.5 * 0.0038 rad = 1.9e-3 rad between sphere and ellipsoid.
SPHERE_BEARING_TOL = 2e-3


def haversine_m(lat1, lon1, lat2, lon2):
    p1, p2 = math.radians(lat1), math.radians(lat2)
    dp, dl = p2 - p1, math.radians(lon2 - lon1)
    h = math.sin(dp / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(dl / 2) ** 2
    return 2 * R_MEAN * math.asin(math.sqrt(h))


def bearing_rad(lat1, lon1, lat2, lon2):
    p1, p2 = math.radians(lat1), math.radians(lat2)
    dl = math.radians(lon2 - lon1)
    y = math.sin(dl) * math.cos(p2)
    x = math.cos(p1) * math.sin(p2) - math.sin(p1) * math.cos(p2) * math.cos(dl)
    return math.atan2(y, x) % (2 * math.pi)


def sample(**kw):
    base = dict(
        t=1000.0,
        lat_deg=41.0,
        lon_deg=-83.0,
        alt_msl_m=288.0,
        height_agl_m=58.0,
        vel_ned_mps=(4.0, 7.0, 0.0),
        ground_speed_mps=math.hypot(4.0, 7.0),
        course_rad=math.atan2(7.0, 4.0),
        roll_rad=0.0,
        pitch_rad=0.0,
        yaw_rad=0.5,
    )
    base.update(kw)
    return TelemetrySample(**base)


# --------------------------------------------------------------------------- REP-103
def test_ned_to_enu_swaps_and_flips():
    assert ned_to_enu([1.0, 2.0, 3.0]).tolist() == [2.0, 1.0, -3.0]
    arr = ned_to_enu(np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -5.0]]))
    assert arr.tolist() == [[0.0, 1.0, 0.0], [0.0, 0.0, 5.0]]
    with pytest.raises(ValueError):
        ned_to_enu([1.0, 2.0])
    s = sample(vel_ned_mps=(3.0, -4.0, 0.5))
    assert s.vel_enu_mps.tolist() == [-4.0, 3.0, -0.5]


H = math.sqrt(0.5)


@pytest.mark.parametrize(
    "rpy, expected",
    [
        ((0.0, 0.0, 0.0), (0.0, 0.0, H, H)),  # nose north = ENU yaw +90 deg
        ((0.0, 0.0, math.pi / 2), (0.0, 0.0, 0.0, 1.0)),  # nose east = ENU identity
        ((0.0, 0.0, math.pi), (0.0, 0.0, -H, H)),  # nose south = ENU yaw -90 deg
        ((0.3, 0.0, math.pi / 2), (math.sin(0.15), 0.0, 0.0, math.cos(0.15))),  # right wing down
        ((0.0, 0.2, math.pi / 2), (0.0, -math.sin(0.1), 0.0, math.cos(0.1))),  # nose up
    ],
)
def test_attitude_quaternion_hand_cases(rpy, expected):
    np.testing.assert_allclose(attitude_quaternion_enu(*rpy), expected, atol=1e-12)


def quat_matrix(q):
    x, y, z, w = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def test_attitude_quaternion_body_axes_point_where_expected():
    # Nose north and 0.2 rad up: the body x axis is (east 0, north cos, up sin).
    r = quat_matrix(attitude_quaternion_enu(0.0, 0.2, 0.0))
    np.testing.assert_allclose(r[:, 0], [0.0, math.cos(0.2), math.sin(0.2)], atol=1e-12)
    # Nose east, rolled 0.3 rad right wing down: the left wing (body y) rises.
    r = quat_matrix(attitude_quaternion_enu(0.3, 0.0, math.pi / 2))
    np.testing.assert_allclose(r[:, 1], [0.0, math.cos(0.3), math.sin(0.3)], atol=1e-12)


def rot(axis, a):
    c, s = math.cos(a), math.sin(a)
    return {
        "x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
        "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
        "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]),
    }[axis]


@settings(max_examples=60, deadline=None)
@given(
    st.floats(-math.pi, math.pi),
    st.floats(-1.5, 1.5),
    st.floats(-math.pi, math.pi),
)
def test_attitude_quaternion_matches_frame_change_matrices(roll, pitch, yaw):
    r_ned_frd = rot("z", yaw) @ rot("y", pitch) @ rot("x", roll)
    ned_to_enu_m = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1]])
    flu_to_frd = np.diag([1, -1, -1])
    expected = ned_to_enu_m @ r_ned_frd @ flu_to_frd
    q = attitude_quaternion_enu(roll, pitch, yaw)
    assert abs(np.linalg.norm(q) - 1) < 1e-12 and q[3] >= 0
    np.testing.assert_allclose(quat_matrix(q), expected, atol=1e-9)


def test_attitude_quaternion_rejects_nan():
    with pytest.raises(ValueError, match="yaw"):
        attitude_quaternion_enu(0.0, 0.0, float("nan"))


def test_course_from_velocity_clockwise_from_north():
    assert course_from_velocity(1.0, 0.0) == 0.0
    assert course_from_velocity(0.0, 1.0) == pytest.approx(math.pi / 2)
    assert course_from_velocity(-1.0, 0.0) == pytest.approx(math.pi)
    assert course_from_velocity(0.0, -1.0) == pytest.approx(3 * math.pi / 2)


# --------------------------------------------------------------------------- geodesy
def ecef(lat, lon, h=0.0):
    a, e2 = 6378137.0, 6.69437999014e-3
    p, l = math.radians(lat), math.radians(lon)
    n = a / math.sqrt(1 - e2 * math.sin(p) ** 2)
    return np.array(
        [
            (n + h) * math.cos(p) * math.cos(l),
            (n + h) * math.cos(p) * math.sin(l),
            (n * (1 - e2) + h) * math.sin(p),
        ]
    )


@pytest.mark.parametrize("de, dn", [(800.0, 0.0), (0.0, -900.0), (-600.0, 700.0), (30.0, 15.0)])
def test_enu_offset_matches_ecef_geometry(de, dn):
    lat0, lon0 = 41.0353080, -83.3062512
    lat, lon = enu_to_latlon(lat0, lon0, de, dn)
    e, n = enu_offset_m(lat0, lon0, lat, lon)
    assert float(e) == pytest.approx(de, abs=1e-6) and float(n) == pytest.approx(dn, abs=1e-6)
    # Independent: the ECEF chord (equal to the ground distance to ~1e-12
    # relative at 1 km) and the ENU direction at the origin.
    d = ecef(float(lat), float(lon)) - ecef(lat0, lon0)
    dist = math.hypot(de, dn)
    assert abs(np.linalg.norm(d) - dist) < 1e-5 * dist
    p, l = math.radians(lat0), math.radians(lon0)
    east = np.array([-math.sin(l), math.cos(l), 0.0])
    north = np.array([-math.sin(p) * math.cos(l), -math.sin(p) * math.sin(l), math.cos(p)])
    # Meridian convergence over the offset: d tan(lat) / (2 R) <= 6e-5 rad here.
    angle = math.atan2(de, dn) - math.atan2(d @ east, d @ north)
    assert abs((angle + math.pi) % (2 * math.pi) - math.pi) < 1e-4


def test_enu_offset_wraps_longitude():
    e, _ = enu_offset_m(0.0, 179.9999, 0.0, -179.9999)
    assert 0 < float(e) < 30  # 0.0002 deg east across the antimeridian, ~22 m


# --------------------------------------------------------------------------- validation
def test_validate_good_sample_and_no_attitude():
    assert validate_sample(sample()) == (True, "")
    assert validate_sample(sample(roll_rad=None, pitch_rad=None, yaw_rad=None))[0]


@pytest.mark.parametrize(
    "kw, fragment",
    [
        (dict(lat_deg=float("nan")), "non-finite lat_deg"),
        (dict(ground_speed_mps=float("inf")), "non-finite ground_speed_mps"),
        (dict(roll_rad=float("nan")), "non-finite roll_rad"),
        (dict(vel_ned_mps=(1.0, float("nan"), 0.0)), "non-finite vel_ned_mps"),
        (dict(lat_deg=90.5), "latitude out of range"),
        (dict(lon_deg=-180.5), "longitude out of range"),
        (dict(height_agl_m=-0.5), "negative height"),
        (dict(ground_speed_mps=-1.0), "negative ground speed"),
        (dict(ground_speed_mps=400.0), "absurd ground speed"),
        (dict(height_agl_m=1e6), "absurd height"),
        (dict(course_rad=7.0), "course out of range"),
    ],
)
def test_validate_rejects_bad_fields(kw, fragment):
    ok, reason = validate_sample(sample(**kw))
    assert not ok and fragment in reason


def test_hover_is_valid_but_not_usable_for_timing():
    hover = sample(vel_ned_mps=(0.0, 0.0, 0.0), ground_speed_mps=0.0)
    assert validate_sample(hover) == (True, "")
    ok, reason = timing_usable(hover)
    assert not ok and "hovering" in reason
    assert timing_usable(sample()) == (True, "")
    ok, reason = timing_usable(sample(ground_speed_mps=400.0))
    assert not ok and "invalid sample: absurd ground speed" in reason


def test_sample_requires_three_velocity_components():
    with pytest.raises(ValueError, match="3 components"):
        sample(vel_ned_mps=(1.0, 2.0))


# --------------------------------------------------------------------------- buffer
def test_buffer_interpolates_linearly_and_unwraps_angles():
    buf = TelemetryBuffer(max_age_s=10.0, stale_after_s=1.0)
    a = sample(
        t=10.0,
        lat_deg=41.0,
        lon_deg=-83.0,
        height_agl_m=50.0,
        vel_ned_mps=(2.0, 0.0, 0.0),
        ground_speed_mps=2.0,
        course_rad=math.radians(350),
        yaw_rad=math.radians(179),
    )
    b = sample(
        t=10.5,
        lat_deg=41.001,
        lon_deg=-83.002,
        height_agl_m=60.0,
        vel_ned_mps=(4.0, 2.0, -1.0),
        ground_speed_mps=4.0,
        course_rad=math.radians(10),
        yaw_rad=math.radians(-179),
    )
    assert buf.add(a)[0] and buf.add(b)[0]
    s, note = buf.at(10.125)
    assert note == ""
    assert s.t == 10.125
    assert s.lat_deg == pytest.approx(41.00025, abs=1e-12)
    assert s.lon_deg == pytest.approx(-83.0005, abs=1e-12)
    assert s.height_agl_m == pytest.approx(52.5)
    np.testing.assert_allclose(s.vel_ned_mps, [2.5, 0.5, -0.25])
    assert s.ground_speed_mps == pytest.approx(2.5)
    assert math.degrees(s.course_rad) == pytest.approx(355.0)  # 350 -> 10 through north
    assert math.degrees(s.yaw_rad) == pytest.approx(179.5)  # 179 -> -179 through 180
    s_mid, _ = buf.at(10.25)
    assert 0.0 <= s_mid.course_rad < 2 * math.pi  # due north, kept in [0, 2 pi)
    assert (
        math.cos(s_mid.course_rad) == pytest.approx(1.0) and abs(math.sin(s_mid.course_rad)) < 1e-9
    )
    assert buf.at(10.5)[0] is b


def test_buffer_out_of_range_stale_and_gaps():
    buf = TelemetryBuffer(max_age_s=100.0, stale_after_s=0.5)
    for t in (1.0, 1.2, 1.4, 3.0):
        assert buf.add(sample(t=t))[0]
    s, reason = buf.at(0.9)
    assert s is None and "before the oldest" in reason
    s, note = buf.at(3.3)
    assert s is not None and s.t == 3.3 and "held newest" in note
    s, reason = buf.at(3.6)
    assert s is None and "stale" in reason
    s, reason = buf.at(2.0)  # between 1.4 and 3.0: a 1.6 s gap
    assert s is None and "gap" in reason
    assert buf.at(float("nan"))[0] is None
    assert buf.is_stale(3.6) and not buf.is_stale(3.4)
    assert TelemetryBuffer().at(5.0) == (None, "no telemetry received")


def test_an_empty_buffer_says_every_sample_was_invalid_not_that_none_came():
    buf = TelemetryBuffer()
    for t in (1.0, 1.1, 1.2):
        assert not buf.add(sample(t=t, height_agl_m=-3.0))[0]
    _, reason = buf.at(1.1)
    assert reason.startswith("telemetry unusable: all 3 sample(s) refused as invalid"), reason
    assert "negative height above ground (-3.000 m)" in reason


def test_buffer_reorders_or_rejects_late_samples_and_counts_them():
    buf = TelemetryBuffer(stale_after_s=1.0)
    buf.add(sample(t=1.0, height_agl_m=10.0))
    buf.add(sample(t=2.0, height_agl_m=30.0))
    ok, note = buf.add(sample(t=1.5, height_agl_m=100.0))
    assert ok and "reordered" in note
    assert buf.stats.out_of_order == 1
    assert buf.at(1.25)[0].height_agl_m == pytest.approx(55.0)  # between 10 and 100
    ok, reason = buf.add(sample(t=2.0))
    assert not ok and "duplicate" in reason and buf.stats.duplicates == 1

    strict = TelemetryBuffer(out_of_order="reject")
    strict.add(sample(t=1.0))
    strict.add(sample(t=2.0))
    ok, reason = strict.add(sample(t=1.5))
    assert not ok and "out-of-order" in reason
    assert strict.stats.out_of_order_rejected == 1 and len(strict) == 2


def test_buffer_rejects_invalid_and_keeps_valid_neighbours():
    buf = TelemetryBuffer()
    assert buf.add(sample(t=1.0))[0]
    ok, reason = buf.add(sample(t=1.5, height_agl_m=-3.0))
    assert not ok and "negative height" in reason
    assert buf.add(sample(t=2.0))[0]
    assert buf.stats.invalid == 1 and len(buf) == 2


def test_buffer_is_bounded_by_age_and_count():
    buf = TelemetryBuffer(max_age_s=1.0, stale_after_s=0.5)
    for k in range(50):
        buf.add(sample(t=k * 0.1))
    lo, hi = buf.time_range()
    assert hi == pytest.approx(4.9) and lo >= hi - 1.0 - 1e-9
    small = TelemetryBuffer(max_age_s=1e6, max_samples=5)
    for k in range(20):
        small.add(sample(t=float(k)))
    assert len(small) == 5 and small.time_range() == (15.0, 19.0)
    assert small.stats.evicted == 15
    with pytest.raises(ValueError):
        TelemetryBuffer(max_age_s=0)
    with pytest.raises(ValueError):
        TelemetryBuffer(out_of_order="shuffle")


def test_buffer_attitude_absent_stays_absent():
    buf = TelemetryBuffer()
    buf.add(sample(t=1.0, roll_rad=None, pitch_rad=None, yaw_rad=None))
    buf.add(sample(t=1.2))
    s, _ = buf.at(1.1)
    assert s.yaw_rad is None and s.orientation_enu() is None


# --------------------------------------------------------------------------- trajectories
def frames_rows():
    import csv

    with (data_root() / "seneca" / "frames.csv").open() as fh:
        return list(csv.DictReader(fh))


def test_frames_trajectory_passes_through_every_fix():
    rows = frames_rows()
    traj = trajectory_from_frames_csv(data_root() / "seneca" / "frames.csv")
    t = np.array([s.t for s in traj])
    assert len(traj) == 361  # 13:39:05 .. 13:39:41 at 10 Hz, both ends
    assert t[0] == 1370353145.0  # 2013-06-04 13:39:05 read as UTC
    assert np.allclose(np.diff(t), 0.1)
    for r in rows:
        hh, mm, ss = (int(x) for x in r["datetime_original"].split()[1].split(":"))
        tk = 1370304000.0 + hh * 3600 + mm * 60 + ss  # 2013-06-04 00:00 UTC
        s = traj[int(np.argmin(np.abs(t - tk)))]
        assert abs(s.t - tk) < 1e-6
        assert s.lat_deg == pytest.approx(float(r["latitude_deg"]), abs=1e-9)
        assert s.lon_deg == pytest.approx(float(r["longitude_deg"]), abs=1e-9)
        assert s.height_agl_m == pytest.approx(float(r["gps_altitude_m"]) - 230.0, abs=1e-6)
    for s in traj:
        assert validate_sample(s) == (True, "")
        assert s.roll_rad == 0.0 and s.pitch_rad == 0.0
        assert (
            abs((s.yaw_rad - s.course_rad + math.pi) % (2 * math.pi) - math.pi) < 1e-9
        )  # yaw = course
        assert s.ground_speed_mps == pytest.approx(math.hypot(*s.vel_ned_mps[:2]))


def test_frames_trajectory_speed_461_to_462_matches_hand_haversine():
    rows = frames_rows()
    r0, r1 = rows[0], rows[1]
    assert r0["file"] == "IMG_0461.jpg" and r1["file"] == "IMG_0462.jpg"
    lat0, lon0, lat1, lon1 = (
        float(r0["latitude_deg"]),
        float(r0["longitude_deg"]),
        float(r1["latitude_deg"]),
        float(r1["longitude_deg"]),
    )
    dt = 4.0  # 13:39:05 -> 13:39:09
    hand_speed = haversine_m(lat0, lon0, lat1, lon1) / dt  # 36.65 m / 4 s = 9.16 m/s
    hand_course = bearing_rad(lat0, lon0, lat1, lon1)
    assert 8.0 < hand_speed < 10.0
    traj = trajectory_from_frames_csv(data_root() / "seneca" / "frames.csv", rate_hz=10.0)
    t = np.array([s.t for s in traj])
    v = np.array([s.vel_ned_mps for s in traj])
    sel = (t >= traj[0].t - 1e-6) & (t <= traj[0].t + dt + 1e-6)
    vs, ts = v[sel], t[sel]
    mean_v = (0.5 * (vs[1:] + vs[:-1]) * np.diff(ts)[:, None]).sum(
        axis=0
    ) / dt  # trapezoid: displacement / dt
    assert math.hypot(mean_v[0], mean_v[1]) == pytest.approx(hand_speed, rel=SPHERE_VS_ELLIPSOID)
    assert course_from_velocity(mean_v[0], mean_v[1]) == pytest.approx(
        hand_course, abs=SPHERE_BEARING_TOL
    )
    # Vertical: GPS altitude 288.40 -> 287.14 m, so mean down velocity +0.315 m/s.
    assert mean_v[2] == pytest.approx((288.40 - 287.14) / dt, abs=1e-3)


def test_trajectory_through_fixes_rejects_bad_fixes():
    t = np.array([0.0, 0.0])
    with pytest.raises(ValueError, match="increase"):
        trajectory_through_fixes(
            t, np.array([41.0, 41.1]), np.array([-83.0, -83.0]), np.array([280.0, 280.0])
        )
    with pytest.raises(ValueError, match="at least 2"):
        trajectory_through_fixes(
            np.array([0.0]), np.array([41.0]), np.array([-83.0]), np.array([280.0])
        )
    with pytest.raises(ValueError, match="rate_hz"):
        trajectory_through_fixes(
            np.array([0.0, 1.0]),
            np.array([41.0, 41.0]),
            np.array([-83.0, -83.0]),
            np.array([280.0, 280.0]),
            rate_hz=0.0,
        )


def test_straight_trajectory_hand_values():
    traj = trajectory_straight(
        t0=100.0,
        duration_s=10.0,
        rate_hz=5.0,
        lat0_deg=41.0,
        lon0_deg=-83.0,
        ground_alt_m=230.0,
        height_agl_m=60.0,
        speed_mps=8.0,
        course_rad=math.radians(60.0),
    )
    assert len(traj) == 51 and traj[-1].t == pytest.approx(110.0)
    first, last = traj[0], traj[-1]
    assert haversine_m(first.lat_deg, first.lon_deg, last.lat_deg, last.lon_deg) == pytest.approx(
        80.0, rel=SPHERE_VS_ELLIPSOID
    )
    assert bearing_rad(first.lat_deg, first.lon_deg, last.lat_deg, last.lon_deg) == pytest.approx(
        math.radians(60.0), abs=SPHERE_BEARING_TOL
    )
    for s in traj:
        np.testing.assert_allclose(
            s.vel_ned_mps, [4.0, 8.0 * math.sin(math.radians(60)), 0.0], atol=1e-12
        )
        assert s.ground_speed_mps == pytest.approx(8.0)
        assert s.course_rad == pytest.approx(math.radians(60.0))
        assert s.height_agl_m == 60.0 and s.alt_msl_m == 290.0
    hover = trajectory_straight(speed_mps=0.0, course_rad=math.radians(270), duration_s=1.0)
    assert all(s.course_rad == pytest.approx(math.radians(270)) for s in hover)
    assert not timing_usable(hover[0])[0]
    with pytest.raises(ValueError):
        trajectory_straight(speed_mps=-1.0)
