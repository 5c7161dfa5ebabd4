"""Spatial calibration: printable marker sheets, capture from the connected nodes with
progress (accept/reject), saved calibrations (list, view, restore) and the bumped-tripod
check (live re-detection from the nodes' frames, or given poses).

The router's lifespan runs the periodic bumped-tripod check every
``calibration_check_interval_s`` (:meth:`CaptureManager.run_periodic`)."""

from __future__ import annotations

import asyncio
import contextlib
import functools
import re
import tempfile
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

from fastapi import APIRouter, FastAPI, HTTPException, Query, Request, status
from fastapi.responses import Response
from pydantic import BaseModel, Field

from app.api.deps import CurrentUser, HubDep, RegistryDep, SettingsDep
from app.api.limits import BoundedRoute
from app.server import calibration as cal
from app.server.calibration import CaptureBusyError, CaptureManager, CaptureNotFoundError


def _manager(app: Any, hub: Any, data_dir: Path) -> CaptureManager:
    st = app.state
    mgr: CaptureManager | None = getattr(st, "calibration_capture", None)
    if mgr is None or mgr.hub is not hub:
        mgr = st.calibration_capture = CaptureManager(hub, data_dir)
    return mgr


@asynccontextmanager
async def _lifespan(app: FastAPI) -> AsyncIterator[None]:
    """Run the periodic bumped-tripod check (unless its interval is 0)."""
    settings = app.state.settings
    mgr = _manager(app, app.state.hub, settings.data_dir)
    task = None
    if settings.calibration_check_interval_s > 0:
        task = asyncio.create_task(mgr.run_periodic(settings.calibration_check_interval_s))
    try:
        yield
    finally:
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task


router = APIRouter(prefix="/calibration", route_class=BoundedRoute, tags=["calibration"],
                   lifespan=_lifespan)

MAX_SHEET_IDS = 64
#: Largest marker id accepted in an id list (the largest ArUco dictionaries have 1000
#: ids); checked before the ranges are expanded, so "1-999999999" is not a list of a
#: billion ids in the server's memory.
MAX_MARKER_ID = 9999


def marker_ids(spec: str) -> list[int]:
    """``parse_ids`` of a client's id list, with every id at most :data:`MAX_MARKER_ID`.

    Raises:
        InputError: malformed list or an id above the limit.
    """
    from engine.calibration.markers import parse_ids
    from engine.errors import InputError

    for number in re.findall(r"\d+", spec):
        if len(number) > 5 or int(number) > MAX_MARKER_ID:
            raise InputError(f"marker id {number[:12]} is too large: ids go from 0 to "
                             f"{MAX_MARKER_ID} (the printed markers' numbers, e.g. 1-8)")
    return parse_ids(spec)


class SimulateRequest(BaseModel):
    """A calibration run on the simulated avenue (no sensors needed)."""

    seed: int = Field(0, ge=0, le=10_000)
    frames: int = Field(10, ge=2, le=60)


class CaptureRequest(BaseModel):
    """Capture from the connected nodes and calibrate."""

    frames: int = Field(30, ge=2, le=120, description="frames per node (averaged)")
    ids: str = Field("1-8", max_length=200, description="marker ids in the room, e.g. 1-8")
    size_m: float = Field(0.20, gt=0.01, le=1.0, description="marker edge length (m)")
    nodes: list[str] | None = Field(None, max_length=64,
                                    description="node ids (default: every connected node)")


class LiveCheckRequest(BaseModel):
    """Re-detect the markers from the connected nodes and compare with the calibration."""

    frames: int = Field(5, ge=2, le=60)


class PoseCheck(BaseModel):
    """Fresh sensor poses (sensor id → 4×4 ``T_world_sensor``)."""

    T_world_sensor: dict[str, list[list[float]]] = Field(max_length=64)


@functools.lru_cache(maxsize=16)
def _marker_sheet_pdf(ids: tuple[int, ...], size_m: float, dictionary: str,
                      paper: str) -> bytes:
    """The sheet's PDF, drawn once per set of parameters: the wizard's download, a second
    print and the next lab member ask for the same sheet (a few kB each, vectors)."""
    from engine.calibration.markers import write_marker_sheet

    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "markers.pdf"
        write_marker_sheet(list(ids), size_m, out, dictionary=dictionary, paper=paper)
        return out.read_bytes()


@router.get("/markers.pdf")
def marker_sheet(
    user: CurrentUser,
    ids: str = Query("1-8", max_length=200, description="e.g. 1-8 or 1,2,5"),
    size: float = Query(0.20, gt=0.01, le=0.5, description="edge length (m)"),
    dictionary: str = Query("DICT_4X4_50", max_length=40),
    paper: str = Query("a4", pattern="^(a4|letter|a3)$"),
) -> Response:
    """The printable marker sheet as a PDF at true size."""
    from engine.errors import InputError

    id_list = marker_ids(ids)
    if len(id_list) > MAX_SHEET_IDS:
        raise InputError(f"at most {MAX_SHEET_IDS} markers per sheet, got {len(id_list)}")
    data = _marker_sheet_pdf(tuple(id_list), size, dictionary, paper)
    return Response(data, media_type="application/pdf", headers={
        "Content-Disposition": f'attachment; filename="markers-{size * 100:.0f}cm.pdf"'})


def _captures(request: Request, hub: HubDep, settings: SettingsDep) -> CaptureManager:
    return _manager(request.app, hub, settings.data_dir)


async def _start(mgr: CaptureManager, kind: str, frames: int,
                 sizes: dict[int, float] | None, nodes: list[str] | None) -> dict[str, Any]:
    try:
        job = await mgr.start(kind, frames, sizes, nodes)
    except CaptureBusyError as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from exc
    return job.to_dict()


