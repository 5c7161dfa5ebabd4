"""Agreement with a reference system over a project
(``GET /api/reports/projects/{id}/agreement``): seed 000's Tables 1–3 of the project's
recordings that have a reference attached.

The recordings' analyses are simulated walks (:mod:`tests.app.study_walks`, analysed by the
gait engine) put in place of the server's fusion; their references are skeleton CSVs of
the same walks with their own noise, attached where the Reports page keeps them. What is
tested is which recordings the study takes, its rows, formats, notes and errors.
"""

from __future__ import annotations

import csv
import datetime as dt
import io
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from app.config import Settings
from app.main import create_app
from app.server import analysis as an
from engine.errors import InputError
from tests.app.study_walks import attach_reference, walk_analysis, walk_reference_csv

#: rec_id → (subject code, walk seed, trial label, state, reference: "ok", "late" (the
#: reference started 2 s before the recording, its times 2 s later; said by its offset, −2:
#: it starts at −2 s into the recording), "broken", "far" (100 s off, no
#: offset: no step matches), or None)
RECORDINGS = {
    "A1": ("V01", 1, "walk 1", "complete", "ok"),
    "A2": ("V01", 2, "walk 2", "complete", "ok"),
    "A3": ("V01", 3, "walk 3", "complete", None),
    "B1": ("V02", 1, "walk 1", "complete", "ok"),
    "B2": ("V02", 2, "walk 2", "complete", "late"),
    "B3": ("V02", 3, "walk 3", "complete", "broken"),
    "C1": ("V03", 1, "walk 1", "complete", "ok"),
    "C2": ("V03", 2, "walk 2", "complete", "ok"),
    "D1": ("V04", 1, "walk 1", "complete", "ok"),
    "D2": ("V04", 2, "walk 2", "on_nodes", "ok"),
    "N1": ("N01", 1, "walk 1", "complete", None),
    "F1": ("F01", 1, "walk 1", "complete", "far"),
}
PROJECTS = {"Validation study": ("V01", "V02", "V03", "V04"),
            "No references": ("N01",), "Far apart": ("F01",)}


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    """The API with three projects: a validation study of four subjects, one without any
    reference, one whose only reference matches no step."""
    tmp = tmp_path_factory.mktemp("project-agreement")
    data = tmp / "server"
    analyses = {rid: walk_analysis(rid, code, seed)
                for rid, (code, seed, _, _, _) in RECORDINGS.items()}
    for rid, (code, seed, _, _, ref) in RECORDINGS.items():
        d = an.recording_dir(data, rid)
        for node in ("S1", "S2"):  # part folders on the server: the recording is there
            (d / node).mkdir(parents=True)
            (d / node / "frames.bin").write_bytes(b"")
            (d / node / "meta.json").write_text("{}")
        if ref == "broken":
            bad = tmp / "vicon walk 3.c3d"
            bad.write_bytes(b"\x02\x50" + b"\x00" * 6 + b"not a c3d file")
            attach_reference(d, bad)
        elif ref is not None:
            delay = {"ok": 0.0, "late": 2.0, "far": 100.0}[ref]
            f = walk_reference_csv(tmp / f"{rid}.csv", code, seed, delay_s=delay)
            attach_reference(d, f, offset_s=-2.0 if ref == "late" else 0.0)

    def fake(rec_dir: Path, options: Any, live: Any = None, use_cache: bool = True
             ) -> dict[str, Any]:
        if options.sensors is not None and not set(options.sensors) <= {"S1", "S2"}:
            raise InputError(f"recording {rec_dir.name} has no sensor "
                             f"{', '.join(sorted(set(options.sensors) - {'S1', 'S2'}))}; "
                             "its sensors are S1, S2")
        a = dict(analyses[rec_dir.name])
        a["sensors_used"] = list(options.sensors or ("S1", "S2"))
        return a

    s = Settings(data_dir=data, viewer_enabled=False, admin_password="study-pw",
                 node_token="study-node-token", storage_check_interval_s=0)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(an, "analyse_recording", fake)
        with TestClient(create_app(s)) as c:
            r = c.post("/api/auth/login", json={"username": "admin", "password": "study-pw"})
            c.headers["Authorization"] = f"Bearer {r.json()['token']}"
            from app.db.data import Project, Recording, Session, Subject

            ids = {}
            with c.app.state.db_sessions() as db:  # type: ignore[attr-defined]
                for name, codes in PROJECTS.items():
                    p = Project(name=name)
                    db.add(p)
                    for code in codes:
                        se = Session(subject=Subject(project=p, code=code),
                                     date=dt.date(2026, 9, 1), label="lab")
                        db.add(se)
                        for rid, (c_, _, label, state, _) in RECORDINGS.items():
                            if c_ == code:
                                db.add(Recording(id=rid, session=se, label=label, state=state))
                db.commit()
                ids = {p.name: p.id for p in db.query(Project).all()}
            c.projects = ids  # type: ignore[attr-defined]
            yield c


