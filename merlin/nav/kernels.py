"""The navigation filter's hot path: the strapdown mechanisation, the covariance prediction and the fused
measurement update with injection and reset, as allocation-free kernels over preallocated arrays.

Why by hand: filterpy's :class:`~filterpy.kalman.ExtendedKalmanFilter` is the reference the filter's
equations are written against (and the tests compare every kernel here with its ``predict`` and
``update``), but it works on dense 19×19 matrices and allocates about ten of them per step: 30 µs for a
prediction and 200 µs for a GPS update, most of the filter's cost at 400 Hz. The transition F and the
measurement matrices H are sparse and fixed in shape, so the same equations can be evaluated on their
non-zero blocks only:

- ``P = F P Fᵀ + Q`` (filterpy ``predict``) as row then column operations on the blocks of F that are not
  the identity (Solà 2017, "Quaternion kinematics for the error-state Kalman filter", arXiv:1711.02508,
  sec. 7.2: δṗ = δv, δv̇ = −[R f]× δθ − R δb_a, δθ̇ = −R δb_g; the receiver's wander a first-order
  Gauss-Markov decay);
- the update (filterpy ``update``): ``S = H P Hᵀ + R``, ``K = P Hᵀ S⁻¹``, ``δx = K y`` and the Joseph
  form ``P = (I − K H) P (I − K H)ᵀ + K R Kᵀ`` (Simon 2006, "Optimal State Estimation", sec. 5.2), which
  holds for any gain, so the heading-only update (its gain's tilt rows zeroed) uses it too; ``H P`` is
  gathered from the non-zero entries of H only, and the result is written symmetric;
- the injection of δx into the nominal state and the reset ``P = G P Gᵀ`` with
  ``G = diag(I, I, I + [δθ/2]×, I, …)`` (Solà sec. 6.2-6.3, 7.3), which touches three rows and three
  columns.

The kernels are compiled by numba, in one of two ways (:data:`BACKEND`):

- ``"aot"``: ahead of time, by ``setup.py`` at install (``numba.pycc``, the functions of
  :data:`AOT_EXPORTS` with their signatures) into the extension module ``merlin.nav._kernels_aot``. A
  process then never imports numba: no numba import (~0.3 s of CPU), no compiler context and cache load
  at the first call of each kernel (~0.4 s and more), and no type dispatch at each call (a prediction
  1.4 µs instead of 1.9 µs). Every ``merlin serve``, campaign worker and test process that flies the filter
  pays those start-up costs otherwise (docs/benchmarks/sim.md, "The filter's kernels compiled at install").
  Used only when the build recorded this file's hash for it (an edited ``kernels.py`` in an editable
  install falls back to ``"numba"`` until reinstalled; ``merlin._build.describe()`` says so).
  ``numba.pycc`` is pending deprecation in numba, with no replacement yet; without it the install simply
  builds no such module.
- ``"numba"``: just in time (``njit(cache=True)``: compiled once per machine, cached beside the sources),
  when the ahead-of-time module is absent or stale, or ``MERLIN_KERNELS=jit`` is set.

Both compile the same Python functions with the same compiler, and give the same bits (``tests/nav/
test_nav_kernels.py``). Without numba, or with ``NUMBA_DISABLE_JIT=1`` (``"python"``), the same functions run
as Python, and the three matrix kernels are replaced by numpy versions of the same equations (dense, as
filterpy does them): slower, same results to rounding.

The nominal state lives in one float array ``s`` so that a kernel call unboxes one argument, not ten;
the slices below name its parts.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Callable
from typing import Any

import numpy as np

#: ``MERLIN_KERNELS=jit``: compile just in time even where the ahead-of-time module is installed (``setup.py``
#: sets it to build that module; tests set it to compare the two).
KERNELS_ENV = "MERLIN_KERNELS"
#: The extension module ``setup.py`` builds from this file (``numba.pycc``).
AOT_MODULE = "merlin.nav._kernels_aot"

_NO_JIT = os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0")


def _load_aot() -> Any:
    """The ahead-of-time module, when it is installed, wanted, and built from this very file."""
    if _NO_JIT or os.environ.get(KERNELS_ENV, "").strip() == "jit" or __name__ != "merlin.nav.kernels":
        return None
    from merlin import _build

    if _build.kernels_aot_state() != "current":
        return None
    try:
        from merlin.nav import _kernels_aot  # type: ignore[attr-defined]
    except ImportError:  # pragma: no cover - a module built for another interpreter
        return None
    return _kernels_aot


_AOT = _load_aot()

numba: Any = None
if _AOT is None and not _NO_JIT:
    try:  # numba is optional: the filter runs (slower) without it
        import numba
    except ImportError:  # pragma: no cover - a machine without numba
        numba = None

#: True when the kernels are compiled: ahead of time, or by numba (importable and not disabled by
#: NUMBA_DISABLE_JIT=1).
JIT: bool = _AOT is not None or (numba is not None and not getattr(numba.config, "DISABLE_JIT", False))
#: How the kernels run: "aot" (compiled at install), "numba" (compiled at first use) or "python".
BACKEND: str = "aot" if _AOT is not None else ("numba" if JIT else "python")


def _njit(fn: Callable[..., Any]) -> Callable[..., Any]:
    if numba is None:  # ahead-of-time kernels replace the exported ones below; the others stay Python
        return fn
    # cached only as this package's module: setup.py loads this file under another name to compile it ahead
    # of time, and a cache entry written then names that module, which later processes cannot import
    cached = __name__ == "merlin.nav.kernels"
    compiled: Callable[..., Any] = numba.njit(cache=cached, fastmath=False, nogil=True)(fn)
    return compiled


# ---- the nominal state vector ``s``
S_P = slice(0, 3)  # position NED, m
S_V = slice(3, 6)  # velocity NED, m/s
S_Q = slice(6, 10)  # attitude quaternion [w, x, y, z], body FRD -> NED
S_QG = slice(10, 14)  # attitude integrated from the bias-corrected gyro alone
S_BG = slice(14, 17)  # gyro bias, rad/s
S_BA = slice(17, 20)  # accelerometer bias, m/s²
S_BGPS = slice(20, 23)  # the receiver's wander, m
I_BBARO = 23  # the barometer's offset, m
S_DR = slice(24, 27)  # position propagated by the mechanisation alone (never corrected)
S_PF = slice(27, 30)  # pending covariance prediction: accumulated NED specific force × dt
I_PDT = 30  # pending covariance prediction: accumulated time
I_PN = 31  # pending covariance prediction: number of IMU samples
N_STATE = 32
N_ERR = 19

# ---- the parameter vector ``c`` (constants of one configuration)
C_GRAV = 0
C_TAU = 1  # the receiver's wander time constant
C_EVERY_N = 2  # covariance prediction every n IMU samples
N_PARAM = 3


# ------------------------------------------------------------------------------ small helpers


@_njit
def _quat_mul_normalize_into(
    s: np.ndarray,
    i: int,
    aw: float,
    ax: float,
    ay: float,
    az: float,
    bw: float,
    bx: float,
    by: float,
    bz: float,
) -> None:
    """s[i:i+4] = normalize(a ⊗ b), scalar part kept positive (merlin.nav.quaternion)."""
    w = aw * bw - ax * bx - ay * by - az * bz
    x = aw * bx + ax * bw + ay * bz - az * by
    y = aw * by - ax * bz + ay * bw + az * bx
    z = aw * bz + ax * by - ay * bx + az * bw
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if w < 0.0:
        n = -n
    s[i] = w / n
    s[i + 1] = x / n
    s[i + 2] = y / n
    s[i + 3] = z / n


@_njit
def _quat_exp(px: float, py: float, pz: float) -> tuple[float, float, float, float]:
    """Exp(φ) (Solà eq. 101), as merlin.nav.quaternion.quat_exp."""
    angle = math.sqrt(px * px + py * py + pz * pz)
    if angle < 1e-9:
        w, x, y, z = 1.0 - angle * angle / 8.0, 0.5 * px, 0.5 * py, 0.5 * pz
        n = math.sqrt(w * w + x * x + y * y + z * z)
        return w / n, x / n, y / n, z / n
    sa = math.sin(0.5 * angle) / angle
    return math.cos(0.5 * angle), px * sa, py * sa, pz * sa


@_njit
def dcm_into(s: np.ndarray, i: int, R: np.ndarray) -> None:
    """R(q) of the quaternion s[i:i+4] (Solà eq. 115), into the 3×3 array R."""
    w, x, y, z = s[i], s[i + 1], s[i + 2], s[i + 3]
    R[0, 0] = 1 - 2 * (y * y + z * z)
    R[0, 1] = 2 * (x * y - w * z)
    R[0, 2] = 2 * (x * z + w * y)
    R[1, 0] = 2 * (x * y + w * z)
    R[1, 1] = 1 - 2 * (x * x + z * z)
    R[1, 2] = 2 * (y * z - w * x)
    R[2, 0] = 2 * (x * z - w * y)
    R[2, 1] = 2 * (y * z + w * x)
    R[2, 2] = 1 - 2 * (x * x + y * y)


# ------------------------------------------------------------------------------ covariance prediction


def transition(s: np.ndarray, dt: float, tau_s: float) -> np.ndarray:
    """The dense F of the pending interval (for the numpy path and the tests): I plus the blocks of
    Solà sec. 7.2, with the mean specific force of the interval."""
    R = np.empty((3, 3))
    dcm_into(s, 6, R)
    fx, fy, fz = s[S_PF] / dt
    F = np.eye(N_ERR)
    F[0, 3] = F[1, 4] = F[2, 5] = dt
    F[3, 7], F[3, 8] = fz * dt, -fy * dt
    F[4, 6], F[4, 8] = -fz * dt, fx * dt
    F[5, 6], F[5, 7] = fy * dt, -fx * dt
    F[3:6, 12:15] = R * -dt
    F[6:9, 9:12] = R * -dt
    F[15, 15] = F[16, 16] = F[17, 17] = math.exp(-dt / tau_s)
    return F


@_njit
def _cov_predict_blocks(s: np.ndarray, P: np.ndarray, q_density: np.ndarray, tau_s: float) -> None:
    dt = s[I_PDT]
    if dt <= 0.0:
        return
    w, x, y, z = s[6], s[7], s[8], s[9]
    r00 = 1 - 2 * (y * y + z * z)
    r01 = 2 * (x * y - w * z)
    r02 = 2 * (x * z + w * y)
    r10 = 2 * (x * y + w * z)
    r11 = 1 - 2 * (x * x + z * z)
    r12 = 2 * (y * z - w * x)
    r20 = 2 * (x * z - w * y)
    r21 = 2 * (y * z + w * x)
    r22 = 1 - 2 * (x * x + y * y)
    fx, fy, fz = s[27] / dt, s[28] / dt, s[29] / dt
    # the non-identity blocks of F: A = -[f]× dt (δv by δθ), B = -R dt (δv by δb_a, δθ by δb_g)
    a01, a02 = fz * dt, -fy * dt
    a10, a12 = -fz * dt, fx * dt
    a20, a21 = fy * dt, -fx * dt
    b00, b01, b02 = -r00 * dt, -r01 * dt, -r02 * dt
    b10, b11, b12 = -r10 * dt, -r11 * dt, -r12 * dt
    b20, b21, b22 = -r20 * dt, -r21 * dt, -r22 * dt
    decay = math.exp(-dt / tau_s)
    n = P.shape[0]
    # M = F P, in place, rows in an order that reads every source row before it is overwritten:
    # rows 0-2 read 3-5, rows 3-5 read 6-8 and 12-14, rows 6-8 read 9-11 (never written)
    for j in range(n):
        p3, p4, p5 = P[3, j], P[4, j], P[5, j]
        p6, p7, p8 = P[6, j], P[7, j], P[8, j]
        p9, p10, p11 = P[9, j], P[10, j], P[11, j]
        p12, p13, p14 = P[12, j], P[13, j], P[14, j]
        P[0, j] += dt * p3
        P[1, j] += dt * p4
        P[2, j] += dt * p5
        P[3, j] = p3 + a01 * p7 + a02 * p8 + b00 * p12 + b01 * p13 + b02 * p14
        P[4, j] = p4 + a10 * p6 + a12 * p8 + b10 * p12 + b11 * p13 + b12 * p14
        P[5, j] = p5 + a20 * p6 + a21 * p7 + b20 * p12 + b21 * p13 + b22 * p14
        P[6, j] = p6 + b00 * p9 + b01 * p10 + b02 * p11
        P[7, j] = p7 + b10 * p9 + b11 * p10 + b12 * p11
        P[8, j] = p8 + b20 * p9 + b21 * p10 + b22 * p11
        P[15, j] *= decay
        P[16, j] *= decay
        P[17, j] *= decay
    # P = M Fᵀ: the same operations on the columns
    for i in range(n):
        p3, p4, p5 = P[i, 3], P[i, 4], P[i, 5]
        p6, p7, p8 = P[i, 6], P[i, 7], P[i, 8]
        p9, p10, p11 = P[i, 9], P[i, 10], P[i, 11]
        p12, p13, p14 = P[i, 12], P[i, 13], P[i, 14]
        P[i, 0] += dt * p3
        P[i, 1] += dt * p4
        P[i, 2] += dt * p5
        P[i, 3] = p3 + a01 * p7 + a02 * p8 + b00 * p12 + b01 * p13 + b02 * p14
        P[i, 4] = p4 + a10 * p6 + a12 * p8 + b10 * p12 + b11 * p13 + b12 * p14
        P[i, 5] = p5 + a20 * p6 + a21 * p7 + b20 * p12 + b21 * p13 + b22 * p14
        P[i, 6] = p6 + b00 * p9 + b01 * p10 + b02 * p11
        P[i, 7] = p7 + b10 * p9 + b11 * p10 + b12 * p11
        P[i, 8] = p8 + b20 * p9 + b21 * p10 + b22 * p11
        P[i, 15] *= decay
        P[i, 16] *= decay
        P[i, 17] *= decay
    # white noise densities integrate to variances growing with dt (Solà sec. 5.4.3)
    for i in range(n):
        P[i, i] += q_density[i] * dt
    # F P Fᵀ is symmetric; its evaluation rounds the two triangles differently: keep the upper one
    for i in range(n):
        for j in range(i):
            P[i, j] = P[j, i]
    s[20] *= decay
    s[21] *= decay
    s[22] *= decay
    s[27] = s[28] = s[29] = 0.0
    s[I_PDT] = 0.0
    s[I_PN] = 0.0


def _cov_predict_dense(s: np.ndarray, P: np.ndarray, q_density: np.ndarray, tau_s: float) -> None:
    dt = float(s[I_PDT])
    if dt <= 0.0:
        return
    F = transition(s, dt, tau_s)
    P[:] = F @ P @ F.T + np.diag(q_density * dt)
    s[S_BGPS] *= F[15, 15]
    s[S_PF] = 0.0
    s[I_PDT] = 0.0
    s[I_PN] = 0.0


cov_predict: Callable[[np.ndarray, np.ndarray, np.ndarray, float], None] = (
    _cov_predict_blocks if JIT else _cov_predict_dense
)


# ------------------------------------------------------------------------------ mechanisation


@_njit
def mechanise(
    s: np.ndarray,
    P: np.ndarray,
    q_density: np.ndarray,
    c: np.ndarray,
    gx: float,
    gy: float,
    gz: float,
    ax: float,
    ay: float,
    az: float,
    dt: float,
) -> None:
    """Strapdown mechanisation of one IMU sample (Solà eq. 260, rates and specific force held over the
    interval), the pending covariance prediction when ``c[C_EVERY_N]`` samples are pending (with the
    attitude at the start of the interval, like the mechanisation), then the attitude."""
    wx, wy, wz = gx - s[14], gy - s[15], gz - s[16]
    fbx, fby, fbz = ax - s[17], ay - s[18], az - s[19]
    # f_n = R(q) f_b (merlin.nav.quaternion.quat_rotate)
    qw, qx, qy, qz = s[6], s[7], s[8], s[9]
    tx = 2.0 * (qy * fbz - qz * fby)
    ty = 2.0 * (qz * fbx - qx * fbz)
    tz = 2.0 * (qx * fby - qy * fbx)
    fnx = fbx + qw * tx + (qy * tz - qz * ty)
    fny = fby + qw * ty + (qz * tx - qx * tz)
    fnz = fbz + qw * tz + (qx * ty - qy * tx)
    an, ae, ad = fnx, fny, fnz + c[C_GRAV]
    half_dt2 = 0.5 * dt * dt
    dn = s[3] * dt + an * half_dt2
    de = s[4] * dt + ae * half_dt2
    s[0] += dn
    s[1] += de
    s[2] += s[5] * dt + ad * half_dt2
    s[24] += dn
    s[25] += de
    s[3] += an * dt
    s[4] += ae * dt
    s[5] += ad * dt
    s[27] += fnx * dt
    s[28] += fny * dt
    s[29] += fnz * dt
    s[I_PDT] += dt
    s[I_PN] += 1.0
    if s[I_PN] >= c[C_EVERY_N]:
        cov_predict(s, P, q_density, c[C_TAU])
    dw, dx, dy, dz = _quat_exp(wx * dt, wy * dt, wz * dt)
    _quat_mul_normalize_into(s, 6, s[6], s[7], s[8], s[9], dw, dx, dy, dz)
    _quat_mul_normalize_into(s, 10, s[10], s[11], s[12], s[13], dw, dx, dy, dz)


# ------------------------------------------------------------------------------ measurement update


@_njit
def _hp_into(H: np.ndarray, P: np.ndarray, HP: np.ndarray) -> None:
    """HP = H P from the non-zero entries of H only."""
    m, n = H.shape
    for a in range(m):
        for j in range(n):
            HP[a, j] = 0.0
        for k in range(n):
            h = H[a, k]
            if h != 0.0:
                for j in range(n):
                    HP[a, j] += h * P[k, j]


@_njit
def _innovation_cov(H: np.ndarray, P: np.ndarray, r: np.ndarray, HP: np.ndarray, S: np.ndarray) -> None:
    """S = H P Hᵀ + R with R = diag(r) (with HP = H P, kept for the gain)."""
    _hp_into(H, P, HP)
    m, n = H.shape
    for a in range(m):
        for b in range(m):
            acc = r[a] if a == b else 0.0
            for k in range(n):
                h = H[b, k]
                if h != 0.0:
                    acc += HP[a, k] * h
            S[a, b] = acc


@_njit
def _inverse_spd(S: np.ndarray, out: np.ndarray) -> bool:
    """out = S⁻¹ of a small symmetric positive-definite matrix by Cholesky (S = L Lᵀ); False if S is not
    positive definite (the caller then treats the measurement as failing its gate)."""
    m = S.shape[0]
    L = np.zeros((m, m))
    for i in range(m):
        for j in range(i + 1):
            acc = S[i, j]
            for k in range(j):
                acc -= L[i, k] * L[j, k]
            if i == j:
                if acc <= 0.0:
                    return False
                L[i, i] = math.sqrt(acc)
            else:
                L[i, j] = acc / L[j, j]
    # L⁻¹, lower triangular
    Li = np.zeros((m, m))
    for i in range(m):
        Li[i, i] = 1.0 / L[i, i]
        for j in range(i):
            acc = 0.0
            for k in range(j, i):
                acc -= L[i, k] * Li[k, j]
            Li[i, j] = acc / L[i, i]
    # S⁻¹ = L⁻ᵀ L⁻¹
    for i in range(m):
        for j in range(i + 1):
            acc = 0.0
            for k in range(i, m):
                acc += Li[k, i] * Li[k, j]
            out[i, j] = acc
            out[j, i] = acc
    return True


@_njit
def _nis_blocks(H: np.ndarray, P: np.ndarray, r: np.ndarray, y: np.ndarray, lo: int, hi: int) -> float:
    """The normalised innovation squared yᵀ S⁻¹ y of the rows lo..hi of (H, R = diag(r), y) (Bar-Shalom
    et al. 2001, sec. 5.4); inf when that S is not positive definite."""
    m = hi - lo
    n = H.shape[1]
    HP = np.empty((m, n))
    S = np.empty((m, m))
    _innovation_cov(H[lo:hi], P, r[lo:hi], HP, S)
    Si = np.empty((m, m))
    if not _inverse_spd(S, Si):
        return math.inf
    acc = 0.0
    for a in range(m):
        for b in range(m):
            acc += y[lo + a] * Si[a, b] * y[lo + b]
    return acc


def _nis_dense(H: np.ndarray, P: np.ndarray, r: np.ndarray, y: np.ndarray, lo: int, hi: int) -> float:
    Hs = H[lo:hi]
    S = Hs @ P @ Hs.T + np.diag(r[lo:hi])
    try:
        np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        return math.inf
    ys = y[lo:hi]
    return float(ys @ np.linalg.solve(S, ys))


nis: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int, int], float] = (
    _nis_blocks if JIT else _nis_dense
)


@_njit
def _fuse_blocks(
    s: np.ndarray, P: np.ndarray, H: np.ndarray, r: np.ndarray, y: np.ndarray, tilt_free: bool
) -> bool:
    m, n = H.shape
    HP = np.empty((m, n))
    S = np.empty((m, m))
    _innovation_cov(H, P, r, HP, S)
    Si = np.empty((m, m))
    if not _inverse_spd(S, Si):
        return False
    # K = P Hᵀ S⁻¹ = (H P)ᵀ S⁻¹ (P symmetric)
    K = np.zeros((n, m))
    for i in range(n):
        for b in range(m):
            acc = 0.0
            for a in range(m):
                acc += HP[a, i] * Si[a, b]
            K[i, b] = acc
    if tilt_free:  # the heading-only update: the gain may not rotate about the horizontal axes
        for b in range(m):
            K[6, b] = 0.0
            K[7, b] = 0.0
    dx = np.zeros(n)
    for i in range(n):
        acc = 0.0
        for a in range(m):
            acc += K[i, a] * y[a]
        dx[i] = acc
    # Joseph form: A = (I − K H) P = P − K (H P); P = A (I − K H)ᵀ + K R Kᵀ = A − (A Hᵀ) Kᵀ + (K R) Kᵀ
    A = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            acc = P[i, j]
            for a in range(m):
                acc -= K[i, a] * HP[a, j]
            A[i, j] = acc
    AHt = np.zeros((n, m))
    for a in range(m):
        for k in range(n):
            h = H[a, k]
            if h != 0.0:
                for i in range(n):
                    AHt[i, a] += A[i, k] * h
    KR = np.empty((n, m))
    for i in range(n):
        for b in range(m):
            KR[i, b] = K[i, b] * r[b]
    for i in range(n):
        for j in range(i, n):
            acc = A[i, j]
            for a in range(m):
                acc += KR[i, a] * K[j, a] - AHt[i, a] * K[j, a]
            P[i, j] = acc
    # written symmetric: the upper triangle is the computed one (A's lower triangle differs by rounding)
    _mirror_then_inject(s, P, dx)
    return True


@_njit
def _mirror_then_inject(s: np.ndarray, P: np.ndarray, dx: np.ndarray) -> None:
    """P's lower triangle copied from its upper one (the computed one), then the injection and reset."""
    n = P.shape[0]
    for i in range(n):
        for j in range(i):
            P[i, j] = P[j, i]
    _inject_reset(s, P, dx)


