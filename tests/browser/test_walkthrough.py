"""A physiotherapist's first day with the console, and what tripped her up.

Each test is one thing a person met on a walk-through of the whole day (log in, rig,
calibration, live view, a subject's walks, their report) at a laptop's 1024×768 or a
tablet's 768 px, checked by what the page shows: visible text, boxes on the screen,
where the keyboard focus is, and no JavaScript error.
"""

from __future__ import annotations

import re
import urllib.error
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from tests.browser.conftest import (
    LiveServer,
    login,
    record_walk,
    screenshot,
    track_requests,
    wait_settled,
)

pytestmark = pytest.mark.browser

LONG_CODE = "LONGCODE_abcdefghijklmnopqrstuvwxyz01234"  # the longest code allowed (40)


@dataclass
class Walked:
    """A subject with one session holding one complete walk, and a long-coded subject."""

    subject_id: int
    session_id: int
    code: str
    long_id: int


@pytest.fixture(scope="module")
def walked(live_server: LiveServer) -> Iterator[Walked]:
    """One short walk recorded through the API and copied to the server (shared by the
    module: the report tests need a complete recording, and recording takes seconds)."""
    srv = live_server
    srv.login()
    project = srv.api("/api/projects", {"name": "Walk-through"})
    subject = srv.api("/api/subjects", {"project_id": project["id"], "code": "WLK01"})
    session = srv.api("/api/sessions", {"subject_id": subject["id"], "label": "first visit"})
    long = srv.api("/api/subjects", {"project_id": project["id"], "code": LONG_CODE})
    for _ in range(3):  # the simulated walker may be turning: walk again until it has steps
        record_walk(srv, session["id"], timeout_s=60)
        try:
            srv.api(f"/api/reports/subjects/{subject['id']}?format=html", timeout=120)
            break
        except urllib.error.HTTPError as e:
            if e.code not in (400, 422):  # "record a longer walk"
                raise
    else:
        raise RuntimeError("three simulated walks gave no gait result")
    yield Walked(subject["id"], session["id"], subject["code"], long["id"])


def _wait_report(page: Any) -> None:
    """Wait until the Reports page shows a report or says why not (then fail with that)."""
    page.wait_for_function("!document.getElementById('report-section').hidden || "
                           "document.getElementById('subject-msg').classList.contains('error')",
                           timeout=120_000)
    assert page.locator("#report").is_visible(), page.inner_text("#subject-msg")


def _no_js_error(page: Any) -> None:
    assert not page.js_errors, page.js_errors


def _subject_page_leads_to_the_gait_report(
        page: Any, live_server: LiveServer, walked: Walked, artifacts_dir: Path) -> None:
    """After recording, the clinician is on the subject's page: the way to the gait report
    was not there (the Reports page had to be found in the menu and the subject chosen
    again from a list of every project's subjects)."""
    page.set_viewport_size({"width": 1024, "height": 768})
    page.goto(f"{live_server.base_url}/subjects.html#subject={walked.subject_id}")
    page.get_by_role("link", name="Gait report…").click()
    page.wait_for_url("**/reports.html#subject=*")
    # the subject's report is shown without choosing anything again
    _wait_report(page)
    assert walked.code in page.inner_text("#report")
    assert page.evaluate("document.getElementById('subject').selectedOptions[0].textContent"
                         ).startswith(walked.code)
    screenshot(page, artifacts_dir, "walkthrough_report_from_subject")

    # one session's report from the session's own link
    page.goto(f"{live_server.base_url}/subjects.html#subject={walked.subject_id}")
    page.get_by_role("link", name="Gait report of this session").click()
    page.wait_for_url("**/reports.html#subject=*&session=*")
    _wait_report(page)
    assert "first visit" in page.evaluate(
        "document.getElementById('session').selectedOptions[0].textContent")
    _no_js_error(page)


