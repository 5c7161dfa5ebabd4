"""Rig page: each sensor says which lens its live 3D view is drawn through, in plain
words — the lens a node announced when it connected (a real sim node rendering through a
lens), or none reported (a node of the protocol revision before lenses: a pinhole)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from app.nodes.protocol import Hello, SensorInfo, dump
from tests.browser.conftest import ROOT, new_page, screenshot, serve_without_nodes, stop_process

pytestmark = pytest.mark.browser

TOKEN = "browser-lens-token-3"
PASSWORD = "lenses on the rig 42"
LENS = "-0.12,0.03,0.0008,-0.0005,0.0"


@pytest.fixture(scope="module")
def rig() -> Iterator[str]:
    """A server without the demo's nodes, a sim node S1 rendering its depth through
    :data:`LENS`, and R2, a node of protocol revision 2 (it announces no lens); yields the
    console URL."""
    import websockets.sync.client

    tmp = Path(tempfile.mkdtemp(prefix="gaitrig-lens-"))
    env = {**os.environ, "GAITRIG_NODE_TOKEN": TOKEN, "GAITRIG_ADMIN_PASSWORD": PASSWORD,
           "PYTHONUNBUFFERED": "1", "GAITRIG_TEST_SIM_DEPTH_DIST": LENS}
    stop = threading.Event()
    try:
        with serve_without_nodes(tmp / "data", env) as (url, _log), \
                (tmp / "node.log").open("wb") as log:
            ws_url = url.replace("http://", "ws://")
            node = subprocess.Popen(
                [sys.executable, "-m", "app.cli", "node", "--id", "S1", "--server", ws_url,
                 "--data-dir", str(tmp / "node"), "--no-images"],
                cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT)

            def old_node() -> None:
                with websockets.sync.client.connect(ws_url + "/ws/node") as ws:
                    ws.send(dump(Hello(node_id="R2", token=TOKEN, protocol=2,
                                       sensor=SensorInfo(depth_K=[[365.0, 0, 255.5],
                                                                  [0, 365.0, 211.5],
                                                                  [0, 0, 1.0]]))))
                    while not stop.is_set():  # read the pings
                        try:
                            ws.recv(timeout=0.5)
                        except TimeoutError:
                            continue

            reader = threading.Thread(target=old_node, daemon=True)
            reader.start()
            try:
                yield url
            finally:
                stop.set()
                reader.join(5)
                stop_process(node, 10.0)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def test_each_sensor_says_its_lens(browser: Any, rig: str, artifacts_dir: Path) -> None:
    page = new_page(browser, 60000)
    try:
        page.goto(rig + "/index.html")
        page.fill("#username", "admin")
        page.fill("#password", PASSWORD)
        page.click("button[type=submit]")
        page.wait_for_url("**/rig.html")
        s1 = page.locator("#nodes tr[data-node=S1] th .lens")
        page.wait_for_function(
            "(document.querySelector('#nodes tr[data-node=S1] th .lens') || {})"
            ".textContent === 'Lens: simulator (k1 -0.120, k2 0.030, …)'")
        assert s1.is_visible()
        r2 = page.locator("#nodes tr[data-node=R2] th .lens")
        r2.wait_for()
        assert r2.inner_text() == "Lens: none reported (drawn as a pinhole camera)"
        screenshot(page, artifacts_dir, "rig_lens", "#nodes")
        assert not page.js_errors
    finally:
        page.context.close()
