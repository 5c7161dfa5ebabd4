"""How fast the server and node processes start and stop (what every demo, deployment and
integration/browser test pays per process).

Figures (medians of ``--repeat`` runs, seconds):

* ``python_s``: a bare interpreter (``python -c pass``), the floor every figure includes.
* ``import_app_main_s``: ``import app.main``; ``app_routers_s``: the same plus
  ``create_app()`` (every API router imported: the server's whole start-up import graph);
  ``app_routers_peer_s``: the same after importing what that graph loaded before its heavy
  imports moved into the functions using them (scipy.signal/stats/…, open3d, matplotlib,
  numba), ``app_routers_ratio`` = now / peer. ``import_node_agent_s``: ``import
  app.nodes.agent`` and the sim backend's module. ``heavy_server`` / ``heavy_node``: which
  heavy libraries those imports still load.
* ``server_start_fresh_s`` / ``server_start_clinic_s``: ``gaitrig serve`` until
  ``/healthz`` answers 200, on a new data folder (migrations, the admin's password hashed
  at the default cost) and on a clinic's (``bench/_clinic.py``, ``--subjects``; its
  recordings list loaded); ``*_login_s``: until the admin's login answers.
* ``server_stop_int_s``: SIGINT (Ctrl-C, the integration tests) to the exit of a server
  (3D view on) with a sim node connected; ``node_stop_s``: SIGTERM to the exit of that
  node (rendering images); ``*_peer_s``: the same processes started through
  ``main(argv)``, which leaves Python's exit collection on (every process before
  :func:`app.cli.main` froze it), ``*_ratio`` = now / peer. ``server_stop_term_s``:
  SIGTERM (``gaitrig demo``, systemd; uvicorn then ends the process by the signal, no
  finalisation either way). ``*_cpu_s``: CPU spent between the signal and the exit.

Before / after this bench's changes (same machine, back to back, load 4.4 / 5.6 on 2
cores): ``import_app_main_s`` 1.55 → 0.66, ``app_routers_s`` 3.18 → 1.61,
``server_start_clinic_s`` 3.96 → 2.23, ``server_start_fresh_s`` 2.90 → 2.83 (the new
database and the password hash dominate it), ``server_stop_int_s`` 0.78 → 0.21 (CPU 0.60 →
0.06), ``node_stop_s`` 0.15 → 0.03.

``loadavg``: the machine's load (every figure grows with it). Prints ONE JSON line.
Run: ``PYTHONPATH=. .venv/bin/python bench/process_start.py`` (a few minutes;
``--subjects 0`` skips the clinic).
"""

from __future__ import annotations

import argparse
import json
import os
import secrets
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bench._clinic import populate
from bench._procs import free_port, stop

ROOT = Path(__file__).resolve().parents[1]
PY = [sys.executable, "-m", "app.cli"]
#: The peer of the exit figures: the same command line through ``main(argv)``, which leaves
#: Python's exit collection on (as every process had it before ``app.cli`` froze it).
PY_COLLECT = [sys.executable, "-c",
              "import sys; from app.cli import main; sys.exit(main(sys.argv[1:]))"]
#: What the server's start path imported before its heavy imports moved into the functions
#: using them: the peer of the import figures loads them first.
OLD_HEAVY = ("import scipy.signal, scipy.stats, scipy.ndimage, scipy.optimize, "
             "scipy.interpolate, scipy.sparse, scipy.spatial, open3d, numba\n"
             "import matplotlib\nmatplotlib.use('Agg')\nimport matplotlib.pyplot\n")
#: One admin password for every server of the run: the clinic's folder is started repeatedly
#: and keeps the account its first start created.
PASSWORD = secrets.token_urlsafe(12)
HEAVY = ("scipy.signal", "scipy.stats", "scipy.ndimage", "scipy.optimize", "scipy.interpolate",
         "scipy.spatial", "open3d", "matplotlib", "weasyprint", "numba", "cv2", "viser")
SERVER_IMPORTS = """
import sys, tempfile
import app.main
from app.config import Settings
if ROUTERS:
    app.main.create_app(Settings(data_dir=tempfile.mkdtemp(), viewer_enabled=False))
"""
NODE_IMPORTS = "import app.nodes.agent, app.nodes.backends.sim\n"
REPORT = "print(','.join(m for m in HEAVY if m in sys.modules))\n"


