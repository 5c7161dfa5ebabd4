"""Planning mode: move planned sensors, see the floor coverage, save and print the rig.

* ``GET /api/planning`` → planned sensors (position, yaw, pitch, moved?), coverage
  fractions (whole grid and walkway), grid, walkway, where the poses came from, legend.
* ``GET /api/planning/coverage.png`` → the coverage map image (north up).
* ``PUT /api/planning/sensors/{id}`` ``{position?, yaw_deg?, pitch_deg?}`` → moves one
  planned sensor (what dragging its handle in the 3D view does) and returns the new state.
* ``POST /api/planning/reset`` → back to the rig's poses.
* ``POST /api/planning/save`` ``{name}`` → writes ``<data_dir>/rigs/<name>.toml``, a
  simulator rig file (``gaitrig node --backend sim --rig ...``).
* ``GET /api/planning/sheet`` → printable placement sheet (HTML): every tripod's distance
  and bearing from marker 1, height, yaw and pitch.
"""

from __future__ import annotations

import html
import time
from typing import Any

from fastapi import APIRouter, Request, Response
from fastapi.responses import HTMLResponse
from pydantic import BaseModel, Field

from app.api.deps import CurrentUser, SettingsDep
from app.api.limits import BoundedRoute
from app.api.routes.live import services_of
from app.viewer.planning import Planner
from engine.coverage import coverage_legend

router = APIRouter(prefix="/planning", route_class=BoundedRoute, tags=["planning"])


class MoveIn(BaseModel):
    """New placement of one planned sensor (omitted fields keep their value)."""

    position: tuple[float, float, float] | None = Field(
        default=None, description="Optical centre (x, y, z) in metres, world frame.")
    yaw_deg: float | None = Field(default=None, ge=-360, le=360,
                                  description="Heading, counter-clockwise from +X.")
    pitch_deg: float | None = Field(default=None, ge=-89, le=89,
                                    description="Elevation; negative tilts down.")


class SaveIn(BaseModel):
    name: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_-]+$",
                      description="File name without extension: letters, digits, - or _.")


def _planner(request: Request) -> Planner:
    return services_of(request.app).get_planner()


def _state(p: Planner) -> dict[str, Any]:
    out = p.summary()
    out["legend"] = [{"label": label, "rgb": list(rgb)} for label, rgb in coverage_legend()]
    return out


@router.get("")
async def get_plan(request: Request, user: CurrentUser) -> dict[str, Any]:
    """The planned rig and its coverage."""
    return _state(_planner(request))


@router.get("/coverage.png")
async def coverage_png(request: Request, user: CurrentUser) -> Response:
    """Coverage map of the planned rig (red = blind spot, white hatch = both sides)."""
    p = _planner(request)
    return Response(p.png(), media_type="image/png",
                    headers={"Cache-Control": "no-store", "X-Plan-Version": str(p.version)})


@router.put("/sensors/{sensor_id}")
async def move_sensor(sensor_id: str, body: MoveIn, request: Request,
                      user: CurrentUser) -> dict[str, Any]:
    """Move one planned sensor; the coverage map (API and 3D view) follows."""
    p = _planner(request)
    p.move(sensor_id, position=body.position, yaw_deg=body.yaw_deg, pitch_deg=body.pitch_deg)
    return _state(p)


@router.post("/reset")
async def reset(request: Request, user: CurrentUser) -> dict[str, Any]:
    """Discard the planned moves."""
    p = _planner(request)
    p.reset()
    return _state(p)


@router.post("/save")
async def save(body: SaveIn, request: Request, user: CurrentUser,
               settings: SettingsDep) -> dict[str, Any]:
    """Save the planned rig as a simulator rig file in the server's data folder."""
    path = _planner(request).save(settings.data_dir / "rigs", body.name)
    return {"name": body.name, "file": f"rigs/{path.name}", "bytes": path.stat().st_size}


@router.get("/sheet", response_class=HTMLResponse)
async def sheet(request: Request, user: CurrentUser) -> HTMLResponse:
    """Printable placement sheet of the planned rig."""
    p = _planner(request)
    s = p.summary()
    rows = "".join(
        f"<tr><th scope='row'>{html.escape(r['id'])}</th><td>{r['distance_cm']:.1f}</td>"
        f"<td>{r['bearing_deg']:.1f}</td><td>{r['height_cm']:.1f}</td>"
        f"<td>{r['yaw_deg']:.1f}</td><td>{r['pitch_deg']:.1f}</td></tr>"
        for r in p.placement_rows())
    when = time.strftime("%Y-%m-%d %H:%M", time.localtime())
    page = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>gaitrig — placement sheet</title>
<link rel="stylesheet" href="/style.css"><link rel="stylesheet" href="/css/live.css"></head>
<body class="sheet"><main>
<h1>Tripod placement sheet</h1>
<p>Printed {html.escape(when)}. Distances and bearings are measured on the floor from the
centre of <strong>marker 1</strong> (the world origin); bearing and yaw are counter-clockwise
from the walkway direction (+X). Poses from: {html.escape(s['source'])}.</p>
<p>Walkway seen by at least one sensor: {100 * s['walkway_covered_fraction']:.0f} %;
from both sides: {100 * s['walkway_two_sided_fraction']:.0f} %.</p>
<table id="placement"><thead><tr><th scope="col">Sensor</th><th scope="col">Distance (cm)</th>
<th scope="col">Bearing (°)</th><th scope="col">Height (cm)</th><th scope="col">Yaw (°)</th>
<th scope="col">Pitch (°)</th></tr></thead><tbody>{rows}</tbody></table>
<img class="sheet-map" src="/api/planning/coverage.png?v={s['version']}"
 alt="Coverage map of the planned rig: red cells are blind spots">
<p class="no-print"><button onclick="window.print()">Print</button></p>
</main></body></html>"""
    return HTMLResponse(page)
