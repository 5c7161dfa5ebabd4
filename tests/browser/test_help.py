"""The clinician's guide (``static/help.html``) stays true to the console.

* Every link of the guide resolves: ``#anchor`` to an element of the guide, a console
  page to a file of ``static/`` (and its anchor to an element there), no link leaves the
  server (the guide must work offline); every "What does this mean?" link of the console
  pages points at an anchor the guide has.
* Every console word the guide quotes (``<q class="ui">``, ``<kbd>``, or an element's
  ``data-ui`` when the quote on screen has a variable part) is found in the console's
  sources — ``static/``, ``app/`` and ``engine/`` (the report and its notes are written
  there) — so renaming a button or a message without updating the guide fails here.
* In Chromium: the guide opens without logging in (it holds no data) with its heading and
  the console's nav (screenshot ``test-artifacts/browser/help.png``); the login page links
  to it; every console page's nav has "Help"; every page the guide links to opens.
"""

from __future__ import annotations

import html
import json
import re
import time
import urllib.request
from html.parser import HTMLParser
from pathlib import Path
from typing import Any

import pytest

from engine.report.render import ReportData, TrialData, render_html
from tests.browser.conftest import ROOT, LiveServer, login, new_page, screenshot

STATIC = ROOT / "static"
GUIDE = STATIC / "help.html"

# The guide's own files are not evidence for what it quotes.
_OWN = {GUIDE, STATIC / "js" / "help.js"}
_SOURCE_GLOBS = [(STATIC, ("*.html", "*.js")), (ROOT / "app", ("*.py",)),
                 (ROOT / "engine", ("*.py", "*.j2"))]
# Where one message is written as adjacent string literals ("… gaitrig corrects "
# "this, but …", f-strings included) or joined with + in JavaScript: the junction is
# dropped so that the message reads as the console shows it.
#: Quotes shorter than this must be a whole element text or string literal.
SHORT_QUOTE = 16
_JUNCTION = re.compile(r"""(["'`]) ?\+? ?(?:[rRfFbBuU]{1,2})?\1""")


class _Page(HTMLParser):
    """Ids, links and quoted console words of one HTML file."""

    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.ids: set[str] = set()
        self.links: list[str] = []
        self.quotes: list[str] = []
        self._open: list[tuple[str, str | None, list[str]]] = []  # (tag, data-ui, text)

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        if a.get("id"):
            self.ids.add(str(a["id"]))
        if tag == "a" and a.get("href") is not None:
            self.links.append(str(a["href"]))
        quoted = (tag == "q" and "ui" in (a.get("class") or "").split()) or tag == "kbd"
        if quoted or "data-ui" in a:
            self._open.append((tag, a.get("data-ui"), []))

    def handle_endtag(self, tag: str) -> None:
        if self._open and self._open[-1][0] == tag:
            _, given, text = self._open.pop()
            self.quotes.append(_norm(given if given is not None else "".join(text)))

    def handle_data(self, data: str) -> None:
        for _, _, text in self._open:
            text.append(data)


def _parse(path: Path) -> _Page:
    p = _Page()
    p.feed(path.read_text(encoding="utf-8"))
    return p


def _norm(text: str) -> str:
    return " ".join(html.unescape(text).split())


def _corpus() -> str:
    parts = []
    for base, patterns in _SOURCE_GLOBS:
        for pattern in patterns:
            for f in sorted(base.rglob(pattern)):
                if f in _OWN or (STATIC / "help") in f.parents:
                    continue
                parts.append(_JUNCTION.sub("", _norm(f.read_text(encoding="utf-8",
                                                                errors="replace"))))
    return "\n".join(parts)


def _shown_in(quote: str, corpus: str) -> bool:
    """Whether the console shows ``quote``: a long one anywhere in its sources, a short one
    ("Stop", "online") only as a whole element text or string literal, so that renaming a
    button is not hidden by the same word elsewhere."""
    if not quote:
        return False
    if len(quote) >= SHORT_QUOTE:
        return quote in corpus
    # bounded by markup, a string's quotes, or a placeholder (${…} in JS, {…} in f-strings)
    return re.search(r"""[>"'`}] ?""" + re.escape(quote) + r""" ?[<"'`${]""",
                     corpus) is not None


def _page_links(guide: _Page) -> set[str]:
    """The console pages (``/rig.html``) the guide links to."""
    return {link.split("#")[0] for link in guide.links if not link.startswith("#")}


