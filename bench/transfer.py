"""Transfer throughput over loopback websockets vs a plain durable file copy.

Prints one JSON line. The node side serves chunks of a recording part over a websocket
(as a node agent does); the server side pulls them with :func:`app.transfer.pull` into a
:class:`app.transfer.TransferSink` (SHA-256 per chunk and per file, fsync). The peer is
``shutil.copyfile`` of the same bytes followed by ``fsync`` (the copy a person would make,
made durable like ours), measured in the same run. Goal: ratio ≥ 0.5.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import multiprocessing as mp
import os
import shutil
import struct
import sys
import tempfile
import time
from collections.abc import AsyncIterator
from pathlib import Path

import websockets

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.transfer import Manifest, TransferSink, build_manifest, pull, read_chunk  # noqa: E402


def _node_process(src: Path, manifest_json: str, port_queue: mp.Queue) -> None:
    """The node side in its own process, as in a lab (one agent per sensor)."""
    manifest = Manifest.from_json(manifest_json)

    async def handler(ws: websockets.ServerConnection) -> None:
        async for msg in ws:
            req = json.loads(msg)
            for idx in req["chunks"]:
                data = read_chunk(src, manifest, req["file"], int(idx))
                await ws.send(struct.pack("!I", int(idx)) + data)

    async def main() -> None:
        # A large write buffer keeps 1 MiB chunks flowing without a drain per frame.
        async with websockets.serve(handler, "127.0.0.1", 0, max_size=None,
                                    compression=None, write_limit=8 << 20) as server:
            port_queue.put(next(iter(server.sockets)).getsockname()[1])
            await asyncio.Future()

    asyncio.run(main())


async def _transfer(port: int, dest: Path, manifest: Manifest, streams: int) -> float:
    conns = [await websockets.connect(f"ws://127.0.0.1:{port}", max_size=None,
                                      compression=None)
             for _ in range(streams)]
    pool: asyncio.Queue[websockets.ClientConnection] = asyncio.Queue()
    for c in conns:
        pool.put_nowait(c)

    async def fetch_range(name: str, indices: list[int]) -> AsyncIterator[tuple[int, bytes]]:
        ws = await pool.get()
        try:
            await ws.send(json.dumps({"file": name, "chunks": indices}))
            for _ in indices:
                reply = await ws.recv()
                assert isinstance(reply, bytes)
                yield struct.unpack("!I", reply[:4])[0], reply[4:]
        finally:
            pool.put_nowait(ws)

    t0 = time.perf_counter()
    await pull(TransferSink(dest, manifest), fetch_range, concurrency=streams)
    dt = time.perf_counter() - t0
    for c in conns:
        await c.close()
    return dt


def _copy(src: Path, dest: Path, names: list[str]) -> float:
    t0 = time.perf_counter()
    for n in names:
        target = dest / n
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src / n, target)
        with open(target, "rb") as fh:
            os.fsync(fh.fileno())
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--mb", type=int, default=256, help="part size in MiB")
    ap.add_argument("--files", type=int, default=8)
    ap.add_argument("--streams", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--chunk-kib", type=int, default=1024)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="gaitrig-bench-") as tmp:
        tmpdir = Path(tmp)
        src = tmpdir / "node"
        src.mkdir()
        per_file = args.mb * (1 << 20) // args.files
        names = []
        for i in range(args.files):
            name = f"part/{i:03d}.bin"
            (src / name).parent.mkdir(parents=True, exist_ok=True)
            (src / name).write_bytes(os.urandom(per_file))
            names.append(name)
        t0 = time.perf_counter()
        manifest = build_manifest(src, "bench", "S1", names, chunk_size=args.chunk_kib * 1024)
        t_manifest = time.perf_counter() - t0
        total = manifest.total_bytes
        ports: mp.Queue = mp.Queue()
        node = mp.Process(target=_node_process, args=(src, manifest.to_json(), ports),
                          daemon=True)
        node.start()
        port = ports.get(timeout=30)
        ours, peer = [], []
        try:
            for r in range(args.repeats):
                peer.append(_copy(src, tmpdir / f"copy{r}", names))
                ours.append(asyncio.run(_transfer(port, tmpdir / f"dest{r}", manifest,
                                                  args.streams)))
        finally:
            node.terminate()
            node.join()
        t_ours, t_peer = min(ours), min(peer)
        mib = total / (1 << 20)
        print(json.dumps({
            "bench": "transfer",
            "bytes": total,
            "streams": args.streams,
            "transfer_mib_s": round(mib / t_ours, 1),
            "copy_mib_s": round(mib / t_peer, 1),
            "ratio_vs_copy": round(t_peer / t_ours, 3),
            "goal_ratio": 0.5,
            "manifest_mib_s": round(mib / t_manifest, 1),
        }))


if __name__ == "__main__":
    main()
