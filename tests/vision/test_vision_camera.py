"""The simulated downward camera: geometry of the rendering and its effects."""

from __future__ import annotations

import math

import numpy as np
import pytest

from merlin.vision.camera_model import CameraModel
from sims.camera import PHOTO_TEXTURES, CameraEffects, DownwardCamera, load_texture

NO_EFFECTS = CameraEffects(
    noise_sigma=0.0, exposure_s=0.0, defocus_sigma_px=0.0, vignetting=0.0, gain_amplitude=0.0
)


def test_bundled_textures_load_offline():
    for name in PHOTO_TEXTURES:
        tex = load_texture(name)
        assert tex.image.dtype == np.uint8 and tex.image.ndim == 2 and tex.image.std() > 10


@pytest.mark.parametrize("name", PHOTO_TEXTURES)
def test_a_photograph_read_with_opencv_is_scikit_images_own_pixel_for_pixel(name):
    from skimage import data

    ours = load_texture(name).image
    theirs = np.asarray(getattr(data, name)(), dtype=np.uint8)
    tile = np.block([[theirs, theirs[:, ::-1]], [theirs[::-1, :], theirs[::-1, ::-1]]])
    assert ours.shape == tile.shape and np.array_equal(ours, tile)


def test_unknown_texture_names_the_allowed_ones():
    with pytest.raises(ValueError, match="grass"):
        load_texture("lava")


@pytest.mark.parametrize("att", [(0.0, 0.0, 0.0), (0.2, -0.1, 2.0)])
def test_homography_maps_a_ground_point_to_its_projection(att):
    cam = DownwardCamera(load_texture("gravel"), CameraModel(), NO_EFFECTS)
    pos = np.array([3.0, -4.0, -25.0])
    H = cam.homography(pos, att)
    s = cam.texture.m_per_px
    # a ground point 2 m north, 1 m east of the vehicle, in texture pixels (columns east, rows south)
    n, e = (
        math.fmod(pos[0], cam.texture.image.shape[0] * s) + 2.0,
        math.fmod(pos[1], cam.texture.image.shape[1] * s) + 1.0,
    )
    tex_px = np.array([e / s, -n / s, 1.0])
    img = H @ tex_px
    img = img[:2] / img[2]
    # the same point through the pinhole model directly
    from merlin.nav.quaternion import dcm_from_euler
    from merlin.vision.camera_model import R_BODY_CAM

    R_cn = (dcm_from_euler(*att) @ R_BODY_CAM).T
    xc = R_cn @ np.array([2.0, 1.0, 25.0])
    expected = CameraModel().K() @ (xc / xc[2])
    assert np.allclose(img, expected[:2], atol=1e-6)


def test_level_camera_sees_north_up_and_east_right():
    # moving the camera north must shift the image down (ground features move to the back)
    cam = DownwardCamera(load_texture("gravel"), CameraModel(160, 120), NO_EFFECTS)
    a = cam.render((0.0, 0.0, -20.0), (0.0, 0.0, 0.0)).astype(float)
    gsd = CameraModel(160, 120).ground_sample_distance_m(20.0)
    b = cam.render((3 * gsd, 0.0, -20.0), (0.0, 0.0, 0.0)).astype(float)
    assert (
        np.abs(a[10:-10, 10:-10] - b[13:-7, 10:-10]).mean()
        < np.abs(a[10:-10, 10:-10] - b[7:-13, 10:-10]).mean()
    )


def test_effects_change_the_image_and_noise_is_seeded():
    tex = load_texture("grass")
    clean = DownwardCamera(tex, CameraModel(160, 120), NO_EFFECTS).render((0, 0, -30), (0, 0, 0))
    n1 = DownwardCamera(tex, CameraModel(160, 120), CameraEffects(), np.random.default_rng(5)).render(
        (0, 0, -30), (0, 0, 0), (10, 0, 0), 3.0
    )
    n2 = DownwardCamera(tex, CameraModel(160, 120), CameraEffects(), np.random.default_rng(5)).render(
        (0, 0, -30), (0, 0, 0), (10, 0, 0), 3.0
    )
    assert np.array_equal(n1, n2)
    assert np.abs(n1.astype(float) - clean).mean() > 2.0


