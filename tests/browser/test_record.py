"""Record and Subjects pages in a real browser: a recording is filed under a new subject's
session, started and stopped from the Record page, transferred (progress bars), and the
Subjects page shows it complete with its export links; deletion needs the code."""

from __future__ import annotations

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
        "document.getElementById('session').selectedOptions[0].textContent.includes('(1 rec.)')")
    page.focus("#stop")
    page.keyboard.press("Enter")  # as a keyboard user: focus must not drop to the page
    page.wait_for_function("document.activeElement.id === 'rec-msg'")
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
