"""How far an orientation estimate is from the truth: tilt, heading drift, and the normalised
estimation error squared (NEES) of the filter's stated covariance."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from imud.rotations import quat_conj, quat_mul

F64 = npt.NDArray[np.float64]


def _body_up(q: F64) -> F64:
    """The world's z in each body frame (the gravity direction an estimate implies)."""
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    out: F64 = np.column_stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)])
    return out


def tilt_error_deg(est: F64, truth: F64) -> F64:
    """Angle between the estimated and true gravity directions in the body frame, per sample."""
    a, b = _body_up(est), _body_up(truth)
    c = np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0)
    s = np.linalg.norm(np.cross(a, b), axis=1)
    out: F64 = np.degrees(np.arctan2(s, c))
    return out


def yaw_deg(q: F64) -> F64:
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.degrees(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))


def world_error(est: F64, truth: F64) -> F64:
    """The world-frame rotation vector taking the estimate to the truth (q_true = exp(e) q_est)."""
    d = quat_mul(truth, quat_conj(est))
    d = np.where(d[:, :1] < 0, -d, d)
    v = d[:, 1:]
    s = np.linalg.norm(v, axis=1)
    angle = 2 * np.arctan2(s, d[:, 0])
    k = np.where(s > 1e-12, angle / np.where(s > 1e-12, s, 1.0), 2.0)
    out: F64 = v * k[:, None]
    return out


def align_heading(est: F64, truth: F64, at: int = 0) -> F64:
    """The truth rotated about the world's z so its heading equals the estimate's at sample
    `at` (a filter without a magnetometer starts at heading zero)."""
    e = world_error(est[at : at + 1], truth[at : at + 1])[0]
    psi = -e[2]
    rz = np.array([math.cos(psi / 2), 0.0, 0.0, math.sin(psi / 2)])
    out: F64 = quat_mul(np.broadcast_to(rz, truth.shape), truth)
    return out


def nees(err: F64, cov6: F64, axes: slice = slice(0, 3)) -> F64:
    """e^T P^-1 e per sample for the world-frame error and the filter's covariance (xx, xy, xz,
    yy, yz, zz), over `axes` (0:2 for the tilt alone)."""
    p = np.empty((cov6.shape[0], 3, 3))
    p[:, 0, 0], p[:, 0, 1], p[:, 0, 2] = cov6[:, 0], cov6[:, 1], cov6[:, 2]
    p[:, 1, 0], p[:, 1, 1], p[:, 1, 2] = cov6[:, 1], cov6[:, 3], cov6[:, 4]
    p[:, 2, 0], p[:, 2, 1], p[:, 2, 2] = cov6[:, 2], cov6[:, 4], cov6[:, 5]
    p = p[:, axes, axes]
    e = err[:, axes]
    sol = np.linalg.solve(p, e[:, :, None])[:, :, 0]
    out: F64 = np.einsum("ij,ij->i", e, sol)
    return out
