"""Subject report over chosen sessions (``GET /api/reports/subjects/{id}?sessions=a,b``).

The recordings' analyses are simulated walks (:class:`engine.sim.walker.Walker`, analysed
by the gait engine) put in place of the server's fusion: what is tested here is which
sessions a report holds, the section "Change over sessions" and the errors.
"""

from __future__ import annotations

import datetime as dt
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.config import Settings
from app.main import create_app
from app.server import analysis as an
from engine.sim.walker import Walker, WalkerParams
from engine.skeleton import KINECT_V2, SkeletonSeries, TrackingState

BASE = WalkerParams()
FASTER = WalkerParams(speed_m_s=BASE.speed_m_s * 1.15, step_length_m=BASE.step_length_m * 1.15)
#: session label → (date, walker, seeds of its recordings)
SESSIONS = {"baseline": (dt.date(2026, 10, 1), BASE, (1, 2, 3)),
            "week 4": (dt.date(2026, 10, 29), BASE, (4, 5, 6)),
            "week 8": (dt.date(2026, 11, 26), FASTER, (7, 8, 9))}


def _analysis(rec_id: str, params: WalkerParams, seed: int) -> dict[str, Any]:
    w = Walker(params, [0.0, 0.0, 0.0], [14.0, 0.0, 0.0], start_time=0.5,
               back_and_forth=False, seed=seed, horizon_s=14.0)
    t = np.arange(0.0, 10.0, 0.02)
    J = w.joints(t) + np.random.default_rng(seed).normal(0.0, 0.005, (len(t), 25, 3))
    s = SkeletonSeries(t, J, np.full(J.shape[:2], TrackingState.TRACKED, np.uint8), KINECT_V2)
    return {"rec_id": rec_id, "ok": True, "error": None, "sensors_used": ["S1", "S2"],
            "sensors": {}, "fusion": None, **an.analyse_series(s)}


@pytest.fixture(scope="module")
def analyses() -> dict[str, dict[str, Any]]:
    out = {}
    for label, (_, params, seeds) in SESSIONS.items():
        for k in seeds:
            rid = f"R{label.replace(' ', '')}-{k}"
            out[rid] = _analysis(rid, params, k)
    return out


@pytest.fixture
def client(tmp_path: Path, analyses: dict[str, dict[str, Any]],
           monkeypatch: pytest.MonkeyPatch) -> Iterator[TestClient]:
    """The API with a subject in three sessions of three complete recordings each."""
    data = tmp_path / "server"
    for rid in analyses:  # a part folder on the server, so the recording counts as there
        part = an.recording_dir(data, rid) / "S1"
        part.mkdir(parents=True)
        (part / "frames.bin").write_bytes(b"")
        (part / "meta.json").write_text("{}")

    def fake(rec_dir: Path, options: Any, live: Any = None, use_cache: bool = True
             ) -> dict[str, Any]:
        return analyses[rec_dir.name]

    monkeypatch.setattr(an, "analyse_recording", fake)
    s = Settings(data_dir=data, viewer_enabled=False, admin_password="report-pw",
                 node_token="report-node-token", storage_check_interval_s=0)
    with TestClient(create_app(s)) as c:
        r = c.post("/api/auth/login", json={"username": "admin", "password": "report-pw"})
        c.headers["Authorization"] = f"Bearer {r.json()['token']}"
        from app.db.data import Project, Recording, Session, Subject

        with c.app.state.db_sessions() as db:  # type: ignore[attr-defined]
            p = Project(name="Therapy study")
            subj = Subject(project=p, code="P21", height_m=1.75, sex="male")
            other = Subject(project=p, code="P22")
            db.add_all([p, subj, other])
            # filed out of date order: the report sorts them by date
            for label in ("week 8", "baseline", "week 4"):
                date, _, seeds = SESSIONS[label]
                se = Session(subject=subj, date=date, label=label)
                db.add(se)
                for k in seeds:
                    db.add(Recording(id=f"R{label.replace(' ', '')}-{k}", session=se,
                                     state="complete"))
            db.add(Session(subject=other, date=dt.date(2026, 10, 2), label="baseline"))
            db.commit()
            c.ids = {se.label: se.id for se in subj.sessions}  # type: ignore[attr-defined]
            c.subject_id = subj.id  # type: ignore[attr-defined]
            c.other_session = other.sessions[0].id  # type: ignore[attr-defined]
        yield c


def _cells(html: str, table_label: str) -> str:
    start = html.index(f'aria-label="{table_label}"')
    return html[start:html.index("</table>", start)]


