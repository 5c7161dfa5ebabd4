"""The minimal console in headless Debian Chromium: log in by keyboard, see the nodes."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest

from tests.integration.conftest import PASSWORD, Rig

pytestmark = [pytest.mark.browser, pytest.mark.slow]


def test_login_and_rig_page(make_rig: object, artifacts_dir: Path, browser: Any) -> None:
    rig: Rig = make_rig()  # type: ignore[operator]
    rig.start_node("S1", "--clock-offset", "0.2", "--clock-drift-ppm", "0")
    rig.start_node("S2", "--clock-offset", "0.0", "--clock-drift-ppm", "0")
    rig.wait_online(["S1", "S2"])
    context = browser.new_context()
    try:
        page = context.new_page()
        page.goto(rig.base + "/rig.html")
        page.wait_for_url("**/index.html?next=*")  # not logged in → login page (and back)
        # the user name field has focus (autofocus; typed keys must not go elsewhere)
        page.wait_for_function("document.activeElement && document.activeElement.id === 'username'")
        page.keyboard.type("admin")
        page.keyboard.press("Tab")
        page.keyboard.type("wrong")
        page.keyboard.press("Enter")
        page.wait_for_selector("#login-error:has-text('Wrong user name or password')")
        page.fill("#password", PASSWORD)
        page.keyboard.press("Enter")
        page.wait_for_url("**/rig.html")
        page.wait_for_selector("tr[data-node='S2']")
        page.wait_for_selector("#summary:has-text('2 of 2 sensors online')")
        s1 = page.inner_text("tr[data-node='S1']")
        assert "online" in s1 and "fps" in s1
        # S1's clock is 200 ms off: shown, with the plain-words note; S2 needs no note
        # (the true 200 ms within the uncertainty shown, and that below the 2 ms warning:
        # on a loaded machine the estimate is 0.5-1 ms off, and says so)
        m = re.search(r"(\d+\.\d\d) ms ± (\d+\.\d\d) ms", s1)
        assert m, s1
        offset, sd = float(m[1]), float(m[2])
        assert sd < 2.0 and abs(offset - 200.0) <= max(0.5, sd), s1
        note = re.search(r"differs from the server by \+(\d+\.\d) ms", s1)
        # (the note rounds to 0.1 ms: 200.05 is said as 200.0 or 200.1)
        assert note and abs(float(note[1]) - offset) <= 0.05 + 1e-9, s1
        assert "Clock" not in page.inner_text("tr[data-node='S2'] td:last-child")
        # record from the console: both sensors, complete on the nodes after stop
        page.click("#record")
        page.wait_for_selector("#record:has-text('Stop recording')")
        page.wait_for_timeout(1000)
        page.click("#record")
        # closed on the sensors; copied to the server by the button or by the automatic
        # sync of the data management, whichever comes first
        row = ("tr[data-recording] td.state:has-text('complete on the sensors'), "
               "tr[data-recording] td.state:has-text('copying'), "
               "tr[data-recording] td.state:has-text('complete on the server')")
        page.wait_for_selector(row, timeout=45000)
        assert page.locator("tr[data-recording] li").count() == 2
        button = page.locator("tr[data-recording] button.transfer")
        if button.count():
            from playwright.sync_api import TimeoutError as PlaywrightTimeout

            # the automatic sync may start the copy (and the button goes) at any moment
            try:
                button.first.click(timeout=5000)
            except PlaywrightTimeout:
                assert button.count() == 0, "the Copy to server button stayed but took no click"
        page.wait_for_selector("tr[data-recording] td.state:has-text('complete on the server')",
                               timeout=60000)
        page.screenshot(path=str(artifacts_dir / "console-rig.png"), full_page=True)
        rig.procs["S2"].terminate()
        page.wait_for_selector("tr[data-node='S2']:has-text('offline')", timeout=15000)
        page.click("#logout")
        page.wait_for_url("**/index.html")
    finally:
        context.close()
