"""``gaitrig demo`` (what ``make demo`` runs): six nodes online within 30 s, clean Ctrl-C."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.integration.conftest import free_port, http, wait_for

pytestmark = pytest.mark.slow


def _children(pid: int) -> set[int]:
    kids = set()
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            if ppid == pid:
                kids.add(int(d.name))
    return kids


def _interrupt(demo: subprocess.Popen[bytes]) -> None:
    """Ctrl-C as in a terminal; killed (and the test failed) if it does not stop in 20 s."""
    demo.send_signal(signal.SIGINT)
    try:
        demo.wait(timeout=20)
    except subprocess.TimeoutExpired:
        demo.kill()
        raise


def test_demo_six_nodes_online_and_clean_stop(tmp_path: Path) -> None:
    port, vport = free_port(), free_port()
    gaitrig = Path(sys.executable).parent / "gaitrig"
    cmd = [str(gaitrig), "demo", "--port", str(port), "--viewer-port", str(vport),
           "--data-dir", str(tmp_path)]
    log = tmp_path / "demo.log"
    with open(log, "wb") as f:
        demo = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT,
                                env={**os.environ, "PYTHONUNBUFFERED": "1"})
    kids: set[int] = set()
    try:
        t0 = time.time()
        password = wait_for(lambda: (tmp_path / "demo-login.txt").read_text().strip(), 15,
                            "the demo password")
        token = wait_for(lambda: http(f"http://127.0.0.1:{port}/api/auth/login",
                                      {"username": "admin", "password": password})["token"],
                         30, "the server")

        def six_online() -> bool:
            nodes = http(f"http://127.0.0.1:{port}/api/nodes", token=token)
            return sum(n["connected"] for n in nodes) == 6

        wait_for(six_online, max(1.0, 30 - (time.time() - t0)), "six nodes online")
        # The demo prints the console line once its own probe of the server answers. The
        # nodes start together with the server, so on a loaded machine all six can be
        # online before that probe got through: wait for the line, not read it once.
        def console_line() -> str | None:
            out = log.read_text()
            return out if f"console at http://127.0.0.1:{port}/" in out else None

        out = wait_for(console_line, max(5.0, 30 - (time.time() - t0)), "the console line")
        assert password in out
        system = http(f"http://127.0.0.1:{port}/api/system", token=token)
        assert system["viewer_url"] == "/viewer/"
        kids = _children(demo.pid)
        assert len(kids) == 7  # server + six nodes
    finally:
        _interrupt(demo)
    alive = [k for k in kids if Path(f"/proc/{k}").exists()
             and "Z" not in (Path(f"/proc/{k}") / "stat").read_text().rsplit(")", 1)[1][:3]]
    assert alive == [], f"processes left behind: {alive}"
    assert demo.returncode == 0


def test_demo_after_the_password_was_changed_in_the_console(tmp_path: Path) -> None:
    """The demo folder's account outlives its generated password: once a clinician has
    changed it in the console, the demo neither prints the dead password as the login nor
    stops on its own refused login; it says which password to use and keeps running."""
    from fastapi.testclient import TestClient

    from app.config import Settings
    from app.main import create_app

    # the server's account as the console left it: another password than the file's
    changed = "Changed-in-the-console-7Qw"
    settings = Settings(data_dir=tmp_path / "server", viewer_enabled=False,
                        admin_password=changed)
    with TestClient(create_app(settings)):
        pass
    (tmp_path / "demo-login.txt").write_text("generated-long-ago-Zr4pQ\n")
    port = free_port()
    gaitrig = Path(sys.executable).parent / "gaitrig"
    log = tmp_path / "demo.log"
    with open(log, "wb") as f:
        demo = subprocess.Popen([str(gaitrig), "demo", "--port", str(port), "--no-viewer",
                                 "--nodes", "1", "--no-images", "--data-dir", str(tmp_path)],
                                stdout=f, stderr=subprocess.STDOUT,
                                env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        out = wait_for(lambda: (lambda t: t if "console at" in t else None)(log.read_text()),
                       60, "the console line")
        assert "the password you set in the console" in out, out
        assert "generated-long-ago-Zr4pQ" not in out
        token = http(f"http://127.0.0.1:{port}/api/auth/login",
                     {"username": "admin", "password": changed})["token"]
        wait_for(lambda: any(n["connected"]  # (the list is empty until the node says hello)
                               for n in http(f"http://127.0.0.1:{port}/api/nodes", token=token)),
                 30, "the node online")
        assert demo.poll() is None, log.read_text()
        assert "Traceback" not in log.read_text()
    finally:
        _interrupt(demo)
    assert demo.returncode == 0, log.read_text()
