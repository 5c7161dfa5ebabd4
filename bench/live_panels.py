"""Live depth panels end to end: six simulated nodes + the server on this machine.

Starts the server and six ``sim`` node processes (as ``gaitrig demo`` does, but with
``--report-true-clock`` so the nodes' true clock offsets are known), logs in, and opens
what the Live page opens: the panel websocket ``/api/live/ws`` with the session cookie
(acknowledging each panel once decoded, answering like the page), and — unless
``--no-viewer-client`` — a client of the 3D view, so the server also builds the merged
point clouds as it does while the page (which embeds the 3D view) is open.

After a warm-up (every node delivered a panel, then ``--warmup`` s), panels are counted
per node for ``--seconds``. Reported (one JSON line):

* ``fps`` per node and its minimum (goal: ≥ 10 per node with six nodes);
* ``latency_ms``: capture → decoded in this client, as the Live page computes it (the
  server's capture time, from the node clock through the server's clock-offset estimate,
  put on the client's clock by min-RTT time pings) — median and 95th percentile;
* ``true_latency_ms``: the same against the simulator's true capture instant (the node's
  clock inverted with its true offset and drift), and ``clock_error_ms``: how far the
  server's corrected capture time is from the truth (the sensors' clock offsets are up to
  ±0.5 s, so an uncorrected offset would show here);
* the machine load (``os.getloadavg``) before and after: other work on the machine slows
  everything down, so the figures are only meaningful with the load beside them.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import struct
import sys
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench._rig import cpu_s, request, sim_rig  # noqa: E402


def _true_host_time(t_local: float, diag: dict[str, float]) -> float:
    """Host (= server) time of a node-clock reading, from the simulator's true clock."""
    off, drift, t_ref = diag["true_offset_at_ref_s"], diag["true_drift"], diag["clock_t_ref"]
    return (t_local - off + drift * t_ref) / (1.0 + drift)


async def _viewer_client(vport: str | int, stop: asyncio.Event) -> None:
    """A 3D-view client that only drains what the server sends (the page's iframe)."""
    import viser
    import websockets

    async with websockets.connect(f"ws://127.0.0.1:{vport}",
                                  subprotocols=[f"viser-v{viser.__version__}"],  # type: ignore[list-item]
                                  max_size=None) as ws:
        while not stop.is_set():
            try:
                await asyncio.wait_for(ws.recv(), 0.5)
            except TimeoutError:
                continue


async def _panels(port: int, token: str, n_nodes: int, warmup: float, seconds: float,
                  pids: list[int]
                  ) -> tuple[dict[str, list[tuple[float, float | None, float | None]]], float,
                             float, list[float]]:
    """Receive panels like the page.

    Returns:
        Per node ``(t_drawn, t_capture, t_local)`` rows of the counting window, the clock
        offset client → server, its ping RTT, and the CPU share used by each of ``pids``
        during the window.
    """
    import websockets

    got: dict[str, list[tuple[float, float | None, float | None]]] = {}
    offset, best_rtt = 0.0, float("inf")
    t_start = None
    cpu0: list[float] = []
    cpu1: list[float] = []
    async with websockets.connect(f"ws://127.0.0.1:{port}/api/live/ws", max_size=None,
                                  additional_headers={"Cookie": f"gaitrig_session={token}"}
                                  ) as ws:
        last_ping = 0.0
        deadline = time.time() + 120.0
        while True:
            now = time.time()
            if now - last_ping > 0.5:
                last_ping = now
                await ws.send(json.dumps({"type": "time", "echo": now}))
            if t_start is None and len(got) >= n_nodes:
                t_start = now + warmup
            if t_start is not None and not cpu0 and now >= t_start:
                cpu0 = cpu_s(pids)
            if t_start is not None and now > t_start + seconds:
                cpu1 = cpu_s(pids)
                break
            if now > deadline:
                raise TimeoutError(f"panels of only {sorted(got)} arrived")
            try:
                msg = await asyncio.wait_for(ws.recv(), 1.0)
            except TimeoutError:
                continue
            t_recv = time.time()
            if isinstance(msg, str):
                m = json.loads(msg)
                if m.get("type") == "time" and isinstance(m.get("echo"), float):
                    rtt = t_recv - m["echo"]
                    if rtt < best_rtt:
                        best_rtt, offset = rtt, m["t"] + rtt / 2 - t_recv
                continue
            hlen = struct.unpack_from("<I", msg)[0]
            h = json.loads(msg[4:4 + hlen])
            img = cv2.imdecode(np.frombuffer(msg, np.uint8, offset=4 + hlen), cv2.IMREAD_COLOR)
            t_drawn = time.time()  # the page acknowledges once the panel is drawn
            await ws.send(json.dumps({"type": "ack", "node": h["node"]}))
            if img is None:
                raise ValueError(f"panel of {h['node']} is not a JPEG")
            if t_start is not None and t_start <= t_recv <= t_start + seconds:
                got[h["node"]].append((t_drawn, h.get("t_capture"), h.get("t_local")))
            else:
                got.setdefault(h["node"], [])
    share = [(b - a) / seconds for a, b in zip(cpu0, cpu1, strict=True)]
    return got, offset, best_rtt, share


CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update"]


def _browser(base: str, password: str, n_nodes: int, warmup: float, seconds: float,
             pids: list[int], vport: int, with_3d: bool
             ) -> tuple[dict[str, float], list[float], list[float]]:
    """The Live page in headless Chromium (with its embedded 3D view unless ``with_3d``
    is false: then the page's requests to the 3D view are refused, as in the browser
    tests of the panels).

    Returns:
        Panels drawn per second per node, the page's own latency figures (median per node,
        sampled every 0.5 s) and the CPU share of each of ``pids`` during the window.
    """
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
        try:
            page = b.new_context(viewport={"width": 1400, "height": 900}).new_page()
            page.goto(base + "/index.html")
            page.fill("#username", "admin")
            page.fill("#password", password)
            page.click("button[type=submit]")
            page.wait_for_url("**/rig.html", timeout=30000)
            if not with_3d:
                page.route(f"http://127.0.0.1:{vport}/**", lambda r: r.abort())
            page.goto(base + "/live.html")
            page.wait_for_function(f"Object.keys(window.liveStats.nodes).length >= {n_nodes}",
                                   timeout=120000)
            page.wait_for_timeout(1000 * warmup)
            count = "Object.fromEntries(Object.entries(window.liveStats.nodes)" \
                    ".map(([k, v]) => [k, v.frames]))"
            f0, cpu0, t0 = page.evaluate(count), cpu_s(pids), time.time()
            lat: list[float] = []
            while time.time() < t0 + seconds:
                page.wait_for_timeout(500)
                lat += [v for v in page.evaluate(
                    "Object.values(window.liveStats.nodes).map((n) => n.latency_ms)")
                    if v is not None]
            f1, cpu1, t1 = page.evaluate(count), cpu_s(pids), time.time()
        finally:
            b.close()
    fps = {k: round((f1[k] - f0.get(k, 0)) / (t1 - t0), 2) for k in sorted(f1)}
    return fps, lat, [(b_ - a) / (t1 - t0) for a, b_ in zip(cpu0, cpu1, strict=True)]


