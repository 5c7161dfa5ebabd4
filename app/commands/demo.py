"""``gaitrig demo``: the server plus six simulated sensor nodes on this machine.

Each node is its own process, exactly as in a lab (one per mini-PC); they talk to the
server over loopback websockets. Ctrl-C (or SIGTERM) stops the nodes, then the server;
children also die with this process (``PR_SET_PDEATHSIG``), so nothing is left behind.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import secrets
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

HELP = "start the server and six simulated sensor nodes (Ctrl-C stops everything)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--host", default="127.0.0.1", help="server interface")
    parser.add_argument("--port", type=int, default=8000, help="console/API port")
    parser.add_argument("--viewer-port", type=int, default=8081, help="3D view port")
    parser.add_argument("--data-dir", type=Path, default=Path("var/demo"),
                        help="demo data folder (server and nodes)")
    parser.add_argument("--nodes", type=int, default=6, choices=range(1, 7), metavar="1..6",
                        help="number of simulated sensors (default 6)")
    parser.add_argument("--seed", type=int, default=0, help="simulation seed")
    parser.add_argument("--no-images", action="store_true",
                        help="skeletons only (lighter; no depth/colour rendering)")
    parser.add_argument("--no-viewer", action="store_true", help="do not start the 3D view")


def _die_with_parent() -> None:
    # Linux: the child gets SIGTERM when the demo process dies, even by kill -9.
    try:
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except OSError:
        pass


def _port_free(host: str, port: int) -> bool:
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError:
            return False
    return True


def _request(url: str, data: dict[str, Any] | None = None, token: str | None = None,
             timeout: float = 2.0) -> Any:
    headers = {"Content-Type": "application/json"}
    if token:
        headers["Authorization"] = f"Bearer {token}"
    body = json.dumps(data).encode() if data is not None else None
    req = urllib.request.Request(url, data=body, headers=headers)
    with urllib.request.urlopen(req, timeout=timeout) as r:
        return json.loads(r.read())


def demo_password(data_dir: Path) -> str:
    """The demo's admin password: generated once, kept in ``<data_dir>/demo-login.txt``."""
    f = data_dir / "demo-login.txt"
    if f.exists():
        return f.read_text().strip()
    pw = secrets.token_urlsafe(9)
    data_dir.mkdir(parents=True, exist_ok=True)
    f.write_text(pw + "\n")
    f.chmod(0o600)
    return pw


def _demo_login(base: str, password: str) -> dict[str, Any] | None:
    """The demo's own login (to count the sensors online), or None when the admin's
    password is no longer the generated one."""
    for attempt in range(3):
        try:
            return dict(_request(base + "/api/auth/login",
                                 {"username": "admin", "password": password}, timeout=15.0))
        except urllib.error.HTTPError as exc:
            if exc.code in (401, 403):
                return None
            raise
        except (urllib.error.URLError, OSError):
            if attempt == 2:  # the server answered /healthz: a loaded start, not a refusal
                raise
            time.sleep(1.0)
    return None


def _stop(procs: list[subprocess.Popen[bytes]]) -> None:
    for p in reversed(procs):  # nodes first, the server last
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
    deadline = time.time() + 8.0
    for p in procs:
        try:
            p.wait(timeout=max(0.1, deadline - time.time()))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def run(args: argparse.Namespace) -> int:
    data = args.data_dir.resolve()
    for port in (args.port,) + (() if args.no_viewer else (args.viewer_port,)):
        if not _port_free(args.host, port):
            print(f"gaitrig demo: port {port} is in use; stop what uses it or pass --port / "
                  "--viewer-port", file=sys.stderr)
            return 2
    password = demo_password(data)
    token = secrets.token_urlsafe(16)
    env = {**os.environ, "GAITRIG_ADMIN_PASSWORD": password, "GAITRIG_NODE_TOKEN": token,
           "PYTHONUNBUFFERED": "1"}
    # -P: a file in the current folder named like a module (http.py) must not shadow it
    py = [sys.executable, "-P", "-m", "app.cli"]
    serve = [*py, "serve", "--host", args.host, "--port", str(args.port), "--viewer-port",
                  str(args.viewer_port), "--data-dir", str(data / "server"), "--log-level",
                  "warning"]
    if args.no_viewer:
        serve.append("--no-viewer")
    procs: list[subprocess.Popen[bytes]] = []
    stopping = False

    def on_signal(signum: int, _frame: Any) -> None:
        nonlocal stopping
        stopping = True

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    base = f"http://{args.host}:{args.port}"
    try:
        # Own sessions: a Ctrl-C in the terminal reaches only this process, which then
        # stops the children in order (no half-imported tracebacks from the children).
        procs.append(subprocess.Popen(serve, env=env, preexec_fn=_die_with_parent,
                                      start_new_session=True))
        # Nodes start together with the server (they retry until it listens): their
        # start-up overlaps the server's instead of following it.
        for k in range(1, args.nodes + 1):
            node = [*py, "node", "--id", f"S{k}", "--backend", "sim", "--server",
                         f"ws://{args.host}:{args.port}", "--data-dir",
                         str(data / "nodes" / f"S{k}"), "--seed", str(args.seed),
                         "--log-level", "warning"]
            if args.no_images:
                node.append("--no-images")
            procs.append(subprocess.Popen(node, env=env, preexec_fn=_die_with_parent,
                                          start_new_session=True))
        while True:  # wait for the API
            if stopping or procs[0].poll() is not None:
                raise SystemExit("gaitrig demo: the server did not start (see messages above)")
            try:
                # a slow answer still means the server is up: while six nodes connect,
                # a loaded machine answers later than 2 s, and a probe that gives up
                # then never announced the console (nodes were all online before it)
                _request(base + "/healthz", timeout=15.0)
                break
            except (urllib.error.URLError, OSError):
                time.sleep(0.2)
        auth = _demo_login(base, password)
        # the account outlives this file: once the password is changed in the console the
        # generated one no longer logs in (printing it, and crashing on it, told a lie)
        login = (f"admin / {password}" if auth is not None else
                 "admin / the password you set in the console (the generated one in "
                 f"{data / 'demo-login.txt'} was changed)")
        print(f"\ngaitrig demo: console at {base}/  (login: {login})", flush=True)
        print(f"gaitrig demo: {args.nodes} simulated sensors starting; Ctrl-C stops everything",
              flush=True)
        announced = -1
        while not stopping:
            if procs[0].poll() is not None:
                print("gaitrig demo: the server stopped", file=sys.stderr)
                return 1
            if auth is not None:  # (without a login of its own, the Rig page counts them)
                try:
                    nodes = _request(base + "/api/nodes", token=auth["token"])
                    online = sum(1 for n in nodes if n["connected"])
                    if online != announced:
                        print(f"gaitrig demo: {online} of {args.nodes} sensors online",
                              flush=True)
                        announced = online
                except (urllib.error.URLError, OSError, KeyError):
                    pass
            for i, p in enumerate(procs[1:], start=1):
                if p.poll() is not None and not stopping:
                    print(f"gaitrig demo: node S{i} exited ({p.returncode})", file=sys.stderr)
            time.sleep(0.5)
        return 0
    finally:
        print("gaitrig demo: stopping", flush=True)
        _stop(procs)