def _pdf_link_without_a_subject_says_what_to_do(
        page: Any, live_server: LiveServer, walked: Walked, artifacts_dir: Path) -> None:
    """Enter on the greyed "Download PDF" link did nothing at all for a keyboard user."""
    page.goto(f"{live_server.base_url}/reports.html")
    page.wait_for_function("document.querySelectorAll('#subject option').length > 1")
    page.focus("#pdf")
    page.keyboard.press("Enter")
    page.wait_for_function("document.getElementById('subject-msg').textContent.length > 0")
    assert "Choose a subject" in page.inner_text("#subject-msg")
    _no_js_error(page)


def _tablet_width_needs_no_sideways_scrolling(
        page: Any, live_server: LiveServer, walked: Walked, artifacts_dir: Path) -> None:
    """On a 768 px tablet the Live page (depth panels beside the 3D view) and the Calibrate
    page (coverage map beside the planning form) ran off the right edge of the screen, and
    the header's "Log out" broke over two lines; the planned poses had no units."""
    page.set_viewport_size({"width": 768, "height": 1024})
    # the 3D view's own content does not size its frame; left out, it spares a loaded
    # machine seconds of software WebGL
    page.route(lambda url: "/viewer" in url and "/api/" not in url,
               lambda route: route.fulfill(status=200, content_type="text/html",
                                           body="<!doctype html><title>3D view</title>"))
    track_requests(page)
    for name in ("live", "calibrate"):
        page.goto(f"{live_server.base_url}/{name}.html")
        wait_settled(page)  # the first answers arrived and drew
        screenshot(page, artifacts_dir, f"walkthrough_tablet_{name}")
        sw, cw = page.evaluate("[document.documentElement.scrollWidth, "
                               "document.documentElement.clientWidth]")
        assert sw <= cw, f"{name}: {sw} px wide on a {cw} px screen"
        one_line = page.evaluate("""() => { const b = document.getElementById('logout');
            return b.clientHeight < 2 * parseFloat(getComputedStyle(b).lineHeight); }""")
        assert one_line, "'Log out' wraps onto two lines"
    heads = page.locator("#planned").locator("xpath=..").locator("thead").inner_text().lower()
    assert "(m)" in heads and "(°)" in heads, heads
    _no_js_error(page)


def _long_subject_code_stays_inside_its_card(
        page: Any, live_server: LiveServer, walked: Walked, artifacts_dir: Path) -> None:
    """A 40-character code ran out of the Subjects table over the subject's details (its
    sessions and size hidden) and pushed the Record page's subject list out of its card."""
    page.set_viewport_size({"width": 1024, "height": 768})
    page.goto(f"{live_server.base_url}/subjects.html#subject={walked.long_id}")
    row = page.locator(f"tr[data-subject='{LONG_CODE}']")
    row.wait_for()
    # measured at once in the page: the list is redrawn as it polls, and a cell taken
    # before a redraw has no box after it
    out = page.evaluate(f"""() => {{
      const card = document.querySelector("section[aria-labelledby=subj-h]")
        .getBoundingClientRect();
      const cells = [...document.querySelectorAll(
        "tr[data-subject='{LONG_CODE}'] :is(th a, td)")];
      return [cells.length, cells.filter((c) => c.getBoundingClientRect().right
                                         > card.right + 0.5).map((c) => c.textContent)];
    }}""")
    assert out[0] >= 4 and out[1] == [], out
    screenshot(page, artifacts_dir, "walkthrough_long_code_subjects")

    page.goto(f"{live_server.base_url}/record.html#subject={walked.long_id}")
    page.wait_for_function(f"document.getElementById('subject').selectedOptions[0]"
                           f"?.textContent === '{LONG_CODE}'")
    card = page.locator("section[aria-labelledby=who-h]").bounding_box()
    box = page.locator("#subject").bounding_box()
    assert box["x"] + box["width"] <= card["x"] + card["width"] + 0.5
    _no_js_error(page)


