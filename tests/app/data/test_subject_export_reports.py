"""The subject export carries the subject's gait reports (PDF rendered at the export),
and a report that cannot be made is a note, not a broken archive."""

from __future__ import annotations

import io
import json
import subprocess
import zipfile
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from app.api.routes import subjects as subjects_route
from tests.app.data.walk_recording import walk_subject


@pytest.fixture
def client(admin_client: TestClient) -> TestClient:
    return admin_client


def _pdf_text(pdf: bytes) -> str:
    out = subprocess.run(["pdftotext", "-layout", "-", "-"], input=pdf, check=True,
                         timeout=60, capture_output=True)
    return out.stdout.decode()


def test_the_export_holds_the_subjects_reports(client: TestClient, tmp_path: Path) -> None:
    ids = walk_subject(client, tmp_path)
    sid, sess = ids["subject_id"], ids["session_id"]
    r = client.get(f"/api/subjects/{sid}/export")
    assert r.status_code == 200, r.text
    z = zipfile.ZipFile(io.BytesIO(r.content))
    assert z.testzip() is None
    pdfs = [n for n in z.namelist() if n.startswith("reports/")]
    assert len(pdfs) == 1 and pdfs[0].startswith(f"reports/gait-report-session-{sess}-")
    pdf = z.read(pdfs[0])
    assert pdf.startswith(b"%PDF")
    text = _pdf_text(pdf)
    assert "A1" in text and "Step length" in text
    # the same report the Reports page hands out for the session
    page = client.get(f"/api/reports/subjects/{sid}",
                      params={"format": "pdf", "session_id": sess})
    assert page.status_code == 200
    assert _pdf_text(page.content).split("Generated")[0] == text.split("Generated")[0]
    assert json.loads(z.read("export-notes.json")) == []
    assert b"reports/" in z.read("README.txt")
    # a second session (nothing recorded in it): its report is a note; the
    # all-sessions report is there too
    client.post("/api/sessions", json={"subject_id": sid, "label": "follow-up"})
    z = zipfile.ZipFile(io.BytesIO(client.get(f"/api/subjects/{sid}/export").content))
    names = [n for n in z.namelist() if n.startswith("reports/")]
    assert names[0].startswith(f"reports/gait-report-session-{sess}-")
    assert "reports/gait-report-all-sessions.pdf" in names and len(names) == 2, names
    notes = json.loads(z.read("export-notes.json"))
    assert len(notes) == 1 and "no complete recording" in notes[0], notes
    assert "all sessions (2)" in _pdf_text(z.read("reports/gait-report-all-sessions.pdf"))


def test_a_report_that_fails_is_a_note_and_the_archive_stays_whole(
        client: TestClient, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    ids = walk_subject(client, tmp_path)

    def broken(data: object) -> bytes:
        raise RuntimeError("font cache is corrupt")

    monkeypatch.setattr(subjects_route, "render_pdf", broken)
    r = client.get(f"/api/subjects/{ids['subject_id']}/export")
    assert r.status_code == 200
    z = zipfile.ZipFile(io.BytesIO(r.content))
    assert z.testzip() is None and not [n for n in z.namelist() if n.startswith("reports/")]
    assert "recordings/R1/S1/frames.bin" in z.namelist()
    notes = json.loads(z.read("export-notes.json"))
    assert len(notes) == 1 and notes[0].startswith("reports/gait-report-session-"), notes
    assert "could not be rendered" in notes[0]
