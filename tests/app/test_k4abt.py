"""k4abt skeletons of the ``k4a`` backend, without hardware.

A stand-in ``libk4abt`` (``tests/app/k4abt_stub/k4abt_stub.c``, the SDK's exact function
signatures and struct layouts) is compiled at test time and scripted with bodies; a fake
``pyk4a`` hands over capsules like the real one. What this cannot check: the real SDK's
tracking, its GPU/CPU runtime and the real pyk4a capsules (see ``docs/backbone.md``).
"""

from __future__ import annotations

import ctypes
import logging
import shutil
import subprocess
import sys
import types
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.nodes.backends import _k4abt
from app.nodes.protocol import SensorInfo
from app.server.registry import NodeRegistry
from engine.errors import InputError
from engine.skeleton import AZURE_KINECT_JOINTS, TrackingState

STUB_SRC = Path(__file__).parent / "k4abt_stub" / "k4abt_stub.c"

#: k4abt_joint_id_t, in order, as written in k4abttypes.h (Body Tracking SDK 1.1.x)
SDK_JOINTS = (
    "PELVIS", "SPINE_NAVEL", "SPINE_CHEST", "NECK", "CLAVICLE_LEFT", "SHOULDER_LEFT",
    "ELBOW_LEFT", "WRIST_LEFT", "HAND_LEFT", "HANDTIP_LEFT", "THUMB_LEFT",
    "CLAVICLE_RIGHT", "SHOULDER_RIGHT", "ELBOW_RIGHT", "WRIST_RIGHT", "HAND_RIGHT",
    "HANDTIP_RIGHT", "THUMB_RIGHT", "HIP_LEFT", "KNEE_LEFT", "ANKLE_LEFT", "FOOT_LEFT",
    "HIP_RIGHT", "KNEE_RIGHT", "ANKLE_RIGHT", "FOOT_RIGHT", "HEAD", "NOSE", "EYE_LEFT",
    "EAR_LEFT", "EYE_RIGHT", "EAR_RIGHT",
)


@pytest.fixture(scope="module")
def stub_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    cc = shutil.which("gcc") or shutil.which("cc")
    if cc is None or sys.platform == "win32":
        pytest.skip("no C compiler (gcc/cc) to build the stand-in libk4abt")
    out = tmp_path_factory.mktemp("k4abt") / "libk4abt_stub.so"
    subprocess.run([cc, "-shared", "-fPIC", "-O1", "-Wall", "-Werror", "-o", str(out),
                    str(STUB_SRC)], check=True, capture_output=True, timeout=60)
    return out


@pytest.fixture
def stub(stub_path: Path) -> Iterator[ctypes.CDLL]:
    lib = ctypes.CDLL(str(stub_path))  # the same handle as the binding's: shared state
    lib.stub_script.argtypes = [ctypes.c_uint64, ctypes.c_uint32,
                                ctypes.POINTER(ctypes.c_uint32),
                                ctypes.POINTER(ctypes.c_float), ctypes.c_uint64]
    lib.stub_last_config.argtypes = [ctypes.POINTER(ctypes.c_int32)] * 3 + [
        ctypes.POINTER(ctypes.c_void_p)]
    lib.stub_last_model_path.restype = ctypes.c_char_p
    lib.stub_sizeof_skeleton.restype = ctypes.c_size_t
    lib.stub_sizeof_config.restype = ctypes.c_size_t
    lib.stub_images_released.restype = ctypes.c_int
    lib.stub_delay_pops.argtypes = [ctypes.c_int]
    lib.stub_reset(0)
    yield lib
    lib.stub_reset(0)


def script(stub: ctypes.CDLL, capture: int, bodies: list[tuple[int, float]], ts: int) -> None:
    """The result the stub returns for ``capture``: ``(id, pelvis z mm)`` per body."""
    n = len(bodies)
    ids = (ctypes.c_uint32 * max(n, 1))(*[b[0] for b in bodies])
    zs = (ctypes.c_float * max(n, 1))(*[b[1] for b in bodies])
    assert stub.stub_script(capture, n, ids, zs, ts) == 0


# --------------------------------------------------------------------------- fake pyk4a

_new_capsule = ctypes.pythonapi.PyCapsule_New
_new_capsule.restype = ctypes.py_object
_new_capsule.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_void_p]


class FakeCalibration:
    def __init__(self) -> None:
        self.buffer = ctypes.create_string_buffer(2048)  # stands for a k4a_calibration_t
        self._calibration_handle = _new_capsule(ctypes.addressof(self.buffer),
                                                _k4abt.CAPSULE_CALIBRATION, None)

    def get_camera_matrix(self, kind: Any) -> np.ndarray:
        return np.array([[504.0, 0, 320], [0, 504.0, 288], [0, 0, 1]])


