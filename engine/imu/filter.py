"""gaitrig's orientation filter: inertial-frame inclination, gated heading, bias tracking.

Ideas (after Laidig & Seel 2023, "VQF", implemented independently here):

* The gyroscope is integrated (after bias removal) into a strapdown quaternion ``q_g``
  relative to an *almost-inertial* frame ``I`` that only drifts slowly.
* The accelerometer sample is rotated into ``I`` and low-pass filtered there (2nd-order
  Butterworth, time constant ``tau_acc``). In an inertial frame linear accelerations
  integrate to velocity changes and so average out, while gravity stays put; the filtered
  vector is therefore a clean estimate of "up" even during vigorous motion. An
  inclination correction ``q_inc`` rotates it onto +z at every sample. This averaging is
  also the rejection of acceleration disturbances (impacts, tapping, vibration): gating
  samples by ``|a|`` instead would break the velocity average (measured on BROAD: 6D
  inclination error 0.65° -> 5°), so every sample is kept.
* Heading is a separate rotation ``δ`` about z, fused from the magnetometer's horizontal
  direction with time constant ``tau_mag``; samples whose field norm or dip angle leave
  the learnt reference (magnetic disturbance) are rejected. A new field is adopted only
  when it stays homogeneous (constant norm and dip) for ``mag_new_time`` seconds while the
  sensor rotates — a magnet carried with the sensor changes norm and dip with orientation
  and is never adopted. After a rejection the field must be clean for
  ``mag_min_undisturbed_t`` before it is used again, then a raised gain catches up on the
  heading drift accumulated meanwhile.
* Gyroscope bias: a rest detector (low gyro and acceleration variation for
  ``rest_min_t``) averages the raw rate into the bias; during motion, the corrections
  applied by inclination (and heading) are fed back as an integral term.
* ``offline=True`` (recorded data): a time-reversed pass supplies the bias at the start,
  and the inclination (and, in clean magnetic field, heading) corrections are low-passed
  zero-phase (no lag), see :func:`_offline`.

Output frame: ENU (x east, y north, z up), quaternions w-first, sensor-to-earth.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray
from scipy.signal import butter

from engine.errors import InputError
from engine.imu.madgwick import sensor_inputs

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class FilterParams:
    """Tuning of :class:`OrientationFilter` (SI units: s, rad/s, m/s²).

    Attributes:
        tau_acc: time constant of the inertial-frame acceleration low-pass (inclination).
        tau_mag: time constant of the heading correction from the magnetometer.
        bias_tau_motion: time constant of the bias integral fed by corrections in motion.
        bias_tau_rest: time constant of the bias average at rest.
        bias_clip: largest plausible gyroscope bias norm, rad/s.
        rest_min_t: how long the rest conditions must hold before rest is declared.
        rest_tau: low-pass time constant of the rest detector's gyro/acc references.
        rest_th_gyr: largest gyro deviation from its low-pass at rest, rad/s.
        rest_th_acc: largest acceleration deviation from its low-pass at rest, m/s².
        mag_current_tau: smoothing of the current field norm and dip.
        mag_ref_tau: learning time constant of the reference norm and dip.
        mag_norm_th: relative norm deviation that counts as a disturbance.
        mag_dip_th: dip-angle deviation that counts as a disturbance, rad.
        mag_new_time: how long a new homogeneous field must persist to be adopted.
        mag_init_time: initial period of fast (averaging) heading convergence.
        mag_new_min_gyr: rotation rate that counts as "moving" for adopting a new field.
        mag_rejection_factor: gain multiplier after a disturbance ends.
        mag_min_undisturbed_t: clean time needed before the field is used again.
        mag_clean_fraction: offline mode: the zero-phase heading is used where at least
            this fraction of the magnetometer samples nearby (within ~``tau_mag``) was
            accepted by both passes; elsewhere the forward pass' heading.
    """

    tau_acc: float = 3.0
    tau_mag: float = 9.0
    bias_tau_motion: float = 150.0
    bias_tau_rest: float = 3.0
    bias_clip: float = np.deg2rad(2.0)
    rest_min_t: float = 1.5
    rest_tau: float = 0.5
    rest_th_gyr: float = np.deg2rad(2.0)
    rest_th_acc: float = 0.5
    mag_current_tau: float = 0.05
    mag_ref_tau: float = 20.0
    mag_norm_th: float = 0.1
    mag_dip_th: float = np.deg2rad(10.0)
    mag_new_time: float = 20.0
    mag_init_time: float = 3.0
    mag_new_min_gyr: float = np.deg2rad(20.0)
    mag_rejection_factor: float = 2.0
    mag_min_undisturbed_t: float = 0.5
    mag_clean_fraction: float = 0.95


def _butter_coeffs(tau: float, fs: float) -> tuple[FloatArray, FloatArray]:
    """2nd-order Butterworth low-pass with cut-off ``√2/(2π τ)`` (time constant ``τ``)."""
    fc = np.sqrt(2.0) / (2.0 * np.pi * tau)
    fc = min(fc, 0.45 * fs)
    b, a = butter(2, fc, fs=fs)
    return np.asarray(b, dtype=float), np.asarray(a, dtype=float)


@njit(cache=True)
def _wrap(x: float) -> float:
    return (x + np.pi) % (2.0 * np.pi) - np.pi


@njit(cache=True)
def _rotate(qw: float, qx: float, qy: float, qz: float, vx: float, vy: float,
            vz: float) -> tuple[float, float, float]:
    # v' = q ⊗ v ⊗ q*  via  t = 2 u×v ; v' = v + w t + u×t
    tx = 2.0 * (qy * vz - qz * vy)
    ty = 2.0 * (qz * vx - qx * vz)
    tz = 2.0 * (qx * vy - qy * vx)
    return (vx + qw * tx + (qy * tz - qz * ty),
            vy + qw * ty + (qz * tx - qx * tz),
            vz + qw * tz + (qx * ty - qy * tx))


@njit(cache=True)
def _qmul(aw: float, ax: float, ay: float, az: float, bw: float, bx: float, by: float,
          bz: float) -> tuple[float, float, float, float]:
    return (aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw)


@njit(cache=True)
def _filter_loop(
    gyr: FloatArray, acc: FloatArray, mag: FloatArray, use_mag: bool, dt: float,
    bb: FloatArray, ba: FloatArray, p: FloatArray, bias0: FloatArray,
) -> tuple[FloatArray, FloatArray, NDArray[np.bool_], NDArray[np.bool_]]:
    """Causal filter over ``(T, S, 3)`` inputs, starting from gyro bias ``bias0`` (S, 3).

    Returns quaternions (T,S,4), bias (T,S,3), rest flags (T,S) and flags of the
    magnetometer samples used for heading (T,S).
    """
    tau_mag, bias_tau_motion, bias_tau_rest, bias_clip = p[0], p[1], p[2], p[3]
    rest_min_t, rest_tau, rest_th_gyr, rest_th_acc = p[4], p[5], p[6], p[7]
    mag_cur_tau, mag_ref_tau, mag_norm_th, mag_dip_th = p[8], p[9], p[10], p[11]
    mag_new_time, mag_init_time = p[12], p[13]
    mag_new_min_gyr, mag_rejection_factor, mag_min_undisturbed_t = p[14], p[15], p[16]
    T, S = gyr.shape[0], gyr.shape[1]
    out = np.empty((T, S, 4))
    bias_out = np.empty((T, S, 3))
    rest_out = np.zeros((T, S), dtype=np.bool_)
    mag_ok_out = np.zeros((T, S), dtype=np.bool_)
    k_rest = 1.0 - np.exp(-dt / rest_tau)
    k_bias_rest = 1.0 - np.exp(-dt / bias_tau_rest)
    k_mag = 1.0 - np.exp(-dt / tau_mag)
    k_magcur = 1.0 - np.exp(-dt / mag_cur_tau)
    k_magref = 1.0 - np.exp(-dt / mag_ref_tau)
    for s in range(S):
        gw, gx, gy, gz = 1.0, 0.0, 0.0, 0.0          # strapdown q_g (sensor -> I)
        iw, ix, iy, iz = 1.0, 0.0, 0.0, 0.0          # inclination correction (I -> I')
        delta = 0.0                                   # heading (I' -> ENU) about z
        b0, b1, b2 = bias0[s, 0], bias0[s, 1], bias0[s, 2]  # gyro bias estimate
        # Butterworth state (direct form II transposed) per axis
        z1 = np.zeros(3)
        z2 = np.zeros(3)
        lp_init = False
        # rest detection
        rg = np.zeros(3)
        ra = np.zeros(3)
        rest_t = 0.0
        rest_init = False
        # magnetometer
        mag_seen = 0.0
        ref_norm, ref_dip = 0.0, 0.0
        cur_norm, cur_dip = 0.0, 0.0
        mag_init = False
        dist_t = 0.0
        cand_norm, cand_dip, cand_motion = 0.0, 0.0, 0.0
        reject_t = 0.0
        undist_t = 1e9
        for t in range(T):
            wx, wy, wz = gyr[t, s, 0], gyr[t, s, 1], gyr[t, s, 2]
            gyr_ok = np.isfinite(wx) and np.isfinite(wy) and np.isfinite(wz)
            ax, ay, az = acc[t, s, 0], acc[t, s, 1], acc[t, s, 2]
            acc_ok = np.isfinite(ax) and np.isfinite(ay) and np.isfinite(az) and \
                (ax * ax + ay * ay + az * az) > 0.0
            # ---------------------------------------------------------------- rest
            is_rest = False
            if gyr_ok and acc_ok:
                if not rest_init:
                    rg[0], rg[1], rg[2] = wx, wy, wz
                    ra[0], ra[1], ra[2] = ax, ay, az
                    rest_init = True
                rg[0] += k_rest * (wx - rg[0])
                rg[1] += k_rest * (wy - rg[1])
                rg[2] += k_rest * (wz - rg[2])
                ra[0] += k_rest * (ax - ra[0])
                ra[1] += k_rest * (ay - ra[1])
                ra[2] += k_rest * (az - ra[2])
                dg = np.sqrt((wx - rg[0]) ** 2 + (wy - rg[1]) ** 2 + (wz - rg[2]) ** 2)
                da = np.sqrt((ax - ra[0]) ** 2 + (ay - ra[1]) ** 2 + (az - ra[2]) ** 2)
                gl = np.sqrt(rg[0] ** 2 + rg[1] ** 2 + rg[2] ** 2)
                if dg < rest_th_gyr and da < rest_th_acc and gl < bias_clip:
                    rest_t += dt
                else:
                    rest_t = 0.0
                if rest_t >= rest_min_t:
                    is_rest = True
                    b0 += k_bias_rest * (rg[0] - b0)
                    b1 += k_bias_rest * (rg[1] - b1)
                    b2 += k_bias_rest * (rg[2] - b2)
            rest_out[t, s] = is_rest
            # ------------------------------------------------------------ strapdown
            if gyr_ok and t > 0:
                ox, oy, oz = wx - b0, wy - b1, wz - b2
                ang = np.sqrt(ox * ox + oy * oy + oz * oz) * dt
                if ang > 1e-12:
                    c = np.cos(0.5 * ang)
                    sn = np.sin(0.5 * ang) / (ang / dt)
                    gw, gx, gy, gz = _qmul(gw, gx, gy, gz, c, sn * ox, sn * oy, sn * oz)
                    n = np.sqrt(gw * gw + gx * gx + gy * gy + gz * gz)
                    gw, gx, gy, gz = gw / n, gx / n, gy / n, gz / n
            # --------------------------------------------------------- inclination
            if acc_ok:
                vx, vy, vz = _rotate(gw, gx, gy, gz, ax, ay, az)
                if not lp_init:
                    # steady state of the low-pass for a constant input
                    for k in range(3):
                        v = vx if k == 0 else (vy if k == 1 else vz)
                        z1[k] = v * (1.0 - bb[0])
                        z2[k] = v * (bb[2] - ba[2])
                    lp_init = True
                fx = bb[0] * vx + z1[0]
                z1[0] = bb[1] * vx - ba[1] * fx + z2[0]
                z2[0] = bb[2] * vx - ba[2] * fx
                fy = bb[0] * vy + z1[1]
                z1[1] = bb[1] * vy - ba[1] * fy + z2[1]
                z2[1] = bb[2] * vy - ba[2] * fy
                fz = bb[0] * vz + z1[2]
                z1[2] = bb[1] * vz - ba[1] * fz + z2[2]
                z2[2] = bb[2] * vz - ba[2] * fz
                ex, ey, ez = _rotate(iw, ix, iy, iz, fx, fy, fz)
                en = np.sqrt(ex * ex + ey * ey + ez * ez)
                if en > 0.0:
                    ex, ey, ez = ex / en, ey / en, ez / en
                    cw = np.sqrt(max(0.5 * (ez + 1.0), 1e-12))
                    # shortest rotation taking e onto +z: axis e × z = (ey, -ex, 0)
                    cx, cy = 0.5 * ey / cw, -0.5 * ex / cw
                    iw, ix, iy, iz = _qmul(cw, cx, cy, 0.0, iw, ix, iy, iz)
                    n = np.sqrt(iw * iw + ix * ix + iy * iy + iz * iz)
                    iw, ix, iy, iz = iw / n, ix / n, iy / n, iz / n
                    # correction rotation vector (earth frame) -> sensor frame -> bias
                    if not is_rest and t > 0:
                        sw, sx, sy, sz = _qmul(iw, ix, iy, iz, gw, gx, gy, gz)
                        rx, ry, rz = _rotate(sw, -sx, -sy, -sz, 2.0 * cx, 2.0 * cy, 0.0)
                        kb = dt / bias_tau_motion
                        b0 -= kb * rx / dt
                        b1 -= kb * ry / dt
                        b2 -= kb * rz / dt
            # ---------------------------------------------------------------- 9D
            if use_mag:
                mx, my, mz = mag[t, s, 0], mag[t, s, 1], mag[t, s, 2]
                mn = np.sqrt(mx * mx + my * my + mz * mz)
                if np.isfinite(mn) and mn > 0.0:
                    sw, sx, sy, sz = _qmul(iw, ix, iy, iz, gw, gx, gy, gz)
                    hx, hy, hz = _rotate(sw, sx, sy, sz, mx, my, mz)
                    hh = np.sqrt(hx * hx + hy * hy)
                    dip = np.arctan2(hz, hh)
                    if not mag_init:
                        cur_norm, cur_dip, ref_norm, ref_dip = mn, dip, mn, dip
                        mag_init = True
                    cur_norm += k_magcur * (mn - cur_norm)
                    cur_dip += k_magcur * (dip - cur_dip)
                    disturbed = (abs(cur_norm - ref_norm) > mag_norm_th * ref_norm
                                 or abs(cur_dip - ref_dip) > mag_dip_th)
                    if disturbed:
                        # a new homogeneous field must stay consistent (norm and dip) for
                        # mag_new_time while the sensor moves before it is adopted; a magnet
                        # fixed to the sensor changes norm/dip with orientation and never is
                        gmag = np.sqrt(wx * wx + wy * wy + wz * wz) if gyr_ok else 0.0
                        if (abs(cur_norm - cand_norm) > mag_norm_th * cand_norm
                                or abs(cur_dip - cand_dip) > mag_dip_th):
                            cand_norm, cand_dip, dist_t, cand_motion = cur_norm, cur_dip, 0.0, 0.0
                        else:
                            dist_t += dt
                            cand_norm += k_magref * (cur_norm - cand_norm)
                            cand_dip += k_magref * (cur_dip - cand_dip)
                            if gmag > mag_new_min_gyr:
                                cand_motion += dt
                        if dist_t > mag_new_time and cand_motion > 0.5 * mag_new_time:
                            ref_norm, ref_dip = cand_norm, cand_dip
                            disturbed = False
                            dist_t = 0.0
                            cand_motion = 0.0
                        reject_t += dt
                        undist_t = 0.0
                    else:
                        undist_t += dt
                        dist_t = 0.0
                        cand_norm, cand_dip, cand_motion = cur_norm, cur_dip, 0.0
                        ref_norm += k_magref * (cur_norm - ref_norm)
                        ref_dip += k_magref * (cur_dip - ref_dip)
                    if not disturbed and undist_t >= mag_min_undisturbed_t and hh > 0.0:
                        mag_ok_out[t, s] = True
                        target = 0.5 * np.pi - np.arctan2(hy, hx)
                        mag_seen += dt
                        k = k_mag
                        if reject_t > 0.0:
                            # catch up on the heading drift accumulated while rejecting
                            k = min(1.0, k_mag * mag_rejection_factor)
                            reject_t = max(0.0, reject_t - mag_rejection_factor * dt)
                        if mag_seen < mag_init_time:
                            k = max(k_mag, dt / mag_seen)
                        err = _wrap(target - delta)
                        delta = _wrap(delta + k * err)
                        if not is_rest and mag_seen >= mag_init_time:
                            # heading correction about earth z fed back into the bias
                            rx, ry, rz = _rotate(sw, -sx, -sy, -sz, 0.0, 0.0, k * err)
                            kb = dt / bias_tau_motion
                            b0 -= kb * rx / dt
                            b1 -= kb * ry / dt
                            b2 -= kb * rz / dt
            # clip bias
            bn = np.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
            if bn > bias_clip:
                b0, b1, b2 = b0 * bias_clip / bn, b1 * bias_clip / bn, b2 * bias_clip / bn
            # --------------------------------------------------------------- output
            qw, qx, qy, qz = _qmul(iw, ix, iy, iz, gw, gx, gy, gz)
            if use_mag:
                hw, hzz = np.cos(0.5 * delta), np.sin(0.5 * delta)
                qw, qx, qy, qz = _qmul(hw, 0.0, 0.0, hzz, qw, qx, qy, qz)
            out[t, s, 0], out[t, s, 1], out[t, s, 2], out[t, s, 3] = qw, qx, qy, qz
            bias_out[t, s, 0], bias_out[t, s, 1], bias_out[t, s, 2] = b0, b1, b2
    return out, bias_out, rest_out, mag_ok_out


def _params_vector(p: FilterParams) -> FloatArray:
    return np.array([p.tau_mag, p.bias_tau_motion, p.bias_tau_rest, p.bias_clip,
                     p.rest_min_t, p.rest_tau, p.rest_th_gyr, p.rest_th_acc,
                     p.mag_current_tau, p.mag_ref_tau, p.mag_norm_th, p.mag_dip_th,
                     p.mag_new_time, p.mag_init_time, p.mag_new_min_gyr,
                     p.mag_rejection_factor, p.mag_min_undisturbed_t])


def orientation_filter(
    gyr: ArrayLike,
    acc: ArrayLike,
    mag: ArrayLike | None = None,
    *,
    frequency: float,
    params: FilterParams | None = None,
    offline: bool = False,
) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
    """Estimate sensor-to-ENU orientation (9D) or inclination (6D) of whole recordings.

    Args:
        gyr: ``(T, 3)`` or ``(T, S, 3)`` angular rate, rad/s.
        acc: same shape, m/s² (any unit works; only directions and ratios are used).
        mag: same shape (any unit) or ``None`` for 6D; 6D heading is arbitrary.
        frequency: sampling rate, Hz.
        params: tuning; defaults suit human motion at 50-1000 Hz.
        offline: for recorded data: bias known from the first sample (time-reversed
            pass), then zero-phase (lag-free) inclination and, where the field is clean,
            heading.
            ``False`` gives the causal (real-time equivalent) estimate.

    Returns:
        ``(quat, bias, rest)``: quaternions ``(T, [S,] 4)``, gyro bias ``(T, [S,] 3)``
        rad/s, rest flags ``(T, [S])``.

    Raises:
        InputError: shape mismatch or a non-positive sampling rate.
    """
    p = params or FilterParams()
    single = np.ndim(gyr) == 2
    g, a, m = sensor_inputs(gyr, acc, mag)
    if not (np.isfinite(frequency) and frequency > 0):
        raise InputError(f"frequency must be positive (Hz), got {frequency}")
    if len(g) < 2:
        raise InputError("need at least two samples")
    dt = 1.0 / float(frequency)
    bb, ba = _butter_coeffs(p.tau_acc, float(frequency))
    pv = _params_vector(p)
    use_mag = mag is not None
    if offline:
        q, bias, rest = _offline(g, a, m, use_mag, dt, bb, ba, pv, p)
    else:
        q, bias, rest, _ = _filter_loop(g, a, m, use_mag, dt, bb, ba, pv,
                                        np.zeros((g.shape[1], 3)))
    if single:
        return q[:, 0], bias[:, 0], rest[:, 0]
    return q, bias, rest


@njit(cache=True)
def _strapdown(gyr: FloatArray, bias: FloatArray, dt: float) -> FloatArray:
    """Integrate bias-corrected rates ``(T, S, 3)`` from identity; quaternions (T, S, 4)."""
    T, S = gyr.shape[0], gyr.shape[1]
    out = np.empty((T, S, 4))
    for s in range(S):
        w, x, y, z = 1.0, 0.0, 0.0, 0.0
        for t in range(T):
            if t > 0:
                ox = gyr[t, s, 0] - bias[t, s, 0]
                oy = gyr[t, s, 1] - bias[t, s, 1]
                oz = gyr[t, s, 2] - bias[t, s, 2]
                n = np.sqrt(ox * ox + oy * oy + oz * oz)
                if np.isfinite(n) and n * dt > 1e-12:
                    c = np.cos(0.5 * n * dt)
                    sn = np.sin(0.5 * n * dt) / n
                    w, x, y, z = _qmul(w, x, y, z, c, sn * ox, sn * oy, sn * oz)
                    nn = np.sqrt(w * w + x * x + y * y + z * z)
                    w, x, y, z = w / nn, x / nn, y / nn, z / nn
            out[t, s, 0], out[t, s, 1], out[t, s, 2], out[t, s, 3] = w, x, y, z
    return out


@njit(cache=True)
def _rotate_series(q: FloatArray, v: FloatArray) -> FloatArray:
    """``q ⊗ v ⊗ q*`` for (T, S, 4) quaternions and (T, S, 3) vectors."""
    out = np.empty(v.shape)
    for t in range(v.shape[0]):
        for s in range(v.shape[1]):
            out[t, s, 0], out[t, s, 1], out[t, s, 2] = _rotate(
                q[t, s, 0], q[t, s, 1], q[t, s, 2], q[t, s, 3], v[t, s, 0], v[t, s, 1],
                v[t, s, 2])
    return out


@njit(cache=True)
def _up_of(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    # earth +z in sensor coordinates: third row of the rotation matrix
    return 2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)


@njit(cache=True)
def _compose_inclination(qg: FloatArray, up: FloatArray, q_f: FloatArray, q_b: FloatArray,
                         e_start: FloatArray, e_end: FloatArray) -> FloatArray:
    """Tilt the strapdown ``qg`` so that the zero-phase ``up`` (inertial frame) is +z,
    fading to the causal passes' tilt (``q_b`` at the start, ``q_f`` at the end)."""
    T, S = qg.shape[0], qg.shape[1]
    out = np.empty((T, S, 4))
    for t in range(T):
        for s in range(S):
            ux, uy, uz = up[t, s, 0], up[t, s, 1], up[t, s, 2]
            n = np.sqrt(ux * ux + uy * uy + uz * uz)
            ux, uy, uz = ux / n, uy / n, uz / n
            cw = np.sqrt(max(0.5 * (uz + 1.0), 1e-12))
            w, x, y, z = _qmul(cw, 0.5 * uy / cw, -0.5 * ux / cw, 0.0,
                               qg[t, s, 0], qg[t, s, 1], qg[t, s, 2], qg[t, s, 3])
            a0, a1, a2 = _up_of(w, x, y, z)
            f0, f1, f2 = _up_of(q_f[t, s, 0], q_f[t, s, 1], q_f[t, s, 2], q_f[t, s, 3])
            b0, b1, b2 = _up_of(q_b[t, s, 0], q_b[t, s, 1], q_b[t, s, 2], q_b[t, s, 3])
            es, ee = e_start[t], e_end[t]
            ez = 1.0 - es - ee
            v0 = ez * a0 + es * b0 + ee * f0
            v1 = ez * a1 + es * b1 + ee * f1
            v2 = ez * a2 + es * b2 + ee * f2
            n = np.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
            v0, v1, v2 = v0 / n, v1 / n, v2 / n
            # sensor-frame rotation r taking v onto the current up a; (q ⊗ r)ᵀ z = v
            rw = 1.0 + v0 * a0 + v1 * a1 + v2 * a2
            rx, ry, rz = v1 * a2 - v2 * a1, v2 * a0 - v0 * a2, v0 * a1 - v1 * a0
            n = np.sqrt(rw * rw + rx * rx + ry * ry + rz * rz)
            w, x, y, z = _qmul(w, x, y, z, rw / n, rx / n, ry / n, rz / n)
            n = np.sqrt(w * w + x * x + y * y + z * z)
            out[t, s, 0], out[t, s, 1], out[t, s, 2], out[t, s, 3] = w / n, x / n, y / n, z / n
    return out


