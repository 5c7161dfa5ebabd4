"""Synchronous recording across nodes.

Where time conversion happens: the **server**. On start it picks ``t_start = now +
margin`` in server time and sends each node ``rec_start`` with that time converted into
the node's own clock through the node's current clock model (the model is also sent, and
the node keeps it in the part's meta). The node records every frame whose local time is
in ``[t_start_local, t_stop_local]``: a command arriving late is served from the 2 s ring
buffer, a stop in the future simply waits, and frames written before a late stop arrived
are cut. So every part covers the same server-time interval to within one frame period
(plus the clock uncertainty), whatever the command latency.

Part states: ``pending`` (command sent) → ``recording`` → ``on_node`` (complete on the
node's disk) or ``incomplete`` (with a reason, e.g. the node disconnected or crashed) →
``transferring`` → ``complete`` (verified copy on the server; :mod:`app.server.transfer`).
An incomplete part can be transferred too; it stays ``incomplete`` with ``on_server``.

A node that drops out of a running recording (crash, restart, power) and comes back while
it still runs is told to record again (:meth:`RecordingManager.rejoin`): ``rec_start``
with ``resume`` continues its part after the frames it kept, with ``rebase_s`` putting the
new frames on the part's first clock model (a restarted node's clock may count from
another origin), so the transfer and the analysis read one part as before; the part ends
``incomplete`` saying how many seconds are missing. A node that connects after the start
records from then on, its part saying so.
This module keeps recordings in memory and in ``<data_dir>/recordings.json`` (a change
appends one line: :mod:`app.server.recording_file`); the data management database builds
on :meth:`RecordingManager.to_dict`.
"""

from __future__ import annotations

import asyncio
import gc
import json
import logging
import random
import secrets
import time
from collections.abc import Iterable
from collections.abc import Set as AbstractSet
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, Self

from app.nodes.protocol import PartInfo, RecStart, RecStop, StreamName, dump
from app.server.clock import ClockEstimate
from app.server.recording_file import RecordingFile
from app.server.registry import NodeRegistry, NodeSession
from engine.errors import InputError
from engine.wording import count

log = logging.getLogger("gaitrig.recording")

#: Recordings loaded from which the manager moves them (and everything made before) out
#: of the garbage collector's passes (:func:`gc.freeze`).
FREEZE_AFTER = 1000
REJOIN_AFTER_S = 1.0  # a node connected this long has reported its parts (hello)


@dataclass
class Part:
    """One node's share of a recording, as the server knows it."""

    node_id: str
    state: str = "pending"
    reason: str | None = None
    n_frames: int = 0
    bytes: int = 0
    t_first_local: float | None = None
    t_last_local: float | None = None
    t_first: float | None = None
    t_last: float | None = None
    clock: dict[str, float] = field(default_factory=dict)
    on_server: bool = False
    transfer_progress: float | None = None


@dataclass
class Recording:
    """A synchronous recording (times in server seconds since the Unix epoch)."""

    id: str
    t_start: float
    t_stop: float | None = None
    created: float = field(default_factory=time.time)
    streams: list[str] = field(default_factory=list)
    image_every: int = 1
    parts: dict[str, Part] = field(default_factory=dict)

    @property
    def state(self) -> str:
        """``recording`` | ``stopping`` | ``on_nodes`` | ``transferring`` | ``complete`` |
        ``incomplete``."""
        if self.t_stop is None:
            return "recording"
        states = {p.state for p in self.parts.values()}
        if "transferring" in states:
            return "transferring"
        if "incomplete" in states:
            return "incomplete"
        if states <= {"complete"}:
            return "complete"
        if states <= {"on_node", "complete"}:
            return "on_nodes"
        return "stopping"


_PART_FIELDS = tuple(f.name for f in fields(Part))
_RECORDING_FIELDS = tuple(f.name for f in fields(Recording) if f.name != "parts")


def _plain(rec: Recording) -> dict[str, Any]:
    """``asdict(rec)`` for JSON, without its deep copies: a server keeps every recording
    it made (tens of thousands after years) and writes them all on every change, where
    ``asdict`` took seconds of the event loop (``bench/list_scale.py``)."""
    d = {k: getattr(rec, k) for k in _RECORDING_FIELDS}
    d["parts"] = {k: {f: getattr(p, f) for f in _PART_FIELDS} for k, p in rec.parts.items()}
    return d


