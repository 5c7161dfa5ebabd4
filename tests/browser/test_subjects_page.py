"""Subjects page in a real browser: two browsers edit one subject (the stale save is
refused with a message, nothing overwritten), and the subject's full export is offered."""

from __future__ import annotations

import contextlib
import io
import json
import re
import sqlite3
import zipfile
from pathlib import Path
from typing import Any

import pytest

from tests.browser.conftest import LiveServer, login

pytestmark = pytest.mark.browser


def _open(page: Any, server: LiveServer, sid: int) -> None:
    page.goto(f"{server.base_url}/subjects.html#subject={sid}")
    page.wait_for_function("document.querySelector('#edit-form [name=code]').value === 'EDT01'")


def test_two_browsers_edit_one_subject(page: Any, browser: Any, live_server: LiveServer) -> None:
    p = live_server.api("/api/projects", {"name": "Edit race"})
    s = live_server.api("/api/subjects", {"project_id": p["id"], "code": "EDT01"})
    other_ctx = browser.new_context(viewport={"width": 1400, "height": 900})
    try:
        other = other_ctx.new_page()
        other.set_default_timeout(20000)
        login(other, live_server)
        _open(page, live_server, s["id"])
        _open(other, live_server, s["id"])
        page.fill("#edit-form [name=height_cm]", "172")
        page.click("#edit-form button[type=submit]")
        page.wait_for_function("document.getElementById('edit-msg').textContent === 'Saved.'")
        other.fill("#edit-form [name=notes]", "uses a cane")
        other.click("#edit-form button[type=submit]")
        other.wait_for_function(
            "document.getElementById('edit-msg').textContent.includes('someone else')")
        got = live_server.api(f"/api/subjects/{s['id']}")
        assert got["height_m"] == pytest.approx(1.72) and got["notes"] == ""
        # after a reload the second browser saves on top of the first one's change
        other.reload()
        other.wait_for_function(
            "Number(document.querySelector('#edit-form [name=height_cm]').value) === 172")
        other.fill("#edit-form [name=notes]", "uses a cane")
        other.click("#edit-form button[type=submit]")
        other.wait_for_function("document.getElementById('edit-msg').textContent === 'Saved.'")
        got = live_server.api(f"/api/subjects/{s['id']}")
        assert got["height_m"] == pytest.approx(1.72) and got["notes"] == "uses a cane"
        # the whole subject as one download; the page says it is being prepared (the link
        # said nothing while the zip was put together), then why it was refused
        link = page.locator("#export-link")
        assert link.get_attribute("href") == f"/api/subjects/{s['id']}/export"
        held: list[Any] = []
        page.route(f"**/api/subjects/{s['id']}/export", lambda route: held.append(route))
        link.click()
        page.wait_for_function("document.getElementById('export-msg').textContent"
                               ".startsWith('Preparing all data of EDT01 (zip)…')")
        assert page.get_attribute("#export-msg", "role") == "status"
        assert link.get_attribute("aria-disabled") == "true"
        link.click(force=True)  # a second press while it runs asks for nothing more
        held[0].fulfill(status=409, json={"detail": "the subject is being deleted"})
        page.wait_for_function("document.getElementById('export-msg').textContent.includes("
                               "'not exported')")
        assert page.text_content("#export-msg") == (
            "All data of EDT01 (zip) not exported: the subject is being deleted")
        assert len(held) == 1 and link.get_attribute("aria-disabled") is None
        page.unroute(f"**/api/subjects/{s['id']}/export")
        with page.expect_download() as dl:
            link.click()
        z = zipfile.ZipFile(io.BytesIO(Path(dl.value.path()).read_bytes()))
        assert json.loads(z.read("subject.json"))["code"] == "EDT01"
        page.wait_for_function("document.getElementById('export-msg').textContent"
                               ".includes('downloaded')")
        said = page.text_content("#export-msg") or ""
        name = dl.value.suggested_filename
        assert said.startswith(f"All data of EDT01 (zip) downloaded ({name}, "), said
        assert re.search(r", \d+ kB\)\.$|, [\d.]+ MB\)\.$", said), said
        # the administrator downloads the audit trail, which recorded that export
        page.wait_for_selector("#audit:not([hidden])")
        with page.expect_download() as dl:
            page.click("#audit-link")
        trail = Path(dl.value.path()).read_text()
        assert f"export,subject {s['id']}" in trail, trail[:500]
        assert not page.js_errors
    finally:
        other_ctx.close()