@_njit
def _inject_reset(s: np.ndarray, P: np.ndarray, dx: np.ndarray) -> None:
    """Inject δx into the nominal state and reset P = G P Gᵀ, G = diag(I, I, I + [δθ/2]×, I, …)
    (Solà sec. 6.2-6.3, 7.3)."""
    for i in range(3):
        s[i] += dx[i]
        s[3 + i] += dx[3 + i]
        s[14 + i] += dx[9 + i]
        s[17 + i] += dx[12 + i]
        s[20 + i] += dx[15 + i]
    s[I_BBARO] += dx[18]
    ew, ex, ey, ez = _quat_exp(dx[6], dx[7], dx[8])
    # q = normalize(Exp(δθ) ⊗ q): the global error is applied on the left
    _quat_mul_normalize_into(s, 6, ew, ex, ey, ez, s[6], s[7], s[8], s[9])
    # G P Gᵀ with G_θ = I + [δθ/2]×: rows 6-8, then columns 6-8
    hx, hy, hz = 0.5 * dx[6], 0.5 * dx[7], 0.5 * dx[8]
    n = P.shape[0]
    for j in range(n):
        p6, p7, p8 = P[6, j], P[7, j], P[8, j]
        P[6, j] = p6 - hz * p7 + hy * p8
        P[7, j] = hz * p6 + p7 - hx * p8
        P[8, j] = -hy * p6 + hx * p7 + p8
    for i in range(n):
        p6, p7, p8 = P[i, 6], P[i, 7], P[i, 8]
        P[i, 6] = p6 - hz * p7 + hy * p8
        P[i, 7] = hz * p6 + p7 - hx * p8
        P[i, 8] = -hy * p6 + hx * p7 + p8
    # outside the 3×3 attitude block the row and column passes give mirror images bit for bit; inside it
    # they round differently: keep it symmetric
    P[7, 6] = P[6, 7]
    P[8, 6] = P[6, 8]
    P[8, 7] = P[7, 8]


