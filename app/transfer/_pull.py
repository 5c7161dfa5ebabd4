"""The pulling loop: fetch missing chunks concurrently, retry the bad ones."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from pathlib import Path

from app.transfer._errors import CorruptChunkError, IncompleteTransferError, StorageFullError
from app.transfer._sink import TransferSink

FetchChunk = Callable[[str, int], Awaitable[bytes]]
ProgressCallback = Callable[[int, int], None]

# What a broken link looks like to a fetcher; anything else is a programming error.
RETRYABLE = (CorruptChunkError, ConnectionError, TimeoutError, OSError)


async def pull(
    sink: TransferSink,
    fetch: FetchChunk,
    *,
    concurrency: int = 4,
    retries: int = 3,
    on_progress: ProgressCallback | None = None,
) -> Path:
    """Fetch every missing chunk into ``sink`` and finalise it.

    Args:
        sink: the receiving part folder (already resumed: only missing chunks fetched).
        fetch: coroutine returning the bytes of ``(file, chunk)`` from the node.
        concurrency: chunks in flight at once.
        retries: attempts per chunk after the first, for corrupt or lost chunks.
        on_progress: called with ``(bytes_done, bytes_total)`` after every chunk.

    Returns:
        The complete part folder.

    Raises:
        IncompleteTransferError: a chunk could not be fetched intact after ``retries``.
        StorageFullError: the server disk is full (not retried).
    """
    queue: asyncio.Queue[tuple[str, int]] = asyncio.Queue()
    for item in sink.missing_chunks():
        queue.put_nowait(item)
    failures: list[str] = []
    total = sink.manifest.total_bytes

    async def worker() -> None:
        while True:
            try:
                name, idx = queue.get_nowait()
            except asyncio.QueueEmpty:
                return
            last: Exception | None = None
            for _attempt in range(retries + 1):
                try:
                    data = await fetch(name, idx)
                    sink.write_chunk(name, idx, data)
                    last = None
                    break
                except StorageFullError:
                    raise
                except RETRYABLE as exc:
                    last = exc
            if last is not None:
                failures.append(f"{name} #{idx}: {last}")
            elif on_progress is not None:
                on_progress(sink.bytes_done, total)

    workers = [asyncio.create_task(worker()) for _ in range(max(1, concurrency))]
    try:
        await asyncio.gather(*workers)
    finally:
        for w in workers:
            w.cancel()
    if failures:
        raise IncompleteTransferError(
            f"{len(failures)} chunk(s) could not be fetched intact: " + "; ".join(failures[:3])
        )
    return sink.finalize()
