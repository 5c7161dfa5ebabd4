"""NaN-aware reductions that return NaN for all-NaN slices without a warning.

Missing values are normal in this project (untracked joints, markers out of view,
frames without a sensor), so numpy's "Mean of empty slice" / "All-NaN slice" warnings
carry no information. Silencing them with ``warnings.catch_warnings`` is not
thread-safe (it swaps the process-wide filter list; the server runs analyses and
sensors in parallel threads), so these functions avoid raising them in the first
place: all-NaN slices are filled before the reduction and set to NaN after it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


def _reduce(fn: Callable[..., Any], a: ArrayLike, axis: int | tuple[int, ...] | None,
            **kwargs: Any) -> Any:
    x = np.asarray(a, dtype=float)
    empty = np.isnan(x).all(axis=axis, keepdims=True) if x.size else None
    if empty is None:
        # a zero-size input has nothing to reduce: NaN of the reduced shape
        shape = np.sum(x, axis=axis).shape
        return np.full(shape, np.nan) if shape else np.nan
    filled = np.where(empty, 0.0, x)
    with np.errstate(invalid="ignore"):  # errstate is thread-local, unlike warnings
        out = fn(filled, axis=axis, **kwargs)
    mask = np.squeeze(empty, axis=axis) if axis is not None else bool(empty.all())
    if np.ndim(out) == 0:
        return np.nan if bool(mask) else float(out)
    out = np.asarray(out, dtype=float)
    out[np.broadcast_to(mask, out.shape)] = np.nan
    return out


def nanmean(a: ArrayLike, axis: int | tuple[int, ...] | None = None) -> Any:
    """``np.nanmean`` without warnings: NaN where a slice is all NaN.

    Args:
        a: Values (NaN = missing).
        axis: Axis or axes to reduce (None: all).

    Returns:
        A float, or an array of the remaining axes.
    """
    return _reduce(np.nanmean, a, axis)


def nanmedian(a: ArrayLike, axis: int | tuple[int, ...] | None = None) -> Any:
    """``np.nanmedian`` without warnings: NaN where a slice is all NaN.

    Args:
        a: Values (NaN = missing).
        axis: Axis or axes to reduce (None: all).

    Returns:
        A float, or an array of the remaining axes.
    """
    return _reduce(np.nanmedian, a, axis)


def nanstd(a: ArrayLike, axis: int | tuple[int, ...] | None = None) -> Any:
    """``np.nanstd`` (ddof 0) without warnings: NaN where a slice is all NaN.

    Args:
        a: Values (NaN = missing).
        axis: Axis or axes to reduce (None: all).

    Returns:
        A float, or an array of the remaining axes.
    """
    return _reduce(np.nanstd, a, axis)


def nanmax(a: ArrayLike, axis: int | tuple[int, ...] | None = None) -> Any:
    """``np.nanmax`` without warnings: NaN where a slice is all NaN.

    Args:
        a: Values (NaN = missing).
        axis: Axis or axes to reduce (None: all).

    Returns:
        A float, or an array of the remaining axes.
    """
    return _reduce(np.nanmax, a, axis)


def nanmin(a: ArrayLike, axis: int | tuple[int, ...] | None = None) -> Any:
    """``np.nanmin`` without warnings: NaN where a slice is all NaN.

    Args:
        a: Values (NaN = missing).
        axis: Axis or axes to reduce (None: all).

    Returns:
        A float, or an array of the remaining axes.
    """
    return _reduce(np.nanmin, a, axis)