def _fuse_dense(
    s: np.ndarray, P: np.ndarray, H: np.ndarray, r: np.ndarray, y: np.ndarray, tilt_free: bool
) -> bool:
    """The same update with dense numpy products (as filterpy's ``update`` computes it)."""
    R = np.diag(r)
    PHT = P @ H.T
    S = H @ PHT + R
    try:
        np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        return False
    K = PHT @ np.linalg.inv(S)
    if tilt_free:
        K[6:8, :] = 0.0
    dx = K @ y
    I_KH = np.eye(P.shape[0]) - K @ H
    P[:] = I_KH @ P @ I_KH.T + K @ R @ K.T
    _inject_reset_dense(s, P, dx)
    return True


def _inject_reset_dense(s: np.ndarray, P: np.ndarray, dx: np.ndarray) -> None:
    s[0:6] += dx[0:6]
    s[S_BG] += dx[9:12]
    s[S_BA] += dx[12:15]
    s[S_BGPS] += dx[15:18]
    s[I_BBARO] += dx[18]
    ew, ex, ey, ez = _quat_exp(float(dx[6]), float(dx[7]), float(dx[8]))
    _quat_mul_normalize_into(s, 6, ew, ex, ey, ez, float(s[6]), float(s[7]), float(s[8]), float(s[9]))
    hx, hy, hz = 0.5 * dx[6], 0.5 * dx[7], 0.5 * dx[8]
    G = np.eye(P.shape[0])
    G[6:9, 6:9] += np.array([[0.0, -hz, hy], [hz, 0.0, -hx], [-hy, hx, 0.0]])
    P[:] = G @ P @ G.T
    P[:] = np.triu(P) + np.triu(P, 1).T


