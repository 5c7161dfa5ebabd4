"""Append-only, crash-safe local recording store of a node.

Layout under the node's data folder::

    recordings/<rec_id>/meta.json    # PartInfo + recording parameters (atomic rewrite)
    recordings/<rec_id>/frames.bin   # records: uint32 length, uint32 crc32, payload
    recordings/<rec_id>/index.json   # [[t_local, byte_offset, kind], ...] written on close
    recordings/<rec_id>/verified.json  # the server holds a verified copy (not transferred)

Each payload is one binary protocol message (:func:`app.nodes.protocol.encode_binary`),
so a part replays exactly what was streamed. Records are flushed to the OS after every
write (survives ``kill -9``) and ``fsync``-ed at least every ``fsync_interval_s`` (survives
power loss up to that interval). On open, :meth:`NodeStore.recover` scans parts that
were never closed, truncates a torn or corrupt tail, rebuilds the index and marks the
part ``incomplete`` with the reason.

Retention: a node's disk would fill within weeks of clinic use if it kept every part for
ever. Once the server has verified its copy of a part (every chunk and file checked
against the node's manifest) it tells the node, which notes it in ``verified.json``
(:meth:`NodeStore.mark_verified`; outside the manifest, so the part's files are not
changed). :meth:`NodeStore.purge` then deletes verified parts by a
:class:`RetentionPolicy`: after ``keep_verified_s``, and, whenever the free space is below
the policy's floor, the oldest verified parts first. A part without ``verified.json`` is
never purged: it may be the only copy.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import re
import shutil
import struct
import time
import zlib
from collections.abc import Callable, Collection, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

from app.nodes.protocol import PartInfo, ProtocolError, decode_binary
from engine.errors import InputError

log = logging.getLogger("gaitrig.node")

_REC = struct.Struct("<II")
_IDX = struct.Struct("<dqB")  # an index entry in the spool: t_local, offset, kind code
_IDX_DTYPE = np.dtype([("t", "<f8"), ("offset", "<i8"), ("kind", "u1")])
SPOOL = "index.spool"  # the index of an open part (index.json once it is closed)
VERIFIED = "verified.json"  # written when the server confirms its verified copy
MAX_RECORD = 64 * 1024 * 1024
_ID_RE = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")


def _atomic_write_json(path: Path, obj: Any) -> None:
    tmp = path.with_suffix(path.suffix + ".tmp")
    try:
        with open(tmp, "w") as f:
            json.dump(obj, f)
            f.flush()
            os.fsync(f.fileno())
    except OSError:
        tmp.unlink(missing_ok=True)
        raise
    os.replace(tmp, path)


def _rewrite_json_in_place(path: Path, obj: Any) -> None:
    """Overwrite an existing small JSON file where it is: on a full disk there is no room
    for the temporary copy of an atomic write, but a file shorter than the block the old
    one already occupies needs no new space."""
    data = json.dumps(obj).encode()
    with open(path, "r+b") as f:
        f.write(data)
        f.truncate(len(data))
        f.flush()
        os.fsync(f.fileno())


def _check_id(rec_id: str) -> str:
    # rec ids become folder names: refuse anything that could traverse paths.
    if not _ID_RE.match(rec_id) or rec_id in (".", ".."):
        raise InputError(f"recording id {rec_id!r} must be 1-64 characters of A-Z a-z 0-9 _ . -")
    return rec_id


class PartWriter:
    """Writer of one recording part; use :meth:`NodeStore.create_part`."""

    def __init__(self, folder: Path, meta: dict[str, Any], fsync_interval_s: float = 0.5) -> None:
        self.folder = folder
        self.meta = meta
        self.fsync_interval_s = fsync_interval_s
        # unbuffered: a record is one write, and a failed one (disk full) leaves nothing
        # behind in a buffer that a later flush or close would try to write again
        self._f = open(folder / "frames.bin", "ab", buffering=0)  # noqa: SIM115 - part's life
        self._offset = self._f.tell()
        # The index goes to a spool file as the records are written, not to a list: a
        # node's memory must not grow with the length of a recording (a list costs
        # ~130 bytes a record, 14 MB an hour of skeletons). A crash loses nothing:
        # recover() rebuilds the index from frames.bin.
        self._spool = open(folder / SPOOL, "w+b", buffering=0)  # noqa: SIM115 - part's life
        self._n_entries = 0
        self._kinds: list[str] = []  # kind names by their code in the spool
        self._last_sync = time.monotonic()
        self.n_frames = 0
        self.t_first: float | None = None
        self.t_last: float | None = None
        self.closed = False

    def append(self, t_local: float, kind: str, message: bytes) -> None:
        """Append one binary protocol message captured at ``t_local``.

        Raises:
            OSError: the record could not be written (disk full, quota, I/O error); the
                file is cut back to the previous record, so the part stays intact.
        """
        if self.closed:
            raise InputError(f"recording part {self.meta['rec_id']} is already closed")
        if kind not in self._kinds:
            self._kinds.append(kind)
        try:
            _write_all(self._f, _REC.pack(len(message), zlib.crc32(message)) + message)
            _write_all(self._spool, _IDX.pack(t_local, self._offset, self._kinds.index(kind)))
        except OSError:
            with contextlib.suppress(OSError):  # no torn record or entry left behind
                os.ftruncate(self._f.fileno(), self._offset)
                os.ftruncate(self._spool.fileno(), self._n_entries * _IDX.size)
            raise
        self._n_entries += 1
        self._offset += _REC.size + len(message)
        if kind == "skeleton":
            self.n_frames += 1
            self.t_first = t_local if self.t_first is None else self.t_first
            self.t_last = t_local
        now = time.monotonic()
        if now - self._last_sync >= self.fsync_interval_s:
            os.fsync(self._f.fileno())
            self._last_sync = now

    def _preload(self, index: list[tuple[float, int, str]]) -> None:
        """Take the records already in ``frames.bin`` into the index (a reopened part)."""
        rows = []
        for t, off, kind in index:
            if kind not in self._kinds:
                self._kinds.append(kind)
            rows.append(_IDX.pack(t, off, self._kinds.index(kind)))
            if kind == "skeleton":
                self.n_frames += 1
                self.t_first = t if self.t_first is None else self.t_first
                self.t_last = t
        _write_all(self._spool, b"".join(rows))
        self._n_entries = len(index)

    def _entries(self) -> np.ndarray:
        """The index so far (``t``, ``offset``, ``kind`` code), read back from the spool."""
        data = os.pread(self._spool.fileno(), self._n_entries * _IDX.size, 0)
        return np.frombuffer(data, dtype=_IDX_DTYPE)

    def truncate_after(self, t_local: float) -> None:
        """Drop the records from the first one captured after ``t_local`` on (a stop
        command that arrived late)."""
        entries = self._entries()
        late = np.flatnonzero(entries["t"] > t_local)
        if not len(late):
            return
        n = int(late[0])
        cut = int(entries["offset"][n])
        self._f.truncate(cut)
        self._f.seek(cut)
        self._offset = cut
        self._spool.truncate(n * _IDX.size)
        self._spool.seek(n * _IDX.size)
        self._n_entries = n
        kept = entries[:n]
        code = self._kinds.index("skeleton") if "skeleton" in self._kinds else -1
        sk = kept["t"][kept["kind"] == code]
        self.n_frames = len(sk)
        self.t_first = float(sk[0]) if len(sk) else None
        self.t_last = float(sk[-1]) if len(sk) else None

    def _write_index(self) -> None:
        """``index.json`` (``[[t_local, offset, kind], ...]``) from the spool, written a
        slice at a time."""
        entries = self._entries()
        tmp = self.folder / "index.json.tmp"
        try:
            with open(tmp, "w") as f:
                f.write("[")
                for k in range(0, len(entries), 8192):
                    part = entries[k : k + 8192]
                    f.write((", " if k else "") + ", ".join(
                        json.dumps([float(t), int(o), self._kinds[c]]) for t, o, c in
                        zip(part["t"], part["offset"], part["kind"], strict=True)))
                f.write("]")
                f.flush()
                os.fsync(f.fileno())
        except OSError:
            tmp.unlink(missing_ok=True)
            raise
        os.replace(tmp, self.folder / "index.json")

    def info(self, state: str | None = None, reason: str | None = None) -> PartInfo:
        """Current :class:`PartInfo` of the part."""
        return PartInfo(
            rec_id=self.meta["rec_id"], state=state or self.meta["state"],  # type: ignore[arg-type]
            n_frames=self.n_frames, t_first=self.t_first, t_last=self.t_last,
            bytes=self._offset, reason=reason if reason is not None else self.meta.get("reason"),
        )

    def close(self, state: str = "on_node", reason: str | None = None, **extra: Any) -> PartInfo:
        """Fsync, write the index and the final meta (``on_node`` or ``incomplete``).

        On a full disk the part still closes: ``index.json`` (optional, it can be rebuilt
        from ``frames.bin``) is left out and ``meta.json`` is rewritten in place.

        Raises:
            OSError: not even the meta could be written (the part is then recovered as
                ``incomplete`` when the node starts again).
        """
        if not self.closed:
            self.closed = True
            try:
                os.fsync(self._f.fileno())
                self._write_index()
            except OSError as exc:
                log.warning("index of %s not written (%s); frames.bin is complete without it",
                            self.meta["rec_id"], exc)
            finally:
                self._f.close()
                self._spool.close()
                (self.folder / SPOOL).unlink(missing_ok=True)
        self.meta.update(extra)
        self.meta.update(self.info(state, reason).model_dump())
        try:
            _atomic_write_json(self.folder / "meta.json", self.meta)
        except OSError:
            _rewrite_json_in_place(self.folder / "meta.json", self.meta)
        return self.info()


@dataclass(frozen=True)
class RetentionPolicy:
    """When a node deletes its copies of parts the server holds verified.

    Args:
        keep_verified_s: keep a verified part this long after its verification
            (0: delete it as soon as it is verified).
        min_free_bytes: below this much free space, delete verified parts, oldest
            recording first, until there is this much again.
        min_free_fraction: the same floor as a share of the disk's size; the larger of
            the two applies.
    """

    keep_verified_s: float = 7 * 86400.0
    min_free_bytes: int = 5 * 1024**3
    min_free_fraction: float = 0.10

    def floor(self, total_bytes: int) -> int:
        """Free bytes to keep on a disk of ``total_bytes``."""
        return max(int(self.min_free_bytes), int(self.min_free_fraction * total_bytes))


@dataclass(frozen=True)
class Purged:
    """One part deleted by :meth:`NodeStore.purge`."""

    rec_id: str
    bytes: int
    why: str


@dataclass(frozen=True)
class StorageUsage:
    """What a node's recordings folder holds (bytes of the part folders)."""

    held_bytes: int = 0
    held_parts: int = 0
    verified_bytes: int = 0
    verified_parts: int = 0
    purgeable_bytes: int = 0  # verified and not in use: deleted first when space is short
    unverified_bytes: int = 0  # closed parts the server has not verified: the only copy
    unverified_parts: int = 0
    unverified: tuple[str, ...] = ()  # ids of those, newest first


