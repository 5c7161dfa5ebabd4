"""The console's lists after three years of a clinic, against a new clinic as the peer.

Two servers (``gaitrig serve``, no nodes) run side by side on data folders filled through
the database layer (``bench/_clinic.py``): the clinic (5 000 subjects, 30 000 recordings
with 2–4 node parts each, 100 000 audit entries, the newest 2 000 recordings' part
folders on the server, every recording in ``recordings.json``) and the peer (50 subjects,
same proportions). Each list endpoint is asked alternately of both (median of
``--repeat``): time per request, answer size, and the ratio clinic / peer. Then a headless
Chromium (``/usr/bin/chromium``) opens the Subjects, Record and Reports pages of each:
time until the page is usable (its subject list drawn) and until a subject typed into the
search field is listed. ``healthz_ms`` is the server's answer time to a trivial request
while idle: its event loop also runs the data sync twice a second, whose one pass over
each data folder ``sync_step_ms`` times (in a process of its own, after the servers; the
median of the passes after the start-up sweep, whose longest pass is
``sync_first_pass_ms``: the sweep looks at every recording not complete once, a few per
pass).

Prints ONE JSON line; ``worst_ratio`` is the largest clinic / peer ratio of the lists as
the console asks for them (not ``audit_10000``, a download-sized page the peer cannot fill:
it holds 1 000 entries). ``loadavg`` is the machine's load when the requests ran: on a
loaded machine every figure of the clinic grows with ``sync_step_ms`` (the data sync holds
the server's event loop and the interpreter that long twice a second).
Run: ``PYTHONPATH=. .venv/bin/python bench/list_scale.py`` (as ``make bench`` does; a
minute or two; ``--subjects`` to change the clinic's size).
"""

from __future__ import annotations

import argparse
import json
import os
import secrets
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
from contextlib import ExitStack
from pathlib import Path
from typing import Any

from bench._clinic import populate, subject_code
from bench._procs import free_port, stop

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = Path("/usr/bin/chromium")

#: name → (method, path, JSON body or None)
ENDPOINTS: dict[str, tuple[str, str, dict[str, Any] | None]] = {
    "projects": ("GET", "/api/projects", None),
    "subjects": ("GET", "/api/subjects", None),
    "subjects_project": ("GET", "/api/subjects?project_id=1&limit=50", None),
    "subjects_last_page": ("GET", "/api/subjects?project_id=1&limit=50&offset=1200", None),
    "subjects_search": ("POST", "/api/subjects/search", {"q": "P0004", "limit": 50}),
    "subject_detail": ("GET", "/api/subjects/3", None),
    "sessions": ("GET", "/api/sessions?subject_id=3", None),
    "recordings": ("GET", "/api/recordings", None),
    "recordings_running": ("GET", "/api/recordings?state=recording&limit=1", None),
    "report_recordings": ("GET", "/api/reports/recordings", None),
    "report_recordings_search": ("GET", "/api/reports/recordings?q=baseline&limit=50", None),
    "audit": ("GET", "/api/audit", None),
    "audit_10000": ("GET", "/api/audit?limit=10000", None),
    "storage_disk": ("GET", "/api/storage?subjects=false", None),
    "unfiled": ("GET", "/api/storage/unfiled", None),
    "nodes": ("GET", "/api/nodes", None),
    "healthz": ("GET", "/healthz", None),
}