_PART_DEFAULTS = {f.name: f.default for f in fields(Part) if f.name != "clock"}


def _recording(r: dict[str, Any]) -> Recording:
    """A recording as :func:`_plain` wrote it. Built without the dataclasses' keyword
    handling (a clinic's 30 000 recordings load in a fraction of the time); an unknown or
    missing required field raises TypeError or KeyError as the constructor would."""
    parts = {}
    for k, v in r["parts"].items():
        if not _PART_KEYS.issuperset(v) or "node_id" not in v:
            raise TypeError(f"part {k}: unknown or missing fields")
        p = object.__new__(Part)
        p.__dict__.update(_PART_DEFAULTS)
        p.clock = {}
        p.__dict__.update(v)
        parts[k] = p
    if not _REC_KEYS.issuperset(r) or "id" not in r or "t_start" not in r:
        raise TypeError("unknown or missing fields")
    rec = object.__new__(Recording)
    rec.t_stop, rec.streams, rec.image_every = None, [], 1
    rec.__dict__.update(r)
    rec.__dict__.setdefault("created", rec.t_start)
    rec.parts = parts
    return rec


_PART_KEYS = frozenset(_PART_FIELDS)
_REC_KEYS = frozenset((*_RECORDING_FIELDS, "parts"))


def _model(clock: dict[str, float]) -> ClockEstimate:
    """Clock model stored with a part (see :meth:`ClockEstimate.as_dict`)."""
    return ClockEstimate(clock["offset_s"], clock["drift"], clock["t_ref"],
                         clock.get("uncertainty_s", 0.0), 0, 0.0)


class _Changes(set[str]):
    """Ids of the recordings changed since DataSync last took the set; each one put in
    is also noted in ``unsaved`` (written to ``recordings.json`` by the next save)."""

    def __init__(self, unsaved: set[str]) -> None:
        super().__init__()
        self.unsaved = unsaved

    def add(self, element: str) -> None:
        super().add(element)
        self.unsaved.add(element)

    def update(self, *others: Iterable[str]) -> None:
        for o in others:
            for x in o:
                self.add(x)

    def __ior__(self, other: AbstractSet[str]) -> Self:  # type: ignore[override,misc]
        self.update(other)
        return self


class _Tracked(dict[str, Recording]):
    """The recordings by id; a recording put in (new, loaded, or put back) is noted in
    ``changed`` like any other change, one taken out in ``removed``."""

    def __init__(self, changed: set[str], removed: set[str]) -> None:
        super().__init__()
        self.changed = changed
        self.removed = removed
        #: ids put in without a stop time (where :meth:`RecordingManager.active` looks)
        self.running: set[str] = set()

    def __setitem__(self, key: str, value: Recording) -> None:
        super().__setitem__(key, value)
        self.changed.add(key)
        self.removed.discard(key)
        if value.t_stop is None:
            self.running.add(key)

    def __delitem__(self, key: str) -> None:
        super().__delitem__(key)
        self.removed.add(key)

    def pop(self, key: str, *default: Any) -> Any:  # type: ignore[override]
        """Take one out (noted as removed)."""
        if key in self:
            self.removed.add(key)
        return super().pop(key, *default)

    def popitem(self) -> tuple[str, Recording]:
        """Take the last one out (noted as removed)."""
        k, v = super().popitem()
        self.removed.add(k)
        return k, v

    def clear(self) -> None:
        """Take every one out (noted as removed)."""
        self.removed.update(self)
        super().clear()

    def update(self, *args: Any, **kwargs: Recording) -> None:  # dict's skips __setitem__
        """Put several in (noted like one)."""
        for k, v in dict(*args, **kwargs).items():
            self[k] = v


