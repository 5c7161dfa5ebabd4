"""Accounts and passwords in a real browser: the first login with the generated password is
asked to change it, a change through the user menu's dialog (wrong current password,
a password the policy refuses, success), and an administrator's Accounts page (create an
account, who sees the page, a refused self-removal, removal with the name typed again,
the account changes in words). A server of its own (no nodes): these tests change the
administrator's password, which the shared demo server's other tests log in with."""

from __future__ import annotations

import json
import os
import re
import shutil
import tempfile
import time
import urllib.request
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from tests.browser.conftest import new_page, screenshot, serve_without_nodes
from tests.browser.test_console_ux import AUDIT_JS, LEAKED

pytestmark = pytest.mark.browser

NEW_ADMIN_PASSWORD = "walking frames at dawn 9"


@dataclass
class Console:
    """The server, and the administrator's password as it is now (a test changes it)."""

    base_url: str
    password: str


@pytest.fixture(scope="module")
def console() -> Iterator[Console]:
    tmp = Path(tempfile.mkdtemp(prefix="gaitrig-accounts-"))
    env = {k: v for k, v in os.environ.items() if k != "GAITRIG_ADMIN_PASSWORD"}
    try:  # no admin password given: the first start generates one
        with serve_without_nodes(tmp / "data", env) as (url, log_path):
            found = None
            for _ in range(50):
                found = re.search(r"account 'admin' with password '([^']+)'",
                                  log_path.read_text())
                if found:
                    break
                time.sleep(0.1)
            assert found, log_path.read_text()[-2000:]
            yield Console(url, found.group(1))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _page(browser: Any) -> Any:
    return new_page(browser, 15000)


def _login(page: Any, console: Console, username: str, password: str) -> None:
    page.goto(console.base_url + "/index.html")
    page.fill("#username", username)
    page.fill("#password", password)
    page.click("button[type=submit]")
    page.wait_for_url("**/rig.html")


