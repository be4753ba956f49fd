"""The monitor's plain parts: token bucket, wire bytes, footprints and GeoJSON, exposure rules."""

import json
import math

import numpy as np
import pytest

from subpix_ros.monitor import (
    MonitorConfig,
    MonitorError,
    TokenBucket,
    check_exposure,
    feature_collection,
    footprint_lonlat,
    wire_bytes,
)
from subpix_ros.monitor.geo import EARTH_RADIUS_M, simplify_track


def test_wire_bytes_counts_the_frame_headers():
    assert wire_bytes(0) == 13 + 2
    assert wire_bytes(112) == 125 + 2
    assert wire_bytes(113) == 126 + 4
    assert wire_bytes(65522) == 65535 + 4
    assert wire_bytes(65523) == 65536 + 10


def test_token_bucket_rate_burst_and_debt():
    b = TokenBucket(1000.0, burst_s=0.5)
    t0 = b._t
    assert b.level(t0) == 500.0
    assert b.allows(400, t0)
    assert b.allows(10_000, t0)  # larger than the whole saving: goes when the bucket is full
    b.charge(100, t0)
    assert not b.allows(10_000, t0) and b.allows(400, t0)
    b.charge(-100, t0)
    b.charge(2000, t0)  # essentials may drive it into debt
    assert b.level(t0) == -1500.0
    assert not b.allows(1, t0 + 1.0)  # -500 after 1 s
    assert b.allows(100, t0 + 1.7)  # +200
    assert b.level(t0 + 100.0) == 500.0  # never more than burst_s of budget


def _metres(ring, lat0, lon0):
    return [
        (
            (lon - lon0) * math.pi / 180 * EARTH_RADIUS_M * math.cos(math.radians(lat0)),
            (lat - lat0) * math.pi / 180 * EARTH_RADIUS_M,
        )
        for lon, lat in ring
    ]


def test_footprint_size_and_orientation():
    # 100 m up, 3.08 um pixels, 4.3 mm lens: 0.07163 m per pixel; 448 x 300 px
    gsd = 100 * 3.08e-6 / 4.3e-3
    ring = footprint_lonlat(42.8, -76.7, 100.0, 0.0, 448, 300, 4.3, 3.08)
    assert ring[0] == ring[-1] and len(ring) == 5
    (x0, y0), (x1, y1), (x2, y2), _, _ = _metres(ring, 42.8, -76.7)
    assert x1 - x0 == pytest.approx(448 * gsd, rel=1e-6) and y0 == pytest.approx(
        150 * gsd, rel=1e-6
    )
    assert y1 - y2 == pytest.approx(300 * gsd, rel=1e-6)
    # heading east: the image top points east, its left edge north
    (x0, y0), (x1, y1), _, _, _ = _metres(
        footprint_lonlat(42.8, -76.7, 100.0, math.pi / 2, 448, 300, 4.3, 3.08), 42.8, -76.7
    )
    assert x0 == pytest.approx(150 * gsd, rel=1e-6) and y0 == pytest.approx(224 * gsd, rel=1e-6)
    assert y1 == pytest.approx(-224 * gsd, rel=1e-6)
    with pytest.raises(ValueError):
        footprint_lonlat(42.8, -76.7, 0.0, 0.0, 448, 300, 4.3, 3.08)


def test_feature_collection_track_and_footprints():
    track = [(-76.7 + i * 1e-5, 42.8) for i in range(2000)]
    ring = footprint_lonlat(42.8, -76.7, 100.0, 0.0, 448, 300, 4.3, 3.08)
    gj = json.loads(feature_collection(track, [ring, ring], max_track_points=100))
    line = gj["features"][0]["geometry"]
    assert line["type"] == "LineString" and len(line["coordinates"]) == 100
    assert line["coordinates"][0] == [-76.7, 42.8] and line["coordinates"][-1] == [
        round(-76.7 + 1999e-5, 6),
        42.8,
    ]
    # the footprints: one MultiPolygon, a polygon (one closed ring) per frame
    (fp,) = gj["features"][1:]
    assert fp["geometry"]["type"] == "MultiPolygon"
    assert fp["geometry"]["coordinates"] == [[[[round(x, 6), round(y, 6)] for x, y in ring]]] * 2
    # a straight track thinned to a tolerance: its two ends
    gj = json.loads(feature_collection(track, [], tolerance_m=2.0))
    assert [f["properties"]["name"] for f in gj["features"]] == ["track"]
    assert len(gj["features"][0]["geometry"]["coordinates"]) == 2


def _survey(n, noise_m, seed=1):
    """Return a lawnmower in metres (east, north): 300 m legs 50 m apart, a fix every 2 m."""
    rng = np.random.default_rng(seed)
    pts = []
    for i in range(n):
        k, r = divmod(2.0 * i, 350.0)
        if r < 300:
            e, nn = (r if k % 2 == 0 else 300 - r), 50 * k
        else:
            e, nn = (300 if k % 2 == 0 else 0), 50 * k + r - 300
        pts.append((e + rng.normal(0, noise_m), nn + rng.normal(0, noise_m)))
    return np.array(pts)


def _lonlat(xy, lat0=42.8, lon0=-76.7):
    return [
        (
            lon0 + math.degrees(e / (EARTH_RADIUS_M * math.cos(math.radians(lat0)))),
            lat0 + math.degrees(n / EARTH_RADIUS_M),
        )
        for e, n in xy
    ]


def _distance_to_polyline(p, line):
    a, b = line[:-1], line[1:]
    d = b - a
    t = np.clip(
        np.einsum("ij,ij->i", p - a, d) / np.maximum(np.einsum("ij,ij->i", d, d), 1e-12), 0, 1
    )
    return float(np.min(np.hypot(*(a + t[:, None] * d - p).T)))


def test_simplify_track_keeps_the_turns_within_the_tolerance():
    xy = _survey(2000, noise_m=0.5)  # 4 km: 11 legs and a half
    track = _lonlat(xy)
    kept = simplify_track(track, 2.0, 500)
    assert kept[0] == track[0] and kept[-1] == track[-1]
    assert len(kept) < 80, len(kept)  # the turns (and a few noise spikes), not 2000 fixes
    index = {p: i for i, p in enumerate(track)}
    line = xy[[index[p] for p in kept]]
    worst = max(_distance_to_polyline(p, line) for p in xy)
    assert worst <= 2.0 + 1e-6, worst  # every fix dropped lies within 2 m of the line kept
    # too many points left: the tolerance grows until they fit, the ends kept
    few = simplify_track(track, 0.01, 40)
    assert len(few) <= 40 and few[0] == track[0] and few[-1] == track[-1]
    assert simplify_track(track[:2], 2.0) == track[:2]


@pytest.mark.parametrize("host", ["127.0.0.1", "localhost", "::1"])
def test_loopback_needs_nothing(host):
    assert check_exposure(MonitorConfig(host=host)) == (None, None)


@pytest.mark.parametrize("host", ["0.0.0.0", "192.168.1.10", "::"])
def test_other_addresses_are_refused_without_tls(host):
    with pytest.raises(MonitorError) as e:
        check_exposure(MonitorConfig(host=host))
    assert "\n" not in str(e.value)
    assert check_exposure(MonitorConfig(host=host, allow_insecure=True)) == (None, None)
