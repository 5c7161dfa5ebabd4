"""Paging and search of the list endpoints (subjects, projects, recordings, reports'
recordings, audit trail).

A list answers a JSON array, as before paging existed, of at most ``limit`` items from
``offset`` on; the ``X-Total-Count`` response header says how many items match in all
(so a client pages with ``offset += limit`` until ``offset >= total``). A ``limit`` above
the endpoint's largest page is refused (422) with a message saying the largest page and
how to ask for the next one, instead of being cut silently.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

from fastapi import HTTPException, Query, Response, status

#: Largest ``offset`` accepted (larger ones name no row; SQLite's integer range).
MAX_OFFSET = 2**62
#: Response header with the number of items matching the request in all.
TOTAL_HEADER = "X-Total-Count"

LimitQ = Annotated[int | None, Query(ge=1, description=(
    "Items per page (at most the endpoint's largest page; default its default page)."))]
OffsetQ = Annotated[int, Query(ge=0, le=MAX_OFFSET, description="Items to skip.")]
SearchQ = Annotated[str | None, Query(max_length=100, description=(
    "Search text (case-insensitive substring)."))]


@dataclass(frozen=True)
class Page:
    """A checked ``limit``/``offset`` pair."""

    limit: int
    offset: int


def page_of(limit: int | None, offset: int, default: int, largest: int) -> Page:
    """The page asked for, ``default`` items when no ``limit`` is given.

    Raises:
        HTTPException: 422 when ``limit`` is above ``largest``.
    """
    if limit is None:
        return Page(default, offset)
    if limit > largest:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"limit {limit} is more than the largest page of this list "
                            f"({largest}); ask for at most {largest} items and for the next "
                            f"page with offset={offset + largest}")
    return Page(limit, offset)


def set_total(response: Response, total: int) -> None:
    """Put the number of matching items in the answer's ``X-Total-Count`` header."""
    response.headers[TOTAL_HEADER] = str(total)


def like_pattern(text: str) -> str:
    """``text`` as a SQL ``LIKE`` substring pattern (``%`` and ``_`` taken literally,
    with ``\\`` as the escape character)."""
    esc = text.replace("\\", "\\\\").replace("%", "\\%").replace("_", "\\_")
    return f"%{esc}%"
