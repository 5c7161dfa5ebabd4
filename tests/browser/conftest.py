"""Browser-test harness: a real server with simulated nodes, and a logged-in Chromium page.

Fixtures:

* ``live_server`` (package): ``gaitrig demo`` on free ports with six simulated sensor nodes
  in a temporary data folder, waited on until every node is online. Gives the console URL,
  the 3D-view URL, the admin password and a logged-in :meth:`LiveServer.api` helper.
  Stopped (nodes, then server) after the last test of ``tests/browser`` — its seven
  streaming processes would otherwise take CPU from the rest of the suite.
* ``browser`` (``tests/conftest.py``): the session's headless Debian Chromium
  (``/usr/bin/chromium``; never a downloaded browser), with no context open at the start
  of a test and its contexts closed after it. Contexts bypass the Content-Security-Policy
  (Playwright's ``wait_for_function`` uses ``eval``) except in ``test_csp.py``. Skips
  every browser test with a reason when Chromium or Playwright is missing.
* ``page`` (function): a new browser context already logged in through the login form
  (so every test also exercises the login), on the Rig page.

Helpers for what a person sees: :func:`screenshot` saves a PNG into ``artifacts_dir`` and
returns it as an RGB array; :func:`color_fraction`, :func:`changed_fraction` and
:func:`saturated_fraction` measure pixels. Mark tests ``@pytest.mark.browser``.
"""

from __future__ import annotations

import contextlib
import functools
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from numpy.typing import NDArray

ROOT = Path(__file__).resolve().parents[2]
N_NODES = int(os.environ.get("GAITRIG_TEST_NODES", "6"))
START_TIMEOUT_S = 90.0


def free_port() -> int:
    """A TCP port on 127.0.0.1 that is free right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class LiveServer:
    """A running ``gaitrig demo`` (server + simulated nodes) for browser tests."""

    base_url: str
    viewer_url: str
    password: str
    data_dir: Path
    n_nodes: int
    process: subprocess.Popen[bytes]
    token: str = ""

    def api(self, path: str, data: dict[str, Any] | None = None, method: str | None = None,
            timeout: float = 15.0) -> Any:
        """Call the REST API as the admin (bearer token); returns the decoded JSON or bytes."""
        headers = {"Content-Type": "application/json"}
        if self.token:
            headers["Authorization"] = f"Bearer {self.token}"
        body = json.dumps(data).encode() if data is not None else None
        req = urllib.request.Request(self.base_url + path, data=body, headers=headers,
                                     method=method)
        with urllib.request.urlopen(req, timeout=timeout) as r:
            raw = r.read()
            if r.headers.get_content_type() == "application/json":
                return json.loads(raw) if raw else None
            return raw

    def login(self) -> None:
        """Get a bearer token for :meth:`api`."""
        self.token = ""
        self.token = self.api("/api/auth/login", {"username": "admin",
                                                  "password": self.password})["token"]

    def online(self) -> list[str]:
        """Ids of the nodes currently online."""
        return [n["id"] for n in self.api("/api/nodes") if n["connected"]]


def _wait_http(url: str, proc: subprocess.Popen[bytes], timeout: float) -> None:
    deadline = time.time() + timeout
    while time.time() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"gaitrig demo exited with {proc.returncode} before serving")
        try:
            with urllib.request.urlopen(url, timeout=2):
                return
        except (urllib.error.URLError, OSError):
            time.sleep(0.2)
    raise TimeoutError(f"{url} did not answer within {timeout:.0f} s")


def stop_process(proc: subprocess.Popen[bytes], timeout_s: float = 20.0) -> None:
    """SIGTERM (a demo stops its nodes, then the server), killed after ``timeout_s``."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@contextmanager
def serve_without_nodes(data_dir: Path, env: dict[str, str]) -> Iterator[tuple[str, Path]]:
    """``gaitrig serve --no-viewer`` on a free port over ``data_dir`` with ``env``; yields
    its base URL and log file (beside ``data_dir``), stopped on exit."""
    port = free_port()
    log_path = data_dir.parent / "server.log"
    with log_path.open("wb") as log:
        proc = subprocess.Popen(
            [sys.executable, "-m", "app.cli", "serve", "--host", "127.0.0.1", "--port",
             str(port), "--no-viewer", "--data-dir", str(data_dir), "--log-level", "warning"],
            cwd=ROOT, stdout=log, stderr=subprocess.STDOUT,
            env={**env, "PYTHONUNBUFFERED": "1"})
        try:
            _wait_http(f"http://127.0.0.1:{port}/healthz", proc, 60)
            yield f"http://127.0.0.1:{port}", log_path
        finally:
            stop_process(proc)


