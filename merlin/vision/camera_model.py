"""The downward camera's geometry, shared by the VO pipeline and the simulator's renderer.

Pinhole model without distortion (the renderer produces undistorted images; a real camera's images are
undistorted with its calibration before they reach the pipeline). Camera frame as in OpenCV: x right, y
down in the image, z along the optical axis. The camera looks straight down: optical axis = body down,
image right = body right, image up = body forward (Hartley & Zisserman 2004, "Multiple View Geometry",
sec. 6.1 for the model).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# columns: the camera axes expressed in body FRD (camera -> body rotation)
R_BODY_CAM = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
R_BODY_CAM.setflags(write=False)


@dataclass(frozen=True, slots=True)
class CameraModel:
    width_px: int = 320
    height_px: int = 240
    hfov_rad: float = math.radians(70.0)

    @property
    def fx_px(self) -> float:
        return 0.5 * self.width_px / math.tan(0.5 * self.hfov_rad)

    @property
    def fy_px(self) -> float:
        return self.fx_px  # square pixels

    @property
    def cx_px(self) -> float:
        return 0.5 * (self.width_px - 1)

    @property
    def cy_px(self) -> float:
        return 0.5 * (self.height_px - 1)

    def K(self) -> np.ndarray:
        return np.array([[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0.0, 0.0, 1.0]])

    def ground_sample_distance_m(self, height_m: float) -> float:
        """Metres of ground per pixel at the image centre, looking straight down."""
        return height_m / self.fx_px
