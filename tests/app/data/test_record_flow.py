"""End to end with real server and node processes: file a recording under a session,
stop it, and the server pulls every node's part (verified) on its own; second start
refused; deletion needs the subject code and deletes the nodes' copies too."""

from __future__ import annotations

import hashlib
import io
import json
import time
import urllib.error
import urllib.request
import zipfile
from pathlib import Path
from typing import Any

import ezc3d
import numpy as np
import pytest

from app.server.storage import (
    StorageLayout,
    export_skeleton,
    read_part_skeleton,
    read_reference,
    uniform_series,
)
from engine.io.c3d import read_c3d
from engine.io.csv import read_skeleton_csv
from engine.io.trc import read_trc
from engine.skeleton import KINECT_V2, TrackingState
from tests.integration.conftest import Rig, wait_for


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def setup_session(rig: Rig, code: str = "P001") -> dict[str, Any]:
    p = rig.api("/api/projects", {"name": "Gait study"})
    s = rig.api("/api/subjects", {"project_id": p["id"], "code": code, "height_m": 1.72,
                                  "leg_length_m": 0.9, "sex": "female", "birth_year": 1980})
    sess = rig.api("/api/sessions", {"subject_id": s["id"], "label": "baseline"})
    return {"project": p, "subject": s, "session": sess}


def two_node_rig(make_rig: Any) -> Rig:
    """A server with node S1 (with images) and node S2 (another simulated walker), both
    online."""
    rig: Rig = make_rig()
    rig.start_node("S1", images=True)
    rig.start_node("S2", "--seed", "1")
    rig.wait_online(["S1", "S2"])
    return rig


def record(rig: Rig, session_id: int, seconds: float = 1.5,
           streams: list[str] | None = None) -> str:
    """A recording filed under the session, ``seconds`` long (images of ``streams`` of
    every 5th frame). Returns its id."""
    rec = rig.api(f"/api/sessions/{session_id}/recordings",
                  {"label": "walk 1", "streams": streams or [], "image_every": 5})
    time.sleep(seconds)
    rig.api(f"/api/recordings/{rec['id']}/stop", {})
    return str(rec["id"])


