"""The node agent: one process per depth sensor (``gaitrig node``).

It connects to the server's ``/ws/node`` websocket, authenticates with the pairing token,
answers clock pings at once, streams every skeleton frame, sends images when subscribed
or asked for a snapshot, keeps a 2 s ring buffer and records to its local store between
the server's start and stop times. When the server goes away it keeps capturing (and
recording, if a recording runs) and reconnects with exponential backoff.

Threads: the backend's blocking frame iterator runs in a capture thread that hands frames
to the asyncio loop; image rendering/encoding runs in a worker thread. The loop itself
only does cheap work so pings are answered within a fraction of a millisecond — the
clock estimate depends on it.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import hashlib
import logging
import os
import socket
import sys
import threading
import time
from collections import deque
from collections.abc import Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import numpy as np
from pydantic import ValidationError
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidURI

from app.nodes.backends.base import Backend, Frame, downscale_image
from app.nodes.protocol import (
    CalibrationCapture,
    ChunkRequest,
    DataChannel,
    DeletePart,
    Hello,
    ManifestRequest,
    NodeError,
    NodeStorage,
    NodeWarning,
    PartInfo,
    PartList,
    PartVerified,
    Ping,
    Pong,
    ProtocolError,
    RecStart,
    RecState,
    RecStop,
    Refused,
    SensorInfo,
    ServerError,
    Snapshot,
    Status,
    Subscribe,
    Welcome,
    calib_error,
    dump,
    encode_binary,
    encode_calib_frame,
    encode_skeletons,
    parse_server_message,
    part_batches,
)
from app.nodes.ringbuffer import RingBuffer
from app.nodes.store import NodeStore, PartWriter, Purged, RetentionPolicy, StorageUsage
from app.transfer import (
    DEFAULT_CHUNK_SIZE,
    Manifest,
    TransferError,
    build_manifest,
    chunk_message,
    connect_channel,
    serve_channel,
)
from engine.errors import GaitrigError, InputError

log = logging.getLogger("gaitrig.node")


_corrupted: set[tuple[str, int]] = set()
CHANNEL_SWITCH_INTERVAL_S = 0.0005  # GIL switch interval while a data channel is open
# Recorded frames whose images wait to be encoded, at most: each holds the sensor's full
# images, so a node encoding slower than it captures would otherwise grow without bound
MAX_IMAGE_BACKLOG = 30
# The backend clock moving this much against the monotonic clock between two reads is a
# step (NTP setting the system clock), not drift (≤ 0.1 ms/s) or a slow read (bounded below)
CLOCK_STEP_MIN_S = 0.02
_CLOCK_READ_MAX_S = 0.002  # a read of both clocks slower than this is not compared
RETENTION_CHECK_S = 10.0  # free space checked this often (a purge runs when it is short)
RETENTION_FULL_S = 300.0  # a purge by age at least this often
LOW_SPACE_WARN_S = 600.0  # "below the floor and nothing to purge" at most this often
#: Backend warnings (:meth:`Backend.warn`) go to the server as ``warning`` messages: at
#: most WARNING_BURST at once, then one per WARNING_INTERVAL_S (a token bucket); repeats of
#: a text still waiting are coalesced into it, and at most WARNING_BACKLOG distinct texts
#: wait (the oldest is dropped, and counted).
WARNING_BURST = 5
WARNING_INTERVAL_S = 10.0
WARNING_BACKLOG = 20


@dataclass
class _PendingWarning:
    text: str
    t: float  # node clock, last raised
    repeats: int = 1


_cut: set[tuple[str, int]] = set()


def _test_corrupt(name: str, idx: int) -> bool:
    """TEST HOOK: whether to flip one byte of this chunk (``GAITRIG_TEST_CORRUPT_CHUNK=
    <file>:<index>``, the first time that chunk is sent, on either path)."""
    target = os.environ.get("GAITRIG_TEST_CORRUPT_CHUNK")
    if target and target == f"{name}:{idx}" and (name, idx) not in _corrupted:
        _corrupted.add((name, idx))
        log.warning("TEST HOOK: flipping one byte of %s chunk %d", name, idx)
        return True
    return False


def _test_chunk_delay() -> float:
    """TEST HOOK: seconds to hold every chunk back (``GAITRIG_TEST_CHUNK_DELAY_S``; with
    ``GAITRIG_TEST_CHUNK_DELAY_FILE`` set, only while that file exists, so a test can
    release a slowed transfer once it has seen what it wanted)."""
    delay = float(os.environ.get("GAITRIG_TEST_CHUNK_DELAY_S", "0") or 0)
    gate = os.environ.get("GAITRIG_TEST_CHUNK_DELAY_FILE")
    return 0.0 if delay <= 0 or (gate and not os.path.exists(gate)) else delay


async def _test_chunk_hooks(name: str, idx: int, message: bytearray, start: int) -> None:
    """TEST HOOKS of the transfer acceptance tests (environment of the node process):
    ``GAITRIG_TEST_CHUNK_DELAY_S`` slows every chunk down (so a transfer can be
    interrupted; see :func:`_test_chunk_delay`), ``GAITRIG_TEST_CORRUPT_CHUNK=<file>:<index>``
    flips one byte of that chunk (at ``message[start]``) the first time it is sent.
    ``GAITRIG_TEST_CHUNK_SIZE`` (in :meth:`_manifest`) makes small parts span many chunks.
    The data channel's equivalent is :func:`_test_channel_hook`."""
    delay = _test_chunk_delay()
    if delay > 0:
        await asyncio.sleep(delay)
    if len(message) > start and _test_corrupt(name, idx):
        message[start] ^= 0xFF


def _test_channel_hook(name: str, idx: int) -> bool:
    """TEST HOOKS on the data channel (runs in its thread): the delay and corruption of
    :func:`_test_chunk_hooks`, and ``GAITRIG_TEST_CUT_DATA_CHANNEL=<file>:<index>``
    closes the channel once, just before that chunk (the websocket stays up)."""
    delay = _test_chunk_delay()
    if delay > 0:
        time.sleep(delay)
    cut = os.environ.get("GAITRIG_TEST_CUT_DATA_CHANNEL")
    if cut and cut == f"{name}:{idx}" and (name, idx) not in _cut:
        _cut.add((name, idx))
        log.warning("TEST HOOK: cutting the data channel before %s chunk %d", name, idx)
        raise ConnectionAbortedError("TEST HOOK: data channel cut")
    return _test_corrupt(name, idx)


