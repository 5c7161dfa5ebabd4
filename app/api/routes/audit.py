"""The audit trail for administrators: logins, exports and deletions (who, when, what).

``GET /api/audit`` lists entries newest first (``limit``, ``before`` = an entry id for the
next page; the ``X-Total-Count`` header counts the entries matching the filters, i.e. this
page and those after it). ``since``/``until`` (ISO dates, UTC days, both included) and
``action`` filter. ``format=csv`` downloads the *whole* trail matching the filters (no
``limit``), streamed in batches so the server never holds it in memory; the download is
itself recorded. The trail is append-only: no route changes or deletes an entry, and
SQLite refuses to.
"""

from __future__ import annotations

import csv
import datetime as dt
import io
from collections.abc import Callable, Iterator
from typing import Annotated, Any, Literal

from fastapi import APIRouter, HTTPException, Query, Request, Response, status
from fastapi.responses import StreamingResponse
from sqlalchemy import ColumnElement, func, select
from sqlalchemy.orm import Session

from app.api.deps import CurrentUser, DbDep
from app.api.limits import BoundedRoute
from app.api.routes._data import audit_now
from app.api.routes._paging import set_total
from app.api.timestamps import utc_iso
from app.db.models import AuditEvent

router = APIRouter(prefix="/audit", route_class=BoundedRoute, tags=["audit"])

FIELDS = ("id", "at", "username", "action", "target", "detail", "client")

#: Rows read per query while a CSV download streams (bounds the server's memory).
CSV_BATCH = 1000


def _json(e: AuditEvent) -> dict[str, Any]:
    return {"id": e.id, "at": utc_iso(e.at), "username": e.username, "action": e.action,
            "target": e.target, "detail": e.detail, "client": e.client}


def _cell(v: Any) -> Any:
    # a user name typed at a failed login reaches the sheet: no formula may run from it
    return f"'{v}" if isinstance(v, str) and v[:1] in ("=", "+", "-", "@", "\t", "\r") else v


def _day_start(d: dt.date) -> dt.datetime:
    return dt.datetime(d.year, d.month, d.day, tzinfo=dt.UTC)


def _csv_rows(sessions: Callable[[], Session], where: list[ColumnElement[bool]],
              last_id: int) -> Iterator[str]:
    """The CSV text, header first, newest entry first, read ``CSV_BATCH`` rows at a time
    (keyset paging on the id) in a session of its own: the request's is closed by then."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, FIELDS)
    w.writeheader()
    below = last_id + 1
    while True:
        with sessions() as db:
            batch = [_json(e) for e in db.scalars(
                select(AuditEvent).where(*where, AuditEvent.id < below)
                .order_by(AuditEvent.id.desc()).limit(CSV_BATCH))]
        w.writerows({k: _cell(v) for k, v in r.items()} for r in batch)
        yield buf.getvalue()
        buf.seek(0)
        buf.truncate()
        if len(batch) < CSV_BATCH:
            return
        below = batch[-1]["id"]


@router.get("", response_model=None)
def entries(request: Request, response: Response, user: CurrentUser, db: DbDep,
            limit: Annotated[int, Query(ge=1, le=10000)] = 200,
            before: Annotated[int | None, Query(ge=1, le=2**63 - 1)] = None,
            action: Annotated[str | None, Query(max_length=16)] = None,
            since: Annotated[dt.date | None, Query(
                description="first day (ISO date, UTC) of the entries, included")] = None,
            until: Annotated[dt.date | None, Query(
                description="last day (ISO date, UTC) of the entries, included")] = None,
            format: Annotated[Literal["json", "csv"], Query()] = "json"
            ) -> list[dict[str, Any]] | Response:
    """Audit entries, newest first (administrators only); ``format=csv``: all of them."""
    if not user.is_admin:
        raise HTTPException(status.HTTP_403_FORBIDDEN,
                            "only an administrator may read the audit trail")
    if since is not None and until is not None and until < since:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"until ({until}) is before since ({since}): give the first "
                            "day as since and the last day as until")
    where: list[ColumnElement[bool]] = []
    if before is not None:
        where.append(AuditEvent.id < before)
    if action:
        where.append(AuditEvent.action == action)
    if since is not None:
        where.append(AuditEvent.at >= _day_start(since))
    if until is not None:
        where.append(AuditEvent.at < _day_start(until) + dt.timedelta(days=1))
    if format == "json":
        q = select(AuditEvent).where(*where).order_by(AuditEvent.id.desc()).limit(limit)
        rows = [_json(e) for e in db.scalars(q)]
        set_total(response, db.scalar(select(func.count(AuditEvent.id)).where(*where)) or 0)
        return rows
    # the download's own entry is recorded first (it would be lost if the client left
    # mid-stream) and is not part of it: the stream ends at the last entry before it
    last_id = db.scalar(select(func.max(AuditEvent.id))) or 0
    count = db.scalar(select(func.count(AuditEvent.id)).where(
        *where, AuditEvent.id <= last_id)) or 0
    span = f" from {since or 'the start'} to {until or 'now'}" if since or until else ""
    audit_now(db, request, user, "export", "audit trail", f"{count} entries{span}")
    name = "gaitrig-audit" + (f"-{since or 'start'}-to-{until or 'now'}" if span else "")
    return StreamingResponse(
        _csv_rows(request.app.state.db_sessions, where, last_id), media_type="text/csv",
        headers={"Content-Disposition": f'attachment; filename="{name}.csv"',
                 "X-Total-Count": str(count)})
