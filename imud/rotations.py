"""Rotations, written once: rotation matrices and the SO(3) exponential, logarithm and right
Jacobian (batched over rows), and unit quaternions (w, x, y, z; Hamilton product; q rotates body
vectors into the world frame). The simulators move with them, the calibration fits integrate
with them.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]


def rotation_zyx(roll_deg: float, pitch_deg: float, yaw_deg: float) -> F64:
    """Body-to-world rotation R = Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = (math.radians(a) for a in (roll_deg, pitch_deg, yaw_deg))
    cr, sr, cp, sp, cy, sy = (
        math.cos(r),
        math.sin(r),
        math.cos(p),
        math.sin(p),
        math.cos(y),
        math.sin(y),
    )
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


# --- quaternions: (w, x, y, z), Hamilton product, q rotates body vectors into the world ---------
def quat_mul(a: F64, b: F64) -> F64:
    """Hamilton product a b, for (4,) or (N, 4) arrays (broadcast)."""
    aw, ax, ay, az = (a[..., i] for i in range(4))
    bw, bx, by, bz = (b[..., i] for i in range(4))
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def quat_mul_floats(
    a: tuple[float, ...] | list[float], b: tuple[float, ...] | list[float]
) -> tuple[float, float, float, float]:
    """a x b (Hamilton) for one pair of quaternions (w, x, y, z) as plain floats: where a
    NumPy call on a 4-vector would cost more than the product."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def quat_conj(q: F64) -> F64:
    """The inverse rotation of a unit quaternion."""
    out: F64 = q * np.array([1.0, -1.0, -1.0, -1.0])
    return out


def cross(a: F64, b: F64) -> F64:
    """np.cross for (..., 3) arrays, without its axis handling (a hot path of the simulators)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def quat_rotate(q: F64, v: F64) -> F64:
    """v rotated by q (q v q*), for (4,)/(N, 4) quaternions and (3,)/(N, 3) vectors."""
    w = q[..., :1]
    r = q[..., 1:]
    t = 2.0 * cross(r, v)
    out: F64 = v + w * t + cross(r, t)
    return out


def quat_exp(phi: F64, th2: F64 | None = None) -> F64:
    """exp of rotation vectors (m, 3) as unit quaternions (m, 4); `th2`: their squared norms,
    when the caller has them."""
    if th2 is None:
        th2 = np.einsum("ij,ij->i", phi, phi)
    th = np.sqrt(th2)
    half = 0.5 * th
    out = np.empty((phi.shape[0], 4))
    out[:, 0] = np.cos(half)
    # sin(th/2)/th -> 1/2 as th -> 0; at th = 0 exactly phi is 0 and so is the product
    out[:, 1:] = phi * (np.sin(half) / (th + 1e-300))[:, None]
    return out


def quat_to_matrix(q: F64) -> F64:
    """The rotation matrix of one unit quaternion (4,)."""
    w, x, y, z = q.tolist()
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def quat_from_axis_angle(axis: F64, angle_rad: float) -> F64:
    """The rotation by `angle_rad` about the unit vector `axis`."""
    half = 0.5 * angle_rad
    return np.concatenate([[math.cos(half)], np.asarray(axis, dtype=np.float64) * math.sin(half)])


def quat_from_euler_zyx(roll_deg: float, pitch_deg: float, yaw_deg: float) -> F64:
    """The quaternion of `rotation_zyx`: Rz(yaw) Ry(pitch) Rx(roll)."""
    z = quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), math.radians(yaw_deg))
    y = quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), math.radians(pitch_deg))
    x = quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), math.radians(roll_deg))
    return quat_mul(quat_mul(z, y), x)


def quat_from_matrix(m: F64) -> F64:
    """The unit quaternion of a proper rotation matrix (Shepperd's method: stable for every
    rotation, including half turns)."""
    tr = float(np.trace(m))
    cands = [tr, m[0, 0], m[1, 1], m[2, 2]]
    i = int(np.argmax(cands))
    if i == 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif i == 1:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif i == 2:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    out = np.array(q)
    result: F64 = out if out[0] >= 0 else -out
    return result