def test_every_link_of_the_guide_resolves() -> None:
    guide = _parse(GUIDE)
    assert len(guide.links) >= 40, "the guide links its sections and pages"
    bad = []
    for link in guide.links:
        if link.startswith("#"):
            if link[1:] not in guide.ids:
                bad.append(f"{link}: no element with this id in help.html")
            continue
        m = re.fullmatch(r"/([\w-]+\.html)(?:#([\w-]+))?", link)
        if m is None:  # offline on the clinic network: nothing outside the console
            bad.append(f"{link}: not a console page (/<page>.html[#anchor])")
            continue
        target = STATIC / m.group(1)
        if not target.is_file():
            bad.append(f"{link}: static/{m.group(1)} does not exist")
        elif m.group(2) and m.group(2) not in _parse(target).ids:
            bad.append(f"{link}: no element #{m.group(2)} in {m.group(1)}")
    assert not bad, "\n".join(bad)
    # the sections the issue asks for, each with its anchor
    for anchor in ("first-session", "clock-warnings", "blind-spots", "calibrating", "printing",
                   "residuals", "accept", "bumped-tripod", "recording", "recording-states",
                   "transfers", "reports", "report-parameters", "cv-asymmetry",
                   "report-quality", "when-not-to-trust", "validation", "imu-kscc",
                   "accounts", "data-protection", "erasure-log", "backups",
                   "troubleshooting", "ts-sensor-offline", "ts-low-frame-rate", "ts-clock",
                   "ts-bumped", "ts-marker-not-seen", "ts-graph-not-connected",
                   "ts-disk-full", "ts-transfer-stuck", "ts-too-few-steps", "ts-cant-log-in",
                   "ts-node-warnings"):
        assert anchor in guide.ids, f"help.html has no #{anchor}"


def test_the_guide_holds_no_data_and_asks_the_api_nothing() -> None:
    # it is served without a login: it must not read anything behind one itself
    text = GUIDE.read_text(encoding="utf-8")
    assert "/api/" not in text
    assert "<script>" not in text, "inline scripts need the CSP hash mechanism; use a file"


def test_context_help_links_of_the_console_point_at_the_guide() -> None:
    ids = _parse(GUIDE).ids
    found: dict[str, list[str]] = {}
    for f in sorted(STATIC.rglob("*")):
        if f.suffix not in (".html", ".js") or f == GUIDE:
            continue
        for anchor in re.findall(r"/help\.html#([\w-]+)", f.read_text(encoding="utf-8")):
            found.setdefault(anchor, []).append(str(f.relative_to(STATIC)))
    missing = {a: where for a, where in found.items() if a not in ids}
    assert not missing, f"links to anchors help.html lacks: {missing}"
    # the warnings the guide explains link to it where they are shown
    for anchor in ("bumped-tripod", "rig-page", "residuals", "ts-calibration-fails",
                   "report-quality", "ts-cant-log-in"):
        assert anchor in found, f"no console page links to help.html#{anchor}"


def test_every_quoted_console_word_is_the_consoles() -> None:
    quotes = _parse(GUIDE).quotes
    assert len(quotes) >= 150, f"only {len(quotes)} console words quoted"
    corpus = _corpus()
    # the search can fail: a word the console never shows is not found
    assert _shown_in("Start recording", corpus) and _shown_in("Stop", corpus)
    assert not _shown_in("Begin the recording now", corpus)
    assert not _shown_in("Stop rec", corpus)  # a word inside a longer label is not the label
    missing = sorted({q for q in quotes if not _shown_in(q, corpus)})
    assert not missing, ("the guide quotes words the console does not show (renamed? "
                         "update static/help.html):\n" + "\n".join(missing))


# ------------------------------------------------------------------ in the browser

def _h1(page: Any) -> str:
    h = page.locator("main h1").first
    h.wait_for(state="visible")
    return " ".join(h.inner_text().split())


@pytest.mark.browser
def test_the_guide_opens_without_a_login(browser: Any, live_server: LiveServer,
                                         artifacts_dir: Path) -> None:
    # served to anyone who can reach the console (no cookie, no token)
    with urllib.request.urlopen(live_server.base_url + "/help.html", timeout=15) as r:
        assert r.status == 200
        assert "Clinician's guide" in r.read().decode()
    page = new_page(browser)
    try:
        # from the login page: "I can't log in" is a help topic
        page.goto(live_server.base_url + "/index.html")
        page.get_by_role("link", name=re.compile("Help")).click()
        page.wait_for_url("**/help.html#ts-cant-log-in")
        assert _h1(page) == "Clinician's guide"
        page.get_by_role("heading", name="I can't log in / I am locked out").wait_for()
        page.wait_for_timeout(300)  # nav.js's requests answer 401: nothing may follow them
        assert page.url.endswith("/help.html#ts-cant-log-in"), "sent away to log in"
        nav = page.locator("header#nav nav[aria-label='Console sections']")
        help_link = nav.get_by_role("link", name="Help", exact=True)
        assert help_link.get_attribute("aria-current") == "page"
        assert nav.locator("a").count() >= 9
        page.goto(live_server.base_url + "/help.html")
        _h1(page)
        img = screenshot(page, artifacts_dir, "help")
        assert img.shape[0] > 300 and img.shape[1] > 1000
        assert page.js_errors == []
    finally:
        page.context.close()