@njit(cache=True)
def _heading_terms(q: FloatArray, q_f: FloatArray, mag: FloatArray
                   ) -> tuple[FloatArray, FloatArray]:
    """Heading of ``q_f`` relative to ``q`` about earth z, and the heading that would put
    the magnetometer's horizontal part on north, both (T, S) rad."""
    T, S = q.shape[0], q.shape[1]
    yaw = np.empty((T, S))
    target = np.empty((T, S))
    for t in range(T):
        for s in range(S):
            w, x, y, z = q[t, s, 0], q[t, s, 1], q[t, s, 2], q[t, s, 3]
            ew, _, _, ez = _qmul(q_f[t, s, 0], q_f[t, s, 1], q_f[t, s, 2], q_f[t, s, 3],
                                 w, -x, -y, -z)
            yaw[t, s] = 2.0 * np.arctan2(ez, ew)
            hx, hy, _ = _rotate(w, x, y, z, mag[t, s, 0], mag[t, s, 1], mag[t, s, 2])
            target[t, s] = 0.5 * np.pi - np.arctan2(hy, hx)
    return yaw, target


@njit(cache=True)
def _apply_yaw(q: FloatArray, yaw: FloatArray) -> FloatArray:
    """Rotate (T, S, 4) quaternions by ``yaw`` (T, S) about earth z."""
    out = np.empty(q.shape)
    for t in range(q.shape[0]):
        for s in range(q.shape[1]):
            c, sn = np.cos(0.5 * yaw[t, s]), np.sin(0.5 * yaw[t, s])
            out[t, s, 0], out[t, s, 1], out[t, s, 2], out[t, s, 3] = _qmul(
                c, 0.0, 0.0, sn, q[t, s, 0], q[t, s, 1], q[t, s, 2], q[t, s, 3])
    return out


