"""The raw TCP data channel: round trip, corrupt chunk, cut channel, node errors, disk
full, the hash list, and the server's one-time tokens."""

from __future__ import annotations

import asyncio
import hashlib
import json
import socket
import threading
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from app.server.transfer import CHANNEL_OFFER_S, TransferManager, _Offer
from app.transfer import (
    CorruptChunkError,
    IncompleteTransferError,
    Manifest,
    ManifestError,
    StorageFullError,
    TransferSink,
    build_manifest,
    chunk_list_sha256,
    end_channel,
    pull_channel,
    serve_channel,
    set_timeout,
)
from app.transfer._channel import HELLO_LEN, hello, parse_hello
from tests.app.transfer._parts import make_part, sha

CHUNK = 64 * 1024


@pytest.fixture()
def part(tmp_path: Path) -> tuple[Path, Manifest]:
    src = tmp_path / "node"
    # chunks larger than the server's 256 KiB receive piece, an uneven tail, an empty file
    make_part(src, {"frames.bin": 3 * (512 << 10) + 12_345, "meta.json": 200, "e.txt": 0})
    return src, build_manifest(src, "rec-1", "S1", chunk_size=512 << 10)


def _tcp_pair() -> tuple[socket.socket, socket.socket]:
    """A loopback TCP connection (what the channel runs on; sendfile needs a socket)."""
    with socket.create_server(("127.0.0.1", 0)) as ls:
        client = socket.create_connection(ls.getsockname())
        server, _ = ls.accept()
    return server, client


class _Node:
    """serve_channel in a thread on one end of a loopback connection."""

    def __init__(self, src: Path, manifest: Manifest, hook: Any = None) -> None:
        self.server, node = _tcp_pair()
        for s in (self.server, node):
            set_timeout(s, 10)
        self.error: BaseException | None = None

        def run() -> None:
            try:
                serve_channel(node, src, lambda: manifest, hook)
            except BaseException as exc:
                self.error = exc
            finally:
                node.close()

        self.thread = threading.Thread(target=run, daemon=True)
        self.thread.start()

    def close(self) -> None:
        end_channel(self.server)
        self.server.close()
        self.thread.join(10)


def test_channel_round_trip_identical_checksums(tmp_path: Path, part) -> None:
    src, manifest = part
    dest = tmp_path / "server"
    node = _Node(src, manifest)
    seen: list[tuple[int, int]] = []
    sink = TransferSink(dest, manifest)
    pull_channel(sink, node.server, on_progress=lambda d, t: seen.append((d, t)))
    node.close()
    sink.finalize()
    for f in manifest.files:
        assert sha(dest / f.name) == sha(src / f.name) == f.sha256
    assert seen[-1] == (manifest.total_bytes, manifest.total_bytes)
    # the manifest says which digest is which, and the hash list is over the chunk digests
    written = json.loads((dest / "manifest.json").read_text())
    assert set(written["hashes"]) == {"sha256", "chunk_sha256", "chunk_list_sha256"}
    f = manifest.file("frames.bin")
    assert f.chunk_list_sha256 == hashlib.sha256(
        b"".join(bytes.fromhex(h) for h in f.chunk_sha256)).hexdigest()
    assert node.error is None


