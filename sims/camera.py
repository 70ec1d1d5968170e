"""A downward camera that renders what a real one would see over flat ground.

The ground is a photograph tiled over the plane ``down = 0`` (home altitude) at a given scale: the
texture photographs scikit-image ships with its data (grass, gravel, brick; bundled, no download), or
generated scenes for the hard cases: ``water`` (almost no texture: smooth low-contrast ripples) and
``tiles`` (a strictly repetitive pattern). The image is the plane seen through the pinhole camera at the
vehicle's pose: the plane-to-image homography ``H = K [r1 r2 t]`` (Hartley & Zisserman 2004, sec. 8.1.1)
composed with the texture's metric scale, applied with one ``cv2.warpPerspective`` and wrapping borders.
On top: motion blur along the image motion during the exposure, a little defocus, vignetting, an
illumination gain that drifts, and sensor noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from merlin.nav.quaternion import dcm_from_euler
from merlin.vision.camera_model import R_BODY_CAM, CameraModel

PHOTO_TEXTURES = ("grass", "gravel", "brick")
SYNTHETIC_TEXTURES = ("water", "tiles")


@dataclass(frozen=True, slots=True)
class GroundTexture:
    name: str
    image: np.ndarray  # uint8, 2-D; tiles the ground plane
    m_per_px: float  # ground metres per texture pixel


def load_texture(name: str, m_per_px: float = 0.1, seed: int = 0) -> GroundTexture:
    """A ground texture by name: one of PHOTO_TEXTURES (scikit-image's bundled photographs) or
    SYNTHETIC_TEXTURES. Photographs are tiled with mirrored copies so the tiling has no seams."""
    if name in PHOTO_TEXTURES:
        from skimage import data

        img = np.asarray(getattr(data, name)(), dtype=np.uint8)
        img = np.block([[img, img[:, ::-1]], [img[::-1, :], img[::-1, ::-1]]])  # seamless 2x2 mirror tile
    elif name == "water":
        rng = np.random.default_rng(seed)
        noise = rng.normal(0.0, 1.0, (512, 512))
        # periodic low-pass (Gaussian in frequency, sigma ~12 px in space) so the tile has no seams
        fy = np.fft.fftfreq(512)[:, None]
        fx = np.fft.fftfreq(512)[None, :]
        ripples = np.real(
            np.fft.ifft2(np.fft.fft2(noise) * np.exp(-2.0 * (np.pi * 12.0) ** 2 * (fx**2 + fy**2)))
        )
        ripples *= 3.0 / max(1e-6, float(ripples.std()))  # about 3 grey levels of contrast
        img = np.clip(90.0 + ripples, 0, 255).astype(np.uint8)
    elif name == "tiles":
        period = 24
        yy, xx = np.mgrid[0:480, 0:480]
        grout = ((xx % period) < 3) | ((yy % period) < 3)
        img = np.where(grout, 60, 170).astype(np.uint8)
    else:
        raise ValueError(f"unknown texture {name!r}; allowed: {PHOTO_TEXTURES + SYNTHETIC_TEXTURES}")
    return GroundTexture(name, np.ascontiguousarray(img), m_per_px)


@dataclass(frozen=True, slots=True)
class CameraEffects:
    noise_sigma: float = 2.0  # grey levels, additive Gaussian
    exposure_s: float = 0.004  # motion blur length = image speed x exposure
    defocus_sigma_px: float = 0.5
    vignetting: float = 0.25  # brightness loss at the image corners
    gain_amplitude: float = 0.15  # illumination gain 1 ± amplitude ...
    gain_period_s: float = 20.0  # ... varying slowly (clouds)


class DownwardCamera:
    """Renders the ground under the vehicle. ``render`` is pure in the pose; noise comes from the
    generator passed in."""

    def __init__(
        self,
        texture: GroundTexture,
        model: CameraModel | None = None,
        effects: CameraEffects = CameraEffects(),
        rng: np.random.Generator | None = None,
    ) -> None:
        model = CameraModel() if model is None else model
        self.texture = texture
        self.model = model
        self.effects = effects
        self.rng = rng if rng is not None else np.random.default_rng(0)
        w, h = model.width_px, model.height_px
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        r2 = ((xx - model.cx_px) / (0.5 * w)) ** 2 + ((yy - model.cy_px) / (0.5 * h)) ** 2
        self._vignette = (1.0 - effects.vignetting * r2 / 2.0).astype(np.float32)

    def homography(self, pos_ned_m: np.ndarray, att_rpy_rad: tuple[float, float, float]) -> np.ndarray:
        """Texture pixel (col, row, 1) -> image pixel. Texture columns run east, rows run south."""
        tex = self.texture
        s = tex.m_per_px
        period_n = tex.image.shape[0] * s
        period_e = tex.image.shape[1] * s
        # the texture tiles the plane, so the camera may be moved by whole periods: keeps numbers small
        c = np.array(
            [math.fmod(pos_ned_m[0], period_n), math.fmod(pos_ned_m[1], period_e), pos_ned_m[2]], dtype=float
        )
        R_cn = (dcm_from_euler(*att_rpy_rad) @ R_BODY_CAM).T
        plane = np.column_stack([R_cn[:, 0], R_cn[:, 1], -R_cn @ c])  # (N, E, 1) -> camera
        tex_to_ne = np.array([[0.0, -s, 0.0], [s, 0.0, 0.0], [0.0, 0.0, 1.0]])  # (col, row, 1) -> (N, E, 1)
        return self.model.K() @ plane @ tex_to_ne

    def render(
        self,
        pos_ned_m: np.ndarray | tuple[float, float, float],
        att_rpy_rad: tuple[float, float, float],
        vel_ned_mps: np.ndarray | tuple[float, float, float] = (0.0, 0.0, 0.0),
        t_s: float = 0.0,
    ) -> np.ndarray:
        pos = np.asarray(pos_ned_m, dtype=float)
        if pos[2] >= -0.1:
            raise ValueError(f"camera height {-pos[2]:.2f} m: must be above the ground plane (down < 0)")
        m, fx = self.model, self.effects
        H = self.homography(pos, att_rpy_rad)
        img = cv2.warpPerspective(
            self.texture.image,
            H,
            (m.width_px, m.height_px),
            flags=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_WRAP,
        ).astype(np.float32)
        # motion blur: the ground moves at f v / h pixels per second in the image
        R_nc = dcm_from_euler(*att_rpy_rad) @ R_BODY_CAM
        v_cam = R_nc.T @ np.asarray(vel_ned_mps, dtype=float)
        blur_px = m.fx_px * fx.exposure_s * math.hypot(v_cam[0], v_cam[1]) / max(0.1, -pos[2])
        if blur_px >= 1.0:
            img = _motion_blur(img, blur_px, math.atan2(-v_cam[1], -v_cam[0]))
        if fx.defocus_sigma_px > 0.0:
            img = cv2.GaussianBlur(img, (0, 0), fx.defocus_sigma_px)
        gain = 1.0 + fx.gain_amplitude * math.sin(2.0 * math.pi * t_s / fx.gain_period_s)
        img = img * (gain * self._vignette)
        if fx.noise_sigma > 0.0:
            img += self.rng.normal(0.0, fx.noise_sigma, img.shape).astype(np.float32)
        return np.clip(img, 0.0, 255.0).astype(np.uint8)


def _motion_blur(img: np.ndarray, length_px: float, angle_rad: float) -> np.ndarray:
    n = math.ceil(length_px) | 1
    kernel = np.zeros((n, n), np.float32)
    c = n // 2
    for i in range(n):
        s = (i - c) * length_px / n
        x = c + s * math.cos(angle_rad)
        y = c + s * math.sin(angle_rad)
        kernel[round(y), round(x)] += 1.0
    kernel /= kernel.sum()
    return cv2.filter2D(img, -1, kernel, borderType=cv2.BORDER_REFLECT)
