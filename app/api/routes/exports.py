"""Exports of a recording (skeleton C3D / TRC / CSV, fused or per sensor; depth frames
as PNG zip or NPZ) and imports of reference recordings (C3D, TRC, CSV) attached to it.

Skeleton exports: ``source=fused`` integrates every sensor with the recording's own pose
snapshot (``sensors.json``, shared with the analysis, so a later recalibration does not
change it; world frame, Z up, 30 Hz; C3D carries the gait events when a walk is detected);
``source=<node id>`` exports that sensor's own skeleton in its camera frame (CSV at the
recorded times; C3D/TRC resampled to a uniform rate). CSV columns are
``time,<Joint>_x,<Joint>_y,<Joint>_z,<Joint>_state`` in metres with Kinect v2 names.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import re
import secrets
import time
from pathlib import Path
from typing import Annotated, Any, Literal
from urllib.parse import quote

from fastapi import APIRouter, File, HTTPException, Query, Request, Response, UploadFile, status

from app.api.deps import CurrentUser, DbDep, HubDep
from app.api.limits import BoundedRoute, refused_with
from app.api.routes import _reference
from app.api.routes._data import (
    audit_event,
    audit_now,
    get_recording,
    get_row,
    layout_of,
    purge,
    reference_json,
)
from app.api.routes._reference import check_reference, receive, reference_type, upload_name
from app.db import data as m
from app.server import erasures
from app.server.recording_file import fsync_dir
from app.server.storage import (
    check_id,
    depth_frames,
    depth_npz,
    depth_zip,
    export_skeleton,
    fused_skeleton,
    note_changed,
    read_part_skeleton,
    recording_poses,
    sensor_streams,
    uniform_series,
)

router = APIRouter(prefix="/exports", route_class=BoundedRoute, tags=["data"])

_MEDIA = {"c3d": "application/octet-stream", "trc": "text/plain", "csv": "text/csv",
          "zip": "application/zip", "npz": "application/octet-stream"}


def _whose(rec: m.Recording) -> str:
    """The recording's subject and session for the audit trail: numeric ids, never the
    subject code (the trail outlives a deleted subject and must not keep its pseudonym)."""
    return f"subject {rec.session.subject_id}, session {rec.session_id}"


def _download(data: bytes, filename: str, ext: str) -> Response:
    # HTTP headers are Latin-1: a clinic's file name with "ü" or "✓" as such made the
    # download a 500. ASCII fallback for old clients, the exact name as RFC 6266 filename*.
    plain = re.sub(r"[^A-Za-z0-9_.() -]", "_", filename) or f"download.{ext}"
    disposition = f"attachment; filename=\"{plain}\"; filename*=UTF-8''{quote(filename, safe='')}"
    return Response(data, media_type=_MEDIA[ext], headers={"Content-Disposition": disposition})


@router.get("/{rec_id}/skeleton")
async def skeleton(rec_id: str, request: Request, user: CurrentUser, db: DbDep, hub: HubDep,
                   format: Annotated[Literal["c3d", "trc", "csv"], Query()] = "c3d",
                   source: Annotated[str, Query(max_length=64)] = "fused") -> Response:
    """Skeleton trajectories of a recording (see the module docstring)."""
    rec = get_recording(db, rec_id)
    layout = layout_of(request)
    if source == "fused":
        # the recording's own poses (sensors.json), not whatever is calibrated now
        poses = await asyncio.to_thread(recording_poses, layout, hub.registry, rec.id)

        def work() -> bytes:
            series, events = fused_skeleton(sensor_streams(layout, rec.id, poses))
            return export_skeleton(series, format, events)
    else:
        node = check_id(source, "sensor id")
        if node not in layout.complete_parts(rec.id):
            raise HTTPException(status.HTTP_404_NOT_FOUND,
                                f"sensor {node}'s part of {rec.id} is not on the server")

        def work() -> bytes:
            series = read_part_skeleton(layout.part_dir(rec.id, node))
            return export_skeleton(series if format == "csv" else uniform_series(series), format)

    data = await asyncio.to_thread(work)
    audit_now(db, request, user, "export", f"recording {rec.id}",
              f"{_whose(rec)}; skeleton {format} {source}")
    return _download(data, f"{rec.id}_{source}.{format}", format)


@router.get("/{rec_id}/depth")
async def depth(rec_id: str, request: Request, user: CurrentUser, db: DbDep,
                node: Annotated[str, Query(max_length=64)],
                format: Annotated[Literal["zip", "npz"], Query()] = "zip",
                t0: Annotated[float | None, Query(ge=0, description="s after the start")] = None,
                t1: Annotated[float | None, Query(ge=0, description="s after the start")] = None
                ) -> Response:
    """Recorded depth frames of one sensor between ``t0`` and ``t1`` (seconds after the
    recording's start): 16-bit PNGs in millimetres (zip) or one NPZ."""
    rec = get_recording(db, rec_id)
    layout = layout_of(request)
    node = check_id(node, "sensor id")
    if node not in layout.complete_parts(rec.id):
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            f"sensor {node}'s part of {rec.id} is not on the server")
    if t0 is not None and t1 is not None and t1 < t0:
        raise HTTPException(status.HTTP_400_BAD_REQUEST, "t1 must not be before t0")
    base = rec.t_start or 0.0
    a = base + t0 if t0 is not None else None
    b = base + t1 if t1 is not None else None

    def work() -> bytes:
        frames = depth_frames(layout.part_dir(rec.id, node), a, b)
        return depth_zip(frames) if format == "zip" else depth_npz(frames)

    data = await asyncio.to_thread(work)
    audit_now(db, request, user, "export", f"recording {rec.id}",
              f"{_whose(rec)}; depth {format} {node}")
    return _download(data, f"{rec.id}_{node}_depth.{format}", format)


