"""Security review 19: the node's ``sensor_lens`` (protocol revision 3) and the live
cloud's ray tables. Each test failed before its fix."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import numpy as np
import pytest

from app.config import Settings
from app.nodes.protocol import (
    CameraLens,
    Hello,
    ProtocolError,
    SensorInfo,
    SensorLens,
    dump,
    parse_node_message,
)
from app.server.hub import Hub
from app.viewer import cloud
from tests.app.test_hub_connections import NODE_TOKEN, FakeSocket

K = [[365.0, 0.0, 255.5], [0.0, 365.0, 211.5], [0.0, 0.0, 1.0]]


def _lens(k1: float) -> str:
    return dump(SensorLens(source="factory calibration",
                           depth=CameraLens(size=(512, 424), K=K, dist=[k1, 0.01, 0.0, 0.0])))


def test_a_second_sensor_lens_on_one_connection_is_refused(tmp_path: Path) -> None:
    """A node flooding lenses (each a new ray table for the live cloud) gets the first
    one kept and every later one refused, as a repeated hello is."""
    settings = Settings(data_dir=tmp_path, viewer_enabled=False, node_token=NODE_TOKEN,
                        admin_password="secret-pw")

    async def scenario() -> None:
        hub = Hub(settings)
        changed: list[str] = []
        hub.registry.listeners.append(lambda s: changed.append(s.id))
        ws = FakeSocket()
        task = asyncio.create_task(hub.handle_node(ws))
        ws.feed(dump(Hello(node_id="S1", token=NODE_TOKEN, protocol=3,
                           sensor=SensorInfo(depth_size=(512, 424), depth_K=K))))
        await ws.answered("welcome")
        n0 = len(changed)
        for i in range(20):
            ws.feed(_lens(0.1 + i / 100))
        s = hub.registry.nodes["S1"]
        for _ in range(2000):
            if s.rejected_messages >= 19:
                break
            await asyncio.sleep(0.005)
        assert s.lens is not None and s.lens.depth is not None
        assert s.lens.depth.dist[0] == pytest.approx(0.1)  # the first is kept
        assert s.rejected_messages == 19 and "twice" in (s.last_rejection or "")
        assert len(changed) - n0 == 1  # the live cloud was told once
        ws.hang_up()
        await asyncio.wait_for(task, 5)

    asyncio.run(scenario())


@pytest.mark.parametrize("source", ["factory\ncalibration", "evil\u202eFDP.exe",
                                    "a\x1b[31mred", "x\u2028y"])
def test_lens_source_with_control_characters_is_refused(source: str) -> None:
    """The source is shown on the Rig page and written to the log: a newline would forge
    log lines, a bidi override reverse what the page shows. (HTML in it is shown as text:
    the page builds the line with text nodes, /api/nodes is JSON.)"""
    good = json.loads(_lens(0.1))
    with pytest.raises(ProtocolError, match="source"):
        parse_node_message(json.dumps({**good, "source": source}))
    assert parse_node_message(json.dumps({**good, "source": "<img src=x onerror=alert(1)>"}))


def test_ray_tables_kept_are_bounded_in_bytes(monkeypatch: pytest.MonkeyPatch) -> None:
    """Frames of many sizes (or many lenses over reconnections) made a table each; the
    cache was bounded by count (65 tables: 8.7 GB at the 4096² images a node may send),
    now by bytes, least recently used dropped first."""
    monkeypatch.setattr(cloud, "MAX_RAYS_CACHE_BYTES", 1 << 20)
    monkeypatch.setattr(cloud, "_rays_cache", type(cloud._rays_cache)())
    Km = np.array(K)
    for w in range(100, 140):
        r = cloud.pixel_rays(Km, w, 100, (0.1, 0.01, 0.0, 0.0))
        assert r.shape == (100, w, 2)
    total = sum(t.nbytes for t in cloud._rays_cache.values())
    assert 0 < total <= 1 << 20, total
    assert next(reversed(cloud._rays_cache))[:2] == (139, 100)  # the newest kept


def test_live_rays_are_the_engines_and_leave_its_cache_alone() -> None:
    """The live cloud's rays are :func:`engine.pointcloud.pixel_ray_table`'s, but held in
    the cloud's byte-bounded cache only: the engine's cache (16 float64 tables, whatever
    their size) no longer grows with each frame size a node sends."""
    from engine.pointcloud import CameraIntrinsics, _ray_table, pixel_ray_table

    dist = (0.1, 0.01, 0.001, -0.002, 0.0)
    before = _ray_table.cache_info().currsize
    r = cloud.pixel_rays(np.array(K), 97, 61, dist)
    assert _ray_table.cache_info().currsize == before
    ref = pixel_ray_table(CameraIntrinsics.from_matrix(np.array(K), 97, 61, dist))
    np.testing.assert_allclose(r, ref, atol=1e-6, equal_nan=True)


def test_hostile_imu_uploads_are_4xx_with_a_message(admin_client: object) -> None:
    """Through the route: an XML bomb past the old 64 kB look, an external entity, a
    UTF-16 DTD, a million-column phone CSV: each a 400 naming the user's file, never a
    500; without a login, 401 before anything is read."""
    import io
    import zipfile

    from fastapi.testclient import TestClient

    c: TestClient = admin_client  # type: ignore[assignment]
    pad = b"<!-- <mvnx " + b"x" * 70_000 + b" -->"
    lol = (b'<!DOCTYPE l [<!ENTITY a "aaaaaaaaaa">' + b"".join(
        b'<!ENTITY a%d "%s">' % (i, (b"&a%d;" % (i - 1) if i > 1 else b"&a;") * 10)
        for i in range(1, 10)) + b"]>")
    xxe = b'<!DOCTYPE m [<!ENTITY x SYSTEM "file:///etc/passwd">]>'
    body = (b"<mvnx><subject frameRate='60'><sensors><sensor label='&x;'/></sensors>"
            b"</subject></mvnx>")
    wide = io.BytesIO()
    with zipfile.ZipFile(wide, "w", zipfile.ZIP_DEFLATED) as z:
        n = 100_000
        z.writestr("Gyroscope.csv", b",".join(b"c%d" % i for i in range(n)) + b"\n"
                   + b",".join(b"1" for _ in range(n)) + b"\n")
        z.writestr("Accelerometer.csv", b"time,x,y,z\n1,0,0,9.8\n2,0,0,9.8\n")
    cases = {"bomb.mvnx": b"<?xml version='1.0'?>" + pad + lol + b"<mvnx>&a9;</mvnx>",
             "xxe.mvnx": b"<?xml version='1.0'?>" + pad + xxe + body,
             "u16.mvnx": ("<?xml version='1.0' encoding='UTF-16'?>" + xxe.decode()
                          + body.decode()).encode("utf-16"),
             "wide.zip": wide.getvalue()}
    for name, data in cases.items():
        r = c.post("/api/imu/sessions",
                   files=[("files", (name, data, "application/octet-stream"))])
        assert r.status_code == 400, (name, r.status_code, r.text[:300])
        detail = str(r.json()["detail"])
        assert name in detail and "root:" not in detail and len(detail) < 1000, detail
    anonymous = TestClient(c.app, raise_server_exceptions=False)  # no login, no cookie
    r = anonymous.post("/api/imu/sessions",
                       files=[("files", ("xxe.mvnx", cases["xxe.mvnx"], "application/xml"))])
    assert r.status_code == 401
