"""Gait reports end to end: a real recording by six simulated sensor nodes, analysed by
the server (all sensors and one side), reported as HTML and PDF per recording, subject
and session, with an agreement section against the simulation's ground truth; uploads
and bad input.

The recording is made once per module by ``gaitrig demo`` (server + six sim node
processes over loopback websockets), ~14 s of the simulated walker's back-and-forth walk;
it is made as a clinic does: a subject's session is recorded, then copied to the server
by the transfer (``<data_dir>/recordings/<rec_id>/<node_id>/``).
"""

from __future__ import annotations

import datetime as dt
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.api.routes import _reference
from app.config import Settings
from app.main import create_app

ROOT = Path(__file__).resolve().parents[3]
RECORD_S = 14.0


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class Recorded:
    base: str
    token: str
    data_dir: Path  # the demo's server data folder
    rec_id: str
    t_start: float
    password: str
    subject_id: int

    def get(self, path: str, timeout: float = 60.0) -> tuple[int, Any, dict[str, str]]:
        req = urllib.request.Request(self.base + path,
                                     headers={"Authorization": f"Bearer {self.token}"})
        try:
            with urllib.request.urlopen(req, timeout=timeout) as r:
                raw = r.read()
                hdr = dict(r.headers.items())
                if r.headers.get_content_type() == "application/json":
                    return r.status, json.loads(raw), hdr
                return r.status, raw, hdr
        except urllib.error.HTTPError as e:
            return e.code, json.loads(e.read() or b"null"), dict(e.headers.items())


def _req(base: str, path: str, body: Any = None, token: str = "") -> Any:
    h = {"Content-Type": "application/json"}
    if token:
        h["Authorization"] = f"Bearer {token}"
    r = urllib.request.Request(base + path, headers=h,
                               data=json.dumps(body).encode() if body is not None else None)
    with urllib.request.urlopen(r, timeout=10) as f:
        return json.loads(f.read())


@pytest.fixture(scope="module")
def recorded() -> Iterator[Recorded]:
    """A ~14 s recording of six sim nodes of subject P017, transferred to the server."""
    from app.commands.demo import demo_password

    tmp = Path(tempfile.mkdtemp(prefix="gaitrig-report-"))
    port = _free_port()
    pw = demo_password(tmp)
    log = (tmp / "demo.log").open("wb")
    proc = subprocess.Popen(
        [sys.executable, "-m", "app.cli", "demo", "--no-viewer", "--no-images", "--port",
         str(port), "--data-dir", str(tmp)], cwd=ROOT, stdout=log, stderr=subprocess.STDOUT,
        env={**os.environ, "PYTHONUNBUFFERED": "1"}, start_new_session=True)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.time() + 90
        while True:
            assert proc.poll() is None, (tmp / "demo.log").read_text()[-2000:]
            try:
                _req(base, "/healthz")
                break
            except OSError:
                assert time.time() < deadline, "server did not start"
                time.sleep(0.2)
        token = _req(base, "/api/auth/login", {"username": "admin", "password": pw})["token"]
        while True:
            nodes = _req(base, "/api/nodes", token=token)
            if sum(1 for n in nodes if n["connected"] and n["clock_offset_ms"] is not None) == 6:
                break
            assert time.time() < deadline, f"nodes not online: {nodes}"
            time.sleep(0.3)
        # The clinic's way: a subject's session, recorded, then copied to the server.
        proj = _req(base, "/api/projects", {"name": "Report test"}, token=token)
        subj = _req(base, "/api/subjects", {"project_id": proj["id"], "code": "P017",
                                            "height_m": 1.74, "sex": "female"}, token=token)
        sess = _req(base, "/api/sessions", {"subject_id": subj["id"], "date": "2026-11-22",
                                            "label": "baseline"}, token=token)
        # The simulated walk restarts every WORLD_CYCLE_S of host time; a recording that
        # straddles the restart has no single ground truth, so wait the restart out first.
        from app.nodes.backends.sim import WORLD_CYCLE_S
        to_restart = WORLD_CYCLE_S - time.time() % WORLD_CYCLE_S
        if to_restart < RECORD_S + 5.0:
            time.sleep(to_restart + 1.0)
        rec = _req(base, f"/api/sessions/{sess['id']}/recordings", {"label": "walk"},
                   token=token)
        time.sleep(RECORD_S)
        _req(base, f"/api/recordings/{rec['id']}/stop", {}, token=token)
        while True:
            r = _req(base, f"/api/recordings/{rec['id']}", token=token)
            if r["state"] not in ("recording", "stopping"):
                break
            assert time.time() < deadline + 60, r
            time.sleep(0.3)
        assert r["state"] in ("on_nodes", "transferring", "complete"), r
        if r["state"] == "on_nodes":  # the server copies automatically; ask if it has not
            try:
                _req(base, f"/api/recordings/{rec['id']}/transfer", {}, token=token)
            except urllib.error.HTTPError as exc:
                assert exc.code == 409, exc  # the automatic transfer started meanwhile
        while True:
            s = _req(base, f"/api/subjects/{subj['id']}", token=token)
            state = s["sessions"][0]["recordings"][0]["state"]
            if state == "complete":
                break
            # The database follows the live state a moment later.
            assert state != "incomplete" and time.time() < deadline + 120, s
            time.sleep(0.3)
        server = tmp / "server"
        yield Recorded(base, token, server, rec["id"], float(r["t_start"]), pw, subj["id"])
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGTERM)
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
        log.close()
        shutil.rmtree(tmp, ignore_errors=True)


