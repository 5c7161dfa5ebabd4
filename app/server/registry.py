"""The server's view of the sensor nodes: who is connected, health, clocks, latest data.

One :class:`NodeSession` per node id survives reconnects (health history, clock
estimator, sensor description); the websocket handler (:mod:`app.server.ws`) feeds it.
Everything runs on the server's event loop, so no locks are needed.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.nodes.protocol import PartInfo, SensorInfo, SensorLens, Status
from app.server.clock import ClockEstimate, ClockEstimator

SendFn = Callable[[str], Awaitable[None]]

#: Distinct backend warnings kept per node (the newest; a repeat updates its entry).
NODE_WARNINGS_KEPT = 5
#: Warning messages taken from one node per minute at most; more are counted, not kept
#: (a node sends far fewer: :data:`app.nodes.agent.WARNING_BURST`).
NODE_WARNINGS_PER_MINUTE = 20
#: Seconds a summary of refused messages (``app.server.hub.RefusalBudget``) stays among the
#: node's health warnings: long enough to be read on the Rig page after a flood closed the
#: connection and the node reconnected.
REFUSAL_SUMMARY_SHOWN_S = 600.0
#: A node's clock warning, once raised at the limit (``clock_warn_ms``), is lifted below
#: this fraction of it (see :meth:`NodeSession.clock_uncertain`).
CLOCK_CLEAR_FRACTION = 0.75


@dataclass
class NodeWarningRecord:
    """A warning a node's backend raised after it connected (``warning`` message)."""

    at: float  # server time it was last raised
    text: str
    repeats: int = 1


@dataclass
class LatestSkeleton:
    """Newest skeleton frame of a node, timestamps already in server time."""

    seq: int
    t_local: float
    t_server: float | None
    positions: NDArray[np.float32]
    states: NDArray[np.uint8]
    body_ids: list[int]


@dataclass
class LatestImage:
    """Newest encoded image of one stream of a node."""

    t_local: float
    t_server: float | None
    format: str
    data: bytes
    header: dict[str, Any]


@dataclass
class NodeSession:
    """Everything the server knows about one node."""

    id: str
    clock: ClockEstimator
    backend: str = "unknown"
    sensor: SensorInfo = field(default_factory=lambda: SensorInfo())
    #: the pose the node reported in its hello: an active calibration's pose replaces
    #: ``sensor.T_world_sensor``, and a node the next active one leaves out goes back to it
    reported_pose: list[list[float]] | None = None
    connected: bool = False
    connected_at: float | None = None
    disconnected_at: float | None = None
    last_seen: float = 0.0
    send: SendFn | None = None
    frames_received: int = 0
    seq_gaps: int = 0
    last_seq: int | None = None
    recent: deque[float] = field(default_factory=lambda: deque(maxlen=90))
    status: Status | None = None
    parts: dict[str, PartInfo] = field(default_factory=dict)
    skeleton: LatestSkeleton | None = None
    images: dict[str, LatestImage] = field(default_factory=dict)
    rejected_messages: int = 0
    last_rejection: str | None = None
    #: (server time, text) of the newest summary of refused messages counted, not logged
    refusal_summary: tuple[float, str] | None = None
    #: the clock's uncertainty state of :meth:`clock_uncertain` (hysteresis)
    _clock_uncertain: bool = True
    node_warnings: deque[NodeWarningRecord] = field(
        default_factory=lambda: deque(maxlen=NODE_WARNINGS_KEPT))
    node_warnings_dropped: int = 0
    #: the cameras' lenses the node announced on this connection (``sensor_lens``)
    lens: SensorLens | None = None
    _warning_arrivals: deque[float] = field(
        default_factory=lambda: deque(maxlen=NODE_WARNINGS_PER_MINUTE))

    def on_warning(self, text: str, at: float, repeats: int, now: float) -> bool:
        """Keep a backend warning of the node (newest first in the health record).

        A text already kept moves to the front with its repeats added. Beyond
        :data:`NODE_WARNINGS_PER_MINUTE` messages a minute (a broken or hostile node) the
        warning is only counted.

        Returns:
            Whether it was kept.
        """
        arrivals = self._warning_arrivals
        if len(arrivals) == arrivals.maxlen and now - arrivals[0] < 60.0:
            self.node_warnings_dropped += 1
            return False
        arrivals.append(now)
        for w in list(self.node_warnings):
            if w.text == text:
                self.node_warnings.remove(w)
                repeats += w.repeats
                break
        self.node_warnings.append(NodeWarningRecord(at, text, repeats))
        return True

    def fps(self, now: float) -> float:
        """Skeleton frames per second received over the last ~3 s (0 when silent)."""
        ts = [t for t in self.recent if t >= now - 3.0]
        if len(ts) < 2 or ts[-1] <= ts[0]:
            return 0.0
        return (len(ts) - 1) / (ts[-1] - ts[0])

    def on_skeleton(self, seq: int, now: float) -> None:
        """Count a received skeleton frame; a gap in ``seq`` counts as dropped frames."""
        self.frames_received += 1
        self.recent.append(now)
        self.last_seen = now
        if self.last_seq is not None and seq > self.last_seq + 1:
            self.seq_gaps += seq - self.last_seq - 1
        self.last_seq = seq

    @property
    def estimate(self) -> ClockEstimate | None:
        return self.clock.estimate_

    def clock_uncertain(self, warn_ms: float) -> bool:
        """Whether the clock offset is uncertain beyond ``warn_ms``, with hysteresis: once
        above, it counts as uncertain until back below :data:`CLOCK_CLEAR_FRACTION` of
        the limit (on a loaded network the uncertainty hovers at the limit, and the Rig
        page's summary, a live region, flipped several times a second)."""
        est = self.estimate
        if est is None or est.uncertainty_s * 1e3 > warn_ms:
            self._clock_uncertain = True
        elif est.uncertainty_s * 1e3 < CLOCK_CLEAR_FRACTION * warn_ms:
            self._clock_uncertain = False
        return self._clock_uncertain

    def to_server(self, t_local: float) -> float | None:
        """Convert a node timestamp to server time (None until the clock is measured)."""
        est = self.estimate
        return est.to_server(t_local) if est is not None else None


