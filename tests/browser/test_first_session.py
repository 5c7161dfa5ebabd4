"""A clinician's first session on a 1366×768 laptop: what went wrong on the Record page
when she did the obvious wrong things, each fixed and checked in a real browser.

* She reloaded the Record page while a walk was being recorded: the page followed the
  recording but "Who and when" showed the newest subject (not the one being recorded), the
  trial label the session's next walk, and no message said which recording was running.
* She pressed Stop at once: the 0.1 s recording was called "complete — every part
  verified" with nothing saying it was too short for a report (which left it out later
  as "no tracked AnkleLeft positions"); with no frame on any sensor it ended
  "incomplete" while the message went on saying that the server copies it.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import pytest

from tests.browser.conftest import LiveServer, screenshot

pytestmark = pytest.mark.browser


def _wait_complete(server: LiveServer, rec_id: str, timeout_s: float = 90.0) -> None:
    deadline = time.time() + timeout_s
    while server.api(f"/api/storage/recordings/{rec_id}")["state"] != "complete":
        if time.time() > deadline:
            raise TimeoutError(f"recording {rec_id} was not copied in {timeout_s:g} s")
        time.sleep(0.2)


def test_reloaded_record_page_shows_the_running_recordings_subject_and_label(
        page: Any, live_server: LiveServer, artifacts_dir: Path) -> None:
    srv = live_server
    srv.login()
    pid = srv.api("/api/projects", {"name": "Reload mid-walk"})["id"]
    walking = srv.api("/api/subjects", {"project_id": pid, "code": "RLD01"})
    session = srv.api("/api/sessions", {"subject_id": walking["id"], "label": "visit"})
    # a subject added later is the newest: the page used to show it
    srv.api("/api/subjects", {"project_id": pid, "code": "RLD02"})
    rec = srv.api(f"/api/sessions/{session['id']}/recordings",
                  {"label": "walk 2", "streams": [], "image_every": 3})
    try:
        page.set_viewport_size({"width": 1366, "height": 768})
        page.goto(srv.base_url + "/record.html")
        page.wait_for_selector("#state-badge[data-state=recording]")
        page.wait_for_function("document.getElementById('rec-msg').textContent !== ''")
        assert page.input_value("#project") == str(pid)
        assert page.input_value("#subject") == str(walking["id"])
        assert page.input_value("#session") == str(session["id"])
        assert page.input_value("#label") == "walk 2"
        msg = page.inner_text("#rec-msg")
        assert rec["id"] in msg and "walk 2" in msg and "RLD01" in msg and "Stop" in msg
        screenshot(page, artifacts_dir, "first_session_reloaded_mid_walk")
        page.click("#stop")
        page.wait_for_selector("#state-badge[data-state=complete]", timeout=90_000)
        # Stop counts the label on as after a Start on this page
        assert page.input_value("#label") == "walk 3"
        assert not page.js_errors
    finally:
        if srv.api(f"/api/storage/recordings/{rec['id']}")["state"] == "recording":
            srv.api(f"/api/recordings/{rec['id']}/stop", {}, method="POST")
        _wait_complete(srv, rec["id"])


def test_stop_pressed_at_once_says_the_recording_is_too_short_for_a_report(
        page: Any, live_server: LiveServer, artifacts_dir: Path) -> None:
    srv = live_server
    srv.login()
    pid = srv.api("/api/projects", {"name": "Stop at once"})["id"]
    subject = srv.api("/api/subjects", {"project_id": pid, "code": "STP01"})
    session = srv.api("/api/sessions", {"subject_id": subject["id"], "label": "visit"})
    page.set_viewport_size({"width": 1366, "height": 768})
    page.goto(srv.base_url + f"/record.html#subject={subject['id']}")
    page.wait_for_function(f"document.getElementById('session').value === '{session['id']}'")
    page.click("#start")
    page.wait_for_function("!document.getElementById('stop').disabled")
    page.click("#stop")
    # complete with a few frames, or incomplete when no sensor had one yet (a loaded
    # machine): the message said "now copies every sensor's part" beside either badge
    page.wait_for_selector("#state-badge[data-state=complete], "
                           "#state-badge[data-state=incomplete]", timeout=90_000)
    page.wait_for_function("!document.getElementById('rec-msg').textContent.includes('now copies')")
    msg = page.locator("#rec-msg")
    text = msg.inner_text()
    assert "too short for a gait report" in text and "Record the walk again" in text
    assert "lasted only" in text and " s:" in text
    assert "bad" in (msg.get_attribute("class") or "")  # not the green of a good walk
    screenshot(page, artifacts_dir, "first_session_stopped_at_once")
    assert not page.js_errors