def _summary(a: dict[str, Any]) -> dict[str, Any]:
    s: dict[str, Any] = a["gait"]["summary"]
    return s


def test_analysis_of_a_real_recording(recorded: Recorded) -> None:
    code, a, _ = recorded.get(f"/api/reports/recordings/{recorded.rec_id}/analysis")
    assert code == 200, a
    assert a["ok"], a["error"]
    assert a["sensors_used"] == [f"S{k}" for k in range(1, 7)]
    s = _summary(a)
    # The sim walker walks at 1.0-1.5 m/s with 0.55-0.85 m steps.
    assert s["n_steps"] >= 4
    assert 0.8 < s["walking_speed_m_s"] < 1.7
    assert 0.5 < s["step_length_m"]["mean"] < 0.9
    assert 0.03 < s["step_width_m"]["mean"] < 0.25
    assert 9.0 < a["fusion"]["duration_s"] < RECORD_S + 1.0
    # Clock offsets of the simulated nodes are tens to hundreds of ms, measured to a few ms.
    offs = [f["clock_offset_ms"] for f in a["sensors"].values()]
    assert max(abs(o) for o in offs) > 5.0
    unc = [f["clock_uncertainty_ms"] for f in a["sensors"].values()]
    assert all(0.0 <= u < 20.0 for u in unc), unc
    # Frames seen from behind are reported (which ones depends on the walking direction in
    # this window; the correction itself is checked against the simulator's truth in
    # test_report_cli_and_mirroring.py).
    assert all(0.0 <= f["mirrored_pct"] <= 100.0 for f in a["sensors"].values())
    # Poses snapshotted beside the recording, result cached.
    d = recorded.data_dir / "recordings" / recorded.rec_id
    assert set(json.loads((d / "sensors.json").read_text())) == {f"S{k}" for k in range(1, 7)}
    assert len(list((d / "analysis").glob("*.json"))) == 1
    code2, again, _ = recorded.get(f"/api/reports/recordings/{recorded.rec_id}/analysis")
    assert code2 == 200 and again == a
    # Listed for the page with the subject it belongs to.
    code, lst, _ = recorded.get("/api/reports/recordings")
    assert [(r["id"], r["subject_code"], r["db_state"]) for r in lst] == \
        [(recorded.rec_id, "P017", "complete")]


