"""Keeps the data-management database in step with live recordings and their transfers.

The backbone's :class:`app.server.recording.RecordingManager` knows the node parts of
every recording and :class:`app.server.transfer.TransferManager` copies them to the
server. :class:`DataSync` runs beside them (twice a second) and

* starts the transfer of every closed part as soon as a recording is stopped (filed
  under a session or not), and
  retries a failed one when its node reconnects or after ``retry_s`` (or at once on
  request, :meth:`DataSync.retry`);
* mirrors states, reasons, sizes and progress into the :mod:`app.db.data` tables, so
  the console shows which node failed and why, and a restarted server still knows;
* asks the nodes to delete their copies of deleted recordings (now, or when they
  reconnect);
* tells a node again which of the parts it lists as unconfirmed (``status``) the server
  holds verified (the message sent after the transfer was lost with a connection or a
  restart), so the node can apply its retention policy;
* has nodes that come back during a running recording (or join it late) record
  (:meth:`app.server.recording.RecordingManager.rejoin`);
* derives the recording state: ``recording`` → ``on_nodes`` → ``transferring`` →
  ``complete`` only when every part is verified on the server (``manifest.json`` in its
  folder), otherwise ``incomplete`` with the reasons; on ``complete`` it snapshots the
  sensor poses of the recording (``sensors.json``, :func:`recording_poses`).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import time
from collections.abc import Collection
from pathlib import Path
from typing import Any

from sqlalchemy import or_, select
from sqlalchemy.orm import selectinload, sessionmaker

from app.db import audit
from app.db import data as m
from app.server.hub import Hub
from app.server.recording import Part
from app.server.recording import Recording as LiveRecording
from app.server.storage import StorageLayout, note_changed, part_meta, recording_poses
from engine.errors import GaitrigError, InputError

log = logging.getLogger("gaitrig.datasync")

TRANSFER_FAILED = "transfer failed"
#: What a recording (and its part) says when its verified copy on the server is gone or
#: damaged (found by the periodic check of settled recordings, :meth:`DataSync.check`).
SERVER_COPY_MISSING = "Server copy missing — restore from backup"
#: Recording states before complete/incomplete (named, not "not in": the state index is
#: then used instead of a scan of every row, twice a second)
_ON_THEIR_WAY = tuple(s for s in m.RECORDING_STATES if s not in ("complete", "incomplete"))
VERIFY_REPEAT_S = 600.0  # a node's part is told "verified" again at most this often
#: Recordings of the start-up sweep (every one not complete) a pass examines besides its
#: own: a clinic has a couple of thousand, which in one pass held the event loop for
#: seconds; a few dozen take milliseconds (bench/storage_scale.py). Passes follow each
#: other every SWEEP_INTERVAL_S until the sweep is done.
SWEEP_CHUNK = 10
SWEEP_INTERVAL_S = 0.05


def part_state(p: Part, complete_on_disk: bool) -> tuple[str, str | None]:
    """Database state and reason of one live part."""
    if p.state == "transferring":
        return "transferring", None
    if p.on_server and p.state == "complete" and complete_on_disk:
        # what happened on the way stays on record (the node reconnected and kept
        # recording, or recorded again after a restart); a failed transfer retried since
        # is over
        keep = p.reason if p.reason and not p.reason.startswith(TRANSFER_FAILED) else None
        return "complete", keep
    if p.state == "incomplete":
        return "incomplete", p.reason or "the node reported the part incomplete"
    if p.state == "on_node" and p.reason and p.reason.startswith(TRANSFER_FAILED):
        return "incomplete", p.reason
    if p.state == "on_node" and p.n_frames == 0:
        return "incomplete", f"node {p.node_id} recorded no frame"
    if p.state == "complete" and not complete_on_disk:
        return "incomplete", (f"{SERVER_COPY_MISSING} (or transfer it again if its sensor "
                              "still holds it)")
    return p.state, p.reason


def recording_state(rec: LiveRecording, parts: dict[str, tuple[str, str | None]]
                    ) -> tuple[str, str | None]:
    """Database state and reason of a recording from its parts' states."""
    if rec.t_stop is None:
        return "recording", None
    states = {s for s, _ in parts.values()}
    if "transferring" in states:
        return "transferring", None
    if parts and states == {"complete"}:
        return "complete", None
    bad = [f"{n}: {r}" for n, (s, r) in sorted(parts.items()) if s == "incomplete"]
    if bad:
        return "incomplete", "; ".join(bad)
    return "on_nodes", None


