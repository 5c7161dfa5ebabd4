"""The Reports page's two uploads of a file from another system — the reference of the
agreement section and "Analyse a file" — say in words what a damaged C3D file is not and
what to do (ezc3d's "File must be a valid c3d file: iostream error" ended both messages).
Screenshots ``test-artifacts/browser/reports_reference_damaged_c3d.png``,
``reports_file_damaged_c3d.png`` and ``reports_file_not_trc.png``; each message names the
file once.

And which of a recording's references its reports use (one attached on the Reports page,
else the newest attached on the Subjects page) is said on the Reports page, naming the
file (``reports_reference_from_subjects_page.png``, ``reports_reference_attached_here.png``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from tests.browser.conftest import LiveServer, screenshot, short_recording

pytestmark = pytest.mark.browser

#: What every upload of a damaged C3D file says, naming it once (the Subjects page's words).
NOT_C3D = ("'trial 3.c3d' is not a readable C3D file: the file is damaged or not a C3D file "
           "(export it again from the motion-capture software, as C3D)")

#: What every upload of a file that is not TRC says (the reader's sentence names it).
NOT_TRC = "Gang.trc is not a TRC file (first line must start with PathFileType)"


def _recording(server: LiveServer, code: str) -> str:
    """A short recording of a new subject ``code``, copied to the server; its id."""
    pid = server.api("/api/projects", {"name": f"References {code}"})["id"]
    sid = server.api("/api/subjects", {"project_id": pid, "code": code})["id"]
    se = server.api("/api/sessions", {"subject_id": sid, "label": "visit"})["id"]
    return short_recording(server, se, "walk 1")


def _attach_on_reports_page(page: Any, live_server: LiveServer, rid: str, file: Path,
                            said: str) -> None:
    """Attach ``file`` as the reference of recording ``rid`` on the Reports page and wait
    until its message holds ``said``."""
    page.goto(live_server.base_url + "/reports.html")
    page.wait_for_function(f"[...document.querySelectorAll('#recording option')]"
                           f".some(o => o.value === '{rid}')")
    page.select_option("#recording", rid)
    page.click("#ref-box summary")
    page.set_input_files("#ref-file", str(file))
    page.click("#ref-form button[type=submit]")
    page.wait_for_function(
        f"document.getElementById('ref-msg').textContent.includes({said!r})")


def test_reports_page_says_what_a_damaged_c3d_is_not(page: Any, live_server: LiveServer,
                                                     artifacts_dir: Path,
                                                     tmp_path: Path) -> None:
    rid = _recording(live_server, "REFM1")
    damaged = tmp_path / "trial 3.c3d"
    damaged.write_bytes(b"\x02\x50" + b"\x00" * 6 + b"not a c3d file at all")
    _attach_on_reports_page(page, live_server, rid, damaged, "C3D")
    # the file named once, in the Subjects page's words and way ("Not attached: …")
    assert page.text_content("#ref-msg") == f"Not attached: {NOT_C3D}"
    screenshot(page, artifacts_dir, "reports_reference_damaged_c3d", "#ref-box")

    page.set_input_files("#file", str(damaged))
    page.click("#file-form button[type=submit]")
    page.wait_for_function("document.getElementById('file-msg').textContent.includes('C3D')")
    # named once here too (was "trial 3.c3d: cannot read trial 3.c3d as C3D: …")
    assert page.text_content("#file-msg") == NOT_C3D
    screenshot(page, artifacts_dir, "reports_file_damaged_c3d",
               "section[aria-labelledby=file-h]")

    # a reader's sentence that names the file is said alone, on both uploads (was "Gang.trc:
    # Gang.trc is not a TRC file …" here, "'Gang.trc' is not a readable TRC file: Gang.trc
    # is not a TRC file …" on the Subjects page)
    trc = tmp_path / "Gang.trc"
    trc.write_bytes(b"PathFileType\t4\n\x00\x01")
    for form, msg, said in (("#ref-form", "#ref-msg", f"Not attached: {NOT_TRC}"),
                            ("#file-form", "#file-msg", NOT_TRC)):
        page.set_input_files(f"{form} input[type=file]", str(trc))
        page.click(f"{form} button[type=submit]")
        page.wait_for_function(f"document.querySelector('{msg}').textContent.includes('TRC')")
        assert page.text_content(msg) == said
    screenshot(page, artifacts_dir, "reports_file_not_trc", "section[aria-labelledby=file-h]")
    assert not page.js_errors


def test_reports_page_names_the_reference_its_reports_use(page: Any, live_server: LiveServer,
                                                          artifacts_dir: Path,
                                                          tmp_path: Path) -> None:
    """A recording's reference comes from one of two places (the Subjects page's "Attach
    reference", the Reports page's reference of the agreement section); the Reports page
    names the one its reports use: its own first, else the newest on the Subjects page."""
    from engine.io.c3d import write_c3d
    from engine.sim.straight_walk import synth_walk, walk_markers

    rid = _recording(live_server, "REFM2")
    walk = tmp_path / "vicon walk.c3d"
    write_c3d(walk, walk_markers(synth_walk()), units="mm")
    page.goto(live_server.base_url + "/reports.html")
    page.wait_for_function(f"[...document.querySelectorAll('#recording option')]"
                           f".some(o => o.value === '{rid}')")
    page.select_option("#recording", rid)
    page.click("#ref-box summary")
    state = "document.getElementById('ref-state').textContent"
    page.wait_for_function(f"{state}.startsWith('None attached')")
    assert page.text_content("#ref-state") == (
        "None attached here or on the Subjects page: reports of this recording have no "
        "agreement section.")
    assert page.inner_text("#ref-box .hint") == (
        "Reports use the reference attached here; without one, the newest one attached to "
        "the recording on the Subjects page (taken to start with the recording).")
    # one attached on the Subjects page is named
    for name in ("older.c3d", "vicon walk.c3d"):
        upload = {"name": name, "mimeType": "application/octet-stream",
                  "buffer": walk.read_bytes()}
        r = page.request.post(f"{live_server.base_url}/api/exports/{rid}/references",
                              multipart={"file": upload})
        assert r.status == 201, r.text()
    page.dispatch_event("#recording", "change")  # (as choosing it again)
    page.wait_for_function(f"{state}.includes('vicon walk.c3d')")
    assert page.text_content("#ref-state") == (
        "None attached here: reports use vicon walk.c3d, attached on the Subjects page.")
    screenshot(page, artifacts_dir, "reports_reference_from_subjects_page", "#ref-box")
    # one attached here comes first
    page.set_input_files("#ref-file", str(walk))
    page.click("#ref-form button[type=submit]")
    page.wait_for_function(f"{state}.startsWith('Attached:')")
    assert (page.text_content("#ref-state") or "").endswith("Reports use this one."), (
        page.text_content("#ref-state"))
    screenshot(page, artifacts_dir, "reports_reference_attached_here", "#ref-box")
    # removed: back to the Subjects page's
    page.click("#ref-remove")
    page.wait_for_function(f"{state}.startsWith('None attached here: reports use')")
    assert not page.js_errors


def _attach_on_subjects_page(page: Any, live_server: LiveServer, sid: int, rid: str,
                             file: Path, ready: str) -> str:
    """Attach ``file`` as a reference of recording ``rid`` on the Subjects page (once the
    box's ``ready`` element shows) and wait for the refusal; the box's selector."""
    page.goto(f"{live_server.base_url}/subjects.html#subject={sid}")
    box_sel = f".recording[data-recording='{rid}'] .actions:has(input[type=file])"
    page.locator(f"{box_sel} {ready}").wait_for()
    page.locator(f"{box_sel} input[type=file]").set_input_files(str(file))
    page.locator(f"{box_sel} button").click()
    page.wait_for_function(
        f"document.querySelector(\"{box_sel} .msg\").textContent.includes('ot attached')")
    return box_sel


def test_subjects_page_refuses_a_reference_with_no_walk(page: Any, live_server: LiveServer,
                                                        artifacts_dir: Path,
                                                        tmp_path: Path) -> None:
    """A reference with no walk in it (the subject standing) was attached on the Subjects
    page and only said so later, as a note in the report: it is refused where it was
    attached, naming the file and what to do, and the reference attached before stays
    (``subjects_reference_no_walk.png``)."""
    from tests.app.mocap_files import standing_trc, walk_trc

    pid = live_server.api("/api/projects", {"name": "References REFM3"})["id"]
    sid = live_server.api("/api/subjects", {"project_id": pid, "code": "REFM3"})["id"]
    se = live_server.api("/api/sessions", {"subject_id": sid, "label": "visit"})["id"]
    rid = short_recording(live_server, se, "walk 1")
    good = walk_trc(tmp_path / "vicon walk.trc")
    r = page.request.post(f"{live_server.base_url}/api/exports/{rid}/references",
                          multipart={"file": {"name": good.name, "mimeType": "text/plain",
                                              "buffer": good.read_bytes()}})
    assert r.status == 201, r.text()
    still = standing_trc(tmp_path / "standing still.trc")

    box_sel = _attach_on_subjects_page(page, live_server, sid, rid, still, "a.button")
    said = page.text_content(f"{box_sel} .msg") or ""
    # beside the button pressed, the file named once, what is wrong and what to do
    assert said.startswith("Not attached: 'standing still.trc' has no walk in it: "
                           "0 steps found"), said
    assert "attach the reference recording of this walk" in said.lower(), said
    assert "'vicon walk.trc' stays attached" in said and said.count("standing still") == 1
    assert "bad" in (page.get_attribute(f"{box_sel} .msg", "class") or "")
    assert page.locator(f"{box_sel} button").is_enabled()
    # the reference attached before is still listed, and the only one
    assert page.locator(f"{box_sel} a.button").all_inner_texts() == [
        "reference vicon walk.trc (TRC, 50 Hz, 10 labels)"]
    assert [x["filename"] for x in live_server.api(f"/api/exports/{rid}/references")] == [
        "vicon walk.trc"]
    screenshot(page, artifacts_dir, "subjects_reference_no_walk",
               f".recording[data-recording='{rid}']")
    assert not page.js_errors


def test_both_pages_say_the_same_of_a_reference_with_no_walk(page: Any,
                                                             live_server: LiveServer,
                                                             artifacts_dir: Path,
                                                             tmp_path: Path) -> None:
    """A reference can be attached on the Subjects page and on the Reports page: the same
    file with no walk in it (the subject standing) is refused with the same words on both,
    in the same way — a polite status beside the button pressed, which keeps the focus —
    (the Reports page said the analysis's words, with advice on placing sensors;
    ``reports_reference_no_walk.png``)."""
    from tests.app.mocap_files import standing_trc

    pid = live_server.api("/api/projects", {"name": "References REFM4"})["id"]
    sid = live_server.api("/api/subjects", {"project_id": pid, "code": "REFM4"})["id"]
    se = live_server.api("/api/sessions", {"subject_id": sid, "label": "visit"})["id"]
    rid = short_recording(live_server, se, "walk 1")
    still = standing_trc(tmp_path / "standing still.trc")

    _attach_on_reports_page(page, live_server, rid, still, "ot attached")
    on_reports = page.text_content("#ref-msg") or ""
    reports_way = page.evaluate("""() => { const m = document.getElementById('ref-msg');
        const f = document.activeElement;
        return [m.getAttribute('role'), f === m || m.contains(f),
                f.matches('#ref-form button[type=submit]')]; }""")
    screenshot(page, artifacts_dir, "reports_reference_no_walk", "#ref-box")

    box_sel = _attach_on_subjects_page(page, live_server, sid, rid, still, "button")
    on_subjects = page.text_content(f"{box_sel} .msg") or ""
    subjects_way = page.evaluate("""(sel) => { const m = document.querySelector(sel + ' .msg');
        const f = document.activeElement;
        return [m.getAttribute('role'), f === m || m.contains(f),
                f.matches(sel + ' button')]; }""", box_sel)

    assert on_reports == on_subjects, (on_reports, on_subjects)
    assert on_reports.startswith("Not attached: 'standing still.trc' has no walk in it: "
                                 "0 steps found"), on_reports
    assert "attach the reference recording of this walk" in on_reports.lower(), on_reports
    assert "--" not in on_reports and "sensors" not in on_reports, on_reports
    # a status (polite, as every refusal of the Reports page's forms and beside the
    # Subjects page's export and reference buttons), never focused; the focus stays on
    # the button pressed
    assert reports_way == subjects_way == ["status", False, True], (reports_way, subjects_way)
    assert not page.js_errors


def test_reports_page_shows_a_projects_agreement_with_its_references(
        page: Any, live_server: LiveServer, artifacts_dir: Path, tmp_path: Path) -> None:
    """"Agreement with a reference system": a project of three subjects, each with a walk
    whose reference is attached on the Reports page, gives the paper's tables (its single
    steps and subject averages) on the page, and their numbers as a CSV file.

    The recordings are short real ones; their analyses are simulated walks
    (:mod:`tests.app.study_walks`) put in the server's analysis cache, so that the walks
    are long enough for steps without recording them (the same walks are the references,
    with their own noise)."""
    import json

    from app.server import analysis as an
    from tests.app.study_walks import walk_analysis, walk_reference_csv

    pid = live_server.api("/api/projects", {"name": "Agreement study"})["id"]
    for k, walker in enumerate(("V01", "V02", "V03"), start=1):
        sid = live_server.api("/api/subjects", {"project_id": pid, "code": f"AGR{k}"})["id"]
        se = live_server.api("/api/sessions", {"subject_id": sid, "label": "lab"})["id"]
        rid = short_recording(live_server, se, "walk 1")
        # the recording's sensor poses fixed (sensors.json), as its first analysis does
        sensors = [s["id"] for s in
                   live_server.api(f"/api/reports/recordings/{rid}/sensors")["sensors"]]
        d = an.recording_dir(live_server.data_dir / "server", rid)
        cache = d / "analysis" / f"{an.AnalysisOptions().key()}-{an._fingerprint(d)}.json"
        cache.parent.mkdir(exist_ok=True)
        cache.write_text(json.dumps(walk_analysis(rid, walker, k, tuple(sensors))))
        ref = walk_reference_csv(tmp_path / f"vicon {k}.csv", walker, k)
        r = page.request.post(f"{live_server.base_url}/api/reports/recordings/{rid}/reference",
                              multipart={"file": {"name": ref.name, "mimeType": "text/csv",
                                                  "buffer": ref.read_bytes()}})
        assert r.status == 201, r.text()
    page.goto(live_server.base_url + "/reports.html")
    page.wait_for_function("[...document.querySelectorAll('#study-project option')]"
                           f".some(o => o.value === '{pid}')")
    page.select_option("#study-project", str(pid))
    page.click("#study-show")
    msg = "document.getElementById('study-msg').textContent"
    page.wait_for_function(f"{msg} === 'Agreement below.' || "
                           "document.getElementById('study-msg').classList.contains('error')",
                           timeout=60_000)
    assert page.text_content("#study-msg") == "Agreement below."
    for label in ("Step width L (cm)", "AV step width AVG (cm)", "AV walking speed (cm/s)"):
        assert page.locator("#report").get_by_role("rowheader", name=label,
                                                   exact=True).is_visible(), label
    shown = page.text_content("#report") or ""
    assert "Project Agreement study: 3 subjects, 3 trials with a reference" in shown
    # the page's words, not the developers' ("seed paper", "issue 8")
    from tests.browser.test_console_ux import JARGON

    assert not JARGON.search(shown), JARGON.findall(shown)
    assert not JARGON.search(page.text_content("section[aria-labelledby=study-h]") or "")
    screenshot(page, artifacts_dir, "reports_agreement_study", "#report-section")
    screenshot(page, artifacts_dir, "reports_agreement_card",
               "section[aria-labelledby=study-h]")
    with page.expect_download() as got:
        page.click("#study-csv")
    text = Path(got.value.path()).read_text()
    assert got.value.suggested_filename.startswith("agreement-Agreement_study-")
    assert got.value.suggested_filename.endswith(".csv")
    assert text.startswith("table,parameter,level,unit,n,"), text[:200]
    assert "step width,L,cm," in text
    page.wait_for_function(f"{msg}.startsWith('CSV downloaded')")
    assert not page.js_errors
