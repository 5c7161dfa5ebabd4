"""Madgwick's gradient-descent orientation filter (IMU 6D and MARG 9D variants).

Implements S. O. H. Madgwick, "An efficient orientation filter for inertial and
inertial/magnetic sensor arrays" (2010), eqs. (12), (13), (25)-(34), (45)-(46) and the
optional gyroscope bias drift compensation (47)-(49) (gain ζ, off by default), the filter
used by the IMU-fusion seed paper (002). The update order and initial-state handling match
``ahrs.filters.Madgwick`` so that both produce the same quaternions for the same input.

Conventions:
    * Quaternions are w-first and sensor-to-earth (``v_earth = q ⊗ v_sensor ⊗ q*``).
    * Madgwick's earth frame is *NWU* (x = horizontal magnetic north, y = west, z = up):
      gravity reference ``(0, 0, 1)``, magnetic reference ``(b_x, 0, b_z)``. Pass
      ``frame="ENU"`` to get (and give ``q0`` in) east-north-up instead; the two differ by
      a constant 90° rotation about z.
    * Inputs are ``(T, 3)`` for one sensor or ``(T, S, 3)`` for ``S`` sensors sampled
      together; time is the first axis. gyr in rad/s, acc in any unit (normalised), mag in
      any unit (normalised).
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from engine.errors import InputError
from engine.geometry import quat_from_matrix, quat_mul

FloatArray = NDArray[np.float64]
Frame = Literal["NWU", "ENU"]

#: Rotation taking NWU earth coordinates to ENU: +90° about z (north: x_NWU -> y_ENU).
Q_ENU_NWU: FloatArray = np.array([np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)])


def as_sensor_array(x: ArrayLike, name: str) -> FloatArray:
    """Return ``x`` as a float ``(T, S, 3)`` array (a ``(T, 3)`` input becomes ``S = 1``).

    Args:
        x: ``(T, 3)`` or ``(T, S, 3)`` samples.
        name: Its name, for the message.

    Returns:
        ``(T, S, 3)`` float array.

    Raises:
        InputError: wrong shape.
    """
    a = np.asarray(x, dtype=float)
    if a.ndim == 2:
        a = a[:, None, :]
    if a.ndim != 3 or a.shape[-1] != 3:
        raise InputError(f"{name} must have shape (T, 3) or (T, S, 3), got {np.shape(x)}")
    return np.ascontiguousarray(a)


def sensor_inputs(gyr: ArrayLike, acc: ArrayLike, mag: ArrayLike | None
                  ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Gyroscope, accelerometer and magnetometer as ``(T, S, 3)`` arrays of one shape
    (magnetometer zeros when absent).

    Args:
        gyr: ``(T, 3)`` or ``(T, S, 3)`` angular rate, rad/s.
        acc: Accelerometer, same shape.
        mag: Magnetometer, same shape, or None.

    Returns:
        ``(gyr, acc, mag)`` as ``(T, S, 3)`` float arrays.

    Raises:
        InputError: the three do not have the same shape.
    """
    g = as_sensor_array(gyr, "gyr")
    a = as_sensor_array(acc, "acc")
    if a.shape != g.shape:
        raise InputError(f"acc shape {a.shape} differs from gyr shape {g.shape}")
    m = np.zeros_like(g) if mag is None else as_sensor_array(mag, "mag")
    if m.shape != g.shape:
        raise InputError(f"mag shape {m.shape} differs from gyr shape {g.shape}")
    return g, a, m


def to_enu(q: ArrayLike) -> FloatArray:
    """Convert sensor-to-NWU quaternions to sensor-to-ENU (``q_ENU = q_ENU_NWU ⊗ q``).

    Args:
        q: ``(..., 4)`` sensor-to-NWU quaternions, w first (Madgwick's default frame).

    Returns:
        ``(..., 4)`` sensor-to-ENU quaternions.
    """
    return quat_mul(Q_ENU_NWU, q)


def from_enu(q: ArrayLike) -> FloatArray:
    """Convert sensor-to-ENU quaternions to sensor-to-NWU.

    Args:
        q: ``(..., 4)`` sensor-to-ENU quaternions, w first.

    Returns:
        ``(..., 4)`` sensor-to-NWU quaternions.
    """
    return quat_mul(Q_ENU_NWU * np.array([1.0, -1.0, -1.0, -1.0]), q)


