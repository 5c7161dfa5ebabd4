"""The audit trail's CSV download: the whole trail (or a date range), streamed."""

from __future__ import annotations

import csv
import datetime as dt
import io

import pytest
from fastapi.testclient import TestClient

from app.api.routes import audit as audit_route
from app.db.audit import event


def _plant(client: TestClient, n: int, at: dt.datetime | None = None) -> None:
    with client.app.state.db_sessions() as db:  # type: ignore[attr-defined]
        for i in range(n):
            e = event("admin", "export", f"recording R{i}", "-planted")
            if at is not None:
                e.at = at
            db.add(e)
        db.commit()


def _rows(text: str) -> list[dict[str, str]]:
    return list(csv.DictReader(io.StringIO(text)))


def test_csv_is_the_whole_trail_in_batches(admin_client: TestClient,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    # a small batch so the 450 entries take several queries (the keyset paging is used)
    monkeypatch.setattr(audit_route, "CSV_BATCH", 7)
    _plant(admin_client, 450)
    total = admin_client.get("/api/audit", params={"limit": 1}).headers["x-total-count"]
    r = admin_client.get("/api/audit", params={"format": "csv"})
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/csv")
    rows = _rows(r.text)
    assert len(rows) == int(total) >= 450  # the login too; not limited to 200
    ids = [int(x["id"]) for x in rows]
    assert ids == sorted(ids, reverse=True) and len(set(ids)) == len(ids)
    assert rows[0]["detail"] == "'-planted"  # still no formula in a cell
    # the download is recorded (after the trail it gave) with the count it gave
    last = admin_client.get("/api/audit").json()[0]
    assert last["target"] == "audit trail" and f"{len(rows)} entries" in last["detail"]
    assert last["id"] > ids[0]
    # the JSON list stays paged
    assert len(admin_client.get("/api/audit").json()) == 200


def test_csv_date_range(admin_client: TestClient) -> None:
    _plant(admin_client, 3, dt.datetime(2025, 3, 1, 23, 59, tzinfo=dt.UTC))
    _plant(admin_client, 5, dt.datetime(2025, 3, 2, 0, 0, tzinfo=dt.UTC))
    _plant(admin_client, 2, dt.datetime(2025, 3, 4, 12, 0, tzinfo=dt.UTC))
    got = _rows(admin_client.get("/api/audit", params={
        "format": "csv", "since": "2025-03-02", "until": "2025-03-04"}).text)
    assert len(got) == 7 and all(x["at"][:10] in ("2025-03-02", "2025-03-04") for x in got)
    got = _rows(admin_client.get("/api/audit", params={
        "format": "csv", "until": "2025-03-01"}).text)
    assert len(got) == 3
    got = _rows(admin_client.get("/api/audit", params={
        "format": "csv", "since": "2025-03-03"}).text)
    assert [x["at"][:10] for x in got].count("2025-03-04") == 2
    assert not any(x["at"].startswith("2025-03-0") and x["at"][:10] < "2025-03-03"
                   for x in got)
    # the JSON list filters the same way
    r = admin_client.get("/api/audit", params={"since": "2025-03-01", "until": "2025-03-01"})
    assert len(r.json()) == 3 and r.headers["x-total-count"] == "3"


def test_bad_dates_are_422_with_a_message(admin_client: TestClient) -> None:
    r = admin_client.get("/api/audit", params={"format": "csv", "since": "03/02/2025"})
    assert r.status_code == 422 and "since" in r.text and "date" in r.text
    r = admin_client.get("/api/audit", params={"format": "csv", "since": "2025-03-05",
                                               "until": "2025-03-01"})
    assert r.status_code == 422 and "before since" in r.json()["detail"]
