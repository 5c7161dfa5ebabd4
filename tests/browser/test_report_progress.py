"""Reports page: a clinician ticks two sessions of a subject and sees the change between
them ("Change over sessions")."""

from __future__ import annotations

from typing import Any

import pytest

from tests.browser.conftest import LiveServer, record_walk, screenshot, wait_copied

pytestmark = pytest.mark.browser


def _record(server: LiveServer, session_ids: list[int]) -> None:
    """A walk of the simulated subject in each session (:func:`record_walk`: stopped once
    it holds a stretch of straight walking, so it has steps), one straight after the
    other, then their copies to the server waited for and each one's analysis checked."""
    rids = [record_walk(server, sid, wait=False) for sid in session_ids]
    for rid in rids:
        wait_copied(server, rid, 120)
    for rid in rids:
        analysis = server.api(f"/api/reports/recordings/{rid}/analysis", timeout=60)
        assert analysis["ok"], analysis["error"]


def test_pick_two_sessions_and_see_the_change(page: Any, live_server: LiveServer,
                                              artifacts_dir: Any) -> None:
    p = live_server.api("/api/projects", {"name": "Therapy follow-up"})
    s = live_server.api("/api/subjects", {"project_id": p["id"], "code": "PRG01"})
    first = live_server.api("/api/sessions", {"subject_id": s["id"], "date": "2026-10-01",
                                              "label": "baseline"})
    live_server.api("/api/sessions", {"subject_id": s["id"], "date": "2026-10-15",
                                     "label": "cancelled"})
    last = live_server.api("/api/sessions", {"subject_id": s["id"], "date": "2026-11-12",
                                             "label": "after therapy"})
    _record(live_server, [first["id"], last["id"]])

    page.goto(f"{live_server.base_url}/reports.html")
    page.wait_for_function(f"[...document.querySelectorAll('#subject option')]"
                           f".some(o => o.value === '{s['id']}')")
    page.select_option("#subject", str(s["id"]))
    pick = page.locator("#sessions-pick")
    pick.wait_for(state="visible")
    boxes = pick.locator("input[type=checkbox]")
    assert boxes.count() == 3
    assert all(boxes.nth(k).is_checked() for k in range(3))  # all by default
    # labelled controls: each checkbox is found by its session's date and label
    page.get_by_label("cancelled").uncheck()
    with page.expect_request(lambda r: "/api/reports/subjects/" in r.url) as req:
        page.click("#show")
    assert f"sessions={first['id']}%2C{last['id']}" in req.value.url, req.value.url
    # the page says "Report below." or why there is none (said in the failure)
    page.wait_for_function("!document.getElementById('subject-msg').textContent"
                           ".startsWith('Analysing')", timeout=120000)
    said = page.inner_text("#subject-msg")
    assert said == "Report below.", said
    assert page.locator("#report table[aria-label='changes between sessions']").count() == 1, \
        page.inner_text("#report")
    report = page.inner_text("#report")
    assert "Change over sessions" in report and "all sessions pooled" in report
    changes = page.inner_text("#report table[aria-label='changes between sessions']")
    assert "12 Nov 2026 after therapy" in changes and "Walking speed" in changes
    # one trial per session: the trial-to-trial test cannot be made, and says so
    assert "too few trials to tell" in changes
    assert "cancelled" not in page.inner_text("#report table[aria-label='sessions']")
    screenshot(page, artifacts_dir, "reports_change_over_sessions",
               "#report table[aria-label='changes between sessions']")
    # one session chosen in "Session": the checkboxes go, the report is of that session
    page.select_option("#session", str(last["id"]))
    assert pick.is_hidden()
    # none ticked: a message, no request
    page.select_option("#session", "")
    for k in range(3):
        boxes.nth(k).uncheck()
    page.click("#show")
    page.wait_for_function(
        "document.getElementById('subject-msg').textContent.includes('Tick at least one')")
    assert not page.js_errors
