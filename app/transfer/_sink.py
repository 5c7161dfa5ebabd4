"""Server side of a transfer: verified, resumable writes into a recording part folder.

Layout of a part folder while transferring::

    <dest>/.incoming/manifest.json     the manifest being fulfilled
    <dest>/.incoming/<name>.part       preallocated files, chunks written in place

Resuming needs no separate journal: the chunks already present are found by hashing
the ``.part`` files against the manifest, so a crash between a write and any
book-keeping can never make a torn chunk count as received. Every chunk is checked
against its SHA-256 before it is written; a file is accepted when every chunk is there
and the SHA-256 over the digests the server computed (the hash list,
:func:`app.transfer.chunk_list_sha256`) equals the manifest's — one hash pass over the
data on the server, no read-back. Only then is it truncated to its size, flushed, and
renamed into ``<dest>/``; ``<dest>/manifest.json`` (written last) is what "complete"
means on disk.
"""

from __future__ import annotations

import errno
import hashlib
import os
import shutil
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from app.transfer._errors import (
    CorruptChunkError,
    IncompleteTransferError,
    ManifestError,
    StorageFullError,
)
from app.transfer._manifest import FileEntry, Manifest, chunk_list_sha256, safe_relative_path

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
        # SHA-256 the server computed for every chunk it holds (the file check hashes them)
        self._chunk_digests: dict[str, list[bytes | None]] = {
            f.name: [None] * f.chunk_count() for f in manifest.files}
        self._sealed: set[str] = set()  # files checked and flushed to disk
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
                    digest = hashlib.sha256(fh.read(self._chunk_len(f, i))).digest()
                    if digest.hex() == expected:
                        self._done[f.name].add(i)
                        self._chunk_digests[f.name][i] = digest
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

    def chunk_len(self, name: str, index: int) -> int:
        """Bytes of chunk ``index`` of ``name`` according to the manifest.

        Raises:
            ManifestError: no such file or chunk.
        """
        entry = self.manifest.file(name)
        if not 0 <= index < entry.chunk_count():
            raise ManifestError(f"{name!r} has no chunk {index}")
        return self._chunk_len(entry, index)

    def write_chunk(self, name: str, index: int, data: bytes | bytearray | memoryview) -> bool:
        """Verify and store one chunk.

        Args:
            name, index: which chunk.
            data: its bytes (not copied; the caller must not change them meanwhile).

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
        digest = hashlib.sha256(data).digest()
        if digest.hex() != entry.chunk_sha256[index]:
            raise CorruptChunkError(f"chunk {index} of {name!r} failed its SHA-256 check")
        if index in self._done[name]:
            return False
        try:
            fd = self.open_part(name)
            try:
                self.write_at(fd, name, index * self.manifest.chunk_size, data)
            finally:
                os.close(fd)
        except OSError as exc:
            raise _storage_error(exc, f"writing {name!r}") from exc
        return self.commit_chunk(name, index, digest, len(data))

    def open_part(self, name: str) -> int:
        """A write descriptor of ``name``'s ``.part`` file (the caller closes it), for
        callers that write a chunk as it streams in and :meth:`commit_chunk` it after."""
        self.manifest.file(name)
        try:
            return os.open(self._part_path(name), os.O_WRONLY)
        except OSError as exc:
            raise _storage_error(exc, f"opening {name!r}") from exc

    @staticmethod
    def write_at(fd: int, name: str, offset: int, data: bytes | bytearray | memoryview
                 ) -> None:
        """``pwrite`` all of ``data`` at ``offset``.

        Raises:
            StorageFullError: the server disk is full.
            OSError: another write failure.
        """
        view = memoryview(data)
        try:
            while view:  # pwrite may write less than asked
                n = os.pwrite(fd, view, offset)
                view, offset = view[n:], offset + n
        except OSError as exc:
            raise _storage_error(exc, f"writing {name!r}") from exc

    def commit_chunk(self, name: str, index: int, digest: bytes, size: int) -> bool:
        """Count a chunk already written in place as received if ``digest`` (its SHA-256,
        computed by the caller over the bytes it wrote) matches the manifest. Bytes of a
        chunk that fails stay uncounted: they are overwritten when it is fetched again,
        and a resumed transfer re-hashes them, so they can never pass as received.

        Returns:
            True if the chunk was new (False: it was already stored).

        Raises:
            CorruptChunkError: wrong size or SHA-256.
        """
        entry = self.manifest.file(name)
        if not 0 <= index < entry.chunk_count():
            raise ManifestError(f"{name!r} has no chunk {index}")
        if size != self._chunk_len(entry, index):
            raise CorruptChunkError(f"chunk {index} of {name!r} has {size} bytes, "
                                    f"expected {self._chunk_len(entry, index)}")
        if digest.hex() != entry.chunk_sha256[index]:
            raise CorruptChunkError(f"chunk {index} of {name!r} failed its SHA-256 check")
        with self._lock:
            if index in self._done[name]:
                return False
            self._chunk_digests[name][index] = digest
            self._done[name].add(index)
            self._bytes_done += size
        return True

    def seal_file(self, name: str) -> bool:
        """Check and flush a file whose chunks have all arrived (before :meth:`finalize`,
        so the disk flush of one file overlaps the transfer of the next).

        Returns:
            True when the file is now checked and on disk (False: chunks still missing).

        Raises:
            IncompleteTransferError: its hash list differs from the manifest's.
            StorageFullError: the server disk is full.
        """
        entry = self.manifest.file(name)
        with self._lock:
            if name in self._sealed:
                return True
            if len(self._done[name]) != entry.chunk_count():
                return False
            digests = list(self._chunk_digests[name])
        if any(d is None for d in digests) or chunk_list_sha256(
                [d for d in digests if d is not None]) != entry.chunk_list_sha256:
            raise IncompleteTransferError(
                f"{name!r}: the chunks' hash list differs from the manifest; the node must "
                "describe the part again")
        part = self._part_path(name)
        try:
            os.truncate(part, entry.size)
            fd = os.open(part, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        except OSError as exc:
            raise _storage_error(exc, f"flushing {name!r}") from exc
        with self._lock:
            self._sealed.add(name)
        return True

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
                sealed = list(pool.map(self.seal_file, [f.name for f in self.manifest.files]))
            if not all(sealed):  # cannot happen once no chunk is missing; never rename then
                raise IncompleteTransferError(f"{self.dest}: a file could not be checked")
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
