"""A clinician's walk-through at a 1366×768 laptop, and what got in her way.

* Reports page: the only subject had to be chosen from a list of one, and "Show report"
  with none chosen gave the browser's "Please select an item" bubble over the button.
* Reports page: "Side A / Side B" of the one- vs two-sided comparison did not say which
  side of the walkway was which.
* Record page: the session list cut its text ("(2 recording…").
* Reports page: the recording list cut its text ("… Nov 28, 2026 first vis"), the subject
  list too ("LAP05 — 1 session, 3 reco").
* Dates were written three ways ("Nov 28, 2026", "11/28/2026, 10:07:14 AM", "2026-11-28").
* Live page: the caption said "body tracked (magenta)" under a picture with no body (the
  caption followed the stream's statistics, not the frame shown).
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable, Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest

from tests.browser.conftest import LiveServer, login, record_walk, screenshot, short_recording

pytestmark = pytest.mark.browser

LAPTOP = {"width": 1366, "height": 768}

#: The measuring both list checks share: ``shown(css)``, the visible lists matching ``css``
#: with an entry chosen; ``cut(s)``, whether list ``s`` shows its chosen entry cut (wider
#: than the list's box less its padding and its arrow, about 20 px); ``said(s)``, what a
#: failed check reports.
_SELECTS_JS = """
  const ctx = document.createElement("canvas").getContext("2d");
  const shown = (css) => [...document.querySelectorAll(css)]
    .filter((s) => s.getClientRects().length > 0 && s.selectedOptions.length);
  const cut = (s) => {
    const cs = getComputedStyle(s); ctx.font = cs.font;
    const room = s.clientWidth - parseFloat(cs.paddingLeft) - parseFloat(cs.paddingRight) - 20;
    return ctx.measureText(s.selectedOptions[0].textContent).width > room + 4;
  };
  const said = (s) => s.id + ": " + s.selectedOptions[0].textContent;"""

#: The chosen option of each visible select (of those matching the CSS selector given, by
#: default all) whose text does not fit it: what a person reads cut off.
CUT_SELECTS_JS = """(css) => {""" + _SELECTS_JS + """
  return shown(css || "select").filter(cut).map(said);
}"""


def _subject(server: LiveServer, project: str, code: str) -> tuple[int, int]:
    """A new project with subject ``code`` and one session; (subject id, session id)."""
    pid = server.api("/api/projects", {"name": project})["id"]
    sid = server.api("/api/subjects", {"project_id": pid, "code": code})["id"]
    session = server.api("/api/sessions", {"subject_id": sid, "label": "first visit"})
    return int(sid), int(session["id"])


@pytest.fixture
def laptop(page: Any) -> Iterator[Any]:
    page.set_viewport_size(LAPTOP)
    yield page
    assert not page.js_errors, page.js_errors


def test_reports_page_chooses_the_only_subject_and_says_when_none_is_chosen(
        laptop: Any, live_server: LiveServer, artifacts_dir: Path) -> None:
    page = laptop
    sid, _ = _subject(live_server, "Laptop one subject", "LAP01")
    one = live_server.api(f"/api/subjects/{sid}")
    # a clinic with one subject: the list answers only it
    page.route("**/api/subjects?sort=*", lambda route: route.fulfill(
        status=200, json=[one], headers={"X-Total-Count": "1"}))
    page.goto(f"{live_server.base_url}/reports.html")
    page.wait_for_function(f"document.getElementById('subject').value === '{sid}'")
    # its sessions are offered as for a subject chosen by hand
    page.wait_for_function("[...document.querySelectorAll('#session option')]"
                           ".some(o => o.textContent.includes('first visit'))")
    screenshot(page, artifacts_dir, "laptop_reports_one_subject", "#subject-form")

    # several subjects: none is chosen for her, and "Show report" says so on the page
    page.unroute("**/api/subjects?sort=*")
    _subject(live_server, "Laptop two subjects", "LAP02")
    page.goto(f"{live_server.base_url}/reports.html")
    page.wait_for_function("document.querySelectorAll('#subject option').length > 2")
    assert page.input_value("#subject") == ""
    page.get_by_role("button", name="Show report").click()
    msg = page.locator("#subject-msg")
    page.wait_for_function("document.getElementById('subject-msg').textContent.length > 0")
    assert "Choose a subject" in msg.inner_text()
    assert "error" in (msg.get_attribute("class") or "")
    # the list to choose from has the focus (no browser bubble over the button)
    assert page.evaluate("document.activeElement.id") == "subject"
    screenshot(page, artifacts_dir, "laptop_reports_no_subject_chosen")

    # a link's subject (#subject=ID) is the one chosen, with two or more on the server
    page.goto("about:blank")
    page.goto(f"{live_server.base_url}/reports.html#subject={sid}")
    page.wait_for_function(f"document.getElementById('subject').value === '{sid}'")


def test_record_page_session_list_is_read_whole(laptop: Any, live_server: LiveServer,
                                                artifacts_dir: Path) -> None:
    page = laptop
    sid, session_id = _subject(live_server, "Laptop record", "LAP03")
    real = live_server.api(f"/api/sessions?subject_id={sid}")
    # the session as the clinician had it: two walks recorded
    shown = [{**s, "n_recordings": 2} for s in real]
    page.route(f"**/api/sessions?subject_id={sid}", lambda route: route.fulfill(
        status=200, json=shown))
    page.goto(f"{live_server.base_url}/record.html#subject={sid}")
    page.wait_for_function(f"document.getElementById('subject').value === '{sid}'")
    page.wait_for_function(f"document.getElementById('session').value === '{session_id}'")
    text = page.evaluate("document.getElementById('session').selectedOptions[0].textContent")
    assert "2 recordings" in text and "first visit" in text, text
    cut = page.evaluate(CUT_SELECTS_JS)
    screenshot(page, artifacts_dir, "laptop_record_session", "section[aria-labelledby=who-h]")
    screenshot(page, artifacts_dir, "laptop_record_page")
    assert cut == [], cut
    # read whole in the lists: not written again under them (the arrow's width was
    # guessed, and the session was written twice)
    assert page.locator("#session-whole").is_hidden()
    assert page.locator("#subject-whole").is_hidden()
    # a label too long for any width is cut at its end: the day and the count stay read
    assert text.index("2 recordings") < text.index("first visit"), text
    assert page.evaluate("document.documentElement.scrollWidth <= innerWidth")


def test_reports_comparison_names_the_sides_of_the_walkway(
        laptop: Any, live_server: LiveServer, artifacts_dir: Path) -> None:
    page = laptop
    _, session_id = _subject(live_server, "Laptop sides", "LAP04")
    # with steps for the report of one side's sensors read below (a 3.5 s stretch gave
    # that report too few steps now and then)
    rid = record_walk(live_server, session_id, straight_s=5.0)
    page.goto(f"{live_server.base_url}/reports.html")
    page.wait_for_function(f"[...document.querySelectorAll('#recording option')]"
                           f".some(o => o.value === '{rid}')")
    page.select_option("#recording", rid)
    page.wait_for_selector("#set-a input")
    # the avenue: S1, S3, S5 on the left of a person walking the way the 3D view looks
    assert page.get_by_role("checkbox", name="S1 (left)").count() == 2
    assert page.get_by_role("checkbox", name="S2 (right)").count() == 2
    presets = page.locator("#set-a .presets").inner_text()
    assert "Left side only (S1, S3, S5)" in presets and "Right side only (S2, S4, S6)" in presets
    said = page.inner_text("#cmp-msg")
    assert "left of the walkway (S1, S3, S5)" in said, said
    screenshot(page, artifacts_dir, "laptop_reports_sides", "section[aria-labelledby=cmp-h]")
    # the report of subset A (the same template as its PDF) names the side in its title
    page.get_by_role("button", name="Report of subset A").click()
    page.wait_for_function("!document.getElementById('report-section').hidden || "
                           "document.getElementById('cmp-msg').classList.contains('error')",
                           timeout=120_000)
    assert page.locator("#report").is_visible(), page.inner_text("#cmp-msg")
    title = page.locator("#report h1").inner_text()
    screenshot(page, artifacts_dir, "laptop_reports_side_report", "#report")
    assert "sensors on the left of the walkway (S1, S3, S5)" in title, title


def _answer_get(body: Any) -> Callable[[Any], None]:
    """A route handler that answers GET with ``body`` and lets other methods through."""
    def answer(route: Any) -> None:
        if route.request.method == "GET":
            route.fulfill(status=200, json=body)
        else:
            route.continue_()
    return answer


def test_date_times_are_written_one_way(browser: Any, live_server: LiveServer,
                                        artifacts_dir: Path) -> None:
    """The calibration wizard wrote "11/28/2026, 10:07:14 AM" beside the Subjects page's
    "Nov 28, 2026": every date-time of the console spells its month as days do
    (``gaitrig.day()``), on the user's clock. The Subjects page wrote a recording's start
    as a bare "11:40:27 AM"."""
    context = browser.new_context(viewport=LAPTOP, locale="en-US", timezone_id="UTC")
    try:
        page = context.new_page()
        page.set_default_timeout(20000)
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        login(page, live_server)
        t = 1795860434  # 2026-11-28 10:07:14 UTC
        saved = [{"version": 3, "created": t, "sensors": ["S1", "S2"],
                  "max_sensor_residual_mm": 1.2, "rejected": 0}]
        page.route("**/api/calibration", lambda route: route.fulfill(status=200, json=saved)
                   if route.request.method == "GET" else route.continue_())
        page.goto(f"{live_server.base_url}/calibration-wizard.html")
        cell = page.locator("#history tbody tr").first.locator("td").nth(1)
        cell.wait_for()
        screenshot(page, artifacts_dir, "laptop_wizard_history", "#history")
        assert cell.inner_text() == "Nov 28, 2026, 10:07:14 AM", cell.inner_text()

        listed = [{"id": "R20261128-100714-0001", "state": "complete", "t_start": t,
                   "t_stop": t + 5.0, "parts": []}]
        page.route("**/api/recordings", lambda route: route.fulfill(
            status=200, json=listed) if route.request.method == "GET" else route.continue_())
        page.goto(f"{live_server.base_url}/rig.html")
        cell = page.locator("tr[data-recording] td").first
        cell.wait_for()
        assert cell.inner_text() == "Nov 28, 2026, 10:07:14 AM", cell.inner_text()
        assert not re.search(r"\d{1,2}/\d{1,2}/\d{4}", page.inner_text("main"))

        # the Subjects page wrote a recording's start as a bare "11:40:27 AM"
        sid, session_id = _subject(live_server, "Start times", "TIM01")
        rid = short_recording(live_server, session_id, "walk 1")
        started = live_server.api(f"/api/subjects/{sid}")["sessions"][0]["recordings"][0]["t_start"]
        d = datetime.fromtimestamp(started, UTC)
        want = (f"{d:%b} {d.day}, {d.year}, {d.hour % 12 or 12}:{d:%M:%S} "
                f"{'AM' if d.hour < 12 else 'PM'}")
        page.goto(f"{live_server.base_url}/subjects.html#subject={sid}")
        about = page.locator(f"#sessions [data-recording='{rid}'] .part .hint").first
        about.wait_for()
        screenshot(page, artifacts_dir, "laptop_subjects_recording_start",
                   f"#sessions [data-recording='{rid}']")
        assert about.inner_text().startswith(f"{rid} · {want} · "), about.inner_text()

        # the calibration's live check wrote a bare time: yesterday's read as this morning's
        now = time.time()
        for created, said in ((now - 86400.0, datetime.fromtimestamp(now - 86400.0, UTC)),
                              (now, None)):
            check = {"checked": True, "created": created, "state": "done", "moved": [],
                     "checks": [], "message": ""}
            page.unroute("**/api/calibration/live-check")
            page.route("**/api/calibration/live-check", _answer_get(check))
            page.goto(f"{live_server.base_url}/calibrate.html")
            state = page.locator("#bump-state")
            page.wait_for_function("() => document.getElementById('bump-state')"
                                   ".textContent.startsWith('Checked at')")
            text = state.inner_text()
            if said is not None:
                assert text.startswith(f"Checked at {said:%b} {said.day}, {said.year}, "), text
            else:
                assert re.match(r"Checked at \d{1,2}:\d\d:\d\d [AP]M: ", text), text
        assert not errors, errors
    finally:
        context.close()


#: A busy page thread (the 3D view renders on it): the Live page hears from its panels'
#: worker a second late. The worker draws the panels on its own meanwhile.
SLOW_PAGE_JS = """(() => {
  const Real = window.Worker;
  window.Worker = class extends Real {
    set onmessage(f) { super.onmessage = (ev) => setTimeout(() => f(ev), 1000); }
    get onmessage() { return super.onmessage; }
  };
})()"""


def _magenta(img: Any) -> float:
    """Share of pixels in the body highlight or the caption's "body tracked" colour."""
    r, g, b = (img[..., k].astype(int) for k in range(3))
    return float(((r > 150) & (g < 70) & (b > 110) & (r > b)).mean())