class DataSync:
    """Background mirror of live recordings into the database (see module docstring).

    Args:
        hub: the server's hub (recordings, transfers, registry).
        db_sessions: session factory of the database.
        layout: the server's storage layout.
        retry_s: retry a failed transfer of a connected node this often.
        check_interval_s: check every settled recording's copy on the server once in this
            time, a few per pass (:meth:`check`); 0: never.
    """

    def __init__(self, hub: Hub, db_sessions: sessionmaker[Any], layout: StorageLayout,
                 retry_s: float = 10.0, check_interval_s: float = 3600.0) -> None:
        self.hub = hub
        self.check_interval_s = check_interval_s
        self._check_queue: list[str] = []  # settled recordings this round still checks
        self._check_quota = 1  # of them per pass
        self._check_round_at: float | None = None  # when the round began (monotonic)
        self._interval_s = 0.5
        #: recordings the periodic check looked at, and found damaged (tests and logs)
        self.checked = 0
        self.found_damaged: list[str] = []
        self.db_sessions = db_sessions
        self.layout = layout
        self.retry_s = retry_s
        self._last_try: dict[str, float] = {}
        self._connected: dict[str, bool] = {}
        self._task: asyncio.Task[None] | None = None
        self._verify_checked: dict[str, float] = {}  # node -> last look at its list
        self._verify_sent: dict[tuple[str, str], float] = {}  # (node, rec) -> last told
        self._notes: set[asyncio.Task[bool]] = set()
        # A pass examines only the recordings that can still change (a clinic keeps
        # thousands that never completed, for good): those changed since the last pass
        # (the recording manager's ``changed``, :meth:`retry`, a row filed by
        # :meth:`write`), those in or just out of a transfer, those with a part a
        # connected node can still send (retried every ``retry_s``), and those waiting
        # for a node that has just reconnected. Every recording not complete is examined
        # once after the start (the sweep), SWEEP_CHUNK per pass beside the others, its
        # list read in a worker thread.
        self._dirty: set[str] = set()
        self._active: set[str] = set()
        self._waiting: dict[str, set[str]] = {}  # node -> recordings with a part on it
        self._was_running: set[str] = set()
        self._sweep: list[str] | None = None  # still to examine (None: not read yet)
        self._in_step = False
        #: recordings examined by the last pass (the work it did; see tests and bench)
        self.examined_last = 0

    # ------------------------------------------------------------------ lifecycle

    def start(self, interval_s: float = 0.5) -> None:
        """Run :meth:`step` every ``interval_s`` in the running event loop."""

        self._interval_s = interval_s

        async def loop() -> None:
            if self._sweep is None:
                try:  # its query reads every complete id: not in the event loop
                    self._sweep = await asyncio.to_thread(self._sweep_ids)
                except Exception:  # the first pass reads it again
                    log.exception("data sync: the recordings to look at could not be read")
            while True:
                try:
                    self.step()
                except Exception:  # a bad row must not stop the sync of the others
                    log.exception("data sync step failed")
                if self._check_due():
                    try:  # the ids of every settled recording: not in the event loop
                        self.begin_check(await asyncio.to_thread(self._settled_ids))
                    except Exception:
                        log.exception("data sync: the settled recordings could not be read")
                        self._check_round_at = time.monotonic()  # tried again next round
                await asyncio.sleep(SWEEP_INTERVAL_S if self._sweep else interval_s)

        self._task = asyncio.create_task(loop())

    async def stop(self) -> None:
        """Stop the background loop."""
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task

    # ------------------------------------------------------------------ work

    def retry(self, rec_id: str) -> None:
        """Transfer the missing parts of a recording now.

        Raises:
            InputError: nothing to transfer, still running or already transferring.
        """
        self._last_try[rec_id] = time.time()
        self._dirty.add(rec_id)
        self.hub.transfers.start(rec_id)

    def _maybe_transfer(self, rec: LiveRecording, reconnected: set[str]) -> None:
        if rec.t_stop is None:
            return
        reg = self.hub.registry
        busy = self.hub.transfers.running_parts(rec.id)
        todo = [n for n, p in rec.parts.items()
                if p.state in ("on_node", "incomplete") and not p.on_server and p.n_frames
                and n not in busy and (s := reg.get(n)) is not None and s.connected]
        if not todo:
            return
        due = (rec.id not in self._last_try or bool(reconnected & set(todo))
               or time.time() - self._last_try[rec.id] >= self.retry_s)
        if not due:
            return
        self._last_try[rec.id] = time.time()
        try:
            self.hub.transfers.start(rec.id)
            log.info("recording %s: transferring %s", rec.id, ", ".join(todo))
        except InputError as exc:
            log.info("recording %s: no transfer now (%s)", rec.id, exc)

    def _cancel_transfers_of(self, nodes: set[str]) -> None:
        # A node that dropped will not answer its pending chunk requests: stop waiting
        # for the reply timeout, the verified chunks stay and are resumed on reconnect.
        for rec_id in self.hub.transfers.running():
            rec = self.hub.recordings.recordings.get(rec_id)
            if rec is None:
                continue
            hit = [n for n, p in rec.parts.items() if n in nodes and p.state == "transferring"]
            if hit:
                log.warning("recording %s: node %s dropped during the transfer; it resumes when "
                            "the node is back", rec_id, ", ".join(hit))
                for n in hit:
                    rec.parts[n].reason = (f"{TRANSFER_FAILED} (node {n} disconnected during "
                                           "the transfer); it resumes when the node is back")
                self.hub.recordings.touch(rec_id)
                self.hub.transfers.cancel(rec_id, hit)

    def _repair(self, rec: LiveRecording) -> None:
        # A part left "transferring" by a server that died mid-transfer: nothing is
        # transferring it now, so it is back to being on its node (resumed later).
        busy = self.hub.transfers.running_parts(rec.id)
        for p in rec.parts.values():
            if p.state == "transferring" and p.node_id not in busy:
                p.state = "on_node" if not p.reason or p.reason.startswith(TRANSFER_FAILED) \
                    else "incomplete"
                p.transfer_progress = None
                self.hub.recordings.touch(rec.id)

    def step(self) -> None:
        """One pass: start/retry transfers and write the state of every recording that can
        still change (see :meth:`__init__`'s note), and the next part of the start-up sweep."""
        reconnected, dropped = set(), set()
        for s in self.hub.registry.nodes.values():
            was = self._connected.get(s.id, False)
            if s.connected and not was:
                reconnected.add(s.id)
            if was and not s.connected:
                dropped.add(s.id)
            self._connected[s.id] = s.connected
        live = self.hub.recordings.recordings
        if dropped:
            self._cancel_transfers_of(dropped)
        # node copies of deleted recordings: ask the connected nodes (again)
        self.hub.transfers.flush_deletions(self.retry_s)
        self.confirm_verified(reconnected)
        # nodes back in (or new to) a running recording record (again)
        self.hub.recordings.rejoin()
        todo = self._take_todo(reconnected)
        self._in_step = True
        try:
            if self._sweep is None:  # called without start(): read it here
                self._sweep = self._sweep_ids()
            if self._sweep:
                todo.update(self._sweep[:SWEEP_CHUNK])
                del self._sweep[:SWEEP_CHUNK]
            with self.db_sessions() as db:
                self.examined_last = len(todo)
                rows, done = self._rows_of(db, todo)
                # every stopped recording is transferred, filed under a session or not yet
                for rec_id in todo:
                    rec = live.get(rec_id)
                    if rec is None or rec_id in done:
                        self._active.discard(rec_id)
                        continue
                    self._repair(rec)
                    self._maybe_transfer(rec, reconnected)
                    if rec_id in rows:
                        self.write(db, rows[rec_id], rec)
                    self._settle(rec)
                # rows still said to be on their way (ids only: a clinic keeps hundreds
                # on nodes that are gone) whose recording the server no longer tracks
                lost = [i for i in db.scalars(select(m.Recording.id).where(
                    m.Recording.state.in_(_ON_THEIR_WAY))) if i not in live]
                for i in range(0, len(lost), 500):
                    for row in db.scalars(select(m.Recording).where(
                            m.Recording.id.in_(lost[i:i + 500]))):
                        row.state = "incomplete"
                        row.reason = ("the server lost track of this recording (its "
                                      "recordings.json is gone); the data may still be on "
                                      "the nodes")
                self._check_some(db)
                db.commit()
        finally:
            self._in_step = False

    # ------------------------------------------------------------------ settled copies

    def _check_due(self) -> bool:
        """Whether a new round of the periodic check begins now (after the start-up
        sweep, then every ``check_interval_s``)."""
        if self.check_interval_s <= 0 or self._sweep or self._sweep is None \
                or self._check_queue:
            return False
        return (self._check_round_at is None
                or time.monotonic() - self._check_round_at >= self.check_interval_s)

    def _settled_ids(self) -> list[str]:
        """Every recording whose copy should be whole on the server: complete, or found
        damaged before (so it is seen when the copy is restored)."""
        t = m.Recording.__table__
        with self.db_sessions() as db:
            return list(db.execute(select(t.c.id).where(or_(
                t.c.state == "complete",
                t.c.reason.startswith(SERVER_COPY_MISSING, autoescape=True)))).scalars())

    def begin_check(self, rec_ids: list[str]) -> None:
        """Start a round of the periodic check over ``rec_ids``, spread over the passes of
        ``check_interval_s`` (a clinic's 30 000 recordings: about four a pass)."""
        self._check_round_at = time.monotonic()
        self._check_queue = list(rec_ids)
        passes = max(1.0, self.check_interval_s / max(self._interval_s, 1e-3))
        self._check_quota = max(1, math.ceil(len(rec_ids) / passes))

    def check(self, rec_ids: Collection[str]) -> list[str]:
        """Check the copies of settled recordings now (see :meth:`_check_row`); returns
        those found damaged or missing."""
        before = len(self.found_damaged)
        with self.db_sessions() as db:
            self._check_rows(db, list(rec_ids))
            db.commit()
        return self.found_damaged[before:]

    def _check_some(self, db: Any) -> None:
        if not self._check_queue:
            return
        ids = self._check_queue[:self._check_quota]
        del self._check_queue[:self._check_quota]
        self._check_rows(db, ids)

    def _check_rows(self, db: Any, ids: list[str]) -> None:
        for row in db.scalars(select(m.Recording).where(m.Recording.id.in_(ids))
                              .options(selectinload(m.Recording.parts))):
            if row.id in self._active or self.hub.transfers.running_parts(row.id):
                continue  # changing now: not settled
            self.checked += 1
            self._check_row(db, row)

    def _check_row(self, db: Any, row: m.Recording) -> None:
        """A settled recording's parts on the server: each complete part's folder must
        hold every file of its manifest with its size. A damaged or missing one makes
        the part and the recording ``incomplete`` with :data:`SERVER_COPY_MISSING` and
        is audited; a copy found whole again (restored) makes them complete again.
        Nothing else changes."""
        faults: dict[str, str] = {}
        for p in row.parts:
            if p.state == "complete" or (p.reason or "").startswith(SERVER_COPY_MISSING):
                fault = server_copy_fault(self.layout.part_dir(row.id, p.node_id))
                if fault is not None:
                    faults[p.node_id] = fault
        was_missing = (row.reason or "").startswith(SERVER_COPY_MISSING)
        if faults and row.state == "complete":
            for p in row.parts:
                if p.node_id in faults:
                    p.state, p.reason = "incomplete", f"{SERVER_COPY_MISSING} ({faults[p.node_id]})"
            row.state = "incomplete"
            row.reason = f"{SERVER_COPY_MISSING}: " + "; ".join(
                f"{n}: {why}" for n, why in sorted(faults.items()))
            self.found_damaged.append(row.id)
            log.error("recording %s: %s", row.id, row.reason)
            db.add(audit.event("(server)", "storage_check", f"recording {row.id}",
                               row.reason))
        elif not faults and was_missing:
            for p in row.parts:
                if (p.reason or "").startswith(SERVER_COPY_MISSING):
                    p.state, p.reason = "complete", None
            if all(p.state == "complete" for p in row.parts):
                row.state, row.reason = "complete", None
                log.info("recording %s: its copy on the server is whole again", row.id)
                db.add(audit.event("(server)", "storage_check", f"recording {row.id}",
                                   "server copy whole again"))
        else:
            return
        note_changed(self.layout.recording_dir(row.id))  # its bytes, measured again

    @property
    def sweeping(self) -> int | None:
        """Recordings the start-up sweep has still to examine (see :meth:`__init__`);
        None before it was read."""
        return len(self._sweep) if self._sweep is not None else None

    def _sweep_ids(self) -> list[str]:
        """Every recording the server knows that has no complete row: what the passes
        after the start look at once (newest first). Reads ids only, without the ORM."""
        t = m.Recording.__table__
        with self.db_sessions() as db:
            done = set(db.execute(select(t.c.id).where(t.c.state == "complete")).scalars())
            ids = sorted(self.hub.recordings.recordings.keys() - done, reverse=True)
            # the ORM builds its loaders and compiles a pass's queries on their first use
            # (half a second): here, in the worker thread, not in the loop's first pass
            self._rows_of(db, ids[:1])
        return ids

    def _take_todo(self, reconnected: set[str]) -> set[str]:
        """The recordings this pass examines (and forget why they were due)."""
        changed = set(self.hub.recordings.changed)  # emptied in place: it is shared
        self.hub.recordings.changed.clear()
        running = set(self.hub.transfers.running())
        todo = self._dirty | changed | self._active | running | self._was_running
        for n in reconnected:
            todo |= self._waiting.pop(n, set())
        self._dirty, self._was_running = set(), running
        return todo

    def _rows_of(self, db: Any, ids: Collection[str]
                 ) -> tuple[dict[str, m.Recording], set[str]]:
        """The not-yet-complete rows (with their parts) and the complete ids among
        ``ids``, read in chunks (a database bounds the parameters of a query)."""
        rows: dict[str, m.Recording] = {}
        done: set[str] = set()
        todo = sorted(ids)
        for i in range(0, len(todo), 500):
            chunk = todo[i:i + 500]
            rows.update((r.id, r) for r in db.scalars(select(m.Recording).where(
                m.Recording.id.in_(chunk), m.Recording.state != "complete")
                .options(selectinload(m.Recording.parts))))
            done.update(db.scalars(select(m.Recording.id).where(
                m.Recording.id.in_(chunk), m.Recording.state == "complete")))
        return rows, done

    def _settle(self, rec: LiveRecording) -> None:
        """Keep ``rec`` examined every pass while it can change by itself; otherwise
        leave it until something changes it (or a node it waits for reconnects)."""
        self._active.discard(rec.id)
        if rec.t_stop is None or self.hub.transfers.running_parts(rec.id) or any(
                p.state in ("pending", "recording", "transferring")
                for p in rec.parts.values()):
            self._active.add(rec.id)
            return
        reg = self.hub.registry
        for n, p in rec.parts.items():
            if p.state in ("on_node", "incomplete") and not p.on_server and p.n_frames:
                s = reg.get(n)
                if s is not None and s.connected:
                    self._active.add(rec.id)  # transferred (retried) by a coming pass
                else:
                    self._waiting.setdefault(n, set()).add(rec.id)

    def confirm_verified(self, reconnected: Collection[str] = ()) -> list[str]:
        """Tell each connected node which of its unconfirmed parts (its ``status``) the
        server holds verified. A node's list is looked at every ``retry_s`` (at once after
        a reconnect); a part is told at most every :data:`VERIFY_REPEAT_S` (a node that
        disagrees, e.g. its part changed, is not asked in a loop).

        Returns:
            ``node/rec_id`` of the parts told now.
        """
        now = time.monotonic()
        told = []
        for s in self.hub.registry.nodes.values():
            st = s.status.storage if s.connected and s.status is not None else None
            if st is None or not st.unverified:
                continue
            if s.id not in reconnected and now - self._verify_checked.get(s.id, -1e9) < \
                    self.retry_s:
                continue
            self._verify_checked[s.id] = now
            for rec_id in st.unverified:
                key = (s.id, rec_id)
                if rec_id in (".", "..") or now - self._verify_sent.get(key, -1e9) < \
                        VERIFY_REPEAT_S:
                    continue
                if self.hub.transfers.verified_sha(rec_id, s.id) is None:
                    continue
                self._verify_sent[key] = now
                task = asyncio.ensure_future(self.hub.transfers.send_verified(rec_id, s.id))
                self._notes.add(task)
                task.add_done_callback(self._notes.discard)
                told.append(f"{s.id}/{rec_id}")
        if told:
            log.info("told nodes of their verified copies: %s", ", ".join(told))
        return told

    def write(self, db: Any, row: m.Recording, rec: LiveRecording) -> None:
        """Copy one live recording's state into its row and part rows (a row written
        from outside a pass, e.g. one just filed under a session, is examined again by the
        next pass)."""
        if not self._in_step:
            self._dirty.add(rec.id)
        complete = set(self.layout.complete_parts(rec.id)) if rec.t_stop is not None else set()
        states: dict[str, tuple[str, str | None]] = {}
        by_node = {p.node_id: p for p in row.parts}
        for node_id, p in rec.parts.items():
            st, reason = part_state(p, node_id in complete)
            states[node_id] = (st, reason)
            pr = by_node.get(node_id)
            if pr is None:
                pr = m.RecordingPart(node_id=node_id, state=st, n_frames=0, bytes_total=0,
                                     bytes_done=0, attempts=0)
                row.parts.append(pr)
            if pr.state != "transferring" and st == "transferring":
                pr.attempts = (pr.attempts or 0) + 1
            done = (p.bytes if st == "complete" else
                    int(p.bytes * p.transfer_progress) if p.transfer_progress is not None else 0)
            new = {"state": st, "reason": reason, "n_frames": p.n_frames,
                   "bytes_total": p.bytes, "bytes_done": done}
            if st == "complete" and pr.manifest_sha256 is None:
                new["manifest_sha256"] = _manifest_sha(self.layout, rec.id, node_id)
            if st == "complete" and pr.images_skipped is None:  # stored once it arrived
                new["images_skipped"] = _images_skipped(self.layout, rec.id, node_id)
            for k, v in new.items():
                if getattr(pr, k) != v:
                    setattr(pr, k, v)
        state, reason = recording_state(rec, states)
        if state == "complete" and row.state != "complete":
            # fix the sensor poses of this recording now (sensors.json), before anyone
            # recalibrates: its analyses and exports always use the rig as it was
            try:
                recording_poses(self.layout, self.hub.registry, rec.id)
            except (GaitrigError, OSError, ValueError) as exc:  # e.g. unreadable calibration
                log.warning("recording %s: sensor poses not saved (%s); the first analysis "
                            "or export saves them", rec.id, exc)
        if (row.state, row.reason, row.t_start, row.t_stop) != (state, reason, rec.t_start,
                                                                rec.t_stop):
            row.state, row.reason, row.t_start, row.t_stop = state, reason, rec.t_start, rec.t_stop


