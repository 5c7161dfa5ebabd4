"""Spatial calibration: printable marker sheets, saved calibrations (list, view, restore)
and the bumped-tripod check."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

from fastapi import APIRouter, Query
from fastapi.responses import Response
from pydantic import BaseModel, Field

from app.api.deps import CurrentUser, RegistryDep, SettingsDep
from app.server import calibration as cal

router = APIRouter(prefix="/calibration", tags=["calibration"])

MAX_SHEET_IDS = 64


class SimulateRequest(BaseModel):
    """A calibration run on the simulated avenue (no sensors needed)."""

    seed: int = Field(0, ge=0, le=10_000)
    frames: int = Field(10, ge=2, le=60)


class PoseCheck(BaseModel):
    """Fresh sensor poses (sensor id → 4×4 ``T_world_sensor``)."""

    T_world_sensor: dict[str, list[list[float]]] = Field(max_length=64)


@router.get("/markers.pdf")
def marker_sheet(
    user: CurrentUser,
    ids: str = Query("1-8", max_length=200, description="e.g. 1-8 or 1,2,5"),
    size: float = Query(0.20, gt=0.01, le=0.5, description="edge length (m)"),
    dictionary: str = Query("DICT_4X4_50", max_length=40),
    paper: str = Query("a4", pattern="^(a4|letter|a3)$"),
) -> Response:
    """The printable marker sheet as a PDF at true size."""
    from engine.calibration.markers import parse_ids, write_marker_sheet
    from engine.errors import InputError

    id_list = parse_ids(ids)
    if len(id_list) > MAX_SHEET_IDS:
        raise InputError(f"at most {MAX_SHEET_IDS} markers per sheet, got {len(id_list)}")
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "markers.pdf"
        write_marker_sheet(id_list, size, out, dictionary=dictionary, paper=paper)
        data = out.read_bytes()
    return Response(data, media_type="application/pdf", headers={
        "Content-Disposition": f'attachment; filename="markers-{size * 100:.0f}cm.pdf"'})


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