class NodeRefusedError(RuntimeError):
    """The server refused this node (wrong token, bad id, version); retrying won't help."""


class ServerBusyError(RuntimeError):
    """The server refused this connection for now (close code 1013, 'try again later':
    too many connections waiting for their hello, the address paused); retried."""


#: The close code of a refusal to retry (RFC 6455 'Try Again Later').
CLOSE_TRY_AGAIN = 1013


def encode_image(stream: str, img: np.ndarray, scale: float, fmt: str) -> tuple[bytes, str]:
    """Downscale and compress one image; returns ``(bytes, format)``.

    Depth and body index are resized with nearest neighbour (no invented depths); depth
    stays 16-bit PNG when PNG is asked for, and becomes a false-colour JPEG preview
    otherwise (JPEG has no 16-bit mode).
    """
    import cv2  # only nodes that send images need OpenCV (as downscale_image)

    img = downscale_image(stream, img, scale)
    if stream == "color" and img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    if fmt == "jpeg":
        if img.dtype == np.uint16:
            img = cv2.applyColorMap(
                np.clip(img / 4500.0 * 255.0, 0, 255).astype(np.uint8), cv2.COLORMAP_TURBO
            )
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 80])
    else:
        ok, buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise ProtocolError(f"could not encode the {stream} image as {fmt}")
    return buf.tobytes(), fmt


@dataclass
class _Rec:
    cmd: RecStart
    writer: PartWriter
    t_stop_local: float = float("inf")
    stop_cmd: RecStop | None = None
    n_seen: int = 0
    pending_images: list[Any] = field(default_factory=list)  # not yet encoded and written
    images_skipped: int = 0  # frames whose images were left out (encoder behind)
    lock: threading.Lock = field(default_factory=threading.Lock)
    rebase: float = 0.0  # added to frame times (a resumed part keeps its first clock's origin)
    gap_s: float | None = None  # a resumed part: seconds missing before this segment