def server_copy_fault(part_dir: Path) -> str | None:
    """What is wrong with a part's verified copy on the server, in words for the console
    (None: every file of its manifest is there with its size). Reads the manifest and
    one ``stat`` per file, not the files."""
    if not part_dir.is_dir():
        return "its folder is gone"
    try:
        man = json.loads((part_dir / "manifest.json").read_bytes())
        files = [(str(f["name"]), int(f["size"])) for f in man["files"]]
    except FileNotFoundError:
        return "its manifest.json is gone"
    except (OSError, ValueError, KeyError, TypeError):
        return "its manifest.json is unreadable"
    if (part_dir / ".incoming").exists():
        return "it is half transferred again"
    for name, size in files:
        try:
            have = (part_dir / name).stat().st_size
        except OSError:
            return f"{name} is gone"
        if have != size:
            return f"{name} has {have} bytes instead of {size}"
    return None


def _images_skipped(layout: StorageLayout, rec_id: str, node_id: str) -> int | None:
    """Frames of a part on the server recorded without their images, from its
    ``meta.json`` (a part recorded before the count existed has none: 0); ``None`` when
    the meta cannot be read (asked again at the next pass)."""
    try:
        return int(part_meta(layout.part_dir(rec_id, node_id)).get("images_skipped", 0))
    except (InputError, ValueError, TypeError):
        return None


def _manifest_sha(layout: StorageLayout, rec_id: str, node_id: str) -> str | None:
    import hashlib

    path = layout.part_dir(rec_id, node_id) / "manifest.json"
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return None