def _pct(a: list[float], q: float) -> float | None:
    return round(float(np.percentile(a, q)), 1) if a else None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--nodes", type=int, default=6)
    ap.add_argument("--seconds", type=float, default=10.0, help="counting window (s)")
    ap.add_argument("--warmup", type=float, default=4.0, help="s after the first panels")
    ap.add_argument("--no-viewer-client", action="store_true",
                    help="do not connect a 3D-view client (no point-cloud work)")
    ap.add_argument("--browser", action="store_true",
                    help="measure in the Live page in headless Chromium (/usr/bin/chromium) "
                         "instead of a Python websocket client; the page also renders the "
                         "3D view in software, on the same 2 cores")
    ap.add_argument("--no-3d", action="store_true",
                    help="with --browser: the page without its 3D view")
    args = ap.parse_args()
    load_before = os.getloadavg()
    with sim_rig("gaitrig-bench-live-", args.nodes) as rig:
        procs, base, port, vport, password, token = (rig.procs, rig.base, rig.port, rig.vport,
                                                     rig.password, rig.token)

        async def run() -> tuple[Any, float, float, list[float]]:
            stop = asyncio.Event()
            viewer = None
            if not args.no_viewer_client:
                viewer = asyncio.create_task(_viewer_client(vport, stop))
            try:
                return await _panels(port, token, args.nodes, args.warmup, args.seconds,
                                     [p.pid for p in procs])
            finally:
                stop.set()
                if viewer is not None:
                    await asyncio.gather(viewer, return_exceptions=True)

        page_fps: dict[str, float] = {}
        page_lat: list[float] = []
        got: dict[str, list[tuple[float, float | None, float | None]]] = {}
        offset, rtt = 0.0, None
        if args.browser:
            page_fps, page_lat, cpu = _browser(base, password, args.nodes, args.warmup,
                                               args.seconds, [p.pid for p in procs], vport,
                                               not args.no_3d)
        else:
            got, offset, rtt, cpu = asyncio.run(run())
        load_after = os.getloadavg()
        nodes = {n["id"]: n for n in request(base + "/api/nodes", token=token)}
        status = request(base + "/api/live/status", token=token)
    fps: dict[str, float] = {}
    lat: list[float] = []
    true_lat: list[float] = []
    clock_err: dict[str, float] = {}
    for node, rows in sorted(got.items()):
        fps[node] = round(len(rows) / args.seconds, 2)
        diag = nodes.get(node, {}).get("diag") or {}
        errs = []
        for t_drawn, t_cap, t_loc in rows:
            if t_cap is not None:
                lat.append(1000.0 * (t_drawn + offset - t_cap))
            if t_loc is not None and "true_drift" in diag:
                t_true = _true_host_time(t_loc, diag)
                true_lat.append(1000.0 * (t_drawn - t_true))
                if t_cap is not None:
                    errs.append(1000.0 * (t_cap - t_true))
        if errs:
            clock_err[node] = round(float(np.median(errs)), 2)
    if args.browser:
        fps, lat = page_fps, page_lat
    min_fps = min(fps.values()) if len(fps) == args.nodes else 0.0
    print(json.dumps({
        "bench": "live_panels", "nodes": args.nodes, "seconds": args.seconds,
        "client": "chromium live page" if args.browser else "python websocket",
        "viewer_client": (not args.no_3d) if args.browser else not args.no_viewer_client,
        "fps_requested": status.get("fps_requested"), "scale": status.get("scale"),
        "fps": fps, "fps_min": min_fps, "goal_10_fps_per_node": min_fps >= 10.0,
        "latency_ms": {"median": _pct(lat, 50), "p95": _pct(lat, 95)},
        "true_latency_ms": {"median": _pct(true_lat, 50), "p95": _pct(true_lat, 95)},
        "clock_error_ms": clock_err,
        "sensor_clock_offsets_ms": {k: round(v["clock_offset_ms"], 1)
                                    for k, v in sorted(nodes.items())
                                    if v.get("clock_offset_ms") is not None},
        "cpu_cores_server": round(cpu[0], 2),
        "cpu_cores_per_node": [round(c, 2) for c in cpu[1:]],
        "client_clock_rtt_ms": round(1000 * rtt, 2) if rtt is not None else None,
        "server_dropped_for_slow_client": status.get("dropped"),
        "loadavg_before": [round(v, 2) for v in load_before],
        "loadavg_after": [round(v, 2) for v in load_after], "cpus": os.cpu_count(),
    }))


if __name__ == "__main__":
    main()