def initial_orientation(
    acc: ArrayLike, mag: ArrayLike | None = None, frame: Frame = "NWU"
) -> FloatArray:
    """Sensor-to-earth quaternion(s) from one accelerometer (and magnetometer) sample.

    The accelerometer at rest measures the upward specific force, which fixes the earth z
    axis; the horizontal part of the magnetic field fixes north (TRIAD). Without a
    magnetometer, the heading is chosen so that the sensor x axis has zero yaw (or the y
    axis when x is vertical).

    Args:
        acc: ``(3,)`` or ``(S, 3)`` accelerometer sample(s).
        mag: same shape, magnetometer sample(s), or ``None``.
        frame: earth frame of the result, ``"NWU"`` (Madgwick's) or ``"ENU"``.

    Returns:
        ``(4,)`` or ``(S, 4)`` unit quaternions, w-first.

    Raises:
        InputError: zero or non-finite acceleration, or magnetic field parallel to gravity.
    """
    a = np.asarray(acc, dtype=float)
    single = a.ndim == 1
    a = np.atleast_2d(a)
    na = np.linalg.norm(a, axis=-1, keepdims=True)
    if not np.all(np.isfinite(na)) or np.any(na == 0):
        raise InputError("initial orientation needs a finite, non-zero accelerometer sample")
    z = a / na
    if mag is None:
        ref = np.tile([1.0, 0.0, 0.0], (len(z), 1))
        steep = np.abs(z[:, 0]) > 0.9
        ref[steep] = [0.0, 1.0, 0.0]
    else:
        ref = np.atleast_2d(np.asarray(mag, dtype=float))
    x = ref - np.sum(ref * z, axis=-1, keepdims=True) * z
    nx = np.linalg.norm(x, axis=-1, keepdims=True)
    if not np.all(np.isfinite(nx)) or np.any(nx < 1e-9 * np.linalg.norm(ref, axis=-1,
                                                                         keepdims=True)):
        raise InputError("magnetic field is parallel to gravity; heading is undetermined")
    x = x / nx
    y = np.cross(z, x)
    # Rows are the earth axes in sensor coordinates, i.e. R maps sensor -> earth (NWU).
    R = np.stack([x, y, z], axis=-2)
    q = quat_from_matrix(R)
    if frame == "ENU":
        q = to_enu(q)
    elif frame != "NWU":
        raise InputError(f"frame must be 'NWU' or 'ENU', got {frame!r}")
    return q[0] if single else q


#: Gradient norm below which the objective is at its minimum (no correction step): the
#: gradient's terms are products of unit quaternions and residuals of at most 2, so a
#: residual at double-precision rounding gives a norm around 1e-16.
_GRAD_ZERO = 1e-12