def _py(code: str) -> tuple[float, str]:
    """(wall seconds, stdout) of a fresh interpreter running ``code``."""
    t = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, check=True, text=True,
                         capture_output=True, env={**os.environ, "PYTHONPATH": str(ROOT)}).stdout
    return time.perf_counter() - t, out.strip()


def _median(f: Callable[[], float], repeat: int) -> float:
    return round(statistics.median(f() for _ in range(repeat)), 3)


def bench_imports(repeat: int) -> dict[str, Any]:
    """Import times of the server's and the node's modules, each in a new interpreter."""
    pre = f"import sys\nHEAVY = {HEAVY!r}\n"
    server = pre + "ROUTERS = False\n" + SERVER_IMPORTS
    routers = pre + "ROUTERS = True\n" + SERVER_IMPORTS
    node = pre + NODE_IMPORTS
    now = _median(lambda: _py(routers)[0], repeat)
    peer = _median(lambda: _py(OLD_HEAVY + routers)[0], repeat)
    return {
        "python_s": _median(lambda: _py("pass")[0], repeat),
        "import_app_main_s": _median(lambda: _py(server)[0], repeat),
        "app_routers_s": now,
        "app_routers_peer_s": peer,
        "app_routers_ratio": round(now / peer, 3),
        "import_node_agent_s": _median(lambda: _py(node)[0], repeat),
        "heavy_server": _py(routers + REPORT)[1],
        "heavy_node": _py(node + REPORT)[1],
    }


def _cpu_s(pid: int) -> float:
    tick = os.sysconf("SC_CLK_TCK")
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / tick


def _get(url: str, token: str | None = None, data: dict[str, Any] | None = None) -> Any:
    headers = {"Content-Type": "application/json"}
    if token:
        headers["Authorization"] = f"Bearer {token}"
    body = json.dumps(data).encode() if data is not None else None
    with urllib.request.urlopen(urllib.request.Request(url, data=body, headers=headers),
                                timeout=30) as r:
        return json.loads(r.read())


def _until(f: Callable[[], Any], proc: subprocess.Popen[bytes], what: str,
           timeout_s: float = 120.0) -> Any:
    deadline = time.time() + timeout_s
    while True:
        try:
            return f()
        except (OSError, urllib.error.URLError):
            if proc.poll() is not None or time.time() > deadline:
                raise SystemExit(f"{what} did not happen (exit code {proc.poll()})") from None
            time.sleep(0.01)


class Server:
    """``gaitrig serve --no-viewer`` on ``data_dir`` (the admin's password set)."""

    def __init__(self, data_dir: Path, log: Path, viewer: bool = False,
                 py: list[str] = PY) -> None:
        self.port, self.password = free_port(), PASSWORD
        self.base = f"http://127.0.0.1:{self.port}"
        self.env = {**os.environ, "GAITRIG_ADMIN_PASSWORD": self.password,
                    "PYTHONUNBUFFERED": "1", "GAITRIG_STORAGE_CHECK_INTERVAL_S": "0",
                    "GAITRIG_NODE_MIN_FREE_GB": "0", "GAITRIG_NODE_MIN_FREE_PERCENT": "0"}
        viewer_args = ["--viewer-port", str(free_port())] if viewer else ["--no-viewer"]
        self.t0 = time.perf_counter()
        self.proc = subprocess.Popen(
            [*py, "serve", "--host", "127.0.0.1", "--port", str(self.port), *viewer_args,
             "--data-dir", str(data_dir), "--log-level", "warning"], cwd=ROOT, env=self.env,
            stdout=log.open("ab"), stderr=subprocess.STDOUT)

    def started(self) -> tuple[float, float]:
        """(seconds to the first ``/healthz`` 200, seconds to the admin's login)."""
        _until(lambda: _get(self.base + "/healthz"), self.proc, "the server's start")
        up = time.perf_counter() - self.t0
        self.token = _until(lambda: _get(self.base + "/api/auth/login", data={
            "username": "admin", "password": self.password})["token"], self.proc, "login")
        return up, time.perf_counter() - self.t0


