"""A part's ``images_skipped`` is stored in its database row when the part arrives on the
server (revision 0002), and read from there; a part stored before that revision (no
stored count) is still answered from the server copy's meta.json."""

from __future__ import annotations

import json
import time
from pathlib import Path

import sqlalchemy as sa
from alembic.config import Config
from fastapi.testclient import TestClient

from alembic import command
from app.db import data as m
from app.db.base import alembic_head, make_engine
from app.server.recording import Part, Recording
from app.server.storage import StorageLayout
from tests.app.data.test_data_api import _recording_row
from tests.app.data.walk_recording import walk_part

WAIT_S = 30.0  # only a bound for a broken test; nothing is timed


def _set_meta(layout: StorageLayout, skipped: int) -> None:
    path = layout.part_dir("R1", "S1") / "meta.json"
    meta = json.loads(path.read_text())
    meta["images_skipped"] = skipped
    path.write_text(json.dumps(meta))


def _stored(client: TestClient) -> int | None:
    with client.app.state.db_sessions() as db:  # type: ignore[attr-defined]
        return db.scalars(sa.select(m.RecordingPart.images_skipped).where(
            m.RecordingPart.recording_id == "R1", m.RecordingPart.node_id == "S1")).first()


def _answered(client: TestClient) -> int | None:
    r = client.get("/api/recordings/R1")
    assert r.status_code == 200, r.text
    listed = client.get("/api/recordings", params={"ids": "R1"}).json()[0]
    assert listed["parts"] == r.json()["parts"]
    [part] = r.json()["parts"]
    return part["images_skipped"]  # type: ignore[no-any-return]


def test_stored_when_the_part_arrives_and_read_from_the_database(
        admin_client: TestClient, tmp_path: Path) -> None:
    client = admin_client
    layout = StorageLayout(tmp_path)
    _recording_row(client)
    with client.app.state.db_sessions() as db:  # type: ignore[attr-defined]
        db.get(m.Recording, "R1").state = "transferring"  # being transferred
        db.commit()
    walk_part(tmp_path, tmp_path / "node-side")  # the part has arrived on the server
    _set_meta(layout, 4)
    now = time.time()
    client.app.state.hub.recordings.recordings["R1"] = Recording(  # type: ignore[attr-defined]
        "R1", t_start=now - 10, t_stop=now - 5,
        parts={"S1": Part("S1", state="complete", on_server=True, n_frames=300)})
    # the data sync (the server's background task) stores the count with the part
    deadline = time.monotonic() + WAIT_S
    while _stored(client) is None:
        assert time.monotonic() < deadline, "images_skipped never stored"
        time.sleep(0.1)
    assert _stored(client) == 4
    # answered from the row: the meta.json is not read again
    _set_meta(layout, 9)
    assert _answered(client) == 4
    # a part stored before the column existed has no count: meta.json answers
    with client.app.state.db_sessions() as db:  # type: ignore[attr-defined]
        db.execute(sa.update(m.RecordingPart).values(images_skipped=None))
        db.commit()
    assert _stored(client) is None
    assert _answered(client) == 9


def test_a_database_of_revision_0001_gets_the_column_with_its_rows_kept(
        tmp_path: Path) -> None:
    path = tmp_path / "old.sqlite3"
    old = sa.create_engine(f"sqlite:///{path}")
    cfg = Config()
    cfg.set_main_option("script_location", str(m.ALEMBIC_DIR))
    with old.begin() as conn:
        cfg.attributes["connection"] = conn
        command.upgrade(cfg, "0001")
        cols = {c["name"] for c in sa.inspect(conn).get_columns("recording_parts")}
        assert "images_skipped" not in cols
        conn.execute(sa.text(
            "insert into recording_parts (recording_id, node_id, state, n_frames, "
            "bytes_total, bytes_done, attempts, updated_at) "
            "values ('R1', 'S1', 'complete', 300, 10, 10, 1, '2026-01-01')"))
    old.dispose()
    eng = make_engine(path)
    with eng.connect() as c:
        version = c.execute(sa.text("select version_num from alembic_version")).scalar()
        assert version == alembic_head()
        row = c.execute(sa.text("select node_id, n_frames, images_skipped "
                                "from recording_parts")).one()
        assert tuple(row) == ("S1", 300, None)
    eng.dispose()