def _crop(img: Any, b: dict[str, float]) -> Any:
    return img[int(b["y"]):int(b["y"] + b["height"]), int(b["x"]):int(b["x"] + b["width"])]


def test_live_caption_describes_the_picture_shown(page: Any, live_server: LiveServer,
                                                  artifacts_dir: Path) -> None:
    """Each screenshot of the panels (one frame of the screen) is checked panel by panel:
    "body tracked (magenta)" under a picture with the magenta body, "no body tracked"
    under one without, while the simulated walker walks in and out of the sensors' view."""
    page.add_init_script(SLOW_PAGE_JS)
    # (taller than the laptop's 768: every caption whole on the screen)
    page.set_viewport_size({"width": 1366, "height": 900})
    page.route(live_server.viewer_url + "/**", lambda r: r.abort())
    page.goto(live_server.base_url + "/live.html")
    n = live_server.n_nodes
    page.wait_for_function(
        f"window.liveStats && Object.keys(window.liveStats.nodes).length === {n} && "
        "Object.values(window.liveStats.nodes).every(s => s.frames >= 3)", timeout=60000)
    assert page.evaluate("window.liveStats.mode") == "worker"
    ids = [f"S{k}" for k in range(1, n + 1)]
    # where each panel's picture and caption are (a caption of two lines moves the next
    # row down: a screenshot between two different layouts is not judged)
    where = ("ids => ids.map(i => ['canvas', 'figcaption'].map(s => { const r = document"
             ".querySelector(`figure[data-node=${i}] ${s}`).getBoundingClientRect(); "
             "return { x: r.x, y: r.y, width: r.width, height: r.height }; }))")
    last: dict[str, bool] = {}
    changes = 0
    for k in range(400):
        before = page.evaluate(where, ids)
        full = screenshot(page, artifacts_dir, "laptop_live_panels")
        if page.evaluate(where, ids) != before:
            continue
        boxes = dict(zip(ids, before, strict=True))
        for i, (pic, cap) in boxes.items():
            assert pic and cap
            body, said = _magenta(_crop(full, pic)), _magenta(_crop(full, cap)) > 0.002
            if 0 < body < 0.002:
                continue  # a few pixels of a body far away: not judged either way
            shown = body > 0
            if said != shown:
                screenshot(page, artifacts_dir, "laptop_live_caption_wrong")
            assert said == shown, (f"{i}: the caption says {'a' if said else 'no'} body "
                                   f"tracked under a picture {'with' if shown else 'without'}"
                                   f" one (screenshot {k})")
            changes += i in last and last[i] != shown
            last[i] = shown
        if changes >= 4:
            break
    assert changes >= 4, f"the walker was seen coming or going only {changes} times"
    assert not page.js_errors, page.js_errors


