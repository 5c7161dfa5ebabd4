"""Azure Kinect / Orbbec Femto backend through ``pyk4a`` (optional extra ``.[k4a]``).

Not testable on machines without the device; it implements the same contract as the
``sim`` backend. ``pyk4a`` delivers depth, colour (registered to depth) and IR; skeletons
come from the Azure Kinect Body Tracking SDK (k4abt 1.1) through the small ctypes binding
:mod:`app.nodes.backends._k4abt`, because pyk4a does not wrap it. Without the SDK the
node still streams and records images, with **empty skeleton frames**, and says so once
(log and a warning on the rig page, :attr:`K4ABackend.warnings`) with how to install it.

Skeletons: every capture is enqueued and its result popped before the next one
(synchronous: at 30 fps this needs the GPU mode; the CPU fallback is slower and the
device then drops captures, which lowers the frame rate but never mistimes a frame).
Joint positions are the SDK's, in the depth camera frame — x right, y down, z forward,
the OpenCV convention the ``sim`` backend and calibration use for the sensor frame —
converted from mm to m, in the ``K4ABT_JOINT_*`` order, which equals
:data:`engine.skeleton.AZURE_KINECT_JOINTS`. Tracking states from the joint confidence:
HIGH/MEDIUM → TRACKED, LOW (occluded, predicted) → INFERRED, NONE (out of range) →
NOT_TRACKED with NaN positions, as the simulator reports untracked joints.

Body index images (live view, recordings with ``body_index``) come from the tracker's
body index map, copied out with libk4a's image functions: the streamed body's pixels are
0, all others 255 (as the simulator marks bodies it does not report); none without the
SDK.

Which body: one per frame, the gait subject. The body followed so far is kept while the
tracker still reports its id (a person stepping into the view mid-walk does not take the
stream over); when it is lost, or at the start, the nearest body (smallest pelvis
distance) is chosen — in a gait lab the walking subject, not the clinician at the side.

Frame times (:class:`DeviceClock`): the device timestamp (µs, mid-exposure, from the
sensor's own clock) is mapped onto the host clock by the smallest arrival latency seen in
the last 10 s, so ``t_local`` runs on the node computer's clock (which chrony/PTP and the
server's estimator take care of) while keeping the device's exact frame spacing. The
arrival is the SDK's host timestamp of the depth image (``depth_system_timestamp_nsec``,
``CLOCK_MONOTONIC``/``QueryPerformanceCounter``, the clock of ``time.perf_counter_ns``),
read before body tracking, so a slow tracker (its first frame takes seconds) does not
delay the frame times. The body frame's device timestamp (its capture's depth
timestamp) goes through the same mapping. Device timestamps that do not run like a clock
(0 or repeated — an Orbbec Femto on Windows without Orbbec's metadata driver — or at a
wrong rate, e.g. a wrapper counting ms) are replaced by the arrival times, with a warning.

pyk4a is opened with ``thread_safe=False``: with pyk4a's default (True) every blocking call
— ``get_capture`` waits up to a frame period — holds the GIL, which would stall the
node's websocket loop (clock pings) most of the time; all pyk4a calls are made from the
capture thread, so pyk4a's own locking is not needed.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.nodes.backends import _k4abt
from app.nodes.backends.base import Backend, Frame
from app.nodes.protocol import SensorInfo
from engine.errors import InputError
from engine.skeleton import AZURE_KINECT_JOINTS, TrackingState

log = logging.getLogger("gaitrig.node")

#: k4abt_joint_confidence_level_t → TrackingState (index = confidence level)
CONFIDENCE_TO_STATE = np.array([TrackingState.NOT_TRACKED, TrackingState.INFERRED,
                                TrackingState.TRACKED, TrackingState.TRACKED], np.uint8)

#: how long one capture may wait for the tracker's queue and result (ms)
TRACK_TIMEOUT_MS = 2000

#: host clocks read for the arrival of a capture (module attributes: tests replace them)
_wall = time.time
_perf_ns = time.perf_counter_ns
#: an SDK host timestamp older than this (s) is not the capture's arrival (a wrapper that
#: sets it wrongly): the wall clock at ``get_capture``'s return is used instead
_MAX_ARRIVAL_AGE_S = 5.0


def arrival_time(cap: Any) -> float:
    """Host time (``time.time`` scale, s) at which the capture's depth image arrived.

    pyk4a 1.5's ``depth_system_timestamp_nsec`` is libk4a's host timestamp ("captured at
    the moment host PC finishes receiving the image": ``CLOCK_MONOTONIC`` on Linux,
    ``QueryPerformanceCounter`` on Windows, i.e. ``time.perf_counter_ns``); without it (0,
    missing, implausible) the wall clock now. Call it right after ``get_capture``.
    """
    wall, perf = _wall(), _perf_ns()
    sys_ns = int(getattr(cap, "depth_system_timestamp_nsec", 0) or 0)
    age = (perf - sys_ns) * 1e-9
    if sys_ns > 0 and 0.0 <= age < _MAX_ARRIVAL_AGE_S:
        return wall - age
    return wall


class DeviceClock:
    """Maps a sensor's device timestamps (µs) onto the host clock (s).

    ``t_local = device time + offset``, the offset being the smallest ``arrival − device
    time`` of the last :attr:`window_s` of host time: the frame that came through fastest
    bounds the latency best, a late one (tracker warm-up, a busy USB bus) moves nothing,
    and the window follows the drift of the device's crystal against the host clock.

    The returned times never go backwards (the server drops a frame that overlaps the
    previous one): the offset applied follows that minimum up at once but down by at most
    :attr:`max_slew` of the device time that passed, so after a first capture that arrived
    late (a busy USB bus at start) the times close in on the better offset over a few
    frames instead of jumping back by the first frame's extra latency.

    Device times that are not a clock — not increasing (0, repeated: Orbbec's wrapper on
    Windows without its metadata driver gives none) or, over at least
    :attr:`rate_span_s`, drifting from the host by more than :attr:`rate_tolerance` (a
    wrapper counting ms) — are given up for good: from then on ``t_local`` is the arrival
    time and :attr:`warning` says why.

    Args:
        window_s: host-time window of the latency minimum.
        rate_tolerance: largest plausible |device rate / host rate − 1|.
        rate_span_s: host time after which the rate is checked.
        max_slew: largest decrease of the applied offset per second of device time (below
            1, so times keep advancing at at least ``1 - max_slew`` of the device's pace).
    """

    def __init__(self, window_s: float = 10.0, rate_tolerance: float = 0.02,
                 rate_span_s: float = 10.0, max_slew: float = 0.5) -> None:
        if not 0.0 < max_slew < 1.0:
            raise ValueError(f"max_slew must be in (0, 1), got {max_slew}")
        self.window_s = window_s
        self.rate_tolerance = rate_tolerance
        self.rate_span_s = rate_span_s
        self.max_slew = max_slew
        self._offset: float | None = None  # offset applied (s)
        self._last_out: float | None = None  # the last time returned
        self._recent: deque[tuple[float, float]] = deque()  # (arrival s, offset s)
        self._start: tuple[float, float] | None = None  # (first arrival, its offset)
        self._last_dev: float | None = None
        self._first_best = 0.0
        self.warning: str | None = None

    @property
    def fallback(self) -> bool:
        """True once device timestamps were given up for arrival times."""
        return self.warning is not None

    def t_local(self, device_usec: int, arrival_s: float,
                stamp_usec: int | None = None) -> float:
        """Record one capture and return the host time of ``stamp_usec``.

        Args:
            device_usec: the capture's depth image device timestamp (µs).
            arrival_s: its host arrival time (:func:`arrival_time`).
            stamp_usec: the device time to convert (default ``device_usec``; the body
                frame's timestamp).
        """
        if self.fallback:
            return self._forward(arrival_s)
        dev = device_usec * 1e-6
        if self._last_dev is not None and dev <= self._last_dev:
            return self._give_up(arrival_s, f"device timestamps do not advance ({device_usec}"
                                 f" µs after {round(self._last_dev * 1e6)} µs)")
        step = 0.0 if self._last_dev is None else dev - self._last_dev
        self._last_dev = dev
        offset = arrival_s - dev
        if self._start is None:
            self._start = (arrival_s, offset)
        recent = self._recent
        recent.append((arrival_s, offset))
        while recent[0][0] < arrival_s - self.window_s:
            recent.popleft()
        best = min(o for _, o in recent)
        elapsed = arrival_s - self._start[0]
        if elapsed <= self.window_s:
            self._first_best = best  # the first window's minimum
        elif elapsed >= self.rate_span_s:
            # a device clock off by a factor (1 + r) moves the best offset by about r·t
            drift = best - self._first_best
            if abs(drift) > self.rate_tolerance * elapsed:
                return self._give_up(arrival_s, "device timestamps do not keep pace with "
                                     f"the host clock ({drift:+.3g} s in {elapsed:.3g} s)")
        if self._offset is None or best >= self._offset:
            self._offset = best
        else:  # a faster frame: close in on it without going back in time
            self._offset = max(best, self._offset - self.max_slew * step)
        return self._forward((dev if stamp_usec is None else stamp_usec * 1e-6) + self._offset)

    def _forward(self, t: float) -> float:
        """``t``, or a microsecond after the last time returned if it is not later."""
        if self._last_out is not None and t <= self._last_out:
            t = self._last_out + 1e-6
        self._last_out = t
        return t

    def _give_up(self, arrival_s: float, why: str) -> float:
        self.warning = (f"Frame times come from the node computer's clock at arrival, not "
                        f"from the sensor: {why}. They are less exact (USB and driver "
                        "latency); on Windows with an Orbbec Femto install Orbbec's metadata "
                        "driver (obsensor_metadata_win10.ps1), then restart the node.")
        return self._forward(arrival_s)


#: The Azure Kinect SDK's ``k4a_calibration_intrinsic_parameters_t.param`` order: cx, cy,
#: fx, fy, k1..k6, codx, cody, p2, p1, metric_radius (p2 BEFORE p1; codx/cody are 0 for
#: the Brown–Conrady model the devices use)
K4A_PARAM_ORDER = ("cx", "cy", "fx", "fy", "k1", "k2", "k3", "k4", "k5", "k6", "codx", "cody",
                   "p2", "p1", "metric_radius")


def distortion_from_k4a_params(params: Sequence[float]) -> list[float]:
    """OpenCV's rational distortion ``[k1, k2, p1, p2, k3, k4, k5, k6]`` from the SDK's
    raw intrinsic parameters (:data:`K4A_PARAM_ORDER`; what ``pyk4a``'s
    ``Calibration.get_distortion_coefficients`` computes, with p1/p2 swapped back)."""
    p = dict(zip(K4A_PARAM_ORDER, (float(x) for x in params), strict=False))
    if len(params) < 14:
        raise InputError(f"Azure Kinect intrinsics need 14 parameters, got {len(params)}")
    return [p["k1"], p["k2"], p["p1"], p["p2"], p["k3"], p["k4"], p["k5"], p["k6"]]


def opencv_distortion(coeffs: Any) -> list[float] | None:
    """A device's OpenCV distortion coefficients as a list for the sensor report, or None
    when they are all zero (an ideal lens) or not 4, 5, 8, 12 or 14 finite numbers (then
    calibration uses the pinhole, as before nodes reported distortion)."""
    d = np.asarray(coeffs, dtype=float).ravel()
    if d.size not in (4, 5, 8, 12, 14) or not np.all(np.isfinite(d)) or not np.any(d):
        return None
    return [float(x) for x in d]


def _require_pyk4a() -> Any:
    try:
        import pyk4a
    except ImportError as exc:
        raise InputError(
            "the k4a backend needs pyk4a and the Azure Kinect Sensor SDK: install the SDK "
            "(libk4a 1.4, or Orbbec's K4A wrapper for a Femto), then run "
            "`.venv/bin/pip install -e '.[k4a]'` in the gaitrig folder (steps: "
            "docs/backbone.md, 'Hardware backend')") from exc
    return pyk4a


def choose_body(body_ids: Sequence[int], positions_mm: NDArray[np.float32],
                previous: int | None) -> int | None:
    """Index of the body to stream: the one followed so far if still reported, otherwise
    the nearest (smallest pelvis distance); None without bodies."""
    if not body_ids:
        return None
    if previous is not None and previous in body_ids:
        return list(body_ids).index(previous)
    pelvis = positions_mm[:, AZURE_KINECT_JOINTS.index("PELVIS")]
    return int(np.argmin(np.linalg.norm(pelvis, axis=1)))


def skeleton_arrays(body: _k4abt.BodyFrame, previous: int | None
                    ) -> tuple[NDArray[np.float32], NDArray[np.uint8], list[int]]:
    """A body frame → the node frame's ``(positions (B,32,3) m, states (B,32), ids)``.

    ``B`` is 1 (the chosen body, :func:`choose_body`) or 0.
    """
    J = len(AZURE_KINECT_JOINTS)
    k = choose_body(body.body_ids, body.positions_mm, previous)
    if k is None:
        return np.zeros((0, J, 3), np.float32), np.zeros((0, J), np.uint8), []
    conf = np.clip(body.confidence[k], 0, len(CONFIDENCE_TO_STATE) - 1)
    states = CONFIDENCE_TO_STATE[conf]
    pos = body.positions_mm[k].astype(np.float32) * np.float32(1e-3)  # mm → m
    pos[states == TrackingState.NOT_TRACKED] = np.nan
    return pos[None], states[None], [body.body_ids[k]]


def body_index_image(body: _k4abt.BodyFrame, streamed: list[int]
                     ) -> NDArray[np.uint8] | None:
    """The body index map of the streamed body: its pixels 0 (it is body 0 of the frame),
    every other pixel 255, as the simulator marks bodies it does not report."""
    if body.body_index is None:
        return None
    out = np.full(body.body_index.shape, 255, np.uint8)
    if streamed:
        out[body.body_index == body.body_ids.index(streamed[0])] = 0
    return out


class K4ABackend(Backend):
    """An Azure Kinect (or Orbbec Femto with the K4A wrapper) through pyk4a.

    Args:
        device: device index.
        body_tracking: track skeletons with k4abt (False: images only, no warning).
        processing_mode: k4abt mode, a key of
            :data:`app.nodes.backends._k4abt.PROCESSING_MODES`: ``gpu`` (the SDK's choice:
            CUDA on Linux, DirectML on Windows; falls back to ``cpu`` with a warning),
            ``cuda``, ``directml`` (Windows), ``tensorrt`` (experimental in the SDK) or
            ``cpu``; an explicit GPU mode that cannot start is not replaced by ``cpu``.
        sensor_orientation: how the sensor is mounted, a key of
            :data:`app.nodes.backends._k4abt.SENSOR_ORIENTATIONS` (``default``,
            ``clockwise90``, ``counterclockwise90``, ``flip180``): tells the tracker's
            network which way up people appear. Joint positions stay in the depth camera
            frame; the calibration places the sensor whichever way it is mounted.
        gpu_device_id: the GPU the tracker runs on in a GPU mode.
        k4abt_path: the libk4abt file (None: the system's).
        k4a_path: the libk4a file whose image functions copy the body index map out
            (None: the system's, already loaded by pyk4a).

    Raises:
        InputError: an unknown processing mode or orientation (checked first, so a
            mistyped option is named even on a machine without pyk4a), or no pyk4a.
    """

    name = "k4a"
    lens_source = "factory calibration"  # the device's, read by pyk4a (open)

    def __init__(self, device: int = 0, body_tracking: bool = True,
                 processing_mode: str = "gpu", k4abt_path: str | Path | None = None,
                 k4a_path: str | Path | None = None, sensor_orientation: str = "default",
                 gpu_device_id: int = 0) -> None:
        self.processing_mode = _k4abt.check_processing_mode(processing_mode)
        self.sensor_orientation = sensor_orientation
        _k4abt.sensor_orientation_value(sensor_orientation)  # refuse a typo before opening
        self.gpu_device_id = int(gpu_device_id)
        self._pyk4a = _require_pyk4a()
        self.device = device
        self.body_tracking = body_tracking
        self.k4abt_path = k4abt_path
        self.k4a_path = k4a_path
        self._k4a: Any = None
        self._tracker: _k4abt.Tracker | None = None
        self._body_id: int | None = None
        self._closed = threading.Event()
        self._clock = DeviceClock()
        #: problems to show on the rig page (e.g. no body tracking SDK), said once
        self.warnings: list[str] = []

    def open(self) -> SensorInfo:
        pyk4a = self._pyk4a
        cfg = pyk4a.Config(color_resolution=pyk4a.ColorResolution.RES_720P,
                           depth_mode=pyk4a.DepthMode.NFOV_UNBINNED,
                           camera_fps=pyk4a.FPS.FPS_30, synchronized_images_only=True)
        # thread_safe=False: pyk4a then releases the GIL while it blocks (module docstring)
        self._k4a = pyk4a.PyK4A(cfg, device_id=self.device, thread_safe=False)
        self._k4a.start()
        cal = self._k4a.calibration
        if self.body_tracking:
            self._open_tracker(cal)
        K_d = np.asarray(cal.get_camera_matrix(pyk4a.CalibrationType.DEPTH)).tolist()
        # the colour image we send is ``transformed_color``: resampled into the DEPTH
        # camera's geometry, so it has the depth camera's size and intrinsics (and the
        # identity as colour → depth transform), not the 1280×720 colour camera's
        # the depth camera's factory Brown–Conrady lens (it is wide: pixels near the border
        # are tens of pixels off the pinhole). pyk4a gives OpenCV's order k1, k2, p1, p2,
        # k3..k6 (the SDK's k4a_calibration_intrinsic_parameters_t stores k1..k6, codx,
        # cody, p2, p1: see :func:`opencv_distortion`); the colour image in depth geometry
        # has the same lens
        get_dist = getattr(cal, "get_distortion_coefficients", None)  # pyk4a ≥ 1.2
        dist_d = (opencv_distortion(get_dist(pyk4a.CalibrationType.DEPTH))
                  if callable(get_dist) else None)
        self.depth_dist = self.color_dist = dist_d
        model = "Azure Kinect (pyk4a" + (", k4abt)" if self._tracker else ", no skeletons)")
        return SensorInfo(model=model, depth_size=(640, 576),
                          color_size=(640, 576), depth_K=K_d, color_K=K_d,
                          fov_deg=(75.0, 65.0), rate_hz=30.0, joint_set="azure_kinect",
                          warnings=list(self.warnings))

    def _open_tracker(self, calibration: Any) -> None:
        """Create the body tracker; without the SDK, warn once and go on without."""
        try:
            lib = _k4abt.load_library(self.k4abt_path)
            self._tracker = _k4abt.Tracker(lib, _k4abt.calibration_pointer(calibration),
                                           self.processing_mode,
                                           sensor_orientation=self.sensor_orientation,
                                           gpu_device_id=self.gpu_device_id,
                                           image_lib=_k4abt.load_image_library(self.k4a_path))
        except _k4abt.K4ABTUnavailable as exc:
            msg = str(exc)
            msg = (msg[:1].upper() + msg[1:])[:1500]
            log.warning("%s", msg)
            self.warnings.append(msg)
            return
        if self._tracker.mode != self.processing_mode:
            msg = (f"Body tracking runs in {self._tracker.mode.upper()} mode (no GPU tracker "
                   f"could be created in {self.processing_mode.upper()} mode): skeletons "
                   "may come at a lower frame rate.")
            log.warning("%s", msg)
            self.warnings.append(msg)

    def now(self) -> float:
        return time.time()

    def close(self) -> None:
        self._closed.set()

    def _t_local(self, depth_usec: int, arrival_s: float, stamp_usec: int | None) -> float:
        t = self._clock.t_local(depth_usec, arrival_s, stamp_usec)
        if self._clock.warning is not None and self._clock.warning not in self.warnings:
            self.warnings.append(self._clock.warning)
            self.warn(self._clock.warning)  # the log, and the server's Rig page
        return t

    def _skeleton(self, cap: Any) -> tuple[NDArray[np.float32], NDArray[np.uint8],
                                           list[int], int | None, NDArray[np.uint8] | None]:
        """The capture's skeleton arrays, the body frame's device timestamp (None without
        a tracker or when tracking this capture failed) and body index image (or None)."""
        J = len(AZURE_KINECT_JOINTS)
        ids: list[int] = []
        empty = (np.zeros((0, J, 3), np.float32), np.zeros((0, J), np.uint8), ids, None, None)
        if self._tracker is None:
            return empty
        try:
            handle = _k4abt.capture_handle(cap)
        except _k4abt.K4ABTUnavailable as exc:  # a pyk4a without capture capsules
            self.warnings.append(f"Body tracking stopped: {exc}")
            self.warn(self.warnings[-1])  # the log, and the server's Rig page
            self._tracker.close()
            self._tracker = None
            return empty
        body = self._tracker.track(handle, TRACK_TIMEOUT_MS, cap.depth_timestamp_usec)
        if body is None:
            return empty
        pos, st, ids = skeleton_arrays(body, self._body_id)
        if ids:
            self._body_id = ids[0]
        return pos, st, ids, body.device_timestamp_usec, body_index_image(body, ids)

    def frames(self) -> Iterator[Frame]:
        try:
            while not self._closed.is_set():
                cap = self._k4a.get_capture()
                arrival = arrival_time(cap)  # before tracking, which may take long
                if cap.depth is None:
                    continue
                pos, st, ids, body_usec, body_index = self._skeleton(cap)
                # the body frame's timestamp is its capture's depth timestamp
                t_local = self._t_local(cap.depth_timestamp_usec, arrival, body_usec)
                depth, color = cap.depth, cap.transformed_color
                yield Frame(t_local, pos, st, ids, _images(depth, color, body_index))
        finally:
            if self._tracker is not None:
                self._tracker.close()
                self._tracker = None
            self._k4a.stop()


def _images(depth: NDArray[np.uint16], color: NDArray[np.uint8] | None,
            body_index: NDArray[np.uint8] | None = None) -> Any:
    def images(streams: Sequence[str]) -> dict[str, NDArray[np.uint8] | NDArray[np.uint16]]:
        out: dict[str, NDArray[np.uint8] | NDArray[np.uint16]] = {}
        if "depth" in streams:
            out["depth"] = depth
        if "body_index" in streams and body_index is not None:
            out["body_index"] = body_index
        if "color" in streams and color is not None:
            out["color"] = np.ascontiguousarray(color[..., 2::-1])  # BGRA → RGB
        return out

    return images
