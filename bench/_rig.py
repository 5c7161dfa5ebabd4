"""Start-up shared by the benches that measure a whole simulated rig on this machine: the
server and ``sim`` node processes (as ``gaitrig demo`` starts them, with
``--report-true-clock``), logged in, every node online; stopped after the block."""

from __future__ import annotations

import contextlib
import ctypes
import json
import os
import secrets
import signal
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bench._procs import free_port, stop

ROOT = Path(__file__).resolve().parents[1]


def request(url: str, data: dict[str, Any] | None = None, token: str | None = None) -> Any:
    """JSON of a GET (or a POST of ``data``) to the server, with the bearer ``token``."""
    headers = {"Content-Type": "application/json"}
    if token:
        headers["Authorization"] = f"Bearer {token}"
    body = json.dumps(data).encode() if data is not None else None
    with urllib.request.urlopen(urllib.request.Request(url, data=body, headers=headers),
                                timeout=10) as r:
        return json.loads(r.read())


def cpu_s(pids: list[int]) -> list[float]:
    """User + system CPU seconds used so far by each process (Linux ``/proc``)."""
    tick = os.sysconf("SC_CLK_TCK")
    out = []
    for pid in pids:
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
            out.append((int(fields[11]) + int(fields[12])) / tick)
        except (OSError, IndexError, ValueError):
            out.append(float("nan"))
    return out


@dataclass
class SimRig:
    """A running rig: ``procs[0]`` is the server, then the nodes ``S1``..``Sn``."""

    tmp: Path
    procs: list[subprocess.Popen[bytes]]
    port: int  # the API
    vport: int  # viser's own loopback port
    password: str  # the admin's
    token: str = ""  # the admin's session, once logged in

    @property
    def base(self) -> str:
        """The API's base URL."""
        return f"http://127.0.0.1:{self.port}"


def _die_with_parent() -> None:
    # Linux: the child gets SIGTERM when the bench dies, even by kill -9 (as in the demo).
    with contextlib.suppress(OSError):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


def _start(tmp: Path, n_nodes: int) -> SimRig:
    port, vport = free_port(), free_port()
    password, token = secrets.token_urlsafe(9), secrets.token_urlsafe(16)
    env = {**os.environ, "GAITRIG_ADMIN_PASSWORD": password, "GAITRIG_NODE_TOKEN": token,
           "PYTHONUNBUFFERED": "1"}
    py = [sys.executable, "-m", "app.cli"]
    log = (tmp / "rig.log").open("wb")
    # Each process in its own session, as ``gaitrig demo`` starts them (and as separate
    # computers would be): with the kernel's autogroup scheduling, a session shares the
    # CPU with other sessions as a whole, so one session for the rig and the browser
    # would let the browser's threads starve the nodes.
    opts: dict[str, Any] = {"cwd": ROOT, "env": env, "stdout": log, "stderr": subprocess.STDOUT,
                            "start_new_session": True, "preexec_fn": _die_with_parent}
    procs = [subprocess.Popen([*py, "serve", "--host", "127.0.0.1", "--port", str(port),
                               "--viewer-port", str(vport), "--data-dir", str(tmp / "server"),
                               "--log-level", "warning"], **opts)]
    for k in range(1, n_nodes + 1):
        procs.append(subprocess.Popen(
            [*py, "node", "--id", f"S{k}", "--backend", "sim", "--server",
             f"ws://127.0.0.1:{port}", "--data-dir", str(tmp / "nodes" / f"S{k}"),
             "--log-level", "warning", "--report-true-clock"], **opts))
    return SimRig(tmp, procs, port, vport, password)


def _log_in(rig: SimRig, timeout_s: float) -> str:
    deadline = time.time() + timeout_s
    while True:
        try:
            return str(request(rig.base + "/api/auth/login",
                               {"username": "admin", "password": rig.password})["token"])
        except OSError as exc:
            if time.time() > deadline or rig.procs[0].poll() is not None:
                raise SystemExit(f"the server did not start; see {rig.tmp / 'rig.log'}") from exc
            time.sleep(0.3)


def _wait_online(rig: SimRig, n: int, timeout_s: float) -> None:
    deadline = time.time() + timeout_s
    while True:
        try:
            nodes = request(rig.base + "/api/nodes", token=rig.token)
            if sum(1 for x in nodes if x["connected"]) >= n:
                return
        except OSError:
            pass
        if time.time() > deadline:
            raise TimeoutError(f"not all {n} nodes came online within {timeout_s:.0f} s")
        time.sleep(0.5)


@contextmanager
def sim_rig(prefix: str, n_nodes: int, timeout_s: float = 120.0) -> Iterator[SimRig]:
    """The server and ``n_nodes`` sim nodes in a new temporary folder (``prefix``), the
    admin logged in and every node online, for the block; all stopped after it."""
    rig = _start(Path(tempfile.mkdtemp(prefix=prefix)), n_nodes)
    try:
        rig.token = _log_in(rig, timeout_s)
        _wait_online(rig, n_nodes, timeout_s)
        yield rig
    finally:
        stop(rig.procs)
