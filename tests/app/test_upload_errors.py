"""A file refused at upload is named as the person chose it: the readers' messages named
the server's temporary copy ("'walk.csv' is not a readable CSV file:
.1a24b5567737b4e5.csv.upload.tmp: no 'time' column", "reference upload.c3d: cannot read
upload.c3d as C3D", "bad.csv: upload.csv: no 'time' column"), a file the clinician never
had. Checked on the three upload routes of reference and report files, each naming the file
once, and in the notes of a report on a stored reference it cannot use."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

#: What a temporary or server-side name looks like in a message.
INTERNAL = re.compile(r"\.upload\.tmp|\bupload\.(csv|c3d|trc)\b|[0-9a-f]{16}")

#: (file name, content) of files that are not what their extension says.
BAD_FILES = [
    ("my walk.csv", b"time_s;x\nhello\n"),
    ("trial 3.c3d", b"not a c3d file at all"),
    ("Gang.trc", b"PathFileType\t4\n\x00\x01"),
]


def _filed_recording(client: TestClient, data_dir: Path, rec_id: str,
                     code: str = "UP1") -> None:
    """``rec_id`` filed under a new subject ``code``, with one sensor part on the server."""
    from app.db import data as m

    pid = client.post("/api/projects", json={"name": f"uploads {code}"}).json()["id"]
    sid = client.post("/api/subjects", json={"project_id": pid, "code": code}).json()["id"]
    se = client.post("/api/sessions", json={"subject_id": sid}).json()["id"]
    with client.app.state.db_sessions() as db:  # type: ignore[attr-defined]
        db.add(m.Recording(id=rec_id, session_id=se, state="complete"))
        db.commit()
    part = data_dir / "recordings" / rec_id / "S1"
    part.mkdir(parents=True)
    (part / "frames.bin").write_bytes(b"")
    (part / "meta.json").write_text("{}")


def _says_only_the_chosen_name(detail: str, name: str) -> None:
    assert name in detail, detail
    assert not INTERNAL.search(detail), f"a server-side file name in {detail!r}"


@pytest.mark.parametrize(("name", "data"), BAD_FILES)
def test_refused_uploads_name_the_chosen_file(admin_client: TestClient, tmp_path: Path,
                                              name: str, data: bytes) -> None:
    _filed_recording(admin_client, tmp_path, "R1")
    # Subjects page: a reference attached to a recording
    r = admin_client.post("/api/exports/R1/references",
                          files={"file": (name, data, "application/octet-stream")})
    assert r.status_code == 400, r.text
    _says_only_the_chosen_name(r.json()["detail"], name)
    # each route names the file once: "'Gang.trc' is not a readable TRC file: Gang.trc is
    # not a TRC file …" (Subjects page), "reference my walk.csv: my walk.csv: no 'time'
    # column" (Reports page reference), "trial 3.c3d: cannot read trial 3.c3d as C3D: …"
    # (Analyse a file) named it twice
    assert r.json()["detail"].count(name) == 1, r.json()["detail"]
    # Reports page: the reference of the agreement section
    r = admin_client.post("/api/reports/recordings/R1/reference",
                          files={"file": (name, data, "application/octet-stream")})
    assert r.status_code == 400, r.text
    _says_only_the_chosen_name(r.json()["detail"], name)
    assert r.json()["detail"].count(name) == 1, r.json()["detail"]
    # Reports page: "Analyse a file"
    r = admin_client.post("/api/reports/upload", data={"subject": "UP1"},
                          files={"file": (name, data, "application/octet-stream")})
    assert r.status_code == 422, r.text
    _says_only_the_chosen_name(r.json()["detail"], name)
    assert r.json()["detail"].count(name) == 1, r.json()["detail"]


#: What a bad C3D file's message says instead of ezc3d's words, and what it never says.
NOT_C3D = ("the file is damaged or not a C3D file (export it again from the motion-capture "
           "software, as C3D)")
LIBRARY_WORDS = re.compile(r"iostream|ezc3d|processor type|valid c3d file", re.IGNORECASE)


def test_a_damaged_c3d_says_what_it_is_not_and_what_to_do(admin_client: TestClient,
                                                          tmp_path: Path) -> None:
    """Each upload route of a C3D file (Subjects page reference, Reports page reference,
    "Analyse a file") says the file is damaged or not C3D and to export it again; the
    reader's "File must be a valid c3d file: iostream error" was the end of each."""
    _filed_recording(admin_client, tmp_path, "R1")
    name, data = "trial 3.c3d", b"not a c3d file at all"
    for url, form, code, want in [
        ("/api/exports/R1/references", None, 400,
         f"'trial 3.c3d' is not a readable C3D file: {NOT_C3D}"),
        ("/api/reports/recordings/R1/reference", None, 400,
         f"'trial 3.c3d' is not a readable C3D file: {NOT_C3D}"),
        ("/api/reports/upload", {"subject": "UP1"}, 422,
         f"'trial 3.c3d' is not a readable C3D file: {NOT_C3D}"),
    ]:
        r = admin_client.post(url, data=form,
                              files={"file": (name, data, "application/octet-stream")})
        assert r.status_code == code, r.text
        detail = r.json()["detail"]
        assert detail == want
        assert not LIBRARY_WORDS.search(detail), detail


#: What a C3D file cut short after its first kilobyte (of 86) says, after its name.
CUT = ("the file is cut short (it holds 0 of the 525 frames its header announces); copy or "
       "export it again")