def test_one_sided_vs_two_sided(recorded: Recorded) -> None:
    code, sens, _ = recorded.get(f"/api/reports/recordings/{recorded.rec_id}/sensors")
    assert code == 200
    sides: dict[str, list[str]] = {}
    for s in sens["sensors"]:
        sides.setdefault(s["side"], []).append(s["id"])
    # The avenue: S1, S3, S5 on the left of a person walking along +X, S2, S4, S6 on the
    # right (engine.sim.rig), named so (was "A"/"B": which side was which went unsaid).
    assert sorted(sides) == ["left", "right"]
    assert sorted(sides["left"]) == ["S1", "S3", "S5"]
    assert sorted(sides["right"]) == ["S2", "S4", "S6"]
    # The report of a subset says so.
    code, html, _ = recorded.get(f"/api/reports/recordings/{recorded.rec_id}/report"
                                 "?sensors=S1,S3,S5")
    assert code == 200, html  # the refusal's words: e.g. too few steps seen from one side
    assert "sensors on the left of the walkway (S1, S3, S5)" in html.decode()
    assert "subset of its sensors" in html.decode()
    code, cmp, _ = recorded.get(f"/api/reports/recordings/{recorded.rec_id}/compare"
                                "?a=S1,S3,S5&b=")
    assert code == 200, cmp
    a, b = cmp["a"], cmp["b"]
    assert a["sensors_used"] == ["S1", "S3", "S5"]
    assert b["sensors_used"] == [f"S{k}" for k in range(1, 7)]
    assert a["ok"] and b["ok"], (a["error"], b["error"])
    assert a["fusion"]["sensors_per_sample"] < b["fusion"]["sensors_per_sample"]
    wa = [s["width_m"] for s in a["gait"]["steps"]]
    wb = [s["width_m"] for s in b["gait"]["steps"]]
    assert wa != wb
    # Both subsets describe the same walk.
    assert abs(_summary(a)["walking_speed_m_s"] - _summary(b)["walking_speed_m_s"]) < 0.15


def _truth_reference(recorded: Recorded, path: Path) -> None:
    """Ground-truth joints of the simulated walker on the recording's time axis (CSV)."""
    from app.nodes.backends.sim import CHUNK_S, WORLD_CYCLE_S, world_time
    from engine.io.csv import write_skeleton_csv
    from engine.sim.rig import default_avenue_rig
    from engine.sim.walker import Walker, WalkerParams
    from engine.skeleton import KINECT_V2, SkeletonSeries

    rig = default_avenue_rig(0)
    w = Walker(WalkerParams.random(np.random.default_rng(0)), rig.walkway.start,
               rig.walkway.end, start_time=0.0, seed=0, horizon_s=WORLD_CYCLE_S + CHUNK_S)
    tau = np.arange(0.0, RECORD_S + 0.5, 0.01)
    tw = np.array([world_time(recorded.t_start + x) for x in tau])
    assert np.all(np.diff(tw) > 0), "the recording straddles the simulated walk's restart"
    P = w.joints(tw)
    write_skeleton_csv(path, SkeletonSeries(tau, P, np.full(P.shape[:2], 2, np.uint8),
                                            KINECT_V2))


def _pdf_pages(pdf: bytes, tmp: Path) -> list[np.ndarray]:
    f = tmp / "report.pdf"
    f.write_bytes(pdf)
    subprocess.run(["pdftoppm", "-r", "60", "-png", str(f), str(tmp / "page")], check=True,
                   timeout=60)
    out = []
    for p in sorted(tmp.glob("page-*.png")):
        img = cv2.imread(str(p))
        assert img is not None, p
        out.append(np.asarray(img))
    return out


def _pdf_text(pdf: bytes, tmp: Path) -> str:
    f = tmp / "t.pdf"
    f.write_bytes(pdf)
    out = subprocess.run(["pdftotext", "-layout", str(f), "-"], check=True, timeout=60,
                         capture_output=True, text=True)
    return out.stdout


