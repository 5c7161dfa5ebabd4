"""Calibration wizard in headless Debian Chromium against an in-process server: log in,
run the simulated calibration, see the residual tables and the saved versions."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from app.config import Settings
from app.main import create_app


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def server(tmp_path: Path) -> Iterator[str]:
    import uvicorn

    port = _free_port()
    app = create_app(Settings(data_dir=tmp_path, viewer_enabled=False, admin_password="wz-pw",
                              node_token="wz-token"))
    srv = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    th = threading.Thread(target=srv.run, daemon=True)
    th.start()
    deadline = time.time() + 30
    while not srv.started and time.time() < deadline:
        time.sleep(0.05)
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        srv.should_exit = True
        th.join(timeout=10)


def test_wizard_runs_simulated_calibration(server: str, artifacts_dir: Path,
                                           browser: Any) -> None:
    b = browser.new_context(viewport={"width": 1200, "height": 1400})
    try:
        page = b.new_page()
        page.goto(server + "/index.html")
        page.fill("#username", "admin")
        page.fill("#password", "wz-pw")
        page.click("button[type=submit]")
        page.wait_for_url("**/rig.html", timeout=15000)
        page.goto(server + "/calibration-wizard.html")
        page.wait_for_selector("#res-summary")
        assert (page.text_content("#res-summary") or "").startswith("No calibration yet")
        # the simulated run is the secondary path (the header's user menu is a <details> too)
        page.click("details:has(#sim-form) > summary")
        page.fill("#sim-frames", "2")
        page.click("#sim-form button[type=submit]")
        page.wait_for_function(
            "document.querySelectorAll('#sensor-table tbody tr').length === 6",
            timeout=240_000)
        assert "Version 1" in (page.text_content("#res-summary") or "")
        rows = page.query_selector_all("#sensor-table tbody tr")
        assert all(r.query_selector(".good") for r in rows)  # every sensor ≤ 1 cm, 0.5°
        assert len(page.query_selector_all("#edge-table tbody tr")) >= 15
        assert "depth points" in (page.text_content("#rejected") or "")
        assert len(page.query_selector_all("#history tbody tr")) == 1
        page.screenshot(path=str(artifacts_dir / "calibration-wizard.png"), full_page=True)
        # a bad sheet request shows the engine's message, not a traceback
        page.fill("#sheet-ids", "8-1")
        page.click("#sheet-form button[type=submit]")
        page.wait_for_function(
            "document.getElementById('sheet-error').textContent.length > 0")
        assert "reversed" in (page.text_content("#sheet-error") or "")
    finally:
        b.close()
