"""Calibrate/planning page in a real browser: moving a sensor changes the coverage map."""

from __future__ import annotations

import urllib.error
from pathlib import Path
from typing import Any

import pytest

from engine.coverage import BLIND_RGB
from tests.browser.conftest import LiveServer, changed_fraction, color_fraction, screenshot

pytestmark = pytest.mark.browser


def _map_loaded(page: Any, version: str | None = None) -> None:
    cond = "img.complete && img.naturalWidth > 0"
    if version is not None:
        cond += f" && img.dataset.version !== '{version}'"
    page.wait_for_function(f"(() => {{ const img = document.getElementById('coverage'); "
                           f"return {cond}; }})()", timeout=30000)


def test_moving_a_sensor_changes_the_coverage_map(page: Any, live_server: LiveServer,
                                                  artifacts_dir: Path) -> None:
    live_server.api("/api/planning/reset", {})
    page.route(live_server.viewer_url + "/**", lambda r: r.abort())
    page.goto(live_server.base_url + "/calibrate.html")
    page.wait_for_selector("#poses tr[data-node]")
    _map_loaded(page)
    page.wait_for_timeout(300)  # the image element paints after load
    before = screenshot(page, artifacts_dir, "plan_map_before", "#coverage")
    screenshot(page, artifacts_dir, "calibrate_page")
    state0 = live_server.api("/api/planning")
    assert len(page.locator("#poses tr[data-node]").all()) == live_server.n_nodes
    v0 = page.get_attribute("#coverage", "data-version")
    # turn S1 round to look away from the walkway, as the 3D view's drag handle would
    page.select_option("#move-id", "S1")
    page.fill("#move-yaw", "35")
    page.click("#move-apply")
    _map_loaded(page, v0)
    page.wait_for_timeout(300)
    after = screenshot(page, artifacts_dir, "plan_map_after", "#coverage")
    state1 = live_server.api("/api/planning")
    moved = next(s for s in state1["sensors"] if s["id"] == "S1")
    assert moved["moved"] and abs(moved["yaw_deg"] - 35) < 0.5
    assert page.locator("#planned tr.moved").count() == 1
    # the picture changed and has more blind (red) floor; the numbers agree
    assert changed_fraction(before, after) > 0.01
    red0, red1 = color_fraction(before, BLIND_RGB, 25), color_fraction(after, BLIND_RGB, 25)
    assert red1 > red0 + 0.005, (red0, red1)
    assert state1["walkway_covered_fraction"] < state0["walkway_covered_fraction"]
    assert not page.js_errors

    # read the version before the click: the map may reload before a read after it
    v1 = page.get_attribute("#coverage", "data-version")
    page.click("#plan-reset")
    _map_loaded(page, v1)
    assert not any(s["moved"] for s in live_server.api("/api/planning")["sensors"])


def test_save_and_placement_sheet(page: Any, live_server: LiveServer,
                                  artifacts_dir: Path) -> None:
    page.route(live_server.viewer_url + "/**", lambda r: r.abort())
    page.goto(live_server.base_url + "/calibrate.html")
    page.wait_for_selector("#poses tr[data-node]")
    page.fill("#save-name", "browser-test-rig")
    page.click("#save-form button[type=submit]")
    page.wait_for_function("document.getElementById('save-status').textContent.includes('Saved')")
    assert "rigs/browser-test-rig.toml" in page.inner_text("#save-status")
    saved = live_server.data_dir / "server" / "rigs" / "browser-test-rig.toml"
    assert saved.is_file() and "S6" in saved.read_text()
    with pytest.raises(urllib.error.HTTPError) as bad:
        live_server.api("/api/planning/save", {"name": "../escape"})
    assert bad.value.code == 422

    page.goto(live_server.base_url + "/api/planning/sheet")
    page.wait_for_function("document.querySelector('img.sheet-map').naturalWidth > 0")
    rows = page.locator("#placement tbody tr")
    assert rows.count() == live_server.n_nodes
    first = [c.inner_text() for c in rows.nth(0).locator("th, td").all()]
    assert first[0] == "S1" and abs(float(first[1]) - 260.0) < 1.0  # √(2.4² + 1²) m
    img = screenshot(page, artifacts_dir, "placement_sheet")
    assert color_fraction(img, BLIND_RGB, 25) > 0.005  # the map is on the sheet