def test_recording_report_html_pdf_and_agreement(recorded: Recorded, tmp_path: Path,
                                                 artifacts_dir: Path) -> None:
    rid = recorded.rec_id
    # Attach the ground truth as the reference recording.
    ref = tmp_path / "truth.csv"
    _truth_reference(recorded, ref)
    import httpx

    h = {"Authorization": f"Bearer {recorded.token}"}
    with open(ref, "rb") as f:
        r = httpx.post(f"{recorded.base}/api/reports/recordings/{rid}/reference", headers=h,
                       files={"file": ("truth.csv", f, "text/csv")}, timeout=60)
    assert r.status_code == 201, r.text
    assert r.json()["n_steps"] >= 6
    code, html, hdr = recorded.get(f"/api/reports/recordings/{rid}/report?format=html")
    assert code == 200, html
    text = html.decode()
    assert "<html" not in text.lower()  # a fragment for the console
    for word in ("Gait report", "Step length", "Step width", "Data quality", "S1", "S6",
                 "Bland", "data:image/png;base64,"):
        assert word in text, word
    assert text.count("data:image/png;base64,") >= 4  # placements, ankles, steps, B–A
    code, pdf, hdr = recorded.get(f"/api/reports/recordings/{rid}/report?format=pdf")
    assert code == 200
    assert hdr["content-type"] == "application/pdf"
    assert hdr["content-disposition"].startswith("attachment; filename=")
    assert hdr["content-disposition"].endswith('.pdf"')
    pages = _pdf_pages(pdf, tmp_path)
    assert len(pages) >= 2
    shutil.copy(tmp_path / "report.pdf", artifacts_dir / "report_recording.pdf")
    cv2.imwrite(str(artifacts_dir / "report_recording_p1.png"), pages[0])
    for p in pages:
        # no blank page (a footer alone inks ~0.3 %; the last page may hold only the end
        # of the agreement section, ~2-3 %)
        assert (p.min(axis=2) < 200).mean() > 0.01
    # Plots are coloured (tables and text are black on white).
    colour = [(np.ptp(p.astype(int), axis=2) > 60).mean() for p in pages]
    assert max(colour) > 0.005, colour
    txt = _pdf_text(pdf, tmp_path)
    for word in ("Gait report", "Spatiotemporal", "Walking speed", "Step length",
                 "Agreement", "ICC"):
        assert word in txt, word
    # Agreement against the truth: the fused recording's step lengths are close to it.
    rows = [ln for ln in txt.splitlines() if "Step length" in ln and "single steps" in ln]
    assert rows, txt[-3000:]


def test_uploaded_file_report(recorded: Recorded, tmp_path: Path) -> None:
    import httpx

    from engine.io.csv import write_skeleton_csv
    from engine.sim.straight_walk import synth_walk, walk_skeleton
    from engine.skeleton import KINECT_V2, SkeletonSeries

    w = synth_walk(n_steps=12, rate=30.0)
    P = walk_skeleton(w)
    f = tmp_path / "walk.csv"
    write_skeleton_csv(f, SkeletonSeries(w.times, P, np.full(P.shape[:2], 2, np.uint8),
                                         KINECT_V2))
    h = {"Authorization": f"Bearer {recorded.token}"}
    r = httpx.post(f"{recorded.base}/api/reports/upload?format=html", headers=h,
                   data={"subject": "P07"},
                   files={"file": ("walk.csv", f.read_bytes(), "text/csv")}, timeout=60)
    assert r.status_code == 200, r.text
    assert "P07" in r.text and "Step length" in r.text
    # synth_walk: 0.70 m steps, 0.12 m wide, 0.55 s.
    assert "70.0" in r.text and "12.0" in r.text


def test_bad_input_over_http(recorded: Recorded, tmp_path: Path) -> None:
    import httpx

    h = {"Authorization": f"Bearer {recorded.token}"}
    rid = recorded.rec_id
    code, body, _ = recorded.get("/api/reports/recordings/R19990101-000000-dead/analysis")
    assert code == 404 and "no recording" in body["detail"]  # unknown: not "transfer it"
    code, body, _ = recorded.get("/api/reports/recordings/..%2F..%2Fetc/analysis")
    assert code in (400, 404)
    code, body, _ = recorded.get(f"/api/reports/recordings/{rid}/analysis?sensors=S9")
    assert code == 400 and "S9" in body["detail"] and "S1" in body["detail"]
    code, body, _ = recorded.get(f"/api/reports/recordings/{rid}/analysis?sensors=../x")
    assert code == 400
    code, body, _ = recorded.get(f"/api/reports/recordings/{rid}/analysis?method=magic")
    assert code == 422
    # A file without ankles: the message names what is missing.
    noank = tmp_path / "noankle.csv"
    noank.write_text("time,Head_x,Head_y,Head_z\n0,0,0,1.7\n0.1,0.1,0,1.7\n0.2,0.2,0,1.7\n")
    r = httpx.post(f"{recorded.base}/api/reports/upload", headers=h,
                   files={"file": ("noankle.csv", noank.read_bytes(), "text/csv")}, timeout=30)
    assert r.status_code in (400, 422), r.text
    assert "ankle" in r.json()["detail"].lower()
    r = httpx.post(f"{recorded.base}/api/reports/upload", headers=h,
                   files={"file": ("notes.txt", b"hello", "text/plain")}, timeout=30)
    assert r.status_code == 400 and ".c3d" in r.json()["detail"]
    r = httpx.post(f"{recorded.base}/api/reports/upload", headers=h,
                   files={"file": ("empty.c3d", b"", "application/octet-stream")}, timeout=30)
    assert r.status_code == 400 and "empty" in r.json()["detail"]
    r = httpx.post(f"{recorded.base}/api/reports/upload", timeout=30,
                   files={"file": ("walk.csv", b"x", "text/csv")})
    assert r.status_code == 401