def _job(mgr: CaptureManager, job_id: int) -> Any:
    try:
        return mgr.get(job_id)
    except CaptureNotFoundError as exc:
        raise HTTPException(status.HTTP_404_NOT_FOUND, str(exc)) from exc


@router.post("/capture", status_code=202)
async def capture(body: CaptureRequest, request: Request, user: CurrentUser, hub: HubDep,
                  settings: SettingsDep) -> dict[str, Any]:
    """Ask the connected nodes for ``frames`` colour + depth frames each and calibrate from
    them (detection, 3D corners, graph, chaining, joint optimisation, ICP). Poll
    ``GET /api/calibration/captures/{id}`` for progress and the result; nothing is saved
    until ``POST .../accept``."""
    ids = marker_ids(body.ids)
    mgr = _captures(request, hub, settings)
    return await _start(mgr, "calibrate", body.frames, {i: body.size_m for i in ids},
                        body.nodes)


@router.post("/live-check", status_code=202)
async def live_check(body: LiveCheckRequest, request: Request, user: CurrentUser,
                     hub: HubDep, settings: SettingsDep) -> dict[str, Any]:
    """Bumped-tripod check: re-detect the markers in fresh frames of every connected node
    and compare each sensor's pose with the active calibration (warns above 1 cm / 0.5°).
    Poll ``GET /api/calibration/captures/{id}``; the latest outcome stays at
    ``GET /api/calibration/live-check``."""
    return await _start(_captures(request, hub, settings), "check", body.frames, None, None)


@router.get("/live-check")
def last_live_check(request: Request, user: CurrentUser, hub: HubDep,
                    settings: SettingsDep) -> dict[str, Any]:
    """The latest bumped-tripod check against the active calibration (``{"checked":
    false}`` when none ran yet), ``warnings`` (every sensor found moved and not found back
    in place since: sensor, moved_mm, rotated_deg, found_at, calibration_version and
    calibration_created — what the Rig and Record pages show) and ``periodic`` (state of
    the automatic check: enabled, interval_s, state, reason, at)."""
    return _captures(request, hub, settings).live_check_view()


@router.get("/captures/{job_id}")
def capture_status(job_id: int, request: Request, user: CurrentUser, hub: HubDep,
                   settings: SettingsDep) -> dict[str, Any]:
    """Progress (frames received per node) and, when done, the result of a capture."""
    d: dict[str, Any] = _job(_captures(request, hub, settings), job_id).to_dict()
    return d


@router.post("/captures/{job_id}/accept")
def accept_capture(job_id: int, request: Request, user: CurrentUser, hub: HubDep,
                   settings: SettingsDep, registry: RegistryDep) -> dict[str, Any]:
    """Save the captured calibration as the new active version and apply it to the nodes."""
    mgr = _captures(request, hub, settings)
    _job(mgr, job_id)
    return mgr.accept(job_id, registry)


@router.post("/captures/{job_id}/reject")
def reject_capture(job_id: int, request: Request, user: CurrentUser, hub: HubDep,
                   settings: SettingsDep) -> dict[str, Any]:
    """Discard the captured calibration; the active one stays."""
    mgr = _captures(request, hub, settings)
    _job(mgr, job_id)
    return mgr.reject(job_id)


@router.post("/simulate")
def simulate(body: SimulateRequest, user: CurrentUser, settings: SettingsDep,
             registry: RegistryDep) -> dict[str, Any]:
    """Calibrate the simulated six-sensor avenue, save it as a new version (the active
    one, applied to the nodes' streams), and return it with each sensor's error against the
    simulator's true pose."""
    doc = cal.simulate_and_save(settings.data_dir, body.seed, body.frames)
    doc["applied_to"] = cal.apply_to_registry(registry, settings.data_dir)
    return doc


@router.post("/apply")
def apply(user: CurrentUser, settings: SettingsDep, registry: RegistryDep) -> dict[str, Any]:
    """Give every node the active calibration's pose (also for nodes connecting later)."""
    return {"applied_to": cal.apply_to_registry(registry, settings.data_dir)}


@router.get("")
def list_calibrations(user: CurrentUser, settings: SettingsDep) -> list[dict[str, Any]]:
    """Saved calibrations, newest (active) first."""
    return cal.list_calibrations(settings.data_dir)


@router.get("/defaults")
def defaults(user: CurrentUser, settings: SettingsDep, registry: RegistryDep) -> dict[str, Any]:
    """Marker ids and size the capture form starts with, and where they come from."""
    return cal.suggested_markers(settings.data_dir,
                                 [n.backend for n in registry.nodes.values() if n.connected])


@router.get("/active")
def active(user: CurrentUser, settings: SettingsDep) -> dict[str, Any]:
    """The active calibration (latest version)."""
    return cal.get_calibration(settings.data_dir)


@router.get("/{version}")
def get_version(version: int, user: CurrentUser, settings: SettingsDep) -> dict[str, Any]:
    """One saved calibration in full."""
    return cal.get_calibration(settings.data_dir, version)


@router.post("/{version}/restore")
def restore(version: int, user: CurrentUser, settings: SettingsDep,
            registry: RegistryDep) -> dict[str, Any]:
    """Make an older calibration active again (saved as a new version) and apply it."""
    v = cal.restore(settings.data_dir, version)
    return {"version": v, "restored_from": version,
            "applied_to": cal.apply_to_registry(registry, settings.data_dir)}


@router.post("/check")
def check(body: PoseCheck, user: CurrentUser, settings: SettingsDep) -> dict[str, Any]:
    """Sensors whose fresh pose differs from the active calibration by > 1 cm or > 0.5°."""
    moved = cal.check_pose_change(settings.data_dir, body.T_world_sensor)
    return {"moved": moved, "ok": not moved}
