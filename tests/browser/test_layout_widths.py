"""Three layout defects a clinician saw (the review after the 1366 px walk-through), each
measured as she would see it, at the widths she works at:

* Reports page: the Recording list cut an entry of 125 characters ("walk 3 self-selected
  speed — KNEE-OA-0117, six weeks after knee replacement, Nov 28, 2026 — 6 sensors —
  R2026…") even at 1920 px: the page kept to 1100 px, the list to 1018 px of it.
* Subjects page: with a long code listed, the count headings broke at their soft hyphens
  ("Ses-sions", "Re-cord-ings") at 1400 px: the list's column was a fixed 400 px, narrower
  than the list with a code of 8em (measured with the codes' own check,
  tests/browser/test_subjects_page.py::test_subject_codes_stay_on_one_line).
* Record page: "Who and when" was a column of 360-420 px at every width from 900 to
  1920 px; a session's list ("Nov 28, 2026 (1 recording) — six weeks after knee
  replacement") was cut at every one of them, with no way to read the rest.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from tests.browser.conftest import LiveServer, screenshot, short_recording
from tests.browser.test_clinician_1366 import CUT_SELECTS_JS, UNREAD_SELECTS_JS

pytestmark = pytest.mark.browser

CODE = "KNEE-OA-0117"
LABEL = "six weeks after knee replacement"


def _subject(server: LiveServer, project: str, code: str = CODE) -> tuple[int, int]:
    """A new project with subject ``code`` and its session :data:`LABEL`; their ids."""
    pid = server.api("/api/projects", {"name": project})["id"]
    sid = server.api("/api/subjects", {"project_id": pid, "code": code})["id"]
    return int(sid), int(server.api("/api/sessions", {"subject_id": sid, "label": LABEL})["id"])


def _no_sideways_scroll(page: Any) -> bool:
    return bool(page.evaluate("document.documentElement.scrollWidth <= innerWidth"))


def test_reports_recording_list_holds_a_long_entry(page: Any, live_server: LiveServer,
                                                   artifacts_dir: Path) -> None:
    """At 1366 and 1920 px the Recording list shows its 125-character entry whole (the
    page takes the screen's room up to 1500 px), not only the line written under it; the
    option's tooltip has it too, and the page's prose keeps to lines of a readable length."""
    sid, session = _subject(live_server, "Long recording entries")
    rid = short_recording(live_server, session, "walk 3 self-selected speed")
    page.goto(f"{live_server.base_url}/reports.html#subject={sid}")
    page.wait_for_function(f"[...document.querySelectorAll('#recording option')]"
                           f".some(o => o.value === '{rid}')")
    page.select_option("#recording", rid)
    option = "document.getElementById('recording').selectedOptions[0]"
    text = page.evaluate(f"{option}.textContent")
    assert text.startswith(f"walk 3 self-selected speed — {CODE}, {LABEL}, "), text
    assert len(text) >= 120, text
    assert page.evaluate(f"{option}.title") == text
    for w in (1366, 1920):
        page.set_viewport_size({"width": w, "height": 900})
        page.wait_for_timeout(100)  # (the page's resize handler)
        screenshot(page, artifacts_dir, f"reports_long_recording_{w}",
                   "section[aria-labelledby=cmp-h]")
        assert page.evaluate(CUT_SELECTS_JS, "#recording") == [], w
        assert page.locator("#recording-whole").is_hidden(), w
        assert _no_sideways_scroll(page), w
        widest = page.evaluate("Math.max(...[...document.querySelectorAll('main > p, main "
                               ".card > p')].map(p => p.getBoundingClientRect().width))")
        assert widest <= 1200.5, (w, widest)
    # narrower, the list cannot hold it: the whole text is written under it (as before)
    page.set_viewport_size({"width": 900, "height": 900})
    page.wait_for_function("!document.getElementById('recording-whole').hidden")
    assert page.evaluate(UNREAD_SELECTS_JS) == []



def test_record_who_and_when_is_read_at_every_width(page: Any, live_server: LiveServer,
                                                    artifacts_dir: Path) -> None:
    """From 320 to 1920 px the Record page's subject and session lists are read: whole in
    the list from 1366 px (the column is half the row, the page up to 1500 px wide), whole
    under it where the list is narrower; the column grows with the screen, nothing in it
    runs off its card, and the page never scrolls sideways."""
    sid, session = _subject(live_server, "Record widths", "KNEE-OA-0117-RIGHT-SIDE")
    page.goto(f"{live_server.base_url}/record.html#subject={sid}")
    page.wait_for_function(f"document.getElementById('session').value === '{session}'")
    who = "section[aria-labelledby=who-h]"
    assert page.evaluate("document.getElementById('session').selectedOptions[0].textContent"
                         ).endswith(f"(0 recordings) — {LABEL}")
    width = {}
    for w in (320, 600, 899, 901, 1024, 1366, 1920):
        page.set_viewport_size({"width": w, "height": 900})
        page.wait_for_timeout(100)  # (the page's resize handler)
        screenshot(page, artifacts_dir, f"record_who_{w}", who)
        if w in (1024, 1920):
            screenshot(page, artifacts_dir, f"record_page_{w}")
        assert _no_sideways_scroll(page), w
        assert page.evaluate(UNREAD_SELECTS_JS, f"{who} select") == [], w
        if w >= 1366:
            assert page.evaluate(CUT_SELECTS_JS, f"{who} select") == [], w
        out = page.evaluate("""(css) => { const card = document.querySelector(css)
            .getBoundingClientRect(); return [...document.querySelectorAll(css + " *")]
            .filter((e) => e.getClientRects().length && e.getBoundingClientRect().right
              > card.right + 0.5).map((e) => e.tagName + " " + e.textContent.trim()); }""", who)
        assert out == [], (w, out)
        width[w] = page.locator(who).bounding_box()["width"]
    assert width[1024] < width[1366] < width[1920], width
    assert not page.js_errors, page.js_errors