def test_all_sessions_have_the_change_section(client: TestClient) -> None:
    sid = client.subject_id  # type: ignore[attr-defined]
    r = client.get(f"/api/reports/subjects/{sid}")
    assert r.status_code == 200, r.text
    html = r.text
    assert "Change over sessions" in html and "all sessions pooled" in html
    heads = _cells(html, "sessions")
    # time order, whatever the order of filing
    assert heads.index("1 Oct 2026 baseline") < heads.index("29 Oct 2026 week 4") \
        < heads.index("26 Nov 2026 week 8")
    changes = _cells(html, "changes between sessions")
    week8 = changes[changes.index("26 Nov 2026 week 8"):]
    row = re.search(r"Walking speed</th><th scope=\"row\"[^>]*>first</th>\s*<td class=\"l\">"
                    r"faster by ([0-9.]+) m/s \(\+([0-9.]+) %\)</td>\s*"
                    r"<td class=\"l beyond\">beyond trial-to-trial", week8)
    assert row, week8[:1500]
    assert float(row.group(2)) == pytest.approx(15.0, abs=3.0)


def test_a_subset_of_sessions(client: TestClient) -> None:
    sid, ids = client.subject_id, client.ids  # type: ignore[attr-defined]
    r = client.get(f"/api/reports/subjects/{sid}?sessions={ids['week 4']},{ids['baseline']}")
    assert r.status_code == 200, r.text
    assert "sessions (2)" in r.text and "Change over sessions" in r.text
    assert "week 8" not in r.text and "faster by" not in _cells(r.text, "changes between sessions")
    # one session through ``sessions``: no change section, as a one-session report
    r = client.get(f"/api/reports/subjects/{sid}?sessions={ids['week 8']}")
    assert r.status_code == 200
    assert "Change over sessions" not in r.text and "all sessions pooled" not in r.text
    r = client.get(f"/api/reports/subjects/{sid}?session_id={ids['week 8']}")
    assert r.status_code == 200 and "Change over sessions" not in r.text
    # the PDF of a subset has the section too
    r = client.get(f"/api/reports/subjects/{sid}?sessions={ids['baseline']},{ids['week 8']}"
                   "&format=pdf")
    assert r.status_code == 200 and r.headers["content-type"] == "application/pdf"


def test_bad_session_ids_are_clear_errors(client: TestClient) -> None:
    sid, ids = client.subject_id, client.ids  # type: ignore[attr-defined]
    other = client.other_session  # type: ignore[attr-defined]
    r = client.get(f"/api/reports/subjects/{sid}?sessions={ids['baseline']},{other}")
    assert r.status_code == 404
    assert f"no session with id {other}" in r.json()["detail"] and "P21" in r.json()["detail"]
    r = client.get(f"/api/reports/subjects/{sid}?sessions=abc")
    assert r.status_code == 422 and "session ids separated by commas" in r.json()["detail"]
    r = client.get(f"/api/reports/subjects/{sid}?sessions=,")
    assert r.status_code == 422 and "at least one session id" in r.json()["detail"]
    r = client.get(f"/api/reports/subjects/{sid}?sessions={ids['baseline']}"
                   f"&session_id={ids['week 4']}")
    assert r.status_code == 422 and "not both" in r.json()["detail"]
    r = client.get(f"/api/reports/subjects/{sid}?sessions=" + "1," * 1500)
    assert r.status_code == 422  # over max_length: FastAPI's validation, not a 500


def test_the_downloaded_pdf_is_tagged_like_the_html(client: TestClient) -> None:
    """The PDF the Reports page downloads is a tagged PDF: language, structure tree, the
    tables' header cells and every plot with the HTML's text alternative."""
    import html as html_lib

    from tests.engine.report.pdf_structure import read_objects, structure_tree

    sid = client.subject_id  # type: ignore[attr-defined]
    r = client.get(f"/api/reports/subjects/{sid}?format=pdf")
    assert r.status_code == 200, r.text
    objs = read_objects(r.content)
    assert objs.catalog["Lang"] == "en"
    tree = structure_tree(objs)
    alts = [f.alt for f in tree.find("Figure")]
    page = client.get(f"/api/reports/subjects/{sid}").text
    assert alts == [html_lib.unescape(a)
                    for a in re.findall(r'<img src="[^"]+" alt="([^"]*)"', page)]
    assert alts[0].startswith("Parameters over 3 sessions, 1 Oct 2026 baseline to "
                              "26 Nov 2026 week 8")
    assert any(t.find("TH") for t in tree.find("Table"))
