"""Transfer integrity: round trip, corruption, lost links, resume after kill -9, disk full."""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from app.transfer import (
    CorruptChunkError,
    IncompleteTransferError,
    Manifest,
    ManifestError,
    StorageFullError,
    TransferSink,
    build_manifest,
    chunk_message,
    per_chunk,
    pull,
    read_chunk,
)
from tests.app.transfer._parts import make_part, sha
from tests.tmpfs import mounted_tmpfs

CHUNK = 64 * 1024


@pytest.fixture()
def part(tmp_path: Path) -> tuple[Path, Manifest]:
    src = tmp_path / "node"
    make_part(src, {"skeleton.bin": 300_000, "depth/000.bin": CHUNK * 3, "empty.txt": 0})
    return src, build_manifest(src, "rec-1", "S1", chunk_size=CHUNK)


def _fetcher(src: Path, manifest: Manifest):
    async def fetch(name: str, idx: int) -> bytes:
        return read_chunk(src, manifest, name, idx)

    return per_chunk(fetch)


def test_round_trip_identical_checksums(tmp_path: Path, part):
    src, manifest = part
    dest = tmp_path / "server" / "rec-1" / "S1"
    seen: list[tuple[int, int]] = []
    asyncio.run(pull(TransferSink(dest, manifest), _fetcher(src, manifest),
                     on_progress=lambda d, t: seen.append((d, t))))
    for f in manifest.files:
        assert sha(dest / f.name) == sha(src / f.name) == f.sha256
    assert TransferSink.is_complete(dest)
    assert seen[-1][0] == seen[-1][1] == manifest.total_bytes
    # the manifest round-trips through JSON
    assert Manifest.from_json(manifest.to_json()) == manifest


def test_corrupted_chunk_is_detected_and_refetched(tmp_path: Path, part):
    src, manifest = part
    calls: dict[tuple[str, int], int] = {}

    async def flaky(name: str, idx: int) -> bytes:
        data = read_chunk(src, manifest, name, idx)
        calls[(name, idx)] = calls.get((name, idx), 0) + 1
        if (name, idx) == ("skeleton.bin", 2) and calls[(name, idx)] == 1:
            flipped = bytearray(data)
            flipped[100] ^= 0x01
            return bytes(flipped)
        return data

    sink = TransferSink(tmp_path / "dest", manifest)
    with pytest.raises(CorruptChunkError):
        sink.write_chunk("skeleton.bin", 2, b"x" * len(read_chunk(src, manifest,
                                                                  "skeleton.bin", 2)))
    asyncio.run(pull(sink, per_chunk(flaky)))
    assert calls[("skeleton.bin", 2)] == 2
    assert sha(tmp_path / "dest" / "skeleton.bin") == manifest.file("skeleton.bin").sha256


def test_socket_cut_mid_transfer_then_resume(tmp_path: Path, part):
    src, manifest = part
    dest = tmp_path / "dest"
    count = 0

    async def dying(name: str, idx: int) -> bytes:
        nonlocal count
        count += 1
        if count > 3:
            raise ConnectionError("node socket closed")
        return read_chunk(src, manifest, name, idx)

    with pytest.raises(IncompleteTransferError, match="could not be fetched"):
        asyncio.run(pull(TransferSink(dest, manifest), per_chunk(dying), retries=1,
                         concurrency=1))
    assert not TransferSink.is_complete(dest)
    resumed = TransferSink(dest, manifest)
    assert 0 < len(resumed.missing_chunks()) < manifest.total_chunks
    asyncio.run(pull(resumed, _fetcher(src, manifest)))
    for f in manifest.files:
        assert sha(dest / f.name) == f.sha256


