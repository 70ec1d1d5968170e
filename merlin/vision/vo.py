"""Downward monocular visual odometry: NED velocity over flat ground, with its covariance and its quality.

The pipeline for each new frame (Scaramuzza & Fraundorfer 2011, "Visual odometry [tutorial]", IEEE RAM
18(4), the paper's reference 3; structure as in their Algorithm 1, feature-based, 2-D to 2-D):

1. Features: FAST corners (Rosten & Drummond 2006) with an *absolute* intensity threshold, kept
   strongest-first on a grid so they cover the image. The absolute threshold is what lets the pipeline
   say "I cannot see": a relative threshold (Shi-Tomasi quality level) finds "corners" in sensor noise
   over water. ``texture_score`` = the fraction of grid cells that hold a corner. Features are tracked
   on from frame to frame rather than detected in every frame (feature tracking as against matching,
   Fraundorfer & Scaramuzza 2012, the tutorial's part II, IEEE RAM 19(2)) and detected again only when
   too few survive (``VoConfig.redetect_fraction``); the texture and repetition scores are those of the
   last detection.
2. Tracking: pyramidal Lucas-Kanade (Bouguet 2000) from the previous to the current frame, started at the
   position predicted by the gyro-integrated rotation (and the prior velocity, if given), with a
   forward-backward check (Kalal et al. 2010) that discards tracks which do not return to their origin.
   With a velocity prior the residual motion is a fraction of the window and no pyramid level is built.
3. De-rotation and metric scale: each tracked pixel is turned into a ray, rotated into NED with the
   attitude at its frame (which removes the camera's rotation between frames), and intersected with the
   ground plane at the height above ground. A ground point seen at unit-height offsets ``u1``, ``u2``
   from the two camera positions satisfies ``h1 u1 = Δ + h2 u2``: three unknowns, the horizontal
   displacement ``Δ`` and the new height ``h2`` (vertical motion from the scale change).
4. Geometric verification with that model (the ground is a plane and the rotation is the gyro's, so a
   homography's eight unknowns are not needed; Hartley & Zisserman 2004, sec. 8.1.1 and 13.1): a robust
   start at the median displacement, inliers by reprojection error in two rounds, least squares on the
   inliers; the residuals give the covariance. The covariance adds the scale error from the height's
   uncertainty and the yaw uncertainty's rotation of the velocity.

The quality fields follow the paper's demand for "measures of accuracy ... based on computer vision
theory"; when any is outside its limit the sample is marked invalid with an uninformative covariance,
never a confident wrong answer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from merlin.measurements import VoQuality, VoSample
from merlin.nav.quaternion import dcm_from_euler, quat_to_dcm
from merlin.vision.camera_model import R_BODY_CAM, CameraModel

_INVALID_COV = (1.0e6, 1.0e6, 1.0e6)


@dataclass(frozen=True, slots=True)
class VoConfig:
    fast_threshold: int = 20  # absolute grey-level difference of a FAST corner
    # A low-contrast photograph (the brick, seen from 10 m at 160x120) gives fewer than 30 corners at
    # fast_threshold, and the filter refuses a frame under 25 (NavConfig.vo_min_features): VO was lost over
    # brick and a GPS spoof there went unseen (docs/navigation.md, "VO over brick"). When fewer than
    # relax_below_features corners are kept, the frame is detected again with the threshold lowered to
    # fast_noise_k times the image's own noise sigma (Immerkaer 1996), never below fast_threshold_min:
    # still far above what sensor noise can fake (a FAST arc of 9 pixels all beyond 5 sigma), so the
    # "I cannot see" answer over water stands.
    relax_below_features: int = 60
    fast_noise_k: float = 5.0
    fast_threshold_min: int = 8
    grid_cols: int = 8
    grid_rows: int = 6
    per_cell: int = 3  # strongest corners kept per grid cell
    # At most this many corners are tracked (tracking is the costliest step and scales with them): the
    # strongest of every cell first, then the second strongest, and so on. Sparse scenes (the brick from
    # 10 m: 30-45 corners) keep them all; rich ones (grass: 144 after the grid) lose the weakest.
    max_tracked: int = 72
    # Tracks carry over: the inliers of one frame pair are the next pair's features, and the frame's
    # corners are detected again (FAST, the grid, the texture score) when fewer than redetect_fraction of
    # the last detection's corners survive (points leave the image, fail the forward-backward check or the
    # geometric test) or fewer than redetect_below; every redetect_every frames both the corners and the
    # repetition score are measured afresh. Detection and the repetition test were ~30 % of a frame's cost.
    # The filter weighs VO by its inlier count (NavConfig.vo_min_features 25 .. vo_good_features 80), so
    # the carried set is kept large: grass keeps 62-72 tracks of 72, and a sparse scene (the brick from
    # 10 m: 30-45 corners) has its corners detected every frame as before. The age limit bounds how stale
    # the scene's scores are and lets a climb or a turn that brings new texture into view be seen: the
    # takeoff's few corners from 1 m up are not tracked on into the hover (found in gps_loss_vo: 23
    # features, under the filter's 25, for 10 s).
    redetect_fraction: float = 0.85
    redetect_below: int = 40
    redetect_every: int = 6
    lk_window_px: int = 11
    lk_levels: int = 1
    fb_max_px: float = 0.5  # forward-backward disagreement tolerated
    ransac_px: float = 1.5
    min_height_m: float = 1.0  # below this the flat-ground model and the scale are too poor
    # validity limits (the filter applies its own, typically stricter, ones on top: NavConfig.vo_*)
    min_features: int = 20
    min_inlier_ratio: float = 0.5
    max_reprojection_px: float = 1.5
    min_texture_score: float = 0.25
    # Relative error of the height above ground beyond the filter's altitude error, which the filter models
    # itself: terrain that is not the flat plane at home altitude.
    height_rel_sigma: float = 0.01
    # Extra variance for an attitude error that rotates the measured velocity. 0 when the attitude given is
    # the navigation filter's own: the filter models that coupling itself (NavEstimator.update_vo).
    yaw_sigma_rad: float = 0.0
    pixel_sigma_floor_px: float = 0.15  # tracking noise never assumed below this
    # The gyro's angle random walk over one frame interval rotates every ray alike: a common ground shift
    # of h·σ_Δθ that the residual scatter cannot see. Set to the IMU's gyro noise density.
    gyro_noise_radps_rthz: float = 1.0e-3
    # Repetitive scenes: the largest normalised autocorrelation peak of the image outside its central lobe
    # (within ±repetition_window_px). Above max_repetition the frame-to-frame motion is ambiguous by a
    # period; the sample is then valid only if a velocity prior predicts the motion to within a third of
    # the period (prior_sigma_mps is the prior's assumed 1-sigma error).
    max_repetition: float = 0.7
    repetition_window_px: int = 48
    prior_sigma_mps: float = 1.0


@dataclass(frozen=True, slots=True)
class _Frame:
    t_s: float
    image: np.ndarray
    R_nb: np.ndarray
    R_gyro: np.ndarray | None  # gyro-integrated attitude (arbitrary reference) at this frame
    height_m: float
    points: np.ndarray  # (n, 1, 2) float32 FAST corners of this frame
    texture_score: float
    repetition: float
    period_px: float  # shortest repetition period found (inf when not repetitive)
    detected: int  # corners found by the last detection (this frame's or the one its tracks came from)
    age: int  # frames since the repetition score was measured (and, for carried tracks, since detection)


class VisualOdometry:
    """Frame-to-frame VO. Call :meth:`process` with each frame in time order."""

    def __init__(self, model: CameraModel | None = None, config: VoConfig = VoConfig()) -> None:
        model = CameraModel() if model is None else model
        self.model = model
        self.cfg = config
        self._K = model.K()
        self._Kinv = np.linalg.inv(self._K)
        self._fast = cv2.FastFeatureDetector_create(threshold=config.fast_threshold, nonmaxSuppression=True)
        self._prev: _Frame | None = None
        self._hann: np.ndarray | None = None
        self._shift_key: tuple[int, int, int] | None = None
        self._shift_rc: tuple[np.ndarray, np.ndarray] = (np.zeros((0, 1), np.intp), np.zeros((1, 0), np.intp))
        self._lk = {
            "winSize": (config.lk_window_px, config.lk_window_px),
            "criteria": (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 10, 0.03),
        }

    def reset(self) -> None:
        self._prev = None

    def _detect(self, image: np.ndarray) -> tuple[np.ndarray, float]:
        cfg = self.cfg
        pts, score = self._detect_at(image, self._fast)
        if len(pts) < cfg.relax_below_features:
            low = max(cfg.fast_threshold_min, math.ceil(cfg.fast_noise_k * noise_sigma(image)))
            if low < cfg.fast_threshold:
                relaxed = cv2.FastFeatureDetector_create(threshold=low, nonmaxSuppression=True)
                pts2, score2 = self._detect_at(image, relaxed)
                if len(pts2) > len(pts):
                    return pts2, score2
        return pts, score

    def _detect_at(self, image: np.ndarray, fast: cv2.FastFeatureDetector) -> tuple[np.ndarray, float]:
        cfg = self.cfg
        kps = fast.detect(image, None)
        h, w = image.shape
        if not kps:
            return np.zeros((0, 1, 2), np.float32), 0.0
        pts = cv2.KeyPoint_convert(kps)
        # strength order: the detector's score (FAST's response) read through the keypoint objects is
        # the costliest step in Python; the smoothed Laplacian magnitude at the corner ranks them alike
        resp = self._strength(image, pts)
        margin = cfg.lk_window_px // 2
        keep = (
            (pts[:, 0] >= margin)
            & (pts[:, 1] >= margin)
            & (pts[:, 0] < w - margin)
            & (pts[:, 1] < h - margin)
        )
        pts, resp = pts[keep], resp[keep]
        col = np.minimum((pts[:, 0] * cfg.grid_cols / w).astype(np.int64), cfg.grid_cols - 1)
        row = np.minimum((pts[:, 1] * cfg.grid_rows / h).astype(np.int64), cfg.grid_rows - 1)
        cell = row * cfg.grid_cols + col
        order = np.lexsort((-resp, cell))  # by cell, strongest first within a cell
        cell_sorted = cell[order]
        first = np.searchsorted(cell_sorted, cell_sorted, side="left")
        rank = np.arange(len(order)) - first
        keep_rank = rank < cfg.per_cell
        chosen = order[keep_rank]
        if len(chosen) > cfg.max_tracked:
            # round by round over the cells (stable: within a round, cell order)
            chosen = chosen[np.argsort(rank[keep_rank], kind="stable")[: cfg.max_tracked]]
        n_cells = cfg.grid_cols * cfg.grid_rows
        score = np.count_nonzero(np.bincount(cell, minlength=n_cells)) / float(n_cells)
        return np.ascontiguousarray(pts[chosen], dtype=np.float32).reshape(-1, 1, 2), score

    def _repetition(self, image: np.ndarray) -> tuple[float, float]:
        """(peak, period_px): the highest local maximum of the normalised autocorrelation outside the
        central lobe (the connected region around zero shift above 0.5) within the search window, on the half-resolution
        image (Wiener-Khinchin: the autocorrelation is the inverse transform of the power spectrum)."""
        small = cv2.pyrDown(image).astype(np.float32)
        small -= float(small.mean())
        h, w = small.shape
        if self._hann is None or self._hann.shape != small.shape:
            self._hann = cv2.createHanningWindow((w, h), cv2.CV_32F)
        x = small * self._hann
        spec = cv2.dft(x, flags=cv2.DFT_COMPLEX_OUTPUT)
        ac = cv2.idft(cv2.mulSpectrums(spec, spec, 0, conjB=True), flags=cv2.DFT_REAL_OUTPUT | cv2.DFT_SCALE)
        zero = float(ac[0, 0])
        if zero <= 0.0:
            return 0.0, math.inf
        r = min(self.cfg.repetition_window_px // 2, h // 2 - 1, w // 2 - 1)
        # shifts −r..r around zero, read with wrapped indices (the crop of np.fft.fftshift(ac), without
        # shifting the whole array)
        rows, cols = self._shift_index(h, w, r)
        ac = ac[rows, cols] / zero
        _, labels = cv2.connectedComponents((ac > 0.5).astype(np.uint8))
        is_peak = ac >= cv2.dilate(ac, np.ones((3, 3), np.uint8))
        outside = (labels != labels[r, r]) & is_peak
        if not outside.any():
            return 0.0, math.inf
        masked = np.where(outside, ac, -1.0)
        k = int(np.argmax(masked))
        peak = float(masked.flat[k])
        dy, dx = divmod(k, 2 * r + 1)
        return peak, 2.0 * math.hypot(dy - r, dx - r)

    def _shift_index(self, h: int, w: int, r: int) -> tuple[np.ndarray, np.ndarray]:
        """Row and column indices (as an open mesh) of the shifts −r..r of an h×w circular
        autocorrelation, cached per shape."""
        key = (h, w, r)
        if self._shift_key != key:
            k = np.arange(-r, r + 1)
            self._shift_rc = ((k % h)[:, None], (k % w)[None, :])
            self._shift_key = key
        return self._shift_rc

    @staticmethod
    def _strength(image: np.ndarray, pts: np.ndarray) -> np.ndarray:
        xi = pts[:, 0].astype(np.intp)
        yi = pts[:, 1].astype(np.intp)
        lap = cv2.Laplacian(image, cv2.CV_16S, ksize=3)
        return np.abs(lap[yi, xi]).astype(np.float32)

    def _unit_ground(self, pts: np.ndarray, R_nb: np.ndarray) -> np.ndarray:
        """Pixels -> ground offsets (north, east) per metre of height, via the NED ray."""
        M = R_nb @ R_BODY_CAM @ self._Kinv
        xy = pts.reshape(-1, 2).astype(np.float64)
        rays = xy @ M[:, :2].T + M[:, 2]
        down = np.maximum(rays[:, 2], 1e-6)
        return rays[:, :2] / down[:, None]

    def _project(self, offsets_ned: np.ndarray, R_nb: np.ndarray) -> np.ndarray:
        """NED vectors from the camera -> pixels."""
        cam = (R_BODY_CAM.T @ R_nb.T @ offsets_ned.T).T
        pix = (self._K @ (cam / cam[:, 2:3]).T).T
        return pix[:, :2]

    def process(
        self,
        image: np.ndarray,
        t_s: float,
        att_rpy_rad: tuple[float, float, float],
        height_m: float,
        vel_prior_ned_mps: tuple[float, float, float] | None = None,
        gyro_att: tuple[float, float, float, float] | None = None,
    ) -> VoSample:
        """One frame: ``image`` uint8 grey, ``att_rpy_rad`` the vehicle attitude at the frame (from the
        filter: the gyro-integrated rotation between frames is what matters), ``height_m`` the height
        above the ground. ``vel_prior_ned_mps`` only seeds the tracker (it never enters the output).

        ``gyro_att`` is the attitude quaternion integrated from the gyro alone (any reference, never
        corrected by measurement updates; ``NavEstimator.gyro_attitude``). When given, the rotation
        between two frames is taken from it and only the previous frame's absolute attitude is used: the
        small jumps a filter's attitude makes at its updates would otherwise look like motion (a 0.1°
        tilt step at 30 m is 5 cm of apparent ground shift, 1 m/s at 20 Hz)."""
        cfg = self.cfg
        if image.ndim != 2 or image.dtype != np.uint8:
            raise ValueError(f"image must be 2-D uint8, got shape {image.shape} dtype {image.dtype}")
        R_nb = dcm_from_euler(*att_rpy_rad)
        R_gyro = None if gyro_att is None else quat_to_dcm(gyro_att)
        prev = self._prev
        if prev is None or t_s <= prev.t_s:
            frame = self._prev = self._detected(t_s, image, R_nb, R_gyro, height_m)
            return _invalid(t_s, VoQuality(features=len(frame.points), texture_score=frame.texture_score))
        dt = t_s - prev.t_s
        R_now = R_nb
        if R_gyro is not None and prev.R_gyro is not None:
            # this frame's attitude = the previous frame's, turned by the gyro's rotation in between
            R_now = prev.R_nb @ (prev.R_gyro.T @ R_gyro)
        # the scene's scores are those of the frame whose features are tracked (carried with the tracks)
        texture = prev.texture_score
        refused = self._refused(prev, t_s, dt, texture, height_m, vel_prior_ned_mps)
        if refused is not None:
            self._prev = self._detected(t_s, image, R_nb, R_gyro, height_m, prev)
            return refused
        p0 = prev.points
        n0 = p0.shape[0]
        g1 = prev.height_m * self._unit_ground(p0, prev.R_nb)  # ground under each feature, from camera 1
        guess = self._predicted(prev, g1, R_now, vel_prior_ned_mps, dt)
        p1, ok = self._track(prev, image, guess, self._lk_max_level(prev, vel_prior_ned_mps, dt))
        tracked = int(ok.sum())
        if tracked < max(cfg.min_features, 8):
            self._prev = self._detected(t_s, image, R_nb, R_gyro, height_m, prev)
            return _invalid(
                t_s, VoQuality(features=tracked, inlier_ratio=tracked / n0, texture_score=texture)
            )
        b = p1[ok]
        fit = self._fit(prev, R_now, g1[ok], b, vel_prior_ned_mps, dt)
        if fit is None:
            self._prev = self._detected(t_s, image, R_nb, R_gyro, height_m, prev)
            return _invalid(t_s, VoQuality(features=0, texture_score=texture))
        inl, sol, AtA_inv, resid_m, reproj = fit
        n_in = int(inl.sum())
        ratio = n_in / float(n0)
        quality = VoQuality(n_in, ratio, reproj, texture, False, prev.repetition)
        if n_in < cfg.min_features or ratio < cfg.min_inlier_ratio or reproj > cfg.max_reprojection_px:
            self._prev = self._detected(t_s, image, R_nb, R_gyro, height_m, prev)
            return _invalid(t_s, quality)
        self._prev = self._carried(prev, t_s, image, R_nb, R_gyro, height_m, b[inl])
        return self._velocity(t_s, prev, sol, AtA_inv, resid_m, dt, quality)

    def _detected(self, t_s: float, image: np.ndarray, R_nb: np.ndarray, R_gyro: np.ndarray | None,
                  height_m: float, prev: _Frame | None = None) -> _Frame:
        """The frame with its features and texture score detected afresh. The repetition score (the costliest
        part: a transform of the image) is measured again every ``redetect_every`` frames and carried from
        ``prev`` in between, like the tracks: it is a property of the scene, which changes slowly."""
        cfg = self.cfg
        points, texture = self._detect(image)
        if texture < cfg.min_texture_score:
            return _Frame(t_s, image, R_nb, R_gyro, height_m, points, texture, 0.0, math.inf, len(points), 0)
        if prev is not None and prev.texture_score >= cfg.min_texture_score and prev.age + 1 < cfg.redetect_every:
            return _Frame(t_s, image, R_nb, R_gyro, height_m, points, texture, prev.repetition, prev.period_px,
                          len(points), prev.age + 1)
        repetition, period = self._repetition(image)
        return _Frame(t_s, image, R_nb, R_gyro, height_m, points, texture, repetition, period, len(points), 0)

    def _carried(self, prev: _Frame, t_s: float, image: np.ndarray, R_nb: np.ndarray,
                 R_gyro: np.ndarray | None, height_m: float, tracked: np.ndarray) -> _Frame:
        """The frame whose features are the tracks that survived into it (away from the border, as detection
        keeps them) with the scene's scores carried over; detected afresh when too few survive."""
        h, w = image.shape
        margin = self.cfg.lk_window_px // 2
        q = tracked.reshape(-1, 2)
        keep = (q[:, 0] >= margin) & (q[:, 1] >= margin) & (q[:, 0] < w - margin) & (q[:, 1] < h - margin)
        n = int(keep.sum())
        cfg = self.cfg
        if n < cfg.redetect_fraction * prev.detected or n < cfg.redetect_below:
            return self._detected(t_s, image, R_nb, R_gyro, height_m, prev)
        if prev.age + 1 >= cfg.redetect_every:
            return self._detected(t_s, image, R_nb, R_gyro, height_m)
        return _Frame(t_s, image, R_nb, R_gyro, height_m, np.ascontiguousarray(tracked[keep]),
                      prev.texture_score, prev.repetition, prev.period_px, prev.detected, prev.age + 1)

    def _refused(self, prev: _Frame, t_s: float, dt: float, texture: float, height_m: float,
                 vel_prior_ned_mps: tuple[float, float, float] | None) -> VoSample | None:
        """An invalid sample when the pair of frames cannot give a velocity (too little texture or too few
        features, too low, or a repetitive texture the prior does not disambiguate); None otherwise."""
        cfg = self.cfg
        if (
            texture < cfg.min_texture_score
            or len(prev.points) < cfg.min_features
            or height_m < cfg.min_height_m
        ):
            return _invalid(t_s, VoQuality(features=len(prev.points), texture_score=texture))

        if prev.repetition > cfg.max_repetition:
            # ambiguous by a period unless the prior pins the motion well inside half a period
            flow_sigma_px = self.model.fx_px * cfg.prior_sigma_mps * dt / max(height_m, cfg.min_height_m)
            if vel_prior_ned_mps is None or 3.0 * flow_sigma_px > 0.5 * prev.period_px:
                return _invalid(
                    t_s,
                    VoQuality(features=len(prev.points), texture_score=texture, repetition=prev.repetition),
                )
        return None

    def _predicted(self, prev: _Frame, g1: np.ndarray, R_nb: np.ndarray,
                   vel_prior_ned_mps: tuple[float, float, float] | None, dt: float) -> np.ndarray:
        """The predicted positions of the previous frame's features: the ground point under each (``g1``,
        metres from the previous camera), seen from the predicted new pose (the prior's velocity, none:
        still)."""
        n0 = len(g1)
        v = np.zeros(3) if vel_prior_ned_mps is None else np.asarray(vel_prior_ned_mps, dtype=float)
        rel = np.empty((n0, 3))
        rel[:, :2] = g1 - v[:2] * dt
        rel[:, 2] = max(prev.height_m - v[2] * dt, 0.1)
        guess: np.ndarray = self._project(rel, R_nb).astype(np.float32).reshape(-1, 1, 2)
        return guess

    def _lk_max_level(self, prev: _Frame, vel_prior_ned_mps: tuple[float, float, float] | None,
                      dt: float) -> int:
        """The pyramid levels above the image that LK needs: none when the prior's velocity error
        (``prior_sigma_mps``, 3 sigma) moves the ground by less than half the window in the image, as the
        filter's velocity does at the scenarios' heights and rates (a coarser level is there to catch
        motion the window cannot; building it cost a third of the tracking); ``lk_levels`` otherwise."""
        cfg = self.cfg
        if vel_prior_ned_mps is None:
            return cfg.lk_levels
        flow_3sigma_px = 3.0 * self.model.fx_px * cfg.prior_sigma_mps * dt / max(prev.height_m, cfg.min_height_m)
        return 0 if flow_3sigma_px < 0.5 * cfg.lk_window_px else cfg.lk_levels

    def _track(self, prev: _Frame, image: np.ndarray, guess: np.ndarray, max_level: int
               ) -> tuple[np.ndarray, np.ndarray]:
        """Pyramidal Lucas-Kanade from the previous frame, started at ``guess``, then back: (the tracked
        positions, which tracks stayed in the image and came back within ``fb_max_px``)."""
        cfg = self.cfg
        p0 = prev.points
        p1, st, _ = cv2.calcOpticalFlowPyrLK(
            prev.image, image, p0, guess.copy(), flags=cv2.OPTFLOW_USE_INITIAL_FLOW, maxLevel=max_level, **self._lk
        )
        h, w = image.shape
        q = p1.reshape(-1, 2)
        inside = (q[:, 0] >= 0) & (q[:, 1] >= 0) & (q[:, 0] < w) & (q[:, 1] < h)
        ok = (st.ravel() == 1) & inside
        # the backward check only for the tracks that survived the forward pass
        fwd = np.flatnonzero(ok)
        if len(fwd):
            pb, stb, _ = cv2.calcOpticalFlowPyrLK(
                image, prev.image, p1[fwd], p0[fwd], flags=cv2.OPTFLOW_USE_INITIAL_FLOW, maxLevel=max_level,
                **self._lk,
            )
            fb = np.linalg.norm((pb - p0[fwd]).reshape(-1, 2), axis=1)
            ok[fwd] = (stb.ravel() == 1) & (fb < cfg.fb_max_px)
        return p1, ok

    def _fit(self, prev: _Frame, R_nb: np.ndarray, rhs: np.ndarray, b: np.ndarray,
             vel_prior_ned_mps: tuple[float, float, float] | None, dt: float
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float] | None:
        """Geometric verification with the motion model the velocity is measured with: the rotation between
        the frames is the gyro's, so over flat ground only the displacement ``Δ`` and the new height ``h2``
        are unknown (``h1 u1 = Δ + h2 u2``). Started at the median of the per-track displacements (the
        prior's height change), inliers within ``3 ransac_px`` and then ``ransac_px`` of the reprojected
        model, each followed by the least-squares fit on them. A homography (8 unknowns, RANSAC and a
        Levenberg-Marquardt refinement) accepted motions this model cannot explain and cost more than the
        rest of this step. Returns (inlier mask, (Δn, Δe, h2), the normal matrix's inverse, the inliers'
        ground residuals in metres, their RMS reprojection error in pixels), or None when fewer than 3
        tracks fit."""
        cfg = self.cfg
        h1 = prev.height_m
        u2 = self._unit_ground(b, R_nb)
        vd = 0.0 if vel_prior_ned_mps is None else float(vel_prior_ned_mps[2])
        h2 = max(h1 - vd * dt, cfg.min_height_m)
        d0 = _column_median(rhs - h2 * u2)
        sol = np.array([d0[0], d0[1], h2])
        pix = b.reshape(-1, 2)
        inl = np.ones(len(pix), bool)
        AtA_inv = np.eye(3)
        for threshold_px in (3.0 * cfg.ransac_px, cfg.ransac_px):
            err = self._reprojection_px(rhs, sol, pix, R_nb)
            inl = err < threshold_px
            if int(inl.sum()) < 3:
                return None
            sol, AtA_inv = _ground_least_squares(rhs[inl], u2[inl])
            if not sol[2] > 0.0:
                return None
        err = self._reprojection_px(rhs[inl], sol, pix[inl], R_nb)
        reproj = float(np.sqrt(np.mean(err * err)))
        resid_m = rhs[inl] - sol[:2] - sol[2] * u2[inl]
        return inl, sol, AtA_inv, resid_m, reproj

    def _reprojection_px(self, rhs: np.ndarray, sol: np.ndarray, pix: np.ndarray, R_nb: np.ndarray) -> np.ndarray:
        """Distance in pixels between each tracked point and its ground point (``rhs`` = h1 u1) seen from
        the new pose of the model ``sol`` = (Δn, Δe, h2)."""
        rel = np.empty((len(rhs), 3))
        rel[:, :2] = rhs - sol[:2]
        rel[:, 2] = sol[2]
        d = self._project(rel, R_nb) - pix
        err: np.ndarray = np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1])
        return err

    def _velocity(self, t_s: float, prev: _Frame, sol: np.ndarray, AtA_inv: np.ndarray, resid_m: np.ndarray,
                  dt: float, quality: VoQuality) -> VoSample:
        """The fitted displacement ``sol`` = (Δn, Δe, h2) of ``h1 u1 = Δ + h2 u2`` over ``dt`` as a
        velocity with its variance (``resid_m``: the inliers' ground residuals)."""
        cfg = self.cfg
        n_in = quality.features
        d_n, d_e, h2 = (float(x) for x in sol)
        dof = max(1, 2 * n_in - 3)
        # residual scatter, floored by the tracking noise projected to the ground
        gsd = prev.height_m / self.model.fx_px
        s2 = max(float(np.einsum("ij,ij->", resid_m, resid_m)) / dof, (cfg.pixel_sigma_floor_px * gsd) ** 2)
        cov = s2 * AtA_inv / (dt * dt)
        vel = np.array([d_n / dt, d_e / dt, (prev.height_m - h2) / dt])
        var = np.diag(cov).copy()
        rot_sigma_mps = prev.height_m * cfg.gyro_noise_radps_rthz * math.sqrt(dt) / dt
        var[:2] += rot_sigma_mps**2
        var += (cfg.height_rel_sigma * vel) ** 2
        vh2 = vel[0] ** 2 + vel[1] ** 2
        var[:2] += cfg.yaw_sigma_rad**2 * vh2
        valid_quality = VoQuality(n_in, quality.inlier_ratio, quality.reprojection_error_px, quality.texture_score,
                                  True, quality.repetition)
        return VoSample(
            t_s,
            (float(vel[0]), float(vel[1]), float(vel[2])),
            (float(var[0]), float(var[1]), float(var[2])),
            valid_quality,
        )


