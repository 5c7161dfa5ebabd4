"""The server's storage at clinic size (5 000 subjects, 30 000 recordings), new paths
against the old ones measured in the same run where the old one can be kept as a peer.

The clinic is built by ``bench/_clinic.py`` (the newest 2 000 recordings with part
folders on the server); a peer of 50 subjects serves the clinic / peer ratios of the
server figures. Figures:

* ``save_ms`` / ``save_ms_old``: one state change written to ``recordings.json`` (one
  appended line, :mod:`app.server.recording_file`) against rewriting every recording
  (the old save, re-implemented here as the peer); ``save_ratio`` = new / old.
* ``load_s`` / ``load_s_old``: loading the clinic's ``recordings.json`` (new loader:
  no collector passes, no keyword construction) against the old loader (``json.loads``
  then ``Part(**v)``/``Recording(**r)`` with the collector on).
* ``server_start_s`` / ``server_start_s_peer``: ``gaitrig serve`` until the login
  answers, and ``imports_s``: the same interpreter only importing the app and its
  routers (what every server pays whatever its data).
* ``healthz_during_sweep_ms``: ``/healthz`` answer times (max, p95, n) while the data
  sync's start-up sweep runs (every recording not complete, a few per pass), asked
  right after the login answered.
* ``storage_ms`` / ``storage_ms_old``: ``GET /api/storage`` (bytes per subject) of the
  running server against the old computation (every subject, session and recording
  loaded by the ORM and every recording folder walked, in this process);
  ``storage_ms_peer`` the peer server's.
* ``unfiled_ms`` / ``unfiled_ms_peer`` / ``unfiled_ratio``: ``GET /api/storage/unfiled``
  of the clinic against the peer; ``unfiled_fn_ms`` / ``unfiled_fn_ms_old``: the new and
  the old computation in this process.
* ``subjects_ms`` / ``recordings_ms`` / ``sessions_ms`` (each with ``_peer`` and
  ``_ratio``): a page of 50 subjects with their counts and bytes, the newest recordings'
  page, one subject's sessions, on the clinic and on the peer; every list figure again
  with ``_settled`` once the clinic's start-up work is over (``SETTLE_S`` after its start).
* ``check_pass_ms``: one pass's share of the periodic check of settled recordings (five
  recordings' parts: manifest read, a ``stat`` per file).
* ``cleanup_s``: the start-up clean-up of leftovers over the clinic's folders.

``loadavg``: the machine's load (every figure grows with it). Prints ONE JSON line.
Run: ``PYTHONPATH=. .venv/bin/python bench/storage_scale.py`` (a few minutes;
``--subjects`` to change the clinic's size).
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from bench._clinic import populate
from bench._procs import stop
from bench.list_scale import Server

ROOT = Path(__file__).resolve().parents[1]


def _ms(t: float) -> float:
    return round(1000 * t, 2)


def bench_recordings_file(data_dir: Path, repeat: int) -> dict[str, Any]:
    """Save one change and load the list: new against the old whole rewrite / loader."""
    from app.server.recording import Part, Recording, RecordingManager, _plain
    from app.server.registry import NodeRegistry

    old_json = (data_dir / "recordings.json").read_bytes()  # the older whole-list format

    def old_load() -> int:
        raw = json.loads(old_json)
        recs = {}
        for r in raw:
            parts = {k: Part(**v) for k, v in r.pop("parts").items()}
            recs[r["id"]] = Recording(**r, parts=parts)
        return len(recs)

    old_s = []
    for _ in range(repeat):
        t = time.perf_counter()
        old_load()
        old_s.append(time.perf_counter() - t)
        gc.collect()
    RecordingManager(NodeRegistry(), data_dir)  # rewrites the older format once
    new_s = []
    for _ in range(repeat):
        t = time.perf_counter()
        rm = RecordingManager(NodeRegistry(), data_dir)
        new_s.append(time.perf_counter() - t)
    gc.unfreeze()  # (the loader froze them; this bench makes many)
    rec = next(iter(rm.recordings.values()))
    old_path = data_dir / "old-recordings.json"

    def old_save() -> None:
        tmp = old_path.with_suffix(".tmp")
        tmp.write_text(json.dumps([_plain(r) for r in rm.recordings.values()]))
        os.replace(tmp, old_path)

    save_new, save_old = [], []
    for i in range(repeat):
        rec.parts[next(iter(rec.parts))].n_frames = 1000 + i  # a change to write
        rm.touch(rec.id)
        t = time.perf_counter()
        rm.save()
        save_new.append(time.perf_counter() - t)
        t = time.perf_counter()
        old_save()
        save_old.append(time.perf_counter() - t)
    old_path.unlink(missing_ok=True)
    assert rm.save_error is None
    save, save_o = statistics.median(save_new), statistics.median(save_old)
    load, load_o = statistics.median(new_s), statistics.median(old_s)
    return {"recordings": len(rm.recordings), "save_ms": _ms(save), "save_ms_old": _ms(save_o),
            "save_ratio": round(save / save_o, 4), "load_s": round(load, 3),
            "load_s_old": round(load_o, 3), "load_ratio": round(load / load_o, 3)}


def old_storage_ms(data_dir: Path) -> float:
    """The old ``GET /api/storage`` computation: the ORM tree and a walk per recording."""
    from sqlalchemy import select
    from sqlalchemy.orm import selectinload

    from app.db import data as m
    from app.db.base import make_engine, make_session_factory
    from app.server.storage import StorageLayout

    layout = StorageLayout(data_dir)
    engine = make_engine(f"sqlite:///{data_dir / 'gaitrig.sqlite3'}")
    try:
        with make_session_factory(engine)() as db:
            t = time.perf_counter()
            q = (select(m.Subject).order_by(m.Subject.project_id, m.Subject.code)
                 .options(selectinload(m.Subject.sessions).selectinload(m.Session.recordings)))
            out = [sum(layout.measure_bytes(r.id) for x in s.sessions for r in x.recordings)
                   for s in db.scalars(q)]
            assert out
            return _ms(time.perf_counter() - t)
    finally:
        engine.dispose()


def unfiled_fn_ms(data_dir: Path) -> tuple[float, float]:
    """The new and the old unfiled computation (ms), same data, same process."""
    from types import SimpleNamespace

    from sqlalchemy import select

    from app.api.routes.storage import _unfiled_ids
    from app.db import data as m
    from app.db.base import make_engine, make_session_factory
    from app.server.recording import RecordingManager
    from app.server.registry import NodeRegistry

    live = RecordingManager(NodeRegistry(), data_dir).recordings
    gc.unfreeze()
    request: Any = SimpleNamespace(app=SimpleNamespace(state=SimpleNamespace()))
    engine = make_engine(f"sqlite:///{data_dir / 'gaitrig.sqlite3'}")
    new, old = [], []
    try:
        for _ in range(6):
            with make_session_factory(engine)() as db:
                t = time.perf_counter()
                ids = _unfiled_ids(request, db, live.keys())  # the filed ids kept after the first
                a = sorted((live[i] for i in ids), key=lambda r: r.created, reverse=True)
                new.append(time.perf_counter() - t)
                t = time.perf_counter()
                filed = set(db.scalars(select(m.Recording.id)))
                b = [r for r in sorted(live.values(), key=lambda r: r.created, reverse=True)
                     if r.id not in filed]
                old.append(time.perf_counter() - t)
                assert [r.id for r in a] == [r.id for r in b]
    finally:
        engine.dispose()
    return _ms(statistics.median(new[1:])), _ms(statistics.median(old))


def check_pass_ms(data_dir: Path) -> float:
    """One pass's share of the periodic check (five recordings with parts on disk)."""
    from app.server.datasync import server_copy_fault

    parts = sorted((data_dir / "recordings").glob("*/*"))[:15]
    for p in parts:  # as a transfer leaves them
        files = [{"name": f.name, "size": f.stat().st_size} for f in sorted(p.iterdir())
                 if f.name != "manifest.json"]
        (p / "manifest.json").write_text(json.dumps({"files": files}))
    t = time.perf_counter()
    faults = [server_copy_fault(p) for p in parts]
    assert faults == [None] * len(parts)
    return _ms(time.perf_counter() - t)