def test_reports_page_in_a_browser(recorded: Recorded, tmp_path: Path,
                                   artifacts_dir: Path, browser: Any) -> None:
    """What a clinician sees: subject report inline, one- vs two-sided table, errors."""
    context = browser.new_context(viewport={"width": 1280, "height": 1000})
    try:
        page = context.new_page()
        page.goto(recorded.base + "/index.html")
        page.fill("input[name=username]", "admin")
        page.fill("input[name=password]", recorded.password)
        page.click("button[type=submit]")
        page.wait_for_url("**/rig.html")
        page.goto(recorded.base + "/reports.html")
        page.wait_for_function("document.querySelectorAll('#subject option').length > 1")
        page.select_option("#subject", str(recorded.subject_id))
        page.wait_for_function("document.querySelectorAll('#session option').length > 1")
        assert "1 complete recording" in page.inner_text("#session")
        page.click("#show")
        page.wait_for_selector("#report table", timeout=60000)
        report = page.inner_text("#report")
        for word in ("Gait report", "P017", "174 cm", recorded.rec_id, "Step width",
                     "Data quality"):
            assert word in report, word
        assert page.locator("#report img").count() >= 3
        page.screenshot(path=str(artifacts_dir / "reports_page_subject.png"), full_page=True)
        # PDF download through the page.
        with page.expect_download(timeout=120000) as dl:
            page.click("#pdf")
        assert dl.value.suggested_filename.startswith("gait-report-P017")
        # One- vs two-sided: side A preset against all sensors.
        page.select_option("#recording", recorded.rec_id)
        page.wait_for_selector("#set-a input")
        ticked = page.eval_on_selector_all("#set-a input:checked", "e => e.map(x => x.value)")
        assert sorted(ticked) == ["S1", "S3", "S5"]
        page.click("#compare")
        page.wait_for_selector("#cmp-table:not([hidden])", timeout=60000)
        rows = page.inner_text("#cmp-table tbody").splitlines()
        assert any(r.startswith("Sensors\tS1, S3, S5\tS1, S2, S3, S4, S5, S6") for r in rows)
        assert any(r.startswith("Step width (cm)") for r in rows)
        page.locator("#cmp-h").scroll_into_view_if_needed()
        page.screenshot(path=str(artifacts_dir / "reports_page_compare.png"))
        # A file without ankles: a message in red, the old report goes away.
        bad = tmp_path / "noankle.csv"
        bad.write_text("time,Head_x,Head_y,Head_z\n0,0,0,1.7\n0.1,0.1,0,1.7\n")
        page.set_input_files("#file", str(bad))
        page.click("#file-form button[type=submit]")
        page.wait_for_function("document.getElementById('file-msg').classList.contains('error')")
        assert "AnkleLeft" in page.inner_text("#file-msg")
        assert page.locator("#report-section").is_hidden()
        page.screenshot(path=str(artifacts_dir / "reports_page_error.png"))
    finally:
        context.close()


# ---------------------------------------------------------------- in-process server, DB


