"""Record and Subjects pages in a real browser: a recording is filed under a new subject's
session, started and stopped from the Record page, transferred (progress bars), and the
Subjects page shows it complete with its export links; deletion needs the code."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from tests.browser.conftest import LiveServer, color_fraction, screenshot

pytestmark = pytest.mark.browser


def test_record_stop_transfer_and_subjects_page(page: Any, live_server: LiveServer,
                                                artifacts_dir: Path) -> None:
    page.goto(live_server.base_url + "/record.html")
    page.wait_for_function("document.querySelectorAll('#project option').length > 0")
    page.fill("#new-subject input[name=code]", "BRW01")
    page.click("#new-subject button")
    page.wait_for_function("document.getElementById('who-msg').textContent.includes('BRW01')")
    page.fill("#new-session input[name=label]", "browser visit")
    page.click("#new-session button")
    page.wait_for_function("document.getElementById('session').value !== ''")
    page.wait_for_function("document.getElementById('nodes-summary').textContent.includes(' of ')")
    page.fill("#label", "walk 1")
    page.click("#start")
    page.wait_for_selector("#state-badge[data-state=recording]")
    page.wait_for_function("document.getElementById('elapsed').textContent >= '0:01.5'")
    img_rec = screenshot(page, artifacts_dir, "record_running")
    n_parts = page.locator("#parts tr[data-node]").count()
    assert n_parts == live_server.n_nodes
    # the session list counts the new recording
    page.wait_for_function(
        "document.getElementById('session').selectedOptions[0].textContent"
        ".includes('(1 recording)')")
    page.focus("#stop")
    page.keyboard.press("Enter")  # as a keyboard user: focus must not drop to the page
    # (onto the recording's sensors: the message is a live region, not focused as well)
    page.wait_for_function("document.activeElement.id === 'parts-table'")
    page.wait_for_selector("#state-badge[data-state=complete]", timeout=60_000)
    # the message no longer says the copy is under way once the badge says complete
    page.wait_for_function("document.getElementById('rec-msg').textContent.includes('copied')")
    assert page.locator("#parts tr[data-state=complete]").count() == n_parts
    img_done = screenshot(page, artifacts_dir, "record_complete")
    # the "complete" badges are drawn in the OK green
    assert color_fraction(img_done, (0x1A, 0x7F, 0x37), tol=30) > color_fraction(
        img_rec, (0x1A, 0x7F, 0x37), tol=30)
    elapsed = page.inner_text("#elapsed")
    assert elapsed >= "0:01.5"

    page.click("#open-subject")
    page.wait_for_selector(".recording[data-state=complete]")
    assert "Subject BRW01" in page.inner_text("#detail-h")
    rec = page.locator(".recording[data-state=complete]").first
    assert rec.locator(".part[data-node] .badge.st-complete").count() == n_parts
    assert rec.locator("a", has_text="fused C3D").count() == 1
    screenshot(page, artifacts_dir, "subjects_complete")
    # a wrong confirmation is refused, the right one deletes
    page.click("details.danger-zone summary")
    page.fill("#delete-form input[name=confirm]", "BRW0")
    page.click("#delete-form button")
    page.wait_for_function("document.getElementById('delete-msg').textContent.includes('BRW01')")
    assert "type 'BRW01'" in page.inner_text("#delete-msg")
    page.fill("#delete-form input[name=confirm]", "BRW01")
    page.click("#delete-form button")
    page.wait_for_function("document.getElementById('delete-msg').textContent.includes('deleted')")
    page.wait_for_function("!document.querySelector('tr[data-subject=BRW01]')")
    assert not page.js_errors


def _json_route(body: Any) -> Any:
    def handle(route: Any) -> None:
        route.fulfill(status=200, content_type="application/json", body=json.dumps(body))
    return handle


def test_record_page_says_what_happened_to_each_part(page: Any, live_server: LiveServer,
                                                    artifacts_dir: Path) -> None:
    """What the server knows beyond the part states is on the page: the reason of a part
    that ended complete (as a note), frames recorded without images, a sensor that joined
    after the start, and a recording list the server could not save. The server's answers
    are given to the page (no real node can be made to drop or fill a disk here); the
    server side of ``images_skipped`` and ``not_in_recording`` is tested on the Subjects
    page against real recordings."""
    rid, t0 = "R20260101-100000-abcd", 1767261600.0
    part = {"n_frames": 90, "bytes_total": 2 ** 20, "bytes_done": 2 ** 20, "progress": 1.0,
            "manifest_sha256": None, "attempts": 1}
    filed = {"id": rid, "session_id": 1, "label": "walk", "notes": "", "state": "incomplete",
             "reason": "S3 is incomplete", "t_start": t0, "t_stop": t0 + 5.0,
             "duration_s": 5.0, "streams": ["depth"], "created_at": "2026-01-01T10:00:00",
             "references": [], "bytes_on_server": 3 * 2 ** 20,
             "session": {"id": 1, "date": "2026-01-01", "label": "visit"},
             "subject": {"id": 1, "code": "FAKE1", "project_id": 1},
             "parts": [{**part, "node_id": "S1", "state": "complete", "reason": None},
                       {**part, "node_id": "S2", "state": "complete", "reason": None},
                       {**part, "node_id": "S3", "state": "incomplete",
                        "reason": "node stopped while recording; data recovered up to the "
                                  "last intact frame"}]}
    kept = "node S1 disconnected at 10:00:02 UTC during the recording; the node kept recording"
    live = {"id": rid, "state": "incomplete", "t_start": t0, "t_stop": t0 + 5.0,
            "save_error": "the server could not save its recording list ([Errno 28] No "
                          "space left on device); a server restart now would lose the latest "
                          "states",
            "not_in_recording": [{"node_id": "S7", "connected_at": t0 + 2.0,
                                  "reason": "connected at 10:00:02 UTC, after the start"}],
            "parts": [{"node_id": "S1", "state": "complete", "reason": kept,
                       "images_skipped": 0},
                      {"node_id": "S2", "state": "complete", "images_skipped": 12,
                       "reason": "transfer failed (timed out); retry when the node is online"},
                      {"node_id": "S3", "state": "incomplete", "reason": None,
                       "images_skipped": None}]}
    listed = {**live, "state": "recording"}  # the page follows a recording that runs
    page.route("**/api/recordings", _json_route([listed]))
    page.route(f"**/api/recordings/{rid}", _json_route(live))
    page.route(f"**/api/storage/recordings/{rid}", _json_route(filed))
    page.goto(live_server.base_url + "/record.html")
    page.wait_for_selector("#parts tr[data-node=S3]")
    s1, s2 = page.locator("#parts tr[data-node=S1]"), page.locator("#parts tr[data-node=S2]")
    # the complete part's reason is a note, not an error
    assert "the node kept recording" in s1.inner_text()
    assert s1.locator(".note[data-kind=reason]").count() == 1
    assert s1.locator(".reason").count() == 0
    assert "12 frames recorded without their images" in s2.inner_text()
    assert "transfer failed" not in s2.inner_text()  # it succeeded since
    assert page.locator("#parts tr[data-node=S3] .reason").inner_text().startswith(
        "node stopped while recording")
    banner = page.locator("#save-error")
    assert banner.is_visible() and "No space left on device" in banner.inner_text()
    assert "after the start" in page.inner_text("#left-out li[data-node=S7]")
    screenshot(page, artifacts_dir, "record_part_notes")
    assert not page.js_errors


def test_a_poll_answered_during_the_stop_leaves_stop_disabled(page: Any,
                                                              live_server: LiveServer) -> None:
    """Stop is pressed while a poll of the running recording is still out: its answer
    ("recording"), arriving before the stop's, must not enable Stop again (a second press
    said "not recording" under the stop's own message). The server's answers are held and
    given by the test, so the order is the one that went wrong."""
    rid, t0 = "R20260101-110000-beef", 1767265200.0
    part = {"n_frames": 30, "bytes_total": 0, "bytes_done": 0, "progress": 0.0,
            "manifest_sha256": None, "attempts": 0, "reason": None}
    filed = {"id": rid, "session_id": 1, "label": "walk", "notes": "", "state": "recording",
             "reason": None, "t_start": t0, "t_stop": None, "duration_s": None,
             "streams": [], "created_at": "2026-01-01T11:00:00", "references": [],
             "bytes_on_server": 0, "session": {"id": 1, "date": "2026-01-01", "label": "visit"},
             "subject": {"id": 1, "code": "FAKE2", "project_id": 1},
             "parts": [{**part, "node_id": "S1", "state": "recording"}]}
    done = {**filed, "state": "complete", "t_stop": t0 + 6.0, "duration_s": 6.0,
            "parts": [{**part, "node_id": "S1", "state": "complete", "progress": 1.0}]}
    live = {"id": rid, "state": "recording", "t_start": t0, "t_stop": None,
            "parts": [{"node_id": "S1", "state": "recording"}]}
    held: list[Any] = []
    stops: list[Any] = []
    mode = {"storage": "answer"}  # "answer" (running), "hold", then "done"

    def storage(route: Any) -> None:
        if mode["storage"] == "hold":
            held.append(route)
            return
        route.fulfill(status=200, content_type="application/json",
                      body=json.dumps(done if mode["storage"] == "done" else filed))

    def wait_until(cond: Any) -> None:
        for _ in range(400):  # (up to 20 s: answers the page asks for every 0.5 s)
            if cond():
                return
            page.wait_for_timeout(50)
        raise AssertionError("the page did not ask")

    page.route("**/api/recordings", _json_route([live]))
    page.route(f"**/api/recordings/{rid}", _json_route(live))
    page.route(f"**/api/recordings/{rid}/stop", lambda route: stops.append(route))
    page.route(f"**/api/storage/recordings/{rid}", storage)
    page.goto(live_server.base_url + "/record.html")
    page.wait_for_selector("#state-badge[data-state=recording]")
    page.wait_for_function("!document.getElementById('stop').disabled")
    # from here on, every time Stop is enabled is seen
    page.evaluate("""() => { const stop = document.getElementById('stop');
        window.stopEnabledAgain = false;
        new MutationObserver(() => { if (!stop.disabled) window.stopEnabledAgain = true; })
          .observe(stop, { attributes: true }); }""")
    mode["storage"] = "hold"
    wait_until(lambda: held)  # a poll is out
    page.click("#stop")
    wait_until(lambda: stops)  # the stop is out too
    mode["storage"] = "done"
    held.pop().fulfill(status=200, content_type="application/json", body=json.dumps(filed))
    # the page draws that answer (or drops it) before the stop's answer comes
    page.wait_for_function(f"""performance.getEntriesByType('resource').some(
        (e) => e.name.endsWith('/api/storage/recordings/{rid}') && e.responseEnd > 0
               && e.startTime > performance.now() - 30000)""")
    page.wait_for_timeout(300)
    assert page.evaluate("window.stopEnabledAgain") is False
    stops.pop().fulfill(status=200, content_type="application/json",
                        body=json.dumps({**live, "state": "on_nodes"}))
    page.wait_for_selector("#state-badge[data-state=complete]")
    assert page.evaluate("window.stopEnabledAgain") is False
    assert page.locator("#stop").is_disabled()
    assert "stopped" in page.inner_text("#rec-msg") or "copied" in page.inner_text("#rec-msg")
    assert not page.js_errors
