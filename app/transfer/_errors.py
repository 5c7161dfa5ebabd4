"""Transfer errors; every message says which file/chunk and what to do."""

from __future__ import annotations


class TransferError(Exception):
    """Base class of transfer failures."""


class ManifestError(TransferError):
    """The manifest is malformed or names an unsafe path."""


class CorruptChunkError(TransferError):
    """A chunk's SHA-256 does not match the manifest (it will be fetched again)."""


class IncompleteTransferError(TransferError):
    """Chunks are missing or a whole-file hash does not match; the part stays incomplete."""


class StorageFullError(TransferError):
    """The server's disk is full; nothing was marked complete."""