@pytest.fixture
def client(recorded: Recorded, tmp_path: Path) -> Iterator[TestClient]:
    """The API on a copy of the recording's server data, without nodes."""
    data = tmp_path / "server"
    shutil.copytree(recorded.data_dir / "recordings", data / "recordings")
    s = Settings(data_dir=data, viewer_enabled=False, admin_password="report-pw",
                 node_token="report-node-token")
    with TestClient(create_app(s)) as c:
        r = c.post("/api/auth/login", json={"username": "admin", "password": "report-pw"})
        c.headers["Authorization"] = f"Bearer {r.json()['token']}"
        yield c


def _add_subject(client: TestClient, rec_id: str, state: str = "complete"
                 ) -> tuple[int, int, int]:
    from app.db.data import Project, Recording, Session, Subject

    factory = client.app.state.db_sessions  # type: ignore[attr-defined]
    with factory() as db:
        p = Project(name="Gait study")
        subj = Subject(project=p, code="P01", height_m=1.74, sex="female", birth_year=1980)
        s1 = Session(subject=subj, date=dt.date(2026, 11, 20), label="baseline")
        s2 = Session(subject=subj, date=dt.date(2026, 11, 22), label="follow-up")
        db.add_all([p, subj, s1, s2])
        db.add(Recording(id=rec_id, session=s1, state=state))
        empty = Subject(project=p, code="P02")
        db.add(empty)
        db.add(Session(subject=empty, date=dt.date(2026, 11, 21), label="baseline"))
        db.commit()
        return subj.id, s1.id, empty.id


def test_subject_and_session_reports(client: TestClient, recorded: Recorded,
                                     tmp_path: Path) -> None:
    sid, sess_id, empty_id = _add_subject(client, recorded.rec_id)
    # A reference imported on the Subjects page (data management) feeds the agreement.
    from app.db.data import ReferenceImport

    data_dir = client.app.state.settings.data_dir  # type: ignore[attr-defined]
    shutil.rmtree(data_dir / "recordings" / recorded.rec_id / "reference", ignore_errors=True)
    (data_dir / "references" / recorded.rec_id).mkdir(parents=True)
    _truth_reference(recorded, data_dir / "references" / recorded.rec_id / "0123abcd4567ef89.csv")
    with client.app.state.db_sessions() as db:  # type: ignore[attr-defined]
        db.add(ReferenceImport(recording_id=recorded.rec_id, filename="truth.csv",
                               format="csv", stored_name="0123abcd4567ef89.csv"))
        db.commit()
    lst = client.get("/api/reports/recordings").json()
    assert [r["id"] for r in lst] == [recorded.rec_id]
    assert lst[0]["subject_code"] == "P01" and lst[0]["session_label"] == "baseline"
    assert isinstance(lst[0]["has_reference"], bool)
    r = client.get(f"/api/reports/subjects/{sid}")
    assert r.status_code == 200, r.text
    assert "P01" in r.text and "174 cm" in r.text and "all sessions (2)" in r.text
    assert "Agreement with the reference" in r.text and "single steps L+R" in r.text
    r = client.get(f"/api/reports/subjects/{sid}?session_id={sess_id}&format=pdf")
    assert r.status_code == 200
    assert r.headers["content-disposition"] == \
        'attachment; filename="gait-report-P01-2026-11-20.pdf"'
    # Bad input: clear messages, never 500.
    r = client.get("/api/reports/subjects/9999")
    assert r.status_code == 404 and "9999" in r.json()["detail"]
    r = client.get(f"/api/reports/subjects/{empty_id}")
    assert r.status_code == 422 and "no complete recording" in r.json()["detail"]
    r = client.get(f"/api/reports/subjects/{sid}?session_id=12345")
    assert r.status_code == 404 and "session" in r.json()["detail"]


def test_incomplete_recording_is_not_reported(client: TestClient, recorded: Recorded) -> None:
    sid, _, _ = _add_subject(client, recorded.rec_id, state="on_nodes")
    r = client.get(f"/api/reports/subjects/{sid}")
    assert r.status_code == 422
    detail = r.json()["detail"]
    assert recorded.rec_id in detail and "not complete on the server" in detail