FreeSpaceFn = Callable[[], tuple[int, int]]  # () -> (free bytes, total bytes)


class NodeStore:
    """A node's recordings folder.

    Args:
        root: folder holding one sub-folder per recording part (created if missing).
        fsync_interval_s: longest time between fsyncs of an open part.
    """

    def __init__(self, root: Path | str, fsync_interval_s: float = 0.5) -> None:
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)
        self.fsync_interval_s = fsync_interval_s

    def create_part(self, rec_id: str, **params: Any) -> PartWriter:
        """Start a new part; ``params`` (times, streams, clock model) go into meta.json."""
        folder = self.root / _check_id(rec_id)
        if folder.exists():
            raise InputError(f"recording {rec_id} already exists on this node")
        folder.mkdir()
        meta = {"rec_id": rec_id, "state": "recording", "created": time.time(), **params}
        _atomic_write_json(folder / "meta.json", meta)
        return PartWriter(folder, meta, self.fsync_interval_s)

    def reopen_part(self, rec_id: str, **segment: Any) -> PartWriter:
        """Record again into a closed part of a recording that is still running (the node
        was restarted during it): new records go after the old ones.

        ``meta.json`` keeps the part's first start (its times and clock model apply to the
        whole part) and gets a ``segments`` list: one entry per start, with ``offset``
        (where its records begin in ``frames.bin``) and ``segment`` (the new start's
        parameters, e.g. ``t_start_local``, ``clock_start``, ``rebase_s``).

        Raises:
            InputError: the part is not here, still open, or the server verified it.
        """
        folder = self.root / _check_id(rec_id)
        meta = self._meta(folder)
        if meta is None:
            raise InputError(f"recording {rec_id} is not on this node")
        if meta.get("state") == "recording":
            raise InputError(f"recording {rec_id} is still open on this node")
        if _verified_at(folder) is not None:
            raise InputError(f"recording {rec_id} was transferred already; it is not reopened")
        if meta.get("t_stop_server") is not None:
            raise InputError(f"recording {rec_id} was stopped; it is not reopened")
        index, good_end = _scan(folder / "frames.bin")
        with open(folder / "frames.bin", "r+b") as f:
            f.truncate(good_end)
        segments = list(meta.get("segments") or [{
            "offset": 0, "t_start_local": meta.get("t_start_local"),
            "t_start_server": meta.get("t_start_server"), "rebase_s": 0.0}])
        segments.append({"offset": good_end, **segment})
        meta.update(state="recording", segments=segments, reason=None)
        _atomic_write_json(folder / "meta.json", meta)
        (folder / "index.json").unlink(missing_ok=True)  # rewritten from the spool on close
        writer = PartWriter(folder, meta, self.fsync_interval_s)
        writer._preload(index)
        return writer

    def recover(self) -> list[PartInfo]:
        """Close every part left open by a crash; returns the parts it repaired."""
        fixed = []
        for folder in sorted(p for p in self.root.iterdir() if p.is_dir()):
            meta = self._meta(folder)
            if meta is None or meta.get("state") != "recording":
                continue
            (folder / SPOOL).unlink(missing_ok=True)
            index, good_end = _scan(folder / "frames.bin")
            with open(folder / "frames.bin", "r+b") as f:
                f.truncate(good_end)
                os.fsync(f.fileno())
            # a full disk (often why the node stopped) must not keep the node from starting
            try:
                _atomic_write_json(folder / "index.json", index)
            except OSError as exc:
                log.warning("index of %s not written (%s)", folder.name, exc)
            sk = [t for t, _, k in index if k == "skeleton"]
            meta.update(
                state="incomplete",
                reason="node stopped while recording; data recovered up to the last intact frame",
                n_frames=len(sk), t_first=sk[0] if sk else None, t_last=sk[-1] if sk else None,
                bytes=good_end,
            )
            try:
                try:
                    _atomic_write_json(folder / "meta.json", meta)
                except OSError:
                    _rewrite_json_in_place(folder / "meta.json", meta)
            except OSError as exc:
                log.error("recording %s cannot be closed (%s); it is recovered when the "
                          "node starts with free disk space", folder.name, exc)
                continue
            with contextlib.suppress(ValidationError):  # closed; parts() says why unlisted
                fixed.append(self._info(meta))
        return fixed

    def _meta(self, folder: Path) -> dict[str, Any] | None:
        try:
            meta = json.loads((folder / "meta.json").read_text())
        except (OSError, json.JSONDecodeError):
            return None
        return meta if isinstance(meta, dict) else None

    @staticmethod
    def _info(meta: dict[str, Any]) -> PartInfo:
        return PartInfo.model_validate({k: meta[k] for k in PartInfo.model_fields if k in meta})

    def parts(self) -> list[PartInfo]:
        """Every part on this node (state from meta.json).

        A part whose meta.json does not describe a valid part (an id that is not a recording
        id, an unknown state: a hand-edited or foreign folder) is left out with a log line:
        listed, it would get the node's hello refused and the node would never connect.
        """
        out = []
        for folder in sorted(p for p in self.root.iterdir() if p.is_dir()):
            meta = self._meta(folder)
            if meta is None:
                continue
            try:
                out.append(self._info(meta))
            except ValidationError as exc:
                log.warning("recording folder %s is not listed to the server: its meta.json "
                            "is not a valid part (%s)", folder.name,
                            "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}"
                                      for e in exc.errors()))
        return out

    def meta(self, rec_id: str) -> dict[str, Any]:
        """Full meta.json of a part."""
        meta = self._meta(self.root / _check_id(rec_id))
        if meta is None:
            raise InputError(f"recording {rec_id} is not on this node")
        return meta

    def read(self, rec_id: str) -> Iterator[tuple[dict[str, Any], bytes]]:
        """Decoded ``(header, payload)`` of every intact record of a part, in order."""
        path = self.root / _check_id(rec_id) / "frames.bin"
        if not path.exists():
            raise InputError(f"recording {rec_id} is not on this node")
        with open(path, "rb") as f:
            while True:
                rec = _read_record(f)
                if rec is None:
                    return
                yield decode_binary(rec, limit=MAX_RECORD)

    def delete(self, rec_id: str) -> bool:
        """Remove a part for good (its recording was deleted on the server).

        Returns:
            False when the part was not (or no longer) on this node.

        Raises:
            OSError: the files could not all be removed (a deletion is never silent).
        """
        folder = self.root / _check_id(rec_id)
        if not folder.exists():
            return False
        shutil.rmtree(folder)
        return True

    def disk_free(self) -> int:
        """Free bytes on the store's file system."""
        return shutil.disk_usage(self.root).free

    def disk_space(self) -> tuple[int, int]:
        """``(free, total)`` bytes of the store's file system."""
        du = shutil.disk_usage(self.root)
        return du.free, du.total

    # ------------------------------------------------------------------ retention

    def mark_verified(self, rec_id: str, manifest_sha256: str, at: float | None = None) -> bool:
        """Note that the server holds a verified copy of a part (persisted, so a restart
        of the node does not forget it).

        Returns:
            False when the part is not on this node (already purged or deleted).

        Raises:
            InputError: the part is still being recorded (it cannot have been verified).
            OSError: ``verified.json`` could not be written.
        """
        folder = self.root / _check_id(rec_id)
        meta = self._meta(folder)
        if meta is None:
            return False
        if meta.get("state") == "recording":
            raise InputError(f"recording {rec_id} is still open on this node; the server "
                             "cannot hold a verified copy of it")
        _atomic_write_json(folder / VERIFIED, {
            "manifest_sha256": manifest_sha256,
            "verified_at": time.time() if at is None else float(at)})
        return True

    def verified_at(self, rec_id: str) -> float | None:
        """When the server confirmed its verified copy of a part; None if it has not."""
        return _verified_at(self.root / _check_id(rec_id))

    def _closed_parts(self) -> list[tuple[Path, dict[str, Any], int, float | None]]:
        """``(folder, meta, bytes, verified_at)`` of every part not being recorded."""
        out = []
        for folder in sorted(p for p in self.root.iterdir() if p.is_dir()):
            meta = self._meta(folder)
            if meta is None or meta.get("state") == "recording":
                continue
            out.append((folder, meta, _dir_bytes(folder), _verified_at(folder)))
        return out

    def usage(self, exclude: Collection[str] = ()) -> StorageUsage:
        """Bytes held, verified (and purgeable) and unverified; ``exclude``: ids of parts
        in use (recorded or served), never counted as purgeable."""
        held = held_n = ver = ver_n = purgeable = unver = 0
        unverified: list[str] = []
        for folder in sorted(p for p in self.root.iterdir() if p.is_dir()):
            size = _dir_bytes(folder)
            held, held_n = held + size, held_n + 1
            meta = self._meta(folder)
            if meta is None or meta.get("state") == "recording":
                continue
            if _verified_at(folder) is not None:
                ver, ver_n = ver + size, ver_n + 1
                purgeable += 0 if folder.name in exclude else size
            else:
                unver += size
                if meta.get("n_frames"):  # a part of no frame is never transferred
                    unverified.append(folder.name)
        return StorageUsage(held, held_n, ver, ver_n, purgeable, unver, len(unverified),
                            tuple(reversed(unverified)))

    def purge(self, policy: RetentionPolicy, *, now: float | None = None,
              free_space: FreeSpaceFn | None = None,
              exclude: Collection[str] = ()) -> list[Purged]:
        """Delete verified parts by ``policy``; never an unverified one (the only copy).

        First every part verified at least ``policy.keep_verified_s`` ago; then, while the
        free space is below ``policy.floor``, the remaining verified parts, oldest
        recording first. Each deletion is logged.

        Args:
            policy: the retention policy.
            now: the current time (default ``time.time()``).
            free_space: ``() -> (free, total)`` bytes (default: the store's disk).
            exclude: ids of parts in use (recorded or being sent), left alone.

        Returns:
            The parts deleted, in order.
        """
        now = time.time() if now is None else now
        space = free_space or self.disk_space
        verified = [(f, meta, size, at) for f, meta, size, at in self._closed_parts()
                    if at is not None and f.name not in exclude]
        # oldest recording first (its creation on the node; ids sort by start time too)
        verified.sort(key=lambda x: (float(x[1].get("created") or x[3] or 0.0), x[0].name))
        out: list[Purged] = []
        keep_days = policy.keep_verified_s / 86400.0
        rest = []
        for folder, _meta, size, at in verified:
            assert at is not None
            if now - at >= policy.keep_verified_s:
                why = (f"verified on the server {(now - at) / 86400.0:.1f} days ago "
                       f"(copies are kept {keep_days:g} days)" if policy.keep_verified_s > 0
                       else "verified on the server (copies are not kept)")
                if self._purge_one(folder, size, why, out):
                    continue
            rest.append((folder, size))
        free, total = space()
        floor = policy.floor(total)
        for folder, size in rest:
            if free >= floor:
                break
            why = (f"only {free / 1024**3:.2f} GB free (floor {floor / 1024**3:.2f} GB); "
                   "the oldest verified copies go first")
            if self._purge_one(folder, size, why, out):
                free, total = space()
        return out

    def _purge_one(self, folder: Path, size: int, why: str, out: list[Purged]) -> bool:
        if _verified_at(folder) is None:  # re-checked: an unverified part is never deleted
            return False
        try:
            shutil.rmtree(folder)
        except FileNotFoundError:
            return False  # deleted meanwhile (the server deleted the recording)
        except OSError as exc:
            log.error("could not purge recording %s (%s); it stays on this node",
                      folder.name, exc)
            return False
        log.info("purged recording %s from this node (%.1f MB): %s", folder.name,
                 size / 1e6, why)
        out.append(Purged(folder.name, size, why))
        return True


