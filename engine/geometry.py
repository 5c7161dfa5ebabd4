"""Rigid-body geometry: SE(3) matrices, quaternions (w, x, y, z) and Procrustes.

Conventions:
    * ``T_a_b`` is a 4×4 homogeneous transform mapping points in frame ``b`` to frame
      ``a``: ``p_a = T_a_b @ p_b``. Compose as ``T_a_c = T_a_b @ T_b_c``.
    * Quaternions are scalar-first ``(w, x, y, z)``, Hamilton product, unit norm, and
      map vectors from the body to the reference frame: ``v_ref = q ⊗ v_body ⊗ q*``.
    * Every function accepts leading batch dimensions where it makes sense
      (``(..., 4)`` quaternions, ``(..., 3)`` points).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.errors import InputError

FloatArray = NDArray[np.float64]


# --------------------------------------------------------------------------- SE(3)


def make_transform(R: ArrayLike, t: ArrayLike) -> FloatArray:
    """Build a 4×4 transform from a 3×3 rotation and a translation.

    Args:
        R: 3×3 rotation ``R_to_from``.
        t: ``(3,)`` translation, m (the ``from`` frame's origin in the ``to`` frame).

    Returns:
        ``T_to_from`` (4×4).
    """
    T = np.eye(4)
    T[:3, :3] = np.asarray(R, dtype=float)
    T[:3, 3] = np.asarray(t, dtype=float)
    return T


def invert_transform(T: ArrayLike) -> FloatArray:
    """Inverse of a rigid transform (uses Rᵀ, exact for rotations).

    Args:
        T: ``(..., 4, 4)`` rigid transforms ``T_a_b``.

    Returns:
        ``(..., 4, 4)`` ``T_b_a``.
    """
    T = np.asarray(T, dtype=float)
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    Ti = np.zeros_like(T)
    Rt = np.swapaxes(R, -1, -2)
    Ti[..., :3, :3] = Rt
    Ti[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, t)
    Ti[..., 3, 3] = 1.0
    return Ti


def transform_points(T: ArrayLike, points: ArrayLike) -> FloatArray:
    """Apply ``T`` (4×4) to points of shape ``(..., 3)``. NaNs propagate.

    Args:
        T: ``T_a_b`` (4×4).
        points: ``(..., 3)`` points in frame ``b``, m (e.g. ``(T, J, 3)``, time first).

    Returns:
        ``(..., 3)`` the same points in frame ``a``.
    """
    T = np.asarray(T, dtype=float)
    p = np.asarray(points, dtype=float)
    return p @ T[:3, :3].T + T[:3, 3]


def rotation_angle(R: ArrayLike) -> FloatArray:
    """Rotation angle (rad, in [0, π]) of rotation matrices ``(..., 3, 3)``.

    Args:
        R: ``(..., 3, 3)`` rotation matrices.

    Returns:
        ``(...)`` angles, rad.
    """
    R = np.asarray(R, dtype=float)
    c = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.arccos(np.clip(c, -1.0, 1.0))


def pose_error(T_est: ArrayLike, T_true: ArrayLike) -> tuple[float, float]:
    """Translation error (m) and rotation error (rad) between two poses.

    Args:
        T_est: Estimated 4×4 pose ``T_world_x``.
        T_true: True 4×4 pose of the same frame.

    Returns:
        ``(distance between the origins in m, angle of R_est·R_trueᵀ in rad)``.
    """
    T_est = np.asarray(T_est, dtype=float)
    T_true = np.asarray(T_true, dtype=float)
    dt = float(np.linalg.norm(T_est[:3, 3] - T_true[:3, 3]))
    dR = T_est[:3, :3] @ T_true[:3, :3].T
    return dt, float(rotation_angle(dR))


def skew(v: ArrayLike) -> FloatArray:
    """Cross-product matrix ``[v]×`` of a 3-vector.

    Args:
        v: ``(3,)`` vector.

    Returns:
        3×3 matrix with ``skew(v) @ u == np.cross(v, u)``.
    """
    x, y, z = np.asarray(v, dtype=float)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def so3_exp(w: ArrayLike) -> FloatArray:
    """Rotation matrix of a rotation vector (axis × angle, rad) via Rodrigues.

    Args:
        w: ``(3,)`` rotation vector, rad.

    Returns:
        3×3 rotation matrix (first order below 1e-12 rad).
    """
    w = np.asarray(w, dtype=float)
    theta = float(np.linalg.norm(w))
    if theta < 1e-12:
        return np.eye(3) + skew(w)
    K = skew(w / theta)
    return np.eye(3) + np.sin(theta) * K + (1.0 - np.cos(theta)) * (K @ K)


def so3_log(R: ArrayLike) -> FloatArray:
    """Rotation vector of a rotation matrix (inverse of :func:`so3_exp`).

    Args:
        R: ``(..., 3, 3)`` rotation matrices.

    Returns:
        ``(..., 3)`` rotation vectors, rad (angle in [0, π]).
    """
    return quat_to_rotvec(quat_from_matrix(R))


def look_at(eye: ArrayLike, target: ArrayLike, up: ArrayLike = (0.0, 0.0, 1.0)) -> FloatArray:
    """``T_world_camera`` for a camera at ``eye`` looking at ``target``.

    Camera frame follows the OpenCV/Kinect depth convention: +Z forward (optical axis),
    +X right in the image, +Y down in the image.

    Args:
        eye: ``(3,)`` camera centre in the world, m.
        target: ``(3,)`` world point on the optical axis, m.
        up: World up direction (the image's −Y points as close to it as possible).

    Returns:
        ``T_world_camera`` (4×4).

    Raises:
        InputError: the viewing direction is parallel to ``up``.
    """
    eye = np.asarray(eye, dtype=float)
    z = np.asarray(target, dtype=float) - eye
    z /= np.linalg.norm(z)
    up = np.asarray(up, dtype=float)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:
        raise InputError("look_at: viewing direction is parallel to 'up'")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_transform(np.stack([x, y, z], axis=1), eye)


# ---------------------------------------------------------------------- quaternions


def quat_normalize(q: ArrayLike) -> FloatArray:
    """Quaternions ``(..., 4)`` scaled to unit norm (w-first; the sign is kept).

    Args:
        q: ``(..., 4)`` quaternions, w first; a zero quaternion gives NaN.

    Returns:
        ``(..., 4)`` unit quaternions.
    """
    q = np.asarray(q, dtype=float)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quat_conj(q: ArrayLike) -> FloatArray:
    """Conjugate (= inverse for unit quaternions).

    Args:
        q: ``(..., 4)`` quaternions, w first.

    Returns:
        ``(..., 4)`` ``(w, −x, −y, −z)``.
    """
    q = np.asarray(q, dtype=float)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def quat_mul(p: ArrayLike, q: ArrayLike) -> FloatArray:
    """Hamilton product ``p ⊗ q`` (broadcasting over leading axes).

    Args:
        p: ``(..., 4)`` quaternions, w first (e.g. ``q_a_b``).
        q: ``(..., 4)`` quaternions, w first (e.g. ``q_b_c``).

    Returns:
        ``(..., 4)`` the product (``q_a_c``).
    """
    p = np.asarray(p, dtype=float)
    q = np.asarray(q, dtype=float)
    pw, px, py, pz = np.moveaxis(p, -1, 0)
    qw, qx, qy, qz = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        axis=-1,
    )


def quat_rotate(q: ArrayLike, v: ArrayLike) -> FloatArray:
    """Rotate vectors ``v`` (..., 3) by unit quaternions ``q`` (..., 4).

    Args:
        q: ``(..., 4)`` unit quaternions ``q_a_b``, w first.
        v: ``(..., 3)`` vectors in frame ``b``.

    Returns:
        ``(..., 3)`` the vectors in frame ``a`` (``q ⊗ v ⊗ q*``).
    """
    q = np.asarray(q, dtype=float)
    v = np.asarray(v, dtype=float)
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def quat_from_axis_angle(axis: ArrayLike, angle: ArrayLike) -> FloatArray:
    """Unit quaternion of a rotation by ``angle`` (rad) about ``axis`` (right-hand rule).

    Args:
        axis: ``(..., 3)`` rotation axes (any length, normalised here).
        angle: ``(...)`` angles, rad.

    Returns:
        ``(..., 4)`` unit quaternions, w first.
    """
    axis = np.asarray(axis, dtype=float)
    axis = axis / np.linalg.norm(axis, axis=-1, keepdims=True)
    half = 0.5 * np.asarray(angle, dtype=float)[..., None]
    return np.concatenate([np.cos(half), np.sin(half) * axis], axis=-1)


def quat_from_rotvec(rv: ArrayLike) -> FloatArray:
    """Unit quaternion of a rotation vector (axis × angle, rad); exact near zero.

    Args:
        rv: ``(..., 3)`` rotation vectors, rad.

    Returns:
        ``(..., 4)`` unit quaternions, w first (w ≥ 0 for angles ≤ π).
    """
    rv = np.asarray(rv, dtype=float)
    theta = np.linalg.norm(rv, axis=-1, keepdims=True)
    half = 0.5 * theta
    # sinc-safe scale sin(θ/2)/θ
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(theta > 1e-12, np.sin(half) / np.where(theta > 0, theta, 1.0), 0.5)
    return np.concatenate([np.cos(half), scale * rv], axis=-1)


def quat_to_rotvec(q: ArrayLike) -> FloatArray:
    """Rotation vector (axis × angle, rad; angle in [0, π]) of quaternions.

    Args:
        q: ``(..., 4)`` quaternions, w first (normalised here; ``q`` and ``-q`` give the same
            result, the shortest rotation).

    Returns:
        ``(..., 3)`` rotation vectors, rad.
    """
    q = quat_normalize(q)
    q = np.where(q[..., :1] < 0, -q, q)  # shortest rotation
    w = np.clip(q[..., 0], -1.0, 1.0)
    s = np.linalg.norm(q[..., 1:], axis=-1)
    angle = 2.0 * np.arctan2(s, w)
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(s > 1e-12, angle / np.where(s > 0, s, 1.0), 2.0)
    return q[..., 1:] * scale[..., None]


def quat_to_matrix(q: ArrayLike) -> FloatArray:
    """Rotation matrices of quaternions (``R @ v`` rotates as :func:`quat_rotate`).

    Args:
        q: ``(..., 4)`` quaternions, w first (normalised here).

    Returns:
        ``(..., 3, 3)`` rotation matrices.
    """
    q = quat_normalize(q)
    w, x, y, z = np.moveaxis(q, -1, 0)
    R = np.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        axis=-1,
    )
    return R.reshape((*q.shape[:-1], 3, 3))


def quat_from_matrix(R: ArrayLike) -> FloatArray:
    """Unit quaternion (w ≥ 0) of rotation matrices ``(..., 3, 3)`` (Shepperd's method).

    Args:
        R: ``(..., 3, 3)`` rotation matrices.

    Returns:
        ``(..., 4)`` unit quaternions, w first, w ≥ 0.
    """
    R = np.asarray(R, dtype=float)
    batch = R.shape[:-2]
    Rf = R.reshape(-1, 3, 3)
    out = np.empty((Rf.shape[0], 4))
    for i, m in enumerate(Rf):
        tr = m[0, 0] + m[1, 1] + m[2, 2]
        if tr > 0:
            s = 2.0 * np.sqrt(tr + 1.0)
            out[i] = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s,
                      (m[1, 0] - m[0, 1]) / s]
        elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
            s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
            out[i] = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s,
                      (m[0, 2] + m[2, 0]) / s]
        elif m[1, 1] > m[2, 2]:
            s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
            out[i] = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s,
                      (m[1, 2] + m[2, 1]) / s]
        else:
            s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
            out[i] = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s,
                      (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    out = np.where(out[:, :1] < 0, -out, out)
    out /= np.linalg.norm(out, axis=-1, keepdims=True)
    return out.reshape((*batch, 4))


def quat_angle(q: ArrayLike) -> FloatArray:
    """Rotation angle (rad, [0, π]) of unit quaternions.

    Args:
        q: ``(..., 4)`` quaternions, w first (normalised here).

    Returns:
        ``(...)`` angles, rad.
    """
    q = quat_normalize(q)
    return 2.0 * np.arccos(np.clip(np.abs(q[..., 0]), 0.0, 1.0))


def quat_slerp(q0: ArrayLike, q1: ArrayLike, u: ArrayLike) -> FloatArray:
    """Spherical linear interpolation for ``u`` in [0, 1] (shortest path).

    Args:
        q0: ``(..., 4)`` start quaternions, w first.
        q1: ``(..., 4)`` end quaternions.
        u: ``(...)`` interpolation fractions (0 → ``q0``, 1 → ``q1``).

    Returns:
        ``(..., 4)`` unit quaternions.
    """
    q0 = quat_normalize(q0)
    q1 = quat_normalize(q1)
    u = np.asarray(u, dtype=float)[..., None]
    d = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(d < 0, -q1, q1)
    d = np.abs(d)
    theta = np.arccos(np.clip(d, -1.0, 1.0))
    s = np.sin(theta)
    small = s < 1e-8
    with np.errstate(invalid="ignore", divide="ignore"):
        a = np.where(small, 1.0 - u, np.sin((1.0 - u) * theta) / np.where(small, 1.0, s))
        b = np.where(small, u, np.sin(u * theta) / np.where(small, 1.0, s))
    return quat_normalize(a * q0 + b * q1)


# ----------------------------------------------------------------------- Procrustes


def procrustes(src: ArrayLike, dst: ArrayLike, weights: ArrayLike | None = None) -> FloatArray:
    """Rigid transform (no scale) ``T_dst_src`` minimising Σ wᵢ‖T·srcᵢ − dstᵢ‖².

    Kabsch/Umeyama with the reflection guard. Rows with NaN in either set are ignored.

    Args:
        src: ``(N, 3)`` points in the source frame.
        dst: ``(N, 3)`` corresponding points in the destination frame.
        weights: ``(N,)`` non-negative weights; None: equal.

    Returns:
        ``T_dst_src`` (4×4, ``dst ≈ T @ src``).

    Raises:
        InputError: fewer than three usable, non-collinear correspondences.
    """
    P = np.asarray(src, dtype=float).reshape(-1, 3)
    Q = np.asarray(dst, dtype=float).reshape(-1, 3)
    if P.shape != Q.shape:
        raise InputError(f"procrustes: shapes differ {P.shape} vs {Q.shape}")
    w = np.ones(P.shape[0]) if weights is None else np.asarray(weights, dtype=float).ravel()
    ok = np.isfinite(P).all(1) & np.isfinite(Q).all(1) & (w > 0)
    P, Q, w = P[ok], Q[ok], w[ok]
    if P.shape[0] < 3:
        raise InputError("procrustes: need at least 3 point correspondences")
    w = w / w.sum()
    cs = w @ P
    cd = w @ Q
    H = (P - cs).T @ ((Q - cd) * w[:, None])
    U, S, Vt = np.linalg.svd(H)
    if S[1] < 1e-12 * max(S[0], 1e-300):
        raise InputError("procrustes: points are collinear; rotation is undetermined")
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0])
    R = Vt.T @ D @ U.T
    return make_transform(R, cd - R @ cs)