class NodeAgent:
    """A sensor node.

    Args:
        node_id: sensor id (``S1`` ...), unique in the rig.
        backend: the sensor.
        server_url: ``ws://host:port/ws/node``.
        token: pairing token.
        data_dir: node folder; recordings go to ``data_dir/recordings``.
        ring_seconds: ring buffer length.
        report_true_clock: send the backend's test-only truths in ``status.diag``.
        retention: when to delete parts the server holds verified (default
            :class:`RetentionPolicy`: 7 days, floor 5 GB or 10 % of the disk).
    """

    def __init__(
        self,
        node_id: str,
        backend: Backend,
        server_url: str,
        token: str,
        data_dir: Path | str,
        *,
        ring_seconds: float = 2.0,
        report_true_clock: bool = False,
        retention: RetentionPolicy | None = None,
    ) -> None:
        self.node_id = node_id
        self.backend = backend
        self.server_url = server_url
        self.token = token
        self.store = NodeStore(Path(data_dir) / "recordings")
        self.ring: RingBuffer[Frame] = RingBuffer(ring_seconds)
        self.report_true_clock = report_true_clock
        self.started = 0.0
        self.info: SensorInfo | None = None
        self.seq = 0
        self.frames_total = 0
        self.dropped = 0
        self._frame_times: deque[float] = deque(maxlen=120)
        self._recs: dict[str, _Rec] = {}
        self._early_stops: dict[str, RecStop] = {}
        self._manifests: dict[str, Manifest] = {}
        self._manifest_lock = threading.Lock()
        self._channels: set[socket.socket] = set()  # open transfer data channels
        self._switch_interval = sys.getswitchinterval()
        self._ever_connected = False
        self._tasks: set[asyncio.Future[None]] = set()
        self._ws: ClientConnection | None = None
        self._out: asyncio.Queue[str | bytes] = asyncio.Queue(maxsize=256)
        self._control: deque[str | bytes] = deque()
        self._wake = asyncio.Event()
        self._finished: dict[str, tuple[PartInfo, float]] = {}
        self._stop = asyncio.Event()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="images")
        self._sub: Subscribe | None = None
        self._sub_last = 0.0
        self._sub_busy = False
        self._dropped_capture = 0  # written by the capture thread only
        self._submitted = 0  # written by the capture thread only
        self._handled = 0  # written by the loop only
        # The node clock is the backend's with its steps undone (:meth:`now`)
        self.clock_steps = 0
        self._step_corr = 0.0  # seconds added to the backend clock
        self._clock_base: float | None = None  # backend clock - monotonic, last read
        self._last_step: tuple[float, float] | None = None  # (monotonic, corr before it)
        self._frame_age = 0.0  # typical age of a frame when it is handled (s)
        # Retention of verified parts (:meth:`_purge`)
        self.retention = retention or RetentionPolicy()
        self._usage: StorageUsage | None = None
        self._serving: dict[str, int] = {}  # parts being sent to the server: never purged
        self._purging = False
        self._purge_again = False
        self.purged_parts = 0
        self.purged_bytes = 0
        self._last_purge: str | None = None
        self._low_space_warned = -float("inf")
        # Backend warnings for the server (:meth:`_flush_warnings`)
        self._warnings: deque[_PendingWarning] = deque()
        self._warning_tokens = float(WARNING_BURST)
        self._warning_refilled = time.monotonic()
        self.warnings_dropped = 0
        self._server_takes_warnings = False
        backend.warning_sink = self._on_backend_warning

    # ------------------------------------------------------------------ lifecycle

    async def run(self) -> None:
        """Open the sensor, then capture, stream and record until :meth:`stop`."""
        self._loop = asyncio.get_running_loop()
        recovered = self.store.recover()
        for p in recovered:
            log.warning("recovered recording %s after a crash: %d frames kept", p.rec_id,
                        p.n_frames)
        self.info = await asyncio.to_thread(self.backend.open)
        self.started = self.now()
        capture = threading.Thread(target=self._capture, name="capture", daemon=True)
        capture.start()
        retention = asyncio.create_task(self._retention_loop())
        try:
            await self._connect_forever()
        finally:
            retention.cancel()
            self.backend.close()
            await asyncio.to_thread(capture.join, 5.0)
            for rec in list(self._recs.values()):
                self._finish(rec, "incomplete", "node shut down during the recording")
            for sock in list(self._channels):  # unblock their threads: the process can exit
                with contextlib.suppress(OSError):
                    sock.shutdown(socket.SHUT_RDWR)
            self._pool.shutdown(wait=True)

    def now(self) -> float:
        """The node clock: the backend's, continuous across its steps.

        When NTP steps the system clock, the backend's clock jumps. The server models each
        node clock as offset + drift (a jump would corrupt that model for its whole
        window) and a recording converts its frame times with one model, so the node
        undoes steps: its clock keeps running at the backend's rate, and the server's
        offset estimate absorbs the difference. Call from the event loop only.
        """
        for _ in range(3):  # a read interrupted by another thread says nothing: again
            m1 = time.monotonic()
            t = self.backend.now()
            m2 = time.monotonic()
            if m2 - m1 <= _CLOCK_READ_MAX_S:
                break
        if m2 - m1 <= _CLOCK_READ_MAX_S:
            base = t - (m1 + m2) / 2.0
            if self._clock_base is not None and abs(base - self._clock_base) >= CLOCK_STEP_MIN_S:
                jump = base - self._clock_base
                self._last_step = (m2, self._step_corr)
                self._step_corr -= jump
                self.clock_steps += 1
                log.warning("the node's clock stepped by %+.3f s (NTP?); recorded times stay "
                            "continuous", jump)
            self._clock_base = base
        return t + self._step_corr

    def _destep(self, frame: Frame) -> Frame:
        """``frame`` on the node clock (:meth:`now`).

        Whether a frame's stamp stepped with the backend clock depends on the backend (the
        simulator stamps with its clock; a sensor may stamp with its own steady device
        clock), and a frame stamped just before a step may be handled after it. Of the
        corrections that can apply (the current one, the one before the last step, none),
        the one giving the frame its usual age when handled is right: they differ by at
        least :data:`CLOCK_STEP_MIN_S`.
        """
        now = self.now()
        corr = self._step_corr
        if self.clock_steps:
            options = {corr, 0.0} | ({self._last_step[1]} if self._last_step else set())
            corr = min(options, key=lambda c: abs(now - (frame.t_local + c) - self._frame_age))
        age = now - (frame.t_local + corr)
        if 0.0 <= age < 1.0:
            self._frame_age = 0.9 * self._frame_age + 0.1 * age
        return frame if corr == 0.0 else replace(frame, t_local=frame.t_local + corr)

    def stop(self) -> None:
        """Ask :meth:`run` to finish (thread-safe)."""
        if self._loop is not None:
            self._loop.call_soon_threadsafe(self._stop.set)

    def _capture(self) -> None:
        assert self._loop is not None
        try:
            for frame in self.backend.frames():
                if self._stop.is_set():
                    break
                if self._submitted - self._handled > 30:
                    # The loop is >1 s behind: drop rather than grow without bound.
                    self._dropped_capture += 1
                    continue
                self._submitted += 1
                self._loop.call_soon_threadsafe(self._on_frame, frame)
        except Exception:
            log.exception("sensor backend failed")
            self._loop.call_soon_threadsafe(self._stop.set)

    async def _connect_forever(self) -> None:
        backoff = 0.2
        while not self._stop.is_set():
            try:
                # newest first (the ones a recording may still wait for), in bounded
                # messages: a node offline through a long day holds more parts than one
                # message may carry. Listed before connecting: the server gives a new
                # connection a few seconds for its hello, and reading every part's
                # meta.json from a slow disk must not eat into them.
                batches = await asyncio.to_thread(
                    lambda: part_batches(self.store.parts()[::-1]))
                # compression=None: permessage-deflate would squeeze every transfer
                # chunk and depth frame through zlib (tens of MB/s) for no gain
                async with connect(self.server_url, max_size=None, open_timeout=5,
                                   ping_interval=5, ping_timeout=10,
                                   compression=None) as ws:
                    backoff = 0.2
                    await self._session(ws, batches)
            except NodeRefusedError:
                raise
            except ServerBusyError as exc:
                log.warning("the server asks to come back later (%s); retrying in %.1f s",
                            exc, backoff)
            except (OSError, ConnectionClosed, InvalidHandshake, TimeoutError) as exc:
                log.info("server unreachable (%s); retrying in %.1f s", exc, backoff)
            except ProtocolError as exc:
                log.warning("server spoke an unexpected protocol (%s); retrying in %.1f s", exc,
                            backoff)
            except InvalidURI as exc:
                raise NodeRefusedError(f"bad server address {self.server_url!r}: {exc}") from exc
            finally:
                self._ws = None
            if self._stop.is_set():
                break
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._stop.wait(), backoff)
            # Until the first connection (server still starting) retry quickly.
            backoff = min(backoff * 2.0, 5.0 if self._ever_connected else 1.0)

    async def _session(self, ws: ClientConnection, batches: list[list[PartInfo]]) -> None:
        """One connection: hello with the first batch of the part listing, the rest after
        the welcome, then serve until it ends."""
        assert self.info is not None
        await ws.send(dump(Hello(node_id=self.node_id, token=self.token,
                                 backend=self.backend.name, sensor=self.info,
                                 parts=batches[0] if batches else [],
                                 agent_started=self.started)))
        first = await asyncio.wait_for(ws.recv(), 10)
        msg = parse_server_message(first)
        if isinstance(msg, Refused):
            # the close code tells a refusal for now from a final one
            with contextlib.suppress(Exception):
                await asyncio.wait_for(ws.wait_closed(), 5)
            if ws.close_code == CLOSE_TRY_AGAIN:
                raise ServerBusyError(msg.reason)
            raise NodeRefusedError(f"server refused node {self.node_id}: {msg.reason}")
        if not isinstance(msg, Welcome):
            raise ProtocolError(f"expected welcome, got {msg.type}")
        # an older server answers a warning with an error: send none to it
        self._server_takes_warnings = "warning" in (msg.accepts or [])
        for batch in batches[1:]:
            await ws.send(dump(PartList(parts=batch)))
        if "sensor_lens" in (msg.accepts or []):  # revision 3: the live view's lens
            await self._announce_lens(ws)
        log.info("connected to %s", self.server_url)
        self._ever_connected = True
        self._ws = ws
        while not self._out.empty():  # stale frames from before the reconnect
            self._out.get_nowait()
        self._flush_warnings()  # those raised while disconnected
        sender = asyncio.create_task(self._sender(ws))
        status = asyncio.create_task(self._status_loop(ws))
        stopper = asyncio.create_task(self._stop.wait())
        receiver = asyncio.create_task(self._receiver(ws))
        try:
            done, _ = await asyncio.wait({sender, status, stopper, receiver},
                                         return_when=asyncio.FIRST_COMPLETED)
            for t in done:
                if t is not stopper and t.exception() is not None:
                    raise t.exception()  # type: ignore[misc]
        finally:
            for t in (sender, status, stopper, receiver):
                t.cancel()
            self._sub = None

    async def _announce_lens(self, ws: ClientConnection) -> None:
        """Send the sensor's cameras and lenses (``sensor_lens``); a lens the protocol
        cannot carry is left out with a warning (the server then draws a pinhole)."""
        assert self.info is not None
        try:
            lens = self.backend.sensor_lens(self.info)
        except (ValidationError, InputError) as exc:
            log.warning("the sensor's lens is not announced (the live view draws a pinhole "
                        "camera): %s", exc)
            return
        if lens is not None:
            await ws.send(dump(lens))

    # ------------------------------------------------------------------ receive

    async def _receiver(self, ws: ClientConnection) -> None:
        async for raw in ws:
            t2 = self.now()
            if isinstance(raw, bytes):
                await ws.send(dump(NodeError(reason="the server sends no binary messages")))
                continue
            try:
                msg = parse_server_message(raw)
            except ProtocolError as exc:
                log.warning("rejected server message: %s", exc)
                await ws.send(dump(NodeError(reason=str(exc))))
                continue
            if isinstance(msg, Ping):
                t3 = self.now()
                await ws.send(dump(Pong(seq=msg.seq, t1=msg.t1, t2=t2, t3=t3)))
            elif isinstance(msg, RecStart | RecStop):
                self._on_command(msg)
            elif isinstance(msg, Subscribe):
                self._sub = msg if msg.fps > 0 and msg.streams else None
            elif isinstance(msg, Snapshot):
                latest = self.ring.latest()
                if latest is not None:
                    self._pool.submit(self._send_images, latest[1], msg.streams, msg.scale,
                                      msg.format, {"req_id": msg.req_id})
            elif isinstance(msg, CalibrationCapture):
                threading.Thread(target=self._calib_capture, args=(msg,), daemon=True,
                                 name="calib-capture").start()
            elif isinstance(msg, ManifestRequest):
                self._spawn(self._serve_manifest(ws, msg))
            elif isinstance(msg, DataChannel):
                self._spawn(self._serve_data_channel(ws, msg))
            elif isinstance(msg, ChunkRequest):
                self._spawn(self._serve_chunks(ws, msg))
            elif isinstance(msg, DeletePart):
                self._spawn(self._serve_delete(ws, msg))
            elif isinstance(msg, PartVerified):
                self._spawn(self._on_verified(msg))
            elif isinstance(msg, ServerError):
                log.warning("server reported: %s", msg.reason)
            elif isinstance(msg, Refused):
                raise NodeRefusedError(msg.reason)

    # ------------------------------------------------------------------ transfer

    def _spawn(self, coro: Any) -> None:
        task = asyncio.ensure_future(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    def _manifest(self, rec_id: str) -> Manifest:
        """Manifest of a closed part (cached: closed parts never change)."""
        if rec_id in self._recs:
            raise InputError(f"recording {rec_id} is still being recorded on {self.node_id}")
        meta = self.store.meta(rec_id)
        if meta.get("state") == "recording":
            raise InputError(f"recording {rec_id} was not closed on {self.node_id}")
        with self._manifest_lock:  # one hashing at a time; a second caller gets the cache
            if rec_id not in self._manifests:
                folder = self.store.root / rec_id
                names = [n for n in ("meta.json", "index.json", "frames.bin")
                         if (folder / n).exists()]
                chunk = (int(os.environ.get("GAITRIG_TEST_CHUNK_SIZE", "0"))
                         or DEFAULT_CHUNK_SIZE)
                self._manifests[rec_id] = build_manifest(folder, rec_id, self.node_id, names,
                                                         chunk_size=chunk)
            return self._manifests[rec_id]

    def _prepare_manifest(self, rec_id: str) -> None:
        """Hash a part that just closed in the background: the server asks for its
        manifest right after the stop, and then it is ready."""
        def work() -> None:
            try:
                self._manifest(rec_id)
            except (GaitrigError, TransferError, OSError) as exc:
                log.info("manifest of %s not prepared: %s", rec_id, exc)

        threading.Thread(target=work, daemon=True, name=f"manifest-{rec_id}").start()

    async def _serve_manifest(self, ws: ClientConnection, msg: ManifestRequest) -> None:
        header: dict[str, Any] = {"kind": "manifest", "req_id": msg.req_id, "rec_id": msg.rec_id}
        try:
            m = await asyncio.to_thread(self._manifest, msg.rec_id)
            await ws.send(encode_binary(header, m.to_json().encode()))
        except (GaitrigError, TransferError, OSError) as exc:
            await ws.send(encode_binary({**header, "error": str(exc)}))

    @contextlib.contextmanager
    def _in_use(self, rec_id: str) -> Iterator[None]:
        """Mark a part as being sent to the server: a purge leaves it alone."""
        self._serving[rec_id] = self._serving.get(rec_id, 0) + 1
        try:
            yield
        finally:
            self._serving[rec_id] -= 1
            if not self._serving[rec_id]:
                del self._serving[rec_id]

    async def _serve_chunks(self, ws: ClientConnection, msg: ChunkRequest) -> None:
        with self._in_use(msg.rec_id):
            await self._send_chunks(ws, msg)

    async def _send_chunks(self, ws: ClientConnection, msg: ChunkRequest) -> None:
        folder = self.store.root / msg.rec_id
        for idx in msg.indices:
            header: dict[str, Any] = {"kind": "chunk", "req_id": msg.req_id,
                                      "file": msg.file, "index": idx}
            try:
                m = self._manifests.get(msg.rec_id)
                if m is None:
                    m = await asyncio.to_thread(self._manifest, msg.rec_id)
                # the chunk is read straight behind its header: one buffer, no copy
                prefix = encode_binary(header)
                data = await asyncio.to_thread(chunk_message, folder, m, msg.file, idx, prefix)
                await _test_chunk_hooks(msg.file, idx, data, len(prefix))
                await ws.send(data)
            except (GaitrigError, TransferError, OSError) as exc:
                await ws.send(encode_binary({**header, "error": str(exc)}))
                return

    async def _serve_data_channel(self, ws: ClientConnection, msg: DataChannel) -> None:
        """Connect to the server's data port and send the chunks it asks for (``sendfile``
        from the part files), or tell the server why not (it then uses the websocket)."""
        header: dict[str, Any] = {"kind": "channel", "req_id": msg.req_id, "rec_id": msg.rec_id}
        url = urlsplit(self.server_url)
        try:
            if url.scheme == "wss":
                raise TransferError("the data channel is not encrypted and this node reaches "
                                    "the server over wss://; chunks go over the websocket")
            if os.environ.get("GAITRIG_TEST_BLOCK_DATA_CHANNEL"):
                raise ConnectionRefusedError("TEST HOOK: data channel blocked")
            m = self._manifests.get(msg.rec_id)
            if m is None:
                m = await asyncio.to_thread(self._manifest, msg.rec_id)
            sock = await asyncio.to_thread(connect_channel, url.hostname or "127.0.0.1",
                                           msg.port, msg.token)
        except (GaitrigError, TransferError, OSError) as exc:
            log.warning("no data channel for %s: %s", msg.rec_id, exc)
            await ws.send(encode_binary({**header, "error": f"{self.node_id}: {exc}"}))
            return
        manifest = m
        with self._in_use(msg.rec_id):
            await self._run_data_channel(sock, msg.rec_id, manifest)

    async def _run_data_channel(self, sock: socket.socket, rec_id: str, manifest: Manifest
                                ) -> None:
        self._channels.add(sock)
        # The sending threads take the GIL back after every chunk's sendfile; with the
        # default 5 ms switch interval the busy capture loop can make them wait that long
        # per 4 MiB chunk. A short interval while a channel is open bounds that wait.
        if len(self._channels) == 1:
            self._switch_interval = sys.getswitchinterval()
            sys.setswitchinterval(CHANNEL_SWITCH_INTERVAL_S)
        try:
            await asyncio.to_thread(serve_channel, sock, self.store.root / rec_id,
                                    lambda: manifest, _test_channel_hook)
        except (GaitrigError, TransferError, OSError) as exc:
            log.info("data channel of %s closed: %s", rec_id, exc)
        finally:
            self._channels.discard(sock)
            if not self._channels:
                sys.setswitchinterval(self._switch_interval)
            sock.close()

    async def _serve_delete(self, ws: ClientConnection, msg: DeletePart) -> None:
        """Delete a part whose recording the server deleted (health data: for real)."""
        header: dict[str, Any] = {"kind": "deleted", "req_id": msg.req_id, "rec_id": msg.rec_id}
        try:
            if msg.rec_id in self._recs:
                raise InputError(f"recording {msg.rec_id} is still being recorded on "
                                 f"{self.node_id}; stop it first")
            self._manifests.pop(msg.rec_id, None)
            self._finished.pop(msg.rec_id, None)
            existed = await asyncio.to_thread(self.store.delete, msg.rec_id)
            log.info("recording %s deleted on request of the server%s", msg.rec_id,
                     "" if existed else " (it was not on this node)")
            self._storage_changed()
            await ws.send(encode_binary({**header, "deleted": True}))
        except (GaitrigError, OSError) as exc:
            await ws.send(encode_binary({**header, "error": f"{self.node_id}: {exc}"}))

    # ------------------------------------------------------------------ retention

    async def _on_verified(self, msg: PartVerified) -> None:
        """The server holds a verified copy of a part: note it, then purge by policy."""
        try:
            noted = await asyncio.to_thread(self._note_verified, msg.rec_id,
                                            msg.manifest_sha256)
        except (GaitrigError, TransferError, OSError) as exc:
            log.warning("recording %s: the server's verified copy could not be noted (%s); "
                        "the part is kept", msg.rec_id, exc)
            return
        if noted:
            await self._purge()

    def _note_verified(self, rec_id: str, manifest_sha256: str) -> bool:
        """Persist the server's verification if it is of this node's part as it is
        (the SHA-256 of the manifest it verified against equals that of ours)."""
        if rec_id in self._recs:
            raise InputError(f"recording {rec_id} is still being recorded on {self.node_id}")
        try:
            if self.store.verified_at(rec_id) is not None:
                return False  # already noted (the server repeats itself after a reconnect)
            self.store.meta(rec_id)
        except InputError:
            return False  # not (or no longer) on this node
        ours = hashlib.sha256(self._manifest(rec_id).to_json().encode()).hexdigest()
        if ours != manifest_sha256:
            log.warning("recording %s: the server's copy was verified against another "
                        "manifest than this node's part; the part is kept", rec_id)
            return False
        if not self.store.mark_verified(rec_id, manifest_sha256):
            return False
        days = self.retention.keep_verified_s / 86400.0
        log.info("recording %s: the server holds a verified copy; this node's copy is %s",
                 rec_id, f"kept {days:g} days" if days > 0 else "deleted now")
        return True

    async def _purge(self) -> None:
        """Delete verified parts by the retention policy (in a thread; one at a time, a
        request meanwhile runs it again) and refresh the storage figures of ``status``."""
        if self._purging:
            self._purge_again = True
            return
        self._purging = True
        try:
            while True:
                self._purge_again = False
                busy = set(self._recs) | set(self._serving)
                purged, usage, space = await asyncio.to_thread(self._purge_sync, busy)
                self._after_purge(purged, usage, space)
                if not self._purge_again:
                    return
        finally:
            self._purging = False

    def _purge_sync(self, busy: set[str]) -> tuple[list[Purged], StorageUsage, tuple[int, int]]:
        purged = self.store.purge(self.retention, exclude=busy)
        return purged, self.store.usage(exclude=busy), self.store.disk_space()

    def _after_purge(self, purged: list[Purged], usage: StorageUsage,
                     space: tuple[int, int]) -> None:
        for p in purged:
            self._manifests.pop(p.rec_id, None)
            self._finished.pop(p.rec_id, None)
            self.purged_parts += 1
            self.purged_bytes += p.bytes
            self._last_purge = (f"{time.strftime('%Y-%m-%d %H:%M', time.gmtime())} UTC: "
                                f"{p.rec_id} ({p.bytes / 1e6:.1f} MB), {p.why}")
        self._usage = usage
        free, total = space
        floor = self.retention.floor(total)
        now = time.monotonic()
        if free < floor and now - self._low_space_warned >= LOW_SPACE_WARN_S:
            self._low_space_warned = now
            log.warning("only %.2f GB free on this node's disk (floor %.2f GB) and no verified "
                        "copy left to delete: %d parts (%.2f GB) wait for the server's "
                        "verification; transfer them", free / 1024**3, floor / 1024**3,
                        usage.unverified_parts, usage.unverified_bytes / 1024**3)

    def _storage_changed(self) -> None:
        """A part closed or was deleted: refresh the storage figures (and purge)."""
        loop = self._loop
        if loop is not None and loop.is_running():
            self._spawn(self._purge())

    async def _retention_loop(self) -> None:
        """Purge by age every :data:`RETENTION_FULL_S` and whenever the free space is below
        the floor (checked every :data:`RETENTION_CHECK_S`), connected or not."""
        last = -float("inf")
        while True:
            try:
                free, total = await asyncio.to_thread(self.store.disk_space)
                if (time.monotonic() - last >= RETENTION_FULL_S
                        or free < self.retention.floor(total)):
                    last = time.monotonic()
                    await self._purge()
            except OSError as exc:
                log.warning("retention check failed: %s", exc)
            await asyncio.sleep(RETENTION_CHECK_S)

    def storage(self, total_bytes: int) -> NodeStorage | None:
        """Storage figures for ``status`` (None until the first purge pass)."""
        u = self._usage
        if u is None:
            return None
        return NodeStorage(
            held_bytes=u.held_bytes, held_parts=u.held_parts, verified_bytes=u.verified_bytes,
            verified_parts=u.verified_parts, purgeable_bytes=u.purgeable_bytes,
            unverified_bytes=u.unverified_bytes, unverified_parts=u.unverified_parts,
            keep_verified_days=self.retention.keep_verified_s / 86400.0,
            min_free_bytes=self.retention.floor(total_bytes), purged_parts=self.purged_parts,
            purged_bytes=self.purged_bytes, last_purge=self._last_purge,
            unverified=list(u.unverified[:100]))

    # ------------------------------------------------------------------ frames

    def _send_now(self, data: str | bytes) -> bool:
        """Queue a frame for the server; False (the frame is dropped) when the link lags."""
        if self._ws is None:
            return False
        try:
            self._out.put_nowait(data)
        except asyncio.QueueFull:
            return False
        self._wake.set()
        return True

    def _send_control(self, text: str | bytes) -> None:
        """Queue a control message: never dropped while connected, sent before frames."""
        if self._ws is not None:
            self._control.append(text)
            self._wake.set()

    async def _sender(self, ws: ClientConnection) -> None:
        while True:
            while self._control:
                await ws.send(self._control.popleft())
            if not self._out.empty():
                await ws.send(self._out.get_nowait())
                continue
            # frames and control messages both set it: one wait per frame, not two
            # tasks and an asyncio.wait (a quarter of an idle node's event-loop time)
            self._wake.clear()
            await self._wake.wait()

    def _on_frame(self, frame: Frame) -> None:
        self._handled += 1
        frame = self._destep(frame)
        self.seq += 1
        self.frames_total += 1
        self._frame_times.append(frame.t_local)
        try:
            self.ring.push(frame.t_local, frame)
        except ValueError:
            log.warning("frame time went backwards; frame dropped")
            self.dropped += 1
            return
        msg = encode_skeletons(self.seq, frame.t_local, frame.positions, frame.states,
                               frame.body_ids)
        if self._ws is not None and not self._send_now(msg):
            self.dropped += 1
        for rec in list(self._recs.values()):
            self._record_frame(rec, frame, msg)
        sub = self._sub
        if (sub is not None and not self._sub_busy
                # 20 % slack: a frame a little early (jitter) must not wait a whole frame
                and frame.t_local - self._sub_last >= 0.8 / sub.fps):
            self._sub_last = frame.t_local
            self._sub_busy = True
            self._pool.submit(self._send_images, frame, sub.streams, sub.scale, sub.format, {})

    def _send_images(self, frame: Frame, streams: Sequence[str], scale: float, fmt: str,
                     extra: dict[str, Any]) -> None:
        try:
            # a backend's own preview is cheaper than rendering full size and downscaling
            preview = frame.preview if scale != 1.0 else None
            pre = preview is not None
            imgs = preview(streams, scale) if preview is not None else frame.images(streams)
            for name, img in imgs.items():
                data, f = encode_image(name, img, 1.0 if pre else scale, fmt)
                h, w = img.shape[:2]
                if pre:  # the header gives the full image size
                    h, w = round(h / scale), round(w / scale)
                header = {"kind": "image", "stream": name, "t": frame.t_local, "format": f,
                          "width": w, "height": h, "scale": scale, **extra}
                msg = encode_binary(header, data)
                if self._loop is not None:
                    self._loop.call_soon_threadsafe(self._send_now, msg)
        except Exception:
            log.exception("could not produce images")
        finally:
            self._sub_busy = False

    # ------------------------------------------------------------------ calibration

    def _calib_capture(self, msg: CalibrationCapture) -> None:
        """Send ``msg.frames`` full-size colour + depth frames with the camera model.

        A backend with its own ``calibration_frames(n)`` (an iterator of ``(t_local,
        colour, depth, colour_K, depth_K, T_depth_color, depth_scale)``, e.g. the simulator
        rendering the colour camera at a detection-worthy size) provides them; otherwise the
        next live frames' images are used with the intrinsics the sensor reported (colour
        and depth assumed co-located when the backend gives no extrinsics). Runs in its own
        thread; frames go on the never-dropped control queue, in order.
        """
        loop = self._loop
        if loop is None:
            return

        def send(data: bytes) -> None:
            loop.call_soon_threadsafe(self._send_control, data)

        try:
            own = getattr(self.backend, "calibration_frames", None)
            frames = own(msg.frames) if callable(own) else self._live_calib_frames(msg.frames)
            # distortion coefficients do not depend on the image size: the backend's lens
            # holds for its own calibration frames too
            c_dist = getattr(self.backend, "color_dist", None)
            d_dist = getattr(self.backend, "depth_dist", None)
            for k, (t, c, d, cK, dK, T_dc, scale) in enumerate(frames):
                send(encode_calib_frame(msg.req_id, k, msg.frames, t + self._step_corr, c, d,
                                        cK, dK, T_dc, scale, c_dist, d_dist))
        except Exception as exc:  # any failure must reach the waiting server
            log.exception("calibration capture failed")
            send(calib_error(msg.req_id, f"{self.node_id}: {exc}"))

    def _live_calib_frames(self, n: int) -> Any:
        """The next ``n`` live frames' colour + depth images (generic backends)."""
        info = self.info
        if info is None or info.color_K is None or info.depth_K is None:
            raise InputError("the sensor reported no colour/depth intrinsics; calibration "
                             "needs both")
        T_dc = getattr(self.backend, "T_depth_color", None)
        T_dc = np.eye(4) if T_dc is None else np.asarray(T_dc, float)
        last = -float("inf")
        deadline = time.monotonic() + 10.0 + n / 5.0
        sent = 0
        while sent < n:
            if time.monotonic() > deadline:
                raise InputError(f"only {sent} of {n} frames arrived in time")
            latest = self.ring.latest()
            if latest is None or latest[0] <= last:
                time.sleep(0.01)
                continue
            last, frame = latest
            imgs = frame.images(["color", "depth"])
            if "color" not in imgs or "depth" not in imgs:
                raise InputError("this node has no " + " and ".join(
                    k for k in ("color", "depth") if k not in imgs) + " image stream "
                    "(started with --no-images?); calibration needs colour and depth")
            sent += 1
            # 1000 units per metre: the Backend contract is uint16 millimetre depth
            yield (frame.t_local, imgs["color"], imgs["depth"], info.color_K, info.depth_K,
                   T_dc, 1000.0)

    # ------------------------------------------------------------------ recording

    def _on_command(self, msg: RecStart | RecStop) -> None:
        if isinstance(msg, RecStart):
            if msg.rec_id in self._recs:
                return  # duplicate (resent after a reconnect)
            old = next((p for p in self.store.parts() if p.rec_id == msg.rec_id), None)
            if old is not None and not (msg.resume and old.state == "incomplete"
                                        and self.store.meta(msg.rec_id).get("t_stop_server")
                                        is None):
                return  # duplicate, or a part that was stopped: never reopened
            try:
                if old is not None:  # this node restarted during the recording: continue
                    writer = self.store.reopen_part(
                        msg.rec_id, t_start_local=msg.t_start_local,
                        t_start_server=msg.t_start_server, clock_start=msg.clock,
                        rebase_s=msg.rebase_s, agent_started=self.started)
                    self._manifests.pop(msg.rec_id, None)
                    self._finished.pop(msg.rec_id, None)
                else:
                    writer = self.store.create_part(
                        msg.rec_id, node_id=self.node_id, t_start_local=msg.t_start_local,
                        t_start_server=msg.t_start_server, streams=list(msg.streams),
                        image_every=msg.image_every, clock_start=msg.clock,
                    )
            except (GaitrigError, OSError) as exc:
                # The server must learn it as the part's state (else the part waits as
                # "pending" for ever); re-announced like any closed part.
                log.error("cannot record %s: %s", msg.rec_id, exc)
                failed = PartInfo(rec_id=msg.rec_id, state="incomplete",
                                  reason=self._write_failure(exc, 0))
                if old is not None:  # what it holds stays as it was
                    failed = old.model_copy(update={"reason": (
                        f"{old.reason or 'closed early'}; not recording again: {exc}")})
                self._finished[msg.rec_id] = (failed, time.monotonic())
                self._send_control(dump(RecState(part=failed)))
                return
            rec = _Rec(msg, writer, rebase=msg.rebase_s if old is not None else 0.0)
            if old is not None and writer.t_last is not None:
                rec.gap_s = max(0.0, msg.t_start_local + rec.rebase - writer.t_last)
                log.warning("recording %s is still running: recording again into its part "
                            "(%.1f s missing since this node stopped)", msg.rec_id, rec.gap_s)
            self._recs[msg.rec_id] = rec
            early = self._early_stops.pop(msg.rec_id, None)
            if early is not None:  # the stop overtook the start (reordered delivery)
                rec.stop_cmd, rec.t_stop_local = early, early.t_stop_local
            # The command may arrive after its start time: take the past from the ring.
            for _t, fr in self.ring.since(msg.t_start_local):
                self._record_frame(rec, fr, encode_skeletons(0, fr.t_local + rec.rebase,
                                                             fr.positions, fr.states,
                                                             fr.body_ids))
                if msg.rec_id not in self._recs:
                    return
            if self.ring.oldest is not None and self.ring.oldest > msg.t_start_local:
                log.warning("recording %s started %.2f s before the ring buffer's oldest frame",
                            msg.rec_id, self.ring.oldest - msg.t_start_local)
            self._send_control(dump(RecState(part=writer.info())))
            late = self.now() - msg.t_start_local
            if late > 0:
                log.info("recording %s: command arrived %.0f ms after the start; %d frames "
                         "taken from the ring buffer", msg.rec_id, late * 1e3, writer.n_frames)
            else:
                log.info("recording %s starts in %.0f ms", msg.rec_id, -late * 1e3)
        else:
            rec_ = self._recs.get(msg.rec_id)
            if rec_ is None:
                if not any(p.rec_id == msg.rec_id for p in self.store.parts()):
                    self._early_stops[msg.rec_id] = msg
                return
            rec_.stop_cmd = msg
            rec_.t_stop_local = msg.t_stop_local
            latest = self.ring.latest()
            if latest is not None and latest[0] > msg.t_stop_local:
                # Frames after the stop time were written while the command travelled.
                with rec_.lock:
                    rec_.writer.truncate_after(msg.t_stop_local + rec_.rebase)
                self._finish(rec_, "on_node", None)

    def _record_frame(self, rec: _Rec, frame: Frame, msg: bytes) -> None:
        if frame.t_local < rec.cmd.t_start_local:
            return
        if frame.t_local > rec.t_stop_local:
            self._finish(rec, "on_node", None)
            return
        if rec.rebase:  # a resumed part: its frames on its first clock's origin
            msg = encode_skeletons(self.seq, frame.t_local + rec.rebase, frame.positions,
                                   frame.states, frame.body_ids)
        try:
            with rec.lock:
                rec.writer.append(frame.t_local + rec.rebase, "skeleton", msg)
        except OSError as exc:  # disk full, quota, I/O error: keep what is written
            self._finish(rec, "incomplete", self._write_failure(exc, rec.writer.n_frames))
            return
        rec.n_seen += 1
        if rec.cmd.streams and (rec.n_seen - 1) % rec.cmd.image_every == 0:
            rec.pending_images = [f for f in rec.pending_images if not f.done()]
            if len(rec.pending_images) >= MAX_IMAGE_BACKLOG:
                if rec.images_skipped == 0:
                    log.warning("recording %s: images are encoded slower than they are "
                                "recorded; leaving some out (record images of fewer frames)",
                                rec.cmd.rec_id)
                rec.images_skipped += 1
            else:
                rec.pending_images.append(
                    self._pool.submit(self._record_images, rec, frame, rec.cmd.streams))

    def _record_images(self, rec: _Rec, frame: Frame, streams: Sequence[str]) -> None:
        imgs = frame.images(streams)
        for name, img in imgs.items():
            data, f = encode_image(name, img, 1.0, "png")
            t = frame.t_local + rec.rebase
            header = {"kind": "image", "stream": name, "t": t, "format": f,
                      "width": img.shape[1], "height": img.shape[0], "scale": 1.0}
            try:
                with rec.lock:
                    if not rec.writer.closed:
                        rec.writer.append(t, "image", encode_binary(header, data))
            except OSError as exc:
                if self._loop is not None:  # _finish waits for this thread: not from here
                    self._loop.call_soon_threadsafe(
                        self._finish, rec, "incomplete",
                        self._write_failure(exc, rec.writer.n_frames))
                return

    def _write_failure(self, exc: OSError | GaitrigError, n_frames: int) -> str:
        """Why a part stopped early on this node, in words for the clinician."""
        errno_ = getattr(exc, "errno", None)
        if errno_ in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
            what = f"node {self.node_id}'s disk is full"
        elif errno_ == errno.EROFS:
            what = f"node {self.node_id}'s recordings folder is read-only"
        else:
            what = f"node {self.node_id} could not write its recording ({exc})"
        if n_frames == 0:
            return f"{what}; nothing was recorded there"
        return (f"{what}; recording stopped there after {n_frames} frames, which are kept "
                "and transferred")

    def _finish(self, rec: _Rec, state: str, reason: str | None) -> None:
        if rec.cmd.rec_id not in self._recs:
            return
        del self._recs[rec.cmd.rec_id]
        for fut in rec.pending_images:
            with contextlib.suppress(Exception):
                fut.result(timeout=10)
        if rec.gap_s is not None:  # a resumed part: whole but for the gap, which is said
            gap = (f"node {self.node_id} was restarted during the recording: {rec.gap_s:.1f} s "
                   "are missing, the frames before and after are kept")
            state, reason = "incomplete", f"{gap}; {reason}" if reason else gap
        with rec.lock:
            try:
                info = rec.writer.close(
                    state, reason,
                    t_stop_local=rec.t_stop_local + rec.rebase if rec.stop_cmd else None,
                    t_stop_server=rec.stop_cmd.t_stop_server if rec.stop_cmd else None,
                    clock_stop=rec.stop_cmd.clock if rec.stop_cmd else {},
                    images_skipped=rec.images_skipped,
                )
            except OSError as exc:
                # not even meta.json could be written: tell the server anyway; the next
                # start of the node recovers the part as incomplete
                state, reason = "incomplete", self._write_failure(exc, rec.writer.n_frames)
                info = rec.writer.info(state, reason)
        log.info("recording %s %s: %d frames%s", info.rec_id, state, info.n_frames,
                 f" ({rec.images_skipped} without their images)" if rec.images_skipped else "")
        self._finished[info.rec_id] = (info, time.monotonic())
        self._send_control(dump(RecState(part=info)))
        self._prepare_manifest(info.rec_id)
        self._storage_changed()

    # ------------------------------------------------------------------ warnings

    def _on_backend_warning(self, text: str) -> None:
        """The backend's :meth:`Backend.warn` (any thread): queue it for the server."""
        loop = self._loop
        if loop is None or loop.is_closed():
            return  # not running: the log has it
        with contextlib.suppress(RuntimeError):  # the loop closing meanwhile
            loop.call_soon_threadsafe(self._queue_warning, text)

    def _queue_warning(self, text: str) -> None:
        """Queue a warning (event loop): a text already waiting counts one more repeat."""
        text = " ".join(text.split()) or "The sensor backend raised an empty warning."
        t = self.now()
        for w in self._warnings:
            if w.text == text:
                w.repeats += 1
                w.t = t
                break
        else:
            if len(self._warnings) >= WARNING_BACKLOG:
                self._warnings.popleft()
                self.warnings_dropped += 1
            self._warnings.append(_PendingWarning(text, t))
        self._flush_warnings()

    def _flush_warnings(self) -> None:
        """Send the waiting warnings the rate limit allows (event loop); they wait while
        the node is disconnected or its server does not take them."""
        now = time.monotonic()
        self._warning_tokens = min(float(WARNING_BURST), self._warning_tokens
                                   + (now - self._warning_refilled) / WARNING_INTERVAL_S)
        self._warning_refilled = now
        if self._ws is None or not self._server_takes_warnings:
            return
        while self._warnings and self._warning_tokens >= 1.0:
            w = self._warnings.popleft()
            self._warning_tokens -= 1.0
            self._send_control(dump(NodeWarning(text=w.text, t=w.t, repeats=w.repeats)))

    # ------------------------------------------------------------------ status

    def fps(self) -> float:
        """Frame rate over the last ~4 s of frames."""
        ts = self._frame_times
        if len(ts) < 2 or ts[-1] <= ts[0]:
            return 0.0
        return (len(ts) - 1) / (ts[-1] - ts[0])

    async def _status_loop(self, ws: ClientConnection) -> None:
        while True:
            diag = self.backend.diagnostics(time.time()) if self.report_true_clock else {}
            free, total = await asyncio.to_thread(self.store.disk_space)
            await ws.send(dump(Status(fps=self.fps(), frames=self.frames_total,
                                      dropped=self.dropped + self._dropped_capture,
                                      disk_free_bytes=free,
                                      ring_seconds=self.ring.span, diag=diag,
                                      storage=self.storage(total))))
            for rec in self._recs.values():
                self._send_control(dump(RecState(part=rec.writer.info())))
            # Re-announce parts closed in the last 30 s (the server's update is idempotent),
            # so a state lost with a broken connection still arrives.
            now = time.monotonic()
            for rec_id, (info, t_done) in list(self._finished.items()):
                if now - t_done > 30.0:
                    del self._finished[rec_id]
                else:
                    self._send_control(dump(RecState(part=info)))
            self._flush_warnings()  # those waiting for the rate limit
            await asyncio.sleep(1.0)
