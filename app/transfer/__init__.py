"""Integrity-checked, resumable transfer of a node's recording part to the server.

The node describes the files of a part in a :class:`Manifest` (size, SHA-256 of every
chunk and of every whole file). The server pulls chunks in any order into a
:class:`TransferSink`, which verifies each chunk against the manifest, persists its
progress in a journal so a restarted server resumes where it stopped, and only after
every whole-file hash matches renames the files into place and reports the part
complete. A part is never accepted partially or silently corrupted. The chunk bytes
travel over a raw TCP data channel (:func:`pull_channel` / :func:`serve_channel`) or,
when it cannot be opened, over the node websocket (:func:`pull`).
"""

from app.transfer._channel import (
    connect_channel,
    end_channel,
    parse_hello,
    pull_channel,
    serve_channel,
    set_timeout,
)
from app.transfer._errors import (
    CorruptChunkError,
    IncompleteTransferError,
    ManifestError,
    StorageFullError,
    TransferError,
)
from app.transfer._manifest import (
    DEFAULT_CHUNK_SIZE,
    FileEntry,
    Manifest,
    build_manifest,
    chunk_list_sha256,
    chunk_message,
    read_chunk,
    safe_relative_path,
)
from app.transfer._pull import FetchChunk, FetchRange, per_chunk, pull
from app.transfer._sink import TransferSink

__all__ = [
    "DEFAULT_CHUNK_SIZE",
    "CorruptChunkError",
    "FetchChunk",
    "FetchRange",
    "FileEntry",
    "IncompleteTransferError",
    "Manifest",
    "ManifestError",
    "StorageFullError",
    "TransferError",
    "TransferSink",
    "build_manifest",
    "chunk_list_sha256",
    "chunk_message",
    "connect_channel",
    "end_channel",
    "parse_hello",
    "per_chunk",
    "pull",
    "pull_channel",
    "read_chunk",
    "safe_relative_path",
    "serve_channel",
    "set_timeout",
]
