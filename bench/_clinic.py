"""A clinic's database after years of use, built fast through the app's own database layer.

:func:`populate` fills a data folder the way the server would have: the data tables
(projects, subjects, sessions, recordings with their node parts), the audit trail, the
backbone's ``recordings.json`` (every recording the server ever made, as
:class:`app.server.recording.RecordingManager` keeps them) and, for the newest
recordings only, part folders on the server (``frames.bin`` + ``meta.json``, a few bytes
each: the list pages read which parts exist, not the skeletons). Rows are written with
SQLAlchemy bulk inserts of the ORM models (:mod:`app.db.data`, :mod:`app.db.models`)
into a database opened by :func:`app.db.base.make_engine`, so every alembic revision
and index applies. Used by ``bench/list_scale.py`` and the scale tests.
"""

from __future__ import annotations

import datetime as dt
import json
import random
from dataclasses import dataclass
from pathlib import Path

from sqlalchemy import insert

from app.db import data as m
from app.db.base import make_engine
from app.db.models import AuditEvent

T0 = dt.datetime(2023, 11, 1, 8, 0, tzinfo=dt.UTC)  # the clinic opened three years ago


@dataclass
class Clinic:
    """What :func:`populate` made (ids in insertion order, codes by subject id)."""

    project_ids: list[int]
    subject_codes: dict[int, str]
    n_sessions: int
    recording_ids: list[str]
    n_parts: int
    n_audit: int


def subject_code(k: int) -> str:
    """The pseudonym of the ``k``-th subject (``P00017``)."""
    return f"P{k:05d}"


def populate(data_dir: Path, n_subjects: int, recordings_per_subject: int = 6,
             n_audit: int = 0, n_projects: int = 4, n_with_files: int = 0,
             live_json: bool = True, seed: int = 0) -> Clinic:
    """Fill ``data_dir`` (its SQLite database, ``recordings.json``, part folders).

    Args:
        data_dir: the server's data folder (created if missing; its database must hold
            no data rows yet).
        n_subjects: subjects, spread over ``n_projects`` projects (codes ``P00001``…).
        recordings_per_subject: recordings per subject (in 1–3 sessions each); 2–4 node
            parts per recording.
        n_audit: audit entries (logins, exports, deletions) spread over the three years.
        n_projects: projects.
        n_with_files: the newest this many recordings get part folders on the server.
        live_json: write ``recordings.json`` with every recording (the backbone's list).
        seed: random seed (the same arguments give the same clinic).
    """
    rnd = random.Random(seed)
    data_dir.mkdir(parents=True, exist_ok=True)
    engine = make_engine(data_dir / "gaitrig.sqlite3")
    projects, subjects, sessions, recordings, parts = [], [], [], [], []
    for p in range(1, n_projects + 1):
        projects.append({"id": p, "name": f"Clinic study {p}", "description": "",
                         "created_at": T0})
    codes: dict[int, str] = {}
    live: list[dict[str, object]] = []
    sid = 0
    n_span_s = 3 * 365 * 86400
    for k in range(1, n_subjects + 1):
        first = T0 + dt.timedelta(seconds=n_span_s * (k - 1) / max(1, n_subjects))
        codes[k] = subject_code(k)
        subjects.append({"id": k, "project_id": 1 + (k - 1) % n_projects, "code": codes[k],
                         "height_m": round(rnd.uniform(1.5, 1.95), 3),
                         "leg_length_m": round(rnd.uniform(0.75, 1.0), 3),
                         "sex": rnd.choice(m.SEXES), "birth_year": rnd.randint(1935, 2010),
                         "notes": "", "created_at": first})
        n_sess = rnd.randint(1, 3)
        for j in range(n_sess):
            sid += 1
            when = first + dt.timedelta(days=42 * j)
            sessions.append({"id": sid, "subject_id": k, "date": when.date(),
                             "label": ("baseline", "6 weeks", "12 weeks")[j], "notes": "",
                             "created_at": when})
            for i in range(recordings_per_subject // n_sess
                           + (j < recordings_per_subject % n_sess)):
                t = when + dt.timedelta(minutes=4 * i)
                rec_id = f"R{t:%Y%m%d-%H%M%S}-{rnd.getrandbits(16):04x}"
                state = rnd.choices(("complete", "incomplete", "on_nodes"), (95, 4, 1))[0]
                ts = t.timestamp()
                recordings.append({"id": rec_id, "session_id": sid, "label": f"walk {i + 1}",
                                   "notes": "", "state": state,
                                   "reason": "S2: node disconnected" if state == "incomplete"
                                   else None, "t_start": ts, "t_stop": ts + 25.0,
                                   "streams": "", "created_at": t})
                nodes = [f"S{n}" for n in range(1, rnd.randint(2, 4) + 1)]
                lparts = {}
                for node in nodes:
                    pstate = state if state != "on_nodes" else "on_node"
                    if state == "incomplete" and node != "S2":
                        pstate = "complete"
                    parts.append({"recording_id": rec_id, "node_id": node, "state": pstate,
                                  "reason": None, "n_frames": 750, "bytes_total": 400_000,
                                  "bytes_done": 400_000 if pstate == "complete" else 0,
                                  "manifest_sha256": None, "attempts": 1,
                                  "images_skipped": 0 if pstate == "complete" else None,
                                  "updated_at": t})
                    lparts[node] = {"node_id": node, "state": pstate, "reason": None,
                                    "n_frames": 750, "bytes": 400_000,
                                    "t_first_local": ts, "t_last_local": ts + 25.0,
                                    "t_first": ts, "t_last": ts + 25.0, "clock": {},
                                    "on_server": pstate == "complete",
                                    "transfer_progress": None}
                live.append({"id": rec_id, "t_start": ts, "t_stop": ts + 25.0, "created": ts,
                             "streams": [], "image_every": 1, "parts": lparts})
    audit = []
    actions = ("login", "login", "login", "export", "export", "logout", "login_failed",
               "delete")
    for k in range(n_audit):
        a = actions[k % len(actions)]
        audit.append({"at": T0 + dt.timedelta(seconds=n_span_s * k / max(1, n_audit)),
                      "username": rnd.choice(("admin", "nurse1", "physio2")), "action": a,
                      "target": f"subject {rnd.randint(1, max(1, n_subjects))}"
                      if a in ("export", "delete") else "",
                      "detail": "", "client": "10.0.0.12"})
    with engine.begin() as conn:
        for model, rows in ((m.Project, projects), (m.Subject, subjects),
                            (m.Session, sessions), (m.Recording, recordings),
                            (m.RecordingPart, parts), (AuditEvent, audit)):
            for i in range(0, len(rows), 5000):
                conn.execute(insert(model), rows[i:i + 5000])
    engine.dispose()
    if live_json:
        (data_dir / "recordings.json").write_text(json.dumps(live))
    for r in live[len(live) - n_with_files:] if n_with_files else []:
        for node, p in r["parts"].items():  # type: ignore[attr-defined]
            if p["state"] != "complete":
                continue
            d = data_dir / "recordings" / str(r["id"]) / node
            d.mkdir(parents=True, exist_ok=True)
            (d / "frames.bin").write_bytes(b"\0" * 64)
            (d / "meta.json").write_text(json.dumps({"node_id": node, "images_skipped": 0}))
    return Clinic([p["id"] for p in projects], codes, len(sessions),
                  [str(r["id"]) for r in recordings], len(parts), len(audit))