def test_reports_recording_list_is_read_whole(laptop: Any, live_server: LiveServer,
                                              artifacts_dir: Path) -> None:
    """The Reports page's recording list showed "walk 3 self-selected speed — LAP05, Nov
    28, 2026 first vis" at 1366 px (half the card's row), the subject list "LAP05 — 1
    session, 3 reco": every list is read whole there; at 320 px the page reflows and the
    chosen recording's whole text is written under its list."""
    page = laptop
    sid, session_id = _subject(live_server, "Laptop recordings", "LAP05")
    rids = [short_recording(live_server, session_id, f"walk {k} self-selected speed")
            for k in (1, 2, 3)]
    page.goto(f"{live_server.base_url}/reports.html#subject={sid}")
    page.wait_for_function(f"[...document.querySelectorAll('#recording option')]"
                           f".some(o => o.value === '{rids[-1]}')")
    page.wait_for_function("document.getElementById('session').options.length > 1")
    page.select_option("#session", str(session_id))
    page.select_option("#recording", rids[-1])
    page.wait_for_selector("#set-a input")
    text = page.evaluate("document.getElementById('recording').selectedOptions[0].textContent")
    assert text.startswith("walk 3 self-selected speed — LAP05, first visit, "), text
    assert text.endswith(f" — 6 sensors — {rids[-1]}"), text
    cut = page.evaluate(CUT_SELECTS_JS)
    screenshot(page, artifacts_dir, "laptop_reports_recordings", "section[aria-labelledby=cmp-h]")
    screenshot(page, artifacts_dir, "laptop_reports_subject_lists", "#subject-form")
    assert cut == [], cut
    assert page.evaluate("document.documentElement.scrollWidth <= innerWidth")
    # whole in its list: not written again under it
    assert page.locator("#recording-whole").is_hidden()

    # 320 px (a 1280 px window at 400 %): the page reflows, and the list, too narrow for the
    # text, has it whole under it
    page.set_viewport_size({"width": 320, "height": 700})
    page.wait_for_function("!document.getElementById('recording-whole').hidden")
    screenshot(page, artifacts_dir, "narrow_reports_recordings", "section[aria-labelledby=cmp-h]")
    assert page.evaluate("document.documentElement.scrollWidth <= innerWidth")
    assert page.inner_text("#recording-whole") == text
    box = page.locator("#recording-whole").bounding_box()
    assert box is not None and box["x"] >= 0 and box["x"] + box["width"] <= 320, box
    # back to the laptop: written once again
    page.set_viewport_size(LAPTOP)
    page.wait_for_function("document.getElementById('recording-whole').hidden")


