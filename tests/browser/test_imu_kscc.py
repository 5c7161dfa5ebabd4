"""IMU and KSCC pages in a real browser against the demo server (six simulated sensors)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest

from tests.browser.conftest import LiveServer, color_fraction, screenshot

pytestmark = pytest.mark.browser


def test_imu_page_simulated_session(page: Any, live_server: LiveServer,
                                    artifacts_dir: Path) -> None:
    page.goto(live_server.base_url + "/imu.html")
    page.click("#simulate")
    page.wait_for_selector("#accuracy-rows tr", timeout=120_000)
    page.wait_for_function("document.getElementById('angles-plot').naturalWidth > 0")
    rows = page.locator("#accuracy-rows tr")
    assert rows.count() == 4
    # every joint: the fused RMSE is below the depth-only one, and marked as better
    for i in range(4):
        cells = [c.strip() for c in rows.nth(i).locator("td").all_inner_texts()]
        depth, fused = (float(c.rstrip("°")) for c in cells[:2])
        assert fused < depth, cells
        assert rows.nth(i).locator("td.better").count() == 1
    assert page.locator("#sync-rows tr").count() == 10
    assert "aligned to the depth skeleton's clock" in page.inner_text("#sync-text")
    href = page.get_attribute("#csv", "href")
    assert href and href.endswith("/data.csv")
    page.locator("#accuracy-card").scroll_into_view_if_needed()
    img = screenshot(page, artifacts_dir, "imu_simulated_accuracy", "#accuracy-card")
    assert color_fraction(img, (0x1A, 0x7F, 0x37), tol=30) > 1e-4  # the green "better" cells
    plot = screenshot(page, artifacts_dir, "imu_angles_plot", "#angles-card")
    assert color_fraction(plot, (0x0B, 0x5C, 0xAD), tol=40) > 1e-3  # fused curves drawn
    # a wrong file: the message says what is wrong, in the page
    page.set_input_files("#files", files=[{"name": "notes.docx", "mimeType": "text/plain",
                                           "buffer": b"hello"}])
    page.click("#upload")
    page.wait_for_function("document.getElementById('error').textContent.length > 0")
    assert "unsupported type .docx" in page.inner_text("#error")
    assert not page.js_errors


def test_imu_page_lists_are_read_whole(page: Any, live_server: LiveServer) -> None:
    """The generic-CSV units' lists showed "from the names or gravit" (cut) at 1366 and
    1920 px: each list's chosen entry fits it at common widths."""
    from tests.browser.test_clinician_1366 import CUT_SELECTS_JS

    page.goto(live_server.base_url + "/imu.html")
    page.wait_for_selector("#quat_order")
    for width in (320, 1024, 1366, 1920):
        page.set_viewport_size({"width": width, "height": 900})
        assert page.evaluate(CUT_SELECTS_JS, None) == [], width
    assert not page.js_errors


def test_imu_page_upload_of_a_session(page: Any, live_server: LiveServer,
                                      artifacts_dir: Path, tmp_path: Path) -> None:
    """Nine generic IMU CSVs (own clocks) and a skeleton CSV with 2 cm joint noise uploaded
    through the form: synchronised by the jumps, fused, plotted, downloadable."""
    import numpy as np

    from app.server.imu_analysis import simulate_session
    from engine.io.csv import write_skeleton_csv

    sim = simulate_session(seed=3, depth_noise_m=0.02)
    paths = []
    for name, rec in sim["recordings"].items():
        f = tmp_path / f"{name}.csv"
        np.savetxt(f, np.column_stack([rec.time, np.degrees(rec.gyr), rec.acc, rec.mag]),
                   delimiter=",", fmt="%.6f", comments="",
                   header="time,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z,mag_x,mag_y,mag_z")
        paths.append(str(f))
    write_skeleton_csv(tmp_path / "depth.csv", sim["depth"])
    page.goto(live_server.base_url + "/imu.html")
    page.set_input_files("#files", files=paths)
    page.fill("#sensors", ", ".join(sim["recordings"]))
    page.set_input_files("#skeleton", files=[str(tmp_path / "depth.csv")])
    page.select_option("#gyr_unit", "deg/s")
    page.select_option("#acc_unit", "m/s2")
    page.select_option("#mag_unit", "uT")
    page.click("#upload")
    page.wait_for_selector("#sync-rows tr", timeout=120_000)
    page.wait_for_function("document.getElementById('angles-plot').naturalWidth > 0")
    page.wait_for_function("document.getElementById('sync-plot').naturalWidth > 0")
    rows = page.locator("#sync-rows tr")
    assert rows.count() == 10
    assert "aligned to the depth skeleton's clock" in page.inner_text("#sync-text")
    assert page.inner_text("#error").strip() == ""
    # every IMU clock offset shown matches the simulated one (to the 1 ms displayed + 10 ms)
    checked = 0
    for i in range(rows.count()):
        cells = [c.strip() for c in rows.nth(i).locator("th, td").all_inner_texts()]
        if cells[0] in sim["true_offsets"]:
            shown = float(cells[1].rstrip(" s"))
            assert abs(shown - sim["true_offsets"][cells[0]]) < 0.011, cells
            checked += 1
    assert checked == 9
    href = page.get_attribute("#csv", "href")
    assert href and href.endswith("/data.csv")
    text = page.evaluate("h => fetch(h).then(r => r.text())", href)
    assert text.startswith("time_s,knee_left_fused_deg,knee_left_depth_deg")
    assert len(text.splitlines()) > 500
    screenshot(page, artifacts_dir, "imu_uploaded_session", "#sync-card")
    assert not page.js_errors


