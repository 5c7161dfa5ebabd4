"""The raw TCP data channel of a transfer: chunk bytes without websocket framing.

The websocket stays the control path (authenticated node session, manifest, the offer of
a channel); the chunk bytes take a plain TCP connection because a websocket costs the
server an unmasking pass and several copies of every byte (node → server frames are
masked), which on two cores made the transfer a fifth of a file copy.

Wire format (all integers little-endian):

* node → server, once: :data:`HELLO_MAGIC` + the 32-character one-time token the server
  offered over the websocket + ``\\n`` (40 bytes). An unknown, used or expired token
  makes the server close the connection.
* server → node: requests ``b"RQST"`` + uint32 length + JSON ``{"file", "indices"}``
  (≤ :data:`MAX_REQUEST` bytes, ≤ :data:`MAX_BATCH` indices, each in the manifest);
  ``b"DONE"`` + 0 ends the channel.
* node → server, per requested index in order: ``b"CHNK"`` + uint32 index + uint32
  status (0 ok, 1 error) + uint64 length, then the chunk (``sendfile`` from the part
  file) or, on error, a UTF-8 reason (≤ :data:`MAX_ERROR` bytes; the rest of that
  request is skipped).

The server receives each chunk in pieces into one small buffer (``recv_into``), hashes
and ``pwrite``-s each piece at once and commits the chunk when its SHA-256 matches
(:func:`pull_channel`): one hash pass and one copy into the page cache per byte.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import socket
import struct
from collections.abc import Callable
from pathlib import Path

from app.transfer._errors import (
    CorruptChunkError,
    IncompleteTransferError,
    ManifestError,
    TransferError,
)
from app.transfer._manifest import Manifest, safe_relative_path
from app.transfer._sink import TransferSink
from engine.wording import count

log = logging.getLogger("gaitrig.transfer")

HELLO_MAGIC = b"GRDC/1 "
TOKEN_CHARS = 32
HELLO_LEN = len(HELLO_MAGIC) + TOKEN_CHARS + 1
MAX_REQUEST = 64 * 1024
MAX_BATCH = 1024
MAX_ERROR = 4096
#: Bytes received, hashed and written at a time on the server: small enough to stay in
#: the core's cache between the three steps.
PIECE = 256 * 1024
_REQ = struct.Struct("<4sI")
_CHK = struct.Struct("<4sIIQ")
_OK, _ERR = 0, 1

ProgressCallback = Callable[[int, int], None]
#: Node-side test hook called before each chunk is sent: ``(file, index)`` → True to
#: send it with one byte flipped; it may sleep or raise ``ConnectionError`` (cut).
ChunkHook = Callable[[str, int], bool]


def hello(token: str) -> bytes:
    """The node's first bytes on a data channel."""
    if len(token) != TOKEN_CHARS or not token.isascii() or not token.isalnum():
        raise TransferError("a data channel token is 32 ASCII letters or digits")
    return HELLO_MAGIC + token.encode("ascii") + b"\n"


def parse_hello(data: bytes) -> str | None:
    """The token of a node's hello, or None when it is not one."""
    if len(data) != HELLO_LEN or not data.startswith(HELLO_MAGIC) or data[-1:] != b"\n":
        return None
    token = data[len(HELLO_MAGIC):-1]
    return token.decode("ascii") if token.isascii() and token.isalnum() else None


def set_timeout(sock: socket.socket, seconds: float) -> None:
    """Make ``sock`` blocking with a kernel receive/send timeout.

    A Python-level ``settimeout`` would make every call a poll + non-blocking call; a
    blocking socket lets ``recv_into(..., MSG_WAITALL)`` take a whole chunk in one call,
    and ``SO_RCVTIMEO``/``SO_SNDTIMEO`` still bound a dead peer.
    """
    sock.settimeout(None)
    secs = max(1, int(seconds))
    tv = struct.pack("ll", secs, 0)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO, tv)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDTIMEO, tv)
    if sock.family in (socket.AF_INET, socket.AF_INET6):
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)


def recv_exact(sock: socket.socket, view: memoryview) -> None:
    """Fill ``view`` from ``sock``.

    Raises:
        ConnectionError: the peer closed the connection first.
        OSError: the socket failed or timed out.
    """
    while view:
        n = sock.recv_into(view, len(view), socket.MSG_WAITALL)
        if n == 0:
            raise ConnectionError("the data channel was closed mid-message")
        view = view[n:]


# ---------------------------------------------------------------------------- server


def _send_request(sock: socket.socket, name: str, indices: list[int]) -> None:
    body = json.dumps({"file": name, "indices": indices}, separators=(",", ":")).encode()
    sock.sendall(_REQ.pack(b"RQST", len(body)) + body)