def _url(c: TestClient, project: str, **q: str) -> tuple[str, dict[str, str]]:
    return f"/api/reports/projects/{c.projects[project]}/agreement", q  # type: ignore[attr-defined]


def _get(c: TestClient, project: str, **q: str) -> Any:
    path, params = _url(c, project, **q)
    return c.get(path, params=params)


@pytest.fixture(scope="module")
def study(client: TestClient) -> dict[str, Any]:
    r = _get(client, "Validation study", format="json")
    assert r.status_code == 200, r.text
    return dict(r.json())


def test_the_study_has_the_papers_three_levels(study: dict[str, Any]) -> None:
    # four subjects; A1 A2, B1 B2, C1 C2, D1 (D2 is not complete, B3's reference is broken)
    assert (study["subjects"], study["trials"]) == (4, 7)
    labels = [r["label"] for r in study["rows"]]
    for want in ("AV walking speed (cm/s)", "Step time L (s)", "Step time R (s)",
                 "Stride length L (cm)", "Step length R (cm)", "Step width L (cm)",
                 "Step width R (cm)", "AV step width L (cm)", "AV step width R (cm)",
                 "AV step width AVG (cm)", "AV step length AVG (cm)"):
        assert want in labels, labels
    # Table 1 before Table 2, as the paper
    tables = [r["table"] for r in study["rows"]]
    assert tables == sorted(tables)
    rows = {r["label"]: r for r in study["rows"]}
    width = rows["Step width L (cm)"]
    # the same walks seen with two noises: close agreement, in cm
    assert width["unit"] == "cm" and abs(width["bias"]) < 2.0 and width["n"] >= 10
    assert 9.0 < width["mean_reference"] < 16.0
    speed = rows["AV walking speed (cm/s)"]
    assert speed["n"] == 4 and 100.0 < speed["mean_measured"] < 140.0
    assert speed["icc_a1"] > 0.9
    # the reference started 2 s before the recording, said by its offset: its steps still
    # matched
    assert study["unmatched"] == []
    # every value JSON can hold (a NaN would have been a 500)
    assert all(v is None or isinstance(v, int | float | str) for r in study["rows"]
               for v in r.values())


def test_left_out_recordings_are_named_with_why(study: dict[str, Any]) -> None:
    notes = study["notes"]
    broken = [n for n in notes if "B3" in n]
    assert broken == ["Trial “walk 3” (recording B3): the reference could not be used — "
                      "'vicon walk 3.c3d' is not a readable C3D file: the file is damaged or "
                      "not a C3D file (export it again from the motion-capture software, as "
                      "C3D)"], notes
    # (the server's data sync may already have marked the recording, tracked by no node
    # that is connected, incomplete: either state is named, and why it was left out)
    left = [n for n in notes if "D2" in n]
    assert len(left) == 1 and re.fullmatch(
        r"Trial “walk 2” \(recording D2, (still on the sensors|incomplete)\) was not used: "
        r"it is not complete on the server\.", left[0]), notes
    assert len(notes) == 2, notes
    basis = study["basis"]
    assert basis[0] == ("Project Validation study: 4 subjects, 7 trials with a reference (1 "
                        "more left out, see the notes); 1 complete recording without a "
                        "reference not part of the study.")
    assert "Sensors: all sensors." in basis and "Sensor fusion: Weighted by view angle." in basis
    assert any(b.startswith("Gait events: Foot placements") for b in basis)


