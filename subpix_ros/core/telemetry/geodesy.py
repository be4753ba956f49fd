"""Local tangent plane on the WGS-84 ellipsoid: east/north offsets to and from lat/lon."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["WGS84_A", "WGS84_E2", "enu_offset_m", "enu_to_latlon"]

#: WGS-84 semi-major axis, m.
WGS84_A = 6378137.0
#: WGS-84 first eccentricity squared.
WGS84_E2 = 6.69437999014e-3


def _radii(lat_rad: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """Return the WGS-84 meridian (M) and prime-vertical (N) radii of curvature, m."""
    s2 = np.sin(lat_rad) ** 2
    w = 1.0 - WGS84_E2 * s2
    m = WGS84_A * (1.0 - WGS84_E2) / w**1.5
    n = WGS84_A / np.sqrt(w)
    return m, n


def enu_offset_m(lat0: float, lon0: float, lat, lon) -> tuple[np.ndarray, np.ndarray]:
    """Return the east and north offsets of (lat, lon) from (lat0, lon0).

    Parameters
    ----------
    lat0, lon0 : float
        Origin, degrees.
    lat, lon : array_like
        Points, degrees (vectorised).

    Returns
    -------
    east, north : ndarray
        Offsets, m.

    Notes
    -----
    Local tangent plane on the WGS-84 ellipsoid:
    ``north = M(lat0) (lat - lat0)``, ``east = N(lat_m) cos(lat_m) (lon - lon0)``
    with angles in radians, M/N the meridian/prime-vertical radii and
    ``lat_m`` the mid latitude. Within 1 km the distance ``hypot(east,
    north)`` matches the ECEF chord to 1e-5 relative and the direction
    matches ECEF-derived ENU at (lat0, lon0) to 1e-4 rad (the remainder is
    meridian convergence, ``d tan(lat) / 2R``). Longitude differences are
    wrapped to [-180, 180).
    """
    lat = np.asarray(lat, dtype=np.float64)
    lon = np.asarray(lon, dtype=np.float64)
    phi0 = math.radians(lat0)
    dlat = np.radians(lat - lat0)
    dlon = np.radians((lon - lon0 + 180.0) % 360.0 - 180.0)
    m0, _ = _radii(phi0)
    phim = phi0 + dlat / 2.0
    _, nm = _radii(phim)
    return nm * np.cos(phim) * dlon, m0 * dlat


def enu_to_latlon(lat0: float, lon0: float, east, north) -> tuple[np.ndarray, np.ndarray]:
    """Return the latitude and longitude at east/north offsets from (lat0, lon0).

    Parameters
    ----------
    lat0, lon0 : float
        Origin, degrees.
    east, north : array_like
        Offsets, m (vectorised).

    Returns
    -------
    lat, lon : ndarray
        Degrees; longitude wrapped to [-180, 180).

    Notes
    -----
    The exact inverse of the approximation of :func:`enu_offset_m`.
    """
    east = np.asarray(east, dtype=np.float64)
    north = np.asarray(north, dtype=np.float64)
    phi0 = math.radians(lat0)
    m0, _ = _radii(phi0)
    dlat = north / m0
    phim = phi0 + dlat / 2.0
    _, nm = _radii(phim)
    dlon = east / (nm * np.cos(phim))
    lon = (lon0 + np.degrees(dlon) + 180.0) % 360.0 - 180.0
    return lat0 + np.degrees(dlat), lon
