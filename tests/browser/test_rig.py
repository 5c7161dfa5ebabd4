"""Rig page in a real browser: login works and every simulated node shows as online."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from tests.browser.conftest import LiveServer, color_fraction, screenshot

pytestmark = pytest.mark.browser


def test_login_and_all_nodes_online(page: Any, live_server: LiveServer,
                                    artifacts_dir: Path) -> None:
    rows = page.locator("#nodes tr[data-node]")
    rows.nth(live_server.n_nodes - 1).wait_for()
    page.wait_for_function(
        f"document.querySelectorAll('#nodes tr[data-node] .ok').length === {live_server.n_nodes}")
    ids = sorted(rows.nth(i).get_attribute("data-node") for i in range(rows.count()))
    assert ids == [f"S{k}" for k in range(1, live_server.n_nodes + 1)]
    img = screenshot(page, artifacts_dir, "rig_nodes_online")
    # the "online" labels are drawn in the OK green (#1a7f37): one per node is visible
    assert color_fraction(img, (0x1A, 0x7F, 0x37), tol=30) > 1e-4
    assert not page.is_visible("#token-warning")  # the demo pairs with a random token
    assert not page.js_errors


def test_shipped_node_token_is_warned_about(page: Any, live_server: LiveServer,
                                           artifacts_dir: Path) -> None:
    """A server still using the shipped pairing token: the Rig page says so and what to do."""
    import json

    def system(route: Any) -> None:
        body = route.fetch().json()
        route.fulfill(status=200, content_type="application/json",
                      body=json.dumps({**body, "node_token_is_default": True}))

    page.route("**/api/system", system)
    page.reload()
    page.wait_for_selector("#token-warning", state="visible")
    text = page.inner_text("#token-warning")
    assert "change-me-node-token" in text and "GAITRIG_NODE_TOKEN" in text
    page.screenshot(path=str(artifacts_dir / "rig_token_warning.png"))


def test_wrong_password_is_refused(browser: Any, live_server: LiveServer) -> None:
    ctx = browser.new_context()
    try:
        p = ctx.new_page()
        p.goto(live_server.base_url + "/index.html")
        p.fill("#username", "admin")
        p.fill("#password", live_server.password + "x")
        p.click("button[type=submit]")
        p.wait_for_function("document.getElementById('login-error').textContent.length > 0")
        assert "Wrong" in p.inner_text("#login-error")
        assert p.url.endswith("/index.html")
    finally:
        ctx.close()