fuse: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, bool], bool] = (
    _fuse_blocks if JIT else _fuse_dense
)


@_njit
def _one_row_update(
    s: np.ndarray, P: np.ndarray, H: np.ndarray, r: np.ndarray, y: np.ndarray, gate: float, tilt_free: bool
) -> float:
    """A one-row measurement (H 1×n, R = r[0], y[0]): its NIS, then, when the NIS is within ``gate``, the
    update, injection and reset that :func:`_fuse_blocks` makes; returns the NIS (inf when S is not
    positive).

    The same operations in the same order as :func:`_nis_blocks` followed by :func:`_fuse_blocks` with
    m = 1, so the same bits: each of their one-term sums starts from 0.0 as theirs do (0.0 + x, which
    differs from x for x = -0.0), and H's non-zero columns are summed in the same ascending order. What
    it saves: H P, S and S⁻¹ are formed once for both, no matrix is allocated (Joseph form's A = P − K H P
    is formed entry by entry as P is overwritten, after the columns A Hᵀ needs were read), and the loops
    over the one row disappear."""
    n = H.shape[1]
    w = np.zeros((4, n))  # the sums below start from +0.0, as the two kernels' do
    hp, k_, aht, dx = w[0], w[1], w[2], w[3]
    # H P from the non-zero entries of H, and S = H P Hᵀ + r
    for k in range(n):
        h = H[0, k]
        if h != 0.0:
            for j in range(n):
                hp[j] += h * P[k, j]
    acc = r[0]
    for k in range(n):
        h = H[0, k]
        if h != 0.0:
            acc += hp[k] * h
    if acc <= 0.0:
        return math.inf
    li = 1.0 / math.sqrt(acc)
    si = 0.0 + li * li
    v = 0.0 + y[0] * si * y[0]
    if not v <= gate:
        return v
    for i in range(n):
        k_[i] = 0.0 + hp[i] * si
    if tilt_free:
        k_[6] = 0.0
        k_[7] = 0.0
    for i in range(n):
        dx[i] = 0.0 + k_[i] * y[0]
    for k in range(n):  # A Hᵀ, A = P − K H P read where H is not zero, before P is written
        h = H[0, k]
        if h != 0.0:
            for i in range(n):
                aht[i] += (P[i, k] - k_[i] * hp[k]) * h
    r0 = r[0]
    for i in range(n):
        kri = k_[i] * r0
        ahti = aht[i]
        for j in range(i, n):
            kj = k_[j]
            P[i, j] = (P[i, j] - k_[i] * hp[j]) + (kri * kj - ahti * kj)
    _mirror_then_inject(s, P, dx)
    return v


