"""What GET /api/recordings adds to the recording manager's view: each part's
``images_skipped`` from the server copy's meta.json and the nodes ``not_in_recording``."""

from __future__ import annotations

import json
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from app.api.routes.recordings import _view
from app.nodes.protocol import SensorInfo
from app.server.recording import Part, Recording, RecordingManager
from app.server.registry import NodeRegistry
from app.server.storage import StorageLayout


async def _send(text: str) -> None:
    pass


def _hub(tmp_path: Path) -> Any:
    reg = NodeRegistry()
    return SimpleNamespace(registry=reg, recordings=RecordingManager(reg, tmp_path))


def test_images_skipped_from_the_server_copy(tmp_path: Path) -> None:
    hub = _hub(tmp_path)
    layout = StorageLayout(tmp_path)
    rec = Recording("R1", t_start=time.time() - 10, t_stop=time.time() - 5)
    rec.parts = {"S1": Part("S1", state="complete", on_server=True),
                 "S2": Part("S2", state="complete", on_server=True),
                 "S3": Part("S3", state="on_node")}
    for node, meta in (("S1", {"images_skipped": 7}), ("S2", {"clock_start": {}})):
        d = layout.part_dir("R1", node)
        d.mkdir(parents=True)
        (d / "meta.json").write_text(json.dumps(meta))
    parts = {p["node_id"]: p for p in _view(hub, layout, rec)["parts"]}
    # S2's meta predates the count: none skipped; S3 is not on the server: unknown
    assert {n: p["images_skipped"] for n, p in parts.items()} == {"S1": 7, "S2": 0, "S3": None}
    # a rewritten meta.json is read again
    time.sleep(0.01)
    (layout.part_dir("R1", "S1") / "meta.json").write_text(json.dumps({"images_skipped": 9}))
    assert _view(hub, layout, rec)["parts"][0]["images_skipped"] == 9


def test_nodes_not_in_the_recording_say_why(tmp_path: Path) -> None:
    hub = _hub(tmp_path)
    reg: NodeRegistry = hub.registry
    for nid in ("S1", "S2", "S3", "S4"):
        reg.connect(nid, "sim", SensorInfo(), _send, restarted=True)
    reg.disconnect("S4")
    reg.nodes["S4"].disconnected_at = time.time() - 100  # gone long before the start
    t0 = time.time() - 5.0
    rec = Recording("R2", t_start=t0 + 0.3, created=t0)
    rec.parts = {"S1": Part("S1", state="recording")}
    for nid in ("S1", "S2"):
        reg.nodes[nid].connected_at = t0 - 10.0  # online before the start
    reg.nodes["S3"].connected_at = t0 + 1.0  # joined after the start
    out = {n["node_id"]: n["reason"] for n in _view(hub, StorageLayout(tmp_path), rec)[
        "not_in_recording"]}
    assert set(out) == {"S2", "S3"}
    assert "clock was not measured" in out["S2"]
    assert "after the start" in out["S3"]
    # a node that connected only after the stop was never left out of it
    rec.t_stop = t0 + 0.5
    assert [n["node_id"] for n in _view(hub, StorageLayout(tmp_path), rec)[
        "not_in_recording"]] == ["S2"]