def _reports_page_before_a_choice(
        page: Any, live_server: LiveServer, walked: Walked, artifacts_dir: Path) -> None:
    """Before a recording was chosen, "One-sided vs two-sided" showed two empty frames
    (Subset A, Subset B); the fields to find a subject or a recording were left at the
    browser's small unstyled size beside full-width lists."""
    page.goto(f"{live_server.base_url}/reports.html")
    page.wait_for_function("document.querySelectorAll('#subject option').length > 1")
    for fs in ("#set-a", "#set-b"):
        assert "Choose a recording" in page.inner_text(fs), page.inner_text(fs)
    for field, cell_of in (("#subject-q", "#subject"), ("#recording-q", "#recording")):
        w = page.locator(field).bounding_box()["width"]
        ref = page.locator(cell_of).bounding_box()["width"]
        # (the recording list now spans the card, its search field half of it, 32 rem:
        # still far from the browser's unstyled ~170 px)
        assert w >= min(0.9 * ref, 400), (field, w, ref)
    _no_js_error(page)


def _subject_click_shows_its_details_on_a_tablet(
        page: Any, live_server: LiveServer, walked: Walked, artifacts_dir: Path) -> None:
    """On a tablet the subject's details are under the list: a click on a subject seemed
    to do nothing (its details appeared out of sight), and the page said to look "on the
    left"."""
    page.set_viewport_size({"width": 768, "height": 1024})
    page.goto(f"{live_server.base_url}/subjects.html#subject={walked.long_id}")
    page.wait_for_function("document.getElementById('detail-h').textContent.includes('LONGCODE')")
    page.evaluate("window.scrollTo(0, 0)")
    page.locator(f"tr[data-subject='{walked.code}'] a").click()
    page.wait_for_function(f"document.getElementById('detail-h').textContent.includes('{walked.code}')")
    # the subject's heading comes into sight
    page.wait_for_function("""() => {
        const r = document.getElementById('detail-h').getBoundingClientRect();
        return r.top >= 0 && r.bottom <= window.innerHeight; }""", timeout=5000)
    assert "on the left" not in page.inner_text("main")
    _no_js_error(page)


def _calibration_wizard_without_a_calibration_says_so(
        page: Any, live_server: LiveServer, walked: Walked, artifacts_dir: Path) -> None:
    """With nothing calibrated the wizard's result showed an empty graph frame, three tables
    of headings over nothing and an empty saved-calibrations table. (The server is shared
    with tests that calibrate: its list is answered empty here.)"""
    page.route("**/api/calibration", lambda route: route.fulfill(
        status=200, body="[]", headers={"Content-Type": "application/json"})
        if route.request.method == "GET" else route.continue_())
    page.goto(f"{live_server.base_url}/calibration-wizard.html")
    page.wait_for_function("document.getElementById('history').innerText"
                           ".includes('No saved calibration yet')")
    assert page.get_by_text("run the simulated one there").is_visible()
    assert not page.locator("#graph").is_visible()
    assert not page.locator("#sensor-table").is_visible()
    _no_js_error(page)


def _real_calibration_has_no_truth_columns(
        page: Any, live_server: LiveServer, walked: Walked, artifacts_dir: Path) -> None:
    """A calibration of a real rig showed two columns of dashes headed "Error vs truth"
    (only a simulated run knows the true poses). The server's answers are a captured
    calibration's here (the shared server may hold a simulated one)."""
    eye = [[1.0, 0, 0, 2.0], [0, 1.0, 0, 1.0], [0, 0, 1.0, 1.0], [0, 0, 0, 1.0]]
    origin = [[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]]
    active = {"version": 1, "created_iso": "2026-11-24T10:00:00Z", "meta": {"source": "captured"},
              "T_world_sensor": {"S1": eye}, "T_world_marker": {"1": origin},
              "sensor_residual_m": {"S1": 0.0008}, "observations": [],
              "edges": [{"sensor": "S1", "marker": 1, "residual_m": 0.0008, "in_chain": True,
                         "distance_m": 2.4}]}
    listed = [{"version": 1, "created": 1795000000, "sensors": ["S1"],
               "max_sensor_residual_mm": 0.8, "rejected": 0}]
    page.route("**/api/calibration", lambda route: route.fulfill(json=listed))
    page.route("**/api/calibration/active", lambda route: route.fulfill(json=active))
    page.goto(f"{live_server.base_url}/calibration-wizard.html")
    page.wait_for_function("document.querySelectorAll('#sensor-table tbody tr').length === 1")
    heads = page.locator("#sensor-table thead").inner_text().lower()
    assert "truth" not in heads, heads
    assert page.locator("#sensor-table tbody td").count() == 4  # sensor, position, residual, ICP
    _no_js_error(page)


