"""A minimal ctypes binding to the Azure Kinect Body Tracking SDK (``libk4abt``).

``pyk4a`` wraps the sensor SDK (libk4a) but not body tracking, so the ``k4a`` backend
binds exactly the functions it needs here. Target: Body Tracking SDK **1.1.x** (1.1.0 –
1.1.2, the last release, also used unchanged with an Orbbec Femto through Orbbec's K4A
wrapper). Every signature and layout below was checked against the SDK's own text; the
sources (API reference pages, header copies, pyKinectAzure's binding, pyk4a's sources)
are listed in ``docs/backbone.md``, "What was checked against the SDKs":

* ``k4abt.h`` (SDK 1.1.x): ``k4abt_tracker_create(const k4a_calibration_t*,
  k4abt_tracker_configuration_t, k4abt_tracker_t*) → k4a_result_t`` (the calibration by
  pointer, the configuration **by value**), ``k4abt_tracker_enqueue_capture(tracker,
  k4a_capture_t, int32_t timeout_ms) → k4a_wait_result_t`` (TIMEOUT: input queue full;
  FAILED e.g. a capture without depth), ``k4abt_tracker_pop_result(tracker,
  k4abt_frame_t*, int32_t timeout_ms) → k4a_wait_result_t``,
  ``k4abt_frame_get_num_bodies → uint32_t``, ``k4abt_frame_get_body_skeleton(frame,
  uint32_t index, k4abt_skeleton_t*) → k4a_result_t``, ``k4abt_frame_get_body_id(frame,
  uint32_t) → uint32_t`` (``K4ABT_INVALID_BODY_ID`` = 0xFFFFFFFF on failure),
  ``k4abt_frame_get_device_timestamp_usec → uint64_t``,
  ``k4abt_frame_get_system_timestamp_nsec → uint64_t`` (new in 1.1: bound only to tell
  1.1 from 1.0), ``k4abt_frame_get_body_index_map → k4a_image_t`` (8 bits a pixel, the
  depth image's size, pixel = index of the body in the frame or
  ``K4ABT_BODY_INDEX_MAP_BACKGROUND`` 255; released with ``k4a_image_release``),
  ``k4abt_frame_release``, ``k4abt_tracker_shutdown`` then ``k4abt_tracker_destroy``.
* ``k4a.h`` (sensor SDK 1.4, libk4a): ``k4a_image_get_buffer → uint8_t*``,
  ``k4a_image_get_width_pixels`` / ``_height_pixels`` / ``_stride_bytes → int``,
  ``k4a_image_release`` — only to copy the body index map out.
* ``k4abttypes.h`` (SDK 1.1.x): ``k4abt_tracker_configuration_t`` = {enum
  sensor_orientation, enum processing_mode, int32_t gpu_device_id, const char*
  model_path} (24 bytes on 64-bit). SDK 1.0.x has no ``model_path`` (12 bytes): a 1.1
  configuration handed to 1.0 by value would be misread, so a library without
  ``k4abt_frame_get_system_timestamp_nsec`` (absent from the 1.0.1 API) is refused.
  ``k4abt_joint_t`` = {``k4a_float3_t`` position (mm, depth camera frame),
  ``k4a_quaternion_t`` orientation (w, x, y, z), ``k4abt_joint_confidence_level_t`` (int:
  NONE 0 out of range, LOW 1 occluded/predicted, MEDIUM 2 the highest the SDK gives, HIGH
  3 "placeholder for future SDK")}: 32 bytes; ``k4abt_skeleton_t`` = 32 joints in
  ``k4abt_joint_id_t`` order (1024 bytes).
* ``k4atypes.h`` (sensor SDK 1.4): ``k4a_result_t`` (SUCCEEDED 0, FAILED 1),
  ``k4a_wait_result_t`` (SUCCEEDED 0, FAILED 1, TIMEOUT 2), ``k4a_float3_t`` = 3 floats;
  handles are opaque pointers.
* ``pyk4a`` 1.0.1 – 1.5.0 (``pyk4a.cpp``, checked in the 1.0.1, 1.1.0, 1.2.0 and 1.5.0
  sources): ``Calibration._calibration_handle`` is a PyCapsule named ``"pyk4a calibration
  handle"`` holding a malloc'd ``k4a_calibration_t*``; ``PyK4ACapture._capture_handle``
  one named ``"pyk4a capture handle"`` holding a malloc'd ``k4a_capture_t*`` (a pointer to
  the handle, dereferenced here). Both are private attributes, not API: pyk4a 0.x had no
  capsules, and a later pyk4a may change them, which :func:`capsule_pointer` reports.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from engine.errors import InputError

JOINT_COUNT = 32  # K4ABT_JOINT_COUNT
INVALID_BODY_ID = 0xFFFFFFFF  # K4ABT_INVALID_BODY_ID
K4A_WAIT_INFINITE = -1

# k4abt_joint_confidence_level_t
CONFIDENCE_NONE, CONFIDENCE_LOW, CONFIDENCE_MEDIUM, CONFIDENCE_HIGH = 0, 1, 2, 3

# k4abt_tracker_processing_mode_t: "gpu" lets the SDK choose (DirectML on Windows, CUDA
# on Linux); "directml" is Windows only; "tensorrt" is experimental in the SDK
PROCESSING_MODES = {"gpu": 0, "cpu": 1, "cuda": 2, "tensorrt": 3, "directml": 4}

# k4abt_sensor_orientation_t: how the sensor is mounted (a hint for the tracker's network;
# joint positions stay in the depth camera frame whatever the orientation)
SENSOR_ORIENTATIONS = {"default": 0, "clockwise90": 1, "counterclockwise90": 2,
                       "flip180": 3}


def sensor_orientation_value(orientation: str | int) -> int:
    """``k4abt_sensor_orientation_t`` of a name of :data:`SENSOR_ORIENTATIONS` (or its
    value, passed through).

    Raises:
        InputError: neither a known name nor a value 0–3.
    """
    if isinstance(orientation, str):
        key = orientation.strip().lower().replace("_", "").replace("-", "")
        if key in SENSOR_ORIENTATIONS:
            return SENSOR_ORIENTATIONS[key]
    elif not isinstance(orientation, bool) and orientation in SENSOR_ORIENTATIONS.values():
        return int(orientation)
    raise InputError(f"unknown sensor orientation {orientation!r}; use one of "
                     f"{', '.join(SENSOR_ORIENTATIONS)}")


def check_processing_mode(mode: str) -> str:
    """``mode`` if it is a key of :data:`PROCESSING_MODES`.

    Raises:
        InputError: an unknown mode (the message lists the known ones).
    """
    if mode not in PROCESSING_MODES:
        raise InputError(f"unknown body-tracking processing mode {mode!r}; "
                         f"use one of {', '.join(PROCESSING_MODES)}")
    return mode

_RESULT_SUCCEEDED = 0
_WAIT_SUCCEEDED, _WAIT_FAILED, _WAIT_TIMEOUT = 0, 1, 2

#: stale results (of captures whose pop timed out) dropped at most per capture; the SDK
#: queues only a few frames
_MAX_STALE = 4
#: results drained at most when the input queue is full (the SDK "will buffer at least
#: three body frames worth of data before stopping new capture being queued")
_MAX_QUEUE = 8
#: a result this close to the capture's depth timestamp is its own (the SDK copies the
#: depth timestamp; the margin, under half a frame at 30 fps, only guards against rounding)
_SAME_CAPTURE_USEC = 10_000

CAPSULE_CALIBRATION = b"pyk4a calibration handle"
CAPSULE_CAPTURE = b"pyk4a capture handle"

INSTALL_HINT = (
    "skeletons need the Azure Kinect Body Tracking SDK 1.1 (libk4abt), which was not "
    "found, so this node streams images with empty skeleton frames. Install it and "
    "restart the node: on Ubuntu add Microsoft's package repository "
    "(packages.microsoft.com, Ubuntu 18.04 repository) and run `sudo apt install "
    "libk4abt1.1-dev`; on Windows run the 'Azure Kinect Body Tracking SDK' installer "
    "(1.1.2). The library must be on the loader path (LD_LIBRARY_PATH on Linux); an "
    "NVIDIA GPU with CUDA is used if present, otherwise the much slower CPU mode.")


class K4ABTUnavailable(InputError):  # noqa: N818 - reads as a state, like InputError
    """libk4abt cannot be loaded or a tracker cannot be created (message says why)."""


# --------------------------------------------------------------------------- layouts


class _Float3(ctypes.Structure):
    """``k4a_float3_t`` (a union of ``{x, y, z}`` and ``float v[3]``: 12 bytes)."""

    _fields_ = [("x", ctypes.c_float), ("y", ctypes.c_float), ("z", ctypes.c_float)]


class _Quaternion(ctypes.Structure):
    """``k4a_quaternion_t`` (union of ``{w, x, y, z}`` and ``float v[4]``: 16 bytes)."""

    _fields_ = [("w", ctypes.c_float), ("x", ctypes.c_float), ("y", ctypes.c_float),
                ("z", ctypes.c_float)]


class Joint(ctypes.Structure):
    """``k4abt_joint_t``: 12 + 16 + 4 = 32 bytes."""

    _fields_ = [("position", _Float3), ("orientation", _Quaternion),
                ("confidence_level", ctypes.c_int)]


class Skeleton(ctypes.Structure):
    """``k4abt_skeleton_t``: 32 joints, 1024 bytes."""

    _fields_ = [("joints", Joint * JOINT_COUNT)]


class TrackerConfiguration(ctypes.Structure):
    """``k4abt_tracker_configuration_t`` (SDK 1.1.x; passed by value)."""

    _fields_ = [("sensor_orientation", ctypes.c_int), ("processing_mode", ctypes.c_int),
                ("gpu_device_id", ctypes.c_int32), ("model_path", ctypes.c_char_p)]


# a numpy view of a Skeleton's bytes: (32,) records of position, orientation, confidence
_JOINT_DTYPE = np.dtype([("position", "<f4", (3,)), ("orientation", "<f4", (4,)),
                         ("confidence", "<i4")])
assert _JOINT_DTYPE.itemsize == ctypes.sizeof(Joint) == 32


# --------------------------------------------------------------------------- loading


def _candidates() -> list[str]:
    """Library names/paths to try, most specific first."""
    if sys.platform == "win32":
        names = ["k4abt.dll"]
        base = Path(os.environ.get("PROGRAMFILES", r"C:\Program Files"))
        sdk = base / "Azure Kinect Body Tracking SDK" / "sdk" / "windows-desktop" / "amd64"
        names.append(str(sdk / "release" / "bin" / "k4abt.dll"))
        return names
    found = ctypes.util.find_library("k4abt")
    # no "libk4abt.so.1.0": SDK 1.0 takes a shorter configuration (refused in _declare)
    return [n for n in (found, "libk4abt.so", "libk4abt.so.1.1") if n]


def load_library(path: str | Path | None = None) -> ctypes.CDLL:
    """Load libk4abt and declare the functions used.

    Args:
        path: the library file; None: the system's (``find_library``, then the SDK's
            usual names and, on Windows, its install folder).

    Raises:
        K4ABTUnavailable: not found or not a body-tracking library; the message says
            how to install the SDK.
    """
    names = [str(path)] if path is not None else _candidates()
    errors: list[str] = []
    for name in names:
        try:
            lib = ctypes.CDLL(name)
        except OSError as exc:
            errors.append(f"{name}: {exc}")
            continue
        try:
            _declare(lib)
        except AttributeError as exc:
            if hasattr(lib, "k4abt_tracker_create"):
                raise K4ABTUnavailable(
                    f"{name} is an Azure Kinect Body Tracking SDK older than 1.1 (it has no "
                    f"{_SDK_1_1_MARKER}); its tracker configuration differs from 1.1's, so "
                    f"it cannot be used; {INSTALL_HINT}") from None
            raise K4ABTUnavailable(f"{name} is not the Azure Kinect Body Tracking SDK "
                                   f"({exc}); {INSTALL_HINT}") from None
        return lib
    raise K4ABTUnavailable(f"{INSTALL_HINT} (tried: {'; '.join(errors)})")


#: a function Body Tracking SDK 1.1 has and 1.0 lacks (1.1.x API reference vs 1.0.1's)
_SDK_1_1_MARKER = "k4abt_frame_get_system_timestamp_nsec"


def _declare(lib: ctypes.CDLL) -> None:
    vp, u32, i32, c_int = ctypes.c_void_p, ctypes.c_uint32, ctypes.c_int32, ctypes.c_int
    sig: dict[str, tuple[Any, list[Any]]] = {
        "k4abt_tracker_create": (c_int, [vp, TrackerConfiguration, ctypes.POINTER(vp)]),
        "k4abt_tracker_destroy": (None, [vp]),
        "k4abt_tracker_shutdown": (None, [vp]),
        "k4abt_tracker_enqueue_capture": (c_int, [vp, vp, i32]),
        "k4abt_tracker_pop_result": (c_int, [vp, ctypes.POINTER(vp), i32]),
        "k4abt_frame_release": (None, [vp]),
        "k4abt_frame_get_num_bodies": (u32, [vp]),
        "k4abt_frame_get_body_skeleton": (c_int, [vp, u32, ctypes.POINTER(Skeleton)]),
        "k4abt_frame_get_body_id": (u32, [vp, u32]),
        "k4abt_frame_get_device_timestamp_usec": (ctypes.c_uint64, [vp]),
        "k4abt_frame_get_body_index_map": (vp, [vp]),
        _SDK_1_1_MARKER: (ctypes.c_uint64, [vp]),
    }
    for name, (restype, argtypes) in sig.items():
        fn = getattr(lib, name)
        fn.restype, fn.argtypes = restype, argtypes


def load_image_library(path: str | Path | None = None) -> ctypes.CDLL | None:
    """libk4a's image functions (for the body index map), or None if not loadable.

    pyk4a has already loaded libk4a into the process, so the system's is found.
    """
    if path is not None:
        names = [str(path)]
    elif sys.platform == "win32":
        names = ["k4a.dll"]
    else:
        names = [n for n in (ctypes.util.find_library("k4a"), "libk4a.so", "libk4a.so.1.4")
                 if n]
    for name in names:
        try:
            lib = ctypes.CDLL(name)
            vp, c_int = ctypes.c_void_p, ctypes.c_int
            sig: dict[str, tuple[Any, list[Any]]] = {
                "k4a_image_get_buffer": (ctypes.POINTER(ctypes.c_uint8), [vp]),
                "k4a_image_get_width_pixels": (c_int, [vp]),
                "k4a_image_get_height_pixels": (c_int, [vp]),
                "k4a_image_get_stride_bytes": (c_int, [vp]),
                "k4a_image_release": (None, [vp]),
            }
            for fn_name, (restype, argtypes) in sig.items():
                fn = getattr(lib, fn_name)
                fn.restype, fn.argtypes = restype, argtypes
        except (OSError, AttributeError):
            continue
        return lib
    return None


# --------------------------------------------------------------------------- capsules


def capsule_pointer(capsule: object, name: bytes) -> int:
    """The pointer a PyCapsule holds (``PyCapsule_GetPointer``).

    Raises:
        K4ABTUnavailable: not a capsule of that name (an unexpected pyk4a version).
    """
    get = ctypes.pythonapi.PyCapsule_GetPointer
    get.restype, get.argtypes = ctypes.c_void_p, [ctypes.py_object, ctypes.c_char_p]
    is_valid = ctypes.pythonapi.PyCapsule_IsValid
    is_valid.restype, is_valid.argtypes = ctypes.c_int, [ctypes.py_object, ctypes.c_char_p]
    if not is_valid(capsule, name):
        raise K4ABTUnavailable(
            f"this pyk4a does not hold its handles in a {name.decode()!r} capsule, as pyk4a "
            "1.0.1 to 1.5.0 do; skeletons need one of those (gaitrig's `.[k4a]` extra "
            "installs pyk4a 1.5)")
    ptr = get(capsule, name)
    if not ptr:
        raise K4ABTUnavailable(f"empty {name.decode()!r} capsule")
    return int(ptr)


def calibration_pointer(calibration: Any) -> int:
    """``k4a_calibration_t*`` of a ``pyk4a.Calibration``."""
    return capsule_pointer(calibration._calibration_handle, CAPSULE_CALIBRATION)


def capture_handle(capture: Any) -> int:
    """The ``k4a_capture_t`` handle of a ``pyk4a.PyK4ACapture`` (the capsule holds a
    pointer to it)."""
    ptr = capsule_pointer(capture._capture_handle, CAPSULE_CAPTURE)
    handle = ctypes.c_void_p.from_address(ptr).value
    if not handle:
        raise K4ABTUnavailable("pyk4a capture without a k4a capture handle")
    return int(handle)


# --------------------------------------------------------------------------- tracker


@dataclass
class BodyFrame:
    """One popped body-tracking result, copied out of the SDK's frame.

    Attributes:
        device_timestamp_usec: the frame's device timestamp (µs; = its depth image's).
        body_ids: ``B`` tracking ids (stable across frames while the body is tracked).
        positions_mm: ``(B, 32, 3)`` float32, depth camera frame (x right, y down, z
            forward), millimetres, ``K4ABT_JOINT_*`` order.
        orientations: ``(B, 32, 4)`` float32 quaternions (w, x, y, z).
        confidence: ``(B, 32)`` int32 ``k4abt_joint_confidence_level_t``.
        body_index: ``(H, W)`` uint8 body index map (pixel = position of the body in
            ``body_ids``, 255 = background), None without libk4a's image functions.
    """

    device_timestamp_usec: int
    body_ids: list[int]
    positions_mm: NDArray[np.float32]
    orientations: NDArray[np.float32]
    confidence: NDArray[np.int32]
    body_index: NDArray[np.uint8] | None = None


class Tracker:
    """A k4abt body tracker (one per process: the SDK allows no second one).

    Args:
        lib: from :func:`load_library`.
        calibration: ``k4a_calibration_t*`` (:func:`calibration_pointer`).
        processing_mode: a key of :data:`PROCESSING_MODES`; ``"gpu"`` falls back to
            ``"cpu"`` when no GPU tracker can be created (:attr:`mode` says which runs).
        sensor_orientation: how the sensor is mounted: a key of
            :data:`SENSOR_ORIENTATIONS` (``"default"``, ``"clockwise90"``,
            ``"counterclockwise90"``, ``"flip180"`` upside down) or its
            ``k4abt_sensor_orientation_t`` value 0–3.
        gpu_device_id: GPU index for GPU modes.
        model_path: another model file (None: the SDK's default).
        image_lib: libk4a (:func:`load_image_library`) to copy the body index map out;
            None: frames carry no body index map.

    Raises:
        InputError: an unknown processing mode or sensor orientation.
        K4ABTUnavailable: no tracker could be created.
    """

    def __init__(self, lib: ctypes.CDLL, calibration: int, processing_mode: str = "gpu",
                 sensor_orientation: str | int = 0, gpu_device_id: int = 0,
                 model_path: str | None = None, image_lib: ctypes.CDLL | None = None) -> None:
        check_processing_mode(processing_mode)
        orientation = sensor_orientation_value(sensor_orientation)
        self._lib = lib
        self._image_lib = image_lib
        self._handle = ctypes.c_void_p()
        # keep the path's bytes alive while the SDK may read them
        self._model = model_path.encode() if model_path else None
        modes = [processing_mode] + (["cpu"] if processing_mode == "gpu" else [])
        for mode in modes:
            cfg = TrackerConfiguration(orientation, PROCESSING_MODES[mode],
                                       gpu_device_id, self._model)
            rc = lib.k4abt_tracker_create(ctypes.c_void_p(calibration), cfg,
                                          ctypes.byref(self._handle))
            if rc == _RESULT_SUCCEEDED and self._handle.value:
                self.mode = mode
                return
        raise K4ABTUnavailable(
            f"k4abt_tracker_create failed (modes tried: {', '.join(modes)}): check the "
            "Body Tracking SDK install (its ONNX model and runtime next to libk4abt), the "
            "GPU driver/CUDA for GPU mode, and that no other tracker runs in this process")

    def track(self, capture: int, timeout_ms: int = K4A_WAIT_INFINITE,
              device_timestamp_usec: int | None = None) -> BodyFrame | None:
        """Enqueue one capture and pop its result (synchronous: one in, one out).

        Args:
            capture: ``k4a_capture_t`` handle (:func:`capture_handle`); the SDK takes its
                own reference, the caller keeps its capture.
            timeout_ms: how long to wait for the queue and for the result.
            device_timestamp_usec: the capture's depth timestamp: results of older
                captures still queued (their pop timed out earlier) are dropped, so the
                stream does not stay one frame behind its images after a slow frame.

        Returns:
            The body frame, or None when the capture was refused (e.g. no depth image)
            or the result timed out.
        """
        lib, h = self._lib, self._handle
        if h.value is None:
            return None
        cap = ctypes.c_void_p(capture)
        rc = lib.k4abt_tracker_enqueue_capture(h, cap, 0)
        if rc == _WAIT_TIMEOUT:
            # The queue is full: results of captures whose pop timed out (a slow first
            # frame) fill the SDK's output queue, which only pops drain, so drop them now
            # (otherwise every later enqueue would time out too and skeletons stop).
            self._drain()
            rc = lib.k4abt_tracker_enqueue_capture(h, cap, timeout_ms)
        if rc != _WAIT_SUCCEEDED:
            return None
        for _ in range(_MAX_STALE + 1):
            frame = ctypes.c_void_p()
            if lib.k4abt_tracker_pop_result(h, ctypes.byref(frame),
                                            timeout_ms) != _WAIT_SUCCEEDED:
                return None
            try:
                ts = int(lib.k4abt_frame_get_device_timestamp_usec(frame))
                if (device_timestamp_usec is not None
                        and ts < device_timestamp_usec - _SAME_CAPTURE_USEC):
                    continue  # a stale result: released in finally
                return _read_frame(lib, frame, self._image_lib)
            finally:
                lib.k4abt_frame_release(frame)
        return None

    def _drain(self) -> int:
        """Release every result ready now (at most :data:`_MAX_QUEUE`); how many."""
        n = 0
        while n < _MAX_QUEUE:
            frame = ctypes.c_void_p()
            if self._lib.k4abt_tracker_pop_result(self._handle, ctypes.byref(frame),
                                                  0) != _WAIT_SUCCEEDED:
                break
            self._lib.k4abt_frame_release(frame)
            n += 1
        return n

    def close(self) -> None:
        """Shut the tracker down and destroy it (idempotent)."""
        if self._handle.value:
            self._lib.k4abt_tracker_shutdown(self._handle)
            self._lib.k4abt_tracker_destroy(self._handle)
            self._handle = ctypes.c_void_p()


def _read_frame(lib: ctypes.CDLL, frame: ctypes.c_void_p,
                image_lib: ctypes.CDLL | None) -> BodyFrame:
    n = int(lib.k4abt_frame_get_num_bodies(frame))
    ids: list[int] = []
    records = []
    kept = np.full(256, 255, np.uint8)  # SDK body index → index in ``ids`` (255: dropped)
    skel = Skeleton()
    for i in range(n):
        if lib.k4abt_frame_get_body_skeleton(frame, i, ctypes.byref(skel)) != _RESULT_SUCCEEDED:
            continue
        body_id = int(lib.k4abt_frame_get_body_id(frame, i))
        if body_id == INVALID_BODY_ID:
            continue
        if i < 255:
            kept[i] = len(ids)
        ids.append(body_id)
        records.append(np.frombuffer(bytes(skel), _JOINT_DTYPE).copy())
    body_index = None
    if image_lib is not None:
        body_index = _copy_body_index(lib, image_lib, frame)
        if body_index is not None:
            body_index = kept[body_index]
    rec = (np.stack(records) if records
           else np.zeros((0, JOINT_COUNT), _JOINT_DTYPE))
    return BodyFrame(
        device_timestamp_usec=int(lib.k4abt_frame_get_device_timestamp_usec(frame)),
        body_ids=ids,
        positions_mm=np.ascontiguousarray(rec["position"], np.float32),
        orientations=np.ascontiguousarray(rec["orientation"], np.float32),
        confidence=np.ascontiguousarray(rec["confidence"], np.int32),
        body_index=body_index,
    )


def _copy_body_index(lib: ctypes.CDLL, image_lib: ctypes.CDLL, frame: ctypes.c_void_p
                     ) -> NDArray[np.uint8] | None:
    """The frame's body index map copied out (the SDK's image is released here)."""
    img = lib.k4abt_frame_get_body_index_map(frame)
    if not img:
        return None
    try:
        w = int(image_lib.k4a_image_get_width_pixels(img))
        h = int(image_lib.k4a_image_get_height_pixels(img))
        stride = int(image_lib.k4a_image_get_stride_bytes(img))
        buf = image_lib.k4a_image_get_buffer(img)
        if w <= 0 or h <= 0 or stride < w or not buf:
            return None
        raw = np.ctypeslib.as_array(buf, shape=(h * stride,))
        return raw.reshape(h, stride)[:, :w].copy()
    finally:
        image_lib.k4a_image_release(img)
