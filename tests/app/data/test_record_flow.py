"""End to end with real server and node processes: file a recording under a session,
stop it, and the server pulls every node's part (verified) on its own; second start
refused; deletion needs the subject code."""

from __future__ import annotations

import hashlib
import json
import time
import urllib.error
from pathlib import Path
from typing import Any

import pytest

from tests.integration.conftest import Rig, wait_for


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def setup_session(rig: Rig, code: str = "P001") -> dict[str, Any]:
    p = rig.api("/api/projects", {"name": "Gait study"})
    s = rig.api("/api/subjects", {"project_id": p["id"], "code": code, "height_m": 1.72,
                                  "leg_length_m": 0.9, "sex": "female", "birth_year": 1980})
    sess = rig.api("/api/sessions", {"subject_id": s["id"], "label": "baseline"})
    return {"project": p, "subject": s, "session": sess}


def record(rig: Rig, session_id: int, seconds: float = 1.5) -> str:
    rec = rig.api(f"/api/sessions/{session_id}/recordings", {"label": "walk 1"})
    time.sleep(seconds)
    rig.api(f"/api/recordings/{rec['id']}/stop", {})
    return str(rec["id"])


def wait_state(rig: Rig, rec_id: str, states: set[str], timeout: float = 40.0
               ) -> dict[str, Any]:
    def done() -> dict[str, Any] | None:
        r = rig.api(f"/api/storage/recordings/{rec_id}")
        return r if r["state"] in states else None

    result: dict[str, Any] = wait_for(done, timeout, f"recording {rec_id} in {states}")
    return result


def http_error(fn: Any) -> tuple[int, str]:
    try:
        fn()
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read())["detail"]
    raise AssertionError("expected an HTTP error")


@pytest.mark.timeout(120)
def test_recording_is_filed_transferred_and_verified(make_rig: Any, tmp_path: Path) -> None:
    rig: Rig = make_rig()
    rig.start_node("S1")
    rig.start_node("S2", "--seed", "1")
    rig.wait_online(["S1", "S2"])
    ids = setup_session(rig)
    rec_id = rig.api(f"/api/sessions/{ids['session']['id']}/recordings", {})["id"]
    # a second recording while one runs is refused with a clear message
    code, msg = http_error(lambda: rig.api(f"/api/sessions/{ids['session']['id']}/recordings",
                                           {}))
    assert code == 409 and "already running" in msg
    time.sleep(1.5)
    rig.api(f"/api/recordings/{rec_id}/stop", {})
    r = wait_state(rig, rec_id, {"complete", "incomplete"})
    assert r["state"] == "complete", r
    assert {p["node_id"] for p in r["parts"]} == {"S1", "S2"}
    for p in r["parts"]:
        assert p["state"] == "complete" and p["progress"] == 1.0 and p["n_frames"] > 20
        node_part = rig.node_dir(p["node_id"]) / "recordings" / rec_id
        server_part = tmp_path / "server" / "recordings" / rec_id / p["node_id"]
        manifest = json.loads((server_part / "manifest.json").read_text())
        for f in manifest["files"]:
            assert _sha(server_part / f["name"]) == f["sha256"] == _sha(node_part / f["name"])
        assert p["manifest_sha256"] == _sha(server_part / "manifest.json")
    subj = rig.api(f"/api/subjects/{ids['subject']['id']}")
    assert subj["bytes_on_server"] > 0
    assert subj["sessions"][0]["recordings"][0]["id"] == rec_id
    usage = rig.api("/api/storage")
    assert usage["subjects"][0]["bytes"] == subj["bytes_on_server"]

    # deletion needs the subject code typed again
    code, msg = http_error(lambda: rig.api(f"/api/storage/recordings/{rec_id}/delete",
                                           {"confirm": "P00"}))
    assert code == 400 and "'P001'" in msg
    rig.api(f"/api/storage/recordings/{rec_id}/delete", {"confirm": "P001"})
    assert not (tmp_path / "server" / "recordings" / rec_id).exists()
    assert rig.api(f"/api/subjects/{ids['subject']['id']}")["n_recordings"] == 0