@pytest.fixture(scope="package")
def live_server() -> Iterator[LiveServer]:
    """``gaitrig demo`` with ``GAITRIG_TEST_NODES`` (default 6) sim nodes, all online."""
    from app.commands.demo import demo_password

    tmp = Path(tempfile.mkdtemp(prefix="gaitrig-browser-"))
    port, vport = free_port(), free_port()
    password = demo_password(tmp)
    log = (tmp / "demo.log").open("wb")
    cmd = [sys.executable, "-m", "app.cli", "demo", "--port", str(port), "--viewer-port",
           str(vport), "--data-dir", str(tmp), "--nodes", str(N_NODES)]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT,
                            env={**os.environ, "PYTHONUNBUFFERED": "1",
                                 # KSCC tests link to a second server on loopback
                                 "GAITRIG_KSCC_PEERS": '["127.0.0.1"]'})
    # the 3D view as the console shows it: behind the login, on the console's port
    server = LiveServer(f"http://127.0.0.1:{port}", f"http://127.0.0.1:{port}/viewer", password,
                        tmp, N_NODES, proc)
    try:
        _wait_http(server.base_url + "/healthz", proc, START_TIMEOUT_S)
        server.login()
        deadline = time.time() + START_TIMEOUT_S
        while len(server.online()) < N_NODES:
            if time.time() > deadline or proc.poll() is not None:
                raise RuntimeError(f"only {server.online()} of {N_NODES} nodes came online; "
                                   f"log: {(tmp / 'demo.log').read_text()[-3000:]}")
            time.sleep(0.3)
        yield server
    finally:
        stop_process(proc)
        log.close()
        # kept for the person reading a failure (a 500's traceback is only in this log)
        from tests.conftest import ARTIFACTS

        ARTIFACTS.mkdir(exist_ok=True)
        with contextlib.suppress(OSError):
            # one per test worker (make test runs several, each with its own server)
            worker = os.environ.get("PYTEST_XDIST_WORKER", "")
            name = f"browser-demo-{worker}.log" if worker else "browser-demo.log"
            shutil.copyfile(tmp / "demo.log", ARTIFACTS / name)
        shutil.rmtree(tmp, ignore_errors=True)


def short_recording(server: LiveServer, session_id: int, label: str) -> str:
    """A short recording ``label`` of ``session_id``, copied to the server; its id."""
    rid = str(server.api(f"/api/sessions/{session_id}/recordings",
                         {"label": label, "streams": [], "image_every": 3})["id"])
    deadline = time.time() + 90
    while not all(p["n_frames"] > 0 for p in server.api(f"/api/recordings/{rid}")["parts"]):
        assert time.time() < deadline, f"recording {rid} got no frame from every sensor"
        time.sleep(0.1)
    server.api(f"/api/recordings/{rid}/stop", {})
    while server.api(f"/api/storage/recordings/{rid}")["state"] != "complete":
        assert time.time() < deadline, f"recording {rid} was not copied"
        time.sleep(0.3)
    return rid


#: Straight walking (s, in one pass of the simulated walker) a :func:`record_walk` holds:
#: ≈ 6 steps at its 0.59 s step time — two or more after the analysis leaves out a pass's
#: first steps, wherever the recording starts.
WALK_STRAIGHT_S = 3.5
#: The first seconds of a pass (from its first heel strike) do not count: the walker
#: comes out of the turn slowly, and the analysis trims a pass's blurred start (a
#: recording of a pass's first 3.5 s gave no step).
PASS_START_SKIP_S = 1.5


@functools.lru_cache(maxsize=4)
def _sim_passes(seed: int) -> tuple[tuple[float, float], ...]:
    """(first, last heel strike) of each straight pass of the simulated nodes' walker, in
    seconds into its world cycle (``app.nodes.backends.sim``: every sim node poses the
    same walker at host time modulo :data:`~app.nodes.backends.sim.WORLD_CYCLE_S`)."""
    from app.nodes.backends.sim import CHUNK_S, WORLD_CYCLE_S
    from engine.sim.rig import default_avenue_rig
    from engine.sim.walker import Walker, WalkerParams

    way = default_avenue_rig(seed).walkway
    walker = Walker(WalkerParams.random(np.random.default_rng(seed)), way.start, way.end,
                    start_time=0.0, seed=seed, horizon_s=WORLD_CYCLE_S + CHUNK_S)
    # (a pass under way at the cycle's end is cut there: the walk starts again standing)
    return tuple((float(a), min(float(b), WORLD_CYCLE_S))
                 for a, b in walker.pass_times(WORLD_CYCLE_S + CHUNK_S) if a < WORLD_CYCLE_S)