#: Each visible list (of those matching the CSS selector given, by default the Reports
#: page's subject and recording forms) whose chosen entry is read neither in the list (cut,
#: as :data:`CUT_SELECTS_JS` measures) nor whole under it (``#<list>-whole``, on the
#: screen): what a person cannot read at this width.
UNREAD_SELECTS_JS = """(css) => {""" + _SELECTS_JS + """
  return shown(css || "#subject-form select, .rec-pick select").filter(cut).filter((s) => {
    const whole = document.getElementById(s.id + "-whole");
    const text = s.selectedOptions[0].textContent;
    if (!whole || whole.hidden || whole.textContent !== text) return true;
    const r = whole.getBoundingClientRect();
    return r.left < 0 || r.right > document.documentElement.clientWidth + 0.5;
  }).map(said);
}"""

#: Text of the page's subject form (the session ticks, the lists' labels) that runs out of
#: its card: not wrapped, and cut or off the screen.
OUT_OF_CARD_JS = """() => {
  const card = document.querySelector("section[aria-labelledby=subject-h]").getBoundingClientRect();
  return [...document.querySelectorAll("#subject-form label, #subject-form p")]
    .filter((e) => e.getClientRects().length > 0)
    .filter((e) => e.getBoundingClientRect().right > card.right + 0.5)
    .map((e) => e.textContent.trim());
}"""


