"""Transfer throughput of the product over loopback vs a plain durable copy of the same bytes.

Prints one JSON line. Runs the real thing: a ``gaitrig serve`` process and ``--nodes``
``gaitrig node`` processes (simulated sensors, streaming their skeletons meanwhile) over
loopback. Each node holds a closed recording part of ``--mb / --nodes`` MiB (random
bytes planted in its store as ``frames.bin``), the server knows the stopped recording,
and the server's DataSync pulls every part as soon as the nodes connect: manifest over
the websocket (hashed by the node on request), chunks over the TCP data channel, each
verified by SHA-256 and written in place, whole files verified by their hash list,
fsync, rename. ``path`` says whether any run fell back to the websocket (it should not).

Timed from the server's log, per node: ``transfer`` from "receiving" (manifest in hand)
to the part "on the server", ``with_manifest`` from the manifest request; the time is the
union of the nodes' intervals (their processes may connect seconds apart).
The peer is ``shutil.copyfile`` of the same files followed by ``fsync`` (the copy a person
would make, made durable like ours), measured in the same run, best of ``--repeats`` each.
Goal: ``ratio_vs_copy`` ≥ 0.5. ``loadavg`` is the 1-minute load before and after: the
machine may be shared, and a loaded machine slows the transfer (three processes) more
than the copy.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import urllib.request
from datetime import datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench._procs import free_port, stop  # noqa: E402

TOKEN = "bench-node-token"
REC = "Rbench"
_LOG_TIME = re.compile(r"^(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3}) ")


def _plant_part(node_dir: Path, node_id: str, size: int) -> Path:
    """A closed part in a node's store, as the node leaves it after a recording."""
    part = node_dir / "recordings" / REC
    part.mkdir(parents=True)
    with open(part / "frames.bin", "wb") as fh:
        left = size
        while left:
            block = os.urandom(min(left, 16 << 20))
            fh.write(block)
            left -= len(block)
    (part / "index.json").write_text("[]")
    (part / "meta.json").write_text(json.dumps({
        "rec_id": REC, "state": "on_node", "n_frames": 1, "t_first": None, "t_last": None,
        "bytes": size, "reason": None, "node_id": node_id}))
    return part


def _server_state(server_dir: Path, parts: dict[str, int]) -> None:
    """The server's record of the stopped recording (``recordings.json``)."""
    server_dir.mkdir(parents=True)
    t = time.time()
    rec = {"id": REC, "t_start": t - 60, "t_stop": t - 30, "created": t - 60, "streams": [],
           "image_every": 1,
           "parts": {n: {"node_id": n, "state": "on_node", "n_frames": 1, "bytes": b}
                     for n, b in parts.items()}}
    (server_dir / "recordings.json").write_text(json.dumps([rec]))


def _log_times(log: Path, pattern: str) -> dict[str, float]:
    """Node id → time of the server log line matching ``pattern`` (with ``{node}``)."""
    out: dict[str, float] = {}
    rx = re.compile(pattern.replace("{node}", r"(?P<node>[A-Za-z0-9_.-]+)"))
    for line in log.read_text(errors="replace").splitlines():
        m = _LOG_TIME.match(line)
        hit = rx.search(line)
        if m and hit:
            t = datetime.strptime(m.group(1), "%Y-%m-%d %H:%M:%S,%f").timestamp()
            out[hit.group("node")] = t
    return out


def _busy(start: dict[str, float], end: dict[str, float]) -> float:
    """Length of the union of the per-node intervals (time any part was in transfer;
    the nodes' processes may connect seconds apart on a loaded machine)."""
    spans = sorted((start[n], end[n]) for n in end)
    total, cur_a, cur_b = 0.0, spans[0][0], spans[0][1]
    for a, b in spans[1:]:
        if a > cur_b:
            total += cur_b - cur_a
            cur_a, cur_b = a, b
        else:
            cur_b = max(cur_b, b)
    return total + cur_b - cur_a


