"""Calibration wizard with real capture from the demo's simulated nodes, in Chromium.

The nodes render colour + depth of the room with its printed floor markers (and the
walker) and send them over the node protocol; the server detects, solves, refines and
shows the graph and residuals; accepting saves and applies it; the live bumped-tripod
check then finds no sensor moved. Poses are compared with the simulator's true ones.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from engine.geometry import pose_error
from engine.sim.rig import default_avenue_rig
from tests.browser.conftest import LiveServer, screenshot

pytestmark = pytest.mark.browser


def test_wizard_captures_from_nodes_accepts_and_checks(page: Any, live_server: LiveServer,
                                                       artifacts_dir: Path) -> None:
    n = live_server.n_nodes
    before = live_server.api("/api/calibration")
    page.goto(live_server.base_url + "/calibration-wizard.html")
    # the form starts from the demo room's markers (40 cm), or the active calibration's
    page.wait_for_function("document.getElementById('cap-source').textContent.length > 0")
    assert re.search(r"Filled in from (the simulated demo room|calibration \d+)\.",
                     page.inner_text("#cap-source"))
    assert page.input_value("#cap-size") == "40" and page.input_value("#cap-ids") == "1-8"
    page.fill("#cap-frames", "8")
    # the first two polls of the capture find the server busy: the page keeps watching
    failed: list[str] = []

    def busy_twice(route: Any) -> None:
        if route.request.method == "GET" and len(failed) < 2:
            failed.append(route.request.url)
            route.fulfill(status=503, body='{"detail": "busy"}',
                          headers={"Content-Type": "application/json"})
        else:
            route.continue_()

    page.route("**/api/calibration/captures/*", busy_twice)
    page.click("#cap-form button[type=submit]")
    # progress per connected node while capturing
    page.wait_for_function(f"document.querySelectorAll('#cap-progress tbody tr').length === {n}",
                           timeout=60_000)
    page.wait_for_function("!document.getElementById('decide').hidden || "
                           "document.getElementById('cap-error').textContent.length > 0",
                           timeout=300_000)
    assert page.text_content("#cap-error") == "", page.text_content("#cap-error")
    assert len(failed) == 2
    summary = page.text_content("#res-summary") or ""
    assert "not saved yet" in summary
    assert not re.search(r"\d{4}-\d\d-\d\dT\d\d:", summary), summary  # a readable time
    assert page.locator("#graph circle.sensor").count() == n
    assert page.locator("#graph rect.marker").count() >= 2
    assert page.locator("#graph line.edge").count() >= n
    assert page.locator("#sensor-table tbody tr").count() == n
    icp = page.locator("#sensor-table tbody tr td:nth-child(4)").all_text_contents()
    assert all(t.startswith(("kept", "not kept")) for t in icp), icp
    assert page.locator("#edge-table tbody tr").count() >= n
    got = page.locator("#cap-progress tbody td:nth-child(2)").all_text_contents()
    assert all(t.strip() == "8 / 8" for t in got), got
    page.locator("#graph").scroll_into_view_if_needed()
    screenshot(page, artifacts_dir, "calibration_capture_result")
    assert live_server.api("/api/calibration") == before  # nothing saved before accepting

    # a first Accept the server refuses says so and keeps the choice open
    page.route("**/api/calibration/captures/*/accept", lambda route: route.fulfill(
        status=503, body='{"detail": "server busy"}', headers={"Content-Type": "application/json"}))
    page.click("#accept")
    page.wait_for_function("document.getElementById('cap-error').textContent.includes('busy')")
    assert "Not saved" in (page.text_content("#cap-error") or "")
    assert page.is_visible("#accept")
    page.unroute("**/api/calibration/captures/*/accept")
    page.click("#accept")
    page.wait_for_function("document.getElementById('cap-state').textContent.includes('Saved')")
    assert page.text_content("#cap-error") == ""
    after = live_server.api("/api/calibration")
    assert len(after) == len(before) + 1
    active = live_server.api("/api/calibration/active")
    assert "capture" in active["meta"]["source"]
    rig = default_avenue_rig(0)
    for s in rig.sensors[:n]:
        dt, dr = pose_error(np.asarray(active["T_world_sensor"][s.id]), s.T_world_sensor)
        assert dt < 0.01 and np.degrees(dr) < 0.5, (s.id, dt, np.degrees(dr))
    # the page shows "Saved" first, then asks for the versions list: wait for the new row
    page.wait_for_function(f"document.querySelectorAll('#history tbody tr').length === "
                           f"{len(after)}")
    # the active version's (disabled) button is not announced as a restore
    assert page.get_attribute("#history tbody tr:first-child button", "aria-label") == (
        f"Calibration version {after[0]['version']} is active")

    page.click("#check-btn")
    page.wait_for_function("document.querySelectorAll('#check-table tbody tr').length > 0",
                           timeout=180_000)
    page.locator("#check-table").scroll_into_view_if_needed()
    statuses = page.locator("#check-table tbody tr td:nth-child(2)").all_text_contents()
    assert statuses == ["ok"] * n, (statuses, page.text_content("#check-state"))
    assert "no sensor moved" in (page.text_content("#check-state") or "")
    last = live_server.api("/api/calibration/live-check")
    assert last["checked"] and last["moved"] == []
    screenshot(page, artifacts_dir, "calibration_live_check")
    assert not page.js_errors
    # the Calibrate page shows the latest check (and would warn about a moved sensor)
    page.goto(live_server.base_url + "/calibrate.html")
    page.wait_for_function("document.getElementById('bump-state').textContent"
                           ".includes('no sensor moved')", timeout=15_000)
    assert not page.js_errors