def signal_exit(proc: subprocess.Popen[bytes], sig: int) -> tuple[float, float]:
    """(seconds, CPU seconds) from ``sig`` to the process's exit."""
    cpu0 = _cpu_s(proc.pid)
    t = time.perf_counter()
    proc.send_signal(sig)
    _, _, usage = os.wait4(proc.pid, 0)
    proc.returncode = 0  # reaped here; Popen must not wait for it again
    return time.perf_counter() - t, usage.ru_utime + usage.ru_stime - cpu0


def bench_start(tmp: Path, subjects: int, repeat: int) -> dict[str, Any]:
    """Server start on a fresh data folder (each run a new one) and on a clinic's."""
    out: dict[str, Any] = {}
    log = tmp / "server.log"
    up, login = [], []
    for k in range(repeat):
        s = Server(tmp / f"fresh{k}", log)
        try:
            a, b = s.started()
            up.append(a)
            login.append(b)
        finally:
            stop([s.proc])
    out["server_start_fresh_s"] = round(statistics.median(up), 3)
    out["server_start_fresh_login_s"] = round(statistics.median(login), 3)
    if subjects:
        t = time.perf_counter()
        clinic = populate(tmp / "clinic", subjects, 6, n_with_files=2000)
        out["clinic_recordings"] = len(clinic.recording_ids)
        out["clinic_build_s"] = round(time.perf_counter() - t, 1)
        up, login = [], []
        for _ in range(repeat):
            s = Server(tmp / "clinic", log)
            try:
                a, b = s.started()
                up.append(a)
                login.append(b)
            finally:
                stop([s.proc])
        out["server_start_clinic_s"] = round(statistics.median(up), 3)
        out["server_start_clinic_login_s"] = round(statistics.median(login), 3)
    return out


def bench_stop(tmp: Path, repeat: int) -> dict[str, Any]:
    """Signal to exit: a server (viewer on) with a sim node connected, and that node; each
    also with the exit collection on (the ``*_peer`` figures, see :data:`PY_COLLECT`)."""
    figures: dict[str, list[float]] = {}
    log = tmp / "stop.log"
    runs = (("", PY, signal.SIGINT), ("_peer", PY_COLLECT, signal.SIGINT),
            ("_term", PY, signal.SIGTERM))
    for k in range(repeat):
        for suffix, py, sig in runs:
            s = Server(tmp / f"stop{k}{suffix}", log, viewer=True, py=py)
            node = subprocess.Popen(
                [*py, "node", "--id", "S1", "--server", f"ws://127.0.0.1:{s.port}",
                 "--data-dir", str(tmp / f"node{k}{suffix}"), "--log-level", "warning"],
                cwd=ROOT, env=s.env, stdout=log.open("ab"), stderr=subprocess.STDOUT)
            try:
                s.started()

                def online(s: Server = s) -> None:
                    nodes = _get(s.base + "/api/nodes", s.token)
                    if not (nodes and nodes[0]["connected"]):
                        raise OSError("not yet")

                _until(online, node, "the node's connection")
                time.sleep(2.0)  # a few frames rendered, sent and drawn
                if suffix != "_term":  # the node first, as the demo's order is
                    dt, cpu = signal_exit(node, signal.SIGTERM)
                    figures.setdefault(f"node_stop{suffix}_s", []).append(dt)
                    figures.setdefault(f"node_stop{suffix}_cpu_s", []).append(cpu)
                dt, cpu = signal_exit(s.proc, sig)
                name = "server_stop_term" if suffix == "_term" else f"server_stop_int{suffix}"
                figures.setdefault(name + "_s", []).append(dt)
                figures.setdefault(name + "_cpu_s", []).append(cpu)
            finally:
                stop([node, s.proc])
    out = {k: round(statistics.median(v), 3) for k, v in figures.items()}
    out["node_stop_ratio"] = round(out["node_stop_s"] / out["node_stop_peer_s"], 3)
    out["server_stop_int_ratio"] = round(out["server_stop_int_s"] / out["server_stop_int_peer_s"],
                                         3)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--subjects", type=int, default=5000,
                    help="the clinic's subjects (0: no clinic start)")
    ap.add_argument("--repeat", type=int, default=3, help="runs per figure")
    args = ap.parse_args()
    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="gaitrig-process-start-") as d:
        tmp = Path(d)
        out.update(bench_imports(args.repeat))
        out.update(bench_start(tmp, args.subjects, args.repeat))
        out.update(bench_stop(tmp, args.repeat))
    out["loadavg"] = round(os.getloadavg()[0], 2)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