def _record_page_refuses_a_bad_image_interval_in_plain_words(
        page: Any, live_server: LiveServer, walked: Walked, artifacts_dir: Path) -> None:
    """An image interval out of range reached the server, whose refusal read
    "image_every: Input should be less than or equal to 1000"; before any recording the
    sensors' table was headings over nothing."""
    page.set_viewport_size({"width": 1024, "height": 768})
    page.goto(f"{live_server.base_url}/record.html#subject={walked.subject_id}")
    page.wait_for_function("document.getElementById('session').value !== ''")
    assert not page.locator("#parts").is_visible()
    # the image interval is offered only with images to record
    assert not page.locator("#every").is_visible()
    page.check("#depth")
    page.fill("#every", "5000")
    page.click("#start")
    page.wait_for_function("document.getElementById('rec-msg').textContent.length > 0")
    msg = page.inner_text("#rec-msg")
    assert "whole number from 1 to 1000" in msg and "image_every" not in msg, msg
    assert page.evaluate("document.activeElement.id") == "every"  # where to fix it
    assert not any(r["state"] == "recording" for r in live_server.api("/api/recordings"))
    _no_js_error(page)


def _code_field_says_which_characters_are_allowed(
        page: Any, live_server: LiveServer, walked: Walked, artifacts_dir: Path) -> None:
    """A code with a space was refused with the browser's bare "Please match the requested
    format." — which format was said nowhere."""
    page.goto(f"{live_server.base_url}/subjects.html")
    field = page.locator("#subject-form input[name=code]")
    field.fill("P 017")
    field.press("Enter")
    said = field.evaluate("e => e.validationMessage")
    assert "no spaces" in said, said
    _no_js_error(page)


def test_dates_are_the_users_own(browser: Any, live_server: LiveServer, walked: Walked) -> None:
    """A clinician in Auckland read recording starts in UTC (eleven hours off her wall
    clock, labelled "(UTC)") on the Rig page, and early in her morning the Subjects page
    offered yesterday's date for a new session (the UTC date); session days read
    "2026-11-24" where she writes "24 Nov 2026"."""
    context = browser.new_context(viewport={"width": 1024, "height": 768},
                                  timezone_id="Pacific/Auckland", locale="en-NZ")
    try:
        page = context.new_page()
        page.set_default_timeout(20000)
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        # 2026-01-15 12:30 UTC is 01:30 on the 16th in Auckland (NZDT, UTC+13)
        page.clock.set_fixed_time("2026-01-15T12:30:00Z")
        login(page, live_server)
        t0 = 1768471200  # 2026-01-15 10:00:00 UTC = 23:00:00 in Auckland
        listed = [{"id": "R20260115-100000-0001", "state": "complete", "t_start": t0,
                   "t_stop": t0 + 5.0, "parts": []}]
        page.route("**/api/recordings", lambda route: route.fulfill(
            status=200, json=listed) if route.request.method == "GET" else route.continue_())
        page.goto(f"{live_server.base_url}/rig.html")
        cell = page.locator("tr[data-recording] td").first
        cell.wait_for()
        assert "11:00:00" in cell.inner_text(), cell.inner_text()  # 11 pm, her time
        assert "UTC" not in page.locator("table").nth(1).locator("thead").inner_text()

        page.goto(f"{live_server.base_url}/subjects.html#subject={walked.subject_id}")
        page.wait_for_function("document.querySelector('#session-form [name=date]').value")
        assert page.input_value("#session-form [name=date]") == "2026-01-16"
        # a session's day as she writes dates ("24 Nov 2026"), not the ISO "2026-11-24"
        heading = page.locator("[data-session] h3").first.inner_text()
        assert re.search(r"\b\d{1,2} [A-Z][a-z]{2} \d{4}\b", heading), heading
        assert not re.search(r"\d{4}-\d{2}-\d{2}", heading), heading
        assert not errors, errors
    finally:
        context.close()


