"""Crash-safe node store: write, close, read, recover a torn tail, truncate a late stop."""

from __future__ import annotations

import contextlib
import json
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from app.nodes.protocol import decode_skeletons, encode_skeletons
from app.nodes.store import NodeStore, RetentionPolicy
from engine.errors import InputError
from tests.tmpfs import mounted_tmpfs


def _write(store: NodeStore, rec_id: str, n: int) -> None:
    w = store.create_part(rec_id, t_start_local=0.0)
    for k in range(n):
        pos = np.full((1, 25, 3), k, np.float32)
        w.append(k / 30.0, "skeleton", encode_skeletons(k, k / 30.0, pos, np.full((1, 25), 2)))
    return None


def test_round_trip_and_close(tmp_path: Path) -> None:
    store = NodeStore(tmp_path)
    w = store.create_part("R1", t_start_local=0.0)
    for k in range(30):
        pos = np.full((1, 25, 3), k, np.float32)
        w.append(k / 30.0, "skeleton", encode_skeletons(k, k / 30.0, pos, np.full((1, 25), 2)))
    info = w.close("on_node")
    assert info.n_frames == 30 and info.t_last == pytest.approx(29 / 30.0)
    frames = list(store.read("R1"))
    assert len(frames) == 30
    p, _ = decode_skeletons(*frames[17])
    assert float(p[0, 0, 0]) == 17.0
    assert store.parts()[0].state == "on_node"
    assert len(json.loads((tmp_path / "R1" / "index.json").read_text())) == 30


def test_recover_truncates_torn_tail(tmp_path: Path) -> None:
    store = NodeStore(tmp_path)
    _write(store, "R2", 50)  # never closed: the process "died"
    f = tmp_path / "R2" / "frames.bin"
    size = f.stat().st_size
    with open(f, "ab") as fh:  # half a record, as left by a kill mid-write
        fh.write(b"\x40\x00\x00\x00\x12\x34")
    fixed = NodeStore(tmp_path).recover()
    assert [p.rec_id for p in fixed] == ["R2"]
    assert fixed[0].state == "incomplete" and fixed[0].n_frames == 50
    assert "recovered" in (fixed[0].reason or "")
    assert f.stat().st_size == size
    assert len(list(store.read("R2"))) == 50
    assert NodeStore(tmp_path).recover() == []  # idempotent