def _column_median(x: np.ndarray) -> np.ndarray:
    """``np.median(x, axis=0)`` of a finite (n, k) array, bit for bit: the middle row of the sorted columns,
    or the two middle rows' sum halved (the mean ``np.median`` takes of them). ``np.median``'s own generic
    path cost about seven times as much on the few dozen tracks of a frame."""
    s = np.sort(x, axis=0)
    k = x.shape[0] // 2
    if x.shape[0] % 2:
        return s[k]
    mid: np.ndarray = (s[k - 1] + s[k]) / 2.0
    return mid


def _ground_least_squares(rhs: np.ndarray, u2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(Δn, Δe, h2) minimising |rhs - Δ - h2 u2|² over the rows, and the normal matrix's inverse. The rows
    are (1, 0, u2x) and (0, 1, u2y), so the normal matrix is [[n, 0, a], [0, n, b], [a, b, c]] with
    a, b the sums of u2 and c the sum of |u2|²; eliminating Δ (Schur complement s = c - (a² + b²)/n) gives
    h2 and the inverse in closed form (the general solvers cost more than the rest of the fit)."""
    n = float(len(rhs))
    X = np.empty((len(rhs), 4))
    X[:, :2] = u2
    X[:, 2:] = rhs
    sums = X.sum(axis=0)
    a, b, ra, rb = (float(x) for x in sums)
    c = float(np.einsum("ij,ij->", u2, u2))
    cr = float(np.einsum("ij,ij->", u2, rhs))
    s = c - (a * a + b * b) / n
    h2 = (cr - (a * ra + b * rb) / n) / s
    sol = np.array([(ra - a * h2) / n, (rb - b * h2) / n, h2])
    ia, ib = a / (n * s), b / (n * s)
    AtA_inv = np.array([
        [1.0 / n + a * ia / n, a * ib / n, -ia],
        [b * ia / n, 1.0 / n + b * ib / n, -ib],
        [-ia, -ib, 1.0 / s],
    ])
    return sol, AtA_inv


_NOISE_KERNEL = np.array([[1.0, -2.0, 1.0], [-2.0, 4.0, -2.0], [1.0, -2.0, 1.0]], np.float32)


def noise_sigma(image: np.ndarray) -> float:
    """The image's additive noise sigma, grey levels: Immerkaer 1996 ("Fast noise variance estimation",
    CVIU 64(2)), sigma = sqrt(pi/2) / (6 (W-2)(H-2)) * sum |I * N| with N the difference of two
    Laplacians, which cancels locally linear image structure. Texture edges leak in a little (it reads
    2.0-3.1 on the simulated camera's σ = 2 over water, brick, gravel and grass): conservative here."""
    r = cv2.filter2D(image.astype(np.float32), -1, _NOISE_KERNEL)[1:-1, 1:-1]
    return math.sqrt(0.5 * math.pi) * float(np.abs(r).mean()) / 6.0


def _invalid(t_s: float, quality: VoQuality) -> VoSample:
    return VoSample(t_s, (0.0, 0.0, 0.0), _INVALID_COV, quality)
