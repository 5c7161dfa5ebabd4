"""Lens distortion on the wire: a node backend that knows its lens has it
(``Backend.color_dist``/``depth_dist``), the agent sends it with every ``calib`` frame, the server
builds the camera model with it; an older node that sends none gets a pinhole (zero
distortion). The Azure Kinect's factory coefficients in OpenCV's order."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from app.nodes.agent import NodeAgent
from app.nodes.backends.base import Backend, Frame
from app.nodes.backends.k4a import distortion_from_k4a_params, opencv_distortion
from app.nodes.protocol import (
    CalibrationCapture,
    ProtocolError,
    SensorInfo,
    calib_distortion,
    decode_binary,
    decode_calib_frame,
    encode_calib_frame,
)
from app.server.calibration import CaptureJob, CaptureManager
from engine.errors import InputError
from engine.pointcloud import CameraIntrinsics

KC = [[500.0, 0.0, 32.0], [0.0, 500.0, 18.0], [0.0, 0.0, 1.0]]
KD = [[360.0, 0.0, 16.0], [0.0, 360.0, 12.0], [0.0, 0.0, 1.0]]
CDIST = [0.12, -0.3, 0.001, -0.002, 0.1]
DDIST = [0.5, -0.1, 0.0002, 0.0001, 0.03, 0.8, 0.05, 0.01]


class _Lens(Backend):
    """A node backend with its own calibration frames and, optionally, a lens report."""

    name = "lens"

    def __init__(self, lens: bool) -> None:
        self.lens = lens

    def open(self) -> SensorInfo:
        if self.lens:
            self.color_dist, self.depth_dist = CDIST, DDIST
        return SensorInfo(color_K=KC, depth_K=KD)

    def frames(self) -> Iterator[Frame]:
        return iter(())

    def now(self) -> float:
        return 0.0

    def calibration_frames(self, n: int) -> Iterator[tuple[Any, ...]]:
        for k in range(n):
            yield (float(k), np.full((36, 64, 3), 100 + k, np.uint8),
                   np.full((24, 32), 1500, np.uint16), KC, KD, np.eye(4), 1000.0)


def _capture(tmp_path: Path, lens: bool) -> list[tuple[dict[str, Any], bytes]]:
    """The ``calib`` messages a node sends for a 2-frame capture."""
    backend = _Lens(lens)
    agent = NodeAgent("S1", backend, "ws://127.0.0.1:9/ws/node", "token-1234", tmp_path)
    agent.info = backend.open()
    sent: list[bytes] = []
    agent._loop = SimpleNamespace(call_soon_threadsafe=lambda f, *a: f(*a))  # type: ignore[assignment]
    agent._send_control = sent.append  # type: ignore[method-assign]
    agent._calib_capture(CalibrationCapture(req_id=4, frames=2))
    return [decode_binary(b) for b in sent]


def _server_frames(tmp_path: Path, msgs: list[tuple[dict[str, Any], bytes]]) -> Any:
    hub = SimpleNamespace(binary_listeners={})
    mgr = CaptureManager(hub, tmp_path)
    job = CaptureJob(1, "calibrate", ["S1"], len(msgs), {1: 0.2}, raw={"S1": msgs})
    return mgr._sensor_frames(job, "S1")


def test_node_lens_reaches_the_server_camera_model(tmp_path: Path) -> None:
    msgs = _capture(tmp_path, lens=True)
    assert len(msgs) == 2 and all("error" not in h for h, _ in msgs)
    assert msgs[0][0]["color_dist"] == CDIST and msgs[0][0]["depth_dist"] == DDIST
    sf = _server_frames(tmp_path, msgs)
    assert isinstance(sf.color_intrinsics, CameraIntrinsics)
    assert isinstance(sf.depth_intrinsics, CameraIntrinsics)
    assert sf.color_intrinsics.dist == pytest.approx(CDIST)
    assert sf.depth_intrinsics.dist == pytest.approx(DDIST)
    assert (sf.color_intrinsics.width, sf.color_intrinsics.height) == (64, 36)
    assert (sf.depth_intrinsics.width, sf.depth_intrinsics.height) == (32, 24)
    assert np.allclose(sf.color_intrinsics.K, KC) and np.allclose(sf.depth_intrinsics.K, KD)


def test_older_node_without_distortion_gets_a_pinhole(tmp_path: Path) -> None:
    """A node of before this change sends neither field (nor does one with an ideal
    lens): the header has no ``*_dist``, the server's model has none (zeros)."""
    msgs = _capture(tmp_path, lens=False)
    assert all("color_dist" not in h and "depth_dist" not in h for h, _ in msgs)
    sf = _server_frames(tmp_path, msgs)
    assert sf.color_intrinsics.dist == () and sf.depth_intrinsics.dist == ()
    assert not np.any(sf.color_intrinsics.dist_array)
    # the lens is not in the hello: a server older than the node refuses unknown sensor
    # fields (extra="forbid"), while it ignores unknown calib header keys
    assert "color_dist" not in SensorInfo.model_fields


def test_calib_header_distortion_is_checked() -> None:
    data = encode_calib_frame(1, 0, 1, 0.0, np.zeros((8, 8), np.uint8),
                              np.ones((8, 8), np.uint16), KC, KD, np.eye(4),
                              color_dist=CDIST, depth_dist=[0.0] * 5)
    h, p = decode_binary(data)
    assert "depth_dist" not in h  # all zeros: nothing to send
    assert calib_distortion(h, "color_dist") == pytest.approx(tuple(CDIST))
    assert calib_distortion(h, "depth_dist") == ()
    decode_calib_frame(h, p)
    for bad in ([0.1, 0.2, 0.3], [0.1, float("nan"), 0, 0], "k1", [[0.1, 0.2], "x"]):
        with pytest.raises(ProtocolError, match="color_dist"):
            decode_calib_frame(dict(h, color_dist=bad), p)


def test_k4a_factory_lens_in_opencv_order() -> None:
    """The SDK's ``k4a_calibration_intrinsic_parameters_t.param``: cx, cy, fx, fy, k1..k6,
    codx, cody, p2, p1, metric_radius — p2 before p1; OpenCV wants k1, k2, p1, p2, k3..k6
    (what pyk4a's ``get_distortion_coefficients`` returns)."""
    # a depth camera's factory parameters (public calibration dump; p1 = 8.1e-5,
    # p2 = -5.1e-5)
    params = [0.5123, 0.4945, 0.4921, 0.4922, 3.1306, 2.3249, 0.1304, 3.4587, 3.3501,
              0.6629, 0.0, 0.0, -5.11557e-05, 8.13217e-05, 1.74]
    d = distortion_from_k4a_params(params)
    assert d == pytest.approx([3.1306, 2.3249, 8.13217e-05, -5.11557e-05, 0.1304, 3.4587,
                               3.3501, 0.6629])
    with pytest.raises(InputError, match="14 parameters"):
        distortion_from_k4a_params(params[:10])
    assert opencv_distortion(np.array(d, np.float32)) == pytest.approx(d, rel=1e-6)
    assert opencv_distortion(np.zeros(8)) is None  # an ideal lens: nothing reported
    assert opencv_distortion([0.1, 0.2, 0.3]) is None  # not an OpenCV vector
    assert opencv_distortion([np.nan] * 8) is None
