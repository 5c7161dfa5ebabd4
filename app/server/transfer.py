"""Pulling recording parts from the nodes into the server's data folder.

Over the node websocket: ``manifest_request`` → binary ``manifest`` (the node hashes the
closed part with :func:`app.transfer.build_manifest`). Then the chunk bytes: the server
offers a raw TCP data channel (``data_channel``: its data port and a one-time token bound
to this node and part, valid :data:`CHANNEL_OFFER_S`), the node connects and presents the
token, and :func:`app.transfer.pull_channel` requests the missing chunks on it. When no
channel opens (firewall, a node on ``wss://``, an older node) or it keeps breaking, the
chunks come over the websocket instead (``chunk_request`` → binary ``chunk``,
:func:`app.transfer.pull`). Either way every chunk and every file is checked against
the manifest and an interrupted transfer resumes, so a part is accepted only complete
and intact. Parts land in ``<data_dir>/recordings/<rec_id>/<node_id>/``
(``manifest.json`` beside the files).

Deleting a recording on the server also deletes the nodes' copies (health data: a
deletion must be real): ``delete_part`` → the node removes its part and answers
``deleted`` on the same request channel. Nodes that are offline are asked when they
reconnect; the pending deletions survive a server restart in
``<data_dir>/node_deletions.json``.

A part verified on the server is announced to its node (``part_verified`` with the
SHA-256 of the manifest it was checked against), which may then delete its copy by its
retention policy (:class:`app.nodes.store.RetentionPolicy`); a node that missed it lists
its unconfirmed parts in ``status`` and :class:`app.server.datasync.DataSync` repeats it.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import functools
import hashlib
import itertools
import json
import logging
import os
import secrets
import socket
import threading
import time
from collections import deque
from collections.abc import AsyncIterator, Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from app.nodes.protocol import (
    ChunkRequest,
    DataChannel,
    DeletePart,
    ManifestRequest,
    PartVerified,
    dump,
)
from app.server.recording import Recording, RecordingManager
from app.server.registry import NodeRegistry, NodeSession
from app.server.storage import note_changed
from app.transfer import (
    Manifest,
    TransferError,
    TransferSink,
    end_channel,
    parse_hello,
    pull,
    pull_channel,
    set_timeout,
)
from app.transfer._channel import HELLO_LEN, HELLO_MAGIC
from engine.errors import InputError
from engine.wording import count

log = logging.getLogger("gaitrig.transfer")

WINDOW_BYTES = 32 << 20  # bytes of one file requested ahead (bounds server memory)
_MAX_BATCH = 4096  # chunk indices per request (protocol limit)
CHANNEL_OFFER_S = 5.0  # a data channel token is valid this long; then the websocket is used
CHANNEL_ATTEMPTS = 3  # rounds of data channels per transfer before falling back
CHANNELS_PER_PART = 2  # one receiving thread each: a single node's part uses both cores
MAX_HANDSHAKES = 32  # connections waiting to present a token at once
_T = TypeVar("_T")


@dataclass
class _Offer:
    """A data channel offered to a node, waiting for it to connect."""

    node_id: str
    rec_id: str
    expires: float
    connected: asyncio.Future[socket.socket]


class TransferManager:
    """Transfers parts of recordings from their nodes.

    Args:
        registry: connected nodes.
        recordings: recording manager (part states are updated here).
        data_dir: server data folder.
        timeout_s: longest wait for one reply from a node.
        data_host: interface of the data channel listener (the API's).
        data_port: its port (0: any free port; taken: any free port, with a warning);
            None: no data channel, chunks over the websocket only.
    """

    def __init__(self, registry: NodeRegistry, recordings: RecordingManager, data_dir: Path,
                 timeout_s: float = 30.0, *, data_host: str = "127.0.0.1",
                 data_port: int | None = None) -> None:
        self.registry = registry
        self.recordings = recordings
        self.root = Path(data_dir) / "recordings"
        self.timeout_s = timeout_s
        self._ids = itertools.count(1)
        self._queues: dict[int, asyncio.Queue[tuple[dict[str, Any], bytes]]] = {}
        self._tasks: dict[tuple[str, str], asyncio.Task[None]] = {}  # (rec, node) -> pull
        # node copies of deleted recordings still to delete: node id -> recording ids
        self._deletions_file = Path(data_dir) / "node_deletions.json"
        self._lock = threading.Lock()  # routes run in worker threads
        self._deletions: dict[str, list[str]] = self._load_deletions()
        self._deleting: dict[tuple[str, str], asyncio.Task[None]] = {}
        self._delete_tried: dict[tuple[str, str], float] = {}
        self.deletion_errors: dict[tuple[str, str], str] = {}
        # data channel: None = websocket only (the listener opens at the first transfer)
        self.data_host = data_host
        self.data_port_setting = data_port
        self.data_port: int | None = None
        self._listener: socket.socket | None = None
        self._accepting: asyncio.Task[None] | None = None
        self._handshakes: set[asyncio.Task[None]] = set()
        self._offers: dict[str, _Offer] = {}

    def on_binary(self, header: dict[str, Any], payload: bytes) -> None:
        """A ``manifest``, ``chunk`` or ``deleted`` answer arrived (from the hub)."""
        q = self._queues.get(header.get("req_id", -1))
        if q is not None:
            q.put_nowait((header, payload))

    def part_dir(self, rec_id: str, node_id: str) -> Path:
        """Where a transferred part lives on the server."""
        return self.root / rec_id / node_id

    async def _send(self, s: NodeSession, text: str) -> None:
        if s.send is None:
            raise ConnectionError(f"node {s.id} is offline")
        try:
            await s.send(text)
        except (ConnectionError, OSError):
            raise
        except Exception as exc:  # the websocket layer's own types (WebSocketDisconnect, ...)
            raise ConnectionError(f"node {s.id} disconnected ({type(exc).__name__})") from exc

    async def manifest(self, s: NodeSession, rec_id: str) -> Manifest:
        """Ask a node for the manifest of its part of ``rec_id``."""
        req_id = next(self._ids)
        q: asyncio.Queue[tuple[dict[str, Any], bytes]] = asyncio.Queue()
        self._queues[req_id] = q
        try:
            await self._send(s, dump(ManifestRequest(req_id=req_id, rec_id=rec_id)))
            header, payload = await asyncio.wait_for(q.get(), self.timeout_s)
        finally:
            del self._queues[req_id]
        if header.get("error"):
            raise TransferError(f"node {s.id}: {header['error']}")
        return Manifest.from_json(payload)

    def _fetcher(self, s: NodeSession, rec_id: str, chunk_size: int) -> Any:
        # Two requests of half a window each are outstanding per file: the node always
        # has the next chunks to send (no round-trip stall between requests) and at most
        # WINDOW_BYTES per file wait in memory on the server.
        batch = max(1, min(_MAX_BATCH, WINDOW_BYTES // 2 // max(1, chunk_size)))

        async def fetch(name: str, indices: list[int]) -> AsyncIterator[tuple[int, bytes]]:
            batches = iter([indices[k : k + batch] for k in range(0, len(indices), batch)])
            inflight: deque[tuple[int, asyncio.Queue[tuple[dict[str, Any], bytes]], int]] = (
                deque())

            async def request(b: list[int]) -> None:
                req_id = next(self._ids)
                q: asyncio.Queue[tuple[dict[str, Any], bytes]] = asyncio.Queue()
                self._queues[req_id] = q
                inflight.append((req_id, q, len(b)))
                await self._send(s, dump(ChunkRequest(req_id=req_id, rec_id=rec_id,
                                                      file=name, indices=b)))

            try:
                for b in itertools.islice(batches, 2):
                    await request(b)
                while inflight:
                    req_id, q, n = inflight[0]
                    for _ in range(n):
                        header, payload = await asyncio.wait_for(q.get(), self.timeout_s)
                        if header.get("error"):
                            raise ConnectionError(f"node {s.id}: {header['error']}")
                        yield int(header["index"]), payload
                    inflight.popleft()
                    del self._queues[req_id]
                    nxt = next(batches, None)
                    if nxt is not None:
                        await request(nxt)
            finally:
                for req_id, _, _ in inflight:
                    self._queues.pop(req_id, None)

        return fetch

    # ------------------------------------------------------------------ data channel

    def _listen(self) -> int | None:
        """Open the data channel listener once; its port, or None (websocket only)."""
        if self._listener is not None or self.data_port_setting is None:
            return self.data_port
        port = self.data_port_setting
        family = socket.AF_INET6 if ":" in self.data_host else socket.AF_INET
        try:
            lsock = socket.create_server((self.data_host, port), family=family, backlog=16)
        except OSError as exc:
            if port == 0 or exc.errno != errno.EADDRINUSE:
                log.warning("transfer data channel unavailable (%s:%d: %s); chunks go over "
                            "the node websocket", self.data_host, port, exc)
                self.data_port_setting = None
                return None
            lsock = socket.create_server((self.data_host, 0), family=family, backlog=16)
            log.warning("transfer port %d is taken; the data channel listens on %d instead "
                        "(set GAITRIG_TRANSFER_PORT if a firewall must let it through)",
                        port, lsock.getsockname()[1])
        lsock.setblocking(False)
        self._listener = lsock
        self.data_port = int(lsock.getsockname()[1])
        self._accepting = asyncio.create_task(self._accept_loop(lsock))
        log.info("transfer data channel listening on %s:%d", self.data_host, self.data_port)
        return self.data_port

    async def _accept_loop(self, lsock: socket.socket) -> None:
        loop = asyncio.get_running_loop()
        while True:
            try:
                conn, peer = await loop.sock_accept(lsock)
            except OSError as exc:
                log.warning("data channel accept failed: %s", exc)
                await asyncio.sleep(0.5)
                continue
            if len(self._handshakes) >= MAX_HANDSHAKES:
                conn.close()  # bounded: a flood of idle connections gets nothing
                continue
            task = asyncio.create_task(self._handshake(conn, peer))
            self._handshakes.add(task)
            task.add_done_callback(self._handshakes.discard)

    async def _handshake(self, conn: socket.socket, peer: Any) -> None:
        """Read the node's token; hand the socket to the transfer that offered it."""
        loop = asyncio.get_running_loop()
        conn.setblocking(False)
        data = b""
        try:
            async with asyncio.timeout(CHANNEL_OFFER_S):
                # bytes that cannot begin a hello are refused at once, not after the
                # timeout (a stray client would hold one of the MAX_HANDSHAKES slots)
                while len(data) < HELLO_LEN and HELLO_MAGIC.startswith(data[:len(HELLO_MAGIC)]):
                    got = await loop.sock_recv(conn, HELLO_LEN - len(data))
                    if not got:
                        break
                    data += got
        except (OSError, TimeoutError):
            pass
        token = parse_hello(data)
        offer = self._offers.pop(token, None) if token else None  # single use
        if offer is None or offer.connected.done() or time.monotonic() > offer.expires:
            log.warning("data channel from %s refused: no valid token", peer)
            conn.close()
            return
        try:
            set_timeout(conn, self.timeout_s)
        except OSError:
            conn.close()
            return
        offer.connected.set_result(conn)

    async def _open_channel(self, s: NodeSession, rec_id: str) -> socket.socket | None:
        """Offer ``s`` a data channel for ``rec_id``; the connected socket, or None when
        the node declines or does not connect in time (the websocket is used then)."""
        port = self._listen()
        if port is None:
            return None
        loop = asyncio.get_running_loop()
        token = secrets.token_hex(16)
        connected: asyncio.Future[socket.socket] = loop.create_future()
        self._offers[token] = _Offer(s.id, rec_id, time.monotonic() + CHANNEL_OFFER_S,
                                     connected)
        req_id = next(self._ids)
        q: asyncio.Queue[tuple[dict[str, Any], bytes]] = asyncio.Queue()
        self._queues[req_id] = q
        answer = asyncio.ensure_future(q.get())
        try:
            await self._send(s, dump(DataChannel(req_id=req_id, rec_id=rec_id, port=port,
                                                 token=token)))
            waiters: set[asyncio.Future[Any]] = {connected, answer}
            await asyncio.wait(waiters, timeout=CHANNEL_OFFER_S,
                               return_when=asyncio.FIRST_COMPLETED)
            if connected.done():
                return connected.result()
            why = (str(answer.result()[0].get("error") or "declined") if answer.done()
                   else f"it did not connect to port {port} within {CHANNEL_OFFER_S:.0f} s")
            log.warning("recording %s: no data channel from %s (%s); chunks go over the "
                        "websocket", rec_id, s.id, why)
            return None
        finally:
            answer.cancel()
            self._offers.pop(token, None)
            del self._queues[req_id]
            connected.cancel()

    async def _in_thread(self, sock: socket.socket, fn: Callable[..., _T], *args: Any,
                         **kwargs: Any) -> _T:
        """Run a blocking channel function; on cancellation shut the socket so the
        thread stops at once instead of finishing the transfer behind our back."""
        loop = asyncio.get_running_loop()
        cf = loop.run_in_executor(None, functools.partial(fn, *args, **kwargs))
        try:
            return await asyncio.shield(cf)
        except asyncio.CancelledError:
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)
            with contextlib.suppress(BaseException):
                await asyncio.wait_for(cf, 10.0)
            raise

    async def _pull_over_channel(self, s: NodeSession, rec_id: str, sink: TransferSink,
                                 progress: Callable[[int, int], None]) -> bool:
        """Fetch the missing chunks over data channels; False when none could be opened
        or they kept breaking (the caller falls back to the websocket).

        :data:`CHANNELS_PER_PART` channels share the chunks (by index modulo their
        number), each received, hashed and written by its own thread: one node's part
        uses both cores of the server. Channels that break are reopened
        (:data:`CHANNEL_ATTEMPTS` rounds) for the chunks still missing.
        """
        for attempt in range(CHANNEL_ATTEMPTS):
            if not sink.missing_chunks():
                return True
            socks = [sock for sock in await asyncio.gather(
                *(self._open_channel(s, rec_id) for _ in range(CHANNELS_PER_PART)))
                if sock is not None]
            if not socks:
                return False
            log.info("recording %s: %s from %s open", rec_id, count(len(socks), "data channel"),
                     s.id)
            async def run(k: int, sock: socket.socket, socks: list[socket.socket] = socks
                          ) -> None:
                try:
                    await self._in_thread(sock, pull_channel, sink, sock,
                                          on_progress=progress, share=(k, len(socks)))
                except (ConnectionError, TimeoutError, OSError):
                    raise
                except Exception:  # disk full, corrupt for good: stop the other channels
                    for other in socks:
                        with contextlib.suppress(OSError):
                            other.shutdown(socket.SHUT_RDWR)
                    raise

            try:
                results = await asyncio.gather(
                    *(run(k, sock) for k, sock in enumerate(socks)), return_exceptions=True)
            finally:
                for sock in socks:
                    end_channel(sock)  # 8 bytes into an idle socket: does not block
                    sock.close()
            errors = [r for r in results if isinstance(r, BaseException)]
            for exc in errors:  # a verdict (disk full, corrupt for good) beats a broken link
                if not isinstance(exc, ConnectionError | TimeoutError | OSError):
                    raise exc
            if not errors:
                return True
            exc = errors[0]
            if not s.connected:
                raise ConnectionError(f"node {s.id} disconnected ({exc})") from exc
            log.warning("recording %s: data channel from %s broke (%s); %s", rec_id, s.id,
                        exc, "reopening it" if attempt + 1 < CHANNEL_ATTEMPTS
                        else "using the websocket")
        return False

    async def transfer_part(self, rec: Recording, node_id: str) -> Path:
        """Pull one node's part of ``rec`` (resumes a partial copy); returns its folder."""
        s = self.registry.get(node_id)
        if s is None or not s.connected:
            raise ConnectionError(f"node {node_id} is offline")
        part = rec.parts[node_id]
        log.info("recording %s: asking %s for the manifest of its part", rec.id, node_id)
        m = await self.manifest(s, rec.id)
        sink = await asyncio.to_thread(TransferSink, self.part_dir(rec.id, node_id), m)
        log.info("recording %s: receiving %d of %d bytes from %s", rec.id,
                 m.total_bytes - sink.bytes_done, m.total_bytes, node_id)

        def progress(done: int, total: int) -> None:
            part.transfer_progress = done / total if total else 1.0

        if await self._pull_over_channel(s, rec.id, sink, progress):
            return await asyncio.to_thread(sink.finalize)
        return await pull(sink, self._fetcher(s, rec.id, m.chunk_size), concurrency=2,
                          on_progress=progress)

    def start(self, rec_id: str) -> list[str]:
        """Transfer the parts of a stopped recording that are not on the server and not
        being transferred, in the background and in parallel (a node that connects later
        gets its own start while the others run).

        Returns:
            The nodes whose parts were started.

        Raises:
            InputError: unknown, still running, nothing to transfer or already transferring.
        """
        rec = self.recordings.recordings.get(rec_id)
        if rec is None:
            raise InputError(f"no recording {rec_id!r}")
        if rec.t_stop is None:
            raise InputError(f"recording {rec_id} is still running; stop it first")
        todo = [n for n, p in rec.parts.items()
                if p.state in ("on_node", "incomplete") and not p.on_server and p.n_frames]
        busy = self.running_parts(rec_id)
        if todo and set(todo) <= busy:
            raise InputError(f"recording {rec_id} is already being transferred")
        if not todo:
            raise InputError(f"recording {rec_id} has no part to transfer (parts must be "
                             "closed on their nodes)")
        started = [n for n in todo if n not in busy]
        for n in started:
            key = (rec_id, n)
            task = asyncio.create_task(self._run_part(rec, n))
            self._tasks[key] = task
            task.add_done_callback(self._task_done(key))
        return started

    def _task_done(self, key: tuple[str, str]) -> Any:
        def done(_task: asyncio.Task[None]) -> None:
            self._tasks.pop(key, None)

        return done

    async def _run_part(self, rec: Recording, node_id: str) -> None:
        part = rec.parts[node_id]
        was = part.state
        part.state, part.transfer_progress = "transferring", 0.0
        try:
            await self.transfer_part(rec, node_id)
        except (TransferError, ConnectionError, TimeoutError, OSError, InputError) as exc:
            part.state = was
            # Keep why the part was incomplete in the first place (e.g. the node
            # disconnected mid-recording); only the transfer note is replaced.
            base = (part.reason or "").split("; transfer failed", 1)[0]
            if base.startswith("transfer failed"):
                base = ""
            note = f"transfer failed ({exc}); retry when the node is online"
            part.reason = f"{base}; {note}" if base else note
            log.warning("recording %s: %s", rec.id, part.reason)
        except asyncio.CancelledError:
            part.state = was  # DataSync noted why (e.g. the node dropped); resumed later
            raise
        else:
            part.on_server, part.transfer_progress = True, 1.0
            part.state = "complete" if was == "on_node" else "incomplete"
            log.info("recording %s: part of %s on the server", rec.id, node_id)
            await self.send_verified(rec.id, node_id)
        finally:
            self.recordings.touch(rec.id)  # what changed here is written by the save
            note_changed(self.part_dir(rec.id, node_id))  # its bytes on the server
            self.recordings.save()

    def verified_sha(self, rec_id: str, node_id: str) -> str | None:
        """SHA-256 of the manifest a part was verified against on the server; None when
        the server holds no verified copy of it."""
        d = self.part_dir(rec_id, node_id)
        if not TransferSink.is_complete(d):
            return None
        try:
            return hashlib.sha256((d / "manifest.json").read_bytes()).hexdigest()
        except OSError:
            return None

    async def send_verified(self, rec_id: str, node_id: str) -> bool:
        """Tell a node that the server holds a verified copy of its part of ``rec_id`` (it
        may then delete its own by its retention policy). False when there is none or the
        node is offline (it asks again in its ``status``)."""
        sha = self.verified_sha(rec_id, node_id)
        s = self.registry.get(node_id)
        if sha is None or s is None or not s.connected:
            return False
        try:
            await self._send(s, dump(PartVerified(rec_id=rec_id, manifest_sha256=sha)))
        except (ConnectionError, OSError) as exc:
            log.info("recording %s: node %s not told of its verified copy (%s)", rec_id,
                     node_id, exc)
            return False
        return True

    # ------------------------------------------------------------------ running transfers

    def is_running(self, rec_id: str) -> bool:
        """True while a part of ``rec_id`` is being transferred."""
        return any(r == rec_id for r, _ in self._tasks)

    def running(self) -> list[str]:
        """Ids of the recordings being transferred now."""
        return sorted({r for r, _ in self._tasks})

    def running_parts(self, rec_id: str) -> set[str]:
        """Nodes whose parts of ``rec_id`` are being transferred now."""
        return {n for r, n in self._tasks if r == rec_id}

    def cancel(self, rec_id: str, nodes: Iterable[str] | None = None) -> bool:
        """Stop the transfer of ``rec_id``'s parts (of ``nodes``, default all); the
        verified chunks stay and the transfer resumes later.

        Returns:
            Whether a transfer was running.
        """
        wanted = None if nodes is None else set(nodes)
        hit = [t for (r, n), t in self._tasks.items()
               if r == rec_id and (wanted is None or n in wanted)]
        for t in hit:
            t.cancel()
        return bool(hit)

    async def close(self) -> None:
        """Cancel running transfers (server shutdown; they resume on the next request)."""
        for t in [*self._tasks.values(), *self._deleting.values(), *self._handshakes]:
            t.cancel()
        if self._accepting is not None:
            self._accepting.cancel()
        if self._listener is not None:
            self._listener.close()
            self._listener = None

    # ------------------------------------------------------------------ node deletions

    def _load_deletions(self) -> dict[str, list[str]]:
        try:
            raw = json.loads(self._deletions_file.read_text())
        except (OSError, ValueError):
            return {}
        if not isinstance(raw, dict):
            return {}
        return {str(n): [str(r) for r in recs] for n, recs in raw.items()
                if isinstance(recs, list) and recs}

    def _save_deletions(self) -> None:
        self._deletions_file.parent.mkdir(parents=True, exist_ok=True)
        tmp = self._deletions_file.with_suffix(".tmp")
        with open(tmp, "w") as fh:
            json.dump(self._deletions, fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, self._deletions_file)

    def request_deletion(self, rec_id: str, nodes: Iterable[str]) -> None:
        """Remember that ``nodes`` must delete their parts of ``rec_id`` (persisted; sent
        by :meth:`flush_deletions` now or when a node reconnects)."""
        with self._lock:
            for n in nodes:
                recs = self._deletions.setdefault(n, [])
                if rec_id not in recs:
                    recs.append(rec_id)
            self._save_deletions()

    def pending_deletions(self) -> dict[str, list[str]]:
        """Node id → recordings whose parts that node has not confirmed deleting yet."""
        with self._lock:
            return {n: list(r) for n, r in self._deletions.items() if r}

    def deletion_status(self, rec_id: str, nodes: Iterable[str]) -> dict[str, str]:
        """Per node: ``deleted``, or why its copy of ``rec_id`` is still there."""
        pending = self.pending_deletions()
        out = {}
        for n in nodes:
            if rec_id not in pending.get(n, []):
                out[n] = "deleted"
                continue
            s = self.registry.get(n)
            err = self.deletion_errors.get((n, rec_id))
            out[n] = (f"not deleted yet: {err}; retried automatically" if err else
                      "node offline: deleted when it reconnects" if s is None or not s.connected
                      else "deleting")
        return out

    def flush_deletions(self, retry_s: float = 10.0) -> list[asyncio.Task[None]]:
        """Ask every connected node to delete its pending parts (failures retried after
        ``retry_s``, at once after a reconnect). Returns the requests started now."""
        started = []
        now = time.monotonic()
        for node_id, recs in self.pending_deletions().items():
            s = self.registry.get(node_id)
            if s is None or not s.connected:
                for r in recs:  # ask again as soon as it is back
                    self._delete_tried.pop((node_id, r), None)
                continue
            for rec_id in recs:
                key = (node_id, rec_id)
                if key in self._deleting or now - self._delete_tried.get(key, -1e9) < retry_s:
                    continue
                self._delete_tried[key] = now
                task = asyncio.create_task(self._delete_on(s, rec_id))
                self._deleting[key] = task
                task.add_done_callback(self._deletion_done(key))
                started.append(task)
        return started

    def _deletion_done(self, key: tuple[str, str]) -> Any:
        def done(_task: asyncio.Task[None]) -> None:
            self._deleting.pop(key, None)

        return done

    async def _delete_on(self, s: NodeSession, rec_id: str) -> None:
        req_id = next(self._ids)
        q: asyncio.Queue[tuple[dict[str, Any], bytes]] = asyncio.Queue()
        self._queues[req_id] = q
        try:
            await self._send(s, dump(DeletePart(req_id=req_id, rec_id=rec_id)))
            header, _ = await asyncio.wait_for(q.get(), self.timeout_s)
        except (ConnectionError, TimeoutError, OSError) as exc:
            self.deletion_errors[(s.id, rec_id)] = f"no answer from node {s.id} ({exc})"
            return
        finally:
            del self._queues[req_id]
        if header.get("error") or not header.get("deleted"):
            self.deletion_errors[(s.id, rec_id)] = str(header.get("error") or "no confirmation")
            log.warning("recording %s: node %s did not delete its copy: %s", rec_id, s.id,
                        self.deletion_errors[(s.id, rec_id)])
            return
        self.deletion_errors.pop((s.id, rec_id), None)
        with self._lock:
            recs = self._deletions.get(s.id, [])
            if rec_id in recs:
                recs.remove(rec_id)
            if not recs:
                self._deletions.pop(s.id, None)
            self._save_deletions()
        log.info("recording %s: node %s deleted its copy", rec_id, s.id)
