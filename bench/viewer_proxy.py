"""The 3D view's login proxy under load: the viser stream through ``/viewer`` vs direct.

Starts the server and six ``sim`` node processes (as ``gaitrig demo`` does; the nodes send
depth images, so the server builds and sends the merged point clouds of six sensors while
a 3D-view client is connected), logs in, then alternates two clients, one at a time:

* ``proxy``: a websocket client of ``/viewer`` on the API port (the session cookie,
  viser's subprotocol ``viser-v<version>``), as the console's embedded 3D view connects;
* ``direct``: the same client straight to viser's loopback port (the peer).

Both clients offer ``permessage-deflate`` as browsers do (``--no-deflate`` to not). Each
phase, after ``--warmup`` s (viser's scene replay), counts for ``--seconds``: bytes/s and
messages/s received, the message latency (viser stamps each message with its
``time.perf_counter()`` when sent — CLOCK_MONOTONIC, shared by the processes of this
machine — so latency = receipt − stamp, viser's send to the client's receipt) and the
server process's CPU (``/proc``, cores). Phases alternate ``--rounds`` times (order
swapped every round) so slow drifts of the machine's load hit both alike; figures are
medians over rounds, and the proxy's cost is given as ratios against the direct peer.
Prints one JSON line.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench._rig import cpu_s, sim_rig  # noqa: E402


def _stamp(msg: bytes, dctx: Any) -> float | None:
    """viser's send time (``timestampSec``) of one message, None if not readable."""
    import msgspec

    try:
        n_inner = int.from_bytes(msg[0:8], "little")
        n_comp = int.from_bytes(msg[8:16], "little")
        inner = dctx.decompress(msg[16:16 + n_comp], max_output_size=n_inner)
        t = msgspec.msgpack.decode(inner).get("timestampSec")
    except Exception:
        return None
    return float(t) if isinstance(t, int | float) else None


def _camera_message() -> bytes:
    """A viser ``ViewerCameraMessage`` as the browser client sends it: viser counts a
    client as connected (and the server then builds point clouds for it) from its first
    camera message on."""
    import msgspec

    return msgspec.msgpack.encode({
        "type": "ViewerCameraMessage", "wxyz": [1.0, 0.0, 0.0, 0.0], "position": [0.0, -3.0, 2.0],
        "fov": 1.0, "near": 0.01, "far": 100.0, "image_height": 720, "image_width": 1280,
        "look_at": [3.0, 0.0, 1.0], "up_direction": [0.0, 0.0, 1.0]})


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


async def _phase(url: str, headers: dict[str, str], deflate: bool, warmup: float,
                 seconds: float, server_pid: int) -> dict[str, Any]:
    """One client for warm-up + counting window; its figures."""
    import viser
    import websockets
    import zstandard

    dctx = zstandard.ZstdDecompressor()
    n_bytes = n_msgs = 0
    lat: list[float] = []
    async with websockets.connect(url, subprotocols=[f"viser-v{viser.__version__}"],  # type: ignore[list-item]
                                  additional_headers=headers, max_size=None,
                                  compression="deflate" if deflate else None) as ws:
        ext = ws.response.headers.get("Sec-WebSocket-Extensions") if ws.response else None
        camera = _camera_message()
        await ws.send(camera)
        t0 = last_camera = time.monotonic()
        t_start, t_end = t0 + warmup, t0 + warmup + seconds
        cpu0: list[float] = []
        c0 = 0.0
        while True:
            now = time.monotonic()
            if now - last_camera >= 1.0:  # the browser re-sends its camera as it moves
                last_camera = now
                await ws.send(camera)
            if not cpu0 and now >= t_start:
                cpu0, c0 = cpu_s([server_pid]), time.process_time()
            if now >= t_end:
                cpu1, c1 = cpu_s([server_pid]), time.process_time()
                break
            try:
                msg = await asyncio.wait_for(ws.recv(), max(0.01, min(t_end - now, 0.5)))
            except TimeoutError:
                continue
            t_recv = time.perf_counter()
            if not cpu0 or not isinstance(msg, bytes):
                continue
            n_bytes += len(msg)
            n_msgs += 1
            t_sent = _stamp(msg, dctx)
            if t_sent is not None:
                lat.append(1000.0 * (t_recv - t_sent))
    return {"MB_per_s": n_bytes / seconds / 1e6, "msgs_per_s": n_msgs / seconds,
            "latency_ms_median": float(np.median(lat)) if lat else None,
            "latency_ms_p95": float(np.percentile(lat, 95)) if lat else None,
            "server_cpu_cores": (cpu1[0] - cpu0[0]) / seconds,
            "client_cpu_cores": (c1 - c0) / seconds,
            "server_rss_mb": _rss_mb(server_pid), "extensions": ext}


