"""Rig page: a warning the sensor raised after it connected shows beside that node, in
plain words with its time (a real server, a real sim node told to raise one)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.browser.conftest import ROOT, new_page, screenshot, serve_without_nodes, stop_process

pytestmark = pytest.mark.browser

TOKEN = "browser-warning-token-7"
PASSWORD = "warnings on the rig 42"
TEXT = "Body tracking fell behind the camera (test warning): skeletons may be missing."


@pytest.fixture(scope="module")
def rig() -> Iterator[str]:
    """A server without the demo's nodes and one sim node S1 raising :data:`TEXT` every
    5 s; yields the console URL."""
    tmp = Path(tempfile.mkdtemp(prefix="gaitrig-warnings-"))
    env = {**os.environ, "GAITRIG_NODE_TOKEN": TOKEN, "GAITRIG_ADMIN_PASSWORD": PASSWORD,
           "PYTHONUNBUFFERED": "1"}
    try:
        with serve_without_nodes(tmp / "data", env) as (url, _log), \
                (tmp / "node.log").open("wb") as log:
            node = subprocess.Popen(
                [sys.executable, "-m", "app.cli", "node", "--id", "S1", "--server",
                 url.replace("http://", "ws://"), "--data-dir", str(tmp / "node"),
                 "--no-images", "--test-warning", TEXT],
                cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT)
            try:
                yield url
            finally:
                stop_process(node, 10.0)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def test_a_sensor_warning_shows_beside_its_node_with_the_time(
        browser: Any, rig: str, artifacts_dir: Path) -> None:
    page = new_page(browser, 60000)
    try:
        page.goto(rig + "/index.html")
        page.fill("#username", "admin")
        page.fill("#password", PASSWORD)
        page.click("button[type=submit]")
        page.wait_for_url("**/rig.html")
        item = page.locator("#nodes tr[data-node=S1] li.node-warning").first
        item.wait_for()  # the node connects, then its backend warns
        text = item.inner_text()
        # the browser's own clock format: whatever the locale, the time has digits and ':'
        found = re.fullmatch(r"The sensor warned at (.+?): (.+)", text)
        assert found, text
        assert re.search(r"\d{1,2}[:.]\d\d", found.group(1)), text
        assert found.group(2).startswith(TEXT), text
        # the same warning again: still one line, saying how often
        page.wait_for_function(
            "document.querySelector('#nodes tr[data-node=S1] li.node-warning')"
            ".textContent.includes('times)')")
        assert page.locator("#nodes tr[data-node=S1] li.node-warning").count() == 1
        screenshot(page, artifacts_dir, "rig_node_warning", "#nodes tr[data-node=S1]")
        assert not page.js_errors
    finally:
        page.context.close()
