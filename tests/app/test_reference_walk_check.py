"""The Subjects page's "Attach reference" runs the report's gait analysis on the file at
once: a readable reference with no usable walk in it (the subject standing, fewer than two
steps, no ankle or heel markers recognised) was stored and only said so later, as a note
in the report. It is refused (422) naming the file and saying what to do, and nothing is
stored: a reference attached before stays, file and row."""

from __future__ import annotations

from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from tests.app.mocap_files import standing_trc, walk_trc
from tests.app.test_upload_errors import INTERNAL, _filed_recording


def _files(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def test_a_standing_reference_is_refused_and_the_attached_one_stays(
        admin_client: TestClient, tmp_path: Path) -> None:
    c = admin_client
    _filed_recording(c, tmp_path, "R1")
    good = walk_trc(tmp_path / "good.trc").read_bytes()
    r = c.post("/api/exports/R1/references",
               files={"file": ("vicon walk.trc", good, "text/plain")})
    assert r.status_code == 201, r.text
    refs = c.get("/api/exports/R1/references").json()
    folder = tmp_path / "references" / "R1"
    stored = _files(folder)

    still = standing_trc(tmp_path / "still.trc").read_bytes()
    r = c.post("/api/exports/R1/references",
               files={"file": ("standing still.trc", still, "text/plain")})
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert detail.startswith("'standing still.trc' has no walk in it: 0 steps found"), detail
    assert "attach the reference recording of this walk" in detail.lower(), detail
    assert "'vicon walk.trc' stays attached" in detail, detail
    assert detail.count("standing still.trc") == 1 and not INTERNAL.search(detail), detail
    # nothing stored: no row, no file (nor a temporary one); the good one as it was
    assert c.get("/api/exports/R1/references").json() == refs
    assert _files(folder) == stored
    d = c.get(f"/api/exports/R1/references/{refs[0]['id']}")
    assert d.status_code == 200 and d.content == good


@pytest.mark.parametrize(("kind", "want"), [
    ("short", "has no walk in it: only 0 steps found in 1 pass; at least two steps are needed"),
    ("unnamed", "has no walk the report can use: no usable left ankle or heel"),
])
def test_a_reference_without_steps_is_refused_at_once(admin_client: TestClient,
                                                      tmp_path: Path, kind: str,
                                                      want: str) -> None:
    """Too short a walk, or markers of unknown names: refused with the analysis's reason,
    without advice the Subjects page cannot follow (gaitrig gait's --left/--right), and
    nothing stored when no reference was attached before."""
    from engine.io.markers import MarkerTrajectories
    from engine.io.trc import read_trc, write_trc

    _filed_recording(admin_client, tmp_path, "R1")
    path = walk_trc(tmp_path / "f.trc", n_steps=2 if kind == "short" else 6)
    if kind == "unnamed":
        m = read_trc(path)
        write_trc(path, MarkerTrajectories(m.times, m.positions,
                                           [f"M{i}" for i in range(len(m.labels))],
                                           m.rate, m.units))
    r = admin_client.post("/api/exports/R1/references",
                          files={"file": ("trial 3.trc", path.read_bytes(), "text/plain")})
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert detail.startswith(f"'trial 3.trc' {want}"), detail
    assert "attach the reference recording of this walk" in detail.lower(), detail
    assert "--" not in detail and "stays attached" not in detail, detail
    assert admin_client.get("/api/exports/R1/references").json() == []
    assert not any((tmp_path / "references" / "R1").iterdir())


def _no_walk_file(tmp_path: Path, kind: str) -> Path:
    """A readable TRC with no usable walk: the subject standing, too short a walk, or
    markers of names the analysis does not know."""
    from engine.io.markers import MarkerTrajectories
    from engine.io.trc import read_trc, write_trc

    if kind == "standing":
        return standing_trc(tmp_path / f"{kind}.trc")
    path = walk_trc(tmp_path / f"{kind}.trc", n_steps=2 if kind == "short" else 6)
    if kind == "unnamed":
        m = read_trc(path)
        write_trc(path, MarkerTrajectories(m.times, m.positions,
                                           [f"M{i}" for i in range(len(m.labels))],
                                           m.rate, m.units))
    return path


@pytest.mark.parametrize("kind", ["standing", "short", "unnamed"])
def test_both_pages_refuse_a_reference_with_no_walk_alike(admin_client: TestClient,
                                                         tmp_path: Path, kind: str) -> None:
    """A reference can be attached on the Subjects page and on the Reports page. The same
    readable file with no usable walk was refused with 422 and the Subjects page's words on
    one, 400 and the analysis's words (its advice on placing sensors) on the other. Both
    answer 422 with the same words: the file named once, what is wrong, what to do, no
    command-line flag; nothing is stored on either."""
    c = admin_client
    _filed_recording(c, tmp_path, "R1")
    data = _no_walk_file(tmp_path, kind).read_bytes()
    said = {}
    for url in ("/api/exports/R1/references", "/api/reports/recordings/R1/reference"):
        r = c.post(url, files={"file": ("trial 3.trc", data, "text/plain")})
        said[url] = (r.status_code, r.json()["detail"])
    (code, detail), other = said.values()
    assert other == (code, detail), said
    assert code == 422, said
    assert detail.startswith("'trial 3.trc' has no walk"), detail
    assert detail.count("trial 3.trc") == 1 and not INTERNAL.search(detail), detail
    assert "attach the reference recording of this walk" in detail.lower(), detail
    assert "--" not in detail and "sensors" not in detail, detail
    assert c.get("/api/exports/R1/references").json() == []
    assert c.get("/api/reports/recordings/R1/reference").json()["attached"] is False


def test_the_reports_page_names_the_reference_that_stays(admin_client: TestClient,
                                                         tmp_path: Path) -> None:
    """Refused on the Reports page, a reference with no walk leaves the one attached there
    before in place, and names it, as the Subjects page does."""
    c = admin_client
    _filed_recording(c, tmp_path, "R1")
    good = walk_trc(tmp_path / "good.trc").read_bytes()
    url = "/api/reports/recordings/R1/reference"
    r = c.post(url, files={"file": ("vicon walk.trc", good, "text/plain")})
    assert r.status_code == 201, r.text
    before = c.get(url).json()
    still = standing_trc(tmp_path / "still.trc").read_bytes()
    r = c.post(url, files={"file": ("standing still.trc", still, "text/plain")})
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert detail.startswith("'standing still.trc' has no walk in it: 0 steps found"), detail
    assert detail.endswith(" 'vicon walk.trc' stays attached."), detail
    assert c.get(url).json() == before
    stored = tmp_path / "recordings" / "R1" / "reference" / "reference.trc"
    assert stored.read_bytes() == good