def test_reports_lists_are_read_at_every_width(page: Any, live_server: LiveServer,
                                               artifacts_dir: Path) -> None:
    """Between about 900 and 1100 px the Reports page put Find, Subject and Session three
    to a row: "KNEE-OA-0117 — 2 sessions, 2 r", "Nov 28, 2026 (1 complete recor", with no
    way to read the rest but opening the list; at 1366 px the subject list was cut too,
    and at 320 px the session ticks ran off the card. At every width
    from 320 to 1920 px each list's chosen entry is read whole, in the list or under it,
    and nothing runs off the card or the screen; from 900 px the subject and session
    lists hold their entries whole."""
    code = "KNEE-OA-0117"
    sid, first = _subject(live_server, "Knee replacement follow-up", code)
    later = live_server.api("/api/sessions", {
        "subject_id": sid, "label": "six weeks after knee replacement"})
    short_recording(live_server, first, "walk 1")
    rid = short_recording(live_server, later["id"], "walk 1 self-selected speed")
    page.goto(f"{live_server.base_url}/reports.html#subject={sid}")
    page.wait_for_function("document.getElementById('session').options.length > 2")
    page.wait_for_function(f"[...document.querySelectorAll('#recording option')]"
                           f".some(o => o.value === '{rid}')")
    page.select_option("#recording", rid)
    widths = (320, 900, 1000, 1100, 1366, 1920)
    # all sessions: the sessions' ticks are shown
    for w in widths:
        page.set_viewport_size({"width": w, "height": 900})
        page.wait_for_selector("#sessions-pick input")
        screenshot(page, artifacts_dir, f"reports_lists_all_sessions_{w}", "#subject-form")
        assert page.evaluate("document.documentElement.scrollWidth <= innerWidth"), w
        assert page.evaluate(OUT_OF_CARD_JS) == [], (w, page.evaluate(OUT_OF_CARD_JS))
    # one session, with its long label
    page.select_option("#session", str(later["id"]))
    assert page.evaluate("document.getElementById('session').selectedOptions[0].textContent"
                         ).endswith("(1 complete recording) — six weeks after knee "
                                    "replacement")
    for w in widths:
        page.set_viewport_size({"width": w, "height": 900})
        page.wait_for_timeout(100)  # (the page's resize handler)
        screenshot(page, artifacts_dir, f"reports_lists_{w}", "#subject-form")
        assert page.evaluate("document.documentElement.scrollWidth <= innerWidth"), w
        assert page.evaluate(OUT_OF_CARD_JS) == [], (w, page.evaluate(OUT_OF_CARD_JS))
        assert page.evaluate(UNREAD_SELECTS_JS) == [], (w, page.evaluate(UNREAD_SELECTS_JS))
        if w >= 900:
            cut = [c for c in page.evaluate(CUT_SELECTS_JS) if c.split(":")[0] in
                   ("subject", "session")]
            assert cut == [], (w, cut)