class NodeRegistry:
    """All nodes ever seen since the server started.

    Args:
        clock_window_s: window of the clock drift fit.
        clock_warn_ms: warn when a node's clock uncertainty exceeds this.
        stale_s: a connected node silent for this long gets a warning.
    """

    def __init__(self, clock_window_s: float = 30.0, clock_warn_ms: float = 2.0,
                 stale_s: float = 3.0) -> None:
        self.clock_window_s = clock_window_s
        self.clock_warn_ms = clock_warn_ms
        self.stale_s = stale_s
        self.nodes: dict[str, NodeSession] = {}
        self.listeners: list[Callable[[NodeSession], None]] = []

    def get(self, node_id: str) -> NodeSession | None:
        return self.nodes.get(node_id)

    def connect(self, node_id: str, backend: str, sensor: SensorInfo, send: SendFn,
                restarted: bool) -> NodeSession:
        """Register a (re)connected node; its clock model restarts when the node did."""
        s = self.nodes.get(node_id)
        if s is None:
            s = NodeSession(node_id, ClockEstimator(window_s=self.clock_window_s))
            self.nodes[node_id] = s
        elif restarted:
            s.clock.reset()
            # the warnings were the previous agent process's
            s.node_warnings.clear()
            s.node_warnings_dropped = 0
        s.backend, s.sensor, s.send = backend, sensor, send
        s.reported_pose = sensor.T_world_sensor
        s.lens = None  # announced anew after the welcome (an older node: never)
        s.connected, s.connected_at = True, time.time()
        s.last_seen = time.time()
        s.last_seq = None
        for cb in self.listeners:
            cb(s)
        return s

    def disconnect(self, node_id: str) -> None:
        s = self.nodes.get(node_id)
        if s is not None:
            s.connected, s.send, s.disconnected_at = False, None, time.time()
            s.images.clear()
            for cb in self.listeners:
                cb(s)

    def connected(self) -> list[NodeSession]:
        return [s for s in self.nodes.values() if s.connected]

    def health(self, s: NodeSession, now: float | None = None) -> dict[str, Any]:
        """The health record the console and ``GET /api/nodes`` show."""
        now = time.time() if now is None else now
        est = s.estimate
        offset_ms = est.offset_at(now) * 1e3 if est else None
        unc_ms = est.uncertainty_s * 1e3 if est else None
        dropped = s.seq_gaps + (s.status.dropped if s.status else 0)
        fps = s.fps(now) if s.connected else 0.0
        warnings: list[str] = []
        uncertain = s.clock_uncertain(self.clock_warn_ms)
        if not s.connected:
            warnings.append("Node is offline: check that its computer and agent are running.")
        else:
            if est is None:
                warnings.append("Clock offset not measured yet.")
            elif unc_ms is not None and uncertain:
                clear_ms = CLOCK_CLEAR_FRACTION * self.clock_warn_ms
                clears = ("" if unc_ms > self.clock_warn_ms
                          else f"; the warning clears below {clear_ms:g} ms")
                warnings.append(
                    f"Clock uncertain by ±{unc_ms:.1f} ms (limit {self.clock_warn_ms:g} ms"
                    f"{clears}): frames of this sensor may be mistimed; check the network "
                    "load.")
            if offset_ms is not None and abs(offset_ms) > self.clock_warn_ms:
                warnings.append(
                    f"Clock differs from the server by {offset_ms:+.1f} ms; gaitrig corrects "
                    "this, but running chrony/PTP on the node keeps it below "
                    f"{self.clock_warn_ms:g} ms.")
            warnings.extend(s.sensor.warnings)
            if now - s.last_seen > self.stale_s:
                warnings.append(f"No frames for {now - s.last_seen:.0f} s.")
            elif 0 < fps < 20:
                warnings.append(f"Low frame rate ({fps:.0f} fps; expected about 30).")
            if dropped:
                warnings.append(f"{dropped} frames dropped since the node connected.")
            free = s.status.disk_free_bytes if s.status else None
            if free is not None and free < 2 * 1024**3:
                warnings.append(f"Only {free / 1024**3:.1f} GB free on the node's disk.")
            st = s.status.storage if s.status else None
            if (st is not None and free is not None and free < st.min_free_bytes
                    and st.unverified_parts):
                warnings.append(
                    f"The node's disk is below its free-space floor and its "
                    f"{st.unverified_parts} parts not yet verified on the server "
                    f"({st.unverified_bytes / 1024**3:.1f} GB) cannot be deleted: transfer "
                    "them.")
        if s.refusal_summary is not None and now - s.refusal_summary[0] < REFUSAL_SUMMARY_SHOWN_S:
            at, text = s.refusal_summary
            warnings.append(f"{text} ({max(now - at, 0):.0f} s ago)")
        return {
            "id": s.id,
            "connected": s.connected,
            "backend": s.backend,
            "model": s.sensor.model,
            "fps": round(fps, 2),
            "frames": s.frames_received,
            "dropped_frames": dropped,
            "clock_offset_ms": offset_ms,
            "clock_uncertainty_ms": unc_ms,
            "clock_drift_ppm": est.drift * 1e6 if est else None,
            "clock_rtt_ms": est.rtt_s * 1e3 if est else None,
            "clock_at": now,
            "clock_warning": s.connected and uncertain,
            "disk_free_bytes": s.status.disk_free_bytes if s.status else None,
            "ring_seconds": s.status.ring_seconds if s.status else None,
            # what the node holds, how much of it the server verified (and the node may
            # delete by its retention policy)
            "storage": (s.status.storage.model_dump(exclude={"unverified"})
                        if s.status is not None and s.status.storage is not None else None),
            "connected_at": s.connected_at,
            "last_seen": s.last_seen or None,
            "rejected_messages": s.rejected_messages,
            "last_rejection": s.last_rejection,
            "warnings": warnings,
            # what the node's sensor backend warned about since it connected, newest first
            # (time in server seconds; repeats of one text coalesced)
            "node_warnings": [{"at": w.at, "text": w.text, "repeats": w.repeats}
                              for w in reversed(s.node_warnings)],
            "node_warnings_dropped": s.node_warnings_dropped,
            # the lens the node announced (None: none reported, drawn as a pinhole)
            "lens": None if s.lens is None else {
                "source": s.lens.source,
                "depth_dist": s.lens.depth.dist if s.lens.depth else None,
                "color_dist": s.lens.color.dist if s.lens.color else None},
            "diag": dict(s.status.diag) if s.status else {},
        }