def _fill_gaps(x: FloatArray, ok: NDArray[np.bool_]) -> FloatArray:
    """Linearly interpolate rows of ``x`` (T, S, k) where ``ok`` (T, S) is False."""
    out = x.copy()
    idx = np.arange(len(x))
    for s in range(x.shape[1]):
        good = ok[:, s]
        if good.all() or not good.any():
            continue
        for k in range(x.shape[2]):
            out[~good, s, k] = np.interp(idx[~good], idx[good], x[good, s, k])
    return out


def _zero_phase(x: FloatArray, ba: tuple[FloatArray, FloatArray], tau: float,
                fs: float) -> FloatArray:
    """Forward-backward 2nd-order Butterworth low-pass ``ba`` along time (no lag).

    The ends are padded by mirroring (``padtype="even"``): filtfilt's default odd
    extension pivots on the last sample, and for an acceleration that sample can be an
    impact or mid-swing value of several m/s² — the low-pass then carried that offset for
    ~3 ``tau`` (on simulated walking, shank inclination errors grew to 9° over the last
    seconds of a recording; mirroring keeps them ≤ 2°).
    """
    from scipy.signal import filtfilt

    return np.asarray(filtfilt(ba[0], ba[1], x, axis=0, padtype="even",
                               padlen=min(len(x) - 1, int(3 * tau * fs))))