def test_recover_stops_at_corrupt_record(tmp_path: Path) -> None:
    store = NodeStore(tmp_path)
    _write(store, "R3", 20)
    f = tmp_path / "R3" / "frames.bin"
    data = bytearray(f.read_bytes())
    data[len(data) // 2] ^= 0xFF  # flip a byte inside record ~10
    f.write_bytes(bytes(data))
    fixed = NodeStore(tmp_path).recover()
    assert 8 <= fixed[0].n_frames < 20


def test_truncate_after_late_stop(tmp_path: Path) -> None:
    store = NodeStore(tmp_path)
    w = store.create_part("R4")
    for k in range(60):
        w.append(k / 30.0, "skeleton",
                 encode_skeletons(k, k / 30.0, np.zeros((0, 25, 3)), np.zeros((0, 25))))
    w.truncate_after(1.0)
    w.append(1.01, "skeleton", encode_skeletons(99, 1.01, np.zeros((0, 25, 3)), np.zeros((0, 25))))
    info = w.close()
    assert info.n_frames == 32 and info.t_last == pytest.approx(1.01)
    assert [h["seq"] for h, _ in store.read("R4")][-2:] == [30, 99]


def test_ids_cannot_traverse(tmp_path: Path) -> None:
    store = NodeStore(tmp_path)
    for bad in ("../x", "a/b", "", ".."):
        with pytest.raises(InputError):
            store.create_part(bad)


def test_writer_memory_does_not_grow_with_the_recording(tmp_path: Path) -> None:
    store = NodeStore(tmp_path)
    w = store.create_part("R5")
    msg = encode_skeletons(0, 0.0, np.zeros((1, 25, 3)), np.zeros((1, 25)))
    w.append(0.0, "skeleton", msg)
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        for k in range(1, 30_000):  # 17 minutes at 30 fps
            w.append(k / 30.0, "image" if k % 10 == 0 else "skeleton", msg)
        grown = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert grown < 100_000, f"{grown} bytes held for 30 000 records"  # a list: ~4 MB
    w.truncate_after(999.0)  # a late stop: records 29 971 … 29 999 go
    info = w.close()
    assert info.n_frames == 1 + sum(1 for k in range(1, 29_971) if k % 10)
    assert info.t_last == pytest.approx(29_969 / 30.0)
    index = json.loads((tmp_path / "R5" / "index.json").read_text())
    assert len(index) == 29_971 and index[10] == [10 / 30.0, 10 * len(msg) + 80, "image"]
    assert not (tmp_path / "R5" / "index.spool").exists()
    assert info.bytes == 29_971 * (len(msg) + 8)


def test_recover_on_a_full_disk(tmp_path: Path) -> None:
    with mounted_tmpfs(tmp_path / "tiny", "128k") as mnt:
        _write(NodeStore(mnt), "R6", 200)  # never closed: the node died
        with open(mnt / "ballast", "wb") as f, contextlib.suppress(OSError):
            f.write(b"\0" * (1 << 20))  # and its disk is full
        fixed = NodeStore(mnt).recover()  # the node can start again
        assert [p.n_frames for p in fixed] == [200]
        assert NodeStore(mnt).parts()[0].state == "incomplete"
        assert len(list(NodeStore(mnt).read("R6"))) == 200


# ---------------------------------------------------------------------- retention

DAY = 86400.0


class _Disk:
    """A fake disk of ``total`` bytes whose free space is what the store's parts leave."""

    def __init__(self, store: NodeStore, total: int, other: int = 0) -> None:
        self.store, self.total, self.other = store, total, other

    def __call__(self) -> tuple[int, int]:
        return self.total - self.other - self.store.usage().held_bytes, self.total


def _closed(store: NodeStore, rec_id: str, n: int = 30, created: float = 0.0) -> int:
    w = store.create_part(rec_id, t_start_local=0.0)
    w.meta["created"] = created
    for k in range(n):
        pos = np.full((1, 25, 3), k, np.float32)
        w.append(k / 30.0, "skeleton", encode_skeletons(k, k / 30.0, pos, np.full((1, 25), 2)))
    w.close("on_node")
    return sum(p.stat().st_size for p in (store.root / rec_id).iterdir())


def test_verified_parts_are_purged_after_the_keep_days(tmp_path: Path) -> None:
    store = NodeStore(tmp_path)
    for k, rec in enumerate(["R1", "R2", "R3"]):
        _closed(store, rec, created=k)
    store.mark_verified("R1", "a" * 64, at=0 * DAY)
    store.mark_verified("R2", "b" * 64, at=5 * DAY)
    policy = RetentionPolicy(keep_verified_s=7 * DAY, min_free_bytes=0, min_free_fraction=0)
    plenty = _Disk(store, 10**9)
    assert store.purge(policy, now=6.9 * DAY, free_space=plenty) == []
    gone = store.purge(policy, now=7.0 * DAY, free_space=plenty)
    assert [p.rec_id for p in gone] == ["R1"] and "7.0 days ago" in gone[0].why
    assert [p.rec_id for p in store.parts()] == ["R2", "R3"]
    # R3 is not verified: never purged, however old
    gone = store.purge(policy, now=100 * DAY, free_space=plenty)
    assert [p.rec_id for p in gone] == ["R2"]
    assert [p.rec_id for p in store.parts()] == ["R3"]
    assert NodeStore(tmp_path).verified_at("R3") is None


def test_keep_zero_days_purges_as_soon_as_verified(tmp_path: Path) -> None:
    store = NodeStore(tmp_path)
    _closed(store, "R1")
    policy = RetentionPolicy(keep_verified_s=0, min_free_bytes=0, min_free_fraction=0)
    assert store.purge(policy, now=1.0, free_space=_Disk(store, 10**9)) == []
    # the mark survives a restart of the node (a new store on the same folder)
    assert store.mark_verified("R1", "a" * 64, at=1.0)
    gone = NodeStore(tmp_path).purge(policy, now=1.0, free_space=_Disk(store, 10**9))
    assert [p.rec_id for p in gone] == ["R1"] and "not kept" in gone[0].why
    assert not (tmp_path / "R1").exists()
    assert not store.mark_verified("R1", "a" * 64)  # gone: nothing to mark


def test_low_space_purges_oldest_verified_first_and_never_an_unverified_part(
        tmp_path: Path) -> None:
    store = NodeStore(tmp_path)
    sizes = {rec: _closed(store, rec, created=c) for rec, c in
             [("R3", 1.0), ("R1", 3.0), ("R2", 2.0), ("R4", 4.0), ("R5", 0.0)]}
    for rec in ("R1", "R2", "R3", "R4"):  # R5, the oldest, is not verified
        store.mark_verified(rec, "c" * 64, at=10.0)
    held = sum(sizes.values())
    # free space 1.5 parts short of the floor: the two oldest verified parts go
    size = sizes["R1"]
    disk = _Disk(store, total=held + 10 * size, other=10 * size - size // 2)
    policy = RetentionPolicy(keep_verified_s=7 * DAY, min_free_bytes=2 * size,
                             min_free_fraction=0)
    gone = store.purge(policy, now=11.0, free_space=disk)
    assert [p.rec_id for p in gone] == ["R3", "R2"]
    assert "floor" in gone[0].why
    assert disk()[0] >= policy.floor(disk.total)
    # a disk too full for any policy: every verified part goes, R5 stays (the only copy)
    disk.other = disk.total
    gone = store.purge(policy, now=11.0, free_space=disk, exclude={"R4"})
    assert [p.rec_id for p in gone] == ["R1"]  # R4 is in use (exclude)
    assert {p.rec_id for p in store.parts()} == {"R4", "R5"}
    use = store.usage()
    assert use.unverified == ("R5",) and use.unverified_bytes == sizes["R5"]
    r4 = sizes["R4"] + (tmp_path / "R4" / "verified.json").stat().st_size
    assert use.verified_parts == 1 and use.purgeable_bytes == r4
    assert store.usage(exclude={"R4"}).purgeable_bytes == 0


def test_floor_is_the_larger_of_bytes_and_share() -> None:
    p = RetentionPolicy(min_free_bytes=5 * 1024**3, min_free_fraction=0.10)
    assert p.floor(20 * 1024**3) == 5 * 1024**3
    assert p.floor(200 * 1024**3) == 20 * 1024**3


def test_an_open_part_cannot_be_marked_verified(tmp_path: Path) -> None:
    store = NodeStore(tmp_path)
    store.create_part("R1", t_start_local=0.0)
    with pytest.raises(InputError, match="still open"):
        store.mark_verified("R1", "a" * 64)
    policy = RetentionPolicy(keep_verified_s=0, min_free_bytes=10**18, min_free_fraction=1)
    assert store.purge(policy, free_space=lambda: (0, 1)) == []
    assert store.usage().held_parts == 1 and store.usage().unverified == ()


def test_a_recovered_part_is_reopened_and_continued(tmp_path: Path) -> None:
    store = NodeStore(tmp_path)
    _write(store, "R1", 20)  # the node died while recording
    with open(tmp_path / "R1" / "frames.bin", "ab") as fh:
        fh.write(b"\x40\x00\x00")  # torn tail
    NodeStore(tmp_path).recover()
    with pytest.raises(InputError, match="not on this node"):
        store.reopen_part("R9")
    w = NodeStore(tmp_path).reopen_part("R1", t_start_local=5.0, rebase_s=0.25)
    with pytest.raises(InputError, match="still open"):
        store.reopen_part("R1")
    assert w.n_frames == 20 and w.t_first == 0.0
    for k in range(10):
        t = 5.0 + k / 30.0
        pos = np.full((1, 25, 3), 100 + k, np.float32)
        w.append(t, "skeleton", encode_skeletons(k, t, pos, np.full((1, 25), 2)))
    w.truncate_after(5.0 + 7.5 / 30.0)  # a late stop still cuts only the new records
    info = w.close("incomplete", "gap")
    assert info.n_frames == 28 and info.t_last == pytest.approx(5.0 + 7 / 30.0)
    frames = [decode_skeletons(h, p)[0][0, 0, 0] for h, p in store.read("R1")]
    assert frames == [float(k) for k in range(20)] + [100.0 + k for k in range(8)]
    index = json.loads((tmp_path / "R1" / "index.json").read_text())
    assert len(index) == 28 and index[20][1] > index[19][1]
    meta = store.meta("R1")
    assert [s["offset"] for s in meta["segments"]] == [0, index[20][1]]
    assert meta["segments"][1]["rebase_s"] == 0.25 and meta["state"] == "incomplete"
    store.mark_verified("R1", "a" * 64)
    with pytest.raises(InputError, match="transferred already"):
        store.reopen_part("R1")
