"""Wire protocol: round trips and rejection of malformed input."""

from __future__ import annotations

import json

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

    assert Hello(node_id="S1", token="t").protocol == PROTOCOL_REVISION == 2
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
