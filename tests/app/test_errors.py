"""Engine errors reach the clinician as 4xx with the engine's message, never a 500."""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter
from fastapi.testclient import TestClient

from app.config import Settings
from app.main import create_app
from engine.errors import CalibrationError, InputError


def test_engine_errors_map_to_4xx(tmp_path: Path) -> None:
    app = create_app(Settings(data_dir=tmp_path, viewer_enabled=False, admin_password="pw-123456"))
    probe = APIRouter()

    @probe.get("/probe/input")
    def bad_input() -> None:
        raise InputError("column 'AnkleLeft_x' is missing")

    @probe.get("/probe/calibration")
    def unreachable() -> None:
        raise CalibrationError("S5, S6 cannot reach marker 1", unreachable=["S5", "S6"])

    # before the static console mounted at "/", which would answer first
    app.router.routes[:0] = probe.routes
    with TestClient(app) as client:
        r = client.get("/probe/input")
        assert r.status_code == 400 and "AnkleLeft_x" in r.json()["detail"]
        r = client.get("/probe/calibration")
        assert r.status_code == 422
        assert r.json() == {"detail": "S5, S6 cannot reach marker 1", "unreachable": ["S5", "S6"]}
