"""WGS84 latitude/longitude/altitude <-> the local NED frame about home.

The local frame is an azimuthal equidistant projection (``+proj=aeqd``) on the WGS84 ellipsoid centred on
home: distances and bearings *from home* are exact (geodesic), and within the few kilometres a test range
spans, distances between any two points are distorted by far less than 0.1 % (checked in
``tests/test_geodesy.py``). North and east come from the projection's y and x; down is home's altitude
minus the point's altitude, so the vertical is a flat-Earth height above home (the curvature drop, about
8 m at 10 km, is not modelled: the fence's altitude limits are heights above home, as in PX4).

Degrees appear here and at the configuration edge only; everything the core sees is metres.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from pyproj import CRS, Transformer

FloatArray = npt.NDArray[np.float64]

_WGS84_GEOGRAPHIC = CRS.from_proj4("+proj=longlat +datum=WGS84 +no_defs")


class LocalFrame:
    """The local NED frame (metres) about a home point given in WGS84 degrees and metres AMSL.

    The pyproj :class:`~pyproj.Transformer` is built once, here; the conversions are vectorised (numpy
    arrays of any matching shape) with scalar conveniences :meth:`to_ned` and :meth:`to_geodetic`.
    """

    __slots__ = ("_alt0_amsl_m", "_lat0_deg", "_lon0_deg", "_to_geo", "_to_local")

    def __init__(self, lat0_deg: float, lon0_deg: float, alt0_amsl_m: float = 0.0) -> None:
        if not (math.isfinite(lat0_deg) and -90.0 <= lat0_deg <= 90.0):
            raise ValueError(f"home latitude {lat0_deg!r} deg is not in [-90, 90]")
        if not (math.isfinite(lon0_deg) and -180.0 <= lon0_deg <= 180.0):
            raise ValueError(f"home longitude {lon0_deg!r} deg is not in [-180, 180]")
        if not math.isfinite(alt0_amsl_m):
            raise ValueError(f"home altitude {alt0_amsl_m!r} m is not finite")
        self._lat0_deg = float(lat0_deg)
        self._lon0_deg = float(lon0_deg)
        self._alt0_amsl_m = float(alt0_amsl_m)
        local = CRS.from_proj4(
            f"+proj=aeqd +lat_0={self._lat0_deg!r} +lon_0={self._lon0_deg!r} "
            "+x_0=0 +y_0=0 +datum=WGS84 +units=m +no_defs"
        )
        # always_xy: (lon, lat) in, (east, north) out, whatever the CRS's declared axis order.
        self._to_local = Transformer.from_crs(_WGS84_GEOGRAPHIC, local, always_xy=True)
        self._to_geo = Transformer.from_crs(local, _WGS84_GEOGRAPHIC, always_xy=True)

    @property
    def lat0_deg(self) -> float:
        return self._lat0_deg

    @property
    def lon0_deg(self) -> float:
        return self._lon0_deg

    @property
    def alt0_amsl_m(self) -> float:
        return self._alt0_amsl_m

    def __repr__(self) -> str:
        return f"LocalFrame(lat0_deg={self._lat0_deg!r}, lon0_deg={self._lon0_deg!r}, alt0_amsl_m={self._alt0_amsl_m!r})"

    # ------------------------------------------------------------------------------- vectorised

    def ne_from_latlon(self, lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        """(north_m, east_m) arrays of WGS84 points (arrays of any matching shape)."""
        lat = np.asarray(lat_deg, dtype=np.float64)
        lon = np.asarray(lon_deg, dtype=np.float64)
        east, north = self._to_local.transform(lon, lat)
        return np.asarray(north, dtype=np.float64), np.asarray(east, dtype=np.float64)

    def latlon_from_ne(self, north_m: npt.ArrayLike, east_m: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        """(lat_deg, lon_deg) arrays of local points (arrays of any matching shape)."""
        north = np.asarray(north_m, dtype=np.float64)
        east = np.asarray(east_m, dtype=np.float64)
        lon, lat = self._to_geo.transform(east, north)
        return np.asarray(lat, dtype=np.float64), np.asarray(lon, dtype=np.float64)

    def ned_from_geodetic(
        self, lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike, alt_amsl_m: npt.ArrayLike
    ) -> FloatArray:
        """NED positions, shape ``(..., 3)``, of WGS84 points with altitudes in metres AMSL."""
        north, east = self.ne_from_latlon(lat_deg, lon_deg)
        down = self._alt0_amsl_m - np.asarray(alt_amsl_m, dtype=np.float64)
        north, east, down = np.broadcast_arrays(north, east, down)
        return np.stack([north, east, down], axis=-1)

    def geodetic_from_ned(self, pos_ned_m: npt.ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(lat_deg, lon_deg, alt_amsl_m) arrays of NED positions given with shape ``(..., 3)``."""
        ned = np.asarray(pos_ned_m, dtype=np.float64)
        if ned.shape[-1:] != (3,):
            raise ValueError(f"NED positions need a last axis of length 3, got shape {ned.shape}")
        lat, lon = self.latlon_from_ne(ned[..., 0], ned[..., 1])
        return lat, lon, self._alt0_amsl_m - ned[..., 2]

    # ------------------------------------------------------------------------------------ scalar

    def to_ned(
        self, lat_deg: float, lon_deg: float, alt_amsl_m: float | None = None
    ) -> tuple[float, float, float]:
        """One WGS84 point to (north_m, east_m, down_m); without an altitude, down is 0 (home's height)."""
        east, north = self._to_local.transform(float(lon_deg), float(lat_deg))
        down = 0.0 if alt_amsl_m is None else self._alt0_amsl_m - float(alt_amsl_m)
        return float(north), float(east), down

    def to_geodetic(self, north_m: float, east_m: float, down_m: float = 0.0) -> tuple[float, float, float]:
        """One local point to (lat_deg, lon_deg, alt_amsl_m)."""
        lon, lat = self._to_geo.transform(float(east_m), float(north_m))
        return float(lat), float(lon), self._alt0_amsl_m - float(down_m)
