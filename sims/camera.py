"""A downward camera that renders what a real one would see over flat ground.

The ground is a photograph tiled over the plane ``down = 0`` (home altitude) at a given scale: the
texture photographs scikit-image ships with its data (grass, gravel, brick; bundled, no download), or
generated scenes for the hard cases: ``water`` (almost no texture: smooth low-contrast ripples) and
``tiles`` (a strictly repetitive pattern). The image is the plane seen through the pinhole camera at the
vehicle's pose: the plane-to-image homography ``H = K [r1 r2 t]`` (Hartley & Zisserman 2004, sec. 8.1.1)
composed with the texture's metric scale, applied with one ``cv2.warpPerspective``.
On top: motion blur along the image motion during the exposure, a little defocus, vignetting, an
illumination gain that drifts, and sensor noise.

Cost (the camera renders every frame of every camera run): the texture's pyramid is built once
(``cv2.pyrDown`` with wrapped borders) and the coarsest level whose pixel is not larger than the centre image
pixel's footprint on the ground is warped, which is also the anti-aliasing a real lens gives; the warp reads
only the visible footprint, a plain slice of the texture tiled 2×2 or more (no wrapping in the inner loop)
unless the footprint is wider than the tiling less one period. The sensor noise is a bank of Gaussian samples drawn once from the
camera's generator, read each frame at an offset drawn from that generator: seeded and deterministic, a
fresh-looking field every frame, at the cost of an add instead of 76,800 normal draws.
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


def _photo(name: str) -> np.ndarray:
    """scikit-image's bundled photograph ``name`` as 2-D uint8, read with OpenCV: the same pixels as
    ``skimage.data.<name>()`` (lossless PNG; tests/vision/test_vision_camera.py compares them) without importing
    scikit-image's image I/O, about a second of a process's start on a 2-core machine that every run with a
    camera, and `merlin serve`, paid. A scikit-image that does not ship the file gets its own loader."""
    from importlib.resources import files

    path = files("skimage") / "data" / f"{name}.png"
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED) if path.is_file() else None
    if img is None or img.ndim != 2:
        from skimage import data

        img = getattr(data, name)()
    return np.asarray(img, dtype=np.uint8)


def load_texture(name: str, m_per_px: float = 0.1, seed: int = 0) -> GroundTexture:
    """A ground texture by name: one of PHOTO_TEXTURES (scikit-image's bundled photographs) or
    SYNTHETIC_TEXTURES. Photographs are tiled with mirrored copies so the tiling has no seams."""
    if name in PHOTO_TEXTURES:
        img = _photo(name)
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


def _texture_pyramid(image: np.ndarray, min_side: int = 64) -> list[np.ndarray]:
    """Levels of the tiling texture, each halved with the borders wrapped (the texture is periodic), kept
    while both sides stay even (so each level still tiles) and at least ``min_side``."""
    levels = [image]
    pad = 4
    while True:
        top = levels[-1]
        h, w = top.shape
        if h % 2 or w % 2 or h // 2 < min_side or w // 2 < min_side:
            return levels
        half = cv2.pyrDown(np.pad(top, pad, mode="wrap"))
        q = pad // 2  # the padding, halved
        levels.append(np.ascontiguousarray(half[q : q + h // 2, q : q + w // 2]))


# Offsets into the noise bank are drawn per frame; a bank twice the image in each direction gives
# (h+1)(w+1) distinct fields.
_NOISE_BANK_SCALE = 2
# The side of each texture level once tiled (DownwardCamera._levels), in level-0 pixels
_TILED_SIDE_PX = 2048


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
        # each level tiled n x n, so that any footprint up to n - 1 periods is a plain slice: 2x2 for the
        # photographs (a 102 m period at 0.1 m per pixel), more for the small synthetic textures (water's
        # 51 m and the tiles' 48 m period are narrower than a 320x240 footprint from 30 m, which would
        # otherwise take the slower wrapped warp), up to the same 2048-pixel side
        self._reps = max(2, math.ceil(_TILED_SIDE_PX / max(texture.image.shape)))
        self._levels = [np.tile(lv, (self._reps, self._reps)) for lv in _texture_pyramid(texture.image)]
        self._noise = (
            self.rng.standard_normal((_NOISE_BANK_SCALE * h, _NOISE_BANK_SCALE * w), dtype=np.float32)
            * np.float32(effects.noise_sigma)
            if effects.noise_sigma > 0.0
            else None
        )
        # the image's corners, then its centre pixel and its two neighbours (for the ground resolution)
        self._corners = np.array(
            [[0.0, 0.0], [w, 0.0], [w, h], [0.0, h],
             [model.cx_px, model.cy_px], [model.cx_px + 1.0, model.cy_px], [model.cx_px, model.cy_px + 1.0]],
            np.float64,
        )

    def homography(self, pos_ned_m: np.ndarray, att_rpy_rad: tuple[float, float, float]) -> np.ndarray:
        """Texture pixel (col, row, 1) -> image pixel. Texture columns run east, rows run south."""
        return self._homography(pos_ned_m, dcm_from_euler(*att_rpy_rad))

    def _homography(self, pos_ned_m: np.ndarray, R_nb: np.ndarray) -> np.ndarray:
        tex = self.texture
        s = tex.m_per_px
        period_n = tex.image.shape[0] * s
        period_e = tex.image.shape[1] * s
        # the texture tiles the plane, so the camera may be moved by whole periods: keeps numbers small
        c = np.array(
            [math.fmod(pos_ned_m[0], period_n), math.fmod(pos_ned_m[1], period_e), pos_ned_m[2]], dtype=float
        )
        R_cn = (R_nb @ R_BODY_CAM).T
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
        R_nb = dcm_from_euler(*att_rpy_rad)
        H = self._homography(pos, R_nb)
        img = self._warp(H)
        # motion blur: the ground moves at f v / h pixels per second in the image
        R_nc = R_nb @ R_BODY_CAM
        v_cam = R_nc.T @ np.asarray(vel_ned_mps, dtype=float)
        blur_px = m.fx_px * fx.exposure_s * math.hypot(v_cam[0], v_cam[1]) / max(0.1, -pos[2])
        if blur_px >= 1.0:
            img = _motion_blur(img, blur_px, math.atan2(-v_cam[1], -v_cam[0]))
        if fx.defocus_sigma_px > 0.0:
            # OpenCV would size the kernel 5x5 at the default 0.5 px, whose outer taps weigh 3e-4 of the
            # sum (below a grey level): 3x3 up to 0.5 px (OpenCV's fast 8-bit path), ±3 sigma beyond
            k = 3 if fx.defocus_sigma_px <= 0.5 else 2 * math.ceil(3.0 * fx.defocus_sigma_px) + 1
            img = cv2.GaussianBlur(img, (k, k), fx.defocus_sigma_px)
        gain = 1.0 + fx.gain_amplitude * math.sin(2.0 * math.pi * t_s / fx.gain_period_s)
        # vignetting and gain in one pass to float, then the noise added with the clip to 0..255 and the
        # rounding to 8 bits in one saturating pass (each step a whole-image pass: most of the cost left
        # after the warp)
        lit = cv2.multiply(img, self._vignette, scale=gain, dtype=cv2.CV_32F)
        if self._noise is None:
            return np.clip(np.rint(lit), 0.0, 255.0).astype(np.uint8)
        oy = int(self.rng.integers(0, self._noise.shape[0] - m.height_px + 1))
        ox = int(self.rng.integers(0, self._noise.shape[1] - m.width_px + 1))
        out: np.ndarray = cv2.add(lit, self._noise[oy : oy + m.height_px, ox : ox + m.width_px], dtype=cv2.CV_8U)
        return out

    def _warp(self, H: np.ndarray) -> np.ndarray:
        """The plane under the camera (``H``: texture level-0 pixel -> image pixel), warped from the visible
        footprint of the pyramid level matching the image's ground resolution."""
        m = self.model
        base = self.texture.image
        Hinv = np.linalg.inv(H)
        pts = cv2.perspectiveTransform(self._corners.reshape(-1, 1, 2), Hinv).reshape(-1, 2)
        corners, (c, cx, cy) = pts[:4], pts[4:]
        # texture pixels per image pixel at the image centre (the area of the centre pixel's footprint)
        (ax, ay), (bx, by) = (cx - c).tolist(), (cy - c).tolist()
        span = math.sqrt(abs(ax * by - ay * bx))  # the 2-D cross product, as np.cross evaluates it
        level = 0
        while level + 1 < len(self._levels) and span >= 2.0 ** (level + 1):
            level += 1
        f = 2.0**-level
        src = self._levels[level]
        ph, pw = base.shape[0] >> level, base.shape[1] >> level
        # level pixel centres sit at (x + 0.5) / 2^level - 0.5 of level 0 (pyrDown's sampling)
        to_level = np.array([[f, 0.0, 0.5 * f - 0.5], [0.0, f, 0.5 * f - 0.5], [0.0, 0.0, 1.0]])
        lc = corners * f + (0.5 * f - 0.5)
        size = (m.width_px, m.height_px)
        if not np.isfinite(lc).all() or np.abs(lc).max() > 1e7:
            return self._wrap_warp(src, ph, pw, H, to_level)
        x0 = math.floor(float(lc[:, 0].min())) - 2
        y0 = math.floor(float(lc[:, 1].min())) - 2
        x1 = math.ceil(float(lc[:, 0].max())) + 3
        y1 = math.ceil(float(lc[:, 1].max())) + 3
        if x1 - x0 > (self._reps - 1) * pw or y1 - y0 > (self._reps - 1) * ph:
            return self._wrap_warp(src, ph, pw, H, to_level)
        sx, sy = x0 % pw, y0 % ph
        # crop pixel = level pixel - (x0, y0): the level is periodic, so the slice from (sx, sy) is it
        crop = src[sy : sy + (y1 - y0), sx : sx + (x1 - x0)]
        shift = np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]])
        # image pixel -> crop pixel, given as the inverse map so OpenCV need not invert it
        return cv2.warpPerspective(
            crop, shift @ to_level @ Hinv, size, flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
            borderMode=cv2.BORDER_REPLICATE,
        )

    def _wrap_warp(
        self, src: np.ndarray, ph: int, pw: int, H: np.ndarray, to_level: np.ndarray
    ) -> np.ndarray:
        """The footprint spans more than a period (very high, or looking near the horizon): the whole
        level with wrapped borders."""
        m = self.model
        return cv2.warpPerspective(
            np.ascontiguousarray(src[:ph, :pw]), to_level @ np.linalg.inv(H), (m.width_px, m.height_px),
            flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_WRAP,
        )


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
