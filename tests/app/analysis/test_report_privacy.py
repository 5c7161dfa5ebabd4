"""Reports as health data: no subject identifier in a URL of an upload, and every report
or analysis handed out is in the audit trail (by numeric id, never the subject code)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.config import Settings
from app.main import create_app
from engine.io.csv import write_skeleton_csv
from engine.sim.straight_walk import synth_walk, walk_skeleton
from engine.skeleton import KINECT_V2, SkeletonSeries


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    s = Settings(data_dir=tmp_path, viewer_enabled=False, node_token="test-node-token",
                 admin_password="secret-pw")
    with TestClient(create_app(s), raise_server_exceptions=False) as c:
        r = c.post("/api/auth/login", json={"username": "admin", "password": "secret-pw"})
        c.headers["Authorization"] = f"Bearer {r.json()['token']}"
        yield c


def _walk_csv(path: Path) -> bytes:
    w = synth_walk(n_steps=12, rate=30.0)
    P = walk_skeleton(w)
    write_skeleton_csv(path, SkeletonSeries(w.times, P, np.full(P.shape[:2], 2, np.uint8),
                                            KINECT_V2))
    return path.read_bytes()


def test_the_upload_takes_the_subject_code_from_the_form_not_the_url(
        client: TestClient, tmp_path: Path) -> None:
    walk = _walk_csv(tmp_path / "walk.csv")
    r = client.post("/api/reports/upload", params={"format": "html"},
                    data={"subject": "P07"}, files={"file": ("walk.csv", walk, "text/csv")})
    assert r.status_code == 200, r.text
    assert "P07" in r.text and "Step length" in r.text
    assert "P07" not in str(r.request.url)
    # the code in the URL (access logs, history) is refused with what to do instead
    for key in ("subject", "code"):
        r = client.post("/api/reports/upload", params={key: "P07"},
                        files={"file": ("walk.csv", walk, "text/csv")})
        assert r.status_code == 400, r.text
        assert "form field" in r.json()["detail"] and "P07" not in r.json()["detail"]
    # no code given: the report says "upload", as before
    r = client.post("/api/reports/upload", files={"file": ("walk.csv", walk, "text/csv")})
    assert r.status_code == 200 and "upload" in r.text
    r = client.post("/api/reports/upload", data={"subject": "x" * 41},
                    files={"file": ("walk.csv", walk, "text/csv")})
    assert r.status_code == 422


def test_the_console_sends_the_upload_code_in_the_form() -> None:
    js = (Path(__file__).resolve().parents[3] / "static" / "js" / "reports.js").read_text()
    assert 'fd.append("subject", code)' in js
    assert "subject: code" not in js