@njit(cache=True, fastmath=False)
def _madgwick_loop(
    gyr: FloatArray, acc: FloatArray, mag: FloatArray, use_mag: bool, q0: FloatArray,
    beta: float, dt: float, zeta: float,
) -> FloatArray:
    """Per-sample Madgwick update for ``S`` sensors; row 0 is ``q0`` (as in ``ahrs``)."""
    T, S = gyr.shape[0], gyr.shape[1]
    out = np.empty((T, S, 4))
    for s in range(S):
        qw, qx, qy, qz = q0[s, 0], q0[s, 1], q0[s, 2], q0[s, 3]
        n = np.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        qw, qx, qy, qz = qw / n, qx / n, qy / n, qz / n
        out[0, s, 0], out[0, s, 1], out[0, s, 2], out[0, s, 3] = qw, qx, qy, qz
        bx_, by_, bz_ = 0.0, 0.0, 0.0  # gyro bias (MARG drift compensation, eq. 48)
        for t in range(1, T):
            gx, gy, gz = gyr[t, s, 0], gyr[t, s, 1], gyr[t, s, 2]
            if not (np.isfinite(gx) and np.isfinite(gy) and np.isfinite(gz)):
                # No rate measurement: hold the last orientation.
                out[t, s, 0], out[t, s, 1], out[t, s, 2], out[t, s, 3] = qw, qx, qy, qz
                continue
            g0, g1, g2, g3, gn = 0.0, 0.0, 0.0, 0.0, 0.0
            ax, ay, az = acc[t, s, 0], acc[t, s, 1], acc[t, s, 2]
            an = np.sqrt(ax * ax + ay * ay + az * az)
            if an > 0.0 and np.isfinite(an):
                ax, ay, az = ax / an, ay / an, az / an
                mx, my, mz = mag[t, s, 0], mag[t, s, 1], mag[t, s, 2]
                mn = np.sqrt(mx * mx + my * my + mz * mz)
                f0 = 2.0 * (qx * qz - qw * qy) - ax
                f1 = 2.0 * (qw * qx + qy * qz) - ay
                f2 = 2.0 * (0.5 - qx * qx - qy * qy) - az
                g0 = -2.0 * qy * f0 + 2.0 * qx * f1
                g1 = 2.0 * qz * f0 + 2.0 * qw * f1 - 4.0 * qx * f2
                g2 = -2.0 * qw * f0 + 2.0 * qz * f1 - 4.0 * qy * f2
                g3 = 2.0 * qx * f0 + 2.0 * qy * f1
                if use_mag and mn > 0.0 and np.isfinite(mn):
                    mx, my, mz = mx / mn, my / mn, mz / mn
                    # Field in the earth frame h = q ⊗ m ⊗ q* (eq. 45), reference b (eq. 46)
                    hx = ((1.0 - 2.0 * (qy * qy + qz * qz)) * mx
                          + 2.0 * (qx * qy - qw * qz) * my + 2.0 * (qx * qz + qw * qy) * mz)
                    hy = (2.0 * (qx * qy + qw * qz) * mx
                          + (1.0 - 2.0 * (qx * qx + qz * qz)) * my
                          + 2.0 * (qy * qz - qw * qx) * mz)
                    hz = (2.0 * (qx * qz - qw * qy) * mx + 2.0 * (qy * qz + qw * qx) * my
                          + (1.0 - 2.0 * (qx * qx + qy * qy)) * mz)
                    bx = np.sqrt(hx * hx + hy * hy)
                    bz = hz
                    # Magnetic part of the objective (eq. 31) and its Jacobian (eq. 32)
                    f3 = 2.0 * bx * (0.5 - qy * qy - qz * qz) + 2.0 * bz * (qx * qz - qw * qy) - mx
                    f4 = 2.0 * bx * (qx * qy - qw * qz) + 2.0 * bz * (qw * qx + qy * qz) - my
                    f5 = 2.0 * bx * (qw * qy + qx * qz) + 2.0 * bz * (0.5 - qx * qx - qy * qy) - mz
                    g0 += -2.0 * bz * qy * f3 + (-2.0 * bx * qz + 2.0 * bz * qx) * f4 \
                        + 2.0 * bx * qy * f5
                    g1 += 2.0 * bz * qz * f3 + (2.0 * bx * qy + 2.0 * bz * qw) * f4 \
                        + (2.0 * bx * qz - 4.0 * bz * qx) * f5
                    g2 += (-4.0 * bx * qy - 2.0 * bz * qw) * f3 \
                        + (2.0 * bx * qx + 2.0 * bz * qz) * f4 \
                        + (2.0 * bx * qw - 4.0 * bz * qy) * f5
                    g3 += (-4.0 * bx * qz + 2.0 * bz * qx) * f3 \
                        + (-2.0 * bx * qw + 2.0 * bz * qy) * f4 + 2.0 * bx * qx * f5
                gn = np.sqrt(g0 * g0 + g1 * g1 + g2 * g2 + g3 * g3)
                if gn < _GRAD_ZERO:
                    # the measurements fit q exactly (e.g. q0 from this very sample): the
                    # gradient is zero, and normalising its rounding noise would step β·dt
                    # in an arbitrary direction (which one depends on the numpy build)
                    gn = 0.0
            if gn > 0.0 and zeta > 0.0:
                # Gyro bias drift compensation (eqs. 47-49): ω_ε = 2 q* ⊗ ∇f/|∇f|
                ex = 2.0 * (qw * g1 - qx * g0 - qy * g3 + qz * g2) / gn
                ey = 2.0 * (qw * g2 + qx * g3 - qy * g0 - qz * g1) / gn
                ez = 2.0 * (qw * g3 - qx * g2 + qy * g1 - qz * g0) / gn
                bx_ += zeta * ex * dt
                by_ += zeta * ey * dt
                bz_ += zeta * ez * dt
                gx, gy, gz = gx - bx_, gy - by_, gz - bz_
            # Rate of change from the gyroscope, q̇ = ½ q ⊗ (0, ω)  (eq. 12)
            dw = 0.5 * (-qx * gx - qy * gy - qz * gz)
            dx = 0.5 * (qw * gx + qy * gz - qz * gy)
            dy = 0.5 * (qw * gy - qx * gz + qz * gx)
            dz = 0.5 * (qw * gz + qx * gy - qy * gx)
            if gn > 0.0:
                # Normalised gradient step (eqs. 33-34)
                dw -= beta * g0 / gn
                dx -= beta * g1 / gn
                dy -= beta * g2 / gn
                dz -= beta * g3 / gn
            # Integrate (eq. 13) and renormalise
            qw, qx, qy, qz = qw + dw * dt, qx + dx * dt, qy + dy * dt, qz + dz * dt
            n = np.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
            qw, qx, qy, qz = qw / n, qx / n, qy / n, qz / n
            out[t, s, 0], out[t, s, 1], out[t, s, 2], out[t, s, 3] = qw, qx, qy, qz
    return out


