"""Process helpers shared by the benches that run real server and node processes."""

from __future__ import annotations

import signal
import socket
import subprocess
from collections.abc import Iterable


def free_port() -> int:
    """A TCP port on loopback that is free right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def stop(procs: Iterable[subprocess.Popen[bytes]], sig: int = signal.SIGTERM,
         timeout_s: float = 15.0) -> None:
    """Signal every process still running (newest first), wait, kill what hangs."""
    procs = list(procs)
    for p in reversed(procs):
        if p.poll() is None:
            p.send_signal(sig)
    for p in procs:
        try:
            p.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
