"""Server side of a transfer: verified, resumable writes into a recording part folder.

Layout of a part folder while transferring::

    <dest>/.incoming/manifest.json     the manifest being fulfilled
    <dest>/.incoming/<name>.part       preallocated files, chunks written in place

Resuming needs no separate journal: the chunks already present are found by hashing
the ``.part`` files against the manifest, so a crash between a write and any
book-keeping can never make a torn chunk count as received. Only after every whole-file
SHA-256 matches are the files renamed into ``<dest>/`` and ``<dest>/manifest.json``
written; that file's presence is what "complete" means on disk.
"""

from __future__ import annotations

import errno
import hashlib
import os
import shutil
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from app.transfer._errors import (
    CorruptChunkError,
    IncompleteTransferError,
    ManifestError,
    StorageFullError,
)
from app.transfer._manifest import FileEntry, Manifest, safe_relative_path

_FULL_ERRNOS = {errno.ENOSPC, errno.EDQUOT}


def _storage_error(exc: OSError, what: str) -> Exception:
    if exc.errno in _FULL_ERRNOS:
        return StorageFullError(
            f"server disk is full while {what}; free space on the server and retry the "
            "transfer (the data is still safe on the node)"
        )
    return exc


class TransferSink:
    """Receives the chunks of one manifest into ``dest``.

    Args:
        dest: the part's folder on the server (created if needed).
        manifest: what the node holds.

    Raises:
        ManifestError: ``dest`` already holds a different transfer or a complete part.
        StorageFullError: the files cannot be preallocated.
    """

    def __init__(self, dest: str | Path, manifest: Manifest) -> None:
        manifest.validate()
        self.dest = Path(dest)
        self.manifest = manifest
        self.incoming = self.dest / ".incoming"
        self._done: dict[str, set[int]] = {f.name: set() for f in manifest.files}
        self._bytes_done = 0
        self._lock = threading.Lock()  # chunks of several files are written from threads
        # Running whole-file hash while chunks arrive in order from chunk 0; None once
        # they don't (then finalize reads the file back).
        self._running: dict[str, tuple[int, Any] | None] = {}
        self._digests: dict[str, str] = {}  # files checked and flushed to disk
        if self.is_complete(self.dest):
            existing = Manifest.from_json((self.dest / "manifest.json").read_bytes())
            if existing.to_json() != manifest.to_json():
                raise ManifestError(f"{self.dest} already holds a different complete part")
            for f in manifest.files:
                self._done[f.name] = set(range(f.chunk_count()))
            return
        fresh: set[str] = set()
        try:
            self.incoming.mkdir(parents=True, exist_ok=True)
            mpath = self.incoming / "manifest.json"
            if mpath.exists():
                if Manifest.from_json(mpath.read_bytes()).to_json() != manifest.to_json():
                    raise ManifestError(
                        f"{self.dest} holds an unfinished transfer of a different manifest"
                    )
            else:
                tmp = mpath.with_suffix(".tmp")
                tmp.write_text(manifest.to_json(), encoding="utf-8")
                os.replace(tmp, mpath)
            for f in manifest.files:
                part = self._part_path(f.name)
                part.parent.mkdir(parents=True, exist_ok=True)
                try:
                    fd = os.open(part, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o600)
                    fresh.add(f.name)
                except FileExistsError:
                    fd = os.open(part, os.O_RDWR)
                try:
                    if f.size and os.fstat(fd).st_size < f.size:
                        # Reserve the space now: a full disk fails here, not mid-way.
                        os.posix_fallocate(fd, 0, f.size)
                finally:
                    os.close(fd)
        except OSError as exc:
            raise _storage_error(exc, f"preparing {self.dest}") from exc
        # A file created just now holds nothing yet: only the files of an interrupted
        # transfer are read back and hashed chunk by chunk.
        self._scan_existing(skip=fresh)
        for f in manifest.files:
            self._running[f.name] = (0, hashlib.sha256()) if not self._done[f.name] else None

    # ------------------------------------------------------------------ helpers
    @staticmethod
    def is_complete(dest: str | Path) -> bool:
        dest = Path(dest)
        return (dest / "manifest.json").is_file() and not (dest / ".incoming").exists()

    def _part_path(self, name: str) -> Path:
        return self.incoming / (str(safe_relative_path(name)) + ".part")

    def _chunk_len(self, f: FileEntry, index: int) -> int:
        cs = self.manifest.chunk_size
        return max(0, min(cs, f.size - index * cs))

    def _scan_existing(self, skip: set[str]) -> None:
        cs = self.manifest.chunk_size
        for f in self.manifest.files:
            if f.name in skip:
                continue
            with open(self._part_path(f.name), "rb") as fh:
                for i, expected in enumerate(f.chunk_sha256):
                    fh.seek(i * cs)
                    if hashlib.sha256(fh.read(cs)).hexdigest() == expected:
                        self._done[f.name].add(i)
                        self._bytes_done += self._chunk_len(f, i)

    # --------------------------------------------------------------------- API
    def missing_chunks(self) -> list[tuple[str, int]]:
        """(file, chunk index) pairs still to fetch, in file order."""
        return [(f.name, i) for f in self.manifest.files for i in range(f.chunk_count())
                if i not in self._done[f.name]]

    @property
    def bytes_done(self) -> int:
        """Bytes of the chunks verified and written so far."""
        return self._bytes_done

    @property
    def progress(self) -> float:
        total = self.manifest.total_bytes
        return 1.0 if total == 0 else self.bytes_done / total

    def write_chunk(self, name: str, index: int, data: bytes | bytearray | memoryview, *,
                    hash_file: bool = True) -> bool:
        """Verify and store one chunk.

        Args:
            name, index: which chunk.
            data: its bytes (not copied).
            hash_file: also feed the running whole-file hash (:meth:`hash_chunk`); a
                caller that overlaps the two in different threads passes False and calls
                :meth:`hash_chunk` itself, in chunk order, after this returned True.

        Returns:
            True if the chunk was new (False: it was already stored).

        Raises:
            CorruptChunkError: the bytes do not match the manifest's hash.
            StorageFullError: the server disk is full.
        """
        entry = self.manifest.file(name)
        if not 0 <= index < entry.chunk_count():
            raise ManifestError(f"{name!r} has no chunk {index}")
        if len(data) != self._chunk_len(entry, index) and entry.size:
            raise CorruptChunkError(f"chunk {index} of {name!r} has {len(data)} bytes, "
                                    f"expected {self._chunk_len(entry, index)}")
        if hashlib.sha256(data).hexdigest() != entry.chunk_sha256[index]:
            raise CorruptChunkError(f"chunk {index} of {name!r} failed its SHA-256 check")
        if index in self._done[name]:
            return False
        try:
            fd = os.open(self._part_path(name), os.O_WRONLY)
            try:
                view = memoryview(data)
                off = index * self.manifest.chunk_size
                while view:  # pwrite may write less than asked
                    n = os.pwrite(fd, view, off)
                    view, off = view[n:], off + n
            finally:
                os.close(fd)
        except OSError as exc:
            raise _storage_error(exc, f"writing {name!r}") from exc
        with self._lock:
            self._done[name].add(index)
            self._bytes_done += len(data)
        if hash_file:
            self.hash_chunk(name, index, data)
        return True

    def hash_chunk(self, name: str, index: int, data: bytes | bytearray | memoryview) -> None:
        """Feed a verified chunk to the file's running SHA-256 (call in chunk order; a
        chunk out of order drops the running hash and :meth:`finalize` reads the file
        back instead)."""
        running = self._running.get(name)
        if running is not None:
            nxt, hasher = running
            if index == nxt:
                hasher.update(data)
                self._running[name] = (nxt + 1, hasher)
            else:
                self._running[name] = None

    def seal_file(self, name: str) -> None:
        """Hash and flush a file whose chunks have all arrived (before finalize, so
        the disk flush of one file overlaps the transfer of the next)."""
        entry = self.manifest.file(name)
        if len(self._done[name]) == entry.chunk_count() and name not in self._digests:
            self._digests[name] = self._hash_part(entry)

    def _hash_part(self, f: FileEntry) -> str:
        if f.name in self._digests:
            return self._digests[f.name]
        part = self._part_path(f.name)
        os.truncate(part, f.size)
        running = self._running.get(f.name)
        with open(part, "rb") as fh:
            if running is not None and running[0] == f.chunk_count():
                digest = str(running[1].hexdigest())
            else:
                h = hashlib.sha256()
                while block := fh.read(1 << 20):
                    h.update(block)
                digest = h.hexdigest()
            os.fsync(fh.fileno())
        return digest

    def finalize(self) -> Path:
        """Check every whole file, move the part into place, mark it complete.

        Returns:
            The part folder.

        Raises:
            IncompleteTransferError: chunks missing or a whole-file hash mismatch.
        """
        if self.is_complete(self.dest):
            return self.dest
        missing = self.missing_chunks()
        if missing:
            raise IncompleteTransferError(
                f"{len(missing)} of {self.manifest.total_chunks} chunks missing "
                f"(first: {missing[0][0]!r} #{missing[0][1]})"
            )
        try:
            with ThreadPoolExecutor(max_workers=min(4, os.cpu_count() or 1)) as pool:
                digests = list(pool.map(self._hash_part, self.manifest.files))
            for f, digest in zip(self.manifest.files, digests, strict=True):
                if digest != f.sha256:
                    # Every chunk matched, so the manifest contradicts itself: the file
                    # changed on the node while it was being described.
                    raise IncompleteTransferError(
                        f"{f.name!r}: chunks verified but the whole-file SHA-256 differs; "
                        "the node must describe the part again"
                    )
            for f in self.manifest.files:
                target = self.dest / safe_relative_path(f.name)
                target.parent.mkdir(parents=True, exist_ok=True)
                os.replace(self._part_path(f.name), target)
            tmp = self.dest / "manifest.json.tmp"
            tmp.write_text(self.manifest.to_json(), encoding="utf-8")
            with open(tmp, "rb") as fh:
                os.fsync(fh.fileno())
            os.replace(tmp, self.dest / "manifest.json")
            shutil.rmtree(self.incoming)
        except OSError as exc:
            raise _storage_error(exc, f"finishing {self.dest}") from exc
        return self.dest
