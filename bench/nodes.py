"""Six simulated sensor nodes against one server: rate, drops, CPU, clock accuracy.

Starts ``gaitrig serve`` and six ``gaitrig node --backend sim`` processes on loopback
(the default avenue rig, its clocks offset up to ±0.5 s and drifting up to ±100 ppm),
lets them settle, then measures for ``--seconds`` (default 60): skeleton frames received
per node per second (goal 30 Hz; ratio against the nominal rate), dropped frames, CPU of
each process (% of one core), and the error of the server's clock-offset estimate
against the simulated truth (ratio against the paper's 2 ms PTP bound). Prints one JSON
line.
"""

from __future__ import annotations

import argparse
import json
import os
import secrets
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.nodes.clock import NodeClock  # noqa: E402
from bench._procs import free_port, stop  # noqa: E402
from engine.sim.rig import default_avenue_rig  # noqa: E402

TICK = os.sysconf("SC_CLK_TCK")


def _http(url: str, data: dict[str, Any] | None = None, token: str | None = None) -> Any:
    headers = {"Content-Type": "application/json"}
    if token:
        headers["Authorization"] = f"Bearer {token}"
    req = urllib.request.Request(url, json.dumps(data).encode() if data else None, headers)
    with urllib.request.urlopen(req, timeout=5) as r:
        return json.loads(r.read())


def _cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICK


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--nodes", type=int, default=6)
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="gaitrig-bench-"))
    port = free_port()
    pw, tok = secrets.token_urlsafe(8), secrets.token_urlsafe(12)
    env = {**os.environ, "GAITRIG_ADMIN_PASSWORD": pw, "GAITRIG_NODE_TOKEN": tok}
    py = [sys.executable, "-m", "app.cli"]
    procs: dict[str, subprocess.Popen[bytes]] = {}
    base = f"http://127.0.0.1:{port}"
    try:
        procs["server"] = subprocess.Popen(
            [*py, "serve", "--port", str(port), "--no-viewer", "--data-dir", str(tmp / "server"),
             "--log-level", "warning"], env=env, cwd=ROOT, stdout=subprocess.DEVNULL)
        for _ in range(150):
            try:
                _http(base + "/healthz")
                break
            except OSError:
                time.sleep(0.2)
        token = _http(base + "/api/auth/login", {"username": "admin", "password": pw})["token"]
        ids = [f"S{k}" for k in range(1, args.nodes + 1)]
        for nid in ids:
            procs[nid] = subprocess.Popen(
                [*py, "node", "--id", nid, "--server", f"ws://127.0.0.1:{port}", "--data-dir",
                 str(tmp / nid), "--report-true-clock", "--log-level", "warning"],
                env=env, cwd=ROOT)
        deadline = time.time() + 60
        while time.time() < deadline:
            ns = {n["id"]: n for n in _http(base + "/api/nodes", token=token)}
            if all(i in ns and ns[i]["connected"] for i in ids):
                break
            time.sleep(0.5)
        time.sleep(10.0)  # clock estimators settle (the 10 s of the acceptance criterion)
        n0 = {n["id"]: n for n in _http(base + "/api/nodes", token=token)}
        c0 = {k: _cpu_s(p.pid) for k, p in procs.items()}
        t0 = time.time()
        errs: dict[str, list[float]] = {i: [] for i in ids}
        rig = default_avenue_rig(0)
        while time.time() < t0 + args.seconds:
            time.sleep(min(2.0, max(0.0, t0 + args.seconds - time.time())))
            for n in _http(base + "/api/nodes", token=token):
                if n["id"] in errs and n["clock_offset_ms"] is not None:
                    s = rig.sensor(n["id"])
                    clock = NodeClock(s.clock_offset_s, s.clock_drift_ppm * 1e-6,
                                      n["diag"]["clock_t_ref"])
                    errs[n["id"]].append(n["clock_offset_ms"] - clock.true_offset(
                        n["clock_at"]) * 1e3)
        dt = time.time() - t0
        c1 = {k: _cpu_s(p.pid) for k, p in procs.items()}
        n1 = {n["id"]: n for n in _http(base + "/api/nodes", token=token)}
    finally:
        stop(procs.values(), timeout_s=10)
    rate = {i: (n1[i]["frames"] - n0[i]["frames"]) / dt for i in ids}
    dropped = {i: n1[i]["dropped_frames"] - n0[i]["dropped_frames"] for i in ids}
    cpu = {k: 100.0 * (c1[k] - c0[k]) / dt for k in procs}
    err_max = {i: max(abs(e) for e in errs[i]) if errs[i] else None for i in ids}
    worst = max(e for e in err_max.values() if e is not None)
    print(json.dumps({
        "bench": "nodes", "seconds": round(dt, 1), "nodes": len(ids),
        "skeleton_rate_hz": {k: round(v, 2) for k, v in rate.items()},
        "rate_min_ratio_vs_30hz": round(min(rate.values()) / 30.0, 4),
        "dropped_frames": dropped, "dropped_total": sum(dropped.values()),
        "cpu_pct_per_node": {k: round(v, 1) for k, v in cpu.items() if k != "server"},
        "cpu_pct_server": round(cpu["server"], 1),
        "clock_err_max_ms": {k: round(v, 4) if v is not None else None
                             for k, v in err_max.items()},
        "clock_err_worst_ms": round(worst, 4),
        "clock_err_ratio_vs_paper_2ms": round(worst / 2.0, 4),
    }))


if __name__ == "__main__":
    main()