def test_server_killed_mid_transfer_resumes(tmp_path: Path, part):
    src, manifest = part
    dest = tmp_path / "dest"
    (tmp_path / "manifest.json").write_text(manifest.to_json())
    script = textwrap.dedent(f"""
        import asyncio, sys, time
        from pathlib import Path
        from app.transfer import Manifest, TransferSink, per_chunk, pull, read_chunk
        m = Manifest.from_json(Path({str(tmp_path / 'manifest.json')!r}).read_text())
        src = Path({str(src)!r})
        async def slow(name, idx):
            print("chunk", flush=True)
            time.sleep(0.2)
            return read_chunk(src, m, name, idx)
        asyncio.run(pull(TransferSink(Path({str(dest)!r}), m), per_chunk(slow),
                         concurrency=1))
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE,
                            cwd=Path(__file__).resolve().parents[3])
    assert proc.stdout is not None
    for _ in range(4):
        assert proc.stdout.readline().strip() == b"chunk"
    time.sleep(0.1)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not TransferSink.is_complete(dest)
    sink = TransferSink(dest, manifest)
    done = manifest.total_chunks - len(sink.missing_chunks())
    assert 2 <= done < manifest.total_chunks
    asyncio.run(pull(sink, _fetcher(src, manifest)))
    for f in manifest.files:
        assert sha(dest / f.name) == f.sha256


def test_unsafe_manifest_rejected(part):
    _src, manifest = part
    bad = manifest.to_json().replace('"skeleton.bin"', '"../../etc/passwd"')
    with pytest.raises(ManifestError, match="unsafe"):
        Manifest.from_json(bad)
    with pytest.raises(ManifestError, match="malformed"):
        Manifest.from_json("{}")
    wrong = manifest.to_json().replace(f'"chunk_size":{CHUNK}', '"chunk_size":1000')
    with pytest.raises(ManifestError, match="chunk hashes"):
        Manifest.from_json(wrong)


def test_different_manifest_in_same_folder_refused(tmp_path: Path, part):
    src, manifest = part
    TransferSink(tmp_path / "dest", manifest)
    make_part(src, {"skeleton.bin": 1000}, seed=9)
    other = build_manifest(src, "rec-1", "S1", chunk_size=CHUNK)
    with pytest.raises(ManifestError, match="different"):
        TransferSink(tmp_path / "dest", other)


@pytest.fixture()
def small_tmpfs(tmp_path: Path):
    with mounted_tmpfs(tmp_path / "tmpfs", "256k") as mnt:
        yield mnt


def test_disk_full_gives_clear_error_and_loses_nothing(tmp_path: Path, small_tmpfs: Path):
    src = tmp_path / "node"
    make_part(src, {"small.bin": 50_000})
    small = build_manifest(src, "rec-0", "S1", chunk_size=CHUNK)
    asyncio.run(pull(TransferSink(small_tmpfs / "rec-0", small), _fetcher(src, small)))
    make_part(src, {"big.bin": 600_000}, seed=1)
    big = build_manifest(src, "rec-1", "S1", ["big.bin"], chunk_size=CHUNK)
    with pytest.raises(StorageFullError, match="disk is full"):
        asyncio.run(pull(TransferSink(small_tmpfs / "rec-1", big), _fetcher(src, big)))
    assert not TransferSink.is_complete(small_tmpfs / "rec-1")
    # the earlier part is untouched and still complete
    assert TransferSink.is_complete(small_tmpfs / "rec-0")
    assert sha(small_tmpfs / "rec-0" / "small.bin") == small.file("small.bin").sha256


def test_chunk_message_reads_the_chunk_behind_its_header(tmp_path: Path, part):
    src, manifest = part
    for name, idx in [("skeleton.bin", 0), ("skeleton.bin", 4), ("empty.txt", 0)]:
        msg = chunk_message(src, manifest, name, idx, b"HEAD")
        assert bytes(msg) == b"HEAD" + read_chunk(src, manifest, name, idx)
    with pytest.raises(ManifestError, match="no chunk"):
        chunk_message(src, manifest, "skeleton.bin", 99)
    (src / "skeleton.bin").write_bytes(b"short")  # changed behind the manifest's back
    with pytest.raises(ManifestError, match="shorter"):
        chunk_message(src, manifest, "skeleton.bin", 1)


def test_chunk_of_the_wrong_length_is_corrupt(tmp_path: Path, part):
    src, manifest = part
    sink = TransferSink(tmp_path / "dest", manifest)
    data = read_chunk(src, manifest, "skeleton.bin", 0)
    with pytest.raises(CorruptChunkError, match="bytes, expected"):
        sink.write_chunk("skeleton.bin", 0, data[:-1])
    assert sink.write_chunk("skeleton.bin", 0, data) is True
    assert sink.write_chunk("skeleton.bin", 0, data) is False  # already stored
    assert sink.bytes_done == len(data)


def test_disk_full_while_chunks_queue_up_does_not_hang(tmp_path: Path, part,
                                                       monkeypatch: pytest.MonkeyPatch):
    """The writer fails while the receiver waits for room in the full queue: the pull
    must end with the clear error, not wait forever."""
    src, manifest = part
    sink = TransferSink(tmp_path / "dest", manifest)

    def full(*_a: object, **_k: object) -> bool:
        time.sleep(0.05)  # the fast fetcher fills the queue meanwhile
        raise StorageFullError("server disk is full while writing; free space")

    monkeypatch.setattr(sink, "write_chunk", full)

    async def fast(name: str, indices: list[int]):
        for idx in indices * 20:  # far more items than the queue holds
            yield idx, read_chunk(src, manifest, name, idx)

    async def run() -> None:
        await asyncio.wait_for(pull(sink, fast, concurrency=1), timeout=20)

    with pytest.raises(StorageFullError, match="disk is full"):
        asyncio.run(run())
    assert not TransferSink.is_complete(tmp_path / "dest")
