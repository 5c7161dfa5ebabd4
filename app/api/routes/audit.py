"""The audit trail for administrators: logins, exports and deletions (who, when, what).

``GET /api/audit`` lists entries newest first (``limit``, ``before`` = an entry id for the
next page; the ``X-Total-Count`` header counts the entries matching ``action`` and
``before``, i.e. this page and those after it); ``format=csv`` downloads them (the
download is itself recorded). The trail is append-only: no route changes or deletes an
entry, and SQLite refuses to.
"""

from __future__ import annotations

import csv
import io
from typing import Annotated, Any, Literal

from fastapi import APIRouter, HTTPException, Query, Request, Response, status
from sqlalchemy import func, select

from app.api.deps import CurrentUser, DbDep
from app.api.limits import BoundedRoute
from app.api.routes._data import audit_now
from app.api.routes._paging import set_total
from app.db.models import AuditEvent

router = APIRouter(prefix="/audit", route_class=BoundedRoute, tags=["audit"])

FIELDS = ("id", "at", "username", "action", "target", "detail", "client")


def _json(e: AuditEvent) -> dict[str, Any]:
    return {"id": e.id, "at": e.at.isoformat(), "username": e.username, "action": e.action,
            "target": e.target, "detail": e.detail, "client": e.client}


def _cell(v: Any) -> Any:
    # a user name typed at a failed login reaches the sheet: no formula may run from it
    return f"'{v}" if isinstance(v, str) and v[:1] in ("=", "+", "-", "@", "\t", "\r") else v


@router.get("", response_model=None)
def entries(request: Request, response: Response, user: CurrentUser, db: DbDep,
            limit: Annotated[int, Query(ge=1, le=10000)] = 200,
            before: Annotated[int | None, Query(ge=1, le=2**63 - 1)] = None,
            action: Annotated[str | None, Query(max_length=16)] = None,
            format: Annotated[Literal["json", "csv"], Query()] = "json"
            ) -> list[dict[str, Any]] | Response:
    """Audit entries, newest first (administrators only)."""
    if not user.is_admin:
        raise HTTPException(status.HTTP_403_FORBIDDEN,
                            "only an administrator may read the audit trail")
    where = []
    if before is not None:
        where.append(AuditEvent.id < before)
    if action:
        where.append(AuditEvent.action == action)
    q = select(AuditEvent).where(*where).order_by(AuditEvent.id.desc()).limit(limit)
    rows = [_json(e) for e in db.scalars(q)]
    if format == "json":
        set_total(response, db.scalar(select(func.count(AuditEvent.id)).where(*where)) or 0)
        return rows
    buf = io.StringIO()
    w = csv.DictWriter(buf, FIELDS)
    w.writeheader()
    w.writerows({k: _cell(v) for k, v in r.items()} for r in rows)
    audit_now(db, request, user, "export", "audit trail", f"{len(rows)} entries")
    return Response(buf.getvalue(), media_type="text/csv", headers={
        "Content-Disposition": 'attachment; filename="gaitrig-audit.csv"'})
