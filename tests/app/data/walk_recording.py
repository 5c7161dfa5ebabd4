"""A subject whose complete recording holds a real walk (not a test module): the
simulated straight walk seen by one calibrated sensor, so that its reports render."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from fastapi.testclient import TestClient

from app.nodes.protocol import encode_skeletons
from app.nodes.store import NodeStore
from engine.sim.straight_walk import synth_walk, walk_skeleton
from engine.skeleton import TrackingState
from tests.app.data.test_data_api import _recording_row, _sink_part

#: S1 stands at the walkway's end, 1 m high, looking back along it (world -X), so the
#: walker comes towards it: camera +Z = world -X, +Y (down) = world -Z, +X = world +Y.
T_WORLD_S1 = np.array([[0, 0, -1, 11.0], [1, 0, 0, 0.0], [0, -1, 0, 1.0], [0, 0, 0, 1]], float)


def walk_part(data_dir: Path, work: Path, rec_id: str = "R1", node: str = "S1") -> Path:
    """Sensor ``node``'s part of a 12-step walk (30 fps, camera frame), copied through a
    transfer sink into ``data_dir`` as the server holds it."""
    w = synth_walk(n_steps=12, rate=30.0)
    P = walk_skeleton(w)
    T_s_w = np.linalg.inv(T_WORLD_S1)
    cam = P @ T_s_w[:3, :3].T + T_s_w[:3, 3]
    store = NodeStore(work / "node")
    wr = store.create_part(rec_id, node_id=node,
                           clock_start={"offset_s": 0.0, "drift": 0.0, "t_ref": 0.0})
    st = np.full((1, 25), TrackingState.TRACKED, np.uint8)
    for k, t in enumerate(w.times):
        t_node = 100.0 + float(t)
        wr.append(t_node, "skeleton", encode_skeletons(k, t_node, cam[k][None], st))
    wr.close()
    return _sink_part(store.root / rec_id, rec_id, node, data_dir)


def calibrate_s1(data_dir: Path) -> None:
    """The rig's active calibration: S1 at :data:`T_WORLD_S1`."""
    from app.server import calibration as cal
    from engine.calibration.pipeline import CalibrationResult

    T = T_WORLD_S1
    cal.save(data_dir, CalibrationResult(
        T_world_sensor={"S1": T}, T_world_sensor_chained={"S1": T}, T_world_marker={1: np.eye(4)},
        marker_sizes={1: 0.4}, sensor_residual_m={"S1": 0.002}, edges=[], observations=[]))


def walk_subject(client: TestClient, data_dir: Path) -> dict[str, int]:
    """Project "S" → subject "A1" → one session → complete recording "R1" (a walk on
    the server, S1 calibrated). Returns the subject's and the session's ids."""
    walk_part(data_dir, data_dir / "node-side")
    calibrate_s1(data_dir)
    _recording_row(client)
    subj = client.get("/api/subjects").json()[0]
    sess = client.get(f"/api/subjects/{subj['id']}").json()["sessions"][0]
    return {"subject_id": subj["id"], "session_id": sess["id"]}