def test_camera_below_ground_is_refused():
    cam = DownwardCamera(load_texture("grass"))
    with pytest.raises(ValueError, match="above the ground"):
        cam.render((0.0, 0.0, 1.0), (0.0, 0.0, 0.0))


def _full_wrapped_warp(cam: DownwardCamera, pos: np.ndarray, att: tuple[float, float, float]) -> np.ndarray:
    """The reference rendering: the whole level-0 texture warped with wrapped borders."""
    import cv2

    m = cam.model
    return cv2.warpPerspective(
        cam.texture.image, cam.homography(pos, att), (m.width_px, m.height_px),
        flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP,
    )


@pytest.mark.parametrize("texture", ["grass", "tiles", "water"])
@pytest.mark.parametrize(
    ("pos", "att"),
    [
        ((0.0, 0.0, -10.0), (0.0, 0.0, 0.0)),
        ((123.4, -77.7, -30.0), (0.1, -0.2, 0.7)),  # the footprint straddles the texture's period
        ((-51.15, 102.35, -20.0), (-0.3, 0.25, -2.5)),
    ],
)
def test_the_footprint_warp_equals_the_whole_texture_warp(texture, pos, att):
    """Below the first pyramid level the cropped-footprint warp is the wrapped warp of the whole texture
    (the crop is only a cheaper way to read the same texels): equal but for one grey level on under 0.5 %
    of the pixels, where the inverse map's rounding differs from the one OpenCV computes itself."""
    cam = DownwardCamera(load_texture(texture, seed=3), CameraModel(), NO_EFFECTS)
    p = np.array(pos)
    d = np.abs(cam.render(p, att).astype(int) - _full_wrapped_warp(cam, p, att).astype(int))
    assert d.max() <= 1 and (d > 0).mean() < 0.005


def test_a_high_camera_reads_a_coarser_pyramid_level_without_aliasing():
    """At 150 m a 320x240 image pixel covers ~6 texture pixels: the plain warp aliases (the contrast of
    the texture survives as noise), the pyramid level averages it as a lens would."""
    cam = DownwardCamera(load_texture("tiles"), CameraModel(), NO_EFFECTS)
    pos, att = np.array([5.0, 7.0, -150.0]), (0.0, 0.0, 0.3)
    smooth, aliased = cam.render(pos, att), _full_wrapped_warp(cam, pos, att)
    assert smooth.std() < 0.8 * aliased.std()
    # the average brightness (the tiles' mean grey) is kept
    assert abs(float(smooth.mean()) - float(cam.texture.image.mean())) < 5.0


def test_sensor_noise_is_seeded_fresh_each_frame_and_of_the_configured_sigma():
    fx = CameraEffects(noise_sigma=2.0, exposure_s=0.0, defocus_sigma_px=0.0, vignetting=0.0,
                       gain_amplitude=0.0)
    tex = load_texture("water", seed=1)
    pos, att = np.array([1.0, 2.0, -15.0]), (0.0, 0.0, 0.0)

    def frames(seed: int) -> list[np.ndarray]:
        cam = DownwardCamera(tex, CameraModel(), fx, np.random.default_rng(seed))
        return [cam.render(pos, att).astype(float) for _ in range(3)]

    a, b, c = frames(7), frames(7), frames(8)
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))  # deterministic in the seed
    assert not np.array_equal(a[0], c[0])
    clean = _full_wrapped_warp(DownwardCamera(tex, CameraModel(), NO_EFFECTS), pos, att).astype(float)
    noise = [f - clean for f in a]
    for n in noise:
        assert 1.7 < n.std() < 2.3
    # consecutive frames carry different noise fields, not the same one again
    assert abs(float(np.corrcoef(noise[0].ravel(), noise[1].ravel())[0, 1])) < 0.1
