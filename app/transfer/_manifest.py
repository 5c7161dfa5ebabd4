"""Manifest of a recording part: files, sizes, per-chunk and per-file SHA-256."""

from __future__ import annotations

import hashlib
import json
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any

from app.transfer._errors import ManifestError

DEFAULT_CHUNK_SIZE = 4 << 20  # 4 MiB: few messages and hash calls per second, cheap to retry
MAX_CHUNK_SIZE = 16 << 20
MAX_FILES = 10_000

#: Written into every manifest (``hashes``) so a person reading ``manifest.json`` knows
#: which digest is which; ``sha256`` is what ``sha256sum`` prints.
HASH_LEGEND = {
    "sha256": "SHA-256 of the whole file (computed by the node; check with sha256sum)",
    "chunk_sha256": "SHA-256 of each chunk_size-byte chunk, in order",
    "chunk_list_sha256": "SHA-256 of the concatenated 32-byte binary chunk digests (the "
                         "file check the server makes from the chunks it verified)",
}


def chunk_list_sha256(digests: list[bytes] | tuple[bytes, ...]) -> str:
    """Hash list of a file: SHA-256 over its chunks' binary SHA-256 digests, in order.

    Given that every chunk was checked against its own SHA-256, this one digest checks
    the whole file (every chunk present, in order, nothing extra) without another pass
    over the data, like the tree hashes of S3 multipart uploads.
    """
    h = hashlib.sha256()
    for d in digests:
        h.update(d)
    return h.hexdigest()


def safe_relative_path(name: str) -> PurePosixPath:
    """Validate a manifest file name: relative, no ``..``, no absolute or drive parts.

    Raises:
        ManifestError: the name could escape the destination folder.
    """
    p = PurePosixPath(name)
    if (not name or name.startswith(("/", "\\")) or "\\" in name or ":" in name
            or any(part in ("", ".", "..") for part in p.parts)):
        raise ManifestError(f"unsafe file name in manifest: {name!r}")
    return p


@dataclass(frozen=True)
class FileEntry:
    """One file of a part.

    Attributes:
        name: POSIX path relative to the part's folder.
        size: bytes.
        sha256: hex digest of the whole file (the node's; what ``sha256sum`` prints).
        chunk_sha256: hex digest of each chunk, in order.
        chunk_list_sha256: :func:`chunk_list_sha256` of the chunk digests (derived from
            ``chunk_sha256`` when not given; a manifest whose value disagrees is refused).
    """

    name: str
    size: int
    sha256: str
    chunk_sha256: tuple[str, ...]
    chunk_list_sha256: str = ""

    def __post_init__(self) -> None:
        if not self.chunk_list_sha256:
            try:
                derived = chunk_list_sha256([bytes.fromhex(h) for h in self.chunk_sha256])
            except ValueError:
                derived = ""  # invalid digests: validate() names the bad one
            object.__setattr__(self, "chunk_list_sha256", derived)

    def chunk_count(self) -> int:
        return len(self.chunk_sha256)