# --- SO(3): the exponential map and its Jacobian, batched -----------------------------------------
def skew(v: F64) -> F64:
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def exp_and_jr(phi: F64) -> tuple[F64, F64]:
    """exp([phi]x) and the right Jacobian J_r(phi) for each row of phi (M, 3), with series
    expansions where the angle is small."""
    th2 = np.einsum("mi,mi->m", phi, phi)
    th = np.sqrt(th2)
    small = th < 1e-4
    safe = np.where(small, 1.0, th)
    sn = np.sin(safe)
    half = np.sin(0.5 * safe)
    a = sn / safe  # sin t / t
    b = 2.0 * half * half / (safe * safe)  # (1 - cos t) / t^2, without cancellation
    c = (safe - sn) / (safe * safe * safe)  # (t - sin t) / t^3
    if np.any(small):
        t2 = th2[small]
        a[small] = 1.0 - t2 / 6.0
        b[small] = 0.5 - t2 / 24.0
        c[small] = 1.0 / 6.0 - t2 / 120.0
    k = skew(phi)
    k2 = phi[:, :, None] * phi[:, None, :]  # [phi]x^2 = phi phi^T - |phi|^2 I
    diag = np.arange(3)
    k2[:, diag, diag] -= th2[:, None]
    a3, b3, c3 = a[:, None, None], b[:, None, None], c[:, None, None]
    e = b3 * k2
    e += a3 * k
    e[:, diag, diag] += 1.0
    jr = c3 * k2
    jr -= b3 * k
    jr[:, diag, diag] += 1.0
    return e, jr


def log(r: F64) -> F64:
    """Rotation vector of one rotation matrix (angle in [0, pi])."""
    cos = min(1.0, max(-1.0, (float(np.trace(r)) - 1.0) / 2.0))
    angle = math.acos(cos)
    w = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    if angle < 1e-6:
        out: F64 = 0.5 * w
        return out
    if angle > math.pi - 1e-4:  # near pi: axis from the symmetric part
        s = (r + np.eye(3)) / 2.0
        axis = s[int(np.argmax(np.diag(s)))]
        axis = axis / np.linalg.norm(axis)
        if float(axis @ w) < 0:
            axis = -axis
        out = angle * axis
        return out
    out = angle / (2.0 * math.sin(angle)) * w
    return out


def jr_inv(rho: F64) -> F64:
    th = float(np.linalg.norm(rho))
    k = skew(rho)
    if th < 1e-6:
        out: F64 = np.eye(3) + 0.5 * k
        return out
    coef = 1.0 / th**2 - (1.0 + math.cos(th)) / (2.0 * th * math.sin(th))
    out = np.eye(3) + 0.5 * k + coef * (k @ k)
    return out


def cumulative_product(e: F64) -> F64:
    """Inclusive running products e[0] @ e[1] @ ... @ e[i] of (M, 3, 3) matrices: a blocked scan
    (products within sqrt(M) blocks in parallel, then the blocks' own running product,
    recursively), so the Python loop runs ~2 sqrt(M) times on batches, never per sample."""
    m = e.shape[0]
    if m <= 64:
        out = e.copy()
        for i in range(1, m):
            out[i] = out[i - 1] @ out[i]
        return out
    size = math.isqrt(m)
    nb = -(-m // size)
    x = np.broadcast_to(np.eye(3), (nb * size, 3, 3)).copy()
    x[:m] = e
    x = x.reshape(nb, size, 3, 3)
    for j in range(1, size):
        x[:, j] = x[:, j - 1] @ x[:, j]
    before = cumulative_product(x[:, -1])  # running product of whole blocks
    x[1:] = before[:-1, None] @ x[1:]
    out = x.reshape(nb * size, 3, 3)[:m]
    return out