class FakeCapture:
    """A pyk4a 1.5 capture; ``get_capture`` returns it ``latency_s`` after mid-exposure
    (on the fake host clock, :data:`HOST`)."""

    def __init__(self, handle: int, depth_usec: int, latency_s: float = 0.004) -> None:
        self.cell = ctypes.c_void_p(handle)  # pyk4a's capsule holds a k4a_capture_t*
        self._capture_handle = _new_capsule(ctypes.addressof(self.cell),
                                            _k4abt.CAPSULE_CAPTURE, None)
        self.depth = np.full((4, 5), 1500, np.uint16)
        self.depth_timestamp_usec = depth_usec
        self.depth_system_timestamp_nsec = 0  # 0: pyk4a had none; the wall clock is used
        self.transformed_color = np.zeros((4, 5, 4), np.uint8)
        self.latency_s = latency_s


#: the fake host clock (s): the device clock started at host time 1000 s
HOST = {"now": 1000.0}


def fake_pyk4a(captures: list[FakeCapture]) -> types.ModuleType:
    mod = types.ModuleType("pyk4a")
    ns = types.SimpleNamespace
    mod.ColorResolution = ns(RES_720P=1)  # type: ignore[attr-defined]
    mod.DepthMode = ns(NFOV_UNBINNED=2)  # type: ignore[attr-defined]
    mod.FPS = ns(FPS_30=2)  # type: ignore[attr-defined]
    mod.CalibrationType = ns(DEPTH=0)  # type: ignore[attr-defined]
    mod.Config = lambda **kw: kw  # type: ignore[attr-defined]

    class PyK4A:
        def __init__(self, config: Any, device_id: int = 0, thread_safe: bool = True) -> None:
            self.calibration = FakeCalibration()
            self.stopped = False
            self.thread_safe = thread_safe

        def start(self) -> None:
            pass

        def stop(self) -> None:
            self.stopped = True

        def get_capture(self) -> FakeCapture:
            cap = captures.pop(0)
            HOST["now"] = 1000.0 + cap.depth_timestamp_usec * 1e-6 + cap.latency_s
            return cap

    mod.PyK4A = PyK4A  # type: ignore[attr-defined]
    return mod


def backend(monkeypatch: pytest.MonkeyPatch, captures: list[FakeCapture],
            lib: Path | str) -> Any:
    monkeypatch.setitem(sys.modules, "pyk4a", fake_pyk4a(captures))
    fake_host_clock(monkeypatch)
    from app.nodes.backends.k4a import K4ABackend

    return K4ABackend(k4abt_path=lib, k4a_path=lib)  # the stub stands for libk4a too


def fake_host_clock(monkeypatch: pytest.MonkeyPatch) -> None:
    """The backend reads :data:`HOST` as its wall clock and ``perf_counter_ns``."""
    from app.nodes.backends import k4a

    monkeypatch.setattr(k4a, "_wall", lambda: HOST["now"])
    monkeypatch.setattr(k4a, "_perf_ns", lambda: round(HOST["now"] * 1e9))


# --------------------------------------------------------------------------- tests


def test_layouts_and_joint_order_match_the_sdk(stub: ctypes.CDLL) -> None:
    assert stub.stub_sizeof_skeleton() == ctypes.sizeof(_k4abt.Skeleton) == 32 * 32
    assert stub.stub_sizeof_config() == ctypes.sizeof(_k4abt.TrackerConfiguration)
    assert SDK_JOINTS == AZURE_KINECT_JOINTS
    assert len(SDK_JOINTS) == _k4abt.JOINT_COUNT


def test_tracker_gets_calibration_and_configuration(stub: ctypes.CDLL, stub_path: Path) -> None:
    cal = FakeCalibration()
    lib = _k4abt.load_library(stub_path)
    tr = _k4abt.Tracker(lib, _k4abt.calibration_pointer(cal), "cuda", sensor_orientation=3,
                        gpu_device_id=1, model_path="/opt/model.onnx")
    o, m, g = ctypes.c_int32(), ctypes.c_int32(), ctypes.c_int32()
    c = ctypes.c_void_p()
    assert stub.stub_last_config(ctypes.byref(o), ctypes.byref(m), ctypes.byref(g),
                                 ctypes.byref(c)) == 1
    assert (o.value, m.value, g.value) == (3, _k4abt.PROCESSING_MODES["cuda"], 1)
    assert c.value == ctypes.addressof(cal.buffer)
    assert stub.stub_last_model_path() == b"/opt/model.onnx"
    assert tr.mode == "cuda"
    with pytest.raises(_k4abt.K4ABTUnavailable, match="no other tracker runs"):
        _k4abt.Tracker(lib, _k4abt.calibration_pointer(cal))  # one per process
    tr.close()
    assert stub.stub_last_config(ctypes.byref(o), ctypes.byref(m), ctypes.byref(g),
                                 ctypes.byref(c)) == 0


