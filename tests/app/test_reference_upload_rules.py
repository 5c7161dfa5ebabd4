"""A reference recording attached on the Subjects page (``POST /api/exports/{rec}/references``)
and on the Reports page (``POST /api/reports/recordings/{rec}/reference``) is refused alike
before it is read: a wrong extension, an empty file and one over the size limit got
different words on the two pages ("file 'x': choose a .c3d, .trc or skeleton .csv file" /
"'x': upload a .c3d, .trc or .csv file"; "x is empty" / a reader's words; 200 MB / 100 MB).
They give the same status and words now, from one limit
(:data:`app.api.routes._reference.MAX_REFERENCE_BYTES`). A reference whose markers have
names the analysis does not know is refused naming the recognised names in words, not the
documentation file ``docs/gait-json.md`` a clinician in the browser cannot open."""

from __future__ import annotations

from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from tests.app.mocap_files import walk_trc
from tests.app.test_upload_errors import INTERNAL, _filed_recording

URLS = ("/api/exports/R1/references", "/api/reports/recordings/R1/reference")


def _both(c: TestClient, name: str, data: bytes) -> tuple[int, str]:
    """The status and words of both pages for the upload of ``data`` named ``name``: the
    same, or the test fails showing both."""
    said = []
    for url in URLS:
        r = c.post(url, files={"file": (name, data, "application/octet-stream")})
        said.append((r.status_code, r.json()["detail"]))
    assert said[0] == said[1], said
    return said[0]


def _nothing_attached(c: TestClient) -> None:
    assert c.get("/api/exports/R1/references").json() == []
    assert c.get("/api/reports/recordings/R1/reference").json()["attached"] is False


def test_a_wrong_extension_is_refused_alike(admin_client: TestClient, tmp_path: Path) -> None:
    _filed_recording(admin_client, tmp_path, "R1")
    code, detail = _both(admin_client, "walk report.pdf", b"%PDF-1.4")
    assert code == 400
    assert detail == "'walk report.pdf': choose a .c3d, .trc or skeleton .csv file", detail
    _nothing_attached(admin_client)


def test_an_empty_file_is_refused_alike(admin_client: TestClient, tmp_path: Path) -> None:
    _filed_recording(admin_client, tmp_path, "R1")
    code, detail = _both(admin_client, "trial 3.c3d", b"")
    assert code == 400
    assert detail.startswith("'trial 3.c3d' is empty"), detail
    assert detail.count("trial 3.c3d") == 1 and not INTERNAL.search(detail), detail
    _nothing_attached(admin_client)


def test_an_oversized_file_is_refused_alike(admin_client: TestClient, tmp_path: Path,
                                            monkeypatch: pytest.MonkeyPatch) -> None:
    from app.api.routes import _reference

    _filed_recording(admin_client, tmp_path, "R1")
    monkeypatch.setattr(_reference, "MAX_REFERENCE_BYTES", 3 * 2**20)
    code, detail = _both(admin_client, "long session.c3d", b"\0" * (3 * 2**20 + 1))
    assert code == 413
    assert detail.startswith("'long session.c3d' is larger than 3 MB"), detail
    _nothing_attached(admin_client)


def test_one_size_limit_for_both_pages() -> None:
    """Both routes accept the same request body: the shared limit, not a page's own."""
    from app.api.routes import _reference, exports, reports

    limits = {r.path: r.body_limit  # type: ignore[attr-defined]
              for r in [*exports.router.routes, *reports.router.routes]
              if getattr(r, "path", "") in ("/exports/{rec_id}/references",
                                            "/reports/recordings/{rec_id}/reference")
              and "POST" in getattr(r, "methods", ())}
    assert len(limits) == 2, limits
    assert set(limits.values()) == {
        _reference.MAX_REFERENCE_BYTES + _reference.UPLOAD_OVERHEAD}, limits


def test_unknown_marker_names_are_said_in_words(admin_client: TestClient,
                                                tmp_path: Path) -> None:
    """The analysis's "looked for names like LANK/RANK, …: docs/gait-json.md lists them"
    becomes the recognised names in words on both pages; ``gaitrig gait`` keeps its own."""
    from engine.io.markers import MarkerTrajectories
    from engine.io.trc import read_trc, write_trc

    _filed_recording(admin_client, tmp_path, "R1")
    path = walk_trc(tmp_path / "f.trc", n_steps=6)
    m = read_trc(path)
    write_trc(path, MarkerTrajectories(m.times, m.positions,
                                       [f"M{i}" for i in range(len(m.labels))],
                                       m.rate, m.units))
    code, detail = _both(admin_client, "trial 3.trc", path.read_bytes())
    assert code == 422, detail
    assert "docs/" not in detail and ".md" not in detail and "--" not in detail, detail
    assert "LANK/RANK" in detail and "LHEE/RHEE" in detail, detail
    assert "recognised" in detail, detail
    _nothing_attached(admin_client)


def test_analyse_a_file_says_the_marker_names_in_words_and_the_cli_keeps_its_own() -> None:
    """"Analyse a file" on the Reports page (``advice=form``) says the names in words too
    (the error's parts); ``gaitrig gait`` (``advice=cli``, the engine's message) still
    points to the docs."""
    import numpy as np

    from app.api.routes.reports import form_say
    from engine.errors import InputError
    from engine.io.markers import MarkerTrajectories
    from engine.mocap import feet_from_markers

    P = np.zeros((3, 2, 3))
    P[:, 1, 2] = 1.0  # a body a metre tall
    m = MarkerTrajectories(np.arange(3) / 100.0, P, ["M0", "M1"], 100.0, "m")
    with pytest.raises(InputError) as exc:
        feet_from_markers(m, up="z")
    cli = str(exc.value)
    said = exc.value.words(form_say)
    assert said is not None
    assert "docs/" not in said and "--" not in said, said
    assert "(markers named like LANK/RANK, LHEE/RHEE, L.Ankle, L_FAL, L_FCC, AnkleLeft are "\
        "recognised)" in said, said
    assert cli == ("no usable left ankle or heel and no right ankle or heel marker (looked "
                   "for names like LANK/RANK, LHEE/RHEE, L.Ankle, L_FAL, L_FCC, AnkleLeft: "
                   "docs/gait-json.md lists them); available labels: M0, M1; name the foot "
                   "markers with --left/--right")
