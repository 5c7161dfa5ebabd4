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
    assert "Error against the markers" in summary and "residual" not in summary, summary
    assert page.locator("#res-summary [data-verdict]").count() == 1
    assert page.evaluate("document.activeElement.id") == "res-summary"
    assert page.locator("#res-figures-list li").count() == n + 1  # the whole, then each sensor
    assert page.get_by_role("group", name="Use this calibration?").is_visible()
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
    page.wait_for_function("document.getElementById('decide-error').textContent.includes('busy')")
    assert "Not saved" in (page.text_content("#decide-error") or "")
    assert page.is_visible("#accept")
    page.unroute("**/api/calibration/captures/*/accept")
    page.click("#accept")
    page.wait_for_function("document.getElementById('decide-state').textContent.includes('Saved')")
    assert page.text_content("#decide-error") == "" and page.is_hidden("#decide")
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


def _result(worst_mm: float) -> dict[str, Any]:
    """A captured calibration's result as the server sends it: two sensors, S2 the worst."""
    def at(x: float, y: float) -> list[list[float]]:
        return [[1.0, 0, 0, x], [0, 1.0, 0, y], [0, 0, 1.0, 1.0], [0, 0, 0, 1.0]]
    res = {"S1": 0.0008, "S2": worst_mm / 1000}
    return {
        "created_iso": "2026-11-24T10:00:00Z", "meta": {"source": "capture from 2 sensors", "icp": [
            {"sensor": "S1", "accepted": True, "reason": "improved", "fitness_before": 0.61,
             "fitness": 0.74, "inlier_rmse_before_mm": 9.3, "inlier_rmse_mm": 6.1},
            {"sensor": "S2", "accepted": False,
             "reason": "too little overlap with the other sensors (fitness 0.05)",
             "fitness_before": 0.05, "fitness": 0.05, "inlier_rmse_before_mm": 16.0,
             "inlier_rmse_mm": 16.0}]},
        "T_world_sensor": {"S1": at(2.0, 1.0), "S2": at(5.0, -1.0)},
        "T_world_marker": {"1": at(0.0, 0.0), "2": at(3.0, 0.0)},
        "sensor_residual_m": res,
        "edges": [{"sensor": s, "marker": m, "residual_m": res[s], "in_chain": True,
                   "distance_m": 2.4} for s, m in (("S1", 1), ("S1", 2), ("S2", 2))],
        "observations": [{"sensor": "S2", "marker": 1, "accepted": False,
                          "reason": "the marker is partly occluded or not flat"}],
    }


