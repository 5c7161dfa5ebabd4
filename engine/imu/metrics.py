"""Error measures: the BROAD orientation errors and the seed paper's RMSE / NCC."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.errors import InputError, InsufficientDataError
from engine.geometry import quat_conj, quat_mul

FloatArray = NDArray[np.float64]


def orientation_errors(
    q_est: ArrayLike, q_ref: ArrayLike, mask: ArrayLike | None = None
) -> dict[str, float]:
    """BROAD error measure (Laidig et al.): RMS total, heading and inclination errors.

    The error quaternion in the earth frame is ``e = q_est ⊗ q_ref⁻¹`` (both w-first,
    sensor-to-earth, same earth frame). Total error ``2·acos|e_w|``, heading error
    ``2·atan|e_z/e_w|``, inclination error ``2·acos√(e_w² + e_z²)``; each is an RMS over
    the samples in ``mask`` (BROAD's ``movement``); rows with NaN are ignored.

    Args:
        q_est: ``(T, 4)`` estimated sensor-to-earth quaternions, w first.
        q_ref: ``(T, 4)`` reference quaternions in the same earth frame.
        mask: ``(T,)`` samples to evaluate; None: all.

    Returns:
        ``{"total_deg", "heading_deg", "inclination_deg"}``.

    Raises:
        InputError: shapes differ. InsufficientDataError: no usable sample.
    """
    qe = np.asarray(q_est, dtype=float)
    qr = np.asarray(q_ref, dtype=float)
    if qe.shape != qr.shape or qe.shape[-1] != 4:
        raise InputError(f"quaternion arrays must have equal (..., 4) shapes, got {qe.shape} "
                         f"and {qr.shape}")
    m = np.ones(qe.shape[:-1], dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    e = quat_mul(qe / np.linalg.norm(qe, axis=-1, keepdims=True),
                 quat_conj(qr / np.linalg.norm(qr, axis=-1, keepdims=True)))
    e = e / np.linalg.norm(e, axis=-1, keepdims=True)
    ok = m & np.all(np.isfinite(e), axis=-1)
    if not ok.any():
        raise InsufficientDataError("no sample with both an estimate and a reference")
    e = e[ok]
    total = 2.0 * np.arccos(np.clip(np.abs(e[:, 0]), 0.0, 1.0))
    with np.errstate(divide="ignore"):
        heading = 2.0 * np.arctan(np.abs(e[:, 3] / e[:, 0]))
    incl = 2.0 * np.arccos(np.clip(np.sqrt(e[:, 0] ** 2 + e[:, 3] ** 2), 0.0, 1.0))

    def rms(x: FloatArray) -> float:
        return float(np.rad2deg(np.sqrt(np.mean(x ** 2))))

    return {"total_deg": rms(total), "heading_deg": rms(heading), "inclination_deg": rms(incl)}


def rmse(estimate: ArrayLike, reference: ArrayLike) -> float:
    """Root-mean-square error over samples where both are finite (same unit as inputs).

    Args:
        estimate: A series (any shape; time first).
        reference: The reference, same shape and unit; NaN samples in either are skipped.

    Returns:
        The RMSE, in the inputs' unit.

    Raises:
        InputError: shapes differ. InsufficientDataError: no common finite sample.
    """
    a = np.asarray(estimate, dtype=float)
    b = np.asarray(reference, dtype=float)
    if a.shape != b.shape:
        raise InputError(f"rmse: shapes differ {a.shape} vs {b.shape}")
    ok = np.isfinite(a) & np.isfinite(b)
    if not ok.any():
        raise InsufficientDataError("rmse: no sample where both series are finite")
    return float(np.sqrt(np.mean((a[ok] - b[ok]) ** 2)))


def ncc(estimate: ArrayLike, reference: ArrayLike) -> float:
    """Normalised cross-correlation at zero lag (Pearson correlation), in [-1, 1].

    The seed paper's Table 1 measure of waveform agreement independent of offset and gain.

    Args:
        estimate: A series (any shape; time first).
        reference: The reference, same shape; NaN samples in either are skipped.

    Returns:
        The correlation coefficient.

    Raises:
        InputError: shapes differ. InsufficientDataError: fewer than two common samples or
            a constant series.
    """
    a = np.asarray(estimate, dtype=float)
    b = np.asarray(reference, dtype=float)
    if a.shape != b.shape:
        raise InputError(f"ncc: shapes differ {a.shape} vs {b.shape}")
    ok = np.isfinite(a) & np.isfinite(b)
    if ok.sum() < 2:
        raise InsufficientDataError("ncc: fewer than two samples where both are finite")
    x = a[ok] - a[ok].mean()
    y = b[ok] - b[ok].mean()
    den = float(np.sqrt(np.sum(x * x) * np.sum(y * y)))
    if den == 0.0:
        raise InsufficientDataError("ncc: a series is constant; correlation is undefined")
    return float(np.sum(x * y) / den)