@_njit
def _heading_r_y(
    P: np.ndarray, r: np.ndarray, y: np.ndarray, innovation: float, sigma2: float, jn: float, je: float
) -> None:
    """The magnetic heading's R = σ² + J_t P_tt J_tᵀ (the levelling's tilt terms through P's tilt block)
    into ``r[0]`` and its innovation into ``y[0]``, for both forms of :data:`heading_update`."""
    r[0] = sigma2 + (jn * jn * P[6, 6] + 2.0 * jn * je * P[6, 7] + je * je * P[7, 7])
    y[0] = innovation


@_njit
def _baro_r_y(s: np.ndarray, r: np.ndarray, y: np.ndarray, alt_m: float, sigma2: float) -> None:
    """The barometer's R = σ² into ``r[0]`` and y = z − (−p̂_d + b̂_baro) into ``y[0]``, for both forms of
    :data:`baro_update`."""
    r[0] = sigma2
    y[0] = alt_m - (-s[2] + s[I_BBARO])


@_njit
def _heading_update_blocks(
    s: np.ndarray, P: np.ndarray, H: np.ndarray, r: np.ndarray, y: np.ndarray, innovation: float,
    sigma2: float, jn: float, je: float, gate: float,
) -> float:
    """The magnetic heading update of ``NavEstimator.update_mag`` (``mag_fusion = "heading"``) in one call:
    R = σ² + J_t P_tt J_tᵀ (the levelling's tilt terms ``jn, je`` through the tilt block of P) into
    ``r[0]``, the innovation into ``y[0]``, the NIS, and the heading-only fusion when the NIS is within
    ``gate``. Returns the NIS.

    The heading-only fusion's gain may not touch the tilt: K = P Hᵀ S⁻¹ with its δθ_n, δθ_e rows set to
    zero, so the attitude correction is a rotation about the vertical and roll and pitch are left to the
    accelerometer's coupling with GPS and VO. That gain is not the optimal one, and the covariance follows
    the gain applied: the Joseph form holds for any gain (Simon 2006, "Optimal State Estimation", sec. 5.2),
    so :data:`fuse` serves with ``tilt_free``.

    Why one kernel: the same arithmetic, in the same order, as computing R and y in the caller and calling
    :data:`nis` and :data:`fuse` one after the other, but the magnetometer's update at 100 Hz spent more of
    its time on those calls and the one-element arrays between them than in the update itself."""
    _heading_r_y(P, r, y, innovation, sigma2, jn, je)
    v: float = _one_row_update(s, P, H, r, y, gate, True)
    return v


