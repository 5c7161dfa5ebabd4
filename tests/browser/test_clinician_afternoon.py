"""A clinician's afternoon with the console: what got in the way of a physiotherapist who
had never seen gaitrig, each fixed and checked in a real browser.

* The calibration wizard's step 2 edge length follows the size printed in step 1, and says
  so when the two differ (a 20 cm sheet captured as 40 cm scales every sensor's distance).
* The project list says what it counts ("1 subject", not "(0)") and counts a subject just
  added.
* The Record page fills the trial label ("walk 1") and counts on after each walk (an
  unlabelled trial was shown by its id everywhere).
* The Reports page's recording list names the trial label and finds a recording by it.
* Deleting a recording without its confirmation says why beside the button pressed (the
  refusal was written above the session's list, off screen for the walks further down).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import pytest

from tests.browser.conftest import LiveServer, screenshot

pytestmark = pytest.mark.browser


def _subject_with_session(server: LiveServer, project: str, code: str) -> tuple[int, int]:
    """A new project, subject ``code`` and a session; (subject id, session id)."""
    pid = server.api("/api/projects", {"name": project})["id"]
    sid = server.api("/api/subjects", {"project_id": pid, "code": code})["id"]
    session = server.api("/api/sessions", {"subject_id": sid, "label": "afternoon"})
    return int(sid), int(session["id"])


def _record(server: LiveServer, session_id: int, label: str, timeout_s: float = 90.0) -> str:
    """A recording under ``label``, stopped once every sensor has frames in it and copied
    to the server; its id. (What these tests look at is its label and its place in the
    lists, not its steps: a fixed 4 s walk each took 12 s of the module.)"""
    rec = server.api(f"/api/sessions/{session_id}/recordings",
                     {"label": label, "streams": [], "image_every": 3})
    deadline = time.time() + timeout_s
    while not all(p["n_frames"] > 0
                  for p in server.api(f"/api/recordings/{rec['id']}")["parts"]):
        if time.time() > deadline:
            raise TimeoutError(f"recording {rec['id']} got no frame from every sensor in "
                               f"{timeout_s:g} s")
        time.sleep(0.1)
    server.api(f"/api/recordings/{rec['id']}/stop", {}, method="POST")
    while server.api(f"/api/storage/recordings/{rec['id']}")["state"] != "complete":
        if time.time() > deadline:
            raise TimeoutError(f"recording {rec['id']} was not copied in {timeout_s:g} s")
        time.sleep(0.3)
    return str(rec["id"])


def test_wizard_capture_edge_length_follows_the_printed_sheet(page: Any,
                                                              artifacts_dir: Path) -> None:
    page.goto(page.url.rsplit("/", 1)[0] + "/calibration-wizard.html")
    # step 2 is filled in from the simulated room's 40 cm markers; step 1 prints 20 cm
    page.wait_for_function("document.getElementById('cap-source').textContent !== ''")
    printed, entered = page.input_value("#sheet-size"), page.input_value("#cap-size")
    assert printed != entered
    note = page.locator("#cap-size-note")
    assert note.is_visible(), "a printed size other than the captured one went unsaid"
    assert f"Not the {printed} cm of the sheet in step 1" in note.inner_text()
    screenshot(page, artifacts_dir, "afternoon_wizard_sizes", "#cap-form")
    # the clinician prints other markers: step 2 takes the same size, nothing to say
    page.fill("#sheet-size", "15")
    assert page.input_value("#cap-size") == "15"
    assert not note.is_visible()
    # a size typed in step 2 is theirs: step 1 no longer changes it, the difference is said
    page.fill("#cap-size", "14.8")
    page.fill("#sheet-size", "16")
    assert page.input_value("#cap-size") == "14.8"
    assert note.is_visible() and "Not the 16 cm" in note.inner_text()


def test_project_list_says_what_it_counts_and_counts_a_new_subject(page: Any) -> None:
    page.goto(page.url.rsplit("/", 1)[0] + "/subjects.html")
    page.wait_for_function("document.querySelectorAll('#project option').length > 0")
    page.fill("#project-form input[name=name]", "Afternoon clinic")
    page.click("#project-form button")
    page.wait_for_function("document.getElementById('project-msg').textContent.includes('created')")
    selected = "document.getElementById('project').selectedOptions[0].textContent"
    # (the message comes before the list is drawn again)
    page.wait_for_function(f"{selected}.startsWith('Afternoon clinic')")
    assert page.evaluate(selected) == "Afternoon clinic (0 subjects)"
    page.fill("#subject-form input[name=code]", "AFT01")
    page.click("#subject-form button[type=submit]")
    page.wait_for_function(f"{selected} === 'Afternoon clinic (1 subject)'", timeout=10000)


def _wait_settled_copy(page: Any, server: LiveServer) -> None:
    """Wait until the Record page's recording is complete or incomplete, and say which
    with the page's reason and message when it is not complete; when it settles on
    neither, say what the page and the server show (the wait once timed out in a
    clean-clone run with nothing to tell why)."""
    try:
        page.wait_for_function("['complete', 'incomplete'].includes(document.getElementById("
                               "'state-badge')?.dataset.state)", timeout=60000)
    except Exception as exc:  # playwright's TimeoutError: say what stood
        rec_id = page.evaluate("(document.getElementById('rec-msg').textContent"
                               ".match(/R[0-9-]+/) || [''])[0]")
        server_view = server.api(f"/api/storage/recordings/{rec_id}") if rec_id else None
        live_view = server.api(f"/api/recordings/{rec_id}") if rec_id else None
        log_tail = (server.data_dir / "demo.log").read_text(errors="replace")[-4000:]
        badge_html = page.evaluate('document.getElementById("rec-state").innerHTML')
        raise AssertionError(
            f"the Record page's recording settled on neither complete nor incomplete: "
            f"badge {badge_html}, "
            f"message {page.inner_text('#rec-msg')!r}, parts {page.inner_text('#parts')!r}, "
            f"server {server_view}, live {live_view}, log tail:\n{log_tail}") from exc
    badge = page.locator("#state-badge")
    assert badge.get_attribute("data-state") == "complete", (
        badge.get_attribute("data-reason"), page.inner_text("#rec-msg"),
        page.inner_text("#parts"))


def test_record_page_fills_the_trial_label_and_counts_on(page: Any, live_server: LiveServer,
                                                         artifacts_dir: Path) -> None:
    sid, session_id = _subject_with_session(live_server, "Afternoon record", "AFT02")
    page.clock.install()  # time flows as usual until the second walk's start (below)
    page.goto(live_server.base_url + f"/record.html#subject={sid}")
    page.wait_for_function(f"document.getElementById('session').value === '{session_id}'")
    # an unlabelled trial is listed by its id on the Subjects and Reports pages
    assert page.input_value("#label") == "walk 1"
    page.wait_for_function("document.getElementById('nodes-summary').textContent.includes(' of ')")
    page.click("#start")
    page.wait_for_selector("#state-badge[data-state=recording]")
    page.wait_for_function("document.getElementById('elapsed').textContent >= '0:02.0'")
    assert page.input_value("#label") == "walk 1", "the running walk's label changed under it"
    page.click("#stop")
    page.wait_for_function("document.getElementById('label').value === 'walk 2'")
    screenshot(page, artifacts_dir, "afternoon_record_next_label")
    _wait_settled_copy(page, live_server)
    recs = live_server.api(f"/api/subjects/{sid}")["sessions"][0]["recordings"]
    assert [r["label"] for r in recs] == ["walk 1"]
    # a label of the clinician's own that ends in a number counts on too
    page.fill("#label", "10 m walk fast 3")
    # The new walk's own time is shown with its "recording" state: the last walk's
    # 0:02.1 stayed on screen until the page's next 100 ms tick, and a Stop pressed on it
    # ended the new walk before its start time, without a frame. The page's timers are
    # held still here (from 1 s on: the clock cannot be moved back to where it already
    # is), so no tick can set the time right before it is read.
    page.clock.pause_at(page.evaluate("Date.now()") / 1000 + 1.0)  # (seconds)
    page.click("#start")
    page.wait_for_selector("#state-badge[data-state=recording]")
    shown = page.inner_text("#elapsed")
    assert shown < "0:01.0", f"the last walk's time ({shown}) shown for the new one"
    page.clock.resume()
    page.wait_for_function("document.getElementById('elapsed').textContent >= '0:01.0'")
    page.click("#stop")
    page.wait_for_function("document.getElementById('label').value === '10 m walk fast 4'")
    _wait_settled_copy(page, live_server)


def test_reports_recording_list_names_and_finds_the_trial_label(page: Any,
                                                                live_server: LiveServer) -> None:
    _, session_id = _subject_with_session(live_server, "Afternoon reports", "AFT03")
    rid = _record(live_server, session_id, "barefoot walk 7")
    page.goto(live_server.base_url + "/reports.html")
    page.wait_for_function(f"[...document.querySelectorAll('#recording option')]"
                           f".some(o => o.value === '{rid}')")
    text = page.evaluate(f"document.querySelector('#recording option[value=\"{rid}\"]')"
                         ".textContent")
    assert text.startswith("barefoot walk 7 — AFT03"), text
    assert rid in text
    # found by the label the clinician gave it
    page.fill("#recording-q", "barefoot walk")
    page.wait_for_function("document.querySelectorAll('#recording option').length === 2")
    assert page.evaluate("document.querySelectorAll('#recording option')[1].value") == rid


def test_recording_delete_refusal_is_said_beside_the_button(page: Any, live_server: LiveServer,
                                                            artifacts_dir: Path) -> None:
    sid, session_id = _subject_with_session(live_server, "Afternoon delete", "AFT04")
    first = _record(live_server, session_id, "walk 1")
    last = _record(live_server, session_id, "walk 2")
    page.set_viewport_size({"width": 1024, "height": 768})
    page.goto(live_server.base_url + f"/subjects.html#subject={sid}")
    box = page.locator(f".recording[data-recording='{last}']")
    box.wait_for()
    box.get_by_role("button", name="Delete recording").click()
    alert = box.get_by_role("alert")
    alert.wait_for()
    assert "type AFT04" in alert.inner_text()
    assert alert.is_visible()
    # focus goes to the box to type in
    assert page.evaluate("document.activeElement.getAttribute('aria-label')") == \
        f"type AFT04 to delete {last}"
    screenshot(page, artifacts_dir, "afternoon_delete_refused")
    assert len(live_server.api(f"/api/subjects/{sid}")["sessions"][0]["recordings"]) == 2
    box.get_by_role("textbox").fill("AFT04")
    box.get_by_role("button", name="Delete recording").click()
    page.wait_for_function("document.getElementById('session-msg').textContent"
                           ".includes('walk 2 (')")
    page.locator(f".recording[data-recording='{last}']").wait_for(state="detached")
    recs = live_server.api(f"/api/subjects/{sid}")["sessions"][0]["recordings"]
    assert [r["id"] for r in recs] == [first]


def test_reports_session_ticks_take_their_own_row(page: Any, live_server: LiveServer,
                                                  artifacts_dir: Path) -> None:
    sid, _ = _subject_with_session(live_server, "Afternoon layout", "AFT05")
    live_server.api("/api/sessions", {"subject_id": sid, "label": "6 weeks"})
    page.goto(live_server.base_url + "/reports.html")
    page.wait_for_function(f"[...document.querySelectorAll('#subject option')]"
                           f".some(o => o.value === '{sid}')")
    page.select_option("#subject", str(sid))
    pick = page.locator("#sessions-pick")
    pick.wait_for()
    screenshot(page, artifacts_dir, "afternoon_reports_sessions", "#subject-form")
    form = page.locator("#subject-form").bounding_box()
    find = page.locator("#subject-q").bounding_box()
    subject = page.locator("#subject").bounding_box()
    box = pick.bounding_box()
    assert form and find and subject and box
    # beside the fields, the ticks' height pushed them down under an empty band
    assert find["y"] - form["y"] < 60, f"Find subject code {find['y'] - form['y']:.0f} px down"
    assert box["y"] >= subject["y"] + subject["height"], "the session ticks sit beside the fields"
    assert box["width"] > 0.9 * form["width"]


def test_backup_reminder_says_who_and_links_the_guide(page: Any) -> None:
    # the browser tests' server was never backed up: its administrator is reminded
    notice = page.locator("#backup-notice")
    notice.wait_for()
    assert "never been backed up" in notice.inner_text()
    # a command and a file name alone told a clinician neither who does it nor why
    assert "Ask whoever looks after the server" in notice.inner_text()
    link = notice.get_by_role("link", name="why backups matter")
    assert link.get_attribute("href") == "/help.html#backups"
    link.click()
    page.wait_for_url("**/help.html#backups")
    assert page.locator("#backups").is_visible()


def test_bumped_tripod_check_before_any_calibration_says_what_to_do(page: Any,
                                                                     live_server: LiveServer
                                                                     ) -> None:
    # a lab that never calibrated (other tests of this server may have saved one)
    page.route("**/api/calibration", lambda route: route.fulfill(
        status=200, body="[]", headers={"Content-Type": "application/json"}))
    page.goto(live_server.base_url + "/calibrate.html")
    state = page.locator("#bump-state")
    page.wait_for_function("document.getElementById('bump-state').textContent"
                           ".startsWith('No calibration yet')")
    # the button was offered and answered "no calibration yet: calibrate the rig first…"
    assert page.locator("#bump-check").is_disabled()
    link = state.get_by_role("link", name="spatial calibration wizard")
    assert link.get_attribute("href") == "/calibration-wizard.html"
    assert not page.js_errors