@pytest.mark.browser
def test_help_is_in_every_pages_nav_and_every_page_the_guide_links_opens(
        browser: Any, live_server: LiveServer) -> None:
    pages = sorted(p.name for p in STATIC.glob("*.html"))
    linked = _page_links(_parse(GUIDE))
    assert {"/rig.html", "/live.html", "/calibrate.html", "/calibration-wizard.html",
            "/record.html", "/subjects.html", "/reports.html", "/imu.html",
            "/kscc.html"} <= linked
    page = new_page(browser)
    try:
        login(page, live_server)
        opened = set()
        for name in pages:
            page.goto(f"{live_server.base_url}/{name}")
            assert _h1(page), name
            if name == "index.html":  # the login page has no nav; it links to the guide
                assert page.locator("a[href^='/help.html']").count() == 1
            else:
                link = page.locator("header#nav nav a[href='/help.html']")
                link.wait_for()
                assert " ".join(link.inner_text().split()) == "Help", name
                assert page.url.endswith("/" + name), f"{name} sent the logged-in user away"
            opened.add("/" + name)
        assert linked <= opened, f"the guide links pages that do not open: {linked - opened}"
        # and the nav takes one there
        page.goto(live_server.base_url + "/rig.html")
        page.locator("header#nav nav a[href='/help.html']").click()
        page.wait_for_url("**/help.html")
        assert _h1(page) == "Clinician's guide"
    finally:
        page.context.close()


def _json(route: Any, body: Any, headers: dict[str, str] | None = None) -> None:
    route.fulfill(status=200, content_type="application/json", body=json.dumps(body),
                  headers=headers or {})


@pytest.mark.browser
def test_warnings_link_to_their_explanation(browser: Any, live_server: LiveServer) -> None:
    """The bumped-tripod banner, a failed calibration and a report's data-quality notes
    carry a "What does this mean?" link that opens the guide at the explanation (the
    server's answers stood in for: a moved sensor, an unconnected graph, a short walk)."""
    page = new_page(browser)
    try:
        login(page, live_server)
        # a moved sensor, as GET /api/calibration/live-check reports it
        page.route("**/api/calibration/live-check", lambda route: _json(route, {
            "checked": True, "warnings": [{"sensor": "S2", "moved_mm": 21.0, "rotated_deg": 0.8,
                                          "calibration_created": time.time() - 3600,
                                          "calibration_version": 3}]}))
        page.goto(live_server.base_url + "/rig.html")
        banner = page.locator("#calib-warning")
        banner.wait_for(state="visible")
        assert "Sensor S2 has moved 2.1 cm" in banner.inner_text()
        assert page.locator("main a[href='/help.html#rig-page']").count() == 1
        banner.get_by_role("link", name="What does this mean?").click()
        page.wait_for_url("**/help.html#bumped-tripod")
        page.get_by_role("heading", name="Bumped-tripod warnings").wait_for()
        page.unroute("**/api/calibration/live-check")

        # a calibration that fails: the graph does not reach marker 1
        page.route("**/api/calibration/capture", lambda route: _json(route, {"id": 991}))
        page.route("**/api/calibration/captures/991", lambda route: _json(route, {
            "id": 991, "state": "failed", "frames": 30, "nodes": {},
            "message": "sensor S5 has no chain of shared markers to marker 1: S5 sees "
                       "no usable marker. Place a marker where an unreachable sensor and a "
                       "reachable one both see it.", "unreachable": ["S5"]}))
        page.goto(live_server.base_url + "/calibration-wizard.html")
        assert page.locator("a[href='/help.html#residuals']").count() == 1
        page.click("#cap-form button[type=submit]")
        err = page.locator("#cap-error")
        err.get_by_role("link", name="What does this mean?").wait_for()
        assert "no chain of shared markers" in err.inner_text()
        assert err.locator("a").get_attribute("href") == "/help.html#ts-calibration-fails"

        # a report of a short walk: the notes the report engine writes, then the link
        steps = [{"side": s, "length_m": 0.7, "width_m": 0.1, "duration_s": 0.55,
                  "time_s": 0.55 * i} for i, s in enumerate("LRL")]
        report = render_html(ReportData("P001", [TrialData("walk 1", {
            "steps": steps, "strides": [], "summary": {}, "events": []})]), standalone=False)
        subject = {"id": 1, "code": "P001", "n_sessions": 0, "n_recordings": 1,
                   "project_id": 1, "sessions": []}
        page.route(re.compile(r".*/api/subjects\?.*"),
                   lambda route: _json(route, [subject], {"X-Total-Count": "1"}))
        page.route("**/api/subjects/1", lambda route: _json(route, subject))
        page.route("**/api/reports/subjects/1?*", lambda route: route.fulfill(
            status=200, content_type="text/html", body=report))
        page.goto(live_server.base_url + "/reports.html")
        page.locator("#subject option[value='1']").wait_for(state="attached")
        page.select_option("#subject", "1")
        page.click("#show")
        notes = page.locator("#report ul.notes")
        notes.wait_for()
        assert "right steps were analysed" in notes.inner_text()
        page.locator("#report").get_by_role("link", name="What does this mean?").click()
        page.wait_for_url("**/help.html#report-quality")
        page.get_by_role("heading", name="The data-quality section").wait_for()
        assert page.js_errors == []
    finally:
        page.context.close()
