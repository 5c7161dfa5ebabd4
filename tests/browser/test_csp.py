"""The console under its real Content-Security-Policy.

Every other browser test bypasses the policy (Playwright's ``wait_for_function`` evaluates
its predicate with ``eval``, which the console's policy refuses); this one does not: it
logs in and opens every page of the console as a clinician's browser would, and fails on
any policy violation the browser reports.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest

from tests.browser.conftest import ROOT, LiveServer

pytestmark = pytest.mark.browser

STATIC = ROOT / "static"

#: Records what the browser reports as refused by the policy, in every frame, from the
#: first script on (an init script runs before the page's own and is not subject to it).
_LISTEN = """
window.__csp = [];
document.addEventListener('securitypolicyviolation', (e) => {
  window.__csp.push(`${e.violatedDirective} blocked ${e.blockedURI || 'inline'} ` +
                    `(${e.sourceFile || location.pathname}:${e.lineNumber})`);
});
"""

_H1 = re.compile(r"<h1[^>]*>(.*?)</h1>", re.S)


def _heading(page: Path) -> str:
    """The text of the first ``<h1>`` of a console page as its file writes it."""
    m = _H1.search(page.read_text(encoding="utf-8"))
    assert m, f"{page.name} has no <h1>"
    text = re.sub(r"<[^>]+>", "", m.group(1)).replace("&amp;", "&")
    return " ".join(text.split())


def _pages() -> list[Path]:
    pages = sorted(STATIC.glob("*.html"))
    names = {p.stem for p in pages}
    # the console's pages as the mission lists them; a new page is picked up by the glob
    expected = {"index", "rig", "live", "record", "subjects", "reports", "calibrate",
                "calibration-wizard", "imu", "kscc", "accounts"}
    assert expected <= names, f"console pages missing: {sorted(expected - names)}"
    return pages


def test_every_console_page_runs_under_its_policy(browser: Any,
                                                  live_server: LiveServer) -> None:
    context = browser.new_context(viewport={"width": 1400, "height": 900}, bypass_csp=False)
    context.add_init_script(_LISTEN)
    page = context.new_page()
    page.set_default_timeout(20000)
    reported: list[str] = []
    page.on("console", lambda m: reported.append(f"{page.url}: {m.text}")
            if "Content Security Policy" in m.text else None)

    # the login form, under the policy: its inline bootstrap script is allowed by hash
    page.goto(live_server.base_url + "/index.html")
    page.get_by_role("heading", level=1, name=_heading(STATIC / "index.html")).wait_for()
    page.fill("#username", "admin")
    page.fill("#password", live_server.password)
    page.click("button[type=submit]")
    page.wait_for_url("**/rig.html")

    seen = []
    for html in _pages():
        page.goto(f"{live_server.base_url}/{html.name}")
        heading = page.locator("h1").first
        heading.wait_for(state="visible")
        assert " ".join(heading.inner_text().split()) == _heading(html), html.name
        if page.locator("header#nav").count():
            # nav.js ran: the header lists the sections
            page.locator("header#nav nav a").first.wait_for()
        page.wait_for_load_state("load")
        found = page.evaluate("window.__csp")
        assert found == [], f"{html.name}: the policy refused {found}"
        seen.append(html.stem)
    assert not reported, "\n".join(reported)
    assert len(seen) == len(_pages())

    # both listeners do report what the policy refuses: an inline script not in the
    # hashes, as an injection would add it (the page's own code cannot be changed here)
    page.goto(live_server.base_url + "/rig.html")
    page.evaluate("""() => {
      const s = document.createElement('script');
      s.textContent = 'window.__injected = true';
      document.body.append(s);
    }""")
    for _ in range(100):  # the event is queued; wait_for_function would need eval itself
        if page.evaluate("window.__csp.length") and reported:
            break
        page.wait_for_timeout(50)
    assert "script-src" in " ".join(page.evaluate("window.__csp")), "violation not seen"
    assert reported, "the browser's console did not report the refused script"
    assert page.evaluate("window.__injected === undefined")
    context.close()
