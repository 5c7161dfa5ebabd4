"""Live depth panels for the console, streamed over a websocket as JPEG.

While anyone watches (a Live page websocket or the 3D view's point cloud), every connected
node is subscribed to ``depth`` + ``body_index`` as lossless PNG at ``scale`` and ``fps``
(the node throttles, and renders one image set at a time). The server decodes each new
pair once, colourises the depth (turbo, 0.5–4.5 m, black = no measurement), paints the
pixels of tracked bodies in :data:`HIGHLIGHT_RGB` (a magenta the turbo map never uses) and
encodes one JPEG that all watchers share. The raw depth also feeds the merged point cloud
of the 3D view (:mod:`app.viewer.live`).

Each watcher has one slot per node holding only the newest panel: a slow browser skips
frames (counted in ``dropped``) instead of queueing them, and a panel is sent only when a
new image arrived. Messages are binary: ``uint32`` little-endian header length, a JSON
header (``node``, ``seq``, ``t_capture`` = capture time in server seconds, ``t_local`` =
the same on the node's clock, ``t_sent``,
``fps``, ``body_pixels``, ``width``, ``height``) and the JPEG. Text messages carry
``{"type": "time", "t": server_time, "echo": ...}`` answers to the page's clock pings so
the page can put the capture time on its own clock and show the end-to-end latency.
When nobody has watched for :data:`IDLE_UNSUBSCRIBE_S`, the nodes are told to stop.

A node holds one image subscription, so :class:`LiveStreams` is the only one that talks
to the nodes about it: ``POST /api/nodes/{id}/subscribe`` hands its request to
:meth:`LiveStreams.request`, and while the live view streams a node the node gets the
union (the live view's 16-bit PNG depth and body index at its scale and rate, plus the
API's streams, in that form, at the higher of both rates). Another request can therefore
never stop or change the live panels, and the API's subscription comes back as asked
when nobody watches any more.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import struct
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from app.nodes.protocol import Subscribe, dump
from app.server.hub import Hub
from app.server.registry import LatestImage, NodeSession

log = logging.getLogger("gaitrig.streaming")

HIGHLIGHT_RGB = (255, 0, 200)
DEPTH_RANGE_MM = (500.0, 4500.0)
IDLE_UNSUBSCRIBE_S = 5.0
PAIR_WAIT_S = 0.2  # how long a depth image waits for its body-index image
SUB_CHECK_S = 0.5  # subscriptions are brought up to date this often
POLL_S = 0.01  # new images are looked for this often while nodes may be sending them


@dataclass
class DepthFrame:
    """One decoded depth + body-index pair of a node (images at the subscribed scale)."""

    node: str
    seq: int
    t_local: float
    t_capture: float | None
    depth_mm: NDArray[np.uint16]
    body: NDArray[np.bool_] | None
    scale: float


@dataclass
class Panel:
    """The newest encoded panel of one node, shared by all watchers."""

    node: str
    seq: int
    message: bytes
    t_capture: float | None


def colourise(depth_mm: NDArray[np.uint16], body: NDArray[np.bool_] | None) -> NDArray[np.uint8]:
    """Depth (mm) → BGR turbo image; body pixels in the highlight colour, no data black."""
    lo, hi = DEPTH_RANGE_MM
    norm = np.clip((depth_mm.astype(np.float32) - lo) * (255.0 / (hi - lo)), 0, 255)
    img = cv2.applyColorMap(norm.astype(np.uint8), cv2.COLORMAP_TURBO)
    img[depth_mm == 0] = 0
    if body is not None and body.any():
        # keep a little depth shading so the body's shape stays readable
        shade = (0.75 + 0.25 * (1.0 - norm[body] / 255.0))[:, None]
        img[body] = (np.array(HIGHLIGHT_RGB[::-1], np.float32) * shade).astype(np.uint8)
    return img


def encode_panel(frame: DepthFrame, fps: float, quality: int = 80) -> bytes:
    """The websocket message of one panel (header + JPEG)."""
    img = colourise(frame.depth_mm, frame.body)
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise ValueError("JPEG encoding failed")
    header = {"node": frame.node, "seq": frame.seq, "t_capture": frame.t_capture,
              "t_local": frame.t_local, "t_sent": time.time(), "fps": round(fps, 2),
              "body_pixels": int(frame.body.sum()) if frame.body is not None else 0,
              "width": int(img.shape[1]), "height": int(img.shape[0])}
    h = json.dumps(header, separators=(",", ":")).encode()
    return struct.pack("<I", len(h)) + h + buf.tobytes()


def decode_pair(node: str, seq: int, depth: LatestImage,
                body: LatestImage | None) -> DepthFrame:
    """Decode a node's PNG depth (uint16) and body index (255 = no body)."""
    d = cv2.imdecode(np.frombuffer(depth.data, np.uint8), cv2.IMREAD_UNCHANGED)
    if d is None or d.dtype != np.uint16 or d.ndim != 2:
        raise ValueError(f"node {node} sent a depth image that is not 16-bit PNG")
    mask = None
    if body is not None:
        b = cv2.imdecode(np.frombuffer(body.data, np.uint8), cv2.IMREAD_UNCHANGED)
        if b is not None and b.shape == d.shape:
            mask = b != 255
    return DepthFrame(node, seq, depth.t_local, depth.t_server, d.astype(np.uint16, copy=False),
                      mask,
                      float(depth.header.get("scale", 1.0)))


