"""The calibration capture on the wire: ``calib_capture`` requests, binary ``calib``
frames (lossless images + camera model) and the agent's generic capture from live frames
for backends without their own ``calibration_frames``."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from app.nodes.agent import NodeAgent
from app.nodes.backends.base import Backend, Frame
from app.nodes.protocol import (
    CalibrationCapture,
    ProtocolError,
    SensorInfo,
    calib_error,
    decode_binary,
    decode_calib_frame,
    encode_calib_frame,
    parse_server_message,
)
from engine.errors import InputError


def test_calib_frame_roundtrip_is_lossless() -> None:
    rng = np.random.default_rng(0)
    color = rng.integers(0, 256, (54, 96, 3), dtype=np.uint8)
    depth = rng.integers(0, 8000, (42, 51), dtype=np.uint16)
    Kc, Kd = np.diag([80.0, 80.0, 1.0]), np.diag([40.0, 41.0, 1.0])
    T = np.eye(4)
    T[0, 3] = -0.052
    header, payload = decode_binary(encode_calib_frame(7, 2, 5, 12.5, color, depth, Kc, Kd, T))
    assert header["kind"] == "calib" and header["req_id"] == 7 and header["index"] == 2
    c, d = decode_calib_frame(header, payload)
    import cv2

    assert np.array_equal(c, cv2.cvtColor(color, cv2.COLOR_RGB2GRAY))  # grey, lossless
    assert np.array_equal(d, depth) and d.dtype == np.uint16
    assert np.allclose(header["color_K"], Kc) and np.allclose(header["T_depth_color"], T)
    bad = dict(header, depth_K=[[1.0]])
    with pytest.raises(ProtocolError, match="depth_K"):
        decode_calib_frame(bad, payload)
    with pytest.raises(ProtocolError, match="cannot hold"):
        decode_calib_frame(dict(header, color_bytes=len(payload) + 5), payload)
    err, _ = decode_binary(calib_error(7, "S3: no depth"))
    assert err["kind"] == "calib" and err["error"] == "S3: no depth"


def test_calib_capture_message_bounds() -> None:
    msg = parse_server_message('{"v": 1, "type": "calib_capture", "req_id": 3, "frames": 30}')
    assert isinstance(msg, CalibrationCapture) and msg.frames == 30
    for n in (0, 121):
        with pytest.raises(ProtocolError, match="frames"):
            parse_server_message(f'{{"v": 1, "type": "calib_capture", "req_id": 3, '
                                 f'"frames": {n}}}')


class _Fake(Backend):
    name = "fake"

    def __init__(self, with_images: bool) -> None:
        self.with_images = with_images

    def open(self) -> SensorInfo:
        return SensorInfo(color_K=np.diag([500.0, 500.0, 1.0]).tolist(),
                          depth_K=np.diag([360.0, 360.0, 1.0]).tolist())

    def frames(self) -> Iterator[Frame]:  # not used: frames are pushed to the ring
        return iter(())

    def now(self) -> float:
        return time.monotonic()


def _feed(agent: NodeAgent, with_images: bool, stop: threading.Event) -> None:
    k = 0
    while not stop.is_set():
        k += 1

        def images(streams: object, k: int = k) -> dict[str, np.ndarray]:
            if not with_images:
                return {}
            return {"color": np.full((36, 64, 3), k, np.uint8),
                    "depth": np.full((24, 32), 1000 + k, np.uint16)}

        agent.ring.push(time.monotonic(), Frame(time.monotonic(), np.zeros((0, 25, 3), np.float32),
                                                np.zeros((0, 25), np.uint8), [], images))
        time.sleep(0.01)


@pytest.mark.parametrize("with_images", [True, False])
def test_generic_capture_from_live_frames(tmp_path: Path, with_images: bool) -> None:
    backend = _Fake(with_images)
    agent = NodeAgent("S1", backend, "ws://127.0.0.1:9/ws/node", "token-1234", tmp_path)
    agent.info = backend.open()
    stop = threading.Event()
    th = threading.Thread(target=_feed, args=(agent, with_images, stop), daemon=True)
    th.start()
    try:
        if not with_images:
            with pytest.raises(InputError, match="no color and depth image stream"):
                list(agent._live_calib_frames(2))
            return
        got = list(agent._live_calib_frames(3))
    finally:
        stop.set()
        th.join()
    assert len(got) == 3
    ts = [g[0] for g in got]
    assert ts == sorted(ts) and len(set(ts)) == 3  # three distinct, newer frames
    _t, c, d, cK, dK, T, scale = got[0]
    assert c.shape == (36, 64, 3) and d.dtype == np.uint16
    assert np.allclose(cK, np.diag([500.0, 500.0, 1.0])) and np.allclose(T, np.eye(4))
    assert np.allclose(dK, np.diag([360.0, 360.0, 1.0]))
    assert scale == 1000.0