class Server:
    """``gaitrig serve`` on a populated data folder, logged in as the admin."""

    def __init__(self, data_dir: Path, log: Path) -> None:
        self.port, self.password = free_port(), secrets.token_urlsafe(9)
        self.base = f"http://127.0.0.1:{self.port}"
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "app.cli", "serve", "--host", "127.0.0.1", "--port",
             str(self.port), "--no-viewer", "--data-dir", str(data_dir), "--log-level",
             "warning"], cwd=ROOT, stdout=log.open("wb"), stderr=subprocess.STDOUT,
            env={**os.environ, "GAITRIG_ADMIN_PASSWORD": self.password,
                 "PYTHONUNBUFFERED": "1",
                 # the clinic's older recordings have rows but no files (bench/_clinic.py):
                 # the periodic check would mark them missing as it went; its cost per
                 # pass is measured on its own (bench/storage_scale.py: check_pass_ms)
                 "GAITRIG_STORAGE_CHECK_INTERVAL_S": "0"})
        self.token = ""

    def wait(self, timeout_s: float = 120.0) -> float:
        """Wait until logged in; returns the seconds the server took to answer."""
        t0, deadline = time.perf_counter(), time.time() + timeout_s
        while True:
            try:
                _, body, _ = self.call("POST", "/api/auth/login",
                                       {"username": "admin", "password": self.password})
                self.token = json.loads(body)["token"]
                return time.perf_counter() - t0
            except OSError:
                if time.time() > deadline or self.proc.poll() is not None:
                    raise SystemExit(f"server on {self.base} did not start") from None
                time.sleep(0.2)

    def call(self, method: str, path: str, body: dict[str, Any] | None = None
             ) -> tuple[float, bytes, str | None]:
        """(seconds, answer, X-Total-Count) of one request."""
        headers = {"Content-Type": "application/json"}
        if self.token:
            headers["Authorization"] = f"Bearer {self.token}"
        req = urllib.request.Request(self.base + path, method=method, headers=headers,
                                     data=json.dumps(body).encode() if body else None)
        t = time.perf_counter()
        with urllib.request.urlopen(req, timeout=120) as r:
            raw = r.read()
            return time.perf_counter() - t, raw, r.headers.get("X-Total-Count")


def measure_endpoints(big: Server, peer: Server, repeat: int) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name, (method, path, body) in ENDPOINTS.items():
        times: dict[str, list[float]] = {"big": [], "peer": []}
        size = {"big": 0, "peer": 0}
        total: str | None = None
        for _ in range(repeat):  # alternately: both see the same load of the machine
            for key, srv in (("peer", peer), ("big", big)):
                dt, raw, tot = srv.call(method, path, body)
                times[key].append(dt)
                size[key] = len(raw)
                if key == "big":
                    total = tot
        ms_big = 1000 * statistics.median(times["big"])
        ms_peer = 1000 * statistics.median(times["peer"])
        out[name] = {"ms": round(ms_big, 1), "ms_peer": round(ms_peer, 1),
                     "ratio": round(ms_big / ms_peer, 2) if ms_peer > 0 else None,
                     "kB": round(size["big"] / 1024, 1), "kB_peer": round(size["peer"] / 1024, 1),
                     "total": int(total) if total else None}
    return out


def measure_pages(srv: Server, find_code: str) -> dict[str, float]:
    """Seconds until each page is usable and until a typed subject is listed."""
    from playwright.sync_api import sync_playwright

    res: dict[str, float] = {}
    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=str(CHROMIUM), headless=True,
                               args=["--no-sandbox", "--disable-gpu"])
        ctx = b.new_context(viewport={"width": 1400, "height": 900})
        page = ctx.new_page()
        page.set_default_timeout(60000)
        page.goto(srv.base + "/index.html")
        page.fill("#username", "admin")
        page.fill("#password", srv.password)
        page.click("button[type=submit]")
        page.wait_for_url("**/rig.html")

        t = time.perf_counter()
        page.goto(srv.base + "/subjects.html")
        page.wait_for_selector("#subjects tr[data-subject]")
        res["subjects_page_s"] = time.perf_counter() - t
        t = time.perf_counter()
        page.fill("#subject-q", find_code)
        page.wait_for_selector(f'#subjects tr[data-subject="{find_code}"]')
        res["subjects_find_s"] = time.perf_counter() - t
        t = time.perf_counter()
        page.fill("#subject-q", "")  # back to every subject, then the next page
        page.wait_for_function("document.querySelector('#subjects-count').textContent"
                               ".startsWith('Subjects 1–')")
        if page.is_enabled("#subjects-next"):  # (a project of the peer fits one page)
            page.click("#subjects-next")
            page.wait_for_function("document.querySelector('#subjects-count').textContent"
                                   ".startsWith('Subjects 51–')")
            res["subjects_next_page_s"] = time.perf_counter() - t

        t = time.perf_counter()
        page.goto(srv.base + "/record.html")
        page.wait_for_function("document.querySelectorAll('#subject option').length > 1")
        res["record_page_s"] = time.perf_counter() - t
        t = time.perf_counter()
        page.fill("#subject-q", find_code)
        page.wait_for_function(f"document.querySelector('#subject').selectedOptions[0]?.text"
                               f" === '{find_code}'")
        res["record_find_s"] = time.perf_counter() - t

        t = time.perf_counter()
        page.goto(srv.base + "/reports.html")
        page.wait_for_function("document.querySelectorAll('#subject option').length > 1 && "
                               "document.querySelectorAll('#recording option').length > 1")
        res["reports_page_s"] = time.perf_counter() - t
        b.close()
    return {k: round(v, 3) for k, v in res.items()}