@dataclass(eq=False)
class Watcher:
    """One browser: newest undelivered panel per node, woken when one arrives.

    Flow control is by credit per node: at most ``window`` panels of a node may be
    unacknowledged (the page acknowledges each panel once drawn, naming its node), so a
    slow page never has a backlog in the socket buffers — newer panels replace older ones
    in :attr:`pending` meanwhile — and one node's panels never wait for another's. Two
    per node keep a node's rate when the round trip to the page is long (a loaded
    machine) without adding more than a panel of delay.
    """

    send: Callable[[bytes], Any]
    window: int = 2
    pending: dict[str, Panel] = field(default_factory=dict)
    wake: asyncio.Event = field(default_factory=asyncio.Event)
    sent: int = 0
    dropped: int = 0
    # node → its unacknowledged panels; oldest node first, for acks that name no node
    _flight: dict[str, int] = field(default_factory=dict)
    _order: deque[str] = field(default_factory=deque)

    @property
    def in_flight(self) -> int:
        """Panels sent and not yet acknowledged, all nodes."""
        return len(self._order)

    def offer(self, panel: Panel) -> None:
        if panel.node in self.pending:
            self.dropped += 1  # the browser is behind: replace, never queue
        self.pending[panel.node] = panel
        self.wake.set()

    def ack(self, n: int = 1, node: str | None = None) -> None:
        """The page drew ``n`` panels (of ``node``; None: the oldest ones in flight)."""
        for _ in range(max(0, min(n, 64))):
            if node is not None and self._flight.get(node):
                self._order.remove(node)
                done = node
            elif self._order:
                done = self._order.popleft()
            else:
                break
            self._flight[done] -= 1
        self.wake.set()

    async def run(self) -> None:
        """Deliver panels until the socket fails (the caller cancels on disconnect)."""
        while True:
            await self.wake.wait()
            self.wake.clear()
            for node in [k for k in self.pending if self._flight.get(k, 0) < self.window]:
                panel = self.pending.pop(node)
                self._flight[node] = self._flight.get(node, 0) + 1
                self._order.append(node)
                await self.send(panel.message)
                self.sent += 1


