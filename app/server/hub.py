"""The node websocket endpoint and the server state it feeds.

:class:`Hub` holds the registry and the recording manager and runs one
:meth:`Hub.handle_node` per connected node: authentication by pairing token, a clock
ping loop, and the message loop. A malformed or oversized message is answered with an
``error`` message and logged with its reason; the connection stays open (only frames above
the transport limit, ``Settings.ws_transport_max_bytes``, make the websocket layer close
it with code 1009). Refusals are bounded per connection (:class:`RefusalBudget`): beyond a
burst they are counted, not answered or logged one by one, and summarised once a window
(log and the node's health); a node that keeps sending refused messages past
:data:`MAX_REFUSED_PER_WINDOW` a window is disconnected (:data:`CLOSE_FLOOD`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import secrets
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from fastapi import WebSocket, WebSocketDisconnect
from starlette.websockets import WebSocketState

from app.api.security import LoginThrottle
from app.config import Settings
from app.nodes.protocol import (
    ACCEPTED_NODE_MESSAGES,
    Hello,
    NodeError,
    NodeWarning,
    PartInfo,
    PartList,
    Ping,
    Pong,
    ProtocolError,
    RecState,
    Refused,
    SensorLens,
    ServerError,
    Status,
    Welcome,
    decode_binary,
    decode_skeletons,
    dump,
    lens_mismatch,
    parse_node_message,
)
from app.server.recording import RecordingManager
from app.server.registry import LatestImage, LatestSkeleton, NodeRegistry, NodeSession
from app.server.transfer import TransferManager

log = logging.getLogger("gaitrig.hub")

CLOSE_REFUSED = 4401
CLOSE_PROTOCOL = 4400
CLOSE_REPLACED = 4409
CLOSE_BUSY = 1013  # try again later
#: Policy violation: the node kept sending messages the server refuses (a broken or hostile
#: node); an ordinary close for the agent, which reconnects after its back-off.
CLOSE_FLOOD = 1008
#: Refusals answered and logged one by one on a connection: a burst of this many, refilled
#: at :data:`REFUSALS_PER_S`. A working node is refused a handful of messages in a day (a
#: lens that does not match, a message of a newer revision), so it never reaches the end.
REFUSAL_BURST = 20
REFUSALS_PER_S = 1.0
#: Beyond the budget, refusals are counted and summarised once per window of this length.
REFUSAL_WINDOW_S = 10.0
#: Refused messages in one window past which the connection is closed (100 a second for
#: ten seconds: no working node comes near; a flood costs the server a parse each).
MAX_REFUSED_PER_WINDOW = 1000
#: Node connections that have not yet presented a valid hello, at once. Each may send one
#: message up to the transport limit before it is checked, so this bounds what anonymous
#: clients on the LAN can make the server hold (as the data channel's MAX_HANDSHAKES).
MAX_PENDING_HELLOS = 8
#: Of those, from one remote address: one peer holding every slot (opening connections and
#: never saying hello, a slowloris) would otherwise lock every node out; with this, a flood
#: from one address leaves the other slots to nodes elsewhere on the LAN.
MAX_PENDING_HELLOS_PER_ADDRESS = 2
#: Addresses the per-address limit does not apply to: the server's own machine, where the
#: demo's six nodes (or a PC driving several sensors beside the server) open their
#: connections in the same instant; a process there could take the whole machine anyway,
#: and the global :data:`MAX_PENDING_HELLOS` still holds.
OWN_MACHINE_ADDRESSES = frozenset({"127.0.0.1", "::1"})
#: Seconds a new connection has to send its hello. A node sends it as soon as the websocket
#: is open (milliseconds on a LAN), so this only bounds how long a silent peer holds a slot.
HELLO_TIMEOUT_S = 5.0
#: Largest image a node may send, in pixels: the largest sensor mode (Azure Kinect colour
#: 4096×3072) with room. A few kB of PNG or JPEG can declare far more, and the decoder
#: would allocate for the declaration (a decompression bomb), so the header is read first.
MAX_IMAGE_PIXELS = 4096 * 4096
_PNG = b"\x89PNG\r\n\x1a\n"
#: JPEG start-of-frame markers (they carry the image size); C4, C8, CC are not frames.
_JPEG_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}


def image_size(data: bytes) -> tuple[int, int] | None:
    """``(width, height)`` that a PNG or JPEG declares in its header; None for anything
    else or a header cut short (the decoder then refuses it itself)."""
    if data[:8] == _PNG and data[12:16] == b"IHDR" and len(data) >= 24:
        w, h = struct.unpack(">II", data[16:24])
        return int(w), int(h)
    if data[:2] != b"\xff\xd8":
        return None
    i = 2
    while i + 4 <= len(data):
        if data[i] != 0xFF:
            return None
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker == 0x01 or 0xD0 <= marker <= 0xD8:  # markers without a length
            i += 2
            continue
        if marker in _JPEG_SOF:
            if i + 9 > len(data):
                return None
            h, w = struct.unpack(">HH", data[i + 5:i + 9])
            return int(w), int(h)
        i += 2 + struct.unpack(">H", data[i + 2:i + 4])[0]
    return None


def check_image_size(data: bytes, what: str) -> None:
    """Refuse an image whose header declares more than :data:`MAX_IMAGE_PIXELS`.

    Raises:
        ProtocolError: it does (the message names the size and the limit).
    """
    size = image_size(data)
    if size is not None and size[0] * size[1] > MAX_IMAGE_PIXELS:
        raise ProtocolError(f"{what} declares {size[0]}×{size[1]} pixels, more than the "
                            f"{MAX_IMAGE_PIXELS:,} a sensor image may have")


@dataclass
class RefusalBudget:
    """How many refused messages of one connection are answered and logged one by one
    (a token bucket), and the count of the current window for its summary.

    Times are ``time.monotonic()`` seconds.
    """

    node_id: str
    tokens: float = float(REFUSAL_BURST)
    last: float | None = None
    window_start: float | None = None
    in_window: int = 0  # refused in the current window
    counted: int = 0  # of those, counted only (neither answered nor logged)
    first_reason: str = ""

    def refuse(self, reason: str, now: float) -> bool:
        """Count a refused message.

        Returns:
            Whether it may be answered and logged by itself (within the budget).
        """
        if self.last is not None:
            self.tokens = min(float(REFUSAL_BURST),
                              self.tokens + (now - self.last) * REFUSALS_PER_S)
        self.last = now
        if self.window_start is None:
            self.window_start = now
        if self.in_window == 0:
            self.first_reason = reason
        self.in_window += 1
        if self.tokens >= 1.0:
            self.tokens -= 1.0
            return True
        self.counted += 1
        return False

    @property
    def flooding(self) -> bool:
        """Whether this window's refusals passed :data:`MAX_REFUSED_PER_WINDOW`."""
        return self.in_window > MAX_REFUSED_PER_WINDOW

    def summary(self, now: float | None = None) -> str | None:
        """The window's summary when some of its refusals were only counted, else None;
        with ``now``, only once the window has ended (it then starts afresh)."""
        if self.window_start is None:
            return None
        elapsed = (now if now is not None else time.monotonic()) - self.window_start
        if now is not None and elapsed < REFUSAL_WINDOW_S:
            return None
        text = None
        if self.counted:
            text = (f"node {self.node_id}: {self.in_window:,} messages refused in the last "
                    f"{max(elapsed, 0.1):.0f} s ({self.counted:,} of them counted only, not "
                    f"answered or logged); the first: {self.first_reason[:200]}")
        self.window_start, self.in_window, self.counted = None, 0, 0
        return text