def test_delete_a_recording_filed_under_no_session(page: Any, live_server: LiveServer) -> None:
    import time

    p = live_server.api("/api/projects", {"name": "Unfiled"})
    s = live_server.api("/api/subjects", {"project_id": p["id"], "code": "UNF01"})
    live_server.api("/api/sessions", {"subject_id": s["id"], "label": "visit"})
    rec = live_server.api("/api/recordings", {})["id"]
    time.sleep(1.0)
    live_server.api(f"/api/recordings/{rec}/stop", {})
    page.goto(f"{live_server.base_url}/subjects.html#subject={s['id']}")
    row = page.locator(f"[data-unfiled='{rec}']")
    row.wait_for()
    row.locator("summary").click()
    row.locator("input").fill(rec[:-1])  # a wrong confirmation deletes nothing
    row.locator("button.danger").click()
    page.wait_for_function(
        f"document.getElementById('session-msg').textContent.includes(\"'{rec}'\")")
    assert rec in [r["id"] for r in live_server.api("/api/storage/unfiled")]
    # the transfer after the stop must be over before a deletion is accepted
    deadline = time.time() + 60
    while (time.time() < deadline
           and live_server.api(f"/api/recordings/{rec}")["state"] != "complete"):
        time.sleep(0.5)
    row.locator("input").fill(rec)
    row.locator("button.danger").click()
    page.wait_for_function("document.getElementById('session-msg').textContent.includes('deleted')")
    assert rec not in [r["id"] for r in live_server.api("/api/storage/unfiled")]
    page.wait_for_function(f"!document.querySelector(\"[data-unfiled='{rec}']\")")
    assert not page.js_errors


def test_subjects_page_says_what_happened_to_each_part(page: Any,
                                                       live_server: LiveServer) -> None:
    """A part recorded partly without images says so (the count comes from the server
    copy's meta.json through GET /api/recordings), and a complete part keeps its reason
    (e.g. its node reconnected and kept recording) as a note, not an error."""
    import time

    p = live_server.api("/api/projects", {"name": "Part notes"})
    s = live_server.api("/api/subjects", {"project_id": p["id"], "code": "NTS01"})
    sess = live_server.api("/api/sessions", {"subject_id": s["id"], "label": "visit"})
    rid = live_server.api(f"/api/sessions/{sess['id']}/recordings", {"label": "walk"})["id"]
    time.sleep(1.0)
    live_server.api(f"/api/recordings/{rid}/stop", {})
    deadline = time.time() + 60
    while (time.time() < deadline
           and live_server.api(f"/api/storage/recordings/{rid}")["state"] != "complete"):
        time.sleep(0.5)
    nodes = sorted(x["node_id"] for x in live_server.api(f"/api/recordings/{rid}")["parts"])
    assert len(nodes) >= 2
    # what a node writes into the part's meta.json when its image encoder fell behind,
    # and the server stores in the part's row when the part arrives (done by now: the
    # recording is complete; no real node can be made to fall behind here)
    server_dir = live_server.data_dir / "server"
    meta_path = server_dir / "recordings" / rid / nodes[0] / "meta.json"
    meta = json.loads(meta_path.read_text())
    meta["images_skipped"] = 5
    meta_path.write_text(json.dumps(meta))
    with contextlib.closing(sqlite3.connect(server_dir / "gaitrig.sqlite3")) as db, db:
        n = db.execute("update recording_parts set images_skipped = 5 where recording_id = ? "
                       "and node_id = ? and images_skipped = 0", (rid, nodes[0])).rowcount
    assert n == 1  # the count stored on arrival (0 then) is what the page shows
    got = live_server.api(f"/api/recordings/{rid}")
    skipped = {x["node_id"]: x["images_skipped"] for x in got["parts"]}
    assert skipped == {n: 5 if n == nodes[0] else 0 for n in nodes}
    assert got["not_in_recording"] == []  # every node online was in it
    kept = (f"node {nodes[1]} disconnected at 10:00:02 UTC during the recording; the node "
            "kept recording")

    def with_reason(route: Any) -> None:  # no real node can be made to drop here
        resp = route.fetch()
        body = resp.json()
        for r in body:
            for part in r["parts"]:
                if r["id"] == rid and part["node_id"] == nodes[1]:
                    part["reason"] = kept
        route.fulfill(response=resp, json=body)

    page.route("**/api/recordings?ids=*", with_reason)
    page.goto(f"{live_server.base_url}/subjects.html#subject={s['id']}")
    box = page.locator(f".recording[data-recording='{rid}'][data-state=complete]")
    box.wait_for()
    first = box.locator(f".part[data-node='{nodes[0]}']")
    first.locator(".note[data-kind=images-skipped]").wait_for()
    assert "5 frames without their images" in first.inner_text()
    second = box.locator(f".part[data-node='{nodes[1]}']")
    assert kept in second.locator(".note[data-kind=reason]").inner_text()
    assert box.locator(".reason").count() == 0  # nothing shown as an error
    assert not page.js_errors