def wait_state(rig: Rig, rec_id: str, states: set[str], timeout: float = 90.0
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


@pytest.mark.timeout(300)
def test_recording_is_filed_transferred_and_verified(make_rig: Any, tmp_path: Path) -> None:
    rig = two_node_rig(make_rig)
    ids = setup_session(rig)
    rec_id = rig.api(f"/api/sessions/{ids['session']['id']}/recordings",
                     {"streams": ["depth"], "image_every": 5})["id"]
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
    # the sensor poses of the rig at that time are kept with the complete recording
    poses = json.loads((tmp_path / "server" / "recordings" / rec_id / "sensors.json")
                       .read_text())
    assert set(poses) == {"S1", "S2"} and all(p["source"] == "node" for p in poses.values())
    subj = rig.api(f"/api/subjects/{ids['subject']['id']}")
    assert subj["bytes_on_server"] > 0
    assert subj["sessions"][0]["recordings"][0]["id"] == rec_id
    usage = rig.api("/api/storage")
    assert usage["subjects"][0]["bytes"] == subj["bytes_on_server"]

    check_exports(rig, tmp_path / "server", rec_id)

    # a recording started without a session (Rig page) is transferred all the same and
    # can be filed under a session afterwards
    other = rig.api("/api/recordings", {})["id"]
    time.sleep(1.0)
    rig.api(f"/api/recordings/{other}/stop", {})
    wait_for(lambda: rig.api(f"/api/recordings/{other}")["state"] == "complete", 40,
             "the unfiled recording to be transferred")
    assert [r["id"] for r in rig.api("/api/storage/unfiled")] == [other]
    rig.api(f"/api/sessions/{ids['session']['id']}/recordings/attach", {"rec_id": other})
    assert wait_state(rig, other, {"complete"})["state"] == "complete"
    assert rig.api("/api/storage/unfiled") == []

    # deleting is real: the nodes delete their copies too; a node that is offline
    # deletes its copy as soon as it is back (the request survives in node_deletions.json)
    on_node = {n: rig.node_dir(n) / "recordings" for n in ("S1", "S2")}
    assert (on_node["S1"] / other).is_dir() and (on_node["S2"] / other).is_dir()
    rig.procs["S2"].terminate()
    rig.procs["S2"].wait()
    wait_for(lambda: not rig.nodes()["S2"]["connected"], 20, "S2 to be offline")
    r = rig.api(f"/api/storage/recordings/{other}/delete", {"confirm": "P001"})
    assert r["node_copies"]["S1"] == "deleted", r
    assert "offline" in r["node_copies"]["S2"], r
    assert not (on_node["S1"] / other).exists()
    assert (on_node["S2"] / other).is_dir()  # still there while S2 is off
    assert rig.api("/api/storage")["pending_node_deletions"] == {"S2": [other]}
    rig.start_node("S2", "--seed", "1", name="S2-again")
    rig.wait_online(["S2"])
    wait_for(lambda: not (on_node["S2"] / other).exists(), 30, "S2 to delete its copy")
    wait_for(lambda: rig.api("/api/storage")["pending_node_deletions"] == {}, 10,
             "no pending node deletion")
    assert rig.api("/api/storage/unfiled") == []  # the reconnected node did not revive it

    # deletion needs the subject code typed again
    code, msg = http_error(lambda: rig.api(f"/api/storage/recordings/{rec_id}/delete",
                                           {"confirm": "P00"}))
    assert code == 400 and "'P001'" in msg
    assert (on_node["S1"] / rec_id).is_dir()  # a refused deletion deletes nothing
    r = rig.api(f"/api/storage/recordings/{rec_id}/delete", {"confirm": "P001"})
    assert r["node_copies"] == {"S1": "deleted", "S2": "deleted"}, r
    assert not (tmp_path / "server" / "recordings" / rec_id).exists()
    assert not (on_node["S1"] / rec_id).exists() and not (on_node["S2"] / rec_id).exists()
    assert rig.api(f"/api/subjects/{ids['subject']['id']}")["n_recordings"] == 0


def download(rig: Rig, path: str) -> bytes:
    req = urllib.request.Request(rig.base + path,
                                 headers={"Authorization": f"Bearer {rig.token}"})
    with urllib.request.urlopen(req, timeout=30) as r:
        data: bytes = r.read()
    return data


def upload(rig: Rig, path: str, name: str, data: bytes) -> Any:
    boundary = "gaitrigboundary"
    body = (f"--{boundary}\r\nContent-Disposition: form-data; name=\"file\"; "
            f"filename=\"{name}\"\r\nContent-Type: application/octet-stream\r\n\r\n"
            ).encode() + data + f"\r\n--{boundary}--\r\n".encode()
    req = urllib.request.Request(rig.base + path, data=body, method="POST", headers={
        "Authorization": f"Bearer {rig.token}",
        "Content-Type": f"multipart/form-data; boundary={boundary}"})
    with urllib.request.urlopen(req, timeout=30) as r:
        return json.loads(r.read())


def check_exports(rig: Rig, server_dir: Path, rec_id: str) -> None:
    tmp = server_dir.parent / "exports"
    tmp.mkdir()
    # per-sensor CSV: exactly the transferred skeleton (times on the server clock)
    truth = read_part_skeleton(StorageLayout(server_dir).part_dir(rec_id, "S2"))
    (tmp / "s2.csv").write_bytes(download(rig, f"/api/exports/{rec_id}/skeleton?format=csv"
                                               "&source=S2"))
    back = read_skeleton_csv(tmp / "s2.csv")
    assert back.joint_set.joints == KINECT_V2.joints
    np.testing.assert_array_equal(back.times, truth.times)
    np.testing.assert_allclose(back.positions, truth.positions, atol=1e-12, equal_nan=True)
    np.testing.assert_array_equal(back.states, truth.states)
    # per-sensor C3D: uniform rate, labels = joint names, mm → m within float32 precision
    (tmp / "s2.c3d").write_bytes(download(rig, f"/api/exports/{rec_id}/skeleton?format=c3d"
                                               "&source=S2"))
    u = uniform_series(truth)
    c = ezc3d.c3d(str(tmp / "s2.c3d"))
    assert c["parameters"]["POINT"]["LABELS"]["value"][:25] == list(KINECT_V2.joints)
    assert c["parameters"]["POINT"]["RATE"]["value"][0] == pytest.approx(30.0)
    m_c3d = read_c3d(tmp / "s2.c3d")
    assert len(m_c3d) == len(u)
    np.testing.assert_allclose(m_c3d.positions, u.positions, atol=1e-5, equal_nan=True)
    # fused TRC and C3D (world frame from the sensors' poses)
    (tmp / "fused.trc").write_bytes(download(rig, f"/api/exports/{rec_id}/skeleton?format=trc"
                                                  "&source=fused"))
    trc = read_trc(tmp / "fused.trc")
    assert trc.labels == list(KINECT_V2.joints) and trc.rate == pytest.approx(30.0)
    # The walker's place in the corridor at recording time depends on the wall clock, so
    # the fused export must cover what the sensors tracked, whatever that was.
    sensor_cover = (u.states == TrackingState.TRACKED).mean()  # fusion drops inferred joints
    fused_cover = np.isfinite(trc.positions).mean()
    if sensor_cover > 0:
        assert fused_cover >= 0.8 * sensor_cover, (fused_cover, sensor_cover)
    fused_c3d = download(rig, f"/api/exports/{rec_id}/skeleton?format=c3d&source=fused")
    (tmp / "fused.c3d").write_bytes(fused_c3d)
    mf = read_c3d(tmp / "fused.c3d")
    np.testing.assert_allclose(mf.positions, trc.positions, atol=1e-5, equal_nan=True)
    # the in-process writer gives the same bytes' content for the same series
    assert export_skeleton(truth, "csv") == (tmp / "s2.csv").read_bytes()
    # depth frames of S1 (recorded every 5th frame) as 16-bit PNGs and as NPZ
    npz = np.load(io.BytesIO(download(rig, f"/api/exports/{rec_id}/depth?node=S1&format=npz")))
    assert npz["depth_mm"].dtype == np.uint16 and npz["depth_mm"].shape[0] >= 3
    z = zipfile.ZipFile(io.BytesIO(download(rig, f"/api/exports/{rec_id}/depth?node=S1")))
    assert len(z.namelist()) == npz["depth_mm"].shape[0]
    code, msg = http_error(lambda: download(rig, f"/api/exports/{rec_id}/depth?node=S2"))
    assert code == 400 and "depth" in msg
    code, _ = http_error(lambda: download(rig, f"/api/exports/{rec_id}/skeleton?source=..%2Fx"))
    assert code == 400
    # reference import: a C3D is attached with its labels and rate; junk is refused. (A
    # synthetic walk as the skeleton export writes it: this 1.5 s recording's own export
    # has no steps, and a reference without steps is refused, test_reference_walk_check.)
    from tests.app.mocap_files import walk_skeleton_c3d

    walk_c3d, n_walk = walk_skeleton_c3d()
    ref = upload(rig, f"/api/exports/{rec_id}/references", "vicon walk.c3d", walk_c3d)
    assert ref["format"] == "c3d" and ref["rate_hz"] == pytest.approx(30.0)
    assert ref["labels"][:25] == list(KINECT_V2.joints) and ref["n_frames"] == n_walk
    assert read_reference(server_dir / "references" / rec_id / next(
        p.name for p in (server_dir / "references" / rec_id).iterdir()), "c3d").labels
    code, msg = http_error(lambda: upload(rig, f"/api/exports/{rec_id}/references", "x.c3d",
                                          b"not a c3d file" * 10))
    assert code == 400 and "not a readable C3D" in msg
    code, msg = http_error(lambda: upload(rig, f"/api/exports/{rec_id}/references", "x.txt",
                                          b"1,2,3"))
    assert code == 400 and ".c3d" in msg
    assert len(rig.api(f"/api/exports/{rec_id}/references")) == 1
