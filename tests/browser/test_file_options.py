"""The Reports page's "Analyse a file" has "Options for files from other labs" (collapsed):
a file whose vertical axis cannot be detected is refused with advice that names that
option (not "give it with --up"), and analysed once the vertical axis is chosen there.
Screenshot ``test-artifacts/browser/reports_file_options_1366.png`` (the open disclosure
at 1366 px)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from tests.app.test_upload_file_options import ambiguous_up_trc
from tests.browser.conftest import LiveServer, screenshot

pytestmark = pytest.mark.browser


def test_vertical_axis_chosen_on_the_page(page: Any, live_server: LiveServer,
                                          artifacts_dir: Path, tmp_path: Path) -> None:
    trc = ambiguous_up_trc(tmp_path / "other lab.trc")
    page.set_viewport_size({"width": 1366, "height": 768})
    page.goto(live_server.base_url + "/reports.html")
    assert not page.is_visible("#file-up")  # collapsed by default
    page.set_input_files("#file", str(trc))
    page.click("#file-form button[type=submit]")
    page.wait_for_function("document.getElementById('file-msg').textContent.includes('axis')")
    msg = page.text_content("#file-msg")
    assert "cannot tell the vertical axis" in msg, msg
    assert "choose the vertical axis under 'Options for files from other labs'" in msg, msg
    assert "--up" not in msg, msg

    page.click("#file-options summary")
    assert page.is_visible("#file-up")
    page.select_option("#file-up", "z")
    page.click("#file-form button[type=submit]")
    page.wait_for_function("document.getElementById('file-msg').textContent === 'Report below.'")
    assert "Walking speed" in page.text_content("#report")
    page.locator("#file-h").scroll_into_view_if_needed()
    # nothing of the open disclosure is cut or pushes the page sideways at 1366 px
    assert page.evaluate("document.documentElement.scrollWidth <= innerWidth")
    screenshot(page, artifacts_dir, "reports_file_options_1366",
               "section[aria-labelledby=file-h]")
    assert not page.js_errors
