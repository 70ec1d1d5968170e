"""PX4's local frame: the azimuthal equidistant projection on a sphere of radius 6,371,000 m about the
estimator's reference point, as PX4's ``map_projection`` (``src/lib/geo``: ``project``/``reproject``, its
``CONSTANTS_RADIUS_OF_EARTH``) computes ``vehicle_local_position`` x/y from latitude and longitude.

Merlin's own frame (``merlin.geodesy.LocalFrame``) is the same projection on the WGS84 ellipsoid. The two
differ by the ratio of the sphere's radius to the ellipsoid's local radii of curvature: about 0.3 % north-south
at mid latitudes, so a replay that takes a PX4 log's x/y as Merlin's metres misplaces the vehicle by metres
per kilometre against the fence. pyproj's spherical ``aeqd`` is that projection (Snyder 1987, "Map
Projections: A Working Manual", USGS PP 1395, eqs. 25-2, 22-4, 22-5); ``tests/replay/test_px4_frame.py``
checks it against PX4's formulas.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from pyproj import CRS, Transformer

EARTH_RADIUS_M = 6_371_000.0  # PX4's CONSTANTS_RADIUS_OF_EARTH

_GEOGRAPHIC = CRS.from_proj4("+proj=longlat +datum=WGS84 +no_defs")


class Px4MapProjection:
    """x (north) / y (east) metres of PX4's local frame about (``ref_lat_deg``, ``ref_lon_deg``)."""

    def __init__(self, ref_lat_deg: float, ref_lon_deg: float) -> None:
        self.ref_lat_deg = float(ref_lat_deg)
        self.ref_lon_deg = float(ref_lon_deg)
        # PX4 feeds WGS84 latitude and longitude straight into the spherical formulas: the sphere's
        # geographic coordinates are WGS84's, with no datum shift (+towgs84 of zero)
        local = CRS.from_proj4(f"+proj=aeqd +R={EARTH_RADIUS_M} +lat_0={self.ref_lat_deg} +lon_0={self.ref_lon_deg} "
                               "+x_0=0 +y_0=0 +units=m +towgs84=0,0,0 +no_defs")
        sphere = CRS.from_proj4(f"+proj=longlat +R={EARTH_RADIUS_M} +towgs84=0,0,0 +no_defs")
        self._to_local = Transformer.from_crs(sphere, local, always_xy=True)
        self._to_geo = Transformer.from_crs(local, sphere, always_xy=True)

    def project(self, lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """(x_north_m, y_east_m) of WGS84 points."""
        east, north = self._to_local.transform(np.asarray(lon_deg, float), np.asarray(lat_deg, float))
        return np.asarray(north, float), np.asarray(east, float)

    def reproject(self, x_north_m: npt.ArrayLike, y_east_m: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """(lat_deg, lon_deg) of local points."""
        lon, lat = self._to_geo.transform(np.asarray(y_east_m, float), np.asarray(x_north_m, float))
        return np.asarray(lat, float), np.asarray(lon, float)
