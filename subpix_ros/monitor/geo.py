"""Ground footprints of camera frames and the GeoJSON the monitor's Map panel shows.

No ROS: plain numbers in, plain numbers and JSON out.
"""

from __future__ import annotations

import json
import math
from typing import Sequence

import numpy as np

__all__ = ["EARTH_RADIUS_M", "footprint_lonlat", "feature_collection"]

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


def feature_collection(
    track: Sequence[tuple[float, float]],
    footprints: Sequence[Sequence[tuple[float, float]]],
    max_track_points: int = 500,
) -> str:
    """GeoJSON FeatureCollection: the track so far (LineString, decimated) and frame footprints.

    Parameters
    ----------
    track : sequence of (lon, lat)
        Fixes in time order.
    footprints : sequence of rings
        Closed (lon, lat) rings from :func:`footprint_lonlat`.
    max_track_points : int
        The track is decimated to at most this many points (the newest kept).

    Returns
    -------
    str
        The GeoJSON text (what ``foxglove.GeoJson`` carries).
    """
    pts = list(track)
    if len(pts) > max_track_points:
        idx = np.linspace(0, len(pts) - 1, max_track_points).round().astype(int)
        pts = [pts[i] for i in idx]
    feats = []
    if len(pts) >= 2:
        feats.append(
            {
                "type": "Feature",
                "properties": {"name": "track"},
                "geometry": {
                    "type": "LineString",
                    "coordinates": [[round(x, 7), round(y, 7)] for x, y in pts],
                },
            }
        )
    for i, ring in enumerate(footprints):
        feats.append(
            {
                "type": "Feature",
                "properties": {"name": f"frame {i}"},
                "geometry": {
                    "type": "Polygon",
                    "coordinates": [[[round(x, 7), round(y, 7)] for x, y in ring]],
                },
            }
        )
    return json.dumps({"type": "FeatureCollection", "features": feats}, separators=(",", ":"))
