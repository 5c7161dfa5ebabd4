"""Real server and node processes over loopback websockets (always cleaned up)."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

TOKEN = "integration-token-42"
PASSWORD = "integration-pw"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def http(url: str, data: dict[str, Any] | None = None, token: str | None = None,
         method: str | None = None) -> Any:
    headers = {"Content-Type": "application/json"}
    if token:
        headers["Authorization"] = f"Bearer {token}"
    body = json.dumps(data).encode() if data is not None else None
    req = urllib.request.Request(url, data=body, headers=headers, method=method)
    with urllib.request.urlopen(req, timeout=5) as r:
        return json.loads(r.read())


def wait_for(cond: Any, timeout: float, what: str, step: float = 0.1) -> Any:
    deadline = time.time() + timeout
    last: Any = None
    while time.time() < deadline:
        try:
            last = cond()
        except (urllib.error.URLError, OSError, KeyError):
            last = None
        if last:
            return last
        time.sleep(step)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


class Rig:
    """A server process plus node processes, with helpers."""

    def __init__(self, tmp: Path, env_extra: dict[str, str] | None = None) -> None:
        self.tmp = tmp
        self.port = free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        # no free-space floor: a nearly full test machine must not make the nodes purge
        # the verified copies the tests compare (test_retention sets its own)
        self.env = {**os.environ, "GAITRIG_NODE_TOKEN": TOKEN, "GAITRIG_ADMIN_PASSWORD": PASSWORD,
                    "PYTHONUNBUFFERED": "1", "GAITRIG_NODE_MIN_FREE_GB": "0",
                    "GAITRIG_NODE_MIN_FREE_PERCENT": "0", **(env_extra or {})}
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        self.logs: dict[str, Path] = {}
        self.start_server()

    def start_server(self) -> None:
        self._spawn("server", ["serve", "--port", str(self.port), "--no-viewer", "--data-dir",
                               str(self.tmp / "server"), "--log-level", "info"])
        wait_for(lambda: http(self.base + "/healthz"), 90, "the server")
        self.token = http(self.base + "/api/auth/login",
                          {"username": "admin", "password": PASSWORD})["token"]

    def kill_server(self) -> None:
        p = self.procs["server"]
        p.kill()
        p.wait()

    def _spawn(self, name: str, args: list[str], env: dict[str, str] | None = None
               ) -> subprocess.Popen[bytes]:
        log = self.tmp / f"{name}.log"
        self.logs[name] = log
        with open(log, "ab") as f:
            p = subprocess.Popen([sys.executable, "-m", "app.cli", *args], env=env or self.env,
                                 stdout=f, stderr=subprocess.STDOUT)
        self.procs[name] = p
        return p

    def node_dir(self, node_id: str) -> Path:
        return self.tmp / "nodes" / node_id

    def start_node(self, node_id: str, *extra: str, token: str | None = None,
                   name: str | None = None, images: bool = False) -> subprocess.Popen[bytes]:
        args = ["node", "--id", node_id, "--server", f"ws://127.0.0.1:{self.port}",
                "--data-dir", str(self.node_dir(node_id)), "--report-true-clock", *extra]
        if not images:
            args.append("--no-images")
        if token is not None:
            args += ["--token", token]
        return self._spawn(name or node_id, args)

    def api(self, path: str, data: dict[str, Any] | None = None, method: str | None = None
            ) -> Any:
        return http(self.base + path, data, self.token, method)

    def nodes(self) -> dict[str, dict[str, Any]]:
        return {n["id"]: n for n in self.api("/api/nodes")}

    def wait_online(self, ids: list[str], timeout: float = 30.0) -> dict[str, dict[str, Any]]:
        def ok() -> dict[str, dict[str, Any]] | None:
            ns = self.nodes()
            good = all(i in ns and ns[i]["connected"] and ns[i]["clock_offset_ms"] is not None
                       for i in ids)
            return ns if good else None

        result: dict[str, dict[str, Any]] = wait_for(ok, timeout, f"nodes {ids} online")
        return result

    def log_text(self, name: str) -> str:
        return self.logs[name].read_text(errors="replace")

    def close(self) -> None:
        for name, p in self.procs.items():
            if p.poll() is None:
                p.send_signal(signal.SIGTERM if name != "server" else signal.SIGINT)
        for p in self.procs.values():
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


@pytest.fixture
def make_rig(tmp_path: Path) -> Iterator[Any]:
    rigs: list[Rig] = []

    def make(env_extra: dict[str, str] | None = None) -> Rig:
        r = Rig(tmp_path, env_extra)
        rigs.append(r)
        return r

    yield make
    for r in rigs:
        r.close()
