"""Reports page: a clinician ticks two sessions of a subject and sees the change between
them ("Change over sessions")."""

from __future__ import annotations

import time
from typing import Any

import pytest

from tests.browser.conftest import LiveServer, screenshot, wait_copied

pytestmark = pytest.mark.browser

RECORD_S = 8.0


def _record(server: LiveServer, session_ids: list[int], attempts: int = 3) -> None:
    """A short walk of the simulated subject in each session, copied to the server, with
    at least two steps in it (the simulated walker turns at the corridor's ends: a few
    seconds caught at a turn are refused by the analysis, and then recorded again).

    The walks are recorded one straight after the other; their copies to the server and
    their analyses follow (each walk waited for its own before the next started)."""
    from app.nodes.backends.sim import WORLD_CYCLE_S

    todo = list(session_ids)
    reasons: list[str] = []
    for _ in range(attempts):
        # a recording across the simulated walk's restart has no single walk in it
        to_restart = WORLD_CYCLE_S - time.time() % WORLD_CYCLE_S
        if to_restart < RECORD_S * len(todo) + 3.0:
            time.sleep(to_restart + 1.0)
        rids: dict[int, str] = {}
        for sid in todo:
            rids[sid] = server.api(f"/api/sessions/{sid}/recordings", {"label": "walk"})["id"]
            time.sleep(RECORD_S)
            server.api(f"/api/recordings/{rids[sid]}/stop", {})
        for rid in rids.values():
            wait_copied(server, rid, 120)
        again = []
        for sid, rid in rids.items():
            analysis = server.api(f"/api/reports/recordings/{rid}/analysis", timeout=60)
            if not analysis["ok"]:
                again.append(sid)
                reasons.append(analysis["error"])
        if not again:
            return
        todo = again
    raise AssertionError(f"no walk with two steps in {attempts} recordings: {reasons}")


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