def test_a_subject_chosen_twice_at_once_lists_its_sessions_once(
        page: Any, live_server: LiveServer) -> None:
    """The Reports page chooses the only subject as it loads; a person choosing it at the
    same moment started a second drawing of the same subject, and both added their
    sessions: every session and its tick box was listed twice."""
    sid, first = _subject(live_server, "Twice chosen", "TWICE01")
    later = live_server.api("/api/sessions", {"subject_id": sid, "label": "second visit"})
    short_recording(live_server, first, "walk 1")
    short_recording(live_server, later["id"], "walk 1")
    page.goto(f"{live_server.base_url}/reports.html#subject={sid}")
    page.wait_for_function("document.getElementById('session').options.length > 2")
    # two drawings of the same subject under way together, as a load and a click make them
    page.evaluate("""() => { const s = document.getElementById('subject');
        s.dispatchEvent(new Event('change')); s.dispatchEvent(new Event('change')); }""")
    page.wait_for_function("document.getElementById('session').options.length > 2")
    page.wait_for_timeout(1000)  # both answers are in (the doubled list came with the second)
    sessions = page.eval_on_selector_all("#session option", "os => os.map(o => o.value)")
    ticks = page.eval_on_selector_all("#sessions-pick input", "cs => cs.map(c => c.value)")
    assert sessions == ["", str(first), str(later["id"])], sessions
    assert sorted(ticks) == sorted([str(first), str(later["id"])]), ticks
