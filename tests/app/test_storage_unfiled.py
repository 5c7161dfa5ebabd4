"""GET /api/storage/unfiled keeps the filed ids between requests and asks the database
only about the others: the list stays right as recordings are filed, made and deleted."""

from __future__ import annotations

from fastapi.testclient import TestClient

from app.server.recording import Part, Recording


def _unfiled(c: TestClient) -> list[str]:
    r = c.get("/api/storage/unfiled")
    assert r.status_code == 200, r.text
    return [x["id"] for x in r.json()]


def test_unfiled_follows_filing_new_recordings_and_deletion(admin_client: TestClient) -> None:
    c = admin_client
    hub = c.app.state.hub  # type: ignore[attr-defined]
    pid = c.post("/api/projects", json={"name": "p"}).json()["id"]
    sid = c.post("/api/subjects", json={"project_id": pid, "code": "P1"}).json()["id"]
    se = c.post("/api/sessions", json={"subject_id": sid}).json()["id"]
    for k in range(1, 4):
        hub.recordings.recordings[f"R{k}"] = Recording(
            f"R{k}", t_start=float(k), t_stop=k + 1.0, created=float(k),
            parts={"S1": Part("S1", state="on_node", n_frames=3)})
    assert _unfiled(c) == ["R3", "R2", "R1"]
    r = c.post(f"/api/sessions/{se}/recordings/attach", json={"rec_id": "R2"})
    assert r.status_code in (200, 201), r.text
    assert _unfiled(c) == ["R3", "R1"]  # filed since the last request
    hub.recordings.recordings["R4"] = Recording("R4", t_start=4.0, t_stop=5.0, created=4.0)
    assert _unfiled(c) == ["R4", "R3", "R1"]  # made since
    r = c.post("/api/storage/unfiled/R3/delete", json={"confirm": "R3"})
    assert r.status_code == 200, r.text
    assert _unfiled(c) == ["R4", "R1"]
    r = c.post("/api/storage/recordings/R2/delete", json={"confirm": "P1"})
    assert r.status_code == 200, r.text
    assert _unfiled(c) == ["R4", "R1"]  # a deleted filed one leaves the server's list
    assert "R2" not in hub.recordings.recordings
