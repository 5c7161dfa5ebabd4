"""Server and node processes start and stop without work they do not need.

What the processes used to pay (``bench/process_start.py`` has the figures): the server's
import graph pulled scipy.signal/stats, open3d, matplotlib and numba through modules that
use them in a few functions; and at every exit Python's finalisation ran full cyclic
collections over all those libraries' objects (seconds of CPU after uvicorn's "Finished
server process", at each node stop and after each command). These tests fail when such a
cause comes back; they time nothing.
"""

from __future__ import annotations

import asyncio
import gc
import json
import socket
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from app.config import Settings
from app.main import create_app

ROOT = Path(__file__).resolve().parents[2]
#: Libraries the server's start and a node's connection never need (each costs 0.05–1 s to
#: import and more to finalise); the functions that use them import them.
HEAVY = ("scipy.signal", "scipy.stats", "scipy.ndimage", "scipy.optimize", "scipy.sparse",
         "scipy.interpolate", "scipy.spatial", "open3d", "matplotlib", "weasyprint", "numba",
         "jinja2", "httpx")


def _loaded(code: str, names: tuple[str, ...]) -> list[str]:
    """Which of ``names`` a new interpreter has imported after running ``code``."""
    probe = (f"{code}\nimport json, sys\n"
             f"print(json.dumps([m for m in {names!r} if m in sys.modules]))")
    out = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, check=True,
                         capture_output=True, text=True).stdout
    result: list[str] = json.loads(out.strip().splitlines()[-1])
    return result


def test_the_server_app_imports_no_heavy_library(tmp_path: Path) -> None:
    # create_app() imports every API router: the whole import graph of the server's start
    # (viser too is left out without the 3D view, as tests and headless servers run)
    code = ("from app.config import Settings\nfrom app.main import create_app\n"
            f"create_app(Settings(data_dir={str(tmp_path)!r}, viewer_enabled=False))")
    assert _loaded(code, (*HEAVY, "viser")) == []


def test_the_node_agent_imports_no_heavy_library() -> None:
    code = "import app.nodes.agent, app.nodes.backends.sim, app.commands.node"
    # (OpenCV too: only a node that sends images needs it, and loads it with its first)
    assert _loaded(code, (*HEAVY, "cv2", "fastapi", "sqlalchemy", "viser")) == []


def test_the_heavy_libraries_still_load_where_they_are_used() -> None:
    # the lazy imports are real: the functions that need a library get it
    code = ("import numpy as np\nfrom engine.gait import _peaks\n"
            "_peaks(np.arange(9.0), np.array([0, 1, 0, 2, 0, 1, 0, 3, 0.0]), 1.0, 0.5, 0.1, 1.0)")
    assert _loaded(code, ("scipy.signal",)) == ["scipy.signal"]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _new_threads_end(before: set[threading.Thread], timeout_s: float = 10.0
                     ) -> list[str]:
    """Names of the threads started since ``before`` that are still running after
    ``timeout_s`` (a bound on the wait, not a figure under test)."""
    for t in set(threading.enumerate()) - before:
        t.join(timeout_s)
    return [f"{t.name} (daemon={t.daemon})" for t in set(threading.enumerate()) - before]


def test_the_server_leaves_no_thread_behind(tmp_path: Path) -> None:
    # the 3D view, the data sync, the live services and the transfer server all stop with
    # the lifespan: a thread left running would hold the process's exit (non-daemon) or
    # keep working while the interpreter finalises
    settings = Settings(data_dir=tmp_path, viewer_enabled=True, viewer_host="127.0.0.1",
                        viewer_port=_free_port(), transfer_port=_free_port(),
                        admin_password="a long enough password")
    app = create_app(settings)
    before = set(threading.enumerate())
    started: list[str] = []

    async def serve_and_stop() -> None:
        ctx = app.router.lifespan_context(app)
        await ctx.__aenter__()
        await asyncio.sleep(0.5)  # its background work under way
        started.extend(t.name for t in set(threading.enumerate()) - before)
        await ctx.__aexit__(None, None, None)

    asyncio.run(serve_and_stop())
    assert started, "the lifespan started no thread: this test checks nothing"
    assert _new_threads_end(before) == []


def test_a_node_leaves_no_thread_behind(tmp_path: Path) -> None:
    from app.nodes.agent import NodeAgent
    from app.nodes.backends.sim import SimBackend

    # no server listens on port 1: the agent captures into its ring buffer and retries
    agent = NodeAgent("S1", SimBackend("S1", images=False), "ws://127.0.0.1:1/ws/node",
                      "token", tmp_path)
    before = set(threading.enumerate())
    started: list[str] = []

    async def run_and_stop() -> None:
        task = asyncio.create_task(agent.run())
        for _ in range(1200):  # until frames flow (the capture thread is up; the sim's
            await asyncio.sleep(0.05)  # start takes seconds on a loaded machine)
            if any(t.name == "capture" for t in set(threading.enumerate()) - before):
                await asyncio.sleep(0.5)  # a few frames through the buffer
                break
        started.extend(t.name for t in set(threading.enumerate()) - before)
        agent.stop()
        await task

    asyncio.run(run_and_stop())
    assert "capture" in started
    assert _new_threads_end(before) == []


def test_the_command_line_skips_the_exit_collection() -> None:
    # `gaitrig …` as a process: the objects alive when the command returns are frozen, so
    # the interpreter's finalisation does not traverse them
    code = ("import gc, sys\nsys.argv = ['gaitrig']\nfrom app.cli import main\nmain()\n"
            "print(gc.get_freeze_count())")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, check=True).stdout
    assert int(out.strip().splitlines()[-1]) > 10_000


def test_a_test_calling_the_command_line_keeps_its_collector(
        capsys: pytest.CaptureFixture[str]) -> None:
    from app.cli import main

    frozen = gc.get_freeze_count()
    assert main([]) == 2  # no command: the help
    assert gc.get_freeze_count() == frozen
    assert "usage: gaitrig" in capsys.readouterr().out
