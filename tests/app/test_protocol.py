"""Wire protocol: round trips and rejection of malformed input."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from app.nodes.protocol import (
    DataChannel,
    Hello,
    Ping,
    Pong,
    ProtocolError,
    RecStart,
    decode_binary,
    decode_skeletons,
    dump,
    encode_binary,
    encode_skeletons,
    parse_node_message,
    parse_server_message,
)


def test_skeleton_round_trip() -> None:
    rng = np.random.default_rng(1)
    pos = rng.normal(size=(2, 25, 3)).astype(np.float32)
    st = rng.integers(0, 3, size=(2, 25)).astype(np.uint8)
    msg = encode_skeletons(7, 1234.5678, pos, st, [11, 12])
    header, payload = decode_binary(msg)
    assert header["seq"] == 7 and header["t"] == 1234.5678 and header["bodies"] == [11, 12]
    p2, s2 = decode_skeletons(header, payload)
    np.testing.assert_array_equal(p2, pos)
    np.testing.assert_array_equal(s2, st)


def test_control_round_trip() -> None:
    hello = Hello(node_id="S1", token="t" * 10)
    assert parse_node_message(dump(hello)) == hello
    pong = Pong(seq=3, t1=1.0, t2=2.0, t3=2.5)
    assert parse_node_message(dump(pong)) == pong
    cmd = RecStart(rec_id="R1", t_start_server=10.0, t_start_local=10.5)
    assert parse_server_message(dump(cmd)) == cmd
    assert parse_server_message(dump(Ping(seq=1, t1=3.0))).t1 == 3.0


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        ("not json", "not valid JSON"),
        ("[1, 2]", "JSON object"),
        (json.dumps({"type": "pong", "seq": 1}), "invalid 'pong'"),
        (json.dumps({"type": "launch"}), "invalid 'launch'"),
        (json.dumps({"v": 9, "type": "pong"}), "protocol version 9"),
        (json.dumps({"type": "hello", "node_id": "../etc", "token": "x"}), "node_id"),
    ],
)
def test_malformed_control_rejected(text: str, fragment: str) -> None:
    with pytest.raises(ProtocolError, match=fragment.replace("(", r"\(")):
        parse_node_message(text)


def test_oversized_control_rejected() -> None:
    big = json.dumps({"type": "error", "reason": "x" * 1000})
    with pytest.raises(ProtocolError, match="exceeds"):
        parse_node_message(big, limit=500)


@pytest.mark.parametrize(
    ("data", "fragment"),
    [
        (b"abc", "shorter"),
        (b"XXXX\x00\x00\x00\x00", "magic"),
        (b"GRB\x07\x00\x00\x00\x00", "version"),
        (b"GRB\x01\xff\x00\x00\x00{}", "inconsistent"),
        (encode_binary({"kind": "video"}), "kind"),
    ],
)
def test_malformed_binary_rejected(data: bytes, fragment: str) -> None:
    with pytest.raises(ProtocolError, match=fragment):
        decode_binary(data)


def test_skeleton_payload_size_checked() -> None:
    msg = encode_skeletons(1, 0.0, np.zeros((1, 25, 3)), np.zeros((1, 25)))
    header, payload = decode_binary(msg)
    with pytest.raises(ProtocolError, match="payload"):
        decode_skeletons(header, payload[:-1])
    with pytest.raises(ProtocolError, match="limit"):
        decode_binary(msg, limit=len(msg) - 1)


def test_data_channel_offer_round_trip_and_bounds() -> None:
    offer = DataChannel(req_id=4, rec_id="R1", port=8001, token="0123456789abcdef" * 2)
    assert parse_server_message(dump(offer)) == offer
    for bad, fragment in [({"token": "x" * 32}, "token"), ({"port": 0}, "port"),
                          ({"rec_id": "../R1"}, "rec_id")]:
        d = {**json.loads(dump(offer)), **bad}
        with pytest.raises(ProtocolError, match=fragment):
            parse_server_message(json.dumps(d))
    # the node's answer when it cannot open the channel is a binary 'channel' message
    header, payload = decode_binary(encode_binary({"kind": "channel", "req_id": 4,
                                                   "error": "S1: blocked"}))
    assert header["error"] == "S1: blocked" and payload == b""


def test_warning_message_and_revision_2_welcome() -> None:
    """Revision 2 of version 1: nodes send ``warning``; the server's welcome names what it
    accepts only to nodes of revision 2 (a revision-1 node's parser refuses unknown
    fields, as this one does: ``extra="forbid"``)."""
    from app.nodes.protocol import PROTOCOL_REVISION, NodeWarning, Welcome

    assert Hello(node_id="S1", token="t").protocol == PROTOCOL_REVISION >= 2
    w = NodeWarning(text="Body tracking stopped: no GPU", t=12.5, repeats=3)
    assert parse_node_message(dump(w)) == w
    cut = parse_node_message(dump(NodeWarning(text="x" * 2000, t=1.0)))
    assert len(cut.text) == 500 and cut.text.endswith("…")
    for bad, fragment in [({"text": ""}, "text"), ({"repeats": 0}, "repeats"),
                          ({"t": "soon"}, "t"), ({"level": "error"}, "level")]:
        with pytest.raises(ProtocolError, match=fragment):
            parse_node_message(json.dumps({**json.loads(dump(w)), **bad}))
    plain = json.loads(dump(Welcome(server_time=1.0, ping_interval_s=0.1)))
    assert set(plain) == {"v", "type", "server_time", "ping_interval_s"}  # as revision 1
    later = Welcome(server_time=1.0, ping_interval_s=0.1, accepts=["warning", "later-kind"])
    assert parse_server_message(dump(later)).accepts == ["warning", "later-kind"]
    # a revision-1 node's welcome, as it was: the plain one passes, one with accepts not
    from typing import Literal

    from pydantic import BaseModel, ConfigDict, ValidationError

    class WelcomeRevision1(BaseModel):
        model_config = ConfigDict(extra="forbid")
        v: Literal[1] = 1
        type: Literal["welcome"] = "welcome"
        server_time: float
        ping_interval_s: float

    WelcomeRevision1.model_validate(plain)
    with pytest.raises(ValidationError, match="accepts"):
        WelcomeRevision1.model_validate(json.loads(dump(later)))


K_DEPTH = [[365.0, 0.0, 255.5], [0.0, 365.0, 211.5], [0.0, 0.0, 1.0]]
LENS = [-0.12, 0.03, 0.0008, -0.0005, 0.0]


def test_sensor_lens_message_and_revision_3_welcome() -> None:
    """Revision 3: a node announces its cameras' lenses (``sensor_lens``) after a welcome
    that accepts it. Malformed lenses are refused by the checks a calibration capture's
    camera model gets; a revision-2 node still parses the revision-3 welcome (it names a
    message it does not know) and a revision-3 node sends no lens to a revision-2 server
    (its welcome does not accept one)."""
    from app.nodes.protocol import (
        ACCEPTED_NODE_MESSAGES,
        PROTOCOL_REVISION,
        CameraLens,
        SensorInfo,
        SensorLens,
        Welcome,
        lens_mismatch,
    )
    from app.server.hub import _welcome

    assert PROTOCOL_REVISION == 3 and "sensor_lens" in ACCEPTED_NODE_MESSAGES
    lens = SensorLens(source="factory calibration",
                      depth=CameraLens(size=(512, 424), K=K_DEPTH, dist=LENS))
    assert parse_node_message(dump(lens)) == lens
    good = json.loads(dump(lens))
    for bad, fragment in [({"dist": [0.1, 0.2, 0.3]}, "4, 5, 8, 12 or 14"),
                          ({"dist": [0.1] * 15}, "dist"),
                          ({"K": [[365.0, 0.0], [0.0, 365.0]]}, "K"),
                          ({"K": [[-1.0, 0, 1], [0, 365.0, 1], [0, 0, 1]]}, "focal"),
                          ({"size": [0, 424]}, "size"), ({"size": [512]}, "size"),
                          ({"model": "brown"}, "model")]:
        with pytest.raises(ProtocolError, match=fragment):
            parse_node_message(json.dumps({**good, "depth": {**good["depth"], **bad}}))
    # NaN and infinity are JSON to Python's parser: refused too
    nan = dump(lens).replace("-0.12", "NaN")
    with pytest.raises(ProtocolError, match="finite"):
        parse_node_message(nan)
    inf_k = dump(lens).replace("365.0", "Infinity", 1)
    with pytest.raises(ProtocolError, match="finite"):
        parse_node_message(inf_k)
    # no lens (an ideal one) is an empty list
    assert parse_node_message(json.dumps({**good, "depth": {**good["depth"], "dist": []}})
                              ).depth.dist == []
    # it must describe the hello's cameras
    hello_sensor = SensorInfo(depth_size=(512, 424), depth_K=K_DEPTH)
    assert lens_mismatch(lens, hello_sensor) is None
    assert "512×424" in str(lens_mismatch(lens, SensorInfo(depth_size=(640, 576),
                                                           depth_K=K_DEPTH)))
    other_K = [[380.0, 0.0, 255.5], [0.0, 380.0, 211.5], [0.0, 0.0, 1.0]]
    assert "K" in str(lens_mismatch(lens, SensorInfo(depth_K=other_K)))
    assert "no depth intrinsics" in str(lens_mismatch(lens, SensorInfo()))

    # both directions of compatibility, by what each side parses and sends
    from typing import Literal

    from pydantic import BaseModel, ConfigDict

    class WelcomeRevision2(BaseModel):  # as a revision-2 node parses it
        model_config = ConfigDict(extra="forbid")
        v: Literal[1] = 1
        type: Literal["welcome"] = "welcome"
        server_time: float
        ping_interval_s: float
        accepts: list[str] | None = None

    settings = SimpleNamespace(clock_ping_interval_s=0.1)
    for revision in (2, 3):  # a revision-2 node takes the new welcome, ignoring the name
        w = json.loads(dump(_welcome(settings, revision)))  # type: ignore[arg-type]
        assert WelcomeRevision2.model_validate(w).accepts == ["warning", "sensor_lens"]
    assert "accepts" not in json.loads(dump(_welcome(settings, 1)))  # type: ignore[arg-type]
    # a revision-2 server's parser (this one without sensor_lens) refuses the message:
    # which is why a node sends it only to a welcome that accepts it (tested end to end
    # in tests/integration/test_node_lens.py)
    assert parse_server_message(dump(Welcome(server_time=1.0, ping_interval_s=0.1,
                                             accepts=["warning"]))).accepts == ["warning"]


def test_backend_announces_its_lenses() -> None:
    """A backend announces each camera whose intrinsics it knows, with its lens; one that
    knows none (a replay) announces nothing."""
    from app.nodes.backends.base import Backend
    from app.nodes.protocol import SensorInfo

    class Fake(Backend):
        lens_source = "factory calibration"

        def open(self) -> SensorInfo:
            return SensorInfo()

        def frames(self):  # type: ignore[no-untyped-def]
            return iter(())

        def now(self) -> float:
            return 0.0

    b = Fake()
    assert b.sensor_lens(SensorInfo()) is None
    b.depth_dist = LENS
    lens = b.sensor_lens(SensorInfo(depth_size=(640, 576), depth_K=K_DEPTH, color_K=K_DEPTH,
                                    color_size=(640, 576)))
    assert lens is not None and lens.source == "factory calibration"
    assert lens.depth is not None and lens.depth.dist == LENS and lens.depth.size == (640, 576)
    assert lens.color is not None and lens.color.dist == []  # an ideal colour lens
    assert parse_node_message(dump(lens)) == lens


def test_a_k4a_node_announces_its_factory_lens(monkeypatch: pytest.MonkeyPatch) -> None:
    """An Azure Kinect node (pyk4a faked) announces the depth camera's factory lens in
    OpenCV's order (the SDK stores p2 before p1), at the depth image's size and K."""
    import sys

    from app.nodes.backends.k4a import K4ABackend, distortion_from_k4a_params
    from tests.app.test_k4abt import FakeCalibration, fake_pyk4a

    # the SDK's raw parameters: cx, cy, fx, fy, k1..k6, codx, cody, p2, p1, radius
    raw = [320.0, 288.0, 504.0, 504.0, 0.5, -0.03, 0.001, 0.8, 0.02, 0.004, 0.0, 0.0,
           -0.0002, 0.0007, 1.7]
    monkeypatch.setattr(FakeCalibration, "get_distortion_coefficients",  # as pyk4a ≥ 1.2
                        lambda self, kind: np.array(distortion_from_k4a_params(raw)),
                        raising=False)
    monkeypatch.setitem(sys.modules, "pyk4a", fake_pyk4a([]))
    be = K4ABackend(body_tracking=False)
    info = be.open()
    lens = be.sensor_lens(info)
    assert lens is not None and lens.source == "factory calibration"
    assert lens.depth is not None and lens.depth.size == (640, 576) == info.depth_size
    assert info.depth_K == lens.depth.K
    assert lens.depth.dist == [0.5, -0.03, 0.0007, -0.0002, 0.001, 0.8, 0.02, 0.004]
    assert parse_node_message(dump(lens)) == lens
