"""Timestamps as the API emits them: ISO 8601 with an explicit UTC offset.

SQLite keeps ``DateTime(timezone=True)`` columns without their zone and gives them back
naive (PostgreSQL gives them back aware); a naive ISO string is read by a browser as its
*local* time, an hour or more off. Every time stored by gaitrig is UTC, so a naive value
(new or stored by an older release) is read as UTC here, and every timestamp leaves the
API as ``2026-11-24T09:15:02.123456+00:00``.
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Literal

Timespec = Literal["auto", "hours", "minutes", "seconds", "milliseconds", "microseconds"]


def as_utc(t: datetime) -> datetime:
    """``t`` as an aware UTC datetime; a naive one is taken to be UTC already."""
    return t.replace(tzinfo=UTC) if t.tzinfo is None else t.astimezone(UTC)


def utc_iso(t: datetime, timespec: Timespec = "auto") -> str:
    """``t`` (naive = UTC) as ISO 8601 with the ``+00:00`` offset."""
    return as_utc(t).isoformat(timespec=timespec)


def utc_iso_or_none(t: datetime | None, timespec: Timespec = "auto") -> str | None:
    """:func:`utc_iso`, or None for None."""
    return None if t is None else utc_iso(t, timespec)