@router.get("/{rec_id}/references")
def references(rec_id: str, user: CurrentUser, db: DbDep) -> list[dict[str, Any]]:
    """Reference recordings attached to a recording."""
    return [reference_json(x) for x in get_recording(db, rec_id).references]


@router.post("/{rec_id}/references", status_code=201,
             max_body_size=_reference.MAX_REFERENCE_BYTES + _reference.UPLOAD_OVERHEAD)
@refused_with(_reference.too_large)  # a request too large: receive()'s words, unnamed
async def upload_reference(rec_id: str, request: Request, user: CurrentUser, db: DbDep,
                           file: Annotated[UploadFile, File(description="C3D, TRC or CSV")]
                           ) -> dict[str, Any]:
    """Attach a reference recording (e.g. Vicon C3D) for the agreement analysis."""
    rec = get_recording(db, rec_id)
    name = upload_name(file.filename)
    ext = reference_type(name)  # the same words, limit and checks as the Reports page's
    folder = layout_of(request).reference_dir(rec.id)
    folder.mkdir(parents=True, exist_ok=True)
    _sweep_stale_uploads(folder)
    stored = f"{secrets.token_hex(8)}.{ext}"
    path = folder / stored
    # Written under a temporary name (backups skip *.tmp, _sweep_stale_uploads removes one
    # left by a killed server), checked, renamed into place and only then its row
    # committed: a backup never takes a half-written file, nor a row without its file (a
    # file without its row, if the server dies in between, is an orphan the start-up
    # clean-up removes a day later: app.server.cleanup); a failed upload leaves none.
    tmp = folder / f".{stored}{_UPLOAD_SUFFIX}"
    placed = False
    try:
        with open(tmp, "wb") as f:
            size = await receive(file, f, name)  # 413 when too large, 400 when empty
            f.flush()
            os.fsync(f.fileno())
        # read, and the report's gait analysis of it, now (as the Reports page's reference
        # is): 400 for a file no reader takes, 422 for one with no usable walk in it, in
        # the same words on both pages (app.api.routes._reference). Bounded by
        # its MAX_REFERENCE_BYTES, in a worker thread.
        traj, _ = await asyncio.to_thread(check_reference, tmp, ext, name,
                                          [x.filename for x in rec.references])
        try:
            os.replace(tmp, path)
            fsync_dir(folder)
        except OSError as exc:
            raise HTTPException(status.HTTP_507_INSUFFICIENT_STORAGE,
                                f"{name!r} could not be stored on the server "
                                f"({exc.strerror or exc}); free space in the data folder and "
                                "upload it again") from exc
        placed = True
        ref = m.ReferenceImport(recording_id=rec.id, filename=name, format=ext,
                                stored_name=stored, size=size, rate_hz=float(traj.rate),
                                n_frames=len(traj), labels_json=json.dumps(traj.labels))
        db.add(ref)
        db.commit()
    except BaseException:
        tmp.unlink(missing_ok=True)
        if placed:  # its row did not commit: the file goes too
            path.unlink(missing_ok=True)
        raise
    finally:
        note_changed(folder)  # the recording's bytes on the server (GET /api/storage)
    return reference_json(ref)


