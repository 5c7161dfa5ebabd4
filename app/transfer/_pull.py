"""The pulling loop: stream each file's missing chunks, verify, retry the bad ones."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path

from app.transfer._errors import CorruptChunkError, IncompleteTransferError, StorageFullError
from app.transfer._sink import TransferSink
from engine.wording import count

FetchChunk = Callable[[str, int], Awaitable[bytes]]
#: Streams ``(chunk index, bytes)`` of one file for the requested indices, in order.
FetchRange = Callable[[str, list[int]], AsyncIterator[tuple[int, bytes]]]
ProgressCallback = Callable[[int, int], None]

# What a broken link or a damaged chunk looks like to a fetcher.
RETRYABLE = (CorruptChunkError, ConnectionError, TimeoutError, OSError)


def per_chunk(fetch: FetchChunk) -> FetchRange:
    """Adapt a one-request-per-chunk fetcher to the streaming interface."""

    async def fetch_range(name: str, indices: list[int]) -> AsyncIterator[tuple[int, bytes]]:
        for idx in indices:
            yield idx, await fetch(name, idx)

    return fetch_range


async def pull(
    sink: TransferSink,
    fetch: FetchRange,
    *,
    concurrency: int = 4,
    retries: int = 3,
    on_progress: ProgressCallback | None = None,
) -> Path:
    """Fetch every missing chunk into ``sink`` and finalise it.

    This is the websocket path (and the fallback of the data channel,
    :func:`app.transfer.pull_channel`). Files are pulled concurrently (``concurrency`` at
    once); each chunk is verified by its SHA-256 as it is written, and each file by its
    hash list when its last chunk is in (:meth:`TransferSink.seal_file`).

    Args:
        sink: the receiving part folder (already resumed: only missing chunks fetched).
        fetch: streams the requested chunks of a file from the node (see
            :func:`per_chunk` to adapt a per-chunk request function).
        concurrency: files in flight at once.
        retries: extra attempts for chunks that arrived corrupt or were lost.
        on_progress: called with ``(bytes_done, bytes_total)`` after every chunk.

    Returns:
        The complete part folder.

    Raises:
        IncompleteTransferError: a chunk could not be fetched intact after ``retries``.
        StorageFullError: the server disk is full (not retried).
    """
    missing: dict[str, list[int]] = {}
    for name, idx in sink.missing_chunks():
        missing.setdefault(name, []).append(idx)
    queue: asyncio.Queue[str] = asyncio.Queue()
    for name in missing:
        queue.put_nowait(name)
    failures: list[str] = []
    total = sink.manifest.total_bytes

    async def fetch_file(name: str) -> None:
        todo = missing[name]
        last: Exception | None = None
        for _attempt in range(retries + 1):
            if not todo:
                return
            received: set[int] = set()
            # The next chunks arrive (event loop) while a thread verifies and writes the
            # previous one (hashlib and pwrite release the GIL).
            pending: asyncio.Queue[tuple[int, bytes] | None] = asyncio.Queue(maxsize=4)

            async def writer(pending: asyncio.Queue[tuple[int, bytes] | None] = pending,
                             received: set[int] = received) -> Exception | None:
                err: Exception | None = None
                while (item := await pending.get()) is not None:
                    idx, data = item
                    try:
                        await asyncio.to_thread(sink.write_chunk, name, idx, data)
                    except CorruptChunkError as exc:
                        err = exc
                    else:
                        received.add(idx)
                    if on_progress is not None:
                        on_progress(sink.bytes_done, total)
                return err

            writer_task = asyncio.create_task(writer())
            try:
                async for item in fetch(name, todo):
                    if writer_task.done():
                        break  # the writer failed (e.g. disk full): stop receiving
                    if pending.full():  # wait for room, unless the writer dies meanwhile
                        put = asyncio.ensure_future(pending.put(item))
                        await asyncio.wait({put, writer_task},
                                           return_when=asyncio.FIRST_COMPLETED)
                        if not put.done():
                            put.cancel()
                            break
                    else:
                        pending.put_nowait(item)
            except RETRYABLE as exc:
                last = exc
            finally:
                if not writer_task.done():
                    await pending.put(None)
            try:
                err = await writer_task
            except StorageFullError:
                raise
            except RETRYABLE as exc:
                err = exc
            last = err or last
            todo = [i for i in todo if i not in received]
            if not todo:
                await asyncio.to_thread(sink.seal_file, name)
        if todo:
            failures.append(f"{name}: {count(len(todo), 'chunk')}, last error: {last}")

    async def worker() -> None:
        while True:
            try:
                name = queue.get_nowait()
            except asyncio.QueueEmpty:
                return
            await fetch_file(name)

    workers = [asyncio.create_task(worker()) for _ in range(max(1, concurrency))]
    try:
        await asyncio.gather(*workers)
    finally:
        for w in workers:
            w.cancel()
    if failures:
        raise IncompleteTransferError(
            f"{count(len(failures), 'file')} could not be fetched intact: "
            + "; ".join(failures[:3])
        )
    return await asyncio.to_thread(sink.finalize)
