"""Crash-safe node store: write, close, read, recover a torn tail, truncate a late stop."""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from app.nodes.protocol import decode_skeletons, encode_skeletons
from app.nodes.store import NodeStore
from engine.errors import InputError


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
    mnt = tmp_path / "tiny"
    mnt.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=128k", "tmpfs", str(mnt)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {r.stderr.strip()}")
    try:
        _write(NodeStore(mnt), "R6", 200)  # never closed: the node died
        with open(mnt / "ballast", "wb") as f, contextlib.suppress(OSError):
            f.write(b"\0" * (1 << 20))  # and its disk is full
        fixed = NodeStore(mnt).recover()  # the node can start again
        assert [p.n_frames for p in fixed] == [200]
        assert NodeStore(mnt).parts()[0].state == "incomplete"
        assert len(list(NodeStore(mnt).read("R6"))) == 200
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=False)