def test_attach_reference_says_each_outcome(page: Any, live_server: LiveServer,
                                            artifacts_dir: Path, tmp_path: Path) -> None:
    """"Attach reference" (one per recording) says what happened and keeps saying it: the
    recording list is drawn again after an attach (and every second while a recording is
    busy), which wiped "Attached." at once; a broken connection left "Uploading…" for
    ever with no error handled; a refusal names the file; a logged-out session goes to
    the login; the button is usable again after each."""
    import time

    from engine.io.c3d import write_c3d
    from engine.sim.straight_walk import synth_walk, walk_markers
    from tests.browser.conftest import screenshot

    walk = tmp_path / "vicon walk.c3d"
    write_c3d(walk, walk_markers(synth_walk()), units="mm")
    damaged = tmp_path / "trial 3.c3d"
    damaged.write_bytes(walk.read_bytes()[:8] + b"not a c3d file at all")
    p = live_server.api("/api/projects", {"name": "Reference upload"})
    s = live_server.api("/api/subjects", {"project_id": p["id"], "code": "REF01"})
    sess = live_server.api("/api/sessions", {"subject_id": s["id"], "label": "visit"})
    rid = live_server.api(f"/api/sessions/{sess['id']}/recordings", {"label": "walk"})["id"]
    time.sleep(1.0)
    live_server.api(f"/api/recordings/{rid}/stop", {})
    page.goto(f"{live_server.base_url}/subjects.html#subject={s['id']}")
    # (the recording's box with the file input: the same before and after this fix)
    box_sel = f".recording[data-recording='{rid}'] .actions:has(input[type=file])"
    page.locator(box_sel).wait_for()
    msg = f"document.querySelector(\"{box_sel} .msg\")"

    def choose_and_attach() -> None:
        page.locator(f"{box_sel} input[type=file]").set_input_files(str(walk))
        page.locator(f"{box_sel} button").click()

    # the server's answer held: "Uploading…", the button disabled; then the server's
    # refusal of a damaged C3D file, in words (not ezc3d's "iostream error")
    url = f"**/api/exports/{rid}/references"
    held: list[Any] = []
    page.route(url, lambda route: held.append(route))
    page.locator(f"{box_sel} input[type=file]").set_input_files(str(damaged))
    page.locator(f"{box_sel} button").click()
    page.wait_for_function(f"{msg}.textContent === 'Uploading trial 3.c3d…'")
    assert page.locator(f"{box_sel} button").is_disabled()
    held[0].continue_()
    page.wait_for_function(f"{msg}.textContent.includes('ot attached')")
    assert page.text_content(f"{box_sel} .msg") == (
        "Not attached: 'trial 3.c3d' is not a readable C3D file: the file is damaged or not "
        "a C3D file (export it again from the motion-capture software, as C3D)")
    assert "bad" in (page.get_attribute(f"{box_sel} .msg", "class") or "")
    assert page.locator(f"{box_sel} button").is_enabled()
    row = f".recording[data-recording='{rid}']"
    screenshot(page, artifacts_dir, "subjects_reference_damaged_c3d", row)
    page.unroute(url)

    # the connection breaks off: said, and the button is usable again
    page.route(url, lambda route: route.abort("connectionreset"))
    choose_and_attach()
    page.wait_for_function(f"{msg}.textContent.includes('broke off')")
    assert page.text_content(f"{box_sel} .msg") == (
        "vicon walk.c3d not attached: the connection to the server broke off; try again")
    assert page.locator(f"{box_sel} button").is_enabled()
    screenshot(page, artifacts_dir, "subjects_reference_failed", row)
    page.unroute(url)

    # the file chosen stays chosen when the list is drawn again before the press (as every
    # second while a recording is busy; here: a session added)
    page.locator(f"{box_sel} input[type=file]").set_input_files(str(walk))
    n_sessions = page.locator(".session[data-session]").count()
    page.fill("#session-form [name=label]", "second visit")
    page.click("#session-form button[type=submit]")
    page.wait_for_function(
        f"document.querySelectorAll('.session[data-session]').length === {n_sessions + 1}")
    # attached: the list is drawn again with the reference, and the message stays
    page.locator(f"{box_sel} button").click()
    page.locator(f"{box_sel} a.button").wait_for()
    page.wait_for_function(f"{msg}.textContent.includes('attached')")
    assert (page.text_content(f"{box_sel} .msg") or "").startswith("vicon walk.c3d attached.")
    assert "good" in (page.get_attribute(f"{box_sel} .msg", "class") or "")
    # which of the two kinds of reference a report uses, said where they are attached
    assert page.text_content(f"{box_sel} [data-kind=reference-used]") == (
        "Reports use this reference, unless one is attached to this recording on the "
        "Reports page.")
    assert page.locator(f"{box_sel} button").is_enabled()
    assert [x["filename"] for x in live_server.api(f"/api/exports/{rid}/references")] == [
        "vicon walk.c3d"]
    screenshot(page, artifacts_dir, "subjects_reference_attached", row)
    assert not page.js_errors

    # a session that ran out goes to the login, and back to this subject after it
    page.route(url, lambda route: route.fulfill(status=401, json={"detail": "not logged in"}))
    choose_and_attach()
    page.wait_for_url("**/index.html?next=*")
    assert f"subject%3D{s['id']}" in page.url or f"subject={s['id']}" in page.url