def test_wizard_says_the_result_in_words_and_asks_under_it(page: Any, live_server: LiveServer,
                                                           artifacts_dir: Path) -> None:
    """The result of a capture says its worst error against the markers in words (good,
    fair, too large), keeps the exact figures under "Technical figures", and asks "Use this
    calibration?" right under it: the focus goes to the result, Tab leads on to Accept, a
    refused Accept says so in the box, Reject closes it and says what happened. The
    server's capture job is answered by the test (a real one: the test above)."""
    job = {"id": 9077, "kind": "capture", "state": "done", "message": "", "frames": 8,
           "created": 0, "nodes": {"S1": {"received": 8, "error": None},
                                   "S2": {"received": 8, "error": None}},
           "marker_sizes_m": {}}
    answers = {"accept": (503, {"detail": "server busy"}), "reject": (200, {"rejected": True})}
    asked: list[str] = []

    def job_route(route: Any) -> None:
        url = route.request.url
        if route.request.method == "POST" and url.endswith("/capture"):
            route.fulfill(status=202, json={"id": job["id"]})
        elif route.request.method == "GET" and url.endswith(f"/captures/{job['id']}"):
            route.fulfill(json=job)
        elif route.request.method == "POST" and url.rsplit("/", 1)[-1] in answers:
            asked.append(url.rsplit("/", 1)[-1])
            status, body = answers[url.rsplit("/", 1)[-1]]
            route.fulfill(status=status, json=body)
        else:
            route.continue_()

    page.route(re.compile(r".*/api/calibration/captur.*"), job_route)
    page.goto(live_server.base_url + "/calibration-wizard.html")
    page.wait_for_function("document.getElementById('cap-source').textContent.length > 0")

    def capture(worst_mm: float) -> str:
        job["result"] = _result(worst_mm)
        page.click("#cap-form button[type=submit]")
        page.wait_for_function("!document.getElementById('decide').hidden")
        page.wait_for_function("document.activeElement.id === 'res-summary'")
        return " ".join((page.text_content("#res-summary") or "").split())

    summary = capture(4.2)
    assert "2 sensors placed from 2 markers" in summary, summary
    assert "Error against the markers: 4.2 mm at worst" in summary, summary
    assert "fair (3–10 mm): a red line in the graph" in summary, summary
    assert page.get_attribute("#res-summary [data-verdict]", "data-verdict") == "check"
    assert "residual" not in summary  # the engineer's word is in the title
    assert "4.20 mm" in (page.get_attribute("#res-summary", "title") or "")
    # in words in the table, the engine's figures in the title and the technical figures
    icp = page.locator("#sensor-table tbody tr td:nth-child(4) span")
    assert icp.nth(1).inner_text().startswith("not kept: this sensor's view overlaps")
    assert "ICP fitness 0.05→0.05" in (icp.nth(1).get_attribute("title") or "")
    assert not page.is_visible("#res-figures-list")  # closed until asked for
    page.click("#res-figures > summary")
    figures = page.inner_text("#res-figures-list")
    assert "worst sensor residual 4.20 mm" in figures, figures
    assert "S2: residual 4.20 mm; ICP not kept (too little overlap" in figures, figures
    assert "inlier RMSE 9.3→6.1 mm" in figures, figures
    assert "sightings left out (1)" in page.inner_text("#res-more-summary")
    # the choice is right under the result it judges, a named group, on screen
    decide = page.get_by_role("group", name="Use this calibration?")
    assert decide.is_visible()
    box, details = decide.bounding_box(), page.locator("#res-details").bounding_box()
    assert box and details and box["y"] >= details["y"] + details["height"], (box, details)
    assert page.evaluate("document.getElementById('res-h').getBoundingClientRect().top") < 200
    page.locator("#decide").scroll_into_view_if_needed()
    screenshot(page, artifacts_dir, "calibration_result_decide", "#decide")
    page.click("#res-more > summary")
    page.screenshot(path=str(artifacts_dir / "browser" / "calibration_result_words.png"),
                    full_page=True)
    # from the result, Tab goes through it (help link, the two disclosures) to Accept
    tabs = []
    for _ in range(6):
        page.keyboard.press("Tab")
        tabs.append(page.evaluate("document.activeElement.id || "
                                  "document.activeElement.textContent"))
        if tabs[-1] == "accept":
            break
    assert tabs[-1] == "accept", tabs
    # a refused Accept says why in the box and keeps the choice (and the focus) there
    page.keyboard.press("Enter")
    page.wait_for_function("document.getElementById('decide-error').textContent.includes('busy')")
    assert (page.text_content("#decide-error") or "").startswith("Not saved: ")
    assert page.get_attribute("#decide-error", "role") == "alert"
    assert page.is_visible("#accept") and page.is_enabled("#accept")
    assert page.evaluate("document.activeElement.id") == "accept"
    # Reject closes the box; the focus goes to what happened (not to the page)
    page.click("#reject")
    page.wait_for_function("document.getElementById('decide').hidden")
    assert page.text_content("#decide-state") == "Rejected: the active calibration is unchanged."
    assert page.evaluate("document.activeElement.id") == "decide-state"
    assert page.text_content("#decide-error") == ""
    assert asked == ["accept", "reject"]

    summary = capture(0.9)
    assert "0.9 mm at worst — good (under 3 mm): accept it." in summary, summary
    assert page.get_attribute("#res-summary [data-verdict]", "data-verdict") == "good"
    assert page.text_content("#decide-state") == ""  # the last outcome is not this one's
    assert page.is_enabled("#accept") and not page.is_visible("#accept-bad")
    summary = capture(12.5)
    assert "too large (over 10 mm): step width would not be reliable" in summary, summary
    assert page.get_attribute("#res-summary [data-verdict]", "data-verdict") == "bad"
    # too large: accepted only once the person ticks that they know what it costs
    assert not page.is_enabled("#accept")
    page.locator("#decide").scroll_into_view_if_needed()
    screenshot(page, artifacts_dir, "calibration_result_too_large", "#decide")
    page.check("#accept-bad")
    assert page.is_enabled("#accept")
    page.uncheck("#accept-bad")
    assert not page.is_enabled("#accept")
    answers["accept"] = (200, {"version": 7, "applied_to": ["S1", "S2"]})
    page.check("#accept-bad")
    page.click("#accept")
    page.wait_for_function("document.getElementById('decide').hidden")
    assert (page.text_content("#decide-state") or "").startswith("Saved as version 7")
    assert asked[-1] == "accept"
    # the next result is asked about afresh: the tick is not carried over
    capture(12.5)
    assert not page.is_checked("#accept-bad") and not page.is_enabled("#accept")
    capture(4.2)
    assert page.is_enabled("#accept") and not page.is_visible("#accept-bad")
    assert not page.js_errors