def sync_step_ms(data_dir: Path, n: int = 5) -> tuple[float, float]:
    """Milliseconds of the longest pass of the data sync's start-up sweep
    (:class:`app.server.datasync.DataSync`: the passes after the start look at every
    recording not complete once, a few per pass) over ``data_dir`` and the median of the
    ``n`` passes after it (those look only at what can still change)."""
    import asyncio

    from app.config import Settings
    from app.db.base import make_engine, make_session_factory
    from app.server.datasync import DataSync
    from app.server.hub import Hub
    from app.server.storage import StorageLayout

    settings = Settings(data_dir=data_dir, viewer_enabled=False)
    engine = make_engine(settings.db_url)
    sync = DataSync(Hub(settings), make_session_factory(engine), StorageLayout(data_dir))

    async def passes() -> tuple[list[float], list[float]]:  # in a loop, as the server runs it
        sync._sweep = await asyncio.to_thread(sync._sweep_ids)  # as start() reads it
        sweep, after = [], []
        while sync.sweeping or len(after) < n:
            t = time.perf_counter()
            busy = bool(sync.sweeping)
            sync.step()
            (sweep if busy else after).append(time.perf_counter() - t)
        return sweep or [0.0], after

    try:
        sweep, rest = asyncio.run(passes())
        return round(1000 * max(sweep), 1), round(1000 * statistics.median(rest), 1)
    finally:
        engine.dispose()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--subjects", type=int, default=5000, help="the clinic's subjects")
    ap.add_argument("--peer", type=int, default=50, help="the peer's subjects")
    ap.add_argument("--repeat", type=int, default=5, help="requests per endpoint and server")
    ap.add_argument("--no-browser", action="store_true", help="skip the page timings")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="gaitrig-list-scale-"))
    try:
        t = time.perf_counter()
        scale = args.subjects / args.peer
        big = populate(tmp / "big", args.subjects, 6, n_audit=20 * args.subjects,
                       n_with_files=min(2000, 6 * args.subjects))
        populate(tmp / "peer", args.peer, 6, n_audit=20 * args.peer,
                 n_with_files=min(2000, round(2000 / scale)))
        fill_s = time.perf_counter() - t
        with ExitStack() as stack:
            servers = [Server(tmp / "big", tmp / "big.log"), Server(tmp / "peer", tmp / "peer.log")]
            stack.callback(stop, [s.proc for s in servers])
            start_s = [s.wait() for s in servers]
            endpoints = measure_endpoints(servers[0], servers[1], args.repeat)
            load = round(os.getloadavg()[0], 1)
            code = subject_code(4 * (args.subjects // 8) + 1)  # project 1, mid-list
            peer_code = subject_code(4 * (args.peer // 8) + 1)
            pages: dict[str, Any] = {}
            if not args.no_browser and CHROMIUM.exists():
                pages = {"clinic": measure_pages(servers[0], code),
                         "peer": measure_pages(servers[1], peer_code)}
        sync = [sync_step_ms(tmp / "big"), sync_step_ms(tmp / "peer")]
        # every list as the console asks for it (the peer's pages are shorter where it has
        # fewer rows than a page holds); not audit_10000, a download-sized page
        ratios = [v["ratio"] for k, v in endpoints.items()
                  if v["ratio"] and k not in ("healthz", "audit_10000")]
        print(json.dumps({
            "bench": "list_scale", "subjects": args.subjects, "peer_subjects": args.peer,
            "recordings": len(big.recording_ids), "parts": big.n_parts,
            "audit_entries": big.n_audit, "fill_s": round(fill_s, 1),
            "server_start_s": [round(x, 1) for x in start_s],
            "loadavg": load, "worst_ratio": max(ratios) if ratios else None,
            "worst_ms": max(v["ms"] for k, v in endpoints.items()
                            if k not in ("audit_10000",)),
            "sync_step_ms": sync[0][1], "sync_step_ms_peer": sync[1][1],
            "sync_first_pass_ms": sync[0][0], "sync_first_pass_ms_peer": sync[1][0],
            "endpoints": endpoints, "pages": pages,
        }))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