def _refused_export_says_why_and_a_good_one_downloads(
        page: Any, live_server: LiveServer, walked: Walked, artifacts_dir: Path) -> None:
    """An export the server refused was only a failed entry in the browser's download bar,
    the reason (here: the sensor's part is not on the server) never shown."""
    page.goto(f"{live_server.base_url}/subjects.html#subject={walked.subject_id}")
    rec = page.locator(".recording[data-state=complete]").first
    rec.wait_for()
    detail = "sensor S1's part of this recording is not on the server"
    page.route(lambda url: "/skeleton?" in url and "source=S1" in url,
               lambda route: route.fulfill(status=404, json={"detail": detail}))
    rec.get_by_role("link", name="S1 CSV").click()
    refused = rec.get_by_role("status").filter(has_text="not exported")
    refused.wait_for()
    assert detail in refused.inner_text()

    with page.expect_download() as got:
        rec.get_by_role("link", name="fused CSV").click()
    assert got.value.suggested_filename.endswith(".csv"), got.value.suggested_filename
    rec.get_by_role("status").filter(has_text="fused CSV downloaded").wait_for()
    _no_js_error(page)


def _first_tab_skips_the_header(
        page: Any, live_server: LiveServer, walked: Walked, artifacts_dir: Path) -> None:
    """A keyboard user went through the ten header links on every page before reaching
    the page itself; the first Tab now offers to skip them, visibly."""
    page.goto(f"{live_server.base_url}/record.html")
    page.wait_for_function("document.querySelectorAll('#project option').length > 0")
    page.keyboard.press("Tab")
    skip = page.get_by_role("link", name="Skip to the page")
    assert skip.evaluate("e => e === document.activeElement")
    box = skip.bounding_box()
    assert box is not None and box["x"] >= 0 and box["y"] >= 0  # on the screen while focused
    page.keyboard.press("Enter")
    page.keyboard.press("Tab")
    # the next stop is the page's first control, not the header's first link
    assert page.evaluate("!!document.activeElement.closest('main')"), page.evaluate(
        "document.activeElement.outerHTML.slice(0, 120)")
    _no_js_error(page)


def _planning_buttons_say_what_they_did(
        page: Any, live_server: LiveServer, walked: Walked, artifacts_dir: Path) -> None:
    """Apply with the values already in the form, and "Reset to the rig" when nothing was
    moved, changed nothing on the screen: was the click taken?"""
    page.goto(f"{live_server.base_url}/calibrate.html")
    page.wait_for_function("document.getElementById('move-x').value !== ''")
    sensor = page.input_value("#move-id")
    page.click("#move-apply")
    status = page.get_by_role("status").filter(has_text="planned at")
    status.wait_for()
    assert sensor in status.inner_text() and " m" in status.inner_text()
    page.click("#plan-reset")
    page.get_by_role("status").filter(has_text="current sensor poses").wait_for()
    _no_js_error(page)


def _marker_sheet_download_is_confirmed(
        page: Any, live_server: LiveServer, walked: Walked, artifacts_dir: Path) -> None:
    """The marker sheet's Download PDF gave no word on the page, neither during the
    seconds the sheet takes to draw nor after (a download bar the user may not notice,
    and the 100 % print advice above the button)."""
    page.goto(f"{live_server.base_url}/calibration-wizard.html")
    page.fill("#sheet-ids", "1-2")  # (a small sheet renders faster)
    with page.expect_download(timeout=120_000) as got:  # seconds on a loaded machine
        page.click("#sheet-form button[type=submit]")
        # while it is drawn the page says so
        page.get_by_text("Making the marker sheet").wait_for()
    assert got.value.suggested_filename == "markers.pdf"
    page.get_by_text("Marker sheet downloaded").wait_for()
    _no_js_error(page)