def _transfer_once(tmp: Path, nodes: list[str], node_dirs: dict[str, Path], sizes: dict[str, int],
                   r: int) -> tuple[float, float, bool]:
    """One transfer by fresh server and node processes; (data phase s, with manifest s,
    whether every part came over the data channel)."""
    port = free_port()
    server_dir = tmp / f"server{r}"
    _server_state(server_dir, sizes)
    env = {**os.environ, "GAITRIG_NODE_TOKEN": TOKEN, "GAITRIG_ADMIN_PASSWORD": "bench-pw",
           "PYTHONUNBUFFERED": "1"}
    logs = {n: tmp / f"{n}-{r}.log" for n in ["server", *nodes]}
    procs: list[subprocess.Popen[bytes]] = []

    def spawn(name: str, args: list[str]) -> None:
        with open(logs[name], "wb") as fh:
            procs.append(subprocess.Popen([sys.executable, "-m", "app.cli", *args], cwd=ROOT,
                                          env=env, stdout=fh, stderr=subprocess.STDOUT))

    try:
        spawn("server", ["serve", "--port", str(port), "--no-viewer", "--data-dir",
                         str(server_dir), "--log-level", "info"])
        deadline = time.time() + 120
        while True:
            try:
                urllib.request.urlopen(f"http://127.0.0.1:{port}/healthz", timeout=2).read()
                break
            except OSError:
                if time.time() > deadline:
                    raise RuntimeError("the server did not start; see "
                                       + str(logs["server"])) from None
                time.sleep(0.2)
        for n in nodes:
            spawn(n, ["node", "--id", n, "--server", f"ws://127.0.0.1:{port}", "--data-dir",
                      str(node_dirs[n]), "--no-images"])
        done = [server_dir / "recordings" / REC / n / "manifest.json" for n in nodes]
        deadline = time.time() + 600
        while not all(p.exists() for p in done):
            if time.time() > deadline:
                raise RuntimeError("the transfer did not finish; see " + str(logs["server"]))
            time.sleep(0.1)
    finally:
        stop(procs, signal.SIGINT)
    asked = _log_times(logs["server"], "asking {node} for the manifest")
    receiving = _log_times(logs["server"], "bytes from {node}$")
    landed = _log_times(logs["server"], "part of {node} on the server")
    if set(landed) != set(nodes) or set(receiving) != set(nodes):
        raise RuntimeError("transfer log lines missing; see " + str(logs["server"]))
    text = logs["server"].read_text(errors="replace")
    channel = not any(w in text for w in ("no data channel", "broke (", "refused: no valid"))
    shutil.rmtree(server_dir)
    return _busy(receiving, landed), _busy(asked, landed), channel


def _copy(sources: list[Path], dest: Path) -> float:
    t0 = time.perf_counter()
    for i, src in enumerate(sources):
        target = dest / f"{i}" / src.name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, target)
        with open(target, "rb") as fh:
            os.fsync(fh.fileno())
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--mb", type=int, default=256, help="MiB to transfer, over all nodes")
    ap.add_argument("--nodes", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    load0 = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="gaitrig-bench-") as tmp_:
        tmp = Path(tmp_)
        nodes = [f"S{i + 1}" for i in range(args.nodes)]
        size = args.mb * (1 << 20) // args.nodes
        node_dirs = {n: tmp / "nodes" / n for n in nodes}
        parts = {n: _plant_part(node_dirs[n], n, size) for n in nodes}
        files = [f for p in parts.values() for f in sorted(p.iterdir())]
        total = sum(f.stat().st_size for f in files)
        sizes = {n: sum(f.stat().st_size for f in p.iterdir()) for n, p in parts.items()}
        ours, with_manifest, peer, channel = [], [], [], []
        for r in range(args.repeats):
            peer.append(_copy(files, tmp / f"copy{r}"))
            shutil.rmtree(tmp / f"copy{r}")
            t, tm, ch = _transfer_once(tmp, nodes, node_dirs, sizes, r)
            ours.append(t)
            channel.append(ch)
            with_manifest.append(tm)
        mib = total / (1 << 20)
        print(json.dumps({
            "bench": "transfer",
            "path": "gaitrig serve + gaitrig node processes over loopback: "
                    + ("TCP data channel" if all(channel) else
                       f"websocket fallback in {channel.count(False)} of {len(channel)} runs"),
            "bytes": total,
            "nodes": args.nodes,
            "transfer_mib_s": round(mib / min(ours), 1),
            "with_manifest_mib_s": round(mib / min(with_manifest), 1),
            "copy_mib_s": round(mib / min(peer), 1),
            "ratio_vs_copy": round(min(peer) / min(ours), 3),
            "ratio_with_manifest": round(min(peer) / min(with_manifest), 3),
            "goal_ratio": 0.5,
            "loadavg": [round(load0, 2), round(os.getloadavg()[0], 2)],
        }))


if __name__ == "__main__":
    main()
