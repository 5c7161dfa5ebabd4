"""A subject's data lifecycle as health data, end to end with real server and node
processes: record, derive (analysis, reference), refuse a wrong confirmation and a
deletion while recording, delete, then search every file of the server and the nodes —
database included, byte for byte — for any trace of the subject."""

from __future__ import annotations

import io
import json
import sqlite3
import urllib.error
import zipfile
from pathlib import Path
from typing import Any

import pytest

from tests.app.data.test_record_flow import (
    download,
    http_error,
    record,
    two_node_rig,
    upload,
    wait_state,
)
from tests.integration.conftest import wait_for

CODE = "ZQ7311"  # distinctive, so a byte search cannot hit anything else
NOTE = "Jane Roe-Wqxv, knee replacement 2019"
KEEP = "KP0042"


def _traces(root: Path, needles: list[str]) -> list[str]:
    """Every file below ``root`` whose path or bytes contain one of ``needles``."""
    found = []
    for p in sorted(root.rglob("*")):
        hit = [n for n in needles if n in str(p.relative_to(root))]
        if p.is_file():
            data = p.read_bytes()
            hit += [n for n in needles if n.encode() in data or n.encode("utf-16-le") in data]
        if hit:
            found.append(f"{p.relative_to(root)}: {sorted(set(hit))}")
    return found


@pytest.mark.timeout(400)
def test_deleting_a_subject_leaves_no_trace(make_rig: Any, tmp_path: Path) -> None:
    rig = two_node_rig(make_rig)
    p = rig.api("/api/projects", {"name": "Lifecycle study"})
    subj = rig.api("/api/subjects", {"project_id": p["id"], "code": CODE, "notes": NOTE,
                                     "height_m": 1.7, "birth_year": 1961})
    keep = rig.api("/api/subjects", {"project_id": p["id"], "code": KEEP})
    sess = rig.api("/api/sessions", {"subject_id": subj["id"], "label": "baseline"})
    keep_sess = rig.api("/api/sessions", {"subject_id": keep["id"], "label": "baseline"})

    rec = record(rig, sess["id"], 1.5, ["depth"])
    assert wait_state(rig, rec, {"complete", "incomplete"})["state"] == "complete"
    kept = record(rig, keep_sess["id"], 1.0)
    assert wait_state(rig, kept, {"complete", "incomplete"})["state"] == "complete"
    # derived data: an analysis (cached on disk, whatever its outcome) and a reference
    try:
        rig.api(f"/api/reports/recordings/{rec}/analysis")
    except urllib.error.HTTPError as exc:  # no walk in 1.5 s: the failure is cached too
        assert exc.code == 422, exc
    # (a synthetic walk: the 1.5 s recording's own export has no steps, and a reference
    # without steps is refused)
    from tests.app.mocap_files import walk_skeleton_c3d

    upload(rig, f"/api/exports/{rec}/references", f"{CODE} vicon.c3d", walk_skeleton_c3d()[0])

    server = tmp_path / "server"
    nodes = {n: rig.node_dir(n) for n in ("S1", "S2")}
    assert (server / "recordings" / rec).is_dir() and (server / "references" / rec).is_dir()
    assert all((d / "recordings" / rec).is_dir() for d in nodes.values())

    # the nodes hold pseudonymous recording ids only; no file name on the server names
    # the subject (its code, notes and project live in the database alone)
    who = [CODE, NOTE.split(",")[0], "Lifecycle study"]
    for d in nodes.values():
        assert _traces(d, who) == []
    assert [f for f in _traces(server, who) if not f.startswith("gaitrig.sqlite3")] == []

    # right of access: one zip with everything, the parts byte-identical to the nodes'
    z = zipfile.ZipFile(io.BytesIO(download(rig, f"/api/subjects/{subj['id']}/export")))
    for n in ("S1", "S2"):
        assert (z.read(f"recordings/{rec}/{n}/frames.bin")
                == (nodes[n] / "recordings" / rec / "frames.bin").read_bytes())
        assert z.read(f"recordings/{rec}/{n}/skeleton.csv").startswith(b"time,")
    assert json.loads(z.read("subject.json"))["notes"] == NOTE
    assert any(x.startswith(f"references/{rec}/") for x in z.namelist())
    assert not any(kept in x for x in z.namelist())  # only this subject's data

    # a wrong confirmation deletes nothing
    code, msg = http_error(lambda: rig.api(f"/api/subjects/{subj['id']}/delete",
                                           {"confirm": CODE.lower()}))
    assert code == 400 and repr(CODE) in msg
    # a subject being recorded cannot be deleted (409 says why), and nothing is deleted
    running = rig.api(f"/api/sessions/{sess['id']}/recordings", {"label": "walk 2"})["id"]
    code, msg = http_error(lambda: rig.api(f"/api/subjects/{subj['id']}/delete",
                                           {"confirm": CODE}))
    assert code == 409 and "running" in msg, msg
    rig.api(f"/api/recordings/{running}/stop", {})
    assert (server / "recordings" / rec).is_dir()
    assert all((d / "recordings" / rec).is_dir() for d in nodes.values())
    assert rig.api(f"/api/subjects/{subj['id']}")["n_recordings"] == 2
    wait_state(rig, running, {"complete", "incomplete"})

    r = rig.api(f"/api/subjects/{subj['id']}/delete", {"confirm": CODE})
    assert r["recordings_deleted"] == 2, r
    assert r["node_copies"] == {"S1": "deleted", "S2": "deleted"}, r
    wait_for(lambda: rig.api("/api/storage")["pending_node_deletions"] == {}, 30,
             "the nodes to delete their copies")
    code, _ = http_error(lambda: rig.api(f"/api/subjects/{subj['id']}"))
    assert code == 404
    code, _ = http_error(lambda: download(rig, f"/api/subjects/{subj['id']}/export"))
    assert code == 404
    # no trace anywhere: paths, files, the database (and its WAL) byte for byte; the
    # recording ids only in the audit trail (which says what was exported and deleted)
    needles = [CODE, NOTE.split(",")[0], rec, running]
    found = _traces(server, needles)
    assert [f for f in found if not f.startswith("gaitrig.sqlite3")] == []
    assert [f for f in found if CODE in f or NOTE[:8] in f] == []
    with sqlite3.connect(server / "gaitrig.sqlite3") as db:
        for (table,) in db.execute("select name from sqlite_master where type = 'table'"):
            dump = str(db.execute(f"select * from {table}").fetchall())
            assert CODE not in dump and NOTE[:8] not in dump, table
            if table != "audit_events":
                assert rec not in dump and running not in dump, table
        trail = db.execute("select username, action, target from audit_events").fetchall()
    assert ("admin", "delete", f"subject {subj['id']}") in trail
    assert ("admin", "export", f"recording {rec}") in trail
    for d in nodes.values():
        assert _traces(d, needles) == []
    # the other subject's data is untouched
    assert (server / "recordings" / kept).is_dir()
    assert all((d / "recordings" / kept).is_dir() for d in nodes.values())
    assert rig.api(f"/api/subjects/{keep['id']}")["n_recordings"] == 1
    # the logs name recordings by their pseudonymous id only, never the subject
    for name in rig.logs:
        text = rig.log_text(name)
        assert CODE not in text and NOTE.split(",")[0] not in text, name