def _verified_at(folder: Path) -> float | None:
    try:
        obj = json.loads((folder / VERIFIED).read_text())
        return float(obj["verified_at"])
    except (OSError, ValueError, TypeError, KeyError):
        return None


def _dir_bytes(folder: Path) -> int:
    """Bytes of the files under ``folder`` (0 for what vanishes meanwhile: a part may be
    deleted by the server's request while a purge or a status counts it)."""
    total = 0
    for base, _dirs, files in os.walk(folder):  # os.walk skips unreadable folders
        for name in files:
            with contextlib.suppress(OSError):
                total += os.stat(os.path.join(base, name)).st_size
    return total


def _write_all(f: Any, data: bytes) -> None:
    """Write all of ``data`` to an unbuffered file (a raw write may be short)."""
    view = memoryview(data)
    while view:
        view = view[f.write(view) or 0:]


def _read_record(f: Any) -> bytes | None:
    head = f.read(_REC.size)
    if len(head) < _REC.size:
        return None
    n, crc = _REC.unpack(head)
    if n > MAX_RECORD:
        return None
    data: bytes = f.read(n)
    if len(data) < n or zlib.crc32(data) != crc:
        return None
    return data


def _scan(path: Path) -> tuple[list[tuple[float, int, str]], int]:
    """Index of the intact prefix of a frames file and the byte where it ends."""
    index: list[tuple[float, int, str]] = []
    pos = 0
    if not path.exists():
        path.touch()
        return index, 0
    with open(path, "rb") as f:
        while True:
            rec = _read_record(f)
            if rec is None:
                break
            try:
                header, _ = decode_binary(rec, limit=MAX_RECORD)
                index.append((float(header["t"]), pos, str(header["kind"])))
            except (ProtocolError, KeyError, TypeError, ValueError):
                break
            pos = f.tell()
    return index, pos