@dataclass(frozen=True)
class Manifest:
    """What a node holds for one recording part."""

    recording_id: str
    node_id: str
    chunk_size: int
    files: tuple[FileEntry, ...]
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def total_bytes(self) -> int:
        return sum(f.size for f in self.files)

    @property
    def total_chunks(self) -> int:
        return sum(f.chunk_count() for f in self.files)

    def file(self, name: str) -> FileEntry:
        for f in self.files:
            if f.name == name:
                return f
        raise ManifestError(f"file {name!r} is not in the manifest")

    def to_json(self) -> str:
        d = asdict(self)
        d["hashes"] = HASH_LEGEND
        return json.dumps(d, sort_keys=True, separators=(",", ":"))

    @classmethod
    def from_json(cls, text: str | bytes) -> Manifest:
        """Parse and validate a manifest (paths, sizes, chunk counts)."""
        try:
            d = json.loads(text)
            chunk_size = int(d["chunk_size"])
            files = tuple(
                FileEntry(str(f["name"]), int(f["size"]), str(f["sha256"]),
                          tuple(str(h) for h in f["chunk_sha256"]),
                          str(f.get("chunk_list_sha256") or ""))
                for f in d["files"]
            )
            m = cls(str(d["recording_id"]), str(d["node_id"]), chunk_size, files,
                    dict(d.get("meta") or {}))
        except (KeyError, TypeError, ValueError) as exc:
            raise ManifestError(f"malformed manifest: {exc}") from exc
        m.validate()
        return m

    def validate(self) -> None:
        if not 1 <= self.chunk_size <= MAX_CHUNK_SIZE:
            raise ManifestError(f"chunk size {self.chunk_size} out of range")
        if len(self.files) > MAX_FILES:
            raise ManifestError(f"too many files in manifest ({len(self.files)})")
        seen: set[str] = set()
        for f in self.files:
            safe_relative_path(f.name)
            if f.name in seen:
                raise ManifestError(f"duplicate file {f.name!r} in manifest")
            seen.add(f.name)
            if f.size < 0:
                raise ManifestError(f"negative size for {f.name!r}")
            expected = max(1, -(-f.size // self.chunk_size))
            if f.chunk_count() != expected:
                raise ManifestError(
                    f"{f.name!r}: {f.chunk_count()} chunk hashes for {f.size} bytes, "
                    f"expected {expected}"
                )
            for h in (f.sha256, *f.chunk_sha256):
                if len(h) != 64 or any(c not in "0123456789abcdef" for c in h):
                    raise ManifestError(f"{f.name!r}: invalid SHA-256 digest {h!r}")
            derived = chunk_list_sha256([bytes.fromhex(h) for h in f.chunk_sha256])
            if f.chunk_list_sha256 != derived:
                raise ManifestError(f"{f.name!r}: chunk_list_sha256 does not match its "
                                    "chunk digests; the node must describe the part again")


def build_manifest(root: str | Path, recording_id: str, node_id: str,
                   names: list[str] | None = None, chunk_size: int = DEFAULT_CHUNK_SIZE,
                   meta: dict[str, Any] | None = None) -> Manifest:
    """Hash the files of a part (node side). ``names`` default: every file under root."""
    root = Path(root)
    if names is None:
        names = sorted(p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file())
    entries = []
    # The whole-file hash runs in a second thread, one chunk behind the chunk hashes
    # (hashlib releases the GIL): the two SHA-256 passes take the time of one.
    with ThreadPoolExecutor(max_workers=1) as pool:
        for name in names:
            safe_relative_path(name)
            whole = hashlib.sha256()
            chunks: list[bytes] = []
            size = 0
            pending: Future[None] | None = None
            with open(root / name, "rb") as fh:
                while True:
                    block = fh.read(chunk_size)
                    if not block and chunks:
                        break
                    if pending is not None:
                        pending.result()
                    pending = pool.submit(whole.update, block)
                    chunks.append(hashlib.sha256(block).digest())
                    size += len(block)
                    if len(block) < chunk_size:
                        break
            if pending is not None:
                pending.result()
            entries.append(FileEntry(name, size, whole.hexdigest(),
                                     tuple(c.hex() for c in chunks), chunk_list_sha256(chunks)))
    m = Manifest(recording_id, node_id, chunk_size, tuple(entries), dict(meta or {}))
    m.validate()
    return m


def read_chunk(root: str | Path, manifest: Manifest, name: str, index: int) -> bytes:
    """Bytes of chunk ``index`` of file ``name`` (node side)."""
    entry = manifest.file(name)
    if not 0 <= index < entry.chunk_count():
        raise ManifestError(f"{name!r} has no chunk {index}")
    with open(Path(root) / safe_relative_path(name), "rb") as fh:
        fh.seek(index * manifest.chunk_size)
        return fh.read(manifest.chunk_size)


def chunk_message(root: str | Path, manifest: Manifest, name: str, index: int,
                  prefix: bytes = b"") -> bytearray:
    """``prefix`` (e.g. a message header) followed by chunk ``index`` of file ``name``, read
    straight into one buffer (node side: the chunk is not copied into the message).

    Raises:
        ManifestError: no such chunk, or the file is shorter than the manifest says.
    """
    entry = manifest.file(name)
    if not 0 <= index < entry.chunk_count():
        raise ManifestError(f"{name!r} has no chunk {index}")
    cs = manifest.chunk_size
    buf = bytearray(len(prefix) + max(0, min(cs, entry.size - index * cs)))
    buf[: len(prefix)] = prefix
    view = memoryview(buf)[len(prefix):]
    with open(Path(root) / safe_relative_path(name), "rb", buffering=0) as fh:
        fh.seek(index * cs)
        while view:
            n = fh.readinto(view)
            if not n:
                raise ManifestError(f"{name!r} is shorter than its manifest says "
                                    f"(chunk {index}); describe the part again")
            view = view[n:]
    return buf