def test_binding_reads_bodies_ids_and_timestamp(stub: ctypes.CDLL, stub_path: Path) -> None:
    lib = _k4abt.load_library(stub_path)
    tr = _k4abt.Tracker(lib, _k4abt.calibration_pointer(FakeCalibration()),
                        image_lib=_k4abt.load_image_library(stub_path))
    try:
        script(stub, 0x51, [(3, 2500.0), (8, 1200.0)], 123_456_789)
        bf = tr.track(_k4abt.capture_handle(FakeCapture(0x51, 0)))
        assert bf is not None
        assert bf.device_timestamp_usec == 123_456_789
        assert bf.body_ids == [3, 8]
        j = np.arange(32)
        assert np.array_equal(bf.positions_mm[1, :, 0], 800 + j)
        assert np.array_equal(bf.positions_mm[1, :, 1], -10.0 * j)
        assert np.array_equal(bf.positions_mm[0, :, 2], 2500 + j)
        assert np.array_equal(bf.orientations[0, :, 0], np.ones(32))  # w first
        assert np.array_equal(bf.orientations[0, :, 1], 0.5 * j)
        assert np.array_equal(bf.confidence[0], j % 4)
        assert stub.stub_released() == 1  # the body frame went back to the SDK
        # body index map: column c = SDK body c, the stride's padding dropped
        assert bf.body_index is not None and bf.body_index.shape == (6, 8)
        assert np.array_equal(bf.body_index[0], [0, 1, 255, 255, 255, 255, 255, 255])
        assert stub.stub_images_released() == 1
        script(stub, 0x52, [(3, -1.0)], 1)  # the stub's "no map" frame
        bf = tr.track(_k4abt.capture_handle(FakeCapture(0x52, 0)))
        assert bf is not None and bf.body_index is None and bf.body_ids == [3]
        assert tr.track(_k4abt.capture_handle(FakeCapture(0x99, 0))) is None  # refused
    finally:
        tr.close()


