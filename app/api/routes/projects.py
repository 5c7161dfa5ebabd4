"""Projects (studies / clinics) that group pseudonymised subjects."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, HTTPException, Request, Response, status
from pydantic import BaseModel, Field
from sqlalchemy import func, select

from app.api.deps import CurrentUser, DbDep, ExportsDep, HubDep
from app.api.limits import BoundedRoute
from app.api.routes._data import (
    audit_event,
    check_confirm,
    delete_rows,
    get_project,
    layout_of,
    node_copies,
    project_json,
)
from app.api.routes._paging import LimitQ, OffsetQ, SearchQ, like_pattern, page_of, set_total
from app.db import data as m
from engine.wording import count

router = APIRouter(prefix="/projects", route_class=BoundedRoute, tags=["data"])


class ProjectIn(BaseModel):
    name: str = Field(min_length=1, max_length=120, description="Unique project name.")
    description: str = Field(default="", max_length=4000)


class ProjectPatch(BaseModel):
    name: str | None = Field(default=None, min_length=1, max_length=120)
    description: str | None = Field(default=None, max_length=4000)


class Confirm(BaseModel):
    confirm: str = Field(max_length=200, description="The project name typed again.")


#: Projects per page of ``GET /api/projects``: by default, and at most.
PROJECTS_PAGE, PROJECTS_PAGE_MAX = 500, 1000


@router.get("")
def list_projects(response: Response, user: CurrentUser, db: DbDep, q: SearchQ = None,
                  limit: LimitQ = None, offset: OffsetQ = 0) -> list[dict[str, Any]]:
    """Projects by name with their number of subjects, a page at a time (``limit`` ≤
    1000, default 500; ``offset``; ``X-Total-Count`` header), ``q`` searching the name.

    Two queries whatever the number of projects (the count; the page with its subject
    counts).
    """
    page = page_of(limit, offset, PROJECTS_PAGE, PROJECTS_PAGE_MAX)
    where = []
    if q and q.strip():
        where.append(m.Project.name.ilike(like_pattern(q.strip()), escape="\\"))
    set_total(response, db.scalar(select(func.count(m.Project.id)).where(*where)) or 0)
    n_subj = (select(func.count(m.Subject.id)).where(m.Subject.project_id == m.Project.id)
              .correlate(m.Project).scalar_subquery())
    rows = db.execute(select(m.Project, n_subj).where(*where)
                      .order_by(m.Project.name, m.Project.id)
                      .limit(page.limit).offset(page.offset)).all()
    return [project_json(db, p, n or 0) for p, n in rows]


@router.post("", status_code=201)
def create_project(body: ProjectIn, user: CurrentUser, db: DbDep) -> dict[str, Any]:
    """Create a project."""
    name = body.name.strip()
    if db.scalar(select(m.Project).where(m.Project.name == name)) is not None:
        raise HTTPException(status.HTTP_409_CONFLICT, f"a project named {name!r} exists already")
    p = m.Project(name=name, description=body.description)
    db.add(p)
    db.commit()
    return project_json(db, p)


@router.patch("/{pid}")
def update_project(pid: int, body: ProjectPatch, user: CurrentUser, db: DbDep) -> dict[str, Any]:
    """Rename or describe a project."""
    p = get_project(db, pid)
    if body.name is not None and body.name.strip() != p.name:
        if db.scalar(select(m.Project).where(m.Project.name == body.name.strip())) is not None:
            raise HTTPException(status.HTTP_409_CONFLICT,
                                f"a project named {body.name.strip()!r} exists already")
        p.name = body.name.strip()
    if body.description is not None:
        p.description = body.description
    db.commit()
    return project_json(db, p)


@router.post("/{pid}/delete")
async def delete_project(pid: int, body: Confirm, request: Request, user: CurrentUser, db: DbDep,
                   hub: HubDep, exports: ExportsDep) -> dict[str, Any]:
    """Delete a project with all its subjects, sessions, recordings and their files.

    The body must repeat the project name (``{"confirm": "<name>"}``).
    """
    p = get_project(db, pid)
    check_confirm(p.name, body.confirm, f"project {p.name!r} and everything in it")
    recs = [r for s in p.subjects for x in s.sessions for r in x.recordings]
    plan = await delete_rows(db, hub, layout_of(request), exports, recs, p, audit_event(
        request, user, "delete", f"project {pid}",
        f"{count(len(p.subjects), 'subject')}, {count(len(recs), 'recording')}"))
    return {"deleted": "project", "id": pid, "recordings_deleted": len(plan),
            "node_copies": await node_copies(hub, plan)}
