"""Time-indexed ring buffer holding the last few seconds of frames on a node.

Recording commands can arrive after their start time (network, busy server); the node
then takes the frames since the start from this buffer (seed 000 keeps 2 s).
"""

from __future__ import annotations

import bisect
from collections import deque
from collections.abc import Iterator
from typing import Generic, TypeVar

T = TypeVar("T")


class RingBuffer(Generic[T]):
    """Frames ordered by time, dropping those older than ``seconds`` before the newest.

    Args:
        seconds: how much history to keep (> 0).
    """

    def __init__(self, seconds: float = 2.0) -> None:
        if seconds <= 0:
            raise ValueError("ring buffer length must be positive seconds")
        self.seconds = float(seconds)
        self._times: deque[float] = deque()
        self._items: deque[T] = deque()

    def __len__(self) -> int:
        return len(self._times)

    def push(self, t: float, item: T) -> None:
        """Append a frame with time ``t`` (must not go backwards) and evict old ones."""
        if self._times and t < self._times[-1]:
            raise ValueError(f"frame time {t} is before the newest buffered one {self._times[-1]}")
        self._times.append(t)
        self._items.append(item)
        limit = t - self.seconds
        while self._times and self._times[0] < limit:
            self._times.popleft()
            self._items.popleft()

    @property
    def span(self) -> float:
        """Seconds between the oldest and newest frame (0 when < 2 frames)."""
        return self._times[-1] - self._times[0] if len(self._times) > 1 else 0.0

    @property
    def oldest(self) -> float | None:
        """Time of the oldest buffered frame."""
        return self._times[0] if self._times else None

    def since(self, t0: float, t1: float = float("inf")) -> Iterator[tuple[float, T]]:
        """Frames with ``t0 <= t <= t1``, oldest first."""
        times = list(self._times)
        i = bisect.bisect_left(times, t0)
        items = list(self._items)
        for k in range(i, len(times)):
            if times[k] > t1:
                break
            yield times[k], items[k]

    def latest(self) -> tuple[float, T] | None:
        """The newest frame, if any."""
        return (self._times[-1], self._items[-1]) if self._times else None