def pull_channel(sink: TransferSink, sock: socket.socket, *, retries: int = 3,
                 on_progress: ProgressCallback | None = None,
                 share: tuple[int, int] = (0, 1)) -> None:
    """Fetch every missing chunk of ``sink`` over a data channel (blocking; run it in a
    thread). Does not finalize: the caller calls :meth:`TransferSink.finalize`.

    Each chunk streams through one :data:`PIECE`-sized buffer: received, fed to the
    chunk's SHA-256 and written in place while it is still in this core's cache, then
    committed if the digest matches (:meth:`TransferSink.commit_chunk`). One thread does
    all three on purpose: handing 4 MiB buffers to a hashing/writing thread made the
    server read them back from another core's cache or from memory, three times the CPU
    of this loop; the parallelism comes from several channels (``share``) and parts,
    each with its own thread.

    Args:
        sink: the receiving part folder (already resumed: only missing chunks fetched).
        sock: the connected, authenticated channel (blocking, see :func:`set_timeout`).
        retries: extra rounds for chunks that arrived corrupt.
        on_progress: called with ``(bytes_done, bytes_total)`` after every chunk.
        share: ``(k, n)``: fetch only the chunks whose index is ``k`` modulo ``n`` (``n``
            channels of one part, each in its own thread, use both cores of the server
            even when a single node sends).

    Raises:
        IncompleteTransferError: chunks still corrupt after ``retries`` rounds, or a file's
            hash list differs.
        StorageFullError: the server disk is full.
        ConnectionError, OSError: the channel broke or the node reported an error (the
            verified chunks are kept; the caller retries or falls back).
    """
    total = sink.manifest.total_bytes
    cs = sink.manifest.chunk_size
    k_share, n_share = share
    if not 0 <= k_share < n_share:
        raise ValueError(f"share {share} must be (k, n) with 0 <= k < n")
    piece = memoryview(bytearray(min(PIECE, cs)))
    head = memoryview(bytearray(_CHK.size))
    corrupt: list[CorruptChunkError] = []
    fds: dict[str, int] = {}
    try:
        for _round in range(retries + 1):
            todo: dict[str, list[int]] = {}
            for name, idx in sink.missing_chunks():
                if idx % n_share == k_share:
                    todo.setdefault(name, []).append(idx)
            if not todo:
                break
            corrupt.clear()
            requests = [(name, idxs[k:k + MAX_BATCH]) for name, idxs in todo.items()
                        for k in range(0, len(idxs), MAX_BATCH)]
            # Two requests outstanding: the node starts the next one without waiting for
            # a round trip, and requests stay far below the socket buffers.
            sent = 0
            for name, idxs in requests[:2]:
                _send_request(sock, name, idxs)
                sent += 1
            for r, (name, idxs) in enumerate(requests):
                if name not in fds:
                    fds[name] = sink.open_part(name)
                fd = fds[name]
                for j, idx in enumerate(idxs):
                    recv_exact(sock, head)
                    magic, index, status, length = _CHK.unpack(head)
                    if magic != b"CHNK" or index != idx:
                        raise ConnectionError(
                            f"data channel out of step (expected chunk {idx} of {name!r})")
                    if status != _OK:
                        if length > MAX_ERROR:
                            raise ConnectionError("node error message too long")
                        msg = bytearray(length)
                        recv_exact(sock, memoryview(msg))
                        raise ConnectionError(msg.decode("utf-8", "replace"))
                    expected = sink.chunk_len(name, idx)
                    if length != expected:
                        raise ConnectionError(
                            f"node announced {length} bytes for chunk {idx} of {name!r}, "
                            f"the manifest says {expected}")
                    h = hashlib.sha256()
                    off, left = idx * cs, length
                    while left:
                        v = piece[:min(left, len(piece))]
                        recv_exact(sock, v)
                        h.update(v)
                        sink.write_at(fd, name, off, v)
                        off += len(v)
                        left -= len(v)
                    if j == 0 and sent < len(requests):
                        _send_request(sock, *requests[sent])
                        sent += 1
                    try:
                        sink.commit_chunk(name, idx, h.digest(), length)
                    except CorruptChunkError as exc:
                        corrupt.append(exc)
                        log.warning("%s; fetching it again", exc)
                    if on_progress is not None:
                        on_progress(sink.bytes_done, total)
                if r + 1 == len(requests) or requests[r + 1][0] != name:
                    os.close(fds.pop(name))
                    # flushed now if complete (else by the channel that completes it, or
                    # after a retry, or in finalize)
                    sink.seal_file(name)
    finally:
        for fd in fds.values():
            os.close(fd)
    missing = [(n, i) for n, i in sink.missing_chunks() if i % n_share == k_share]
    if missing:
        last = corrupt[-1] if corrupt else None
        raise IncompleteTransferError(
            f"{count(len(missing), 'chunk')} could not be fetched intact after "
            f"{count(retries + 1, 'round')} (first: {missing[0][0]!r} #{missing[0][1]}), "
            f"last error: {last}")