def _keep_history(page: Any, selector: str, name: str) -> None:
    """Record in ``window[name]`` every text and class each ``selector`` element shows.

    A transient display (a 3 s countdown, a collecting state) can come and go between two
    polls of a loaded test process; the page's own history of what it showed cannot miss it.
    """
    page.evaluate("""([selector, name]) => {
        const seen = window[name] = [];
        document.querySelectorAll(selector).forEach((e, i) => {
            seen[i] = [];
            const note = () => seen[i].push({ text: e.textContent, cls: e.className });
            new MutationObserver(note).observe(e, { childList: true, characterData: true,
                                                    subtree: true, attributes: true });
        });
    }""", [selector, name])


def test_kscc_page_live_progress_and_active_area(page: Any, live_server: LiveServer,
                                                 artifacts_dir: Path) -> None:
    page.goto(live_server.base_url + "/kscc.html")
    page.wait_for_selector("#node-b option[value=S2]", state="attached")
    page.select_option("#node-a", "S1")
    page.select_option("#node-b", "S2")
    page.fill("#countdown", "3")
    _keep_history(page, "#sides .countdown", "countdowns")
    page.click("#start")
    # the countdown is shown on both sides (it may be over by the time this test looks) ...
    page.wait_for_function(
        "window.countdowns.length === 2 && window.countdowns.every(h => "
        "h.some(x => /^[1-3] s$/.test(x.text)))", timeout=10_000)
    # ... then each side reports a stillness state from KsccProgress
    page.wait_for_function(
        "[...document.querySelectorAll('#sides .state')].every(e => e.textContent.length > 0)",
        timeout=30_000)
    page.wait_for_function(
        "[...document.querySelectorAll('#sides .message')].every(e => "
        "!/Not started|Calibration starts/.test(e.textContent))", timeout=30_000)
    s = live_server.api("/api/kscc/session")
    for side in ("a", "b"):
        st = s["sides"][side]
        assert st["frames"] > 0 or "No skeleton" in st["message"], st
        assert st["message"]
    assert s["sides"]["a"]["source"] == "S1" and s["sides"]["b"]["source"] == "S2"
    # active area: every sensor's trapezoid numbers from its height
    rows = page.locator("#areas tr[data-node]")
    rows.nth(live_server.n_nodes - 1).wait_for()
    for i in range(rows.count()):
        text = rows.nth(i).inner_text()
        assert re.search(r"\d\.\d\d m", text) and text.count(" cm") == 4, text
    # calculator: seed 004's Kinect v1 at 1 m
    v1 = page.locator("#presets tr[data-preset=kinect_v1]").inner_text()
    assert "254 cm" in v1 and "400 cm" in v1
    page.fill("#height", "2.0")
    page.wait_for_function("!document.querySelector('#presets tr[data-preset=kinect_v1]')"
                           ".textContent.includes('254 cm')")
    screenshot(page, artifacts_dir, "kscc_progress", "#sides")
    screenshot(page, artifacts_dir, "kscc_active_area", "section[aria-labelledby=area-h]")
    page.click("#stop")
    page.wait_for_function("document.querySelector('#sides .message').textContent"
                           " === 'Not started.'")
    assert not page.js_errors


