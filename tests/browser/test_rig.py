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


def test_disk_column_says_what_the_node_holds(page: Any, live_server: LiveServer) -> None:
    """Free space, and the node's own recordings: how many, and how many the server does
    not hold verified yet (the only copies, which the node never deletes)."""
    import json

    def with_storage(route: Any) -> None:
        nodes = json.loads(route.fetch().text())
        for n in nodes:
            n["storage"] = ({"held_parts": 3, "held_bytes": 3 * 2**30, "unverified_parts": 1,
                             "keep_verified_days": 7, "min_free_bytes": 5 * 2**30}
                            if n["id"] == "S1" else None)
        route.fulfill(status=200, content_type="application/json", body=json.dumps(nodes))

    page.route("**/api/nodes", with_storage)
    page.reload()
    s1, s2 = page.locator("#nodes tr[data-node=S1]"), page.locator("#nodes tr[data-node=S2]")
    s1.wait_for()
    page.wait_for_function(
        "document.querySelector('#nodes tr[data-node=S1]').textContent.includes('recording part')")
    text = s1.inner_text()
    assert "GB free" in text and "3 recording parts (3.0 GB)" in text, text
    assert "1 not yet on the server" in text, text
    assert "recording part" not in s2.inner_text() and "GB free" in s2.inner_text()
    title = s1.locator(".disk").get_attribute("title") or ""
    assert "7 days after verification" in title and "never deleted" in title
    assert not page.js_errors