def _one_row_update_dense(
    s: np.ndarray, P: np.ndarray, H: np.ndarray, r: np.ndarray, y: np.ndarray, gate: float, tilt_free: bool
) -> float:
    """:func:`_one_row_update` with the dense numpy steps (no compiler): the NIS, then the fusion within
    ``gate``."""
    v = _nis_dense(H, P, r, y, 0, 1)
    if v <= gate:
        _fuse_dense(s, P, H, r, y, tilt_free)
    return v


def _heading_update_dense(
    s: np.ndarray, P: np.ndarray, H: np.ndarray, r: np.ndarray, y: np.ndarray, innovation: float,
    sigma2: float, jn: float, je: float, gate: float,
) -> float:
    _heading_r_y(P, r, y, innovation, sigma2, jn, je)
    return _one_row_update_dense(s, P, H, r, y, gate, True)


heading_update: Callable[..., float] = _heading_update_blocks if JIT else _heading_update_dense


@_njit
def _baro_update_blocks(
    s: np.ndarray, P: np.ndarray, H: np.ndarray, r: np.ndarray, y: np.ndarray, alt_m: float, sigma2: float,
    gate: float,
) -> float:
    """The barometer's update of ``NavEstimator.update_baro`` in one call: y = z − (−p̂_d + b̂_baro) into
    ``y[0]``, R = ``sigma2`` into ``r[0]``, the NIS, and the fusion when the NIS is within ``gate``; returns
    the NIS. The same arithmetic, in the same order, as the steps it replaces (the caller's y and R, then
    :data:`nis` and :data:`fuse`), for the same reason as :func:`_heading_update_blocks`."""
    _baro_r_y(s, r, y, alt_m, sigma2)
    v: float = _one_row_update(s, P, H, r, y, gate, False)
    return v