def healthz_during_sweep(srv: Server, seconds: float) -> dict[str, float]:
    times = []
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        times.append(srv.call("GET", "/healthz")[0])
        time.sleep(0.02)
    times.sort()
    return {"max": _ms(times[-1]), "p95": _ms(times[int(0.95 * (len(times) - 1))]),
            "n": len(times)}


def imports_s() -> float:
    import subprocess

    code = ("import time; t=time.perf_counter(); import app.main as a; a.api_routers(); "
            "print(time.perf_counter()-t)")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, check=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
    return round(float(out.stdout.strip().splitlines()[-1]), 2)


#: Seconds after the clinic's start when its list figures are measured again
#: (``*_settled``): its start-up sweep of the recordings not complete and the usage
#: rescan run in the background for tens of seconds on a loaded machine, and slow every
#: answer meanwhile.
SETTLE_S = 90.0

#: What a clinician's pages ask on every visit, measured on the clinic and on the peer
#: (the same page size on both: the peer has 50 subjects, so 50 a page).
LIST_ENDPOINTS = (("storage", "/api/storage"), ("unfiled", "/api/storage/unfiled"),
                  ("subjects", "/api/subjects?limit=50"), ("recordings", "/api/recordings"),
                  ("sessions", "/api/sessions?subject_id=1"))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--subjects", type=int, default=5000, help="the clinic's subjects")
    ap.add_argument("--peer", type=int, default=50, help="the peer's subjects")
    ap.add_argument("--repeat", type=int, default=5, help="repetitions per figure")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="gaitrig-storage-scale-"))
    out: dict[str, Any] = {"bench": "storage_scale", "subjects": args.subjects,
                           "peer_subjects": args.peer}
    try:
        n_files = min(2000, 6 * args.subjects)
        populate(tmp / "big", args.subjects, 6, n_with_files=n_files)
        populate(tmp / "peer", args.peer, 6,
                 n_with_files=min(2000, round(n_files * args.peer / args.subjects)))
        shutil.copytree(tmp / "big", tmp / "files")  # for the in-process figures
        out.update(bench_recordings_file(tmp / "files", args.repeat))
        out["storage_ms_old"] = old_storage_ms(tmp / "files")
        out["unfiled_fn_ms"], out["unfiled_fn_ms_old"] = unfiled_fn_ms(tmp / "files")
        out["imports_s"] = imports_s()
        t_big = time.perf_counter()
        servers = [Server(tmp / "big", tmp / "big.log")]
        try:
            out["server_start_s"] = round(servers[0].wait(), 2)
            out["healthz_during_sweep_ms"] = healthz_during_sweep(servers[0], 6.0)
            servers.append(Server(tmp / "peer", tmp / "peer.log"))  # one start at a time
            out["server_start_s_peer"] = round(servers[1].wait(), 2)
            for suffix in ("", "_settled"):
                if suffix:  # the clinic's start-up work (data sync sweep, usage rescan) done
                    time.sleep(max(0.0, SETTLE_S - (time.perf_counter() - t_big)))
                for name, path in LIST_ENDPOINTS:
                    big, peer = [], []
                    for _ in range(args.repeat):
                        peer.append(servers[1].call("GET", path)[0])
                        big.append(servers[0].call("GET", path)[0])
                    out[f"{name}_ms{suffix}"] = _ms(statistics.median(big))
                    out[f"{name}_ms_peer{suffix}"] = _ms(statistics.median(peer))
                    out[f"{name}_ratio{suffix}"] = round(
                        statistics.median(big) / statistics.median(peer), 2)
            out["loadavg"] = round(os.getloadavg()[0], 1)
        finally:
            stop([s.proc for s in servers])
        out["storage_ratio_old"] = round(out["storage_ms"] / out["storage_ms_old"], 4)
        out["check_pass_ms"] = check_pass_ms(tmp / "files")
        from app.server.cleanup import clean_stale

        t = time.perf_counter()
        clean_stale(tmp / "files", set())
        out["cleanup_s"] = round(time.perf_counter() - t, 3)
        print(json.dumps(out))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