#: Suffix of a reference being uploaded (ends in ``.tmp``: backups leave it out).
_UPLOAD_SUFFIX = ".upload.tmp"
#: Age after which an upload's temporary file is an orphan (a server killed mid-upload).
_STALE_UPLOAD_S = 24 * 3600.0


def _sweep_stale_uploads(folder: Path) -> None:
    """Remove temporary upload files of ``folder`` older than a day (no upload lasts so long)."""
    now = time.time()
    for p in folder.glob(f".*{_UPLOAD_SUFFIX}"):
        with contextlib.suppress(OSError):
            if now - p.stat().st_mtime > _STALE_UPLOAD_S:
                p.unlink()


def _ref(db: DbDep, rec_id: str, ref_id: int) -> m.ReferenceImport:
    ref = get_row(db, m.ReferenceImport, ref_id)
    if ref is None or ref.recording_id != rec_id:
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            f"no reference {ref_id} attached to {rec_id}")
    return ref


@router.get("/{rec_id}/references/{ref_id}")
def download_reference(rec_id: str, ref_id: int, request: Request, user: CurrentUser,
                       db: DbDep) -> Response:
    """The uploaded reference file as it was uploaded."""
    ref = _ref(db, rec_id, ref_id)
    rec = get_recording(db, rec_id)
    path = layout_of(request).reference_dir(rec_id) / check_id(ref.stored_name, "file")
    if not path.is_file():  # e.g. the data folder was restored without it
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            f"the file of reference {ref_id} ({ref.filename!r}) is missing from "
                            "the server; delete the reference and upload it again")
    data = path.read_bytes()
    audit_now(db, request, user, "export", f"recording {rec_id}",
              f"{_whose(rec)}; reference {ref_id}")
    return _download(data, ref.filename, ref.format)


@router.post("/{rec_id}/references/{ref_id}/delete")
def delete_reference(rec_id: str, ref_id: int, request: Request, user: CurrentUser,
                     db: DbDep) -> dict[str, Any]:
    """Detach and delete a reference recording."""
    ref = _ref(db, rec_id, ref_id)
    layout = layout_of(request)
    path = layout.reference_dir(rec_id) / check_id(ref.stored_name, "file")
    # logged like every deletion, so that a restore of an older backup deletes it again
    eid = erasures.begin(layout.data_dir, [], ref, {})
    try:
        db.delete(ref)
        db.add(audit_event(request, user, "delete", f"recording {rec_id}",
                           f"reference {ref_id}"))
        db.commit()
    except BaseException:
        db.rollback()
        erasures.finish(layout.data_dir, eid, committed=False)
        raise
    erasures.finish(layout.data_dir, eid, committed=True)
    path.unlink(missing_ok=True)  # after the commit: a failed one keeps row and file
    note_changed(path)
    purge(db)
    return {"deleted": "reference", "id": ref_id}
