"""ROS-side telemetry helpers: heading from an ENU quaternion, samples from ENU inputs."""

import math

import numpy as np
import pytest

from subpix_ros.core.telemetry import (
    attitude_quaternion_enu,
    heading_from_quaternion_enu,
    sample_from_enu,
)


@pytest.mark.parametrize("yaw_deg", [0.0, 30.0, 90.0, 181.0, 359.0])
def test_heading_inverts_the_attitude_quaternion(yaw_deg):
    q = attitude_quaternion_enu(0.02, -0.03, math.radians(yaw_deg))
    assert math.degrees(heading_from_quaternion_enu(*q)) == pytest.approx(yaw_deg % 360.0, abs=1e-6)


def test_sample_from_enu_hand_values():
    s = sample_from_enu(10.0, (7.0, 4.0, 0.5), 58.4, heading_rad=1.0)
    np.testing.assert_allclose(s.vel_ned_mps, [4.0, 7.0, -0.5])
    assert s.ground_speed_mps == pytest.approx(math.hypot(4, 7))
    assert math.degrees(s.course_rad) == pytest.approx(
        60.2551187, abs=1e-6
    )  # atan2(east 7, north 4)
    assert s.yaw_rad == 1.0 and s.height_agl_m == 58.4
    assert sample_from_enu(0.0, (0.0, -3.0, 0.0), 10.0).yaw_rad == pytest.approx(
        math.pi
    )  # no heading: course
