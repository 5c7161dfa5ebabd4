"""A node's local clock.

Real nodes read their own wall clock (``time.time()``; chrony/PTP keep it near the
server's, the server measures what is left). The simulator gives each sensor a clock
offset and drift; :class:`NodeClock` applies them to the host clock so that several sim
nodes on one machine behave like separate computers:

``t_local(t) = t + offset_s + drift * (t - t_ref)``, with ``t`` the host wall clock (which
is also the server's clock when both run on one host) and ``drift`` in s/s (1e-4 =
100 ppm). The true offset ``t_local - t_server`` is therefore ``offset_s + drift·(t - t_ref)``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field


@dataclass(frozen=True)
class NodeClock:
    """Local clock = host clock + offset + drift since ``t_ref``.

    Attributes:
        offset_s: offset at ``t_ref`` (s).
        drift: rate error in s/s (ppm × 1e-6).
        t_ref: host time where the offset equals ``offset_s``; defaults to creation time.
    """

    offset_s: float = 0.0
    drift: float = 0.0
    t_ref: float = field(default_factory=time.time)

    def now(self) -> float:
        """Current local time (s)."""
        return self.from_host(time.time())

    def from_host(self, t_host: float) -> float:
        """Local time at host time ``t_host``."""
        return t_host + self.offset_s + self.drift * (t_host - self.t_ref)

    def to_host(self, t_local: float) -> float:
        """Host time at local time ``t_local`` (exact inverse of :meth:`from_host`)."""
        return (t_local - self.offset_s + self.drift * self.t_ref) / (1.0 + self.drift)

    def true_offset(self, t_host: float) -> float:
        """``t_local - t_host`` at host time ``t_host`` (ground truth for tests)."""
        return self.offset_s + self.drift * (t_host - self.t_ref)