def test_backend_streams_the_chosen_body_in_metres(
        stub: ctypes.CDLL, stub_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    t0 = 5_000_000
    script(stub, 1, [(7, 2000.0)], t0)
    script(stub, 2, [(9, 1500.0), (7, 3000.0)], t0 + 33_333)  # 7 is kept: followed
    script(stub, 3, [], t0 + 66_666)  # nobody
    script(stub, 4, [(11, 2500.0), (9, 1800.0)], t0 + 100_000)  # 7 lost: nearest = 9
    caps = [FakeCapture(k, t0 + d) for k, d in
            ((1, 0), (2, 33_333), (3, 66_666), (4, 100_000))]
    be = backend(monkeypatch, caps, stub_path)
    info = be.open()
    assert info.joint_set == "azure_kinect" and info.warnings == []
    gen = be.frames()
    frames = [next(gen) for _ in range(4)]
    gen.close()
    assert stub.stub_released() == 4

    assert [f.body_ids for f in frames] == [[7], [7], [], [9]]
    f = frames[1]
    assert f.positions.shape == (1, 32, 3) and f.positions.dtype == np.float32
    j = np.arange(32)
    expect = np.stack([(700 + j) / 1000, -10 * j / 1000, (3000 + j) / 1000], axis=1)
    states = f.states[0]
    assert np.array_equal(states[j % 4 == 0], np.full(8, TrackingState.NOT_TRACKED))
    assert np.array_equal(states[j % 4 == 1], np.full(8, TrackingState.INFERRED))
    assert np.all(states[j % 4 >= 2] == TrackingState.TRACKED)  # MEDIUM and HIGH
    seen = j % 4 != 0
    np.testing.assert_allclose(f.positions[0][seen], expect[seen], rtol=1e-6)
    assert np.all(np.isnan(f.positions[0][~seen]))  # NONE: no position, as the sim
    # the image axes are untouched: x right, y down (negative y = above), z forward
    assert frames[3].positions[0, 1, 2] == pytest.approx(1.801)
    assert frames[2].positions.shape == (0, 32, 3) and frames[2].states.shape == (0, 32)
    dt = [fr.t_local - frames[0].t_local for fr in frames]
    np.testing.assert_allclose(dt, [0.0, 0.033333, 0.066666, 0.1], atol=1e-6)
    img = frames[0].images(["depth", "color"])
    assert img["depth"].shape == (4, 5) and img["color"].shape == (4, 5, 3)
    # body index: the streamed body's pixels 0, everything else 255 (SDK index 1 = id 7)
    bi = frames[1].images(["body_index"])["body_index"]
    assert bi.dtype == np.uint8 and bi.shape == (6, 8)
    assert np.array_equal(bi[3], [255, 0, 255, 255, 255, 255, 255, 255])
    assert np.all(frames[2].images(["body_index"])["body_index"] == 255)
    assert np.array_equal(frames[3].images(["body_index"])["body_index"][0, :3],
                          [255, 0, 255])  # id 9 is SDK index 1 there
    assert stub.stub_images_released() == 4
    assert be._k4a.stopped


def test_a_late_result_is_dropped_not_carried_one_frame_behind(
        stub: ctypes.CDLL, stub_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    script(stub, 1, [(5, 2000.0)], 1_000_000)
    script(stub, 2, [(5, 2100.0)], 1_033_333)
    script(stub, 3, [(5, 2200.0)], 1_066_666)
    be = backend(monkeypatch, [FakeCapture(k, 1_000_000 + 33_333 * (k - 1) + (k == 3))
                               for k in (1, 2, 3)], stub_path)
    be.open()
    stub.stub_delay_pops(1)  # capture 1's result comes too late
    gen = be.frames()
    a, b, c = next(gen), next(gen), next(gen)
    gen.close()
    assert a.body_ids == [] and a.positions.shape == (0, 32, 3)  # timed out: no skeleton
    assert stub.stub_released() == 3  # capture 1's late result was released, not streamed
    # capture 2 gets its own body (pelvis z 2.1 m), capture 3 too (1 µs off: its own)
    assert b.positions[0, 1, 2] == pytest.approx(2.101)
    assert c.positions[0, 1, 2] == pytest.approx(2.201)
    assert b.t_local - a.t_local == pytest.approx(0.033333, abs=1e-6)


def test_body_timestamp_drives_frame_time(
        stub: ctypes.CDLL, stub_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    script(stub, 1, [(1, 2000.0)], 1_000_000)
    script(stub, 2, [(1, 2000.0)], 1_500_000)  # the body frame's own time, not the depth's
    be = backend(monkeypatch, [FakeCapture(1, 1_000_000), FakeCapture(2, 1_400_000)],
                 stub_path)
    be.open()
    gen = be.frames()
    a, b = next(gen), next(gen)
    gen.close()
    assert b.t_local - a.t_local == pytest.approx(0.5, abs=1e-6)


def test_gpu_failure_falls_back_to_cpu_with_a_warning(
        stub: ctypes.CDLL, stub_path: Path, monkeypatch: pytest.MonkeyPatch,
        caplog: pytest.LogCaptureFixture) -> None:
    stub.stub_reset(1)  # GPU modes fail, as without CUDA
    script(stub, 1, [(4, 2000.0)], 10)
    be = backend(monkeypatch, [FakeCapture(1, 10)], stub_path)
    with caplog.at_level(logging.WARNING, "gaitrig.node"):
        info = be.open()
    assert len(info.warnings) == 1 and "CPU mode" in info.warnings[0]
    gen = be.frames()
    assert next(gen).body_ids == [4]
    gen.close()


def test_without_the_sdk_images_flow_and_the_node_says_why(
        monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture,
        tmp_path: Path) -> None:
    be = backend(monkeypatch, [FakeCapture(1, 0), FakeCapture(2, 33_333)],
                 tmp_path / "libk4abt.so")
    with caplog.at_level(logging.WARNING, "gaitrig.node"):
        info = be.open()
        gen = be.frames()
        frames = [next(gen), next(gen)]
        gen.close()
    assert len(info.warnings) == 1
    msg = info.warnings[0]
    assert "Body Tracking SDK" in msg and "apt install libk4abt1.1-dev" in msg
    assert "no skeletons" in info.model
    said = [r for r in caplog.records if "Body Tracking SDK" in r.getMessage()]
    assert len(said) == 1  # once, not per frame
    assert all(f.positions.shape == (0, 32, 3) and f.body_ids == [] for f in frames)
    assert frames[1].t_local - frames[0].t_local == pytest.approx(0.033333, abs=1e-6)
    assert frames[0].images(["depth"])["depth"].shape == (4, 5)

    # the warning reaches the node's health record (rig page, GET /api/nodes)
    reg = NodeRegistry()

    async def send(text: str) -> None:
        pass

    s = reg.connect("K1", "k4a", SensorInfo.model_validate(info.model_dump()), send,
                    restarted=True)
    assert msg in reg.health(s)["warnings"]


def test_a_library_that_is_not_k4abt_is_refused() -> None:
    libc = "libc.so.6" if sys.platform.startswith("linux") else None
    if libc is None:
        pytest.skip("needs glibc's libc.so.6 as a library that is not k4abt")
    with pytest.raises(_k4abt.K4ABTUnavailable, match="is not the Azure Kinect Body"):
        _k4abt.load_library(libc)


def test_capsule_of_another_kind_is_refused() -> None:
    cap = FakeCapture(1, 0)
    with pytest.raises(_k4abt.K4ABTUnavailable, match=r"pyk4a 1\.0\.1 to 1\.5\.0"):
        _k4abt.capsule_pointer(cap._capture_handle, _k4abt.CAPSULE_CALIBRATION)
    with pytest.raises(_k4abt.K4ABTUnavailable):
        _k4abt.capsule_pointer(object(), _k4abt.CAPSULE_CAPTURE)


def test_system_search_without_the_sdk_says_how_to_install(
        monkeypatch: pytest.MonkeyPatch) -> None:
    import ctypes.util

    monkeypatch.setattr(ctypes.util, "find_library", lambda name: None)
    monkeypatch.setattr(_k4abt.ctypes, "CDLL", _no_such_library)
    with pytest.raises(_k4abt.K4ABTUnavailable) as info:
        _k4abt.load_library()
    msg = str(info.value)
    assert "Body Tracking SDK 1.1" in msg and "libk4abt1.1-dev" in msg
    assert "libk4abt.so.1.1" in msg  # the names tried
    assert _k4abt.load_image_library() is None  # no libk4a: no body index, no crash


def _no_such_library(name: str, *args: Any, **kwargs: Any) -> ctypes.CDLL:
    raise OSError(f"{name}: cannot open shared object file")


def test_a_pyk4a_without_capture_capsules_stops_tracking_not_the_stream(
        stub: ctypes.CDLL, stub_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cap = FakeCapture(1, 0)
    cap._capture_handle = object()  # what an incompatible pyk4a would hand over
    be = backend(monkeypatch, [cap, FakeCapture(2, 33_333)], stub_path)
    be.open()
    sent: list[str] = []
    be.warning_sink = sent.append  # what the node agent sends on to the server
    gen = be.frames()
    a, b = next(gen), next(gen)
    gen.close()
    assert a.body_ids == [] and b.body_ids == []
    assert b.images(["depth"])["depth"].shape == (4, 5)
    assert any("pyk4a" in w for w in be.warnings)
    assert sent == be.warnings and sent[0].startswith("Body tracking stopped")


# --------------------------------------------------------------------------- node options


def _node_args(*argv: str) -> Any:
    import argparse

    from app.commands import node

    parser = argparse.ArgumentParser()
    node.add_arguments(parser)
    return parser.parse_args(["--id", "K1", "--backend", "k4a", *argv])


@pytest.mark.parametrize(("argv", "orientation", "mode"), [
    ((), 0, "gpu"),
    (("--sensor-orientation", "clockwise90", "--body-tracking", "cpu"), 1, "cpu"),
    (("--sensor-orientation", "counterclockwise90", "--body-tracking", "cuda"), 2, "cuda"),
    (("--sensor-orientation", "flip180", "--body-tracking", "directml"), 3, "directml"),
])
def test_node_options_reach_the_tracker_configuration(
        stub: ctypes.CDLL, stub_path: Path, monkeypatch: pytest.MonkeyPatch,
        argv: tuple[str, ...], orientation: int, mode: str) -> None:
    from app.commands.node import make_backend

    monkeypatch.setitem(sys.modules, "pyk4a", fake_pyk4a([FakeCapture(1, 0)]))
    # the system search finds the stand-in, as it would find the installed SDK
    monkeypatch.setattr(_k4abt, "_candidates", lambda: [str(stub_path)])
    be = make_backend(_node_args(*argv))
    info = be.open()  # type: ignore[attr-defined]
    assert info.warnings == [] and "k4abt" in info.model
    o, m, g = ctypes.c_int32(), ctypes.c_int32(), ctypes.c_int32()
    c = ctypes.c_void_p()
    assert stub.stub_last_config(ctypes.byref(o), ctypes.byref(m), ctypes.byref(g),
                                 ctypes.byref(c)) == 1
    assert (o.value, m.value) == (orientation, _k4abt.PROCESSING_MODES[mode])
    be._tracker.close()  # type: ignore[attr-defined]


def test_an_explicit_gpu_mode_that_fails_is_not_replaced_by_cpu(
        stub: ctypes.CDLL, stub_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    stub.stub_reset(1)  # GPU modes fail, as without CUDA
    be = backend(monkeypatch, [FakeCapture(1, 10)], stub_path)
    be.processing_mode = "cuda"
    info = be.open()
    assert be._tracker is None and "no skeletons" in info.model
    assert len(info.warnings) == 1 and "modes tried: cuda" in info.warnings[0]


def test_body_tracking_off_streams_images_without_a_warning(
        stub: ctypes.CDLL, monkeypatch: pytest.MonkeyPatch) -> None:
    from app.commands.node import make_backend

    monkeypatch.setitem(sys.modules, "pyk4a", fake_pyk4a([FakeCapture(1, 0)]))
    be: Any = make_backend(_node_args("--body-tracking", "off"))
    info = be.open()
    assert be._tracker is None and info.warnings == []
    frame = next(be.frames())
    assert frame.body_ids == [] and frame.images(["depth"])["depth"].shape == (4, 5)
    assert stub.stub_last_config(*(ctypes.byref(ctypes.c_int32()) for _ in range(3)),
                                 ctypes.byref(ctypes.c_void_p())) == 0  # no tracker made


def test_orientation_names_and_values() -> None:
    assert [_k4abt.sensor_orientation_value(n) for n in _k4abt.SENSOR_ORIENTATIONS] == [
        0, 1, 2, 3]
    assert _k4abt.sensor_orientation_value("Clockwise_90") == 1
    assert _k4abt.sensor_orientation_value(3) == 3
    for bad in ("upside-down", 4, True):
        with pytest.raises(InputError, match="clockwise90"):
            _k4abt.sensor_orientation_value(bad)  # type: ignore[arg-type]


@pytest.mark.parametrize(("kwargs", "named"), [
    ({"sensor_orientation": "sideways"}, "flip180"),
    ({"processing_mode": "opencl"}, "directml"),
])
def test_a_bad_k4a_option_is_named_before_pyk4a_is_needed(
        monkeypatch: pytest.MonkeyPatch, kwargs: dict[str, str], named: str) -> None:
    from app.nodes.backends.k4a import K4ABackend

    monkeypatch.setitem(sys.modules, "pyk4a", None)  # not installed
    with pytest.raises(InputError, match=named):
        K4ABackend(**kwargs)  # type: ignore[arg-type]
    with pytest.raises(InputError, match="pip install"):
        K4ABackend()


def test_a_k4a_nodes_recording_part_reads_as_azure_kinect_skeletons(tmp_path: Path) -> None:
    # The server's analysis reads a part's skeleton stream, which carries no joint names:
    # 32 joints must be the Azure Kinect set (it raised "unknown joint set" before).
    from app.nodes.protocol import encode_skeletons
    from app.nodes.store import NodeStore
    from app.server.analysis import read_part

    store = NodeStore(tmp_path / "K1")
    part = store.create_part("R20260101-000000-ab12")
    J = len(AZURE_KINECT_JOINTS)
    for k in range(5):
        pos = np.full((1, J, 3), 2.0, np.float32)
        pos[0, :, 0] = 0.01 * k
        part.append(k / 30, "skeleton", encode_skeletons(k, k / 30, pos,
                                                         np.full((1, J), 2, np.uint8)))
    part.close()
    s = read_part(tmp_path / "K1" / "R20260101-000000-ab12")
    assert s.joint_set.name == "azure_kinect" and s.positions.shape == (5, J, 3)
    np.testing.assert_allclose(s.joint("ANKLE_LEFT")[:, 0], 0.01 * np.arange(5), atol=1e-6)


def test_back_facing_azure_kinect_skeletons_are_unmirrored_as_kinect_v2_ones() -> None:
    # Azure Kinect body tracking also fits a person seen from behind as facing the
    # sensor (front/back flips: Azure-Kinect-Sensor-SDK issues 575, 1330); the server's
    # un-mirroring found no left/right pairs in its "_LEFT" names and did nothing.
    from app.server.analysis import unmirror_back_facing
    from engine.sim.straight_walk import synth_walk, walk_skeleton
    from engine.skeleton import AZURE_KINECT, KINECT_V2, SkeletonSeries

    w = synth_walk(n_steps=8, rate=30.0)  # walks along +x
    P2 = walk_skeleton(w)
    mirrored = P2.copy()
    for i, n in enumerate(KINECT_V2.joints):  # labels swapped, as a tracker from behind
        if n.endswith("Left"):
            mirrored[:, i] = P2[:, KINECT_V2.index(n[:-4] + "Right")]
            mirrored[:, KINECT_V2.index(n[:-4] + "Right")] = P2[:, i]
    J = len(AZURE_KINECT.joints)
    truth = np.full((len(w.times), J, 3), np.nan)
    seen = truth.copy()
    for role, name in AZURE_KINECT.roles.items():
        if role in KINECT_V2.roles:
            k2 = KINECT_V2.index(KINECT_V2.roles[role])
            truth[:, AZURE_KINECT.index(name)] = P2[:, k2]
            seen[:, AZURE_KINECT.index(name)] = mirrored[:, k2]
    states = np.full((len(w.times), J), 2, np.uint8)
    behind = np.array([-6.0, 0.0, 1.0])  # the sensor sees the subject's back
    fixed, frac = unmirror_back_facing(SkeletonSeries(w.times, seen, states, AZURE_KINECT),
                                       behind)
    assert frac > 0.9
    ok = np.isfinite(truth).all(axis=2).all(axis=0)
    moving = slice(10, -10)  # the ends take the nearest walking frame's decision
    np.testing.assert_allclose(fixed.positions[moving][:, ok], truth[moving][:, ok])
    # seen from the front, the same labels are right and nothing is swapped
    front = np.array([12.0, 0.0, 1.0])
    _, frac = unmirror_back_facing(SkeletonSeries(w.times, truth, states, AZURE_KINECT),
                                   front)
    assert frac == 0.0


# --------------------------------------------------------------------------- checked
# against the SDKs (docs/backbone.md, "What was checked against the SDKs")


def test_field_offsets_match_the_sdk_headers(stub: ctypes.CDLL) -> None:
    # k4abttypes.h 1.1: joint {float3 position, quaternion w,x,y,z, enum confidence},
    # configuration {orientation, mode, int32 gpu_device_id, const char* model_path}
    stub.stub_offsetof.restype = ctypes.c_long
    stub.stub_offsetof.argtypes = [ctypes.c_char_p]
    stub.stub_sizeof_joint.restype = stub.stub_sizeof_body.restype = ctypes.c_size_t
    J, Q, C = _k4abt.Joint, _k4abt._Quaternion, _k4abt.TrackerConfiguration
    ours = {
        "joint.position": J.position.offset,
        "joint.orientation": J.orientation.offset,
        "joint.orientation.w": J.orientation.offset + Q.w.offset,
        "joint.orientation.z": J.orientation.offset + Q.z.offset,
        "joint.confidence_level": J.confidence_level.offset,
        "config.sensor_orientation": C.sensor_orientation.offset,
        "config.processing_mode": C.processing_mode.offset,
        "config.gpu_device_id": C.gpu_device_id.offset,
        "config.model_path": C.model_path.offset,
    }
    for name, offset in ours.items():
        assert stub.stub_offsetof(name.encode()) == offset, name
    assert stub.stub_sizeof_joint() == ctypes.sizeof(J) == _k4abt._JOINT_DTYPE.itemsize
    assert stub.stub_sizeof_body() == 4 + ctypes.sizeof(_k4abt.Skeleton)  # k4abt_body_t
    # enum values of k4abttypes.h 1.1
    assert _k4abt.PROCESSING_MODES == {"gpu": 0, "cpu": 1, "cuda": 2, "tensorrt": 3,
                                       "directml": 4}
    assert (_k4abt.CONFIDENCE_NONE, _k4abt.CONFIDENCE_LOW, _k4abt.CONFIDENCE_MEDIUM,
            _k4abt.CONFIDENCE_HIGH) == (0, 1, 2, 3)


def test_body_tracking_sdk_1_0_is_refused_not_misfed(tmp_path: Path) -> None:
    # 1.0's configuration has no model_path: a 1.1 configuration passed by value would be
    # misread, so the binding refuses a libk4abt without 1.1's system-timestamp function
    cc = shutil.which("gcc") or shutil.which("cc")
    if cc is None or sys.platform == "win32":
        pytest.skip("no C compiler (gcc/cc) to build the stand-in libk4abt 1.0")
    lib = tmp_path / "libk4abt_1_0.so"
    subprocess.run([cc, "-DSTUB_K4ABT_1_0", "-shared", "-fPIC", "-O1", "-Wall", "-Werror",
                    "-o", str(lib), str(STUB_SRC)], check=True, capture_output=True,
                   timeout=60)
    with pytest.raises(_k4abt.K4ABTUnavailable, match=r"older than 1\.1") as info:
        _k4abt.load_library(lib)
    assert "libk4abt1.1-dev" in str(info.value)
    assert "libk4abt.so.1.0" not in _k4abt._candidates()


def test_pyk4a_is_opened_so_that_waiting_for_a_capture_releases_the_gil(
        stub: ctypes.CDLL, stub_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # pyk4a's thread_safe=True (its default) keeps the GIL in k4a_device_get_capture
    # (pyk4a.cpp _gil_release), which would stall the node's websocket loop
    be = backend(monkeypatch, [FakeCapture(1, 0)], stub_path)
    be.body_tracking = False
    be.open()
    assert be._k4a.thread_safe is False


def test_a_slow_first_tracking_does_not_shift_the_frame_times(
        stub: ctypes.CDLL, stub_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # capture 2 is read 1.5 s late (the tracker's first frame took that long) and has no
    # SDK host timestamp; capture 3 has one: its arrival, not the late read, counts
    for k in (1, 2, 3):
        script(stub, k, [(1, 2000.0)], 1_000_000 + 33_333 * (k - 1))
    caps = [FakeCapture(1, 1_000_000), FakeCapture(2, 1_033_333, latency_s=1.5),
            FakeCapture(3, 1_066_666, latency_s=1.4)]
    caps[2].depth_system_timestamp_nsec = round((1000.0 + 1.066666 + 0.004) * 1e9)
    be = backend(monkeypatch, caps, stub_path)
    be.open()
    gen = be.frames()
    frames = [next(gen) for _ in range(3)]
    gen.close()
    # every frame: device time + the 4 ms latency of the fastest arrival
    expect = [1000.0 + 1.0 + 0.004, 1000.0 + 1.033333 + 0.004, 1000.0 + 1.066666 + 0.004]
    np.testing.assert_allclose([f.t_local for f in frames], expect, atol=1e-6)
    assert be.warnings == []


def test_arrival_uses_the_sdk_host_timestamp_when_plausible(
        monkeypatch: pytest.MonkeyPatch) -> None:
    from app.nodes.backends.k4a import arrival_time

    fake_host_clock(monkeypatch)
    HOST["now"] = 2000.0
    cap = FakeCapture(1, 0)
    cap.depth_system_timestamp_nsec = round(1999.98 * 1e9)  # received 20 ms ago
    assert arrival_time(cap) == pytest.approx(1999.98, abs=1e-6)
    for bad in (0, round(1990.0 * 1e9), round(2000.5 * 1e9)):  # none, 10 s old, future
        cap.depth_system_timestamp_nsec = bad
        assert arrival_time(cap) == 2000.0
    del cap.depth_system_timestamp_nsec  # a pyk4a before 1.5
    assert arrival_time(cap) == 2000.0


def test_device_clock_follows_drift_and_ignores_late_frames() -> None:
    from app.nodes.backends.k4a import DeviceClock

    rng = np.random.default_rng(3)
    clock = DeviceClock()
    drift = 50e-6  # the device crystal 50 ppm fast against the host clock
    errors = []
    for k in range(30 * 120):  # two minutes at 30 fps
        true_t = 500.0 + k / 30  # host time of mid-exposure
        dev_usec = round((k / 30) * (1 + drift) * 1e6)
        latency = 0.010 + rng.exponential(0.005) + (2.0 if k % 97 == 5 else 0.0)
        t = clock.t_local(dev_usec, true_t + latency)
        errors.append(t - (true_t + 0.010))
    assert clock.warning is None
    # within a millisecond of the minimum latency, after the first frames
    assert np.max(np.abs(errors[60:])) < 1e-3
    # without the window the 50 ppm drift would have reached 6 ms by the end


def test_device_clock_never_goes_back_after_a_late_first_capture() -> None:
    """The first capture arriving 300 ms late set the offset; the next, on time, lowered it
    by 290 ms and its time came out before the first frame's (the server then dropped the
    overlapping frames). Times now only advance, and still reach the fastest latency."""
    from app.nodes.backends.k4a import DeviceClock

    clock = DeviceClock()
    times, truth = [], []
    for k in range(90):
        true_t = 200.0 + k / 30
        latency = 0.010 + (0.300 if k == 0 else 0.0) + (0.150 if k == 40 else 0.0)
        times.append(clock.t_local(round(k / 30 * 1e6), true_t + latency))
        truth.append(true_t + 0.010)
    steps = np.diff(times)
    assert np.all(steps > 0), np.flatnonzero(steps <= 0)
    # never slower than (1 - max_slew) of the device's pace
    assert np.all(steps >= (1 - clock.max_slew) / 30 - 1e-6)
    err = np.asarray(times) - np.asarray(truth)
    assert err[0] == pytest.approx(0.300, abs=1e-6)
    assert np.all(np.diff(err[:30]) <= 2e-6)  # closes in (µs rounding), never overshoots
    assert np.max(np.abs(err[30:])) < 2e-6  # converged, a late frame later moves nothing
    # a body frame stamped before its capture's previous one still comes out later
    t_prev = clock.t_local(round(90 / 30 * 1e6), 203.010)
    assert clock.t_local(round(91 / 30 * 1e6), 203.043, stamp_usec=0) > t_prev
    with pytest.raises(ValueError, match="max_slew"):
        DeviceClock(max_slew=1.0)


@pytest.mark.parametrize(("stamps", "why"), [
    ([0] * 5, "do not advance"),  # Femto on Windows without the metadata driver
    ([round(k * 1e6 / 30 / 1000) for k in range(900)], "keep pace"),  # ms, not µs
])
def test_device_clock_gives_up_timestamps_that_are_not_a_clock(
        stamps: list[int], why: str) -> None:
    from app.nodes.backends.k4a import DeviceClock

    clock = DeviceClock()
    times = [clock.t_local(u, 100.0 + k / 30) for k, u in enumerate(stamps)]
    assert clock.fallback and why in (clock.warning or "")
    assert times[-1] == pytest.approx(100.0 + (len(stamps) - 1) / 30)  # arrival times
    assert "metadata driver" in (clock.warning or "")


def test_timestamps_that_are_not_a_clock_warn_once_and_keep_streaming(
        stub: ctypes.CDLL, stub_path: Path, monkeypatch: pytest.MonkeyPatch,
        caplog: pytest.LogCaptureFixture) -> None:
    caps = [FakeCapture(k, 0) for k in (1, 2, 3)]
    for k, cap in enumerate(caps):
        cap.latency_s = 0.004 + k / 30  # arrives a frame apart, device time stuck at 0
    be = backend(monkeypatch, caps, stub_path)
    be.body_tracking = False
    be.open()
    sent: list[str] = []
    be.warning_sink = sent.append  # what the node agent sends on to the server
    with caplog.at_level(logging.WARNING, "gaitrig.node"):
        gen = be.frames()
        frames = [next(gen) for _ in range(3)]
        gen.close()
    assert len(be.warnings) == 1 and "do not advance" in be.warnings[0]
    assert sent == be.warnings  # raised after the node connected: to the Rig page too
    assert len([r for r in caplog.records if "do not advance" in r.getMessage()]) == 1
    np.testing.assert_allclose(np.diff([f.t_local for f in frames]), [1 / 30, 1 / 30])


def test_a_full_tracker_queue_is_drained_so_skeletons_come_back(
        stub: ctypes.CDLL, stub_path: Path) -> None:
    # Five pops time out (a first frame that takes seconds): three results pile up in the
    # SDK's queue (it takes three), enqueue then times out, and without popping nothing
    # would ever leave the queue again.
    lib = _k4abt.load_library(stub_path)
    tr = _k4abt.Tracker(lib, _k4abt.calibration_pointer(FakeCalibration()))
    try:
        for k in range(1, 9):
            script(stub, k, [(k, 2000.0)], 1_000_000 + 33_333 * k)
        stub.stub_delay_pops(5)
        out = [tr.track(k, 50, 1_000_000 + 33_333 * k) for k in range(1, 9)]
        assert out[:5] == [None] * 5
        got = [(f.body_ids, f.device_timestamp_usec) for f in out[5:] if f is not None]
        assert got == [([k], 1_000_000 + 33_333 * k) for k in (6, 7, 8)]  # their own
        assert stub.stub_released() == 6  # the three drained results went back too
    finally:
        tr.close()