def _median(rows: list[dict[str, Any]], key: str) -> float | None:
    vals = [r[key] for r in rows if r[key] is not None]
    return round(float(np.median(vals)), 3) if vals else None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--nodes", type=int, default=6)
    ap.add_argument("--seconds", type=float, default=8.0, help="counting window per phase (s)")
    ap.add_argument("--warmup", type=float, default=3.0, help="s before counting, per phase")
    ap.add_argument("--rounds", type=int, default=3, help="direct/proxy phase pairs")
    ap.add_argument("--no-deflate", action="store_true",
                    help="the clients do not offer permessage-deflate (browsers do)")
    args = ap.parse_args()
    load_before = os.getloadavg()
    rows: dict[str, list[dict[str, Any]]] = {"direct": [], "proxy": []}
    with sim_rig("gaitrig-bench-viewer-proxy-", args.nodes) as rig:
        targets = {"direct": (f"ws://127.0.0.1:{rig.vport}", {}),
                   "proxy": (f"ws://127.0.0.1:{rig.port}/viewer",
                             {"Cookie": f"gaitrig_session={rig.token}"})}
        for r in range(args.rounds):
            for mode in (("direct", "proxy") if r % 2 == 0 else ("proxy", "direct")):
                url, headers = targets[mode]
                rows[mode].append(asyncio.run(_phase(url, headers, not args.no_deflate,
                                                     args.warmup, args.seconds,
                                                     rig.procs[0].pid)))
        load_after = os.getloadavg()
    keys = ("MB_per_s", "msgs_per_s", "latency_ms_median", "latency_ms_p95",
            "server_cpu_cores", "client_cpu_cores", "server_rss_mb")
    fig = {m: {k: _median(rows[m], k) for k in keys} for m in rows}

    def ratio(k: str) -> float | None:
        a, b = fig["proxy"][k], fig["direct"][k]
        return round(a / b, 3) if a is not None and b else None

    print(json.dumps({
        "bench": "viewer_proxy", "nodes": args.nodes, "seconds": args.seconds,
        "rounds": args.rounds, "client_offers_deflate": not args.no_deflate,
        "extensions": {m: rows[m][0]["extensions"] for m in rows},
        "direct": fig["direct"], "proxy": fig["proxy"],
        "proxy_vs_direct": {"server_cpu": ratio("server_cpu_cores"),
                            "bytes_per_s": ratio("MB_per_s"), "msgs_per_s": ratio("msgs_per_s"),
                            "latency_median": ratio("latency_ms_median"),
                            "latency_p95": ratio("latency_ms_p95")},
        "goal_server_cpu_within_20pct": (ratio("server_cpu_cores") or 9.9) <= 1.2,
        "goal_throughput_not_lower": (ratio("MB_per_s") or 0.0) >= 0.95,
        "per_round": rows,
        "loadavg_before": [round(v, 2) for v in load_before],
        "loadavg_after": [round(v, 2) for v in load_after], "cpus": os.cpu_count(),
    }))


if __name__ == "__main__":
    main()