def madgwick(
    gyr: ArrayLike,
    acc: ArrayLike,
    mag: ArrayLike | None = None,
    *,
    beta: float = 0.041,
    frequency: float = 100.0,
    q0: ArrayLike | None = None,
    frame: Frame = "NWU",
    zeta: float = 0.0,
) -> FloatArray:
    """Run Madgwick's filter over whole recordings (pure function).

    Args:
        gyr: ``(T, 3)`` or ``(T, S, 3)`` angular rate, rad/s.
        acc: same shape, accelerometer (any unit).
        mag: same shape, magnetometer (any unit), or ``None`` for the IMU (6D) variant.
        beta: gradient-step gain β (rad/s).
        frequency: sampling rate, Hz (constant step ``1/frequency``).
        q0: ``(4,)`` or ``(S, 4)`` initial sensor-to-earth quaternion in ``frame``; by
            default computed from the first accelerometer (and magnetometer) sample.
        frame: earth frame of ``q0`` and of the result, ``"NWU"`` or ``"ENU"``.
        zeta: gain ζ of the report's gyroscope bias drift compensation (eqs. 47-49, rad/s²
            scale); 0 (default, as ``ahrs``) disables it.

    Returns:
        ``(T, 4)`` or ``(T, S, 4)`` quaternions (same leading shape as ``gyr``), w-first.

    Raises:
        InputError: shape mismatch, non-positive gain/rate, unusable first sample.
    """
    single = np.ndim(gyr) == 2
    g, a, m = sensor_inputs(gyr, acc, mag)
    if not (np.isfinite(beta) and beta >= 0):
        raise InputError(f"beta must be a finite non-negative gain, got {beta}")
    if not (np.isfinite(zeta) and zeta >= 0):
        raise InputError(f"zeta must be a finite non-negative gain, got {zeta}")
    if not (np.isfinite(frequency) and frequency > 0):
        raise InputError(f"frequency must be positive (Hz), got {frequency}")
    if frame not in ("NWU", "ENU"):
        raise InputError(f"frame must be 'NWU' or 'ENU', got {frame!r}")
    if len(g) == 0:
        raise InputError("no samples")
    S = g.shape[1]
    if q0 is None:
        init = initial_orientation(a[0], None if mag is None else m[0], "NWU")
    else:
        init = np.broadcast_to(np.asarray(q0, dtype=float), (S, 4)).copy()
        if not np.all(np.isfinite(init)) or np.any(np.linalg.norm(init, axis=-1) == 0):
            raise InputError("q0 must be finite non-zero quaternions (w, x, y, z)")
        if frame == "ENU":
            init = from_enu(init)
    q = _madgwick_loop(g, a, m, mag is not None, np.ascontiguousarray(init), float(beta),
                       1.0 / float(frequency), float(zeta))
    if frame == "ENU":
        q = to_enu(q)
    return q[:, 0] if single else q


class Madgwick:
    """Estimator-object wrapper of :func:`madgwick`.

    Example:
        >>> q = Madgwick(beta=0.041, frequency=256.0).fit(gyr, acc, mag).quat_

    Attributes:
        quat_: ``(T, 4)`` or ``(T, S, 4)`` orientation after :meth:`fit`.
    """

    def __init__(self, beta: float = 0.041, frequency: float = 100.0,
                 frame: Frame = "NWU", zeta: float = 0.0) -> None:
        self.beta = beta
        self.zeta = zeta
        self.frequency = frequency
        self.frame: Frame = frame
        self.quat_: FloatArray | None = None

    def fit(self, gyr: ArrayLike, acc: ArrayLike, mag: ArrayLike | None = None,
            q0: ArrayLike | None = None) -> Madgwick:
        """Filter a recording; the result is stored in ``quat_``.

        Args:
            gyr: ``(T, 3)`` or ``(T, S, 3)`` angular rate, rad/s (time first axis).
            acc: Same shape, accelerometer (any unit).
            mag: Same shape, magnetometer (any unit), or None for the 6D variant.
            q0: Initial sensor-to-earth quaternion(s) in ``frame``; default from the first
                accelerometer (and magnetometer) sample.

        Returns:
            ``self`` (``quat_``: sensor-to-earth in ``frame``, w first).
        """
        self.quat_ = madgwick(gyr, acc, mag, beta=self.beta, frequency=self.frequency, q0=q0,
                              frame=self.frame, zeta=self.zeta)
        return self
