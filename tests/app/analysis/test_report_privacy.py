"""Reports as health data: no subject identifier in a URL of an upload, and every report
or analysis handed out is in the audit trail (by numeric id, never the subject code)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from engine.io.csv import write_skeleton_csv
from engine.sim.straight_walk import synth_walk, walk_skeleton
from engine.skeleton import KINECT_V2, SkeletonSeries


@pytest.fixture
def client(admin_client: TestClient) -> TestClient:
    return admin_client


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


def test_reports_analyses_and_exports_are_audited_by_numeric_id(
        client: TestClient, tmp_path: Path) -> None:
    from tests.app.data.walk_recording import walk_subject

    ids = walk_subject(client, tmp_path)
    sid, sess = ids["subject_id"], ids["session_id"]
    start = client.get("/api/audit").json()[0]["id"]
    calls = [
        (f"/api/reports/subjects/{sid}", {"format": "pdf"}, f"subject {sid}",
         ["all sessions (1)", "report pdf"]),
        (f"/api/reports/subjects/{sid}", {"format": "html", "session_id": sess},
         f"subject {sid}", [f"session {sess}", "report html"]),
        ("/api/reports/recordings/R1/report", {"format": "pdf"}, "recording R1",
         [f"subject {sid}, session {sess}", "report pdf"]),
        ("/api/reports/recordings/R1/analysis", {"sensors": "S1"}, "recording R1",
         [f"subject {sid}, session {sess}", "analysis json", "sensors S1"]),
        ("/api/reports/recordings/R1/compare", {"a": "S1"}, "recording R1",
         [f"subject {sid}, session {sess}", "comparison"]),
        ("/api/exports/R1/skeleton", {"format": "csv", "source": "S1"}, "recording R1",
         [f"subject {sid}, session {sess}", "skeleton csv S1"]),
        ("/api/exports/R1/skeleton", {"format": "c3d"}, "recording R1",
         [f"subject {sid}, session {sess}", "skeleton c3d fused"]),
    ]
    for path, params, target, words in calls:
        r = client.get(path, params=params)
        assert r.status_code == 200, (path, r.text[:300])
        e = client.get("/api/audit").json()[0]
        assert e["id"] > start, f"{path} {params} left no audit entry"
        start = e["id"]
        assert (e["username"], e["action"], e["target"]) == ("admin", "export", target), e
        assert all(w in e["detail"] for w in words), (words, e)
        assert e["client"] and e["at"]
    # a refused request hands nothing out and records nothing
    assert client.get(f"/api/reports/subjects/{sid}",
                      params={"session_id": 999}).status_code == 404
    assert client.get("/api/audit").json()[0]["id"] == start
    # an uploaded file's report is recorded too, without the code typed for it
    walk = _walk_csv(tmp_path / "walk.csv")
    r = client.post("/api/reports/upload", data={"subject": "P07"},
                    files={"file": ("walk.csv", walk, "text/csv")})
    assert r.status_code == 200
    e = client.get("/api/audit").json()[0]
    assert (e["target"], e["detail"]) == ("uploaded file", "report html of a .csv file (crossing)")
    # no entry names the subject by its code
    log = client.get("/api/audit", params={"limit": 1000}).json()
    assert "A1" not in str(log) and "P07" not in str(log)