def _baro_update_dense(
    s: np.ndarray, P: np.ndarray, H: np.ndarray, r: np.ndarray, y: np.ndarray, alt_m: float, sigma2: float,
    gate: float,
) -> float:
    _baro_r_y(s, r, y, alt_m, sigma2)
    return _one_row_update_dense(s, P, H, r, y, gate, False)


baro_update: Callable[..., float] = _baro_update_blocks if JIT else _baro_update_dense


@_njit
def vo_jacobian_into(s: np.ndarray, H: np.ndarray, coupling: bool) -> None:
    """The horizontal VO velocity's Jacobian (``NavEstimator._vo_jacobian`` gives the equations) into the
    2×19 array H: I₂ along δv_h and, with ``coupling``, v_h/h along δp_d, (v_e, −v_n) along δθ_d and
    h [−R₂; R₁] along δb_g (R_i the rows of R(q))."""
    for a in range(2):
        for k in range(H.shape[1]):
            H[a, k] = 0.0
    H[0, 3] = 1.0
    H[1, 4] = 1.0
    if not coupling:
        return
    vn, ve = s[3], s[4]
    H[0, 8] = ve
    H[1, 8] = -vn
    h = -s[2]
    if h > 1.0:
        H[0, 2] = vn / h
        H[1, 2] = ve / h
        w, x, y, z = s[6], s[7], s[8], s[9]
        H[0, 9] = -h * (2 * (x * y + w * z))
        H[0, 10] = -h * (1 - 2 * (x * x + z * z))
        H[0, 11] = -h * (2 * (y * z - w * x))
        H[1, 9] = h * (1 - 2 * (y * y + z * z))
        H[1, 10] = h * (2 * (x * y - w * z))
        H[1, 11] = h * (2 * (x * z + w * y))


@_njit
def vo_filter_variance(H: np.ndarray, P: np.ndarray) -> tuple[float, float]:
    """The variance the filter's own errors put into each horizontal VO velocity component: row a of H
    without its δv columns (3, 4), H_a P H_aᵀ (the VO Jacobian's nonzero columns besides δv are δp_d,
    δθ_d and δb_g: 2, 8, 9-11)."""
    out = [0.0, 0.0]
    cols = (2, 8, 9, 10, 11)
    for a in range(2):
        acc = 0.0
        for j in cols:
            hj = H[a, j]
            if hj != 0.0:
                for k in cols:
                    acc += hj * P[j, k] * H[a, k]
        out[a] = max(acc, 0.0)
    return out[0], out[1]