def test_a_c3d_file_cut_short_says_so_on_every_upload(admin_client: TestClient,
                                                      tmp_path: Path) -> None:
    """A C3D file whose copy stopped after 1 kB was attached as a reference of 525 frames
    of gaps; each upload route refuses it, saying it is cut short and what to do."""
    from engine.io.c3d import write_c3d
    from engine.sim.straight_walk import synth_walk, walk_markers

    _filed_recording(admin_client, tmp_path, "R1")
    whole = tmp_path / "whole.c3d"
    write_c3d(whole, walk_markers(synth_walk()), units="mm")
    name, data = "walk.c3d", whole.read_bytes()[:1024]
    for url, form, code, want in [
        ("/api/exports/R1/references", None, 400,
         f"'walk.c3d' is not a readable C3D file: {CUT}"),
        ("/api/reports/recordings/R1/reference", None, 400,
         f"'walk.c3d' is not a readable C3D file: {CUT}"),
        ("/api/reports/upload", {"subject": "UP1"}, 422,
         f"'walk.c3d' is not a readable C3D file: {CUT}"),
    ]:
        r = admin_client.post(url, data=form,
                              files={"file": (name, data, "application/octet-stream")})
        assert r.status_code == code, r.text
        assert r.json()["detail"] == want


#: What each route says of each bad file: the Subjects page's words wherever a reader
#: refuses the file, the reader's own sentence where it names the file.
NOT_TRC = "Gang.trc is not a TRC file (first line must start with PathFileType)"
NO_TIME = ("'my walk.csv' is not a readable CSV file: no 'time' column; the first column must "
           "be 'time' (seconds), then <Joint>_x,<Joint>_y,<Joint>_z[,<Joint>_state]")


@pytest.mark.parametrize(("name", "data", "want"), [
    ("my walk.csv", b"time_s;x\nhello\n", NO_TIME),
    ("Gang.trc", b"PathFileType\t4\n\x00\x01", NOT_TRC),
])
def test_every_route_says_the_same_of_a_bad_file(admin_client: TestClient, tmp_path: Path,
                                                 name: str, data: bytes, want: str) -> None:
    _filed_recording(admin_client, tmp_path, "R1")
    for url, form, code in [("/api/exports/R1/references", None, 400),
                            ("/api/reports/recordings/R1/reference", None, 400),
                            ("/api/reports/upload", {"subject": "UP1"}, 422)]:
        r = admin_client.post(url, data=form,
                              files={"file": (name, data, "application/octet-stream")})
        assert r.status_code == code, r.text
        assert r.json()["detail"] == want, url


#: A TRC file every reader takes that holds no walk (one marker standing still).
STILL_TRC = ("PathFileType\t4\t(X/Y/Z)\tstill.trc\n"
             "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\n100\t100\t2\t1\tmm\n"
             "Frame#\tTime\tFoo\n\t\tX1\tY1\tZ1\n1\t0\t1\t2\t3\n2\t0.01\t1\t2\t3\n")


def test_a_stored_reference_that_cannot_be_used_is_named_once(admin_client: TestClient,
                                                              tmp_path: Path) -> None:
    """A report's note on a stored reference it cannot use names the file once, as the
    person chose it: "the reference could not be used — reference reference.c3d: cannot
    read reference.c3d as C3D: …" named the server's copy, twice."""
    from app.api.routes import reports as rr
    from app.server import analysis as an
    from engine.io.c3d import write_c3d
    from engine.sim.straight_walk import synth_walk, walk_markers

    for rec_id, code in (("R1", "UP1"), ("R2", "UP2")):
        _filed_recording(admin_client, tmp_path, rec_id, code)
    # R1: attached on the Subjects page, holding no walk (as one attached before that page
    # checked for steps: it now refuses such a file, tests/app/test_reference_walk_check.py)
    from tests.app.mocap_files import walk_trc

    r = admin_client.post("/api/exports/R1/references", files={"file": (
        "still walk.trc", walk_trc(tmp_path / "walk.trc").read_bytes(), "text/plain")})
    assert r.status_code == 201, r.text
    (stored_r1,) = (tmp_path / "references" / "R1").iterdir()
    stored_r1.write_text(STILL_TRC)
    # R2: attached on the Reports page, damaged on the server since
    whole = tmp_path / "whole.c3d"
    write_c3d(whole, walk_markers(synth_walk()), units="mm")
    r = admin_client.post("/api/reports/recordings/R2/reference",
                          files={"file": ("trial 3.c3d", whole.read_bytes(), "x/y")})
    assert r.status_code == 201, r.text
    stored = tmp_path / "recordings" / "R2" / "reference" / "reference.c3d"
    stored.write_bytes(b"not a c3d file at all")

    with admin_client.app.state.db_sessions() as db:  # type: ignore[attr-defined]
        paths = rr._reference_paths(db, tmp_path, {
            r: an.recording_dir(tmp_path, r) for r in ("R1", "R2")})
    assert {k: v.name for k, v in paths.items()} == {"R1": "still walk.trc",
                                                     "R2": "trial 3.c3d"}
    _, notes = rr._reference_steps(paths, "crossing", {"R1": "walk 1", "R2": ""})
    assert notes == [
        "Trial “walk 1” (recording R1): the reference still walk.trc could not be used — "
        "cannot guess the length unit: no frame with two or more markers; give the units "
        "explicitly",
        f"Recording R2: the reference could not be used — 'trial 3.c3d' is not a readable "
        f"C3D file: {NOT_C3D}"]
    for note, name in zip(notes, ("still walk.trc", "trial 3.c3d"), strict=True):
        assert note.count(name) == 1, note
        assert not INTERNAL.search(note) and "reference.c3d" not in note, note