def _offline(
    g: FloatArray, a: FloatArray, m: FloatArray, use_mag: bool, dt: float, bb: FloatArray,
    ba: FloatArray, pv: FloatArray, p: FilterParams,
) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
    """Non-causal estimate from forward and time-reversed causal passes.

    * Bias: a time-reversed pass learns the bias up to the start of the recording; the
      forward pass starts from it, so it knows the bias from its first sample even when
      the recording starts in motion (no rest to learn it from).
    * Inclination: the bias-corrected gyroscope is integrated once and the acceleration is
      low-passed *zero-phase* in that almost-inertial frame (no lag). Within a few
      ``tau_acc`` of either end, where a zero-phase filter lacks data on one side, the
      inclination fades to the causal pass that has settled there (backward at the
      start, forward at the end).
    * Heading (9D): the zero-phase low-pass of the magnetometer heading over the samples
      both passes accepted (normalised convolution), where the field nearby was clean;
      near rejected stretches the forward pass' heading, which has the causal rejection
      history and starts with the right bias.
    """
    # time reversal: reversed sample k is reached from k-1 by the negated later rate (so
    # the bias appears negated)
    g_rev = np.ascontiguousarray(-np.concatenate([g[1:], g[-1:]])[::-1])
    a_rev, m_rev = np.ascontiguousarray(a[::-1]), np.ascontiguousarray(m[::-1])
    zero = np.zeros((g.shape[1], 3))
    q_b, bias_b, _, mag_ok_b = _filter_loop(g_rev, a_rev, m_rev, use_mag, dt, bb, ba, pv,
                                            zero)
    q_f, bias, rest, mag_ok_f = _filter_loop(g, a, m, use_mag, dt, bb, ba, pv,
                                             np.ascontiguousarray(-bias_b[-1]))
    q_b = q_b[::-1]
    qg = _strapdown(g, np.ascontiguousarray(bias), dt)
    fs = 1.0 / dt
    acc_ok = np.all(np.isfinite(a), axis=-1) & (np.linalg.norm(a, axis=-1) > 0)
    if not acc_ok.any():
        raise InputError("no finite accelerometer sample")
    a_i = _fill_gaps(_rotate_series(qg, np.where(acc_ok[..., None], a, 0.0)), acc_ok)
    up = np.ascontiguousarray(_zero_phase(a_i, (bb, ba), p.tau_acc, fs))
    # edge fading of the inclination towards the settled causal pass
    t = np.arange(len(g)) * dt
    e_start = np.exp(-t / p.tau_acc)
    e_end = np.exp(-(t[-1] - t) / p.tau_acc)
    e_start, e_end = e_start * (1.0 - e_end), e_end * (1.0 - e_start)
    q = _compose_inclination(qg, up, q_f, np.ascontiguousarray(q_b), e_start, e_end)
    if use_mag:
        ok = mag_ok_f & mag_ok_b[::-1] & np.all(np.isfinite(m), axis=-1)
        yaw, target = _heading_terms(q, q_f, np.where(ok[..., None], m, 0.0))
        w0 = p.mag_clean_fraction
        ba_mag = _butter_coeffs(p.tau_mag, fs)
        # the zero-phase heading lacks data on one side near the ends: fade out there
        edge_mag = (1.0 - np.exp(-t / p.tau_mag)) * (1.0 - np.exp(-(t[-1] - t) / p.tau_mag))
        for s in range(q.shape[1]):
            good = ok[:, s]
            if good.sum() < 2:
                continue
            # zero-phase heading (normalised convolution over the accepted samples) where
            # nearly all nearby samples were accepted; near rejected stretches the forward
            # pass' heading, whose rejection logic has the causal history, is kept
            d = np.unwrap(target[good, s])
            d_full = np.interp(np.arange(len(q)), np.flatnonzero(good), d)
            w = np.clip(_zero_phase(good.astype(float), ba_mag, p.tau_mag, fs), 0.0, 1.0)
            num = _zero_phase(np.where(good, d_full, 0.0), ba_mag, p.tau_mag, fs)
            zp = np.where(w > 1e-3, num / np.maximum(w, 1e-3), 0.0)
            diff = (zp - yaw[:, s] + np.pi) % (2 * np.pi) - np.pi
            alpha = np.clip((w - w0) / (1.0 - w0), 0.0, 1.0) * edge_mag
            yaw[:, s] = yaw[:, s] + alpha * diff
        q = _apply_yaw(q, np.ascontiguousarray(yaw))
    return q, bias, rest


