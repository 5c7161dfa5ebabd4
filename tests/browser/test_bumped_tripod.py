"""Bumped tripod in a real browser: the server's periodic check (every 3 s here) finds that
a sensor no longer stands where the calibration says, and the Rig and Record pages warn in
plain words, naming the sensor, without anyone clicking a check.

Runs its own two-node ``gaitrig demo`` (the shared demo checks only every 300 s and must
not get a wrong calibration): the saved calibration puts S2 2 cm / 0.8° away from where
its simulated camera really is — what a knocked tripod looks like to the check.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.server.calibration import calibration_dir
from engine.calibration.store import save_version
from engine.geometry import make_transform, so3_exp
from tests.app.calibration.sim_truth import BUMP_DEG, BUMP_M, truth_calibration
from tests.browser.conftest import (
    ROOT,
    START_TIMEOUT_S,
    LiveServer,
    _wait_http,
    free_port,
    login,
    screenshot,
    stop_process,
)

pytestmark = pytest.mark.browser


@pytest.fixture
def bumped_server() -> Iterator[LiveServer]:
    """A two-node demo whose active calibration has S2 where it stood before the bump."""
    from app.commands.demo import demo_password

    tmp = Path(tempfile.mkdtemp(prefix="gaitrig-bumped-"))
    cal = truth_calibration(["S1", "S2"])
    T = cal.T_world_sensor["S2"] @ make_transform(
        so3_exp(np.radians([0.0, BUMP_DEG, 0.0])), [0.0, 0.0, 0.0])
    T[:3, 3] += [BUMP_M, 0.0, 0.0]
    cal.T_world_sensor["S2"] = T
    save_version(cal, calibration_dir(tmp / "server"))
    port = free_port()
    password = demo_password(tmp)
    log = (tmp / "demo.log").open("wb")
    proc = subprocess.Popen(
        [sys.executable, "-m", "app.cli", "demo", "--port", str(port), "--no-viewer",
         "--data-dir", str(tmp), "--nodes", "2"], cwd=ROOT, stdout=log,
        stderr=subprocess.STDOUT,
        env={**os.environ, "PYTHONUNBUFFERED": "1", "GAITRIG_CALIBRATION_CHECK_INTERVAL_S": "3"})
    server = LiveServer(f"http://127.0.0.1:{port}", "", password, tmp, 2, proc)
    try:
        _wait_http(server.base_url + "/healthz", proc, START_TIMEOUT_S)
        server.login()
        yield server
    finally:
        stop_process(proc)
        log.close()
        shutil.rmtree(tmp, ignore_errors=True)


def test_rig_and_record_pages_warn_about_a_moved_sensor(
        browser: Any, bumped_server: LiveServer, artifacts_dir: Path) -> None:
    ctx = browser.new_context(viewport={"width": 1400, "height": 900})
    try:
        page = ctx.new_page()
        page.set_default_timeout(20000)
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        login(page, bumped_server)  # lands on the Rig page
        # nobody clicks anything: the periodic check runs on the server, the page polls
        banner = page.locator("#calib-warning")
        banner.wait_for(state="visible", timeout=600_000)
        text = banner.inner_text()
        m = re.search(r"Sensor (\S+) has moved ([\d.]+) cm / ([\d.]+)° since the calibration "
                      r"of (.+?)\. Recalibrate before recording\.", text)
        assert m is not None, text
        assert m.group(1) == "S2" and "S1" not in text, text
        assert float(m.group(2)) == pytest.approx(BUMP_M * 100, abs=0.5), text
        assert float(m.group(3)) == pytest.approx(BUMP_DEG, abs=0.25), text
        assert str(time.gmtime().tm_year) in m.group(4), text  # the calibration's date
        link = banner.locator("a[href='/calibration-wizard.html']")
        assert link.get_attribute("href") == "/calibration-wizard.html"
        assert "calibration wizard" in link.inner_text()
        screenshot(page, artifacts_dir, "rig_bumped_tripod_banner", "#calib-warning")

        # the Record page warns before a recording is started (a warning, not a block)
        page.goto(bumped_server.base_url + "/record.html")
        rec_banner = page.locator("#calib-warning")
        rec_banner.wait_for(state="visible", timeout=60_000)
        assert "Sensor S2 has moved" in rec_banner.inner_text()
        assert "Recalibrate before recording" in rec_banner.inner_text()
        assert page.locator("#start").is_visible()
        assert not errors, errors
    finally:
        ctx.close()
