"""Ground footprints of camera frames and the GeoJSON the monitor's Map panel shows.

No ROS: plain numbers in, plain numbers and JSON out.
"""

from __future__ import annotations

import json
import math
from typing import Sequence

import numpy as np

__all__ = ["EARTH_RADIUS_M", "footprint_lonlat", "feature_collection", "simplify_track"]

EARTH_RADIUS_M = 6378137.0  # WGS-84 equatorial radius: the local flat-earth step below


def footprint_lonlat(
    lat_deg: float,
    lon_deg: float,
    height_m: float,
    heading_rad: float,
    width_px: int,
    height_px: int,
    focal_mm: float,
    pixel_um: float,
) -> list[tuple[float, float]]:
    """Corners of a nadir frame's ground footprint, (lon, lat) degrees, closed ring.

    Parameters
    ----------
    lat_deg, lon_deg : float
        Position of the camera (the footprint's centre for a nadir camera).
    height_m : float
        Height above ground, m (> 0).
    heading_rad : float
        Compass angle of the image top, rad, clockwise from north (vehicle heading
        plus the camera's yaw offset).
    width_px, height_px : int
        Image size in pixels (columns, rows).
    focal_mm, pixel_um : float
        Focal length (mm) and detector pixel pitch (um) of the image as published.

    Returns
    -------
    list of (lon, lat)
        Top-left, top-right, bottom-right, bottom-left, top-left again (GeoJSON order).

    Notes
    -----
    Ground sample distance ``g = h a / f`` (METHODS.md eq. 1's pixel footprint). An image
    offset (dx right, dy up) in metres lies at east ``e = dx cos(psi) + dy sin(psi)``,
    north ``n = -dx sin(psi) + dy cos(psi)`` for heading ``psi``; degrees follow from the
    local flat earth: ``dlat = n / R``, ``dlon = e / (R cos(lat))``. Valid for footprints of
    a few hundred metres (error below 1e-4 relative).
    """
    if not (height_m > 0 and focal_mm > 0 and pixel_um > 0 and width_px > 0 and height_px > 0):
        raise ValueError("footprint needs height, focal length, pixel pitch and image size > 0")
    gsd = height_m * pixel_um * 1e-6 / (focal_mm * 1e-3)
    hw, hh = 0.5 * width_px * gsd, 0.5 * height_px * gsd
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    corners = []
    for dx, dy in ((-hw, hh), (hw, hh), (hw, -hh), (-hw, -hh), (-hw, hh)):
        e = dx * c + dy * s
        n = -dx * s + dy * c
        lat = lat_deg + math.degrees(n / EARTH_RADIUS_M)
        lon = lon_deg + math.degrees(e / (EARTH_RADIUS_M * math.cos(math.radians(lat_deg))))
        corners.append((lon, lat))
    return corners


def simplify_track(
    track: Sequence[tuple[float, float]], tolerance_m: float, max_points: int = 500
) -> list[tuple[float, float]]:
    """Thin a GNSS track for the map: Douglas-Peucker to ``tolerance_m``, at most ``max_points``.

    Parameters
    ----------
    track : sequence of (lon, lat)
        Fixes in time order (degrees).
    tolerance_m : float
        Largest distance (m) of a dropped fix from the line kept; 0 keeps every fix. A
        survey's straight legs shrink to their turns and the GNSS noise along them goes.
    max_points : int
        If more points are left, the tolerance doubles until they fit (the first and the
        last fix are always kept).

    Returns
    -------
    list of (lon, lat)
        The fixes kept, in time order.

    Notes
    -----
    Distances on the local flat earth around the track's mean latitude (as
    :func:`footprint_lonlat`): east ``R cos(lat0) dlon``, north ``R dlat``.
    """
    pts = list(track)
    n = len(pts)
    max_points = max(2, int(max_points))
    if n <= 2 or (tolerance_m <= 0 and n <= max_points):
        return pts
    a = np.radians(np.asarray(pts, dtype=float))
    xy = np.column_stack(
        (a[:, 0] * EARTH_RADIUS_M * math.cos(float(np.mean(a[:, 1]))), a[:, 1] * EARTH_RADIUS_M)
    )
    tol = tolerance_m if tolerance_m > 0 else 0.1
    while True:
        keep = _douglas_peucker(xy, tol)
        if keep.sum() <= max_points:
            return [pts[i] for i in np.flatnonzero(keep)]
        tol *= 2.0


def _douglas_peucker(xy: np.ndarray, tol: float) -> np.ndarray:
    """Return the mask of the points Douglas-Peucker keeps at ``tol`` (iterative, vectorised)."""
    keep = np.zeros(len(xy), dtype=bool)
    keep[0] = keep[-1] = True
    stack = [(0, len(xy) - 1)]
    while stack:
        i, j = stack.pop()
        if j - i < 2:
            continue
        p0, d = xy[i], xy[j] - xy[i]
        q = xy[i + 1 : j] - p0
        norm = math.hypot(d[0], d[1])
        if norm > 0:
            dist = np.abs(q[:, 0] * d[1] - q[:, 1] * d[0]) / norm
        else:
            dist = np.hypot(q[:, 0], q[:, 1])
        k = int(np.argmax(dist))
        if dist[k] > tol:
            m = i + 1 + k
            keep[m] = True
            stack.append((i, m))
            stack.append((m, j))
    return keep


def feature_collection(
    track: Sequence[tuple[float, float]],
    footprints: Sequence[Sequence[tuple[float, float]]],
    max_track_points: int = 500,
    tolerance_m: float = 0.0,
    decimals: int = 6,
) -> str:
    """GeoJSON FeatureCollection: the track so far (LineString, thinned) and frame footprints.

    Parameters
    ----------
    track : sequence of (lon, lat)
        Fixes in time order.
    footprints : sequence of rings
        Closed (lon, lat) rings from :func:`footprint_lonlat`.
    max_track_points : int
        The track keeps at most this many points (:func:`simplify_track`).
    tolerance_m : float
        Douglas-Peucker tolerance of the track, m (0: the track is only decimated evenly
        to ``max_track_points``, the first and the newest fix kept).
    decimals : int
        Decimals of the coordinates (6: 0.11 m of latitude).

    Returns
    -------
    str
        The GeoJSON text (what ``foxglove.GeoJson`` carries): a ``track`` LineString and one
        ``footprints`` MultiPolygon (one polygon per frame, oldest first), each present when
        there is something to draw.
    """
    pts = list(track)
    if tolerance_m > 0:
        pts = simplify_track(pts, tolerance_m, max_track_points)
    elif len(pts) > max_track_points:
        idx = np.linspace(0, len(pts) - 1, max_track_points).round().astype(int)
        pts = [pts[i] for i in idx]

    def xy(ring):
        return [[round(x, decimals), round(y, decimals)] for x, y in ring]

    feats = []
    if len(pts) >= 2:
        feats.append(
            {
                "type": "Feature",
                "properties": {"name": "track"},
                "geometry": {"type": "LineString", "coordinates": xy(pts)},
            }
        )
    if footprints:
        feats.append(
            {
                "type": "Feature",
                "properties": {"name": "footprints"},
                "geometry": {
                    "type": "MultiPolygon",
                    "coordinates": [[xy(ring)] for ring in footprints],
                },
            }
        )
    return json.dumps({"type": "FeatureCollection", "features": feats}, separators=(",", ":"))
