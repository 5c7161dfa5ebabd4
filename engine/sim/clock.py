"""A simulated sensor computer's clock and the sensor's jittering frame times.

Every sensor of the rig is plugged into its own computer whose clock is offset from the
true (server) time and runs slightly fast or slow. The seed paper (000) observed offsets
of "several hundreds of milliseconds and sometimes even seconds" between Windows clocks;
crystal oscillators of commodity PCs drift by tens of ppm (typ. ±20–100 ppm), hence the
defaults of the rig (offset within ±0.5 s, drift within ±100 ppm).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.errors import InputError

#: The Kinect v2 delivers frames "at a slightly varying frequency of about 30 Hz" (seed
#: 000); with exposure changes the period stays within 25–35 Hz.
MIN_FPS = 25.0
MAX_FPS = 35.0


@dataclass(frozen=True)
class SimClock:
    """Local clock ``t_local = offset_s + (1 + drift_ppm·1e-6) · t_true``.

    Attributes:
        offset_s: Local time at true time 0 (s).
        drift_ppm: Rate error in parts per million (positive = local clock runs fast).
    """

    offset_s: float = 0.0
    drift_ppm: float = 0.0

    @property
    def rate(self) -> float:
        """Local seconds per true second."""
        return 1.0 + self.drift_ppm * 1e-6

    def local(self, t_true: ArrayLike) -> NDArray[np.float64] | float:
        """Local clock reading(s) at true time(s) ``t_true``.

        Args:
            t_true: True time(s), s.

        Returns:
            Local time(s), s (a float for a scalar input).
        """
        t = np.asarray(t_true, dtype=float)
        out = self.offset_s + self.rate * t
        return float(out) if out.ndim == 0 else out

    def true(self, t_local: ArrayLike) -> NDArray[np.float64] | float:
        """True time(s) at which the local clock reads ``t_local`` (inverse of :meth:`local`).

        Args:
            t_local: Local clock reading(s), s.

        Returns:
            True time(s), s (a float for a scalar input).
        """
        t = np.asarray(t_local, dtype=float)
        out = (t - self.offset_s) / self.rate
        return float(out) if out.ndim == 0 else out


def frame_times(
    t0: float,
    t1: float,
    rng: np.random.Generator,
    fps: float = 30.0,
    jitter: float = 0.05,
) -> NDArray[np.float64]:
    """True capture times of a sensor's frames in ``[t0, t1)``.

    Periods are ``1/fps`` times ``1 + jitter·N(0, 1)``, clipped so every instantaneous
    frame rate stays within 25–35 Hz.

    Args:
        t0: First frame time (s).
        t1: End of the interval (s, exclusive).
        rng: Random generator.
        fps: Nominal frame rate (Hz), within 25–35.
        jitter: Relative standard deviation of the frame period.

    Returns:
        ``(N,)`` strictly increasing times.
    """
    if not MIN_FPS <= fps <= MAX_FPS:
        raise InputError(f"fps must be within {MIN_FPS}–{MAX_FPS} Hz, got {fps}")
    if jitter < 0:
        raise InputError(f"jitter must be >= 0, got {jitter}")
    if t1 <= t0:
        return np.empty(0)
    n = int(np.ceil((t1 - t0) * MAX_FPS)) + 2
    periods = np.clip((1.0 + jitter * rng.standard_normal(n)) / fps, 1.0 / MAX_FPS, 1.0 / MIN_FPS)
    t = t0 + np.concatenate([[0.0], np.cumsum(periods)])
    return t[t < t1]