def test_kscc_stop_sharing_that_fails_says_so(page: Any, live_server: LiveServer) -> None:
    """A refused 'Stop sharing' is said on the page (it was an unhandled rejection)."""
    page.goto(live_server.base_url + "/kscc.html")
    page.wait_for_selector("#share-node option[value=S3]", state="attached")
    page.select_option("#share-node", "S3")
    page.click("#suggest")
    page.click("#share-form button[type=submit]")
    button = page.locator("#shares li", has_text="S3").get_by_role("button", name="Stop sharing")
    button.wait_for()
    page.route("**/api/kscc/shares/S3", lambda route: route.fulfill(
        status=503, content_type="application/json", body='{"detail": "the server is busy"}'))
    button.click()
    page.wait_for_function("document.getElementById('error').textContent.includes('S3')")
    assert "the server is busy" in page.inner_text("#error")
    page.unroute("**/api/kscc/shares/S3")
    page.locator("#shares li", has_text="S3").get_by_role("button", name="Stop sharing").click()
    page.wait_for_function("!document.getElementById('shares').textContent.includes('S3 is')")
    assert page.inner_text("#error") == ""


def test_kscc_two_remote_users_calibrated_and_compared(page: Any, live_server: LiveServer,
                                                       artifacts_dir: Path,
                                                       tmp_path: Path) -> None:
    """The demo server links to another site (a second real server on loopback) whose two
    sensors each see a still person: both calibrate, the page draws them and scores them."""
    from engine.coverage import sensor_pose
    from tests.app.analysis.test_kscc_api import ScriptedNode, Site, standing_person

    site = Site(tmp_path / "site-b")
    nodes = [ScriptedNode(site, "R1", sensor_pose((0.0, 0.0, 1.0), 0.0),
                          standing_person((2.6, 0.2), 200.0)),
             ScriptedNode(site, "R2", sensor_pose((5.0, 4.0, 1.2), 230.0),
                          standing_person((2.0, 1.5), 120.0))]
    try:
        token = "browser-link-token-0042"
        for n in ("R1", "R2"):
            for _ in range(100):
                if site.http.get(f"/api/nodes/{n}/skeleton").status_code == 200:
                    break
                page.wait_for_timeout(100)
            assert site.http.post("/api/kscc/shares",
                                  json={"node_id": n, "token": token}).status_code == 201
        page.goto(live_server.base_url + "/kscc.html")
        for side, node in (("a", "R1"), ("b", "R2")):
            page.check(f"input[name=kind-{side}][value=remote]")
            page.fill(f"#url-{side}", site.base)
            page.fill(f"#rnode-{side}", node)
            page.fill(f"#token-{side}", token)
        page.fill("#countdown", "0")
        _keep_history(page, "#sides .state", "states")
        page.click("#start")
        # user A is seen collecting still frames (a state that lasts a few seconds only)
        page.wait_for_function("window.states[0].some(x => x.cls.split(' ').includes("
                               "'collecting'))", timeout=30_000)
        page.wait_for_function("document.getElementById('score').textContent !== '—'",
                               timeout=60_000)
        for side in ("a", "b"):
            assert "Done" in page.inner_text(f".side[data-side={side}] .state")
            assert "link: connected" in page.inner_text(f".side[data-side={side}] h3")
        score = float(page.inner_text("#score"))
        assert score > 85 and "apart on average" in page.inner_text("#meaning")
        page.wait_for_timeout(700)
        img = screenshot(page, artifacts_dir, "kscc_two_users", "#skeletons")
        assert color_fraction(img, (0x0B, 0x5C, 0xAD), tol=40) > 2e-3  # user A drawn
        assert color_fraction(img, (0xCF, 0x22, 0x2E), tol=40) > 2e-3  # user B drawn
        diff = screenshot(page, artifacts_dir, "kscc_difference", "#diff")
        assert color_fraction(diff, (0x12, 0x35, 0x5B), tol=30) > 5e-4  # the curve
        # recalibrate user A only: A collects again, B stays calibrated
        _keep_history(page, "#sides .state", "states")
        page.click("button.recal[data-side=a]")
        page.wait_for_function("window.states[0].some(x => !x.text.includes('Done'))",
                               timeout=10_000)
        assert "Done" in page.inner_text(".side[data-side=b] .state")
        page.wait_for_selector(".side[data-side=a] .state.done", timeout=30_000)
        page.click("#stop")
        assert not page.js_errors
    finally:
        for n in nodes:
            n.stop.set()
            n.thread.join(5)
        site.close()