class LiveStreams:
    """Subscriptions, decoding and fan-out of the live depth panels.

    Args:
        hub: the node hub (registry with every node's newest images).
        fps: requested image rate per node.
        scale: image downscale factor requested from the nodes.
    """

    def __init__(self, hub: Hub, fps: float = 15.0, scale: float = 0.5) -> None:
        self.hub = hub
        self.fps = fps
        self.scale = scale
        self.watchers: set[Watcher] = set()
        self.cloud_consumers = 0
        self.panels: dict[str, Panel] = {}
        self.frames: dict[str, DepthFrame] = {}
        self.frame_listeners: list[Callable[[DepthFrame], None]] = []
        # node → the last depth image handled (kept, so identity comparison is safe)
        self._seen: dict[str, LatestImage] = {}
        self._seq: dict[str, int] = {}
        self._rate: dict[str, list[float]] = {}
        self.external: dict[str, Subscribe] = {}  # node → subscription asked for by the API
        # node → (connected_at, subscription) the node was last told; None = stopped
        self._sent: dict[str, tuple[float | None, Subscribe | None]] = {}
        self._live_on = False  # the live view's subscription is in force
        self._sub_lock = asyncio.Lock()  # one subscription update at a time
        self._idle_since: float | None = time.time()
        self._task: asyncio.Task[None] | None = None
        self._busy: set[str] = set()
        self._wake = asyncio.Event()  # a watcher or an API request: stop idling now

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> None:
        """Start the pump on the running event loop (idempotent)."""
        if self._task is None or self._task.done():
            self._task = asyncio.get_running_loop().create_task(self._pump())

    async def stop(self) -> None:
        """Stop the pump and unsubscribe the nodes."""
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
        self._live_on = False
        self.external.clear()
        await self._sync_subscriptions()

    @property
    def watched(self) -> bool:
        """Whether anybody needs images now."""
        return bool(self.watchers) or self.cloud_consumers > 0

    def add_watcher(self, w: Watcher) -> None:
        """Register a browser; it gets every node's current panel at once."""
        self.watchers.add(w)
        for p in self.panels.values():
            w.offer(p)
        self.start()
        self._wake.set()

    def remove_watcher(self, w: Watcher) -> None:
        self.watchers.discard(w)

    def node_fps(self, node: str) -> float:
        """Panels per second of a node over the last ~2 s."""
        ts = self._rate.get(node, [])
        if len(ts) < 2 or ts[-1] <= ts[0]:
            return 0.0
        return (len(ts) - 1) / (ts[-1] - ts[0])

    def stats(self) -> dict[str, Any]:
        """Rates and watcher counters (for the API and the page)."""
        return {"fps_requested": self.fps, "scale": self.scale, "watchers": len(self.watchers),
                "nodes": {n: {"fps": round(self.node_fps(n), 2), "seq": self._seq.get(n, 0),
                              "body_pixels": int(f.body.sum()) if f.body is not None else 0}
                          for n, f in sorted(self.frames.items())},
                "sent": sum(w.sent for w in self.watchers),
                "dropped": sum(w.dropped for w in self.watchers)}

    # ------------------------------------------------------------------ pump

    def live_subscription(self) -> Subscribe:
        """What the live panels and the point cloud need from every node."""
        return Subscribe(streams=["depth", "body_index"], fps=self.fps, scale=self.scale,
                         format="png")

    def effective(self, node: str) -> Subscribe | None:
        """The subscription node ``node`` should have now (None: no images)."""
        ext = self.external.get(node)
        if not self._live_on:
            return ext
        own = self.live_subscription()
        if ext is None:
            return own
        extra = [x for x in ext.streams if x not in own.streams]
        return Subscribe(streams=[*own.streams, *extra], fps=max(own.fps, ext.fps),
                         scale=own.scale, format="png")

    async def request(self, node: str, sub: Subscribe) -> Subscribe | None:
        """An API client's subscription for ``node`` (``fps`` 0 or no streams: cancel it).

        Returns:
            What the node is told now: the request itself, or — while the live view streams
            the node — the union with the live view's subscription (see the module doc).
        """
        if sub.fps > 0 and sub.streams:
            self.external[node] = sub
        else:
            self.external.pop(node, None)
        self._wake.set()
        await self._sync_subscriptions(only=node)
        return self.effective(node)

    async def _sync_subscriptions(self, only: str | None = None) -> None:
        """Tell each node (or just ``only``) its effective subscription if it changed."""
        async with self._sub_lock:
            await self._sync_locked(only)

    async def _sync_locked(self, only: str | None) -> None:
        for s in list(self.hub.registry.nodes.values()):
            if only is not None and s.id != only:
                continue
            if not s.connected or s.send is None:
                continue
            want = self.effective(s.id)
            last = self._sent.get(s.id)
            if last is None and want is None:
                continue  # never told anything: it streams nothing
            if last is not None and last == (s.connected_at, want):
                continue
            msg = want if want is not None else Subscribe(streams=["depth"], fps=0)
            try:
                await s.send(dump(msg))
                self._sent[s.id] = (s.connected_at, want)
            except Exception as exc:  # a node that just left: retried next round
                log.info("could not update the subscription of %s: %s", s.id, exc)

    def _streaming(self) -> bool:
        """Whether nodes may be sending images to look for every :data:`POLL_S`."""
        return self._live_on or self.watched or bool(self.external)

    async def _pump(self) -> None:
        last_sub_check = 0.0
        while True:
            now = time.time()
            if now - last_sub_check > SUB_CHECK_S:
                last_sub_check = now
                if self.watched:
                    self._idle_since = None
                    self._live_on = True
                else:
                    self._idle_since = self._idle_since or now
                    if now - self._idle_since > IDLE_UNSUBSCRIBE_S:
                        self._live_on = False
                await self._sync_subscriptions()
            for s in list(self.hub.registry.nodes.values()):
                self._check(s, now)
            if self._streaming():
                await asyncio.sleep(POLL_S)
                continue
            # Idle (nobody watches, nothing subscribed): no 100 wake-ups a second for
            # nothing. Sleep until the next subscription check (kept on its 0.5 s beat)
            # or until a watcher or a request comes; a snapshot's image meanwhile waits
            # for that check (no panel shows it).
            self._wake.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._wake.wait(),
                                       last_sub_check + SUB_CHECK_S + POLL_S - time.time())

    def _check(self, s: NodeSession, now: float) -> None:
        depth = s.images.get("depth")
        if depth is None or depth.format != "png" or depth is self._seen.get(s.id):
            return
        if s.id in self._busy:
            return
        body = s.images.get("body_index")
        paired = body is not None and body.t_local == depth.t_local
        if not paired and depth.t_server is not None and now - depth.t_server < PAIR_WAIT_S:
            return  # its body-index image is probably on the wire
        self._seen[s.id] = depth
        self._busy.add(s.id)
        seq = self._seq.get(s.id, 0) + 1
        self._seq[s.id] = seq
        asyncio.get_running_loop().create_task(
            self._process(s.id, seq, depth, body if paired else None))

    async def _process(self, node: str, seq: int, depth: LatestImage,
                       body: LatestImage | None) -> None:
        try:
            rate = self._rate.setdefault(node, [])
            rate.append(time.time())
            while rate and rate[0] < rate[-1] - 2.0:
                rate.pop(0)
            frame = await asyncio.to_thread(decode_pair, node, seq, depth, body)
            msg = await asyncio.to_thread(encode_panel, frame, self.node_fps(node))
        except Exception as exc:
            log.warning("could not make the live panel of %s: %s", node, exc)
            return
        finally:
            self._busy.discard(node)
        self.frames[node] = frame
        panel = Panel(node, seq, msg, frame.t_capture)
        self.panels[node] = panel
        for w in list(self.watchers):
            w.offer(panel)
        for cb in self.frame_listeners:
            try:
                cb(frame)
            except Exception:
                log.exception("live frame listener failed")
