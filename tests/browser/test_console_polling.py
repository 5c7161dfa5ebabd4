"""Console leftovers a person notices: pages that stop asking the server while their tab
is hidden (and ask at once when it is shown again), the Calibrate page's poses table
while it loads, counts written in the right number ("1 session", never "1 session(s)").

The tab is hidden the way a browser hides it for a page script: ``document.hidden`` and
``document.visibilityState`` report it and ``visibilitychange`` fires (headless Chromium
has no window to minimise). Requests are counted by wrapping ``window.fetch``.
"""

from __future__ import annotations

import time
import uuid
from typing import Any

import pytest

from tests.browser.conftest import LiveServer

pytestmark = pytest.mark.browser

# Hide or show the page as the browser would (properties on the document shadow the
# prototype's getters), and count the page's requests by path from now on.
SET_HIDDEN_JS = """(hidden) => {
  window.__setHidden = (h) => {
    Object.defineProperty(document, "hidden", { configurable: true, get: () => h });
    Object.defineProperty(document, "visibilityState", { configurable: true,
      get: () => (h ? "hidden" : "visible") });
    document.dispatchEvent(new Event("visibilitychange"));
  };
  window.__setHidden(hidden);
}"""
WAIT_JS = """() => {
  window.__waited = false;
  gaitrig.wait(50).then(() => { window.__waited = true; });
}"""
COUNT_FETCHES_JS = """() => {
  window.__asked = [];
  if (!window.__realFetch) {
    window.__realFetch = window.fetch;
    window.fetch = (url, ...rest) => {
      window.__asked.push(String(url instanceof Request ? url.url : url));
      return window.__realFetch(url, ...rest);
    };
  }
}"""


def _asked(page: Any, part: str) -> int:
    return int(page.evaluate("(part) => window.__asked.filter((u) => u.includes(part)).length",
                             part))


def test_rig_page_stops_polling_while_hidden_and_polls_at_once_when_shown(
        page: Any, live_server: LiveServer) -> None:
    """The Rig page asks for the sensors and recordings every second while it is seen;
    hidden, it asks nothing; shown again, it asks at once (before its next second)."""
    # the page's timers on a clock the test moves on (time flows as usual meanwhile):
    # 3.5 s of a hidden tab pass at once instead of being waited for
    page.clock.install()
    page.reload()
    page.wait_for_function("document.getElementById('summary').textContent.includes('online')")
    page.evaluate(COUNT_FETCHES_JS)
    page.wait_for_function("window.__asked.filter((u) => u.includes('/api/nodes')).length >= 2")
    page.evaluate(SET_HIDDEN_JS, True)
    page.wait_for_timeout(300)  # a request already on its way when the tab was hidden
    page.evaluate(COUNT_FETCHES_JS)  # counts start over
    page.clock.run_for(3500)  # 3 polls of each list when the page polled regardless
    assert _asked(page, "/api/nodes") == 0
    assert _asked(page, "/api/recordings") == 0
    # shown: both lists asked for within the visibilitychange handler itself
    asked_at_once = page.evaluate(
        "() => { window.__asked = []; window.__setHidden(false); return window.__asked.slice(); }")
    assert any("/api/nodes" in u for u in asked_at_once), asked_at_once
    assert any("/api/recordings" in u for u in asked_at_once), asked_at_once
    # and it keeps polling
    page.wait_for_function("window.__asked.filter((u) => u.includes('/api/nodes')).length >= 3")
    assert page.js_errors == []


def test_a_polling_chain_waits_while_hidden(page: Any) -> None:
    """gaitrig.wait (the step of the Record, Subjects, KSCC and calibration pages' chains
    of polls) does not settle while the page is hidden, and settles once it is shown."""
    page.evaluate(SET_HIDDEN_JS, True)
    page.evaluate(WAIT_JS)
    page.wait_for_timeout(1000)
    assert page.evaluate("window.__waited") is False
    page.evaluate(SET_HIDDEN_JS, False)
    page.wait_for_function("window.__waited === true")
    # seen throughout: it simply waits
    page.evaluate(WAIT_JS)
    page.wait_for_function("window.__waited === true")


def test_live_page_stops_polling_while_hidden(page: Any, live_server: LiveServer) -> None:
    """The Live page's sensor list (every 5 s) is not asked for from a hidden tab."""
    page.add_init_script(f"({COUNT_FETCHES_JS})()")  # counted from the page's start
    page.goto(live_server.base_url + "/live.html")
    # its first load done (the list asked for once, the websocket opened)
    page.wait_for_function("window.__asked.some((u) => u.includes('/api/nodes'))")
    page.wait_for_timeout(500)
    page.evaluate(SET_HIDDEN_JS, True)
    page.evaluate(COUNT_FETCHES_JS)
    # (real time: on Playwright's fake clock the page's 200 ms timers and animation frames
    # of six streaming panels run one by one, minutes for 6 s)
    page.wait_for_timeout(6000)
    assert _asked(page, "/api/nodes") == 0
    page.evaluate(SET_HIDDEN_JS, False)
    page.wait_for_function("window.__asked.some((u) => u.includes('/api/nodes'))")


def test_calibrate_page_says_the_poses_are_loading(page: Any, live_server: LiveServer) -> None:
    """While the sensor list is on its way the poses table says so (it was an empty table
    under its headings); then it lists every sensor."""
    held: list[Any] = []
    page.route("**/api/nodes", lambda route: held.append(route))
    page.goto(live_server.base_url + "/calibrate.html", wait_until="domcontentloaded")
    line = page.locator("#poses td[role=status]")
    line.wait_for()
    assert line.inner_text() == "Loading the sensor poses…"
    deadline = time.time() + 20
    while not held and time.time() < deadline:
        page.wait_for_timeout(100)
    for route in held:
        route.continue_()
    page.unroute("**/api/nodes")
    page.wait_for_function(f"document.querySelectorAll('#poses tr th').length === "
                           f"{live_server.n_nodes}")
    assert page.locator("#poses td[role=status]").count() == 0


def test_counts_are_written_in_the_right_number(page: Any, live_server: LiveServer) -> None:
    """A subject with one session and no recording reads "1 session, 0 recordings" on the
    Reports and Subjects pages."""
    code = "PL" + uuid.uuid4().hex[:6].upper()
    project = live_server.api("/api/projects", {"name": f"plurals {code}"})
    subject = live_server.api("/api/subjects", {"project_id": project["id"], "code": code})
    live_server.api("/api/sessions", {"subject_id": subject["id"], "label": "baseline"})
    page.goto(live_server.base_url + f"/reports.html#subject={subject['id']}")
    page.fill("#subject-q", code)
    option = page.locator(f"#subject option[value='{subject['id']}']")
    option.wait_for(state="attached")
    assert option.inner_text() == f"{code} — 1 session, 0 recordings"
    page.goto(live_server.base_url + f"/subjects.html#subject={subject['id']}")
    page.wait_for_function("document.getElementById('detail-hint').textContent"
                           ".includes('on the server')")
    hint = page.inner_text("#detail-hint")
    assert hint.startswith("1 session, 0 recordings, ") and "(s)" not in hint
    assert page.js_errors == []