def end_channel(sock: socket.socket) -> None:
    """Tell the node the channel is no longer needed (best effort)."""
    with contextlib.suppress(OSError):
        sock.sendall(_REQ.pack(b"DONE", 0))


# ---------------------------------------------------------------------------- node


def _parse_request(body: bytes) -> tuple[str, list[int]]:
    try:
        d = json.loads(body)
        name, indices = d["file"], d["indices"]
    except (ValueError, KeyError, TypeError) as exc:
        raise ManifestError(f"malformed data channel request: {exc}") from exc
    if (not isinstance(name, str) or not isinstance(indices, list) or not indices
            or len(indices) > MAX_BATCH
            or not all(isinstance(i, int) and not isinstance(i, bool) for i in indices)):
        raise ManifestError("a data channel request names a file and 1-1024 chunk indices")
    return name, indices


def _send_error(sock: socket.socket, idx: int, reason: str) -> None:
    msg = reason.encode("utf-8", "replace")[:MAX_ERROR]
    sock.sendall(_CHK.pack(b"CHNK", idx & 0xFFFFFFFF, _ERR, len(msg)) + msg)


def serve_channel(sock: socket.socket, root: str | Path, manifest: Callable[[], Manifest],
                  hook: ChunkHook | None = None) -> None:
    """Answer the server's requests on a data channel until it ends it (node side,
    blocking; run it in a thread). Chunks go out with ``sendfile`` from the part files.

    Args:
        sock: the connected channel, hello already sent (blocking, :func:`set_timeout`).
        root: the part's folder.
        manifest: returns the part's manifest (the one the server was given).
        hook: test hook, see :data:`ChunkHook`.

    Raises:
        ConnectionError, OSError: the channel broke.
        ManifestError: the server sent a malformed request (the channel is closed).
    """
    root = Path(root)
    head = memoryview(bytearray(_REQ.size))
    while True:
        recv_exact(sock, head)
        magic, n = _REQ.unpack(head)
        if magic == b"DONE":
            return
        if magic != b"RQST" or n > MAX_REQUEST:
            raise ManifestError("the server sent a malformed data channel request")
        body = bytearray(n)
        recv_exact(sock, memoryview(body))
        name, indices = _parse_request(bytes(body))
        m = manifest()
        try:
            entry = m.file(name)
            fh = open(root / safe_relative_path(name), "rb")  # noqa: SIM115 - closed below
        except (ManifestError, OSError) as exc:
            _send_error(sock, indices[0], str(exc))
            continue
        with fh:
            size = os.fstat(fh.fileno()).st_size
            for idx in indices:
                if not 0 <= idx < entry.chunk_count():
                    _send_error(sock, idx, f"{name!r} has no chunk {idx}")
                    break
                off = idx * m.chunk_size
                length = max(0, min(m.chunk_size, entry.size - off))
                if size < off + length:
                    _send_error(sock, idx, f"{name!r} is shorter than its manifest says "
                                f"(chunk {idx}); describe the part again")
                    break
                flip = hook(name, idx) if hook is not None else False
                head_out = _CHK.pack(b"CHNK", idx, _OK, length)
                if flip and length:
                    data = bytearray(os.pread(fh.fileno(), length, off))
                    data[0] ^= 0xFF
                    sock.sendall(head_out + bytes(data))
                    continue
                # MSG_MORE: the header leaves with the chunk's first segment
                sock.sendall(head_out, socket.MSG_MORE)
                sent = 0
                while sent < length:
                    k = os.sendfile(sock.fileno(), fh.fileno(), off + sent, length - sent)
                    if k == 0:
                        raise ConnectionError(f"{name!r} shrank while it was being sent")
                    sent += k


def connect_channel(host: str, port: int, token: str, timeout_s: float = 5.0
                    ) -> socket.socket:
    """Open a data channel to the server and present ``token`` (node side).

    Raises:
        OSError: the server's data port cannot be reached (e.g. a firewall).
    """
    sock = socket.create_connection((host, port), timeout=timeout_s)
    try:
        set_timeout(sock, 120.0)
        sock.sendall(hello(token))
    except BaseException:
        sock.close()
        raise
    return sock