def test_two_channels_share_one_part(tmp_path: Path, part) -> None:
    """Two channels, each in its own thread, fetch the even and the odd chunks."""
    src, manifest = part
    sent: list[list[tuple[str, int]]] = [[], []]
    nodes = [_Node(src, manifest, lambda n, i, k=k: sent[k].append((n, i)) is None and False)
             for k in range(2)]
    sink = TransferSink(tmp_path / "dest", manifest)
    threads = [threading.Thread(target=pull_channel, args=(sink, nodes[k].server),
                                kwargs={"share": (k, 2)}) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    for node in nodes:
        node.close()
    assert all(i % 2 == 0 for _, i in sent[0]) and all(i % 2 == 1 for _, i in sent[1])
    assert sent[1]  # both channels carried chunks
    sink.finalize()
    for f in manifest.files:
        assert sha(tmp_path / "dest" / f.name) == f.sha256
    with pytest.raises(ValueError, match="share"):
        pull_channel(sink, nodes[0].server, share=(2, 2))


def test_channel_corrupt_chunk_is_refetched(tmp_path: Path, part) -> None:
    src, manifest = part
    sent: list[tuple[str, int]] = []

    def flip_once(name: str, idx: int) -> bool:
        sent.append((name, idx))
        return (name, idx) == ("frames.bin", 1) and sent.count((name, idx)) == 1

    node = _Node(src, manifest, flip_once)
    sink = TransferSink(tmp_path / "dest", manifest)
    pull_channel(sink, node.server)
    node.close()
    assert sent.count(("frames.bin", 1)) == 2  # rejected, then fetched again
    sink.finalize()
    assert sha(tmp_path / "dest" / "frames.bin") == manifest.file("frames.bin").sha256


def test_channel_always_corrupt_stays_incomplete(tmp_path: Path, part) -> None:
    src, manifest = part
    node = _Node(src, manifest, lambda name, idx: (name, idx) == ("frames.bin", 2))
    sink = TransferSink(tmp_path / "dest", manifest)
    with pytest.raises(IncompleteTransferError, match="could not be fetched intact"):
        pull_channel(sink, node.server, retries=2)
    node.close()
    assert sink.missing_chunks() == [("frames.bin", 2)]
    with pytest.raises(IncompleteTransferError, match="missing"):
        sink.finalize()
    assert not TransferSink.is_complete(tmp_path / "dest")


def test_channel_cut_mid_transfer_then_resume(tmp_path: Path, part) -> None:
    src, manifest = part
    dest = tmp_path / "dest"

    def cut(name: str, idx: int) -> bool:
        if (name, idx) == ("frames.bin", 2):
            raise ConnectionAbortedError("cable pulled")
        return False

    node = _Node(src, manifest, cut)
    with pytest.raises((ConnectionError, OSError)):
        pull_channel(TransferSink(dest, manifest), node.server)
    node.close()
    assert not TransferSink.is_complete(dest)
    resumed = TransferSink(dest, manifest)  # a new sink re-hashes what is on disk
    # what arrived before the cut is kept (chunks still in flight may be lost with it)
    assert ("e.txt", 0) not in resumed.missing_chunks()
    assert ("frames.bin", 2) in resumed.missing_chunks()
    node = _Node(src, manifest)
    pull_channel(resumed, node.server)
    node.close()
    resumed.finalize()
    for f in manifest.files:
        assert sha(dest / f.name) == f.sha256


def test_channel_node_error_is_reported(tmp_path: Path, part) -> None:
    src, manifest = part
    (src / "frames.bin").write_bytes(b"short")  # changed behind the manifest's back
    node = _Node(src, manifest)
    with pytest.raises(ConnectionError, match="shorter than its manifest"):
        pull_channel(TransferSink(tmp_path / "dest", manifest), node.server)
    node.close()


def test_channel_disk_full_stops_with_clear_error(tmp_path: Path, part,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    src, manifest = part
    sink = TransferSink(tmp_path / "dest", manifest)

    def full(*_a: object) -> None:
        raise StorageFullError("server disk is full while writing 'frames.bin'; free space")

    monkeypatch.setattr(sink, "write_at", full)
    node = _Node(src, manifest)
    with pytest.raises(StorageFullError, match="disk is full"):
        pull_channel(sink, node.server)
    node.close()
    assert sink.bytes_done == 0 and not TransferSink.is_complete(tmp_path / "dest")


def test_node_refuses_malformed_requests(tmp_path: Path, part) -> None:
    src, manifest = part
    node = _Node(src, manifest)
    body = b'{"file": "frames.bin"}'
    node.server.sendall(b"RQST" + len(body).to_bytes(4, "little") + body)
    node.thread.join(10)
    assert isinstance(node.error, ManifestError)
    node.close()
    node = _Node(src, manifest)
    node.server.sendall(b"RQST" + (1 << 20).to_bytes(4, "little"))  # oversized
    node.thread.join(10)
    assert isinstance(node.error, ManifestError)
    node.close()


def test_hash_list_mismatch_is_refused(tmp_path: Path, part) -> None:
    src, manifest = part
    f = manifest.file("frames.bin")
    d = json.loads(manifest.to_json())
    d["files"][[x["name"] for x in d["files"]].index("frames.bin")]["chunk_list_sha256"] = (
        "0" * 64)
    with pytest.raises(ManifestError, match="chunk_list_sha256"):
        Manifest.from_json(json.dumps(d))
    # an old manifest without the field gets it derived from the chunk digests
    for x in d["files"]:
        del x["chunk_list_sha256"]
    assert Manifest.from_json(json.dumps(d)).file("frames.bin").chunk_list_sha256 == (
        chunk_list_sha256([bytes.fromhex(h) for h in f.chunk_sha256]))
    # a verified chunk recorded with another digest (cannot happen through commit_chunk)
    # is caught by the file check: the file is never sealed
    sink = TransferSink(tmp_path / "dest", manifest)
    for i in range(f.chunk_count()):
        data = (src / "frames.bin").read_bytes()[i * manifest.chunk_size:
                                                 (i + 1) * manifest.chunk_size]
        sink.write_chunk("frames.bin", i, data)
    sink._chunk_digests["frames.bin"][0] = b"\0" * 32
    with pytest.raises(IncompleteTransferError, match="hash list"):
        sink.seal_file("frames.bin")


def test_commit_chunk_checks_size_and_digest(tmp_path: Path, part) -> None:
    src, manifest = part
    sink = TransferSink(tmp_path / "dest", manifest)
    data = (src / "meta.json").read_bytes()
    with pytest.raises(CorruptChunkError, match="bytes, expected"):
        sink.commit_chunk("meta.json", 0, hashlib.sha256(data).digest(), len(data) - 1)
    with pytest.raises(CorruptChunkError, match="SHA-256"):
        sink.commit_chunk("meta.json", 0, b"\1" * 32, len(data))
    assert sink.missing_chunks().count(("meta.json", 0)) == 1


def test_hello_format() -> None:
    token = "a" * 32
    assert len(hello(token)) == HELLO_LEN
    assert parse_hello(hello(token)) == token
    assert parse_hello(b"GET / HTTP/1.1\r\n" + b"x" * 24) is None
    assert parse_hello(hello(token)[:-1] + b"x") is None


class _Registry:
    def get(self, _node_id: str) -> None:
        return None


def test_server_tokens_are_single_use_and_bound(tmp_path: Path) -> None:
    """Unknown tokens are closed; a valid one hands the socket over exactly once."""

    async def scenario() -> None:
        tm = TransferManager(_Registry(), None, tmp_path, data_port=0)  # type: ignore[arg-type]
        port = tm._listen()
        assert port
        loop = asyncio.get_running_loop()

        async def connect(payload: bytes) -> socket.socket:
            s = socket.socket()
            s.setblocking(False)
            await loop.sock_connect(s, ("127.0.0.1", port))
            await loop.sock_sendall(s, payload)
            return s

        async def closed_by_server(s: socket.socket) -> bool:
            try:
                got = await asyncio.wait_for(loop.sock_recv(s, 1), 5)
            except (ConnectionError, OSError):
                return True
            finally:
                s.close()
            return got == b""

        assert await closed_by_server(await connect(hello("b" * 32)))  # never offered
        # bytes that cannot begin a hello: closed at once, well before the 5 s timeout
        assert await closed_by_server(await connect(b"garbage\n"))
        token = "c" * 32
        fut: asyncio.Future[socket.socket] = loop.create_future()
        tm._offers[token] = _Offer("S1", "rec-1", loop.time() + 1e9, fut)
        # the expiry is on the monotonic clock, like the one the handshake compares with
        tm._offers[token].expires = __import__("time").monotonic() + CHANNEL_OFFER_S
        client = await connect(hello(token))
        conn = await asyncio.wait_for(fut, 5)
        assert token not in tm._offers
        conn.sendall(b"ok")
        assert await asyncio.wait_for(loop.sock_recv(client, 2), 5) == b"ok"
        conn.close()
        client.close()
        assert await closed_by_server(await connect(hello(token)))  # used
        expired = "d" * 32
        tm._offers[expired] = _Offer("S1", "rec-1", 0.0, loop.create_future())
        assert await closed_by_server(await connect(hello(expired)))
        await tm.close()

    asyncio.run(scenario())


def test_taken_transfer_port_falls_back_to_a_free_one(tmp_path: Path,
                                                      caplog: pytest.LogCaptureFixture) -> None:
    async def scenario() -> tuple[int | None, int]:
        with socket.create_server(("127.0.0.1", 0)) as taken:
            busy = taken.getsockname()[1]
            tm = TransferManager(_Registry(), None, tmp_path,  # type: ignore[arg-type]
                                 data_port=busy)
            port = tm._listen()
            await tm.close()
        return port, busy

    port, busy = asyncio.run(scenario())
    assert port is not None and port != busy
    assert f"transfer port {busy} is taken" in caplog.text
    # no data port configured: the websocket only
    assert TransferManager(_Registry(), None, tmp_path)._listen() is None  # type: ignore[arg-type]


def test_node_on_wss_declines_the_unencrypted_channel(tmp_path: Path) -> None:
    """Health data must not leave an encrypted link: the node answers why, and the
    server then uses the websocket."""
    from app.nodes.agent import NodeAgent
    from app.nodes.protocol import DataChannel, decode_binary

    # the channel offer needs no sensor: a bare object stands in for the backend (the
    # agent only hands it its warning sink)
    agent = NodeAgent("S1", SimpleNamespace(),  # type: ignore[arg-type]
                      "wss://server.example:8000/ws/node", "token-12345", tmp_path)
    sent: list[bytes] = []

    class _WS:
        async def send(self, data: bytes) -> None:
            sent.append(data)

    offer = DataChannel(req_id=7, rec_id="R1", port=8001, token="a" * 32)
    try:
        asyncio.run(agent._serve_data_channel(_WS(), offer))  # type: ignore[arg-type]
    finally:
        agent._pool.shutdown()
    header, _ = decode_binary(sent[0])
    assert header["kind"] == "channel" and header["req_id"] == 7
    assert "not encrypted" in header["error"] and "wss://" in header["error"]