#: The Subjects list's headings that take more than one line (a word broken at a soft
#: hyphen, or at all): each line of a heading's text is a box of its own.
BROKEN_HEADINGS_JS = """() => [...document.querySelectorAll(
    "section[aria-labelledby=subj-h] thead th")].filter((th) => {
  const r = document.createRange(); r.selectNodeContents(th);
  return new Set([...r.getClientRects()].map((b) => Math.round(b.top))).size > 1;
}).map((th) => th.textContent)"""


def test_subject_codes_stay_on_one_line(page: Any, live_server: LiveServer,
                                        artifacts_dir: Path) -> None:
    """In the narrow list column at 1400 px a code broke inside itself ("A11Y" over "01",
    read as two codes), and with a long code listed the count headings broke at their soft
    hyphens ("Ses-sions"). Every code and heading is on one line at every width from 320
    to 1920 px and the list fits its card; a code too long for the column ends in "…" and
    keeps the whole code as its link's name and title, and on a wide screen a study's
    code of 12 characters is whole ("KNEE-OA-01…" at 1400 px)."""
    from tests.browser.conftest import screenshot, short_recording

    p = live_server.api("/api/projects", {"name": "One-line codes"})
    codes = ["A11Y01", "KBD07", "P2026-0117", "KNEE-OA-0117",
             "LONGCODE_abcdefghijklmnopqrstuvwxyz01234"]
    ids = [live_server.api("/api/subjects", {"project_id": p["id"], "code": c})["id"]
           for c in codes]
    session = live_server.api("/api/sessions", {"subject_id": ids[0], "label": "first visit"})
    short_recording(live_server, session["id"], "walk 1")  # (a size in kB in its row)
    page.goto(f"{live_server.base_url}/subjects.html#subject={ids[0]}")
    page.wait_for_selector("tr[data-subject='A11Y01'] a")
    headings = page.eval_on_selector_all("section[aria-labelledby=subj-h] thead th",
                                         "ths => ths.map(th => th.textContent)")
    assert [h.replace("\u00ad", "") for h in headings] == ["Code", "Sessions", "Recordings",
                                                          "Size"], headings
    measure = """(codes) => codes.map((c) => {
      const a = document.querySelector(`tr[data-subject="${c}"] a`);
      const line = parseFloat(getComputedStyle(a).lineHeight);
      return { code: c, lines: Math.round(a.getBoundingClientRect().height / line),
               cut: a.scrollWidth > a.clientWidth + 1, title: a.title, text: a.textContent };
    })"""
    for w in (1920, 1400, 1024, 901, 900, 768, 600, 320):
        page.set_viewport_size({"width": w, "height": 900})
        table = page.locator("section[aria-labelledby=subj-h] table")
        table.scroll_into_view_if_needed()
        screenshot(page, artifacts_dir, f"subjects_codes_{w}",
                   "section[aria-labelledby=subj-h] table")
        if w in (1400, 901):
            screenshot(page, artifacts_dir, f"subjects_page_{w}")
        got = page.evaluate(measure, codes)
        assert all(g["lines"] == 1 for g in got), (w, got)
        assert all(g["text"] == c and g["title"] == c for g, c in zip(got, codes, strict=True)), got
        # short codes are whole; the 40 characters end in "…"; a 10-character code is
        # whole from a tablet up, a 12-character one on a wide screen
        cut = [g["code"] for g in got if g["cut"]]
        assert codes[-1] in cut and not set(cut) & set(codes[:2]), (w, got)
        if w >= 768:
            assert "P2026-0117" not in cut, (w, got)
        if w >= 1400:
            assert cut == codes[-1:], (w, got)
        assert page.evaluate(BROKEN_HEADINGS_JS) == [], w
        if w == 1920:  # the page takes a wide screen's room (up to 1500 px), prose does not
            assert page.evaluate("document.querySelector('main').getBoundingClientRect()"
                                 ".width") > 1400
            assert page.evaluate("Math.max(...[...document.querySelectorAll('main > p')]"
                                 ".map(p => p.getBoundingClientRect().width))") <= 1200.5
        assert page.evaluate("document.documentElement.scrollWidth <= innerWidth"), w
        assert table.evaluate("t => t.parentElement.scrollWidth <= t.parentElement.clientWidth"), w
        # every cell measured at once in the page (the polled list may be drawn anew
        # between taking a cell and measuring it)
        out = page.evaluate("""() => {
          const card = document.querySelector("section[aria-labelledby=subj-h]")
            .getBoundingClientRect();
          const cells = [...document.querySelectorAll("#subjects tr[data-subject] > *")];
          return { n: cells.length, out: cells
            .filter((c) => c.getBoundingClientRect().right > card.right + 0.5)
            .map((c) => c.textContent) };
        }""")
        assert out["n"] >= 4 * len(codes) and out["out"] == [], (w, out)
    # the whole code is the link's accessible name
    assert page.get_by_role("link", name=codes[-1], exact=True).count() == 1
    assert not page.js_errors, page.js_errors