class Hub:
    """Server state shared by the REST routes and the node websocket.

    Args:
        settings: server settings.
    """

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.registry = NodeRegistry(settings.clock_window_s, settings.clock_warn_ms,
                                     settings.health_stale_s)
        self.recordings = RecordingManager(self.registry, settings.data_dir,
                                           settings.record_start_margin_s,
                                           settings.test_command_delay_max_s)
        self.transfers = TransferManager(self.registry, self.recordings, settings.data_dir,
                                         data_host=settings.host,
                                         data_port=settings.transfer_port)
        self._sockets: dict[str, WebSocket] = {}
        #: Connection number of each node's current connection: a replaced connection's
        #: loop sees it changed and handles nothing more (messages it had buffered before
        #: the replacement would otherwise act on the new connection's state).
        self._generation: dict[str, int] = {}
        self._next_generation = 0
        self._pending_hellos = 0
        self._pending_by_address: dict[str, int] = {}
        #: Wrong pairing tokens per address: a rogue process on the LAN guessing the token
        #: gets a handful of tries per window, as a password guesser does at the login.
        self._token_failures = LoginThrottle(5, 300.0)
        self._agent_started: dict[str, float] = {}
        self.skeleton_listeners: list[Callable[[NodeSession], None]] = []
        #: Binary kind → handler ``(session, header, payload)`` for kinds other modules own
        #: (``calib``: :mod:`app.server.calibration`'s capture).
        self.binary_listeners: dict[str, Callable[[NodeSession, dict[str, Any], bytes],
                                                  None]] = {}

    async def close(self) -> None:
        """Close every node connection (server shutdown)."""
        await self.transfers.close()
        for ws in list(self._sockets.values()):
            with contextlib.suppress(Exception):
                await ws.close(code=1001, reason="server shutting down")

    # ------------------------------------------------------------------ websocket

    async def handle_node(self, ws: WebSocket) -> None:
        """Serve one node connection until it closes."""
        await ws.accept()
        peer = f"{ws.client.host}:{ws.client.port}" if ws.client else "?"
        address = ws.client.host if ws.client else "?"
        if (address not in OWN_MACHINE_ADDRESSES
                and self._pending_by_address.get(address, 0) >= MAX_PENDING_HELLOS_PER_ADDRESS):
            await self._refuse(ws, peer, f"{MAX_PENDING_HELLOS_PER_ADDRESS} connections from "
                               f"{address} are already waiting to say hello; try again in a "
                               "few seconds", CLOSE_BUSY)
            return
        if self._pending_hellos >= MAX_PENDING_HELLOS:
            await self._refuse(ws, peer, f"{MAX_PENDING_HELLOS} connections are already "
                               "waiting to say hello; try again in a few seconds", CLOSE_BUSY)
            return
        self._pending_hellos += 1
        self._pending_by_address[address] = self._pending_by_address.get(address, 0) + 1
        try:
            first = await asyncio.wait_for(ws.receive(), timeout=HELLO_TIMEOUT_S)
        except (TimeoutError, WebSocketDisconnect):
            await self._refuse(ws, peer, f"no hello within {HELLO_TIMEOUT_S:g} s",
                               CLOSE_PROTOCOL)
            return
        finally:
            self._pending_hellos -= 1
            left = self._pending_by_address.pop(address) - 1
            if left > 0:
                self._pending_by_address[address] = left
        text = first.get("text")
        if text is None:
            await self._refuse(ws, peer, "first message must be a JSON hello", CLOSE_PROTOCOL)
            return
        try:
            hello = parse_node_message(text, self.settings.max_control_bytes)
        except ProtocolError as exc:
            await self._refuse(ws, peer, str(exc), CLOSE_PROTOCOL)
            return
        if not isinstance(hello, Hello):
            await self._refuse(ws, peer, f"expected hello first, got {hello.type}", CLOSE_PROTOCOL)
            return
        if hello.node_id in (".", ".."):  # names a folder of the server's recordings
            await self._refuse(ws, peer, f"node id {hello.node_id!r} is not allowed; use "
                               "letters, digits, '_', '-' or '.' (e.g. S1)", CLOSE_PROTOCOL)
            return
        wait = self._token_failures.retry_after("node", address)
        if wait > 0:
            # 'try again later': a right node at that address (another process guessed)
            # retries after the pause instead of stopping for good
            await self._refuse(ws, peer, f"too many wrong pairing tokens from {address}; "
                               f"connections from it are refused for {wait:.0f} s more",
                               CLOSE_BUSY)
            return
        if not secrets.compare_digest(hello.token.encode(), self.settings.node_token.encode()):
            self._token_failures.failed("node", address)
            await self._refuse(ws, peer, f"wrong pairing token for node {hello.node_id}; start "
                               "the node with the token shown in the server settings",
                               CLOSE_REFUSED)
            return
        self._token_failures.succeeded("node", address)
        # numbered before the old connection is closed (which awaits): from here on its
        # loop handles nothing, whatever it still has buffered
        self._next_generation += 1
        generation = self._generation[hello.node_id] = self._next_generation
        old = self._sockets.get(hello.node_id)
        if old is not None:
            log.warning("node %s reconnected from %s; closing its previous connection",
                        hello.node_id, peer)
            with contextlib.suppress(Exception):
                await old.close(code=CLOSE_REPLACED, reason="replaced by a new connection")
        self._sockets[hello.node_id] = ws
        restarted = self._agent_started.get(hello.node_id) != hello.agent_started
        self._agent_started[hello.node_id] = hello.agent_started

        async def send(text: str) -> None:
            await ws.send_text(text)

        session = self.registry.connect(hello.node_id, hello.backend, hello.sensor, send,
                                        restarted)
        log.info("node %s connected from %s (%s)", hello.node_id, peer, hello.backend)
        pinger: asyncio.Task[None] | None = None
        budget = RefusalBudget(hello.node_id)
        try:
            # inside the try: a node gone before its welcome is disconnected, not left
            # registered as connected
            await ws.send_text(dump(_welcome(self.settings, hello.protocol)))
            self._on_listing(hello.node_id, hello.parts)
            pinger = asyncio.create_task(self._ping_loop(ws, session, budget))
            await self._message_loop(ws, session, generation, budget)
        except WebSocketDisconnect:
            pass
        except Exception:
            log.exception("node %s connection failed", hello.node_id)
        finally:
            if pinger is not None:
                pinger.cancel()
            self._summarise(session, budget.summary())  # what the last window counted
            # only the node's current connection cleans up: a replaced one ending while
            # the new one is being set up must not mark the node offline
            if self._generation.get(hello.node_id) == generation:
                self._sockets.pop(hello.node_id, None)
                self.registry.disconnect(hello.node_id)
                self.recordings.on_disconnect(hello.node_id)
                log.info("node %s disconnected", hello.node_id)

    def _on_listing(self, node_id: str, parts: list[PartInfo]) -> None:
        """A node's listing of the parts it holds: one save of the recording list for the
        message (a save rewrites every recording: a second at a clinic's 30 000), not one
        per part whose state changed."""
        changed = [self.recordings.on_part(node_id, p, from_hello=True, save=False)
                   for p in parts]
        if any(changed):
            self.recordings.save()

    async def _refuse(self, ws: WebSocket, peer: str, reason: str, code: int) -> None:
        log.warning("refused node connection from %s: %s", peer, reason)
        with contextlib.suppress(Exception):
            await ws.send_text(dump(Refused(reason=reason)))
            await ws.close(code=code, reason=reason[:120])

    async def _ping_loop(self, ws: WebSocket, s: NodeSession,
                         budget: RefusalBudget) -> None:
        seq = 0
        try:
            while ws.application_state == WebSocketState.CONNECTED:
                # a flood that stopped is still summarised, once its window ends
                self._summarise(s, budget.summary(time.monotonic()))
                seq += 1
                await ws.send_text(dump(Ping(seq=seq, t1=time.time())))
                await asyncio.sleep(self.settings.clock_ping_interval_s)
        except (WebSocketDisconnect, RuntimeError, OSError):
            pass  # the message loop notices the disconnect and cleans up

    def _summarise(self, s: NodeSession, text: str | None) -> None:
        """Log a window's refusal summary and show it in the node's health."""
        if text is not None:
            log.warning("%s", text)
            s.refusal_summary = (time.time(), text)

    async def _reject(self, ws: WebSocket, s: NodeSession, reason: str,
                      budget: RefusalBudget) -> bool:
        """Refuse one message: answered with ``error`` and logged within the budget,
        counted beyond it.

        Returns:
            Whether the connection must be closed (:attr:`RefusalBudget.flooding`).
        """
        s.rejected_messages += 1
        s.last_rejection = reason
        now = time.monotonic()
        self._summarise(s, budget.summary(now))  # the previous window's, when it ended
        if budget.refuse(reason, now):
            log.warning("rejected message from node %s: %s", s.id, reason)
            await ws.send_text(dump(ServerError(reason=reason)))
        elif budget.counted == 1:  # told once a window, so the node knows why it hears nothing
            await ws.send_text(dump(ServerError(
                reason=f"{reason[:200]} (more refused messages are counted, not answered; "
                f"past {MAX_REFUSED_PER_WINDOW:,} in {REFUSAL_WINDOW_S:g} s the connection is "
                "closed)")))
        return budget.flooding

    async def _close_flooding(self, ws: WebSocket, s: NodeSession,
                              budget: RefusalBudget) -> None:
        first = budget.first_reason
        self._summarise(s, budget.summary())
        reason = (f"more than {MAX_REFUSED_PER_WINDOW} refused messages in "
                  f"{REFUSAL_WINDOW_S:g} s; first: {first}")
        log.warning("node %s: connection closed: %s", s.id, reason[:300])
        with contextlib.suppress(Exception):
            await ws.send_text(dump(ServerError(reason=reason[:2000])))
            await ws.close(code=CLOSE_FLOOD, reason=_close_reason(reason))

    async def _message_loop(self, ws: WebSocket, s: NodeSession, generation: int,
                            budget: RefusalBudget) -> None:
        while True:
            msg = await ws.receive()
            t4 = time.time()
            if msg["type"] == "websocket.disconnect":
                return
            if self._generation.get(s.id) != generation:
                # replaced by a newer connection of this node: a status, part state or
                # transfer answer it still had buffered is stale and must not act on the
                # session (now the new connection's); stop at once
                log.info("node %s: the replaced connection's remaining messages are "
                         "ignored", s.id)
                return
            s.last_seen = t4
            refused: str | None = None
            data = msg.get("bytes")
            if data is not None:
                try:
                    self._on_binary(s, data, t4)
                except ProtocolError as exc:
                    refused = str(exc)
            else:
                try:
                    m = parse_node_message(msg.get("text") or "",
                                           self.settings.max_control_bytes)
                except ProtocolError as exc:
                    refused = str(exc)
                else:
                    refused = self._on_message(s, m, t4)
            if refused is not None and await self._reject(ws, s, refused, budget):
                await self._close_flooding(ws, s, budget)
                return

    def _on_message(self, s: NodeSession, m: Any, t4: float) -> str | None:
        """Act on one parsed control message; the reason when it is refused."""
        if isinstance(m, Pong):
            s.clock.add(m.t1, m.t2, m.t3, t4)
        elif isinstance(m, Status):
            s.status = m
        elif isinstance(m, RecState):
            s.parts[m.part.rec_id] = m.part
            self.recordings.on_part(s.id, m.part)
        elif isinstance(m, PartList):  # the rest of the hello's listing
            self._on_listing(s.id, m.parts)
        elif isinstance(m, NodeError):
            log.warning("node %s reported: %s", s.id, m.reason)
        elif isinstance(m, NodeWarning):
            at = s.to_server(m.t)
            # no clock estimate yet, or one that puts it after its arrival: arrival
            at = t4 if at is None else min(at, t4)
            if s.on_warning(m.text, at, m.repeats, t4):
                log.warning("node %s warns: %s", s.id, m.text)
        elif isinstance(m, SensorLens):
            return self._on_lens(s, m)
        elif isinstance(m, Hello):
            return "hello sent twice on one connection"
        return None

    def _on_lens(self, s: NodeSession, m: SensorLens) -> str | None:
        """A node's announced lenses (revision 3): kept for the live view and the Rig page
        when they describe the cameras of its hello; otherwise refused (the reason is
        returned: a warning, an ``error`` answer; the connection stays and the node is
        drawn as a pinhole)."""
        if s.lens is not None:  # sent once after the welcome: a flood rebuilds nothing
            return ("sensor lens sent twice on one connection; the first is kept (reconnect "
                    "to announce another)")
        problem = lens_mismatch(m, s.sensor)
        if problem is not None:
            return f"sensor lens refused: {problem}; {s.id} is drawn as a pinhole camera"
        s.lens = m
        log.info("node %s lens (%s): depth %s, colour %s", s.id, m.source,
                 m.depth.dist if m.depth else "not reported",
                 m.color.dist if m.color else "not reported")
        for cb in self.registry.listeners:  # the live cloud's rays follow it
            cb(s)
        return None

    def _on_binary(self, s: NodeSession, data: bytes, now: float) -> None:
        header, payload = decode_binary(data, self.settings.max_binary_bytes)
        t_local = float(header.get("t", 0.0))
        if header["kind"] == "skeleton":
            pos, st = decode_skeletons(header, payload)
            seq = int(header["seq"])
            s.on_skeleton(seq, now)
            s.skeleton = LatestSkeleton(seq, t_local, s.to_server(t_local), pos, st,
                                        [int(b) for b in header["bodies"]])
            for cb in self.skeleton_listeners:
                cb(s)
        elif header["kind"] in ("manifest", "chunk", "deleted", "channel"):
            self.transfers.on_binary(header, payload)
        elif header["kind"] in self.binary_listeners:
            if header["kind"] == "calib":  # a colour image, then a depth image
                n = header.get("color_bytes")
                if isinstance(n, int) and 0 < n < len(payload):
                    check_image_size(payload[:n], "a calibration colour image")
                    check_image_size(payload[n:], "a calibration depth image")
            self.binary_listeners[header["kind"]](s, header, payload)
        elif header["kind"] == "calib":
            log.warning("node %s sent calibration frames nobody asked for; ignored", s.id)
        else:
            stream = header.get("stream")
            if stream not in ("depth", "color", "body_index"):
                raise ProtocolError(f"image stream {stream!r} is not depth, color or body_index")
            check_image_size(payload, f"a {stream} image")
            s.images[str(stream)] = LatestImage(t_local, s.to_server(t_local),
                                                str(header.get("format", "png")), bytes(payload),
                                                header)


def _close_reason(text: str) -> str:
    """``text`` cut to a websocket close reason's 123 bytes of UTF-8."""
    raw = text.encode()
    return text if len(raw) <= 123 else raw[:120].decode(errors="ignore") + "…"


def _welcome(settings: Settings, revision: int) -> Welcome:
    """The welcome for a node of protocol ``revision`` (an older node's parser refuses
    fields it does not know: it gets none)."""
    return Welcome(server_time=time.time(), ping_interval_s=settings.clock_ping_interval_s,
                   accepts=list(ACCEPTED_NODE_MESSAGES) if revision >= 2 else None)