def _api_login(console: Console, username: str, password: str) -> None:
    """A login from elsewhere (no browser): a session the server keeps."""
    req = urllib.request.Request(console.base_url + "/api/auth/login", method="POST",
                                 data=json.dumps({"username": username,
                                                  "password": password}).encode(),
                                 headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(req, timeout=15) as r:
        assert r.status == 200


def _open_dialog(page: Any) -> None:
    page.click(".user-menu summary")
    page.click("#password-open")
    page.wait_for_selector("#password-dialog[open]")


def _change(page: Any, current: str, new: str, repeat: str | None = None) -> None:
    page.fill("#pw-current", current)
    page.fill("#pw-new", new)
    page.fill("#pw-repeat", new if repeat is None else repeat)
    page.click("#pw-submit")


def test_first_login_is_asked_to_change_the_generated_password(
        browser: Any, console: Console, artifacts_dir: Path) -> None:
    page = _page(browser)
    try:
        _login(page, console, "admin", console.password)
        banner = page.locator("#password-banner")
        banner.wait_for()
        assert "generated" in banner.inner_text()
        screenshot(page, artifacts_dir, "accounts_first_login_banner")
        _open_dialog(page)
        # wrong current password: said beside that field
        _change(page, "not my password at all", NEW_ADMIN_PASSWORD)
        page.wait_for_function("document.getElementById('pw-current-msg').textContent"
                               ".includes('current password is wrong')")
        assert page.get_attribute("#pw-current", "aria-invalid") == "true"
        # the policy's sentence beside the new one
        _change(page, console.password, "short one")
        page.wait_for_function("document.getElementById('pw-new-msg').textContent"
                               ".includes('at least 12 characters')")
        assert page.inner_text("#pw-current-msg") == ""
        screenshot(page, artifacts_dir, "accounts_password_refused")
        _change(page, console.password, "admin's own gait lab", None)
        page.wait_for_function("document.getElementById('pw-new-msg').textContent"
                               ".includes('user name')")
        # two different new ones: refused before asking the server
        _change(page, console.password, NEW_ADMIN_PASSWORD, NEW_ADMIN_PASSWORD + "x")
        page.wait_for_function("document.getElementById('pw-repeat-msg').textContent"
                               ".includes('differ')")
        # two other logins of the administrator (other computers): the change ends them
        # and says so in words
        for _ in range(2):
            _api_login(console, "admin", console.password)
        _change(page, console.password, NEW_ADMIN_PASSWORD)
        page.wait_for_function("document.getElementById('pw-status').textContent"
                               ".includes('Password changed')")
        assert page.inner_text("#pw-status") == (
            "Password changed. 2 other logins (other browsers or computers) were ended; "
            "this one stays.")
        assert page.locator("#password-banner").count() == 0
        page.click("#pw-close")
        # the keyboard focus comes back to the menu it was opened from
        page.wait_for_function("document.activeElement === "
                               "document.querySelector('.user-menu summary')")
        old, console.password = console.password, NEW_ADMIN_PASSWORD
        # another browser: the old password no longer logs in, the new one does
        other = _page(browser)
        try:
            other.goto(console.base_url + "/index.html")
            other.fill("#username", "admin")
            other.fill("#password", old)
            other.click("button[type=submit]")
            other.wait_for_function("document.getElementById('login-error').textContent"
                                    ".includes('Wrong')")
            _login(other, console, "admin", NEW_ADMIN_PASSWORD)
            other.wait_for_selector(".user-menu")
            assert other.locator("#password-banner").count() == 0  # changed: no suggestion
        finally:
            other.context.close()
        assert not page.js_errors
    finally:
        page.context.close()


def _remove(page: Any, username: str, typed: str) -> None:
    row = page.locator(f"#accounts tr[data-user='{username}']")
    if row.locator("details.danger-zone").get_attribute("open") is None:
        row.locator("details.danger-zone summary").click()
    row.locator("details.danger-zone input").fill(typed)
    row.locator("details.danger-zone button[type=submit]").click()


def test_administrator_manages_accounts(browser: Any, console: Console,
                                        artifacts_dir: Path) -> None:
    admin = _page(browser)
    try:
        _login(admin, console, "admin", console.password)
        admin.click(".user-menu summary")
        admin.click("#accounts-link")
        admin.wait_for_url("**/accounts.html")
        admin.wait_for_selector("#accounts tr[data-user='admin']")
        assert admin.get_attribute("#accounts-link", "aria-current") == "page"
        # the console's first-visit checks: every field labelled, nothing hidden shown, no
        # "undefined" or "[object Object]" in the text
        got = admin.evaluate(AUDIT_JS)
        assert got["unlabeled"] == [] and got["shownHidden"] == [], got
        assert not LEAKED.search(got["text"]), got["text"]
        # a new colleague, with a temporary password
        admin.fill("#create-form [name=username]", "a.physio")
        admin.fill("#create-form [name=password]", "temporary gait 12")
        admin.click("#create-form button[type=submit]")
        admin.wait_for_function("document.getElementById('create-msg').textContent"
                                ".includes('Account a.physio created')")
        physio_row = admin.locator("#accounts tr[data-user='a.physio']")
        assert "temporary" in physio_row.inner_text() and "never" in physio_row.inner_text()
        # one's own account cannot be removed: the server's reason is shown
        _remove(admin, "admin", "admin")
        admin.wait_for_function("document.getElementById('accounts-msg').textContent"
                                ".includes('cannot remove your own account')")
        # the new user logs in, is asked to choose their own password, sees no Accounts
        physio = _page(browser)
        try:
            _login(physio, console, "a.physio", "temporary gait 12")
            physio.wait_for_selector("#password-banner")
            assert "administrator" in physio.inner_text("#password-banner")
            physio.click(".user-menu summary")
            physio.wait_for_selector("#password-open")
            assert physio.locator("#accounts-link").count() == 0
            physio.goto(console.base_url + "/accounts.html")
            physio.wait_for_selector("#not-admin:not([hidden])")
            assert "Only administrators manage accounts" in physio.inner_text("#not-admin")
            assert physio.locator("#admin-only").is_hidden()
            # they choose their own password: no more suggestion
            _open_dialog(physio)
            _change(physio, "temporary gait 12", "my own gait password 8")
            physio.wait_for_function("document.getElementById('pw-status').textContent"
                                     ".includes('Password changed')")
            assert physio.locator("#password-banner").count() == 0
            assert not physio.js_errors
        finally:
            physio.context.close()
        # removal needs the name typed again
        admin.reload()
        admin.wait_for_selector("#accounts tr[data-user='a.physio']")
        assert "never" not in physio_row.inner_text()  # the last login is shown
        assert "chosen by its owner" in physio_row.inner_text()
        # a forgotten password: the administrator sets a new one (a temporary one again)
        setpw = physio_row.locator("details.account-action:not(.danger-zone)")
        setpw.locator("summary").click()
        setpw.locator("input").fill("new temporary walk 5")
        setpw.locator("button[type=submit]").click()
        admin.wait_for_function("document.getElementById('accounts-msg').textContent"
                                ".includes('New password set for a.physio')")
        assert "temporary" in physio_row.inner_text()
        _remove(admin, "a.physio", "a.phys")
        admin.wait_for_function("document.getElementById('accounts-msg').textContent"
                                ".includes(\"type the user name 'a.physio'\")")
        _remove(admin, "a.physio", "a.physio")
        admin.wait_for_function("document.getElementById('accounts-msg').textContent"
                                ".includes('Account a.physio removed')")
        assert admin.locator("#accounts tr[data-user='a.physio']").count() == 0
        # the account changes in words
        log = admin.inner_text("#account-log")
        assert "admin created the account a.physio." in log
        assert "admin removed the account a.physio." in log
        screenshot(admin, artifacts_dir, "accounts_page")
        assert admin.get_attribute("#account-log li", "data-action") == "account"
        # on a tablet the header keeps to the screen with the menu open, "Log out" on one line
        admin.set_viewport_size({"width": 768, "height": 1024})
        admin.click(".user-menu summary")
        admin.wait_for_selector("#accounts-link")
        fits = admin.evaluate("""() => {
            const r = document.querySelector('.user-menu-items').getBoundingClientRect();
            const b = document.getElementById('logout');
            return [document.documentElement.scrollWidth <= document.documentElement.clientWidth,
                    r.left >= 0 && r.right <= document.documentElement.clientWidth,
                    b.clientHeight < 2 * parseFloat(getComputedStyle(b).lineHeight)]; }""")
        assert fits == [True, True, True], fits
        admin.keyboard.press("Escape")  # closes the menu, as a menu does
        assert admin.locator("#accounts-link").is_hidden()
        assert not admin.js_errors
    finally:
        admin.context.close()