def walk_stop_time(t_start: float, straight_s: float = WALK_STRAIGHT_S,
                   seed: int = 0) -> float:
    """Host time (s) at which a recording of the default avenue's simulated nodes started
    at ``t_start`` holds ``straight_s`` of one straight pass of the walker: a fixed
    length can be caught at a corridor turn (two short halves of passes, < 2 steps)."""
    from app.nodes.backends.sim import WORLD_CYCLE_S

    cycle0 = t_start - t_start % WORLD_CYCLE_S
    for k in range(3):
        for a, b in _sim_passes(seed):
            a = cycle0 + k * WORLD_CYCLE_S + a + PASS_START_SKIP_S
            b = cycle0 + k * WORLD_CYCLE_S + b
            if b - max(a, t_start) >= straight_s:
                return max(a, t_start) + straight_s
    raise AssertionError(f"the simulated walker has no {straight_s:g} s pass")  # not reached


def record_walk(server: Any, session_id: int, timeout_s: float = 90.0,
                wait: bool = True, straight_s: float = WALK_STRAIGHT_S) -> str:
    """Record a few steps of the simulated walker (default avenue, seed 0) under
    ``session_id`` through ``server.api`` (a :class:`LiveServer` or a test's own lab) and
    wait until the recording is complete on the server; its id. With ``wait=False`` it
    returns once the recording is stopped, its copy to the server under way (another
    walk can start at once; :func:`wait_copied` waits for it).

    The recording is stopped once it holds :data:`WALK_STRAIGHT_S` of straight walking
    (by the simulator's own footprints, :func:`walk_stop_time`), so each walk has steps:
    3.5-12 s (6.4 on average), instead of a fixed 7 s that a turn could leave without
    any (the callers then walked again). ``straight_s``: more straight walking, for a
    report of one side's sensors (which lose the far foot now and then)."""
    rec = server.api(f"/api/sessions/{session_id}/recordings",
                     {"label": "walk", "streams": [], "image_every": 3})
    # + 0.3 s: the nodes' frames reach the ring a moment after their capture time
    time.sleep(max(0.0, walk_stop_time(float(rec["t_start"]), straight_s) + 0.3
                   - time.time()))
    server.api(f"/api/recordings/{rec['id']}/stop", {}, method="POST")
    if wait:
        wait_copied(server, str(rec["id"]), timeout_s)
    return str(rec["id"])


def wait_copied(server: Any, rec_id: str, timeout_s: float = 90.0) -> None:
    """Wait until the stopped recording ``rec_id`` is complete on the server."""
    deadline = time.time() + timeout_s
    while server.api(f"/api/storage/recordings/{rec_id}")["state"] != "complete":
        if time.time() > deadline:
            raise TimeoutError(f"recording {rec_id} was not copied to the server in "
                               f"{timeout_s:g} s")
        time.sleep(0.1)


def login(page: Any, server: LiveServer) -> None:
    """Log in through the console's login form and land on the Rig page."""
    page.goto(server.base_url + "/index.html")
    page.fill("#username", "admin")
    page.fill("#password", server.password)
    page.click("button[type=submit]")
    page.wait_for_url("**/rig.html", timeout=15000)


def new_page(browser: Any, timeout_ms: float = 20000) -> Any:
    """A page in a fresh browser context (own cookies), 1400×900, whose JavaScript errors
    collect in ``page.js_errors`` (tests may assert there were none). The context bypasses
    the console's Content-Security-Policy, which refuses the ``eval`` of Playwright's
    ``wait_for_function`` (``test_csp.py`` checks the pages under the policy)."""
    context = browser.new_context(viewport={"width": 1400, "height": 900}, bypass_csp=True)
    p = context.new_page()
    p.set_default_timeout(timeout_ms)
    errors: list[str] = []
    p.on("pageerror", lambda e: errors.append(str(e)))
    p.js_errors = errors
    return p


@pytest.fixture
def page(browser: Any, live_server: LiveServer) -> Iterator[Any]:
    """A fresh browser context (own cookies), logged in, 1400×900, on the Rig page."""
    p = new_page(browser)
    try:
        login(p, live_server)
        yield p
    finally:
        p.context.close()