@_njit
def gps_innovation(
    s: np.ndarray,
    P: np.ndarray,
    H: np.ndarray,
    pn: float,
    pe: float,
    pd: float,
    vn: float,
    ve: float,
    vd: float,
    lag: float,
    ax_b: float,
    ay_b: float,
    az_b: float,
    grav: float,
    sig_h2: float,
    sig_v2: float,
    vel_var: float,
    y: np.ndarray,
    r: np.ndarray,
) -> tuple[float, float, float, float, float, float, float]:
    """The GPS epoch carried forward by ``lag`` and its innovation (``NavEstimator._gps_innovation`` gives
    the equations): fills y = z − h(x̂) and R's diagonal r, returns the position and velocity NIS, the
    NED acceleration used to carry the epoch, and the mechanisation-only position (north, east) carried
    back to the epoch's time of validity with it (for the window test)."""
    fbx, fby, fbz = ax_b - s[17], ay_b - s[18], az_b - s[19]
    qw, qx, qy, qz = s[6], s[7], s[8], s[9]
    tx = 2.0 * (qy * fbz - qz * fby)
    ty = 2.0 * (qz * fbx - qx * fbz)
    tz = 2.0 * (qx * fby - qy * fbx)
    an = fbx + qw * tx + (qy * tz - qz * ty)
    ae = fby + qw * ty + (qz * tx - qx * tz)
    ad = fbz + qw * tz + (qx * ty - qy * tx) + grav
    y[0] = (pn + (s[3] * lag + 0.5 * an * lag * lag)) - (s[0] + s[20])
    y[1] = (pe + (s[4] * lag + 0.5 * ae * lag * lag)) - (s[1] + s[21])
    y[2] = (pd + (s[5] * lag + 0.5 * ad * lag * lag)) - (s[2] + s[22])
    y[3] = (vn + an * lag) - s[3]
    y[4] = (ve + ae * lag) - s[4]
    y[5] = (vd + ad * lag) - s[5]
    lag_var_p = max(P[3, 3], P[4, 4], P[5, 5]) * lag * lag
    r[0] = r[1] = sig_h2 + lag_var_p
    r[2] = sig_v2 + lag_var_p
    r[3] = r[4] = r[5] = vel_var
    dr_n = s[24] - s[3] * lag + 0.5 * an * lag * lag
    dr_e = s[25] - s[4] * lag + 0.5 * ae * lag * lag
    return nis(H, P, r, y, 0, 3), nis(H, P, r, y, 3, 6), an, ae, ad, dr_n, dr_e


# ------------------------------------------------------------------------------ ahead-of-time build

_C1 = "f8[::1]"
_C2 = "f8[:,::1]"
#: What ``setup.py`` compiles into :data:`AOT_MODULE`: exported name -> (function here, numba signature).
#: The arrays are C-contiguous float64 (the filter's own: state, covariance, H, y, r); a caller passing
#: anything else gets a TypeError from the compiled module, never a silent copy.
AOT_EXPORTS: dict[str, tuple[str, str]] = {
    "mechanise": ("mechanise", f"void({_C1},{_C2},{_C1},{_C1},f8,f8,f8,f8,f8,f8,f8)"),
    "cov_predict_blocks": ("_cov_predict_blocks", f"void({_C1},{_C2},{_C1},f8)"),
    "nis_blocks": ("_nis_blocks", f"f8({_C2},{_C2},{_C1},{_C1},i8,i8)"),
    "fuse_blocks": ("_fuse_blocks", f"b1({_C1},{_C2},{_C2},{_C1},{_C1},b1)"),
    "heading_update_blocks": ("_heading_update_blocks", f"f8({_C1},{_C2},{_C2},{_C1},{_C1},f8,f8,f8,f8,f8)"),
    "baro_update_blocks": ("_baro_update_blocks", f"f8({_C1},{_C2},{_C2},{_C1},{_C1},f8,f8,f8)"),
    "gps_innovation": ("gps_innovation", f"UniTuple(f8,7)({_C1},{_C2},{_C2},{','.join(['f8'] * 14)},{_C1},{_C1})"),
    "vo_jacobian_into": ("vo_jacobian_into", f"void({_C1},{_C2},b1)"),
    "vo_filter_variance": ("vo_filter_variance", f"UniTuple(f8,2)({_C2},{_C2})"),
}

_BODIES: dict[str, Callable[..., Any]] = {
    attr: getattr(globals()[attr], "py_func", globals()[attr]) for attr, _ in AOT_EXPORTS.values()
}


def python_body(name: str) -> Callable[..., Any]:
    """The Python function behind the compiled kernel ``name`` (one of :data:`AOT_EXPORTS`' functions),
    whichever backend runs it."""
    return _BODIES[name]


if _AOT is not None:
    mechanise = _AOT.mechanise
    _cov_predict_blocks = _AOT.cov_predict_blocks
    _nis_blocks = _AOT.nis_blocks
    _fuse_blocks = _AOT.fuse_blocks
    _heading_update_blocks = _AOT.heading_update_blocks
    _baro_update_blocks = _AOT.baro_update_blocks
    gps_innovation = _AOT.gps_innovation
    vo_jacobian_into = _AOT.vo_jacobian_into
    vo_filter_variance = _AOT.vo_filter_variance
    cov_predict = _cov_predict_blocks
    nis = _nis_blocks
    fuse = _fuse_blocks
    heading_update = _heading_update_blocks
    baro_update = _baro_update_blocks


def build_aot(out_dir: str) -> str:
    """Compile :data:`AOT_EXPORTS` into :data:`AOT_MODULE`'s file in ``out_dir`` (``setup.py``; this module
    must have been loaded with numba compiling, i.e. :data:`BACKEND` ``"numba"``). Returns the file's path."""
    if BACKEND != "numba":
        raise RuntimeError(f"the kernels must be numba's to be compiled ahead of time, not {BACKEND!r}")
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # numba.pycc's pending deprecation
        from numba.pycc import CC

        cc = CC(AOT_MODULE.rpartition(".")[2], source_module=sys.modules[__name__])
        cc.output_dir = out_dir
        for export, (attr, signature) in AOT_EXPORTS.items():
            cc.export(export, signature)(python_body(attr))
        cc.compile()
    return os.path.join(out_dir, cc.output_file)
