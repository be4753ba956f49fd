"""Telemetry samples rebuilt from the telemetry node's topics (io.telemetry_msgs)."""

from __future__ import annotations

from rosbags.typesys import Stores, get_typestore

from subpix_ros.core.telemetry import TelemetrySample
from subpix_ros.io.telemetry_msgs import TelemetryFromTopics, sample_messages

T = get_typestore(Stores.ROS2_JAZZY)


def _sample(t: float, height: float) -> TelemetrySample:
    return TelemetrySample(
        t=t,
        vel_ned_mps=(3.0, 4.0, 0.0),
        ground_speed_mps=5.0,
        course_rad=0.927,
        height_agl_m=height,
        lat_deg=50.0,
        lon_deg=30.0,
        alt_msl_m=200.0,
        roll_rad=0.0,
        pitch_rad=0.0,
        yaw_rad=0.5,
    )


def _replay(messages, rebuild: TelemetryFromTopics) -> list[TelemetrySample]:
    """Feed (topic, type, CDR) messages in order; the samples they give."""
    take = {
        "telemetry/fix": rebuild.navsat,
        "telemetry/height": rebuild.height,
        "telemetry/imu": rebuild.imu,
        "telemetry/velocity": rebuild.velocity,
    }
    out = []
    for topic, msgtype, raw in messages:
        if topic in take:
            s = take[topic](T.deserialize_cdr(raw, msgtype))
            if s is not None:
                out.append(s)
    return out


def test_every_sample_comes_back_with_its_own_height():
    """The node's order (height and attitude before the velocity): one sample per velocity."""
    samples = [_sample(100.0 + 0.1 * k, 50.0 + k) for k in range(5)]
    msgs = [m for s in samples for m in sample_messages(s, 0.5)]
    got = _replay(msgs, TelemetryFromTopics())
    assert [round(s.t, 3) for s in got] == [round(s.t, 3) for s in samples]
    assert [s.height_agl_m for s in got] == [s.height_agl_m for s in samples]


def test_a_velocity_before_the_first_height_is_not_lost():
    """Bags recorded with the velocity before the height (and topics out of order live)."""
    samples = [_sample(100.0 + 0.1 * k, 50.0 + k) for k in range(3)]
    msgs = []
    for s in samples:  # the old order: fix, velocity, height
        by = {t: (t, ty, raw) for t, ty, raw in sample_messages(s)}
        msgs += [by["telemetry/fix"], by["telemetry/velocity"], by["telemetry/height"]]
    got = _replay(msgs, TelemetryFromTopics())
    assert len(got) == 3, "the first velocity waits for the first height"
    assert round(got[0].t, 3) == 100.0 and got[0].height_agl_m == 50.0