class RecordingManager:
    """Starts/stops recordings on every connected node and tracks their parts.

    Args:
        registry: the node registry.
        data_dir: where ``recordings.json`` lives.
        start_margin_s: start this far in the future (the command then usually arrives
            before the start; the ring buffer covers it when not).
        command_delay_max_s: TEST HOOK; each command to each node is held back by a
            random 0..this seconds, simulating a congested network.
    """

    def __init__(self, registry: NodeRegistry, data_dir: Path, start_margin_s: float = 0.3,
                 command_delay_max_s: float = 0.0) -> None:
        self.registry = registry
        self.file = RecordingFile(Path(data_dir) / "recordings.json")
        self.path = self.file.path
        self.start_margin_s = start_margin_s
        self.command_delay_max_s = command_delay_max_s
        #: ids of the recordings whose state this manager changed since DataSync last
        #: took the set (it revisits only those, not every recording ever made)
        self._unsaved: set[str] = set()  # changed since the last save
        self._removed: set[str] = set()  # taken out since the last save
        self.changed: set[str] = _Changes(self._unsaved)
        tracked = _Tracked(self.changed, self._removed)
        self.recordings: dict[str, Recording] = tracked
        self._maybe_running = tracked.running
        self.save_error: str | None = None  # why the last save failed, if it did
        self._tasks: set[asyncio.Task[None]] = set()
        self._dropped: set[tuple[str, str]] = set()  # (rec, node) parts cut short by a drop
        self._load()
        self.changed.clear()  # DataSync's first pass looks at every loaded one anyway
        self._unsaved.clear()

    # ------------------------------------------------------------------ persistence

    def _load(self) -> None:
        # Tens of thousands of objects at once: the collector's passes over them (none
        # is garbage) cost three times the parsing (bench/storage_scale.py).
        collecting = gc.isenabled()
        gc.disable()
        try:
            self._load_all()
        finally:
            if collecting:
                gc.enable()
        if len(self.recordings) >= FREEZE_AFTER:
            # They live as long as the server: kept out of the collector's full passes,
            # which otherwise walk them all (a quarter of a second of the event loop, at
            # any moment, in a clinic). Memory is still freed by reference counting.
            gc.freeze()
        if self._unsaved:
            self.save()

    def _load_all(self) -> None:
        try:
            raw = self.file.load()
        except (OSError, ValueError) as exc:
            log.error("ignoring unreadable %s: %s", self.path, exc)
            return
        bad = 0
        for r in raw:
            try:
                rec = _recording(r)
            except (TypeError, KeyError, AttributeError, ValueError):
                bad += 1
                continue
            if rec.t_stop is None:  # the server died during it: nodes that kept
                # recording are stopped now (they get rec_stop when they reconnect)
                rec.t_stop = max(time.time(), rec.t_start)
                for p in rec.parts.values():
                    if p.state in ("pending", "recording"):
                        p.state, p.reason = "incomplete", "server restarted during recording"
                self._unsaved.add(rec.id)
            dict.__setitem__(self.recordings, rec.id, rec)  # loaded: nothing to note
        if bad:
            log.error("%s: ignored %s", self.path, count(bad, "unreadable recording"))

    def touch(self, rec_id: str) -> None:
        """Note a change made to a recording outside this manager (e.g. by a transfer):
        the data sync looks at it again and the next :meth:`save` writes it."""
        self.changed.add(rec_id)

    def save(self) -> None:
        """Write the recordings changed (or put in, or taken out) since the last save.

        A change is appended to ``recordings.json`` as one line
        (:mod:`app.server.recording_file`): its cost does not grow with the recordings
        the server keeps. A change made to a recording object from outside must be
        noted first (:meth:`touch`).

        A failure (the server's disk full) is logged and kept in :attr:`save_error`, not
        raised: it must not fail a start whose commands already went out, nor drop the
        node connection whose message triggered it. The next save writes what is left.
        """
        ids, removed = set(self._unsaved), set(self._removed)
        lines = {}
        for k in ids:
            rec = self.recordings.get(k)
            if rec is not None:
                lines[k] = json.dumps(_plain(rec), separators=(",", ":")).encode()
        try:
            self.file.write(lines, removed)
        except OSError as exc:
            if self.save_error is None:
                log.error("cannot save %s (%s); recordings are kept in memory and saved "
                          "again with the next change", self.path, exc)
            self.save_error = (f"the server could not save its recording list ({exc}); a "
                               "server restart now would lose the latest states")
            return
        self._unsaved.difference_update(ids)
        self._removed.difference_update(removed)
        self.save_error = None

    # ------------------------------------------------------------------ commands

    def active(self) -> Recording | None:
        """The recording in progress, if any (looked for among those put in without a
        stop time: every pass of the data sync asks, and a clinic keeps 30 000)."""
        for rec_id in list(self._maybe_running):
            r = self.recordings.get(rec_id)
            if r is not None and r.t_stop is None:
                return r
            self._maybe_running.discard(rec_id)
        return None

    def _send_later(self, s: NodeSession, text: str) -> None:
        async def go() -> None:
            if self.command_delay_max_s > 0:
                await asyncio.sleep(random.uniform(0.0, self.command_delay_max_s))
            if s.send is not None:
                try:
                    await s.send(text)
                except Exception as exc:  # the node vanished; disconnect handling follows
                    log.warning("could not send to %s: %s", s.id, exc)

        task = asyncio.create_task(go())
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    def start(self, streams: list[StreamName] | None = None, image_every: int = 1) -> Recording:
        """Start a recording on every connected node whose clock is measured.

        Raises:
            InputError: a recording already runs, or no node can record.
        """
        if self.active() is not None:
            raise InputError("a recording is already running; stop it first")
        ready = [s for s in self.registry.connected() if s.estimate is not None]
        if not ready:
            raise InputError("no connected node with a measured clock; wait until the "
                             "Rig page shows the nodes online")
        now = time.time()
        rec_id = time.strftime("R%Y%m%d-%H%M%S", time.gmtime(now)) + "-" + secrets.token_hex(2)
        rec = Recording(rec_id, t_start=now + self.start_margin_s, streams=list(streams or []),
                        image_every=image_every)
        for s in ready:
            est = s.estimate
            assert est is not None
            rec.parts[s.id] = Part(s.id, clock=est.as_dict())
            cmd = RecStart(rec_id=rec_id, t_start_server=rec.t_start,
                           t_start_local=est.to_local(rec.t_start), streams=list(streams or []),
                           image_every=image_every, clock=est.as_dict())
            self._send_later(s, dump(cmd))
        self.recordings[rec_id] = rec
        self.save()
        log.info("recording %s starts at %.3f on %s", rec_id, rec.t_start, ", ".join(rec.parts))
        return rec

    def stop(self, rec_id: str) -> Recording:
        """Stop a recording now (server time) on all its nodes.

        Raises:
            InputError: unknown or already stopped recording.
        """
        rec = self.recordings.get(rec_id)
        if rec is None:
            raise InputError(f"no recording {rec_id!r}")
        if rec.t_stop is not None:
            raise InputError(f"recording {rec_id} is already stopped")
        rec.t_stop = max(time.time(), rec.t_start)
        self.changed.add(rec_id)
        for node_id in rec.parts:
            self._send_stop(rec, node_id)
        self.save()
        return rec

    def _send_stop(self, rec: Recording, node_id: str) -> None:
        s = self.registry.get(node_id)
        if s is None or not s.connected or rec.t_stop is None:
            return
        est = s.estimate or _model(rec.parts[node_id].clock)
        cmd = RecStop(rec_id=rec.id, t_stop_server=rec.t_stop,
                      t_stop_local=est.to_local(rec.t_stop), clock=est.as_dict())
        self._send_later(s, dump(cmd))

    # ------------------------------------------------------------------ node events

    def on_part(self, node_id: str, info: PartInfo, from_hello: bool = False,
                save: bool = True) -> bool:
        """A node reported the state of one of its parts.

        Args:
            save: save the list when the state changed; False for a node's listing of
                many parts, which the caller saves once (a save rewrites every recording).

        Returns:
            Whether the part's state changed.
        """
        rec = self.recordings.get(info.rec_id)
        if rec is None:
            return False
        part = rec.parts.setdefault(node_id, Part(node_id))
        prev = part.state
        if prev in ("transferring", "complete") or part.on_server:
            return False  # the server's copy is authoritative now
        self.changed.add(rec.id)  # frames and bytes too, even when the state stays
        part.n_frames, part.bytes = info.n_frames, info.bytes
        part.t_first_local, part.t_last_local = info.t_first, info.t_last
        if part.clock:
            model = _model(part.clock)
            part.t_first = model.to_server(info.t_first) if info.t_first is not None else None
            part.t_last = model.to_server(info.t_last) if info.t_last is not None else None
        if info.state == "incomplete":
            part.state, part.reason = "incomplete", info.reason or part.reason
        elif info.state == "recording" and prev == "incomplete" and part.reason:
            # A network blip: the node kept recording locally.
            part.state = "recording"
            part.reason = part.reason + "; the node kept recording"
        elif not (prev == "incomplete" and info.state != "on_node"):
            part.state = info.state
        if from_hello and info.state == "recording" and rec.t_stop is not None:
            self._send_stop(rec, node_id)  # it missed the stop while disconnected
        if from_hello and info.state == "incomplete" and rec.t_stop is None:
            self._dropped.add((rec.id, node_id))  # restarted during it: record again
        if prev != part.state:
            log.info("recording %s part %s: %s → %s", rec.id, node_id, prev, part.state)
            if save:
                self.save()
            return True
        return False

    def on_disconnect(self, node_id: str) -> None:
        """A node dropped: its unfinished parts become incomplete."""
        for rec in self.recordings.values():
            part = rec.parts.get(node_id)
            if part is not None and part.state in ("pending", "recording"):
                part.state = "incomplete"
                part.reason = (f"node {node_id} disconnected at "
                               f"{time.strftime('%H:%M:%S', time.gmtime())} UTC during the "
                               "recording")
                log.warning("recording %s: %s", rec.id, part.reason)
                self.changed.add(rec.id)
                if rec.t_stop is None:
                    self._dropped.add((rec.id, node_id))
                self.save()

    def rejoin(self) -> list[str]:
        """Bring nodes (back) into the running recording: a node whose part was cut short
        (it dropped; restarted, its part is closed) records again into that part; a node
        that was not there at the start records from now on. Only nodes connected for
        :data:`REJOIN_AFTER_S` with a measured clock; each drop is answered once (a node
        that kept recording through a network blip ignores the resume).

        Returns:
            The nodes told to record now.
        """
        rec = self.active()
        if rec is None:
            return []
        now = time.time()
        told = []
        for s in self.registry.connected():
            est = s.estimate
            if est is None or s.connected_at is None or now - s.connected_at < REJOIN_AFTER_S:
                continue
            part = rec.parts.get(s.id)
            if part is not None and (rec.id, s.id) not in self._dropped:
                continue
            self._dropped.discard((rec.id, s.id))
            if part is not None and part.state != "incomplete":
                continue  # it kept recording (a network blip): nothing to do
            t = max(now + self.start_margin_s, rec.t_start)
            when = time.strftime("%H:%M:%S", time.gmtime(t))
            if part is None:
                part = Part(s.id, clock=est.as_dict(), reason=(
                    f"node {s.id} joined {t - rec.t_start:.0f} s after the start; recorded "
                    f"from {when} UTC"))
                rec.parts[s.id] = part
                cmd = RecStart(rec_id=rec.id, t_start_server=t, t_start_local=est.to_local(t),
                               streams=list(rec.streams), image_every=rec.image_every,  # type: ignore[arg-type]
                               clock=est.as_dict())
            else:
                first = _model(part.clock) if part.clock else est
                part.state = "pending"
                part.reason = f"{part.reason or 'cut short'}; recording again from {when} UTC"
                cmd = RecStart(rec_id=rec.id, t_start_server=t, t_start_local=est.to_local(t),
                               streams=list(rec.streams), image_every=rec.image_every,  # type: ignore[arg-type]
                               clock=est.as_dict(), resume=True,
                               rebase_s=first.to_local(t) - est.to_local(t))
            self._send_later(s, dump(cmd))
            log.info("recording %s: node %s records (again): %s", rec.id, s.id, part.reason)
            told.append(s.id)
        if told:
            self.changed.add(rec.id)
            self.save()
        return told

    def to_dict(self, rec: Recording) -> dict[str, Any]:
        """JSON view of a recording (REST)."""
        d = asdict(rec)
        d["state"] = rec.state
        d["parts"] = list(d["parts"].values())
        d["save_error"] = self.save_error
        return d
