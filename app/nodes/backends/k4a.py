"""Azure Kinect / Orbbec Femto backend through ``pyk4a`` (optional extra ``gaitrig[k4a]``).

Not testable on machines without the device; it implements the same contract as the
``sim`` backend. ``pyk4a`` delivers depth, colour (registered to depth) and IR; it does
not wrap the body-tracking SDK (k4abt), so this backend streams and records images with
**empty skeleton frames**. Adding k4abt skeletons means filling ``Frame.positions`` /
``states`` (Azure joint set) in :meth:`K4ABackend.frames`; nothing else changes.

Frame times: the device timestamp (µs since the device started) is mapped once onto the
host clock at the first frame, so ``t_local`` runs on the node computer's clock, which
chrony/PTP and the server's estimator take care of.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.nodes.backends.base import Backend, Frame
from app.nodes.protocol import SensorInfo
from engine.errors import InputError
from engine.skeleton import AZURE_KINECT_JOINTS


def _require_pyk4a() -> Any:
    try:
        import pyk4a
    except ImportError as exc:
        raise InputError(
            "the k4a backend needs pyk4a and the Azure Kinect SDK: install the SDK "
            "(libk4a) and run `pip install gaitrig[k4a]`") from exc
    return pyk4a


class K4ABackend(Backend):
    """An Azure Kinect (or Orbbec Femto with the K4A wrapper) through pyk4a.

    Args:
        device: device index.
    """

    name = "k4a"

    def __init__(self, device: int = 0) -> None:
        self._pyk4a = _require_pyk4a()
        self.device = device
        self._k4a: Any = None
        self._closed = threading.Event()
        self._t0: tuple[float, float] | None = None

    def open(self) -> SensorInfo:
        pyk4a = self._pyk4a
        cfg = pyk4a.Config(color_resolution=pyk4a.ColorResolution.RES_720P,
                           depth_mode=pyk4a.DepthMode.NFOV_UNBINNED,
                           camera_fps=pyk4a.FPS.FPS_30, synchronized_images_only=True)
        self._k4a = pyk4a.PyK4A(cfg, device_id=self.device)
        self._k4a.start()
        cal = self._k4a.calibration
        K_d = np.asarray(cal.get_camera_matrix(pyk4a.CalibrationType.DEPTH)).tolist()
        # the colour image we send is ``transformed_color``: resampled into the DEPTH
        # camera's geometry, so it has the depth camera's size and intrinsics (and the
        # identity as colour → depth transform), not the 1280×720 colour camera's
        return SensorInfo(model="Azure Kinect (pyk4a)", depth_size=(640, 576),
                          color_size=(640, 576), depth_K=K_d, color_K=K_d,
                          fov_deg=(75.0, 65.0), rate_hz=30.0, joint_set="azure_kinect")

    def now(self) -> float:
        return time.time()

    def close(self) -> None:
        self._closed.set()

    def frames(self) -> Iterator[Frame]:
        J = len(AZURE_KINECT_JOINTS)
        try:
            while not self._closed.is_set():
                cap = self._k4a.get_capture()
                if cap.depth is None:
                    continue
                dev_t = cap.depth_timestamp_usec * 1e-6
                if self._t0 is None:
                    self._t0 = (time.time(), dev_t)
                t_local = self._t0[0] + (dev_t - self._t0[1])
                pos = np.zeros((0, J, 3), np.float32)
                st = np.zeros((0, J), np.uint8)
                depth, color = cap.depth, cap.transformed_color
                yield Frame(t_local, pos, st, [], _images(depth, color))
        finally:
            self._k4a.stop()


def _images(depth: NDArray[np.uint16], color: NDArray[np.uint8] | None) -> Any:
    def images(streams: Sequence[str]) -> dict[str, NDArray[np.uint8] | NDArray[np.uint16]]:
        out: dict[str, NDArray[np.uint8] | NDArray[np.uint16]] = {}
        if "depth" in streams:
            out["depth"] = depth
        if "color" in streams and color is not None:
            out["color"] = np.ascontiguousarray(color[..., 2::-1])  # BGRA → RGB
        return out

    return images
