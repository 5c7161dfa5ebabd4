"""Shared fixtures of the server tests."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from app.config import Settings
from app.main import create_app


@pytest.fixture
def admin_client(tmp_path: Path) -> Iterator[TestClient]:
    """The app on ``tmp_path`` (no 3D view), logged in as the administrator (bearer
    token); a server error is answered as 500, not raised into the test."""
    s = Settings(data_dir=tmp_path, viewer_enabled=False, node_token="test-node-token",
                 admin_password="secret-pw")
    with TestClient(create_app(s), raise_server_exceptions=False) as c:
        r = c.post("/api/auth/login", json={"username": "admin", "password": "secret-pw"})
        c.headers["Authorization"] = f"Bearer {r.json()['token']}"
        yield c
