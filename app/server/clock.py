"""Continuous estimation of a node's clock offset from NTP-style four-timestamp exchanges.

The server sends ``ping(t1)`` (server clock), the node stamps receipt ``t2`` and reply
``t3`` (its own clock), the server stamps the answer ``t4``. For one exchange

    offset θ = ((t2 - t1) + (t3 - t4)) / 2      (node minus server)
    round trip r = t4 - t1

and the true offset lies within θ ± r/2 whatever the asymmetry of the paths. Samples
with a long round trip are the ones distorted by queueing (a busy event loop, a full
socket), so the estimator keeps, per time bin, only the exchange with the shortest round
trip (best-of-N; we rank by ``t4 - t1`` rather than the NTP delay because a node that
reads the ping late shifts ``t2`` without lengthening the NTP delay). A weighted straight
line through these best samples over a sliding window tracks the drift (crystal clocks
drift by up to ~100 ppm = 0.1 ms/s, so a constant offset would be wrong within seconds).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ClockEstimate:
    """Offset model ``offset(t) = offset_s + drift·(t - t_ref)`` (node minus server).

    Attributes:
        offset_s: offset at ``t_ref`` (s).
        drift: s/s (1e-6 = 1 ppm).
        t_ref: server time of the model's reference (the newest sample).
        uncertainty_s: one-sigma uncertainty of the offset at ``t_ref`` (s).
        n_samples: best-of-bin samples behind the fit.
        rtt_s: median round trip of those samples (s).
    """

    offset_s: float
    drift: float
    t_ref: float
    uncertainty_s: float
    n_samples: int
    rtt_s: float

    def offset_at(self, t_server: float) -> float:
        """Estimated ``t_local - t_server`` at server time ``t_server``."""
        return self.offset_s + self.drift * (t_server - self.t_ref)

    def to_local(self, t_server: float) -> float:
        """Node-local time at server time ``t_server``."""
        return t_server + self.offset_at(t_server)

    def to_server(self, t_local: float) -> float:
        """Server time of node-local time ``t_local`` (exact inverse of :meth:`to_local`)."""
        return (t_local - self.offset_s + self.drift * self.t_ref) / (1.0 + self.drift)

    def as_dict(self) -> dict[str, float]:
        """Plain numbers (kept in each recording part so it can be converted later)."""
        return {"offset_s": self.offset_s, "drift": self.drift, "t_ref": self.t_ref,
                "uncertainty_s": self.uncertainty_s}


class ClockEstimator:
    """Sliding-window best-of-N linear clock model of one node.

    Args:
        window_s: history used for the fit (s).
        bin_s: one best sample is kept per bin of this length (s).
        min_bins_for_drift: below this many bins the drift is taken as 0.
    """

    def __init__(self, window_s: float = 30.0, bin_s: float = 0.5, min_bins_for_drift: int = 6):
        self.window_s = window_s
        self.bin_s = bin_s
        self.min_bins_for_drift = min_bins_for_drift
        # (t_mid_server, offset, rtt)
        self._samples: deque[tuple[float, float, float]] = deque()
        # bin → its samples (oldest first) and its best one, kept as samples come and go
        # (rebuilding them from the whole window at every exchange was a third of the fit)
        self._bins: dict[int, deque[tuple[float, float, float]]] = {}
        self._best: dict[int, tuple[float, float, float]] = {}
        self.estimate_: ClockEstimate | None = None

    def add(self, t1: float, t2: float, t3: float, t4: float) -> None:
        """Add one exchange (t1, t4 server clock; t2, t3 node clock) and refit."""
        rtt = t4 - t1
        if rtt < 0 or t3 < t2:
            return  # impossible stamps (clock stepped): ignore rather than poison the fit
        theta = ((t2 - t1) + (t3 - t4)) / 2.0
        t_mid = (t1 + t4) / 2.0
        b = int(t_mid // self.bin_s)  # first: a NaN stamp raises before anything changed
        sample = (t_mid, theta, rtt)
        self._samples.append(sample)
        self._bins.setdefault(b, deque()).append(sample)
        best = self._best.get(b)
        if best is None or rtt < best[2]:  # strict: the first of equals stays
            self._best[b] = sample
        while self._samples and self._samples[0][0] < t_mid - self.window_s:
            gone = self._samples.popleft()
            gb = int(gone[0] // self.bin_s)
            left = self._bins[gb]
            left.popleft()  # the oldest of its bin too: both are in arrival order
            if not left:
                del self._bins[gb], self._best[gb]
            elif self._best[gb] is gone:
                self._best[gb] = min(left, key=lambda x: x[2])  # min keeps the first of equals
        self._fit()

    def reset(self) -> None:
        """Forget every sample (the node restarted: its clock may have stepped)."""
        self._samples.clear()
        self._bins.clear()
        self._best.clear()
        self.estimate_ = None

    def _best_per_bin(self) -> np.ndarray:
        best = self._best
        return np.array([best[k] for k in sorted(best)], dtype=float)

    def _fit(self) -> None:
        arr = self._best_per_bin()
        t, th, rtt = arr[:, 0], arr[:, 1], arr[:, 2]
        # Bins whose best exchange was still slow (a burst of load) would bias the line.
        keep = rtt <= max(2.0 * float(np.median(rtt)), float(np.min(rtt)) + 2e-4)
        t, th, rtt = t[keep], th[keep], rtt[keep]
        t_ref = float(t[-1])
        n = len(t)
        rtt_med = float(np.median(rtt))
        asym = rtt_med / (2.0 * np.sqrt(3.0))  # std of a uniform path asymmetry in ±rtt/2
        if n < self.min_bins_for_drift:
            i = int(np.argmin(rtt))
            self.estimate_ = ClockEstimate(float(th[i]), 0.0, t_ref,
                                           float(rtt[i]) / 2.0, n, rtt_med)
            return
        w = 1.0 / np.maximum(rtt, 1e-5) ** 2
        x = t - t_ref
        W = w.sum()
        xm = (w * x).sum() / W
        ym = (w * th).sum() / W
        sxx = (w * (x - xm) ** 2).sum()
        b = float((w * (x - xm) * (th - ym)).sum() / sxx) if sxx > 0 else 0.0
        a = ym - b * xm
        res = th - (a + b * x)
        s2 = float((w * res**2).sum() / W) * n / max(n - 2, 1)
        se = np.sqrt(s2 * (1.0 / n + (0.0 - xm) ** 2 / max(sxx / W * n, 1e-12)))
        self.estimate_ = ClockEstimate(float(a), b, t_ref, float(np.hypot(se, asym)), n, rtt_med)