def test_html_csv_and_pdf(client: TestClient, study: dict[str, Any]) -> None:
    r = _get(client, "Validation study")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    html = r.text
    assert "<html" not in html.lower()[:200]  # a fragment for the console page
    for word in ("Agreement with a reference system", "Step width L", "AV step width AVG",
                 "Project Validation study", "vicon walk 3.c3d"):
        assert word in html, word
    assert html.count(">gaitrig</th>") == 2 and html.count(">reference</th>") == 2
    # the reference system named by the user heads its columns (escaped as any text)
    named = _get(client, "Validation study", reference_name="  Vicon <Nexus>  ").text
    assert named.count(">Vicon &lt;Nexus&gt;</th>") == 2 and ">reference</th>" not in named
    assert _get(client, "Validation study", reference_name="x" * 41).status_code == 422
    r = _get(client, "Validation study", format="csv")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/csv")
    cd = r.headers["content-disposition"]
    assert cd == (f'attachment; filename="agreement-Validation_study-'
                  f'{dt.date.today().isoformat()}.csv"')
    rows = list(csv.DictReader(io.StringIO(r.text)))
    assert [(x["parameter"], x["level"]) for x in rows] == [
        (x["parameter"], x["level"]) for x in study["rows"]]
    width = next(x for x in rows if (x["parameter"], x["level"]) == ("step width", "L"))
    assert float(width["bias"]) == pytest.approx(
        next(x["bias"] for x in study["rows"] if x["label"] == "Step width L (cm)"), rel=1e-4)
    r = _get(client, "Validation study", format="pdf")
    assert r.status_code == 200 and r.content.startswith(b"%PDF")
    assert r.headers["content-disposition"].endswith('.pdf"')


def test_options_are_in_the_basis_and_the_audit(client: TestClient,
                                                study: dict[str, Any]) -> None:
    r = _get(client, "Validation study", format="json", sensors="S1",
             method="heelstrike", estimator="mean")
    assert r.status_code == 200, r.text
    basis = r.json()["basis"]
    assert "Sensors: S1." in basis and "Sensors: all sensors." not in basis
    assert "Sensor fusion: Equal-weight mean." in basis
    assert any(b.startswith("Gait events: Heel strike / toe off") for b in basis)
    e = client.get("/api/audit").json()[0]
    assert (e["action"], e["target"]) == (
        "export", f"project {client.projects['Validation study']}")  # type: ignore[attr-defined]
    assert e["detail"] == "agreement json (heelstrike, mean, sensors S1; 4 subjects, 7 trials)"
    assert "V01" not in e["detail"]


def test_refusals_are_clear(client: TestClient) -> None:
    r = client.get("/api/reports/projects/987654/agreement")
    assert r.status_code == 404 and r.json()["detail"] == "no project with id 987654"
    r = _get(client, "No references")
    assert r.status_code == 422
    assert r.json()["detail"] == (
        "project No references has no recording with a reference attached; attach one to "
        "each validation walk (Reports page, 'Reference recording for the agreement "
        "section', or the Subjects page)")
    r = _get(client, "Far apart", format="csv")
    assert r.status_code == 422
    assert r.json()["detail"].startswith(
        "project Far apart: no agreement can be computed from 1 subject and 1 trial")
    assert "at least three steps must match the reference in time" in r.json()["detail"]
    # a sensor no recording has: each trial says so, and the study cannot be computed
    r = _get(client, "Validation study", sensors="S9")
    assert r.status_code == 422 and "has no sensor S9" in r.json()["detail"]
    r = _get(client, "Validation study", sensors="S1;drop")
    assert r.status_code == 400 and "must be 1-64 characters" in r.json()["detail"]
    r = _get(client, "Validation study", format="xml")
    assert r.status_code == 422  # FastAPI's validation, not a 500


def test_a_reference_is_analysed_once_per_version(tmp_path: Path,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """A project's study reads every reference at each request (HTML, PDF and CSV are
    three): each file is analysed once per version and method; a file replaced (another
    size or modification time) is analysed anew, and one gone is a clear error."""
    import os

    from engine.errors import GaitrigError

    calls: list[str] = []
    real = an.analyse_file

    def counted(path: Path, method: str = "crossing", *a: Any, **k: Any) -> dict[str, Any]:
        calls.append(method)
        return real(path, method, *a, **k)

    monkeypatch.setattr(an, "analyse_file", counted)
    f = walk_reference_csv(tmp_path / "ref.csv", "V09", 9)
    first = an.reference_gait(f, "crossing")
    first["steps"].clear()  # a caller's change does not reach the next caller
    again = an.reference_gait(f, "crossing")
    assert again["steps"] and calls == ["crossing"]
    assert an.reference_steps(f, "crossing") == again["steps"] and len(calls) == 1
    an.reference_gait(f, "heelstrike")
    assert calls == ["crossing", "heelstrike"]
    walk_reference_csv(f, "V09", 10)  # replaced by another walk
    os.utime(f, ns=(1, 1))
    an.reference_gait(f, "crossing")
    assert len(calls) == 3
    f.unlink()
    with pytest.raises(GaitrigError, match=r"cannot read ref\.csv"):
        an.reference_gait(f, "crossing")
