"""Ring buffer keeps exactly the last N seconds."""

from __future__ import annotations

import pytest

from app.nodes.ringbuffer import RingBuffer


def test_keeps_last_two_seconds() -> None:
    rb: RingBuffer[int] = RingBuffer(2.0)
    for k in range(100):
        rb.push(k / 30.0, k)
    oldest = rb.oldest
    assert oldest is not None
    assert 99 / 30.0 - oldest <= 2.0 < 99 / 30.0 - (oldest - 1 / 30.0)
    assert rb.span == pytest.approx(60 / 30.0)
    got = [i for _, i in rb.since(3.0, 3.1)]
    assert got == [90, 91, 92, 93]
    assert rb.latest() == (99 / 30.0, 99)


def test_rejects_time_going_backwards() -> None:
    rb: RingBuffer[int] = RingBuffer(2.0)
    rb.push(1.0, 1)
    with pytest.raises(ValueError, match="before"):
        rb.push(0.5, 2)