def _logging_in_again_returns_to_the_page(
        page: Any, live_server: LiveServer, walked: Walked, artifacts_dir: Path) -> None:
    """A session that ran out sent the clinician to the login page and, once logged in,
    to the Rig page: her subject had to be found again. Another site as the way back is
    not followed."""
    page.goto(f"{live_server.base_url}/subjects.html#subject={walked.subject_id}")
    page.wait_for_function(f"document.getElementById('detail-h').textContent.includes('{walked.code}')")
    page.context.clear_cookies()  # the session is gone
    try:
        page.reload()
    except Exception as exc:  # the page's own poll may get its 401 first and navigate to
        # the login page during the reload (Chromium: "Not attached to an active page");
        # where the page ends up is checked just below
        print(f"reload interrupted by the page's own navigation: {exc}")
    page.wait_for_url("**/index.html?next=*")
    page.fill("#username", "admin")
    page.fill("#password", live_server.password)
    page.keyboard.press("Enter")
    page.wait_for_url(f"**/subjects.html#subject={walked.subject_id}")
    page.wait_for_function(f"document.getElementById('detail-h').textContent.includes('{walked.code}')")

    page.goto(f"{live_server.base_url}/index.html?next=//example.org/rig.html")
    page.fill("#username", "admin")
    page.fill("#password", live_server.password)
    page.keyboard.press("Enter")
    page.wait_for_url(f"{live_server.base_url}/rig.html")
    _no_js_error(page)


def _server_out_of_reach_is_said_in_words(
        page: Any, live_server: LiveServer, walked: Walked, artifacts_dir: Path) -> None:
    """With the server out of reach the Rig page said "Cannot reach the server: Failed to
    fetch" — the browser's words, which say nothing about what to check."""
    page.route("**/api/nodes", lambda route: route.abort("connectionrefused"))
    page.goto(f"{live_server.base_url}/rig.html")
    page.wait_for_function("document.getElementById('summary').textContent.includes('server')")
    said = page.inner_text("#summary")
    assert "Failed to fetch" not in said and "running" in said, said
    _no_js_error(page)


def _run(page: Any, checks: list[Any], *args: Any) -> None:
    """Run checks one after another in one logged-in page (a browser and a login per check
    cost seconds each); each starts at a laptop's size with no route left by the last."""
    for check in checks:
        page.unroute_all(behavior="ignoreErrors")
        page.set_viewport_size({"width": 1024, "height": 768})
        check(page, *args)


def test_from_the_subject_to_the_report_and_exports(page: Any, live_server: LiveServer,
                                                    walked: Walked, artifacts_dir: Path) -> None:
    """After the walks: the subject's report, one session's report, the PDF, the exports."""
    _run(page, [_subject_page_leads_to_the_gait_report,
                _pdf_link_without_a_subject_says_what_to_do,
                _refused_export_says_why_and_a_good_one_downloads],
         live_server, walked, artifacts_dir)


def test_pages_fit_tablets_and_long_codes(page: Any, live_server: LiveServer, walked: Walked,
                                          artifacts_dir: Path) -> None:
    """Layouts at a tablet's width and with the longest subject code."""
    _run(page, [_tablet_width_needs_no_sideways_scrolling,
                _long_subject_code_stays_inside_its_card,
                _subject_click_shows_its_details_on_a_tablet],
         live_server, walked, artifacts_dir)


def test_empty_states_and_plain_messages(page: Any, live_server: LiveServer, walked: Walked,
                                         artifacts_dir: Path) -> None:
    """What a page says before there is anything to show, after a click, and on a mistake."""
    _run(page, [_reports_page_before_a_choice,
                _calibration_wizard_without_a_calibration_says_so,
                _real_calibration_has_no_truth_columns,
                _record_page_refuses_a_bad_image_interval_in_plain_words,
                _code_field_says_which_characters_are_allowed,
                _planning_buttons_say_what_they_did,
                _marker_sheet_download_is_confirmed,
                _server_out_of_reach_is_said_in_words],
         live_server, walked, artifacts_dir)


def test_keyboard_and_logging_in_again(page: Any, live_server: LiveServer, walked: Walked,
                                       artifacts_dir: Path) -> None:
    """The first Tab of a page, and a session that ran out (last: it logs the page out)."""
    _run(page, [_first_tab_skips_the_header, _logging_in_again_returns_to_the_page],
         live_server, walked, artifacts_dir)