class OrientationFilter:
    """Estimator-object wrapper of :func:`orientation_filter`.

    Attributes:
        quat_: sensor-to-ENU quaternions after :meth:`fit`.
        bias_: estimated gyroscope bias (rad/s).
        rest_: rest-detection flags.
    """

    def __init__(self, frequency: float, params: FilterParams | None = None,
                 offline: bool = False) -> None:
        self.frequency = frequency
        self.params = params or FilterParams()
        self.offline = offline
        self.quat_: FloatArray | None = None
        self.bias_: FloatArray | None = None
        self.rest_: NDArray[np.bool_] | None = None

    def fit(self, gyr: ArrayLike, acc: ArrayLike, mag: ArrayLike | None = None,
            ) -> OrientationFilter:
        """Filter a recording; results go to ``quat_``, ``bias_``, ``rest_``.

        Args:
            gyr: ``(T, 3)`` or ``(T, S, 3)`` angular rate, rad/s (time first axis).
            acc: Same shape, accelerometer (m/s²; only directions and ratios are used).
            mag: Same shape (any unit) or None for 6D (heading then arbitrary).

        Returns:
            ``self`` (``quat_``: sensor-to-ENU, w first).

        Raises:
            InputError: shape mismatch or a non-positive ``frequency``.
        """
        self.quat_, self.bias_, self.rest_ = orientation_filter(
            gyr, acc, mag, frequency=self.frequency, params=self.params, offline=self.offline)
        return self

    def get_params(self) -> dict[str, float]:
        """Tuning parameters as a plain dict.

        Returns:
            :class:`FilterParams`' fields (SI units: s, rad/s, m/s²).
        """
        return asdict(self.params)
