"""The console header on a page open without a login (the Help page): "Log in", not
"Log out" and a user menu, for nobody logged in; the user menu and "Log out" for a user.

Who is logged in is learnt from ``GET /api/auth/session``, which answers 200 for nobody
too: a logged-out page makes no failing request at all (the 3D view's address, behind the
login, is not asked for then).
"""

from __future__ import annotations

from typing import Any
from urllib.parse import urlparse

import pytest

from tests.browser.conftest import LiveServer, login, new_page


@pytest.mark.browser
def test_help_page_logged_out_offers_log_in_and_back(browser: Any,
                                                     live_server: LiveServer) -> None:
    page = new_page(browser)
    failed: list[str] = []
    page.on("response", lambda r: failed.append(urlparse(r.url).path)
            if r.status >= 400 else None)
    try:
        page.goto(live_server.base_url + "/help.html#ts-cant-log-in")
        header = page.locator("header#nav")
        link = header.get_by_role("link", name="Log in", exact=True)
        link.wait_for()
        assert header.get_by_role("button", name="Log out").count() == 0
        assert "Log out" not in header.inner_text()
        assert header.locator(".user-menu, #user-menu *").count() == 0
        assert header.locator("#viewer-link").is_hidden()
        assert page.url.endswith("/help.html#ts-cant-log-in"), "sent away to log in"
        assert failed == [], failed
        assert page.js_errors == []

        # the link logs in and comes back to the same place of the guide
        link.click()
        page.wait_for_url("**/index.html?next=*")
        page.fill("#username", "admin")
        page.fill("#password", live_server.password)
        page.click("button[type=submit]")
        page.wait_for_url("**/help.html#ts-cant-log-in")
        header.locator(".user-menu summary").wait_for()
        assert header.get_by_role("button", name="Log out").is_visible()
        assert header.get_by_role("link", name="Log in", exact=True).count() == 0
        assert page.js_errors == []
    finally:
        page.context.close()


@pytest.mark.browser
def test_help_page_logged_in_shows_the_user_menu(browser: Any,
                                                 live_server: LiveServer) -> None:
    page = new_page(browser)
    try:
        login(page, live_server)
        page.goto(live_server.base_url + "/help.html")
        header = page.locator("header#nav")
        summary = header.locator(".user-menu summary")
        summary.wait_for()
        assert summary.inner_text().strip() == "admin"
        logout = header.get_by_role("button", name="Log out")
        logout.wait_for()  # shown once the user is known
        assert header.get_by_role("link", name="Log in", exact=True).count() == 0
        header.locator("#viewer-link").wait_for()  # asked for once logged in
        summary.click()
        assert header.get_by_role("link", name="Accounts").is_visible()
        # and the header's "Log out" still logs out
        logout.click()
        page.wait_for_url("**/index.html")
        page.goto(live_server.base_url + "/help.html")
        header.get_by_role("link", name="Log in", exact=True).wait_for()
        assert page.js_errors == []
    finally:
        page.context.close()
