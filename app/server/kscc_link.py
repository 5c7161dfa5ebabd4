"""KSCC sessions: two skeleton streams calibrated into the universal frame and compared.

A :class:`KsccSession` has two sides, ``a`` and ``b``. Each side's skeletons come from a
node of this server (the hub's skeleton listener) or from a gaitrig server at another site
over an authenticated websocket (:func:`remote_link`). Each side runs its own streaming
:class:`engine.kscc.KsccCalibrator` after a countdown; once both are calibrated, every
frame is moved into the universal frame and the two users are compared
(:mod:`engine.compare`): per-joint distances over time (frames paired by arrival time) and
a DTW similarity score over the last seconds.

Two-site link. The site that *shares* a node (``KsccManager.shares``: node id -> link
token, set by a logged-in operator there) accepts a websocket at ``/api/kscc/link``; the
first message must be ``{"type": "hello", "node_id": ..., "token": ...}``. A wrong token or
an unshared node is answered with ``{"type": "refused", "reason": ...}`` and close code
4401. Otherwise it sends ``{"type": "welcome", "joint_set", "T_world_sensor", "model"}``
and then one ``{"type": "skeleton", "seq", "t", "positions", "states"}`` per frame of the
node's first body (``null`` for joints without an estimate), or ``{"type": "status",
"connected": false}`` while the node is offline.

Only configured peers. A remote side may only name a server listed in the setting
``kscc_peers`` (:func:`check_peer`): otherwise any logged-in user could make this server
open connections to any address it can reach.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import secrets
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal
from urllib.parse import urlsplit

import numpy as np
from numpy.typing import NDArray

from engine import nanstats
from engine.errors import GaitrigError, InputError
from engine.kscc import N_STILL_FRAMES, KsccCalibrator, KsccProgress
from engine.skeleton import JOINT_SETS, JointSet, SkeletonSeries, TrackingState

log = logging.getLogger("gaitrig.kscc")

FloatArray = NDArray[np.float64]
CLOSE_REFUSED = 4401
MIN_TOKEN_LEN = 16
HISTORY_S = 30.0
COMPARE_WINDOW_S = 10.0
#: A side with no frame for this long is reported as silent.
SILENT_S = 2.0
#: After this many restarts the page says the user keeps moving.
KEEPS_MOVING_RESTARTS = 3

SourceKind = Literal["node", "remote"]


@dataclass(frozen=True)
class SourceSpec:
    """Where one side's skeletons come from.

    Attributes:
        kind: ``node`` (a node of this server) or ``remote`` (another site's server).
        node_id: the node (at the remote site for ``remote``).
        url: remote server base URL (``http(s)://`` or ``ws(s)://host:port``).
        token: the link token the remote site set for that node.
    """

    kind: SourceKind
    node_id: str
    url: str | None = None
    token: str | None = field(default=None, repr=False)

    def label(self) -> str:
        return self.node_id if self.kind == "node" else f"{self.node_id} @ {self.url}"


def link_url(base: str) -> str:
    """The link websocket URL of a remote server given its base URL.

    Raises:
        InputError: not an http(s)/ws(s) URL.
    """
    b = base.strip().rstrip("/")
    for a, w in (("http://", "ws://"), ("https://", "wss://")):
        if b.startswith(a):
            b = w + b[len(a):]
    if not (b.startswith("ws://") or b.startswith("wss://")) or len(b) < 8:
        raise InputError(f"remote server URL {base!r}: use the address of the other site's "
                         "gaitrig console, e.g. https://lab-b.example.org:8000")
    if b.endswith("/api/kscc/link"):
        return b
    return b + "/api/kscc/link"


class PeerNotAllowedError(InputError):
    """A remote site that is not in the ``kscc_peers`` setting (HTTP 403)."""


_DEFAULT_PORTS = {"ws": 80, "wss": 443}


def _endpoint(ws_url: str) -> tuple[str, str, int]:
    """``(scheme, host, port)`` of a ws(s) URL, the port defaulted by the scheme."""
    u = urlsplit(ws_url)
    try:
        port = u.port
    except ValueError:
        port = -1
    if not u.hostname or port == -1:
        raise InputError(f"remote server URL {ws_url!r} has no valid host and port")
    return u.scheme, u.hostname.lower(), port if port is not None else _DEFAULT_PORTS[u.scheme]


def _peer_matches(peer: str, target: tuple[str, str, int]) -> bool:
    p = peer.strip()
    if not p:
        return False
    try:
        if "://" in p:  # a full base URL: scheme, host and port must all agree
            return _endpoint(link_url(p)) == target
        u = urlsplit("//" + p)  # host[:port], any scheme
        return (u.hostname or "").lower() == target[1] and u.port in (None, target[2])
    except (InputError, ValueError):
        return False  # a malformed entry allows nothing


def check_peer(url: str, peers: Sequence[str]) -> str:
    """The link websocket URL of ``url`` if it names a configured peer.

    Args:
        url: The remote server address an operator typed.
        peers: The ``kscc_peers`` setting.

    Raises:
        InputError: not an http(s)/ws(s) URL.
        PeerNotAllowedError: the server is not among ``peers``.
    """
    ws = link_url(url)
    target = _endpoint(ws)
    if not any(_peer_matches(p, target) for p in peers):
        allowed = ", ".join(repr(p) for p in peers) if peers else "none"
        raise PeerNotAllowedError(
            f"remote site {url!r} is not an allowed peer of this server; an administrator "
            "must add it to the setting kscc_peers (environment GAITRIG_KSCC_PEERS, e.g. "
            f"'[\"https://{target[1]}:{target[2]}\"]') and restart it. Allowed now: {allowed}"
        )
    return ws


def skeleton_json(positions: FloatArray, states: NDArray[np.uint8]) -> dict[str, Any]:
    """JSON-ready joints (``null`` for NaN) and states."""
    pos = np.asarray(positions, dtype=float)
    out = [[None if not np.isfinite(v) else round(float(v), 4) for v in p] for p in pos]
    return {"positions": out, "states": [int(s) for s in states]}


def _from_json(positions: Any, states: Any, n_joints: int) -> tuple[FloatArray, NDArray[np.uint8]]:
    pos = np.array([[np.nan if v is None else float(v) for v in p] for p in positions],
                   dtype=float)
    st = np.asarray(states, dtype=np.uint8)
    if pos.shape != (n_joints, 3) or st.shape != (n_joints,):
        raise InputError(f"remote skeleton has shape {pos.shape}, expected ({n_joints}, 3)")
    return pos, st


class KsccSide:
    """One side of a session: its source, calibrator, progress and universal-frame history.

    Args:
        name: ``a`` or ``b``.
        source: where the skeletons come from.
        countdown_s: seconds before collection starts (time for the user to get still).
    """

    def __init__(self, name: str, source: SourceSpec, countdown_s: float,
                 centre: Literal["all", "roles"] = "all") -> None:
        self.name = name
        self.centre: Literal["all", "roles"] = centre
        self.source = source
        self.countdown_s = countdown_s
        self.joint_set: JointSet | None = None
        self.T_world_sensor: FloatArray | None = None
        self.model = ""
        self.link_state = "connecting" if source.kind == "remote" else "local"
        self.error: str | None = None
        self.frames = 0
        self.last_frame_at: float | None = None
        self.latest_raw: tuple[FloatArray, NDArray[np.uint8]] | None = None
        self.history: deque[tuple[float, FloatArray, NDArray[np.uint8]]] = deque()
        self.restarts = 0
        self.restart()

    def restart(self) -> None:
        """Start (again) with the countdown; keeps the source and the link."""
        self.calibrator: KsccCalibrator | None = None
        self.progress: KsccProgress | None = None
        self.calibrated = False
        self.countdown_until = time.time() + self.countdown_s
        self.history.clear()
        self.restarts = 0
        self.error = None if self.link_state != "refused" else self.error

    def set_sensor(self, joint_set: str, T_world_sensor: Any, model: str) -> None:
        """What the source reported about its sensor (before the first frame).

        Raises:
            InputError: unknown joint set or a malformed pose.
        """
        if joint_set not in JOINT_SETS:
            raise InputError(f"source {self.source.label()} uses an unknown joint set "
                             f"{joint_set!r}; known: {sorted(JOINT_SETS)}")
        if self.joint_set is not None and self.joint_set.name != joint_set:
            self.restart()
        self.joint_set = JOINT_SETS[joint_set]
        T = None if T_world_sensor is None else np.asarray(T_world_sensor, dtype=float)
        if T is not None and (T.shape != (4, 4) or not np.isfinite(T).all()):
            raise InputError(f"source {self.source.label()}: malformed sensor pose")
        self.T_world_sensor = T
        self.model = model

    def _new_calibrator(self) -> KsccCalibrator:
        # a known pose gives a Z-up world; otherwise the device's own (OpenCV) camera frame
        if self.T_world_sensor is not None:
            return KsccCalibrator(N_STILL_FRAMES, T_world_sensor=self.T_world_sensor,
                                  centre=self.centre)
        return KsccCalibrator(N_STILL_FRAMES, frame="opencv", centre=self.centre)

    def feed(self, t: float, positions: FloatArray, states: NDArray[np.uint8]) -> None:
        """One frame of the side's user (source frame, metres)."""
        now = time.time()
        self.frames += 1
        self.last_frame_at = now
        self.latest_raw = (positions, states)
        if self.joint_set is None or len(positions) != len(self.joint_set.joints):
            self.error = (f"{self.source.label()} sends {len(positions)}-joint skeletons; "
                          "expected its declared joint set")
            return
        if now < self.countdown_until:
            return
        if not self.calibrated:
            if self.calibrator is None:
                self.calibrator = self._new_calibrator()
            try:
                prog = self.calibrator.update(t, positions, states, self.joint_set)
            except GaitrigError as e:
                self.error = str(e)
                self.calibrator = None
                return
            if prog.state == "moved":
                self.restarts += 1
            self.progress = prog
            self.calibrated = prog.state == "done"
            if self.calibrated:
                self.error = None
            return
        assert self.calibrator is not None
        U = self.calibrator.transform_points(positions)
        U[states == TrackingState.NOT_TRACKED] = np.nan
        self.history.append((t, U, states.copy()))
        while self.history and self.history[0][0] < t - HISTORY_S:
            self.history.popleft()

    def series(self, since: float) -> SkeletonSeries | None:
        """Universal-frame frames with ``t ≥ since``, or ``None`` when there are none."""
        rows = [h for h in self.history if h[0] >= since]
        if not rows or self.joint_set is None:
            return None
        return SkeletonSeries(np.array([r[0] for r in rows]), np.stack([r[1] for r in rows]),
                              np.stack([r[2] for r in rows]), self.joint_set,
                              {"frame": "kscc_universal"})

    def status(self, now: float) -> dict[str, Any]:
        """JSON for the page: link, countdown, stillness progress, calibration, skeleton."""
        countdown = max(0.0, self.countdown_until - now)
        prog = self.progress.to_dict() if self.progress else None
        if self.link_state in ("connecting", "refused", "unreachable"):
            message = self.error or "Connecting to the other site…"
        elif self.error:
            message = self.error
        elif self.last_frame_at is None or now - self.last_frame_at > SILENT_S:
            message = (f"No skeleton from {self.source.label()}: make sure the person is in "
                       "the sensor's view (the whole body) and the sensor is online.")
        elif countdown > 0:
            message = (f"Calibration starts in {countdown:.0f} s: stand still, arms relaxed, "
                       "facing roughly towards the sensor.")
        elif self.calibrated:
            message = "Calibrated: this user's skeleton is in the universal frame."
        elif self.progress is not None:
            message = self.progress.message
            if self.restarts >= KEEPS_MOVING_RESTARTS:
                message += (f" The user has moved {self.restarts} times: ask them to stand "
                            "still for about four seconds; small sway is fine.")
        else:
            message = "Waiting for the first frame…"
        cal = None
        if self.calibrated and self.calibrator is not None:
            c = self.calibrator
            cal = {"centre_m": [float(x) for x in c.centre_],
                   "heading_deg": float(np.degrees(c.heading_)),
                   "initial_angle_deg": c.initial_angle_deg_}
        skel = None
        if self.history:
            _, U, st = self.history[-1]
            skel = skeleton_json(U, st)
        return {"name": self.name, "source": self.source.label(), "kind": self.source.kind,
                "link": self.link_state, "model": self.model,
                "joint_set": self.joint_set.name if self.joint_set else None,
                "bones": ([[int(p), j] for j, p in enumerate(self.joint_set.parent_indices)
                           if p >= 0] if self.joint_set else []),
                "frames": self.frames, "countdown_s": countdown, "progress": prog,
                "calibrated": self.calibrated, "calibration": cal, "message": message,
                "restarts": self.restarts, "skeleton": skel}


class KsccSession:
    """Two sides and their comparison.

    Args:
        a, b: the two sources.
        countdown_s: countdown before each side's collection starts.
        by_role: compare different joint sets through their shared roles.
    """

    def __init__(self, a: SourceSpec, b: SourceSpec, countdown_s: float = 3.0,
                 by_role: bool = False) -> None:
        # different joint sets compared by role need centres from the same body parts
        centre: Literal["all", "roles"] = "roles" if by_role else "all"
        self.sides = {"a": KsccSide("a", a, countdown_s, centre),
                      "b": KsccSide("b", b, countdown_s, centre)}
        self.by_role = by_role
        self.started = time.time()
        self.tasks: list[asyncio.Task[None]] = []

    def comparison(self) -> dict[str, Any]:
        """Difference over time and similarity once both sides are calibrated."""
        # here, not at the top: the comparison's DTW kernel loads numba, which the server's
        # start (the API imports this module) must not pay
        from engine.compare import common_joints, compare_motions, joint_distances

        a, b = self.sides["a"], self.sides["b"]
        if not (a.calibrated and b.calibrated):
            return {"ready": False, "message": "Both users must be calibrated first."}
        if a.joint_set is not None and b.joint_set is not None:
            try:
                names, _, _ = common_joints(a.joint_set, b.joint_set, self.by_role)
            except InputError:
                return {"ready": False, "mismatch": True, "message": (
                    f"The two sites use different skeletons ({a.joint_set.name}, "
                    f"{len(a.joint_set.joints)} joints, and {b.joint_set.name}, "
                    f"{len(b.joint_set.joints)} joints). Tick \"compare the joints both "
                    "skeletons share\" and start again.")}
        t_end = max(a.history[-1][0] if a.history else 0.0, b.history[-1][0] if b.history
                    else 0.0)
        sa, sb = a.series(t_end - HISTORY_S), b.series(t_end - HISTORY_S)
        if sa is None or sb is None or len(sa) < 5 or len(sb) < 5:
            return {"ready": False, "message": "Collecting frames from both users…"}
        try:
            t, names, d = joint_distances(sa, sb, by_role=self.by_role, max_gap_s=0.1)
            wa = a.series(t_end - COMPARE_WINDOW_S)
            wb = b.series(t_end - COMPARE_WINDOW_S)
            assert wa is not None and wb is not None
            # ≤ 150 frames a side keeps DTW at interactive speed
            wa = _decimate(wa, 150)
            wb = _decimate(wb, 150)
            cmp = compare_motions(wa, wb, by_role=self.by_role)
        except GaitrigError as e:
            return {"ready": False, "message": str(e)}
        keep = np.unique(np.linspace(0, len(t) - 1, min(len(t), 300)).round().astype(int))
        mean = nanstats.nanmean(d, axis=1)  # frames without a pair are NaN rows

        def clean(x: FloatArray) -> list[float | None]:
            return [None if not np.isfinite(v) else round(float(v), 4) for v in x]

        return {
            "ready": True, "joints": names, "times": [round(float(x - t_end), 3) for x in t[keep]],
            "mean_m": clean(mean[keep]), "per_joint_m": [clean(d[keep, j])
                                                        for j in range(d.shape[1])],
            "per_joint_mean_m": clean(cmp.per_joint_mean_m),
            "similarity": cmp.similarity, "mean_distance_m": cmp.mean_distance_m,
            "window_s": COMPARE_WINDOW_S, "meaning": similarity_meaning(cmp.similarity,
                                                                        cmp.mean_distance_m),
        }

    def status(self) -> dict[str, Any]:
        now = time.time()
        return {"sides": {k: s.status(now) for k, s in self.sides.items()},
                "by_role": self.by_role, "comparison": self.comparison()}


def _decimate(s: SkeletonSeries, n: int) -> SkeletonSeries:
    if len(s) <= n:
        return s
    k = np.unique(np.linspace(0, len(s) - 1, n).round().astype(int))
    return SkeletonSeries(s.times[k], s.positions[k], s.states[k], s.joint_set, s.meta)


def similarity_meaning(score: float, mean_m: float) -> str:
    """Plain words for the similarity score (``engine.compare``: 100·exp(−d̄/10 cm))."""
    cm = mean_m * 100
    if score >= 90:
        verdict = "practically the same motion"
    elif score >= 61:
        verdict = "the same motion within the sensors' own accuracy (about 5 cm)"
    elif score >= 37:
        verdict = "similar motions with visible differences"
    elif score >= 14:
        verdict = "clearly different motions"
    else:
        verdict = "unrelated motions (more than 20 cm apart on average)"
    return (f"{score:.0f}/100: {verdict}; the joints are {cm:.1f} cm apart on average after "
            "time alignment (100 = identical, 61 = 5 cm, 37 = 10 cm).")


# --------------------------------------------------------------------------- manager


class KsccManager:
    """Per-server KSCC state: the current session, shared nodes, viewer redraws.

    Args:
        hub: the node hub (skeletons of this server's nodes).
        on_change: called (≤ 10 Hz) after new frames, e.g. to redraw the 3D view.
    """

    def __init__(self, hub: Any, on_change: Callable[[KsccSession], None] | None = None
                 ) -> None:
        self.hub = hub
        self.session: KsccSession | None = None
        self.shares: dict[str, str] = {}
        self.on_change = on_change
        self._last_change = 0.0
        self._link_queues: dict[str, set[asyncio.Queue[str]]] = {}
        hub.skeleton_listeners.append(self._on_node_skeleton)

    @property
    def peers(self) -> list[str]:
        """The ``kscc_peers`` setting: servers a remote side may connect to."""
        return list(getattr(getattr(self.hub, "settings", None), "kscc_peers", None) or [])

    # -------------------------------------------------------------- local nodes

    def _on_node_skeleton(self, s: Any) -> None:
        sk = s.skeleton
        if sk is None:
            return
        pos = np.asarray(sk.positions, dtype=float)
        st = np.asarray(sk.states, dtype=np.uint8)
        # remote links: one JSON frame per skeleton of a shared node
        queues = self._link_queues.get(s.id)
        if queues:
            msg = json.dumps({"type": "skeleton", "seq": sk.seq,
                              "t": sk.t_server if sk.t_server is not None else time.time(),
                              **(skeleton_json(pos[0], st[0]) if len(pos) else
                                 {"positions": None, "states": None})})
            for q in queues:
                if q.full():
                    with contextlib.suppress(asyncio.QueueEmpty):
                        q.get_nowait()  # a slow link drops the oldest frame, not the node
                q.put_nowait(msg)
        sess = self.session
        if sess is None or not len(pos):
            return
        t = sk.t_server if sk.t_server is not None else time.time()
        for side in sess.sides.values():
            if side.source.kind == "node" and side.source.node_id == s.id:
                if side.joint_set is None:
                    side.set_sensor(s.sensor.joint_set, s.sensor.T_world_sensor, s.sensor.model)
                side.feed(t, pos[0], st[0])
        self._changed(sess)

    def _changed(self, sess: KsccSession) -> None:
        now = time.time()
        if self.on_change is not None and now - self._last_change >= 0.1:
            self._last_change = now
            try:
                self.on_change(sess)
            except Exception:  # the 3D view must never break calibration
                log.exception("KSCC view update failed")

    # ----------------------------------------------------------------- sessions

    async def start(self, a: SourceSpec, b: SourceSpec, countdown_s: float, by_role: bool
                    ) -> KsccSession:
        """Replace the current session; remote sides get a link task.

        Raises:
            InputError: unknown or offline local node, both sides the same source.
        """
        if a == b:
            raise InputError("choose two different skeleton sources")
        for src in (a, b):
            if src.kind == "node":
                s = self.hub.registry.get(src.node_id)
                if s is None:
                    raise InputError(f"no node {src.node_id!r} on this server; pick one of "
                                     f"{sorted(self.hub.registry.nodes) or 'none yet'}")
                if not s.connected:
                    raise InputError(f"node {src.node_id} is offline; start its sensor first")
            elif not src.token or len(src.token) < MIN_TOKEN_LEN or not src.url:
                raise InputError("a remote site needs its server address and the link token "
                                 f"(≥ {MIN_TOKEN_LEN} characters) its operator set when "
                                 "sharing the node")
            else:
                check_peer(src.url, self.peers)
        await self.stop()
        sess = KsccSession(a, b, countdown_s, by_role)
        for side in sess.sides.values():
            if side.source.kind == "node":
                s = self.hub.registry.get(side.source.node_id)
                side.set_sensor(s.sensor.joint_set, s.sensor.T_world_sensor, s.sensor.model)
            else:
                sess.tasks.append(asyncio.create_task(self._remote(sess, side)))
        self.session = sess
        return sess

    async def stop(self) -> None:
        """End the current session and its links."""
        sess, self.session = self.session, None
        if sess is not None:
            for task in sess.tasks:
                task.cancel()
            for task in sess.tasks:
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await task

    async def _remote(self, sess: KsccSession, side: KsccSide) -> None:
        """Client end of a two-site link; reconnects every 2 s until refused or stopped."""
        import websockets

        src = side.source
        url = link_url(src.url or "")  # checked against kscc_peers by start()
        while self.session is sess:
            try:
                async with websockets.connect(url, max_size=1 << 20, open_timeout=5,
                                              ping_interval=10) as ws:
                    await ws.send(json.dumps({"type": "hello", "node_id": src.node_id,
                                              "token": src.token}))
                    first = json.loads(await asyncio.wait_for(ws.recv(), 10))
                    if first.get("type") == "refused":
                        side.link_state = "refused"
                        side.error = ("The other site refused the link: "
                                      f"{first.get('reason', 'no reason given')}")
                        return
                    if first.get("type") != "welcome":
                        raise InputError("the other site did not answer as a gaitrig server")
                    side.set_sensor(str(first.get("joint_set")), first.get("T_world_sensor"),
                                    str(first.get("model", "")))
                    side.link_state = "connected"
                    side.error = None
                    async for raw in ws:
                        m = json.loads(raw)
                        if m.get("type") == "skeleton" and m.get("positions") is not None:
                            assert side.joint_set is not None
                            pos, st = _from_json(m["positions"], m["states"],
                                                 len(side.joint_set.joints))
                            # arrival time: both sides are then on this server's clock
                            side.feed(time.time(), pos, st)
                            self._changed(sess)
                        elif m.get("type") == "status" and not m.get("connected", True):
                            side.error = f"The other site's sensor {src.node_id} is offline."
            except asyncio.CancelledError:
                raise
            except (OSError, TimeoutError, ValueError, GaitrigError) as e:
                side.link_state = "unreachable"
                side.error = (f"Cannot reach the other site at {src.url} ({e}); retrying every "
                              "2 s. Check the address and that its server is running.")
            except Exception as e:  # websockets' ConnectionClosed, InvalidStatus, ...
                side.link_state = "unreachable"
                side.error = f"Link to {src.url} lost ({type(e).__name__}: {e}); retrying."
            await asyncio.sleep(2.0)

    # ------------------------------------------------------------ serving links

    async def serve_link(self, ws: Any) -> None:
        """Server end of a two-site link (Starlette websocket); see the module docstring."""
        await ws.accept()
        try:
            raw = await asyncio.wait_for(ws.receive_text(), 10.0)
            if len(raw) > 4096:
                raise ValueError("hello too long")
            hello = json.loads(raw)
            node_id = str(hello["node_id"])
            token = str(hello["token"])
        except Exception:
            await self._refuse(ws, "send {\"type\": \"hello\", \"node_id\", \"token\"} first")
            return
        expected = self.shares.get(node_id)
        if expected is None or not secrets.compare_digest(token.encode(), expected.encode()):
            log.warning("refused a KSCC link for node %s (wrong token or not shared)", node_id)
            await self._refuse(ws, f"node {node_id!r} is not shared with this token; ask the "
                               "other site's operator to share it and give you its link token")
            return
        s = self.hub.registry.get(node_id)
        sensor = s.sensor if s is not None else None
        await ws.send_text(json.dumps({
            "type": "welcome", "node_id": node_id,
            "joint_set": sensor.joint_set if sensor else "kinect_v2",
            "T_world_sensor": sensor.T_world_sensor if sensor else None,
            "model": sensor.model if sensor else ""}))
        q: asyncio.Queue[str] = asyncio.Queue(maxsize=60)
        self._link_queues.setdefault(node_id, set()).add(q)
        log.info("KSCC link for node %s opened", node_id)
        try:
            while self.shares.get(node_id) == expected:
                try:
                    msg = await asyncio.wait_for(q.get(), 1.0)
                except TimeoutError:
                    s = self.hub.registry.get(node_id)
                    if s is None or not s.connected:
                        msg = json.dumps({"type": "status", "connected": False})
                    else:
                        continue
                await ws.send_text(msg)
        except Exception:  # the other site went away
            pass
        finally:
            self._link_queues.get(node_id, set()).discard(q)
            with contextlib.suppress(Exception):
                await ws.close(code=1000)
            log.info("KSCC link for node %s closed", node_id)

    async def _refuse(self, ws: Any, reason: str) -> None:
        with contextlib.suppress(Exception):
            await ws.send_text(json.dumps({"type": "refused", "reason": reason}))
            await ws.close(code=CLOSE_REFUSED, reason=reason[:120])