def test_recording_without_a_walk_gives_a_clear_message(client: TestClient,
                                                        recorded: Recorded) -> None:
    """A recording whose frames hold no body: 200 with ok=False and the reason."""
    from app.nodes.protocol import encode_skeletons
    from app.nodes.store import NodeStore

    src = client.app.state.settings.data_dir / "recordings" / recorded.rec_id  # type: ignore[attr-defined]
    dst = src.parent / "R20260101-000000-0000"
    store = NodeStore(dst)
    (dst / "sensors.json").write_text((src / "sensors.json").read_text())
    for node in ("S1", "S2"):
        meta = json.loads((src / node / "meta.json").read_text())
        w = store.create_part(node, **{k: v for k, v in meta.items()
                                       if k in ("t_start_server", "clock_start")})
        for k in range(60):
            t = meta["t_start_local"] + k / 30
            w.append(t, "skeleton", encode_skeletons(k, t, np.zeros((0, 25, 3)),
                                                      np.zeros((0, 25), np.uint8)))
        w.close()
        # A part arriving later (transfer) makes a new analysis, not the cached one.
        r = client.get(f"/api/reports/recordings/{dst.name}/analysis")
        assert r.status_code == 200 and r.json()["sensors_available"] == \
            (["S1"] if node == "S1" else ["S1", "S2"])
    r = client.get(f"/api/reports/recordings/{dst.name}/analysis")
    assert r.status_code == 200
    a = r.json()
    assert a["ok"] is False
    assert "body" in a["error"], a["error"]
    r = client.get(f"/api/reports/recordings/{dst.name}/report")
    assert r.status_code == 422 and "no recording gave a gait result" in r.json()["detail"]


def test_oversized_upload_is_refused(client: TestClient, monkeypatch: pytest.MonkeyPatch
                                     ) -> None:
    monkeypatch.setattr(_reference, "MAX_REFERENCE_BYTES", 1000)
    r = client.post("/api/reports/upload",
                    files={"file": ("big.c3d", b"\0" * 5000, "application/octet-stream")})
    assert r.status_code == 413, r.text
    assert "'big.c3d' is larger than 1 KB" in r.json()["detail"]  # (limits.size_words)


def test_fused_export_read_by_the_cli_gives_the_reports_steps(recorded: Recorded,
                                                               tmp_path: Path) -> None:
    """A research engineer downloads the fused C3D of a recording and runs ``gaitrig gait``
    on it: the steps are the report's (the same steps at the same times, lengths and
    widths within 1 cm, durations within one frame; an edge step may differ)."""
    import httpx

    code, a, _ = recorded.get(f"/api/reports/recordings/{recorded.rec_id}/analysis")
    assert code == 200 and a["ok"], a
    h = {"Authorization": f"Bearer {recorded.token}"}
    r = httpx.get(f"{recorded.base}/api/exports/{recorded.rec_id}/skeleton",
                  params={"format": "c3d", "source": "fused"}, headers=h, timeout=60)
    assert r.status_code == 200, r.text
    f = tmp_path / "fused.c3d"
    f.write_bytes(r.content)
    out = subprocess.run([sys.executable, "-m", "app.cli", "gait", str(f), "--json"],
                         cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    cli = json.loads(out.stdout)["steps"]
    rep = a["gait"]["steps"]
    assert len(rep) >= 4
    # The two time bases differ by a constant (the report counts from the recording's
    # start, the file from its first frame): the offset that pairs the most steps of the
    # same side within 20 ms lines them up. A step at either end of the recording may be
    # found by one and not the other (where a pass is cut by the recording's edge).
    def pairs(offset: float) -> list[tuple[dict[str, Any], dict[str, Any]]]:
        return [(r, c) for r in rep for c in cli if r["side"] == c["side"]
                and abs(c["time_s"] - offset - r["time_s"]) < 0.02]

    offsets = [c["time_s"] - r["time_s"] for r in rep for c in cli if r["side"] == c["side"]]
    matched = max((pairs(o) for o in offsets), key=len)
    assert len(matched) >= max(4, min(len(rep), len(cli)) - 2), (rep, cli)
    for r, c in matched:
        assert abs(r["length_m"] - c["length_m"]) < 0.01, (r, c)
        assert abs(r["width_m"] - c["width_m"]) < 0.01, (r, c)
        assert abs(r["duration_s"] - c["duration_s"]) < 0.034, (r, c)