#: Counts the page's requests in flight (``fetch`` and ``XMLHttpRequest``) from its first
#: script on: :func:`wait_settled` waits on it. Added with ``add_init_script`` before the
#: page is opened; a page's streams (websockets) are not requests and are not counted.
TRACK_REQUESTS_JS = """(() => {
  if (window.__net) return;
  const net = window.__net = { pending: 0, started: 0, last: performance.now() };
  const begin = () => { net.pending += 1; net.started += 1; net.last = performance.now(); };
  const end = () => { net.pending -= 1; net.last = performance.now(); };
  const realFetch = window.fetch;
  window.fetch = function (...args) {
    begin();
    // settled once the body is read too: a page reads it (json()) on the answer
    return realFetch.apply(this, args).then((r) => {
      r.clone().arrayBuffer().then(end, end);
      return r;
    }, (e) => { end(); throw e; });
  };
  const send = XMLHttpRequest.prototype.send;
  XMLHttpRequest.prototype.send = function (...args) {
    begin();
    this.addEventListener("loadend", end);
    return send.apply(this, args);
  };
})()"""


def track_requests(page: Any) -> None:
    """Count ``page``'s requests in flight from its next navigation on (for
    :func:`wait_settled`)."""
    page.add_init_script(TRACK_REQUESTS_JS)


def wait_settled(page: Any, quiet_ms: float = 400, timeout_ms: float = 30000) -> None:
    """Wait until the page (opened after :func:`track_requests`) has loaded, asked for
    something, has no request in flight and none finished or began in the last
    ``quiet_ms`` (an answer that leads to another request, and its drawing, have
    happened), then for two animation frames: what a fixed "let the first answers
    arrive" sleep waited for, without its margin. A page that polls settles between
    two polls."""
    page.wait_for_load_state("load")
    page.wait_for_function(
        "(q) => window.__net && window.__net.started > 0 && window.__net.pending === 0 "
        "&& performance.now() - window.__net.last >= q", arg=quiet_ms, timeout=timeout_ms,
        polling=50)
    page.evaluate("() => new Promise((r) => requestAnimationFrame(() => "
                  "requestAnimationFrame(() => r(true))))")


def screenshot(page: Any, artifacts_dir: Path, name: str,
               selector: str | None = None) -> NDArray[np.uint8]:
    """Save a PNG of the page (or of one element) as ``<artifacts>/browser/<name>.png``.

    Returns:
        The screenshot as an ``(H, W, 3)`` RGB uint8 array.
    """
    out = artifacts_dir / "browser"
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{name}.png"
    if selector is None:
        png = page.screenshot(path=str(path))
        return decode_png(png)
    # crop a viewport screenshot rather than Playwright's element screenshot, which can
    # capture mid-scroll while the page is repainting
    loc = page.locator(selector).first
    loc.scroll_into_view_if_needed()
    box = loc.bounding_box()
    if box is None:
        raise AssertionError(f"{selector} is not visible on the page")
    full = decode_png(page.screenshot())
    x0, y0 = max(0, int(box["x"])), max(0, int(box["y"]))
    x1 = min(full.shape[1], int(box["x"] + box["width"]))
    y1 = min(full.shape[0], int(box["y"] + box["height"]))
    img = np.ascontiguousarray(full[y0:y1, x0:x1])
    cv2.imwrite(str(path), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    return img


def decode_png(data: bytes) -> NDArray[np.uint8]:
    """PNG/JPEG bytes → ``(H, W, 3)`` RGB array."""
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if img is None:
        raise ValueError("not a decodable image")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def color_fraction(img: NDArray[np.uint8], rgb: tuple[int, int, int], tol: int = 40) -> float:
    """Fraction of pixels within ``tol`` (max per channel) of the colour ``rgb``."""
    d = np.abs(img[..., :3].astype(np.int16) - np.asarray(rgb, np.int16)).max(axis=-1)
    return float((d <= tol).mean())


def changed_fraction(a: NDArray[np.uint8], b: NDArray[np.uint8], tol: int = 12) -> float:
    """Fraction of pixels whose colour differs by more than ``tol`` between two images."""
    if a.shape != b.shape:
        return 1.0
    d = np.abs(a.astype(np.int16) - b.astype(np.int16)).max(axis=-1)
    return float((d > tol).mean())


def saturated_fraction(img: NDArray[np.uint8], min_sat: int = 80) -> float:
    """Fraction of strongly coloured (not grey/white/black) pixels — e.g. a colour map."""
    hsv = cv2.cvtColor(np.ascontiguousarray(img[..., :3]), cv2.COLOR_RGB2HSV)
    return float(((hsv[..., 1] >= min_sat) & (hsv[..., 2] >= 40)).mean())
