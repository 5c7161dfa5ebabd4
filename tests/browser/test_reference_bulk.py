"""The Reports page's "Attach references to several recordings" (card "Agreement with a
reference system"): the reference files of a project's walks chosen at once, each matched
to its recording by its name (trial label, with the subject code when labels repeat over
subjects; never a guess between two), checked (two files for one recording, a file with no
recording), then attached one after another through the one-recording upload: a refused
file says the server's words in its row, the others stay attached, and its recording keeps
the reference it had. The project's agreement study then counts the attached walks.

Screenshots ``test-artifacts/browser/reports_bulk_references.png`` (1366 px, after
"Attach all") and ``reports_bulk_references_1024.png``."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from tests.browser.conftest import LiveServer, screenshot, short_recording
from tests.browser.test_reference_messages import NOT_C3D

pytestmark = pytest.mark.browser

MSG = "document.getElementById('bulk-msg').textContent"


def _cached_walk(server: LiveServer, rid: str, walker: str, seed: int) -> None:
    """Put a simulated walk's analysis in recording ``rid``'s analysis cache (as
    test_reference_messages's agreement test does: a short recording has too few steps)."""
    from app.server import analysis as an
    from tests.app.study_walks import walk_analysis

    sensors = [s["id"] for s in server.api(f"/api/reports/recordings/{rid}/sensors")["sensors"]]
    d = an.recording_dir(server.data_dir / "server", rid)
    cache = d / "analysis" / f"{an.AnalysisOptions().key()}-{an._fingerprint(d)}.json"
    cache.parent.mkdir(exist_ok=True)
    cache.write_text(json.dumps(walk_analysis(rid, walker, seed, tuple(sensors))))


def _rows(page: Any) -> list[dict[str, str]]:
    return page.evaluate("""() => [...document.querySelectorAll('#bulk-table tbody tr')].map(
        (tr) => ({file: tr.cells[0].textContent, rec: tr.querySelector('select').value,
                  label: tr.querySelector('select').getAttribute('aria-label'),
                  offset: tr.querySelector('input').value, now: tr.cells[3].textContent,
                  result: tr.cells[4].textContent}))""")


def _choose(page: Any, files: list[Path], n_rows: int | None = None) -> None:
    """Choose ``files`` under "Reference files" and wait for their rows (``n_rows``: a
    manifest among them has none)."""
    page.set_input_files("#bulk-files", [str(f) for f in files])
    page.wait_for_function(f"document.querySelectorAll('#bulk-table tbody tr').length === "
                           f"{len(files) if n_rows is None else n_rows} && "
                           "!document.getElementById('bulk-table').hidden")


def _reference(server: LiveServer, rid: str) -> dict[str, Any]:
    return server.api(f"/api/reports/recordings/{rid}/reference")


def test_reports_page_attaches_references_to_several_recordings(
        page: Any, live_server: LiveServer, artifacts_dir: Path, tmp_path: Path) -> None:
    from tests.app.mocap_files import standing_trc
    from tests.app.study_walks import walk_reference_csv

    pid = live_server.api("/api/projects", {"name": "Bulk references"})["id"]
    sessions = []
    for code in ("BLK1", "BLK2"):
        sid = live_server.api("/api/subjects", {"project_id": pid, "code": code})["id"]
        sessions.append(live_server.api("/api/sessions", {"subject_id": sid, "label": "lab"})["id"])
    # both subjects' first walk is "walk 1": a file's name tells them apart by the code
    r1 = short_recording(live_server, sessions[0], "walk 1")
    r2 = short_recording(live_server, sessions[1], "walk 1")
    r3 = short_recording(live_server, sessions[1], "walk 2")
    _cached_walk(live_server, r1, "V01", 1)
    _cached_walk(live_server, r2, "V02", 2)
    good1 = walk_reference_csv(tmp_path / "vicon BLK1 walk 1.csv", "V01", 1)
    good2 = walk_reference_csv(tmp_path / "Vicon_blk2-Walk1.csv", "V02", 2)
    broken = tmp_path / "BLK2 walk 2.c3d"
    broken.write_bytes(b"\x02\x50" + b"\x00" * 6 + b"not a c3d file at all")
    either = tmp_path / "walk 1.trc"  # fits both subjects' walk 1: not guessed
    either.write_text("PathFileType\t4\n")

    page.set_viewport_size({"width": 1366, "height": 900})
    page.goto(live_server.base_url + "/reports.html")
    page.wait_for_function("[...document.querySelectorAll('#study-project option')]"
                           f".some(o => o.value === '{pid}')")
    page.select_option("#study-project", str(pid))
    page.click("#bulk-ref summary")
    _choose(page, [good1, good2, broken, either])
    rows = _rows(page)
    assert [r["rec"] for r in rows] == [r1, r2, r3, ""], rows
    assert [r["label"] for r in rows] == [f"Recording for {f.name}"
                                          for f in (good1, good2, broken, either)]
    assert [r["offset"] for r in rows] == ["0"] * 4
    assert [r["now"] for r in rows] == ["none", "none", "none", ""]
    assert rows[3]["result"] == ("Its name fits 2 recordings (BLK1 walk 1; BLK2 walk 1): "
                                 "choose one.")
    assert page.text_content("#bulk-state") == (
        "4 files: 3 matched to a recording by name, 1 to choose (“— choose —”); then press "
        "“Attach all”.")

    # a file without a recording, then two files for one recording: said, nothing sent
    page.click("#bulk-attach")
    page.wait_for_function(f"{MSG}.startsWith('Choose a recording for')")
    assert page.text_content("#bulk-msg") == (
        "Choose a recording for walk 1.trc (or “Leave this file out”).")
    assert page.evaluate("document.activeElement.id") == "bulk-rec-3"
    page.select_option("#bulk-rec-3", r1)
    rows = _rows(page)
    assert rows[0]["result"] == "Also chosen for walk 1.trc: a recording takes one reference."
    assert rows[3]["result"] == ("Also chosen for vicon BLK1 walk 1.csv: a recording takes "
                                 "one reference.")
    page.click("#bulk-attach")
    page.wait_for_function(f"{MSG}.startsWith('Two files')")
    assert "Nothing was attached." in (page.text_content("#bulk-msg") or "")
    assert not _reference(live_server, r1)["attached"]

    # the ambiguous file left out; the broken one refused in its row, the others attached
    page.select_option("#bulk-rec-3", "-")
    page.click("#bulk-attach")
    page.wait_for_function(f"{MSG}.includes(' of 3 attached') && !{MSG}.endsWith('…')")
    assert page.text_content("#bulk-msg") == (
        "2 of 3 attached; not attached: BLK2 walk 2.c3d — its row says why. Press “Attach "
        "all” again once fixed: attached files are not sent again.")
    assert "error" in (page.get_attribute("#bulk-msg", "class") or "")
    ref1, ref2 = _reference(live_server, r1), _reference(live_server, r2)
    assert ref1["attached"] and ref1["filename"] == good1.name and ref1["n_steps"] > 3
    assert ref2["attached"] and ref2["filename"] == good2.name
    assert not _reference(live_server, r3)["attached"]
    rows = _rows(page)
    assert [r["result"] for r in rows] == [
        f"Attached: {ref1['n_steps']} steps", f"Attached: {ref2['n_steps']} steps",
        f"Not attached: {NOT_C3D.replace('trial 3.c3d', broken.name)}", ""]
    assert rows[0]["now"] == f"{good1.name} ({ref1['n_steps']} steps)"
    fits = page.evaluate("document.documentElement.scrollWidth <= innerWidth")
    screenshot(page, artifacts_dir, "reports_bulk_references", "#bulk-ref")
    assert fits

    # the agreement study counts both walks
    page.click("#study-show")
    page.wait_for_function("document.getElementById('study-msg').textContent === "
                           "'Agreement below.' || document.getElementById('study-msg')"
                           ".classList.contains('error')", timeout=60_000)
    assert page.text_content("#study-msg") == "Agreement below."
    assert ("Project Bulk references: 2 subjects, 2 trials with a reference"
            in (page.text_content("#report") or ""))

    # a refused file leaves the recording's reference as it was, and says so
    still = standing_trc(tmp_path / "BLK1 walk 1 standing.trc")
    _choose(page, [still])
    page.wait_for_function("document.querySelector('#bulk-table tbody td:nth-child(4)')"
                           ".textContent.includes('steps')")
    rows = _rows(page)
    assert rows[0]["rec"] == r1 and rows[0]["now"] == f"{good1.name} ({ref1['n_steps']} steps)"
    page.click("#bulk-attach")
    page.wait_for_function(f"{MSG}.startsWith('0 of 1 attached;')")
    said = _rows(page)[0]["result"]
    assert said.startswith("Not attached: 'BLK1 walk 1 standing.trc' has no walk in it"), said
    assert f"'{good1.name}' stays attached" in said, said
    assert _reference(live_server, r1)["filename"] == good1.name

    # a manifest chooses each file's recording (by code, or label and subject) and start
    manifest = tmp_path / "manifest.csv"
    manifest.write_text(f"recording,subject,reference,offset_s\n{r3},,walk 1.trc,0.25\n"
                        "Walk 1,blk2,BLK2 walk 2.c3d,-1.5\n")
    _choose(page, [manifest, either, broken], 2)
    rows = _rows(page)
    assert [(r["file"], r["rec"], r["offset"]) for r in rows] == [
        ("walk 1.trc", r3, "0.25"), ("BLK2 walk 2.c3d", r2, "-1.5")], rows

    # 1024 px: the table in the card's width
    page.set_viewport_size({"width": 1024, "height": 800})
    _choose(page, [good1, good2, broken, either])
    page.wait_for_function("document.querySelector('#bulk-table tbody td:nth-child(4)')"
                           ".textContent.includes('steps')")
    assert page.evaluate("document.documentElement.scrollWidth <= innerWidth")
    assert page.evaluate("(() => { const b = document.querySelector('#bulk-table')"
                         ".parentElement; return b.scrollWidth <= b.clientWidth; })()")
    screenshot(page, artifacts_dir, "reports_bulk_references_1024", "#bulk-ref")
    assert not page.js_errors
