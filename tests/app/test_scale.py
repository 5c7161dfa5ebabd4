"""The list endpoints at clinic scale: a bounded number of SQL queries whatever the number
of rows, server-side paging (``limit``/``offset``, ``X-Total-Count``), search and sort,
and a largest page refused with a message. Timing is measured by ``bench/list_scale.py``,
not here."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.config import Settings
from app.db.base import make_engine
from app.main import create_app
from bench._clinic import Clinic, populate, subject_code

SMALL, LARGE = 30, 300  # subjects
RECS = 2  # recordings per subject

#: Every list of the console, as the pages ask for them.
LISTS = ("/api/projects", "/api/subjects", "/api/subjects?project_id=1&sort=-created",
         "/api/sessions?subject_id=3",
         "/api/subjects/3", "/api/recordings", "/api/recordings?state=complete",
         "/api/reports/recordings", "/api/reports/recordings?q=baseline", "/api/audit",
         "/api/storage?subjects=false")


class Rig:
    """The app on a populated data folder, with a counter of the SQL statements run."""

    def __init__(self, client: TestClient, clinic: Clinic) -> None:
        self.client, self.clinic, self.statements = client, clinic, 0

    def get(self, path: str, **params: Any) -> Any:
        return self.client.get(path, params=params or None)

    def search(self, **body: Any) -> Any:
        return self.client.post("/api/subjects/search", json=body)

    def queries(self, path: str, body: dict[str, Any] | None = None) -> int:
        """SQL statements the request ran (the login's lookups included); a POST of
        ``body`` if given."""
        self.statements = 0
        r = self.client.get(path) if body is None else self.client.post(path, json=body)
        assert r.status_code == 200, (path, r.text)
        return self.statements


def _rig(data_dir: Path, n_subjects: int) -> Iterator[Rig]:
    clinic = populate(data_dir, n_subjects, RECS, n_audit=10 * n_subjects,
                      n_with_files=n_subjects // 2)
    s = Settings(data_dir=data_dir, viewer_enabled=False, node_token="test-node-token",
                 admin_password="secret-pw")
    app = create_app(s)
    with TestClient(app) as c:
        # the data sync's own queries (twice a second) are not the requests'
        c.portal.call(app.state.datasync.stop)  # type: ignore[union-attr]
        r = c.post("/api/auth/login", json={"username": "admin", "password": "secret-pw"})
        c.headers["Authorization"] = f"Bearer {r.json()['token']}"
        rig = Rig(c, clinic)
        engine = app.state.db_sessions.kw["bind"]

        def count(*_: Any) -> None:
            rig.statements += 1

        sa.event.listen(engine, "before_cursor_execute", count)
        yield rig


@pytest.fixture(scope="module")
def small(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    yield from _rig(tmp_path_factory.mktemp("small"), SMALL)


@pytest.fixture(scope="module")
def large(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    yield from _rig(tmp_path_factory.mktemp("large"), LARGE)


def test_list_queries_do_not_grow_with_the_rows(small: Rig, large: Rig) -> None:
    for path in LISTS:
        n_small, n_large = small.queries(path), large.queries(path)
        assert n_large == n_small, f"{path}: {n_small} queries for {SMALL} subjects, " \
                                   f"{n_large} for {LARGE}"
        assert n_large <= 8, f"{path}: {n_large} queries"
    body = {"q": "P0002", "sort": "-created"}
    assert small.queries("/api/subjects/search", body) == \
        large.queries("/api/subjects/search", body) <= 8


def _codes(rows: list[dict[str, Any]]) -> list[str]:
    return [r["code"] for r in rows]


def test_subjects_page_through_sorted_with_the_total(large: Rig) -> None:
    seen: list[str] = []
    for offset in range(0, LARGE, 120):
        r = large.get("/api/subjects", limit=120, offset=offset)
        assert r.headers["X-Total-Count"] == str(LARGE)
        assert len(r.json()) == min(120, LARGE - offset)
        seen += _codes(r.json())
    assert seen == sorted(large.clinic.subject_codes.values())
    down = _codes(large.get("/api/subjects", sort="-code", limit=5).json())
    assert down == sorted(large.clinic.subject_codes.values(), reverse=True)[:5]
    newest = large.get("/api/subjects", sort="-created", limit=1).json()[0]
    assert newest["code"] == subject_code(LARGE)
    # the default page
    r = large.get("/api/subjects")
    assert len(r.json()) == 100 and r.headers["X-Total-Count"] == str(LARGE)
    # one project: every fourth subject (populate's round robin)
    r = large.get("/api/subjects", project_id=2, limit=500)
    assert r.headers["X-Total-Count"] == str(LARGE // 4)
    assert {s["project_id"] for s in r.json()} == {2}


def test_subjects_search_finds_the_code(large: Rig) -> None:
    r = large.search(q="p0017")  # case-insensitive substring
    assert _codes(r.json()) == [f"P0017{k}" for k in range(10)]
    assert r.headers["X-Total-Count"] == "10"
    assert _codes(large.search(q=" P00042 ").json()) == ["P00042"]
    r = large.search(q="P001", project_id=2, sort="-code", limit=3, offset=1)
    every = sorted((c for k, c in large.clinic.subject_codes.items()
                    if "P001" in c and k % 4 == 2), reverse=True)
    assert _codes(r.json()) == every[1:4] and r.headers["X-Total-Count"] == str(len(every))
    # LIKE's wildcards are taken literally
    for text in ("%", "_", "P0_01", "\\"):
        r = large.search(q=text)
        assert r.json() == [] and r.headers["X-Total-Count"] == "0", text
    assert large.search(q="x" * 101).status_code == 422
    assert large.search(q="P0", limit=501).status_code == 422
    # a code in a URL would stay in the access logs: refused, saying where it goes
    r = large.get("/api/subjects", q="P00042")
    assert r.status_code == 400 and "POST /api/subjects/search" in r.json()["detail"]


def test_subject_list_item_is_the_subject(large: Rig) -> None:
    item = large.search(q="P00003").json()[0]
    one = large.get(f"/api/subjects/{item['id']}").json()
    one.pop("sessions")
    assert item == one
    assert item["n_recordings"] == RECS and item["n_sessions"] >= 1
    # without the disk usage (no folder read): the same but for it
    brief = large.search(q="P00003", bytes_on_server=False).json()[0]
    assert brief == {**item, "bytes_on_server": None}
    assert large.get("/api/subjects", offset=2, limit=1, bytes_on_server="false"
                     ).json()[0]["bytes_on_server"] is None


def test_largest_page_is_refused_with_a_message(large: Rig) -> None:
    for path, largest in (("/api/subjects", 500), ("/api/recordings", 500),
                          ("/api/reports/recordings", 500), ("/api/projects", 1000)):
        r = large.get(path, limit=largest + 1, offset=40)
        assert r.status_code == 422, path
        msg = r.json()["detail"]
        assert f"largest page of this list ({largest})" in msg and \
            f"offset={40 + largest}" in msg, msg
        assert large.get(path, limit=largest).status_code == 200
        assert large.get(path, limit=0).status_code == 422
        assert large.get(path, offset=-1).status_code == 422


def test_recordings_page_filter_and_ids(large: Rig) -> None:
    every = large.clinic.recording_ids
    r = large.get("/api/recordings", limit=50, offset=50)
    assert r.headers["X-Total-Count"] == str(len(every))
    got = [x["id"] for x in r.json()]
    newest_first = sorted(every, reverse=True)  # populate's ids carry their start time
    assert got == newest_first[50:100]
    for st in ("complete", "incomplete"):
        rows = large.get("/api/recordings", state=st, limit=500).json()
        assert rows and {x["state"] for x in rows} == {st}
    want = every[:3]
    assert sorted(x["id"] for x in large.get("/api/recordings",
                                              ids=",".join(want)).json()) == sorted(want)
    r = large.get("/api/recordings", q=every[7][1:12].lower())
    assert every[7] in [x["id"] for x in r.json()]


def test_reports_recordings_page_and_search(large: Rig) -> None:
    on_server = large.clinic.recording_ids[-(LARGE // 2):]
    seen: list[str] = []
    for offset in range(0, len(on_server) + 1, 60):
        r = large.get("/api/reports/recordings", limit=60, offset=offset)
        assert r.headers["X-Total-Count"] == str(len(on_server))
        seen += [x["id"] for x in r.json()]
    assert sorted(seen) == sorted(on_server) and len(seen) == len(set(seen))
    code = subject_code(LARGE)  # the newest subject: its recordings are on the server
    sid = large.search(q=code).json()[0]["id"]
    rows = large.get("/api/reports/recordings", subject_id=sid).json()
    assert len(rows) == RECS and {x["subject_code"] for x in rows} == {code}
    assert [x["id"] for x in large.get("/api/reports/recordings", q=rows[0]["id"][3:].lower()
                                       ).json()] == [rows[0]["id"]]
    labelled = large.get("/api/reports/recordings", q="6 WEEKS", limit=500).json()
    assert labelled and {x["session_label"] for x in labelled} == {"6 weeks"}
    assert large.get("/api/reports/recordings", q="no-such-thing").json() == []


def test_projects_and_audit_totals(large: Rig) -> None:
    r = large.get("/api/projects", limit=2, offset=1)
    assert r.headers["X-Total-Count"] == "4"
    assert [p["name"] for p in r.json()] == ["Clinic study 2", "Clinic study 3"]
    assert sum(p["n_subjects"] for p in large.get("/api/projects").json()) == LARGE
    assert [p["name"] for p in large.get("/api/projects", q="STUDY 4").json()] == \
        ["Clinic study 4"]
    r = large.get("/api/audit", limit=10, action="delete")
    assert len(r.json()) == 10 and {e["action"] for e in r.json()} == {"delete"}
    total = int(r.headers["X-Total-Count"])
    after = large.get("/api/audit", limit=10, action="delete", before=r.json()[-1]["id"])
    assert int(after.headers["X-Total-Count"]) == total - 10


def test_migration_0003_adds_the_indexes(tmp_path: Path) -> None:
    from alembic.config import Config

    from alembic import command
    from app.db.data import ALEMBIC_DIR

    path = tmp_path / "old.sqlite3"
    old = sa.create_engine(f"sqlite:///{path}")
    cfg = Config()
    cfg.set_main_option("script_location", str(ALEMBIC_DIR))
    with old.begin() as conn:
        cfg.attributes["connection"] = conn
        command.upgrade(cfg, "0002")
        assert "ix_recordings_state" not in {
            i["name"] for i in sa.inspect(conn).get_indexes("recordings")}
    old.dispose()
    eng = make_engine(path)
    with eng.connect() as c:
        names = {i["name"] for t in ("recordings", "subjects")
                 for i in sa.inspect(c).get_indexes(t)}
        plan = " ".join(str(x) for x in c.execute(sa.text(
            "explain query plan select id from recordings where state != 'complete' "
            "order by created_at desc")).all())
    eng.dispose()
    assert {"ix_recordings_state", "ix_recordings_created_at", "ix_subjects_code"} <= names
    assert "ix_recordings_" in plan


def test_recording_list_is_saved_as_asdict_wrote_it(tmp_path: Path) -> None:
    """recordings.json (every recording the server made, written on every change) is
    built without ``asdict``'s deep copies, and reads back the same."""
    from dataclasses import asdict

    from app.server.recording import Part, Recording, RecordingManager, _plain
    from app.server.registry import NodeRegistry

    rec = Recording("R20260101-100000-abcd", 1767261600.0, 1767261625.0, 1767261599.5,
                    ["depth"], 3, {"S1": Part("S1", "complete", "kept", 750, 4096, 1.0, 26.0,
                                              1767261600.0, 1767261625.0,
                                              {"offset_s": 0.5, "drift": 1e-6, "t_ref": 3.0},
                                              True, 1.0),
                                   "S2": Part("S2")})
    assert _plain(rec) == asdict(rec)
    rm = RecordingManager(NodeRegistry(), tmp_path)
    rm.recordings[rec.id] = rec
    rm.save()
    again = RecordingManager(NodeRegistry(), tmp_path).recordings[rec.id]
    assert asdict(again) == asdict(rec)
