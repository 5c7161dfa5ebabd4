"""``gaitrig backup`` of a running server while a node's part is arriving (real server
and node processes): the part in transfer is left out and named, everything else is in
the archive; after the transfer a second backup holds it, and that backup restored into
a fresh folder serves the same subjects and recordings, its files byte-identical."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from app.server import backup as bk
from tests.app.data.test_record_flow import record, setup_session, wait_state
from tests.integration.conftest import Rig, wait_for

# chunks of 512 bytes at 0.3 s each (two channels) while the test holds the transfer back
# (the file exists): a 3-s part takes seconds, beyond the start-up of the backup command
# on a loaded machine; released once the backup has left it out
SLOW = {"GAITRIG_TEST_CHUNK_SIZE": "512", "GAITRIG_TEST_CHUNK_DELAY_S": "0.3"}


def _gaitrig(rig: Rig, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "app.cli", *args], env=rig.env,
                          capture_output=True, text=True, timeout=120)


def _sha_tree(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for d in ("recordings", "references") for p in sorted((root / d).rglob("*"))
            if p.is_file()}


def _listing(rig: Rig) -> list[tuple[str, list[tuple[str, str]]]]:
    out = []
    for s in rig.api("/api/subjects"):
        full = rig.api(f"/api/subjects/{s['id']}")
        out.append((s["code"], [(r["id"], r["state"]) for x in full["sessions"]
                                for r in x["recordings"]]))
    return sorted(out)


@pytest.mark.timeout(400)
def test_backup_while_a_part_arrives_then_restore(make_rig: Any, tmp_path: Path) -> None:
    hold = tmp_path / "hold-transfers"
    rig: Rig = make_rig({**SLOW, "GAITRIG_TEST_CHUNK_DELAY_FILE": str(hold)})
    rig.start_node("S1")
    rig.wait_online(["S1"])
    ids = setup_session(rig)
    done = record(rig, ids["session"]["id"], seconds=1.0)
    assert wait_state(rig, done, {"complete", "incomplete"}, timeout=120)["state"] == "complete"

    hold.touch()
    arriving = record(rig, ids["session"]["id"], seconds=3.0)
    incoming = tmp_path / "server" / "recordings" / arriving / "S1" / ".incoming"
    wait_for(incoming.is_dir, 30, "the part's transfer to be under way", step=0.05)
    first = tmp_path / "first.tar"
    p = _gaitrig(rig, "backup", str(first), "--data-dir", str(tmp_path / "server"))
    assert p.returncode == 0, p.stderr
    assert f"left out: recordings/{arriving}/S1: part still being transferred" in p.stdout
    man = bk.verify_backup(first).manifest
    names = {e["name"] for e in man["members"]}
    assert f"files/recordings/{done}/S1/frames.bin" in names
    assert not any(n.startswith(f"files/recordings/{arriving}/S1/") for n in names)
    assert man["counts"]["recordings"] == 2  # the row is in: its part is what is left out

    # the transfer was not disturbed; once complete a backup holds it
    hold.unlink()  # full speed from now on: the backup has seen it arriving
    assert wait_state(rig, arriving, {"complete", "incomplete"}, timeout=180)["state"] == (
        "complete")
    second = tmp_path / "second.tar"
    p = _gaitrig(rig, "backup", str(second), "--data-dir", str(tmp_path / "server"))
    assert p.returncode == 0 and "left out" not in p.stdout, p.stdout + p.stderr
    p = _gaitrig(rig, "backup", "--verify", str(second))
    assert p.returncode == 0, p.stderr
    assert rig.api("/api/system")["last_backup_at"] is not None
    before = _listing(rig)
    files = _sha_tree(tmp_path / "server")
    events = rig.api("/api/audit?action=backup")
    events = events.get("events", events) if isinstance(events, dict) else events
    assert [e["target"] for e in events][:2] == ["second.tar", "first.tar"]

    # restored into a fresh folder, a new server serves the same data
    other = tmp_path / "restored"
    p = _gaitrig(rig, "restore", str(second), "--data-dir", str(other / "server"),
                 "--deletion-log", str(tmp_path / "server"))
    assert p.returncode == 0, p.stderr
    rig.close()
    rig2 = Rig(other)
    try:
        assert _listing(rig2) == before
        assert _sha_tree(other / "server") == files
        r = rig2.api(f"/api/storage/recordings/{arriving}")
        assert r["state"] == "complete" and r["bytes_on_server"] > 0
        assert json.loads((other / "server" / "recordings" / arriving / "S1" / "manifest.json")
                          .read_text())["files"]
    finally:
        rig2.close()


@pytest.mark.browser
@pytest.mark.timeout(200)
def test_console_reminds_the_administrator_of_backups(make_rig: Any, browser: Any,
                                                     tmp_path: Path) -> None:
    from tests.integration.conftest import PASSWORD

    rig: Rig = make_rig()
    page = browser.new_context(viewport={"width": 1400, "height": 900}).new_page()
    page.set_default_timeout(20000)
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(rig.base + "/index.html")
    page.fill("#username", "admin")
    page.fill("#password", PASSWORD)
    page.click("button[type=submit]")
    page.wait_for_url("**/rig.html", timeout=15000)
    # never backed up: a quiet status line (not an alert), saying what to run
    page.wait_for_selector("#backup-notice", state="visible")
    note = page.locator("#backup-notice")
    assert "never been backed up" in note.inner_text() and "gaitrig backup" in note.inner_text()
    assert note.get_attribute("role") == "status"
    # a backup made: gone
    p = _gaitrig(rig, "backup", str(tmp_path / "b.tar"), "--data-dir", str(tmp_path / "server"))
    assert p.returncode == 0, p.stderr
    page.reload()
    page.wait_for_selector("#summary")
    page.wait_for_function("document.getElementById('summary').textContent !== 'Loading…'")
    assert page.locator("#backup-notice").count() == 0

    # the last one 8 days ago: said, with its date
    def old(route: Any) -> None:
        body = route.fetch().json()
        route.fulfill(status=200, content_type="application/json",
                      body=json.dumps({**body, "last_backup_at": "2020-01-02T03:00:00+00:00"}))

    page.route("**/api/system", old)
    page.reload()
    page.wait_for_selector("#backup-notice", state="visible")
    assert "No backup of this server since" in page.inner_text("#backup-notice")
    assert not errors
