"""Node retention with real server and node processes over loopback websockets.

Three nodes record one recording; the server pulls and verifies every part and tells
each node. S1 keeps verified copies 0 days: its copy goes at once. S2's disk is below
its floor (the floor set to the whole disk): its verified part goes too, but a part the
server never verified (planted before the node started) survives every purge, and its
health says so. S3 keeps verified copies a week; it is stopped, "forgets" the
verification (as if the message had been lost) and restarted with 0 days: its status
lists the part as unconfirmed, the server repeats the verification and the copy goes.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.nodes.protocol import encode_skeletons
from app.nodes.store import NodeStore
from tests.integration.conftest import Rig, wait_for

pytestmark = pytest.mark.slow


def _parts(rig: Rig, rec_id: str) -> dict[str, dict[str, Any]]:
    return {p["node_id"]: p for p in rig.api(f"/api/recordings/{rec_id}")["parts"]}


def _node(rig: Rig, node_id: str, **env: str) -> None:
    rig._spawn(node_id, ["node", "--id", node_id, "--server", f"ws://127.0.0.1:{rig.port}",
                         "--data-dir", str(rig.node_dir(node_id)), "--no-images"],
               env={**rig.env, **env})


def _plant_unverified_part(folder: Path) -> None:
    """A closed part of a recording this server never saw: the only copy anywhere."""
    w = NodeStore(folder).create_part("R20200101-000000-0000", t_start_local=0.0)
    for k in range(30):
        pos = np.full((1, 25, 3), k, np.float32)
        w.append(k / 30.0, "skeleton", encode_skeletons(k, k / 30.0, pos, np.full((1, 25), 2)))
    w.close("on_node")


@pytest.mark.timeout(150)
def test_verified_copies_are_purged_by_policy_and_unverified_ones_never(make_rig: Any
                                                                        ) -> None:
    rig: Rig = make_rig()
    planted = rig.node_dir("S2") / "recordings"
    _plant_unverified_part(planted)
    _node(rig, "S1", GAITRIG_NODE_KEEP_VERIFIED_DAYS="0")
    _node(rig, "S2", GAITRIG_NODE_MIN_FREE_PERCENT="100")
    _node(rig, "S3", GAITRIG_NODE_KEEP_VERIFIED_DAYS="7")
    rig.wait_online(["S1", "S2", "S3"], timeout=60)
    rec_id = rig.api("/api/recordings", {})["id"]
    wait_for(lambda: all(p["n_frames"] > 15 for p in _parts(rig, rec_id).values()), 30,
             "every node recording")
    rig.api(f"/api/recordings/{rec_id}/stop", method="POST")
    wait_for(lambda: all(p["state"] == "complete" for p in _parts(rig, rec_id).values()), 60,
             "every part verified on the server")
    server = rig.tmp / "server" / "recordings" / rec_id

    def copy(n: str) -> Path:
        return rig.node_dir(n) / "recordings" / rec_id

    # S1 (0 days) and S2 (below its floor) delete their verified copies
    wait_for(lambda: not copy("S1").exists() and not copy("S2").exists(), 30,
             "S1's and S2's copies purged")
    assert f"purged recording {rec_id}" in rig.log_text("S1")
    assert "copies are not kept" in rig.log_text("S1")
    assert "floor" in rig.log_text("S2")
    # the unverified part is the only copy: it stays, and the node's health says so
    assert (planted / "R20200101-000000-0000" / "frames.bin").exists()
    s2 = wait_for(lambda: (h := rig.nodes()["S2"])["storage"] and
                  h["storage"]["purged_parts"] == 1 and h, 15, "S2's storage figures")
    st = s2["storage"]
    assert st["unverified_parts"] == 1 and st["verified_parts"] == 0
    assert st["held_bytes"] == st["unverified_bytes"] > 0
    assert any("cannot be deleted" in w for w in s2["warnings"]), s2["warnings"]
    # S3 keeps its verified copy for its days
    assert (copy("S3") / "verified.json").exists() and (copy("S3") / "frames.bin").exists()
    s3 = wait_for(lambda: (h := rig.nodes()["S3"]["storage"]) and h["verified_parts"] == 1
                  and h, 15, "S3's storage figures")
    assert s3["purgeable_bytes"] > 0 and s3["unverified_parts"] == 0
    assert s3["keep_verified_days"] == 7
    for n in ("S1", "S2", "S3"):  # the server's copies are untouched
        assert (server / n / "manifest.json").exists() and (server / n / "frames.bin").exists()

    # S3 loses the note (a verification message lost with a restart) and comes back with
    # 0 days: the server repeats the verification it holds, and the copy goes
    p = rig.procs["S3"]
    p.terminate()
    p.wait(timeout=15)
    (copy("S3") / "verified.json").unlink()
    _node(rig, "S3", GAITRIG_NODE_KEEP_VERIFIED_DAYS="0")
    wait_for(lambda: not copy("S3").exists(), 40, "S3's copy purged after its restart")
    assert json.loads((server / "S3" / "manifest.json").read_text())["node_id"] == "S3"
    assert "told nodes of their verified copies: S3/" + rec_id in rig.log_text("server")
