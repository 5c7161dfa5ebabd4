"""Accessibility of the console, checked by a machine and by a person's keyboard.

* axe-core (the ``axe-playwright-python`` package bundles ``axe.min.js``; nothing is
  downloaded) runs on every page of ``static/*.html`` in its loaded, populated state (a
  subject with a session and a complete recording, its report shown, a simulated IMU
  session, a calibration result) and on the states that matter most: a login error shown,
  the subject's delete confirmation open, the change-password dialog open. No violation of
  impact "serious" or "critical" may remain.
* A person with only a keyboard logs in, goes to Record, finds a subject by typing, starts
  and stops a recording and opens its report; the test asserts the accessible name of the
  focused element at each step, as a screen reader would say it. The dialog keeps the
  focus inside and Escape returns it to the button that opened it.
* Reflow (WCAG 1.4.10): at 320 CSS px wide no page scrolls sideways (data tables and plots
  scroll inside their own box).

One server for the module (``gaitrig serve`` without the demo) with six simulated sensor
nodes (no images), so that a recording can be made. Screenshots (and axe's findings as
JSON): ``test-artifacts/browser/a11y_*``.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import os
import re
import secrets
import shutil
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from html.parser import HTMLParser
from pathlib import Path
from typing import Any

import pytest

from tests.browser.conftest import (
    ROOT,
    new_page,
    record_walk,
    screenshot,
    serve_without_nodes,
    stop_process,
    wait_copied,
)

pytestmark = [pytest.mark.browser, pytest.mark.slow]

NODES = ("S1", "S2", "S3", "S4", "S5", "S6")  # the whole avenue: a walk has steps anywhere
CODE = "A11Y01"  # the subject that has a session and a complete recording
KEY_CODE = "KBD07"  # the subject the keyboard user records
BLOCKING = ("serious", "critical")
WARNING = "Body tracking fell behind the camera (test warning): skeletons may be missing."


@dataclass
class Lab:
    """The module's server: its URL, the admin password and the populated subject."""

    url: str
    password: str
    subject_id: int
    session_id: int
    rec_id: str
    token: str = ""
    #: the module's one simulated calibration, made at its first use (:func:`_simulated`)
    simulated: dict[str, Any] | None = None

    def api(self, path: str, data: Any = None, method: str | None = None) -> Any:
        """Call the REST API as the administrator; returns the decoded JSON."""
        if not self.token and path != "/api/auth/login":
            self.token = self.api("/api/auth/login", {"username": "admin",
                                                      "password": self.password})["token"]
        headers = {"Content-Type": "application/json"}
        if self.token:
            headers["Authorization"] = f"Bearer {self.token}"
        body = json.dumps(data).encode() if data is not None else None
        req = urllib.request.Request(self.url + path, data=body, headers=headers, method=method)
        with urllib.request.urlopen(req, timeout=120) as r:
            raw = r.read()
            if r.headers.get_content_type() != "application/json":
                return raw
            return json.loads(raw) if raw else None


def _walks_with_steps(lab: Lab, sessions: dict[int, int]) -> dict[int, str]:
    """Record a walk into each subject's session (subject id → session id, in that
    order), each started as soon as the one before is stopped (its copy to the server
    goes on meanwhile), and again into those whose report has no steps (the simulated
    walker may be turning or out of view), three walks each at most; returns each
    subject's last recording id."""
    last: dict[int, str] = {}
    todo = dict(sessions)
    why: dict[int, str] = {}
    for _ in range(3):
        for subject_id, session_id in todo.items():
            last[subject_id] = record_walk(lab, session_id, wait=False)
        for subject_id in todo:
            wait_copied(lab, last[subject_id])
        why = {}
        for subject_id in todo:
            try:
                lab.api(f"/api/reports/subjects/{subject_id}?format=html")
            except urllib.error.HTTPError as e:
                if e.code not in (400, 422):
                    raise
                why[subject_id] = e.read().decode(errors="replace")
        if not why:
            return last
        todo = {s: todo[s] for s in why}
    raise RuntimeError(f"three simulated walks gave no gait result: {why}")


@pytest.fixture(scope="module")
def lab() -> Iterator[Lab]:
    """A server with six simulated sensor nodes; subjects :data:`CODE` and
    :data:`KEY_CODE` each hold one session with a complete walk whose report can be
    computed."""
    tmp = Path(tempfile.mkdtemp(prefix="gaitrig-a11y-"))
    password = secrets.token_urlsafe(12)
    env = {**os.environ, "GAITRIG_ADMIN_PASSWORD": password,
           "GAITRIG_NODE_TOKEN": secrets.token_urlsafe(16), "PYTHONUNBUFFERED": "1"}
    nodes: list[subprocess.Popen[bytes]] = []
    try:
        with serve_without_nodes(tmp / "data", env) as (url, _log), \
                (tmp / "nodes.log").open("wb") as log:
            for node_id in NODES:
                nodes.append(subprocess.Popen(
                    [sys.executable, "-m", "app.cli", "node", "--id", node_id, "--server",
                     url.replace("http://", "ws://"), "--data-dir", str(tmp / node_id),
                     "--no-images", "--log-level", "warning",
                     # the Rig page's warning text (orange) is on screen, as in a lab
                     *(["--test-warning", WARNING] if node_id == NODES[-1] else [])],
                    cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT))
            lab = Lab(url, password, 0, 0, "")
            deadline = time.time() + 90
            while sum(n["connected"] and n["clock_offset_ms"] is not None
                      for n in lab.api("/api/nodes")) < len(NODES):
                if time.time() > deadline:
                    raise TimeoutError(f"nodes not ready in 90 s: {lab.api('/api/nodes')}")
                time.sleep(0.3)
            project = lab.api("/api/projects", {"name": "Accessibility"})
            subject = lab.api("/api/subjects", {"project_id": project["id"], "code": CODE})
            session = lab.api("/api/sessions", {"subject_id": subject["id"],
                                                "label": "baseline"})
            keyed = lab.api("/api/subjects", {"project_id": project["id"], "code": KEY_CODE})
            keyed_session = lab.api("/api/sessions", {"subject_id": keyed["id"],
                                                      "label": "keyboard"})
            lab.subject_id, lab.session_id = subject["id"], session["id"]
            # the keyboard user's session already holds a walk with steps: the report
            # they open shows whatever their own short walk caught
            walks = _walks_with_steps(lab, {keyed["id"]: keyed_session["id"],
                                            subject["id"]: session["id"]})
            lab.rec_id = walks[subject["id"]]
            try:
                yield lab
            finally:
                for node in nodes:
                    stop_process(node, 10.0)
    finally:
        for node in nodes:
            if node.poll() is None:
                node.kill()
        shutil.rmtree(tmp, ignore_errors=True)


def _login(page: Any, lab: Lab) -> None:
    page.goto(lab.url + "/index.html")
    page.fill("#username", "admin")
    page.fill("#password", lab.password)
    page.click("button[type=submit]")
    page.wait_for_url("**/rig.html", timeout=20000)


@pytest.fixture
def page(browser: Any, lab: Lab) -> Iterator[Any]:
    """A logged-in page (1400×900) of the module's server, on the Rig page. Its context
    holds the session cookie of the module's administrator (:attr:`Lab.token`, one login)
    instead of logging in through the form again for each test (the form is tested by
    :func:`test_login_page_and_its_error_pass_axe_and_reflow` and the keyboard test)."""
    from app.api.deps import SESSION_COOKIE

    p = new_page(browser, 30000)
    try:
        if not lab.token:
            lab.api("/api/nodes")  # (logs in)
        p.context.add_cookies([{"name": SESSION_COOKIE, "value": lab.token, "url": lab.url,
                                "httpOnly": True, "sameSite": "Strict"}])
        p.goto(lab.url + "/rig.html")
        assert p.url.endswith("/rig.html"), p.url  # (not sent to the login form)
        yield p
    finally:
        p.context.close()


# ---------------------------------------------------------------- axe on every page

def axe_violations(page: Any, impacts: tuple[str, ...] = BLOCKING) -> list[dict[str, Any]]:
    """axe-core's violations on the page as it is now, those of the given impacts."""
    from axe_playwright_python.sync_playwright import Axe

    results = Axe().run(page)
    return [v for v in results.response["violations"] if v.get("impact") in impacts]


def describe(violations: list[dict[str, Any]]) -> str:
    """One line per violated rule: id, impact, help and the first few targets."""
    lines = []
    for v in violations:
        targets = [" ".join(map(str, n["target"])) for n in v["nodes"][:6]]
        lines.append(f"{v['id']} ({v['impact']}): {v['help']} — {len(v['nodes'])} nodes: "
                     + "; ".join(targets))
    return "\n".join(lines)


def _shown(page: Any, selector: str) -> None:
    page.wait_for_selector(selector, state="visible", timeout=120_000)


def _text(page: Any, selector: str, pattern: str) -> None:
    page.wait_for_function(
        "([s, p]) => { const e = document.querySelector(s); "
        "return e && new RegExp(p).test(e.textContent); }", arg=[selector, pattern],
        timeout=120_000)


def _rig(page: Any, lab: Lab) -> None:
    page.goto(lab.url + "/rig.html")
    _shown(page, f"#nodes tr[data-node={NODES[-1]}] li.node-warning")
    _shown(page, f"#recordings tr[data-recording='{lab.rec_id}']")


def _live(page: Any, lab: Lab) -> None:
    page.goto(lab.url + "/live.html")
    page.wait_for_function(f"document.querySelectorAll('#panels .panel').length >= {len(NODES)}")


def _calibrate(page: Any, lab: Lab) -> None:
    page.goto(lab.url + "/calibrate.html")
    _shown(page, f"#poses tr[data-node={NODES[-1]}]")
    _shown(page, "#planned tr")


def _simulated(lab: Lab) -> dict[str, Any]:
    """The module's simulated calibration (2 frames per sensor, seed 0): run through the
    API at its first use, saved as the active version, and its answer kept for the
    wizard's simulated runs after it (:func:`_wizard`)."""
    if lab.simulated is None:
        lab.simulated = lab.api("/api/calibration/simulate", {"frames": 2, "seed": 0})
    return lab.simulated


def _wizard(page: Any, lab: Lab) -> None:
    """The wizard after a simulated run through its form, its result on show. The run is
    answered with the module's one simulated calibration (:func:`_simulated`): each takes
    ~5 s of the server's CPU (far longer on a loaded machine) and this module showed four;
    the page draws the same answer the same way. The form's run on the server, its
    result's tables and the saved version are tested by
    tests/app/calibration/test_wizard_browser.py."""
    doc = _simulated(lab)
    asked: list[Any] = []

    def answer(route: Any) -> None:
        asked.append(route.request.post_data_json)
        route.fulfill(json=doc)

    page.route("**/api/calibration/simulate", answer)
    page.goto(lab.url + "/calibration-wizard.html")
    page.click("summary:text('No sensors?')")
    # the fewest frames the form takes: the result's page is the same, computed in a
    # fraction of the default 10 frames' time
    page.fill("#sim-frames", "2")
    page.click("#sim-form button[type=submit]")
    # until the run has answered: the result on show may still be the active calibration
    # (an earlier test's), drawn at the page's load
    page.wait_for_function("document.getElementById('cal-busy').hidden && !document"
                           ".querySelector('#sim-form button[type=submit]').disabled",
                           timeout=120_000)
    assert asked == [{"frames": 2, "seed": 0}], asked  # the form's run is the one answered
    _shown(page, "#res-details")
    _shown(page, "#sensor-table tbody tr")


def _wizard_capture(page: Any) -> None:
    """On the wizard, a capture whose job is answered with the active (simulated)
    calibration (a real capture takes minutes: tests/browser/test_calibration.py), its
    result waiting for its "Use this calibration?" answer."""
    doc = page.evaluate("fetch('/api/calibration/active').then((r) => r.json())")
    job = {"id": 1, "kind": "capture", "state": "done", "message": "", "frames": 2,
           "created": 0, "nodes": {s: {"received": 2, "error": None}
                                   for s in doc["T_world_sensor"]}, "result": doc}
    page.route("**/api/calibration/capture", lambda route: route.fulfill(
        status=202, json={"id": 1}))
    page.route("**/api/calibration/captures/1", lambda route: route.fulfill(json=job))
    page.click("#cap-form button[type=submit]")
    _shown(page, "#decide")


def _wizard_decide(page: Any, lab: Lab) -> None:
    """A captured result waiting for its "Use this calibration?" answer, with its
    sensor-marker table and technical figures open."""
    _wizard(page, lab)
    _wizard_capture(page)
    page.click("#res-more > summary")
    page.click("#res-figures > summary")


def _check(page: Any, lab: Lab) -> None:
    page.goto(lab.url + "/calibration-wizard.html")
    page.click("#check-btn")
    page.wait_for_function("document.getElementById('check-state').textContent && "
                           "!document.getElementById('check-btn').disabled", timeout=120_000)


def _record(page: Any, lab: Lab) -> None:
    page.goto(f"{lab.url}/record.html#subject={lab.subject_id}")
    page.wait_for_function(f"document.getElementById('session').value === '{lab.session_id}'")
    _text(page, "#nodes-summary", f"{len(NODES)} of {len(NODES)} sensors ready")


def _subjects(page: Any, lab: Lab) -> None:
    page.goto(f"{lab.url}/subjects.html#subject={lab.subject_id}")
    _shown(page, f"#sessions [data-recording='{lab.rec_id}'][data-state=complete]")


def _delete_confirm(page: Any, lab: Lab) -> None:
    _subjects(page, lab)
    page.click("details.danger-zone > summary")
    _shown(page, "#delete-form [name=confirm]")
    page.fill("#delete-form [name=confirm]", "wrong")
    page.click("#delete-form button[type=submit]")
    _text(page, "#delete-msg", ".")


def _reports(page: Any, lab: Lab) -> None:
    page.goto(f"{lab.url}/reports.html#subject={lab.subject_id}")
    _shown(page, "#report-section")
    _shown(page, "#report table")


def _imu(page: Any, lab: Lab) -> None:
    page.goto(lab.url + "/imu.html")
    page.click("#simulate")
    _shown(page, "#result")
    _shown(page, "#angles-card")


def _kscc(page: Any, lab: Lab) -> None:
    page.goto(lab.url + "/kscc.html")
    page.wait_for_function(f"document.querySelectorAll('#node-a option').length >= {len(NODES)}")
    _shown(page, "#areas tr")


def _accounts(page: Any, lab: Lab) -> None:
    page.goto(lab.url + "/accounts.html")
    _shown(page, "#accounts tr")


def _password_dialog(page: Any, lab: Lab) -> None:
    page.goto(lab.url + "/rig.html")
    page.click(".user-menu summary")
    page.click("#password-open")
    _shown(page, "#password-dialog")
    page.click("#pw-submit")  # empty: the refusal is said beside the field
    _text(page, "#pw-current-msg", ".")


def _help(page: Any, lab: Lab) -> None:
    page.goto(lab.url + "/help.html")
    _shown(page, "main h1")


#: page (or state) name → how to bring the logged-in page into it
STATES: dict[str, Callable[[Any, Lab], None]] = {
    "rig": _rig, "live": _live, "calibrate": _calibrate, "calibration-wizard": _wizard,
    "calibration-wizard-decide": _wizard_decide,
    "calibration-check": _check,
    "record": _record, "subjects": _subjects, "subjects-delete-confirm": _delete_confirm,
    "reports": _reports, "imu": _imu, "kscc": _kscc, "accounts": _accounts,
    "password-dialog": _password_dialog, "help": _help,
}


def test_every_console_page_is_checked() -> None:
    """A page added to ``static/`` without an accessibility check fails here."""
    pages = {p.stem for p in (ROOT / "static").glob("*.html")}
    checked = set(STATES) | {"index"}
    assert pages <= checked, f"pages without an axe check: {sorted(pages - checked)}"


# ------------------------------------------- a message read once: live or focused, not both

#: what makes an element a live region (role=status/alert/log and <output> are live
#: without aria-live): the roles in the files, the selector in the browser
LIVE_ROLES = {"status", "alert", "log"}
LIVE_SELECTOR = ("[aria-live]:not([aria-live=off]), [role=status], [role=alert], [role=log], "
                 "output")
#: a script's focus on an element of the page by its id
FOCUS_BY_ID = re.compile(r"""(?:(?:\$|getElementById)\(\s*["'`]|querySelector\(\s*["'`]#)"""
                         r"""([\w-]+)["'`]\s*\)\.focus\(""")
#: an element a script makes (``el("p", {...})``) that is both live and focusable
LIVE_AND_TABINDEX = re.compile(
    r"""\{[^{}]*(?:role["']?\s*:\s*["'](?:status|alert|log)["']|["']aria-live["']\s*:\s*"""
    r"""["'](?:polite|assertive)["'])[^{}]*\}""")

#: an object literal of an element a script makes, ``${…}`` substitutions and all
_OBJECT = r"\{(?:[^{}]|\$\{[^{}]*\})*\}"
_LIVE_ATTR = (r"""(?:role["']?\s*:\s*["'](?:status|alert|log)["']|["']aria-live["']\s*:\s*"""
              r"""["'](?:polite|assertive)["'])""")
#: a live region a script makes with an id (the id's text, substitutions and all), and an
#: element a script makes with an ``aria-describedby`` (the value's text)
LIVE_WITH_ID = re.compile(rf"""(?={_OBJECT})\{{(?=(?:[^{{}}]|\$\{{[^{{}}]*\}})*{_LIVE_ATTR})"""
                          r"""(?:[^{}]|\$\{[^{}]*\})*?\bid["']?\s*:\s*(["'`])((?:(?!\1).)*)\1""")
DESCRIBED_BY = re.compile(r"""["']aria-describedby["']\s*:\s*(["'`])((?:(?!\1).)*)\1""")


def _id_in(id_text: str, described: str) -> bool:
    """Whether a script's id (``${id}-msg``) is among those of a script's
    ``aria-describedby`` value (``${id}-msg${hint ? …}``), both as written in the source:
    the id's own words in the same places, any substitution where it has one."""
    pattern = r"\$\{[^}]*\}".join(map(re.escape, re.split(r"\$\{[^}]*\}", id_text)))
    return re.search(rf"(?<![\w-]){pattern}(?![\w-])", described) is not None


class _LiveRegions(HTMLParser):
    """Each element's id of a page, with whether it is a live region or inside one, and
    the live regions that take the focus (``tabindex``)."""

    VOID = frozenset({"area", "base", "br", "col", "embed", "hr", "img", "input", "link",
                      "meta", "source", "track", "wbr"})

    def __init__(self) -> None:
        super().__init__()
        self.stack: list[tuple[str, bool]] = []  # (tag, in a live region)
        self.live_ids: dict[str, str] = {}  # id → the live region's id (itself or around it)
        self.focusable_live: list[str] = []
        self.described_by: dict[str, list[str]] = {}  # id → the ids of its description

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        live = (a.get("role") in LIVE_ROLES or tag == "output"
                or (a.get("aria-live") not in (None, "off")))
        around = self.stack[-1][1] if self.stack else False
        if live and "tabindex" in a:
            self.focusable_live.append(f"<{tag} id={a.get('id')}>")
        if (i := a.get("id")) and (live or around):
            self.live_ids[i] = "itself" if live else "inside one"
        if (i := a.get("id")) and a.get("aria-describedby"):
            self.described_by[i] = (a.get("aria-describedby") or "").split()
        if tag not in self.VOID:
            self.stack.append((tag, live or around))

    def handle_endtag(self, tag: str) -> None:
        for i in range(len(self.stack) - 1, -1, -1):  # (an unclosed <p> ends with its parent)
            if self.stack[i][0] == tag:
                del self.stack[i:]
                return


def live_and_focused(pages: dict[str, str], scripts: dict[str, str]) -> list[str]:
    """Elements that are a live region (or inside one) and that a script focuses: a screen
    reader reads their words twice, once as news and once as the focus.

    Args:
        pages: HTML by file name.
        scripts: JavaScript by file name.

    A live region that is the description (``aria-describedby``) of a field that a script
    focuses is read twice too: as news, and as the focused field's description. Found in
    a page (the field focused by its id) and in a script that makes both the live region
    and an element it describes, and that focuses anything (the field is focused by a
    variable there, which the file does not tie to it).

    Returns:
        One line per problem: a focused live region named by id, a live region with a
        ``tabindex`` in a page, or one made focusable by a script, a live region that
        describes a field a script focuses.
    """
    live: dict[str, str] = {}
    described: dict[str, list[str]] = {}  # field id → its live descriptions, in any page
    out: list[str] = []
    for name, html in pages.items():
        parser = _LiveRegions()
        parser.feed(html)
        page_live = {i: f"{name}: #{i} is a live region ({why})"
                     for i, why in parser.live_ids.items()}
        live.update(page_live)
        for f, ds in parser.described_by.items():
            described.setdefault(f, []).extend(page_live[d] for d in ds if d in page_live)
        out += [f"{name}: {t} is a live region with a tabindex" for t in parser.focusable_live]
    for name, js in scripts.items():
        for m in FOCUS_BY_ID.finditer(js):
            line = js.count("\n", 0, m.start()) + 1
            if m.group(1) in live:
                out.append(f"{name}:{line} focuses it: {live[m.group(1)]}")
            out += [f"{name}:{line} focuses #{m.group(1)}, described by {d}"
                    for d in described.get(m.group(1), [])]
        if ".focus(" in js:
            for m in LIVE_WITH_ID.finditer(js):
                for d in DESCRIBED_BY.finditer(js):
                    if _id_in(m.group(2), d.group(2)):
                        line = js.count("\n", 0, m.start()) + 1
                        out.append(f"{name}:{line} makes a live region (id {m.group(2)}) "
                                   f"that describes a field it makes, and focuses fields")
        for m in LIVE_AND_TABINDEX.finditer(js):
            if re.search(r"tabindex|tabIndex", m.group(0)):
                line = js.count("\n", 0, m.start()) + 1
                out.append(f"{name}:{line} makes a live region that takes the focus")
    return out


def test_no_live_region_is_focused_by_a_script() -> None:
    """A message is said once: a script that moves the focus moves it to an element that is
    no live region (a heading, the result, a button), and a live region is left to say what
    changed while the focus stays put. Read from the files: every ``static/*.html`` and
    the scripts that focus an element by its id (a focus on an element made by a script is
    watched in the browser, :func:`test_focus_after_an_action_is_on_no_live_region`)."""
    static = ROOT / "static"
    pages = {p.name: p.read_text() for p in sorted(static.glob("*.html"))}
    scripts = {str(p.relative_to(static)): p.read_text() for p in sorted(static.rglob("*.js"))
               if "vendor" not in p.parts and p.name != "live-worker.js"}
    assert {"console.js", "js/record.js", "js/calibration.js"} <= set(scripts), sorted(scripts)
    problems = live_and_focused(pages, scripts)
    assert not problems, "\n".join(problems)
    # the check can fail: a focused status, an element inside a live region, a live region
    # with a tabindex and a script's focusable status are all found
    canary = live_and_focused(
        {"c.html": '<p id="said" role="status"></p><div aria-live="polite"><p id="in">x'
                   '</div><p id="fine" aria-live="off"></p><span role="alert" tabindex="-1">'},
        {"c.js": '$("said").focus();\ndocument.getElementById("in").focus({});\n'
                 '$("fine").focus();\nel("p", { role: "status", tabindex: "-1" });\n'
                 'document.querySelector("#said").focus();\nm.querySelector("summary").focus();'})
    assert len(canary) == 5, canary
    assert not any("#fine" in c for c in canary), canary
    # and a live region that describes a field a script focuses: in a page, and made by a
    # script (the change-password dialog's refusals were, and were read twice)
    canary = live_and_focused(
        {"d.html": '<p id="count" aria-live="polite"></p><select id="pick" '
                   'aria-describedby="hint count"></select><p id="hint">h</p>'
                   '<input id="q" aria-describedby="hint">'},
        {"d.js": '$("pick").focus();\n$("q").focus();\n',
         "e.js": 'const msg = el("p", { id: `${id}-msg`, "aria-live": "polite" });\n'
                 'el("input", { id, "aria-describedby": `${id}-msg${hint ? " h" : ""}` });\n'
                 'el("input", { "aria-describedby": `${id}-message` });\ninput.focus();'})
    assert len(canary) == 2 and "#pick" in canary[0] and "e.js:1" in canary[1], canary


def _axe_problems(page: Any, name: str, artifacts_dir: Path) -> list[str]:
    """Screenshot the page, keep all of axe's findings beside it (``a11y_<name>.json``:
    the moderate and minor ones are listed there for a person to judge) and describe the
    serious and critical ones."""
    screenshot(page, artifacts_dir, f"a11y_{name}")
    found = axe_violations(page, ("minor", "moderate", "serious", "critical"))
    (artifacts_dir / "browser" / f"a11y_{name}.json").write_text(json.dumps(
        [{"id": v["id"], "impact": v["impact"], "help": v["help"],
          "targets": [n["target"] for n in v["nodes"]],
          "html": [n.get("html", "")[:200] for n in v["nodes"]]} for v in found], indent=1))
    blocking = [v for v in found if v["impact"] in BLOCKING]
    return [f"axe on {name}:\n{describe(blocking)}"] if blocking else []


def _focus_problems(page: Any, name: str) -> list[str]:
    """Every element that takes the keyboard focus shows a ring while it has it (an
    outline of at least 2 px or a box shadow: axe does not check this)."""
    bare = page.evaluate("""() => {
        const sel = 'a[href], button, input, select, textarea, summary, iframe, [tabindex]';
        const out = [];
        for (const e of document.querySelectorAll(sel)) {
            if (e.disabled || e.tabIndex < 0 || !e.getClientRects().length
                || e.closest('[inert], dialog:not([open])')) continue;
            e.focus({ preventScroll: true });
            if (document.activeElement !== e) continue;
            const cs = getComputedStyle(e);
            const ring = (cs.outlineStyle !== 'none' && parseFloat(cs.outlineWidth) >= 2)
                || cs.boxShadow !== 'none';
            if (!ring) out.push(e.outerHTML.slice(0, 90));
        }
        document.activeElement.blur();
        return out; }""")
    return [f"{name}: no visible focus ring on {len(bare)} elements: " + " | ".join(bare[:6])
            ] if bare else []


#: WCAG 1.4.10: 320 CSS px is a 1280 px wide window zoomed to 400 %
REFLOW_WIDTH = 320


def _reflow_problems(page: Any, name: str, artifacts_dir: Path) -> list[str]:
    """At :data:`REFLOW_WIDTH` px the page itself must not scroll sideways (a table or a
    plot may, inside its own box); names the elements that stick out when it does."""
    page.set_viewport_size({"width": REFLOW_WIDTH, "height": 700})
    # the layout and the pages' resize handlers (a resize event, ResizeObserver) run in
    # the first frame at the new width; two frames on, they have (was a fixed 300 ms)
    page.wait_for_function("(w) => window.innerWidth === w", arg=REFLOW_WIDTH)
    page.evaluate("() => new Promise((r) => requestAnimationFrame(() => "
                  "requestAnimationFrame(() => r(true))))")
    screenshot(page, artifacts_dir, f"a11y_{name}_{REFLOW_WIDTH}px")
    scroll, inner = page.evaluate(
        "[document.documentElement.scrollWidth, window.innerWidth]")
    # a table box that scrolls can be reached and scrolled with the keyboard, and is named
    # (one in a closed <details> is not shown: it is measured, and takes the focus, once
    # the details is opened)
    unreachable = page.evaluate("""() => [...document.querySelectorAll('.table-scroll')]
        .filter((b) => !b.closest('details:not([open])'))
        .filter((b) => b.scrollWidth > b.clientWidth + 1 && !(b.tabIndex === 0
            && b.getAttribute('role') === 'region' && b.getAttribute('aria-label')))
        .map((b) => b.outerHTML.slice(0, 80))""")
    out = [f"{name}: table boxes that scroll but take no focus: {unreachable}"
           ] if unreachable else []
    if scroll <= inner + 1:
        return out
    wide = page.evaluate("""(w) => [...document.querySelectorAll('body *')]
        .filter((e) => { const r = e.getBoundingClientRect();
            const up = e.parentElement.getBoundingClientRect();  // the outermost culprits
            return r.width > 0 && r.right > w + 1 && up.right <= w + 1; })
        .slice(0, 8).map((e) => e.tagName.toLowerCase() + (e.id ? '#' + e.id : '') +
            (e.className && typeof e.className === 'string' ? '.' + e.className.split(' ')[0] : '')
            + ' right=' + Math.round(e.getBoundingClientRect().right))""", inner)
    return [*out, f"{name} scrolls sideways at {inner} px: scrollWidth {scroll}; sticking out: "
            + ", ".join(wide)]


def test_login_page_and_its_error_pass_axe_and_reflow(browser: Any, lab: Lab,
                                                       artifacts_dir: Path) -> None:
    page = new_page(browser, 30000)
    page.goto(lab.url + "/index.html")
    problems = _axe_problems(page, "login", artifacts_dir) + _focus_problems(page, "login")
    page.fill("#username", "admin")
    page.fill("#password", "not the password")
    page.click("button[type=submit]")
    _text(page, "#login-error", "Wrong user name or password")
    problems += _axe_problems(page, "login-error", artifacts_dir)
    problems += _reflow_problems(page, "login-error", artifacts_dir)
    assert not problems, "\n".join(problems)
    # the check itself can fail: a button without a name and grey-on-grey text are found
    page.evaluate("""() => { const m = document.querySelector('main');
        m.insertAdjacentHTML('beforeend', '<button id=nameless></button>' +
          '<p id=faint style="color:#999;background:#bbb">faint</p>' +
          '<div id=too-wide style="width:600px">wide</div>' +
          '<button id=ringless style="outline:none;box-shadow:none">no ring</button>'); }""")
    found = {v["id"]: v for v in axe_violations(page)}
    assert {"button-name", "color-contrast"} <= set(found), describe(list(found.values()))
    assert "ringless" in " ".join(_focus_problems(page, "login-canary"))
    assert _reflow_problems(page, "login-canary", artifacts_dir)


@pytest.mark.parametrize("name", sorted(STATES))
def test_console_page_passes_axe_and_reflows(page: Any, lab: Lab, artifacts_dir: Path,
                                             name: str) -> None:
    """axe and focus rings at a desktop's 1400 px, then the same state at 320 px: no
    sideways scroll, axe and focus rings again."""
    STATES[name](page, lab)
    problems = _axe_problems(page, name, artifacts_dir)
    problems += _focus_problems(page, name)
    problems += _reflow_problems(page, name, artifacts_dir)
    # narrow, the tables' scroll boxes take the focus: named regions, rings, axe again
    problems += _axe_problems(page, f"{name}_{REFLOW_WIDTH}px", artifacts_dir)
    problems += _focus_problems(page, f"{name}_{REFLOW_WIDTH}px")
    assert not problems, "\n".join(problems)
    assert not page.js_errors, page.js_errors


# ---------------------------------------------------------------- a person's keyboard

class Focus:
    """What a screen reader says about the focused element: its role and accessible name
    as Chromium's accessibility tree computes them (CDP), not as the test guesses them."""

    def __init__(self, page: Any) -> None:
        self.page = page
        self.cdp = page.context.new_cdp_session(page)

    def now(self) -> tuple[str, str]:
        """(role, name) of ``document.activeElement``."""
        obj = self.cdp.send("Runtime.evaluate", {"expression": "document.activeElement"})
        node = self.cdp.send("Accessibility.getPartialAXTree", {
            "objectId": obj["result"]["objectId"], "fetchRelatives": False})["nodes"][0]
        return (str(node.get("role", {}).get("value", "")),
                str(node.get("name", {}).get("value", "")))

    def expect(self, name: str, timeout_s: float = 5.0) -> None:
        """Wait until the focused element is the one named ``name``: where a script moves
        the focus after an event, Chromium's tree follows a moment later."""
        deadline = time.time() + timeout_s
        while (got := self.now())[1] != name:
            if time.time() > deadline:
                raise AssertionError(f"focus on {got}, not {name!r}: " + self.page.evaluate(
                    "document.activeElement.outerHTML.slice(0, 120)"))
            time.sleep(0.1)

    def press(self, key: str) -> tuple[str, str]:
        """Press ``key`` and say where the focus went."""
        self.page.keyboard.press(key)
        return self.now()

    def tab_to(self, name: str, limit: int = 60, key: str = "Tab") -> list[str]:
        """Press Tab until the element named ``name`` has the focus; returns the names
        passed on the way (fails after ``limit`` presses)."""
        passed: list[str] = []
        for _ in range(limit):
            _role, got = self.press(key)
            if got == name:
                return passed
            passed.append(got)
        raise AssertionError(f"{name!r} not reached in {limit} presses of {key}: {passed}")


#: Added with ``add_init_script``: every focus that lands on a live region (or on an
#: element holding one with words in it), by a script or by Tab, is kept in
#: ``window.focusOnLive``. A landing inside a live region (a button in a list that is one)
#: is no double reading and is not kept.
WATCH_FOCUS_JS = """(() => {
  const sel = LIVE_SELECTOR;
  window.focusOnLive = [];
  // live regions written since the focus last moved: one of them that describes
  // (aria-describedby) the element the focus lands on says its news twice, as news and
  // as the focused field's description (a description merely present is read once)
  const news = new Set();
  const note = (ms) => { for (const m of ms) {
    const t = m.target.nodeType === 1 ? m.target : m.target.parentElement;
    const r = t && t.closest(sel);
    if (r) news.add(r); } };
  const watch = new MutationObserver(note);
  watch.observe(document, {childList: true, subtree: true, characterData: true});
  document.addEventListener("focusin", (ev) => {
    note(watch.takeRecords());  // (written just before the focus() in the same task)
    const t = ev.target;
    const said = [...news];
    news.clear();
    if (!(t instanceof Element) || t === document.body || t.matches("main")) return;
    if (t.matches(sel) || [...t.querySelectorAll(sel)].some((r) => r.textContent.trim()))
      window.focusOnLive.push(location.pathname + ": " + t.outerHTML.slice(0, 120));
    for (const id of (t.getAttribute("aria-describedby") || "").split(/\\s+/)) {
      const d = id && document.getElementById(id), r = d && d.closest(sel);
      if (r && said.includes(r) && d.textContent.trim())
        window.focusOnLive.push(location.pathname + ": described by news: "
                                + t.outerHTML.slice(0, 120));
    }
  }, true);
})()""".replace("LIVE_SELECTOR", json.dumps(LIVE_SELECTOR))


def _live_focus(page: Any) -> list[str]:
    """The focus now and all the landings :data:`WATCH_FOCUS_JS` kept: elements that a
    screen reader reads twice (once as a live region's news, once as the focus). The
    focused element itself may be neither a live region, nor inside one, nor hold one."""
    return page.evaluate("""(sel) => {
        const out = [...(window.focusOnLive || [])];
        const a = document.activeElement;
        if (a && a !== document.body && (a.closest(sel)
                || [...a.querySelectorAll(sel)].some((r) => r.textContent.trim())))
            out.push("now: " + a.outerHTML.slice(0, 120));
        return out; }""", LIVE_SELECTOR)


def test_keyboard_only_login_record_and_report(browser: Any, lab: Lab,
                                               artifacts_dir: Path) -> None:
    """Log in, go to Record, find a subject by typing, start and stop a recording and
    open its report with Tab, Shift+Tab, Enter, Space and typing only."""
    page = new_page(browser, 30000)
    page.add_init_script(WATCH_FOCUS_JS)
    focus = Focus(page)
    page.goto(lab.url + "/index.html")
    # the field has the focus as soon as the page has loaded (autofocus; Chromium's tree
    # follows a moment later, so wait for it rather than read it at once)
    focus.expect("User name")
    assert focus.now() == ("textbox", "User name")
    page.keyboard.type("admin")
    assert focus.press("Tab") == ("textbox", "Password")
    page.keyboard.type(lab.password)
    assert focus.press("Tab") == ("button", "Log in")
    page.keyboard.press("Enter")
    page.wait_for_url("**/rig.html")
    page.wait_for_selector(".user-menu summary")

    # the first Tab offers to skip the header; the sections follow in the order shown
    assert focus.press("Tab") == ("link", "Skip to the page")
    assert focus.tab_to("Record") == ["Rig", "Live", "Calibrate"]
    page.keyboard.press("Enter")
    page.wait_for_url("**/record.html")
    page.wait_for_function("document.querySelectorAll('#subject option[value]').length > 0")

    assert focus.press("Tab") == ("link", "Skip to the page")
    page.keyboard.press("Enter")  # to the page's own content
    assert page.evaluate("document.activeElement.tagName") == "MAIN"
    assert focus.press("Tab") == ("combobox", "Project")
    assert focus.press("Tab") == ("searchbox", "Find subject code")
    page.keyboard.type(KEY_CODE[:3].lower())
    page.keyboard.press("Enter")  # the list is searched now and the focus goes to it
    focus.expect("Subject")
    assert focus.now()[0] == "combobox"
    assert page.evaluate("document.getElementById('subject').selectedOptions[0].text") \
        == KEY_CODE
    # (the session list follows the subject: its one session, "keyboard", is chosen)
    page.wait_for_function("/keyboard/.test(document.getElementById('session')"
                           ".selectedOptions[0]?.text || '')")
    assert focus.tab_to("Start recording") == [
        "…or a new subject code", "Add", "Session", "…or a new session today, label", "Add",
        "Subjects & recordings", "Trial label", "Depth images", "Colour images"]
    # (no images ticked: the image interval is not offered)
    page.keyboard.press("Enter")
    _text(page, "#rec-msg", "started")
    focus.expect("Stop")  # Start is disabled: the focus is on Stop
    assert focus.now()[0] == "button"
    # the message is said by its live region, once: the focus is not on it too
    assert page.get_attribute("#rec-msg", "role") == "status"
    assert not _live_focus(page), _live_focus(page)
    # a short walk: the session already holds one with steps (the ``lab``), so its report
    # opens whatever this one caught (8 s were waited here)
    time.sleep(2.0)
    page.keyboard.press("Space")
    _text(page, "#rec-msg", "stopped")
    # the disabled Stop gave the focus to the recording's sensors right under it (where
    # the copy shows), not to the message: that is a live region, read once as such
    focus.expect("Sensors of this recording")
    assert focus.now()[0] == "table"
    assert not _live_focus(page), _live_focus(page)
    screenshot(page, artifacts_dir, "a11y_keyboard_record_stopped")
    _shown(page, "#state-badge[data-state=complete]")
    assert focus.press("Tab") == ("link", "Open this recording in Subjects & recordings")
    screenshot(page, artifacts_dir, "a11y_keyboard_record")
    page.keyboard.press("Enter")
    page.wait_for_url("**/subjects.html#subject=*")
    _shown(page, "#sessions .recording[data-state=complete]")
    focus.tab_to("Gait report of this session", limit=120)
    page.keyboard.press("Enter")
    page.wait_for_url("**/reports.html#subject=*")
    _shown(page, "#report h1")
    focus.expect("Gait report", timeout_s=30)  # the report's title, then its subject
    assert focus.now()[0] == "heading"
    assert KEY_CODE in page.inner_text("#report table.meta")
    screenshot(page, artifacts_dir, "a11y_keyboard_report")
    assert not _live_focus(page), _live_focus(page)  # (nor anywhere on the way)
    assert not page.js_errors, page.js_errors


def test_a_calibration_result_and_its_outcome_are_read_once(page: Any, lab: Lab,
                                                            artifacts_dir: Path) -> None:
    """A simulated calibration's result and a capture's take the focus on their summary
    (the verdict in words) and Reject on its outcome: each is then read once, as the
    focus, so none of them may be a live region too (it was, and was read twice)."""
    page.add_init_script(WATCH_FOCUS_JS)
    focus = Focus(page)

    def focused_on(element_id: str) -> str:
        page.wait_for_function("(i) => document.activeElement.id === i", arg=element_id)
        words = " ".join((page.text_content(f"#{element_id}") or "").split())
        focus.expect(words)  # what a screen reader says as the focus: all of it
        assert not _live_focus(page), _live_focus(page)
        return words

    _wizard(page, lab)  # a simulated run
    assert "placed from" in focused_on("res-summary")
    _wizard_capture(page)
    assert "not saved yet" in focused_on("res-summary")
    screenshot(page, artifacts_dir, "a11y_calibration_captured_focus")
    page.route("**/api/calibration/captures/1/reject", lambda route: route.fulfill(json={}))
    page.click("#reject")
    assert focused_on("decide-state") == "Rejected: the active calibration is unchanged."
    screenshot(page, artifacts_dir, "a11y_calibration_rejected_focus")
    # Restore: the redrawn list takes its button away; the focus goes to the verdict of
    # the version now in use. A second version (the simulated one restored through the
    # API, instead of a second simulated run's ~5 s) gives an older one to restore; the
    # second run (answered as the first) draws the versions list anew
    lab.api(f"/api/calibration/{_simulated(lab)['version']}/restore", method="POST")
    page.click("#sim-form button[type=submit]")
    page.wait_for_function("document.querySelectorAll('#history tbody tr').length >= 2")
    focused_on("res-summary")
    newest = page.evaluate("fetch('/api/calibration').then((r) => r.json())")[0]["version"]
    page.click("#history tbody tr:nth-child(2) button")
    page.wait_for_function("(v) => document.getElementById('res-summary').textContent"
                           ".startsWith(`Version ${v + 1} `)", arg=newest)
    assert "placed from" in focused_on("res-summary")
    assert not page.js_errors, page.js_errors


def test_dialogs_keep_the_focus_and_escape_gives_it_back(page: Any, lab: Lab) -> None:
    """The change-password dialog: Tab and Shift+Tab go round inside it, Escape closes it
    and the focus is back on the menu it was opened from; the delete confirmation of the
    Subjects page closes with Escape onto its own summary."""
    focus = Focus(page)
    page.wait_for_selector(".user-menu summary")
    assert focus.press("Tab") == ("link", "Skip to the page")
    focus.tab_to("Account: admin")
    page.keyboard.press("Enter")  # opens the menu
    assert focus.press("Tab") == ("button", "Change password")
    page.keyboard.press("Enter")
    _shown(page, "#password-dialog[open]")
    assert focus.now() == ("textbox", "Current password")
    inside = [focus.press("Tab")[1] for _ in range(5)]
    assert inside == ["New password", "New password again", "Change password", "Close",
                      "Current password"]
    assert focus.press("Shift+Tab") == ("button", "Close")
    page.keyboard.press("Escape")
    # (the dialog's close event, which hands the focus back, follows a moment later)
    focus.expect("Account: admin")
    assert not page.evaluate("document.getElementById('password-dialog').open")

    page.goto(f"{lab.url}/subjects.html#subject={lab.subject_id}")
    _shown(page, f"#sessions [data-recording='{lab.rec_id}']")
    focus.tab_to("Delete this subject", limit=150)
    page.keyboard.press("Enter")
    assert focus.press("Tab") == ("textbox", "Type the subject code to confirm")
    page.keyboard.press("Escape")
    assert page.evaluate("document.querySelector('details.danger-zone').open") is False
    focus.expect("Delete this subject")


@pytest.mark.parametrize("width", [REFLOW_WIDTH, 768])
def test_header_with_its_menu_open_fits_a_phone_and_a_tablet(page: Any, lab: Lab,
                                                             artifacts_dir: Path,
                                                             width: int) -> None:
    page.set_viewport_size({"width": width, "height": 800})
    page.click(".user-menu summary")
    _shown(page, "#accounts-link")
    screenshot(page, artifacts_dir, f"a11y_menu_{width}px")
    fits = page.evaluate("""() => {
        const r = document.querySelector('.user-menu-items').getBoundingClientRect();
        const b = document.getElementById('logout');
        const w = document.documentElement.clientWidth;
        return {page: document.documentElement.scrollWidth <= w + 1,
                menu: r.left >= 0 && r.right <= w + 1,
                logout: b.clientHeight < 2 * parseFloat(getComputedStyle(b).lineHeight)}; }""")
    assert fits == {"page": True, "menu": True, "logout": True}, fits


@pytest.mark.parametrize("name", ["rig", "record", "live"])
def test_live_regions_speak_only_of_changes(page: Any, lab: Lab, name: str) -> None:
    """The pages that poll: a live region (``role=status``/``alert``, ``aria-live``) is
    not rewritten with the words it already holds (screen readers read them out again,
    every second) and does not change more than twice in 6 s when nothing happens. One
    observer of the whole page, so regions drawn after the start count too: a region is
    known by its recording (if in one) and its id or class, and an alert put on the page
    anew is read as it appears (a polite region put on the page is not read, but sets
    the words that are news for it)."""
    STATES[name](page, lab)
    page.evaluate("""(sel) => {
        window.liveNoise = {};
        const key = (r) => [r.closest('[data-recording]')?.dataset.recording,
                            r.id || r.getAttribute('class') || r.tagName]
                           .filter(Boolean).join(' ');
        const last = new Map();
        for (const r of document.querySelectorAll(sel)) last.set(key(r), r.textContent);
        const note = (r) => {
            const k = key(r), now = r.textContent;
            const n = window.liveNoise[k] || {same: 0, changed: 0};
            if (last.has(k) && now === last.get(k)) n.same += 1; else n.changed += 1;
            window.liveNoise[k] = n;
            last.set(k, now);
        };
        new MutationObserver((records) => {
            const touched = new Set();
            for (const m of records) {
                const t = m.target.nodeType === 1 ? m.target : m.target.parentElement;
                const region = t && t.closest(sel);
                if (region) { touched.add(region); continue; }
                for (const n of m.addedNodes) {
                    if (n.nodeType !== 1) continue;
                    for (const r of [n, ...n.querySelectorAll(sel)]) {
                        if (!r.matches(sel)) continue;
                        if (r.matches('[role=alert]') && r.textContent.trim()) touched.add(r);
                        else last.set(key(r), r.textContent);
                    }
                }
            }
            touched.forEach(note);
        }).observe(document.body, {childList: true, subtree: true, characterData: true});
        }""", "[aria-live]:not([aria-live=off]), [role=status], [role=alert]")
    page.wait_for_timeout(6000)
    noise = page.evaluate("window.liveNoise")
    loud = {k: v for k, v in noise.items() if v["same"] or v["changed"] > 2}
    assert not loud, f"live regions of {name} that speak without news: {loud}"


#: Run in a page: from then on, what its live regions would say, in ``window.said`` as
#: [where, words]: a live region on the page whose words change or get nodes added (a
#: screen reader reads the additions, even words it said before), and an alert put on the
#: page with words in it (read as it appears). ``where`` is the recording's id (if the
#: region is in one) and the region's id or class. Unlike
#: :func:`test_live_regions_speak_only_of_changes` (one observer per region found at the
#: start), one observer of the whole page: a list drawn anew replaces its regions.
LISTEN_JS = """(sel) => {
  window.said = [];
  const where = (r) => [r.closest('[data-recording]')?.dataset.recording,
                        r.id || r.getAttribute('class') || r.tagName].filter(Boolean).join(' ');
  new MutationObserver((records) => {
    for (const m of records) {
      const t = m.target.nodeType === 1 ? m.target : m.target.parentElement;
      const region = t && t.closest(sel);
      if (region) {
        const added = m.type === 'characterData' ? m.target.data
          : [...m.addedNodes].map((n) => n.textContent).join('');
        if (added.trim()) window.said.push([where(region), region.textContent.trim()]);
        continue;
      }
      for (const n of m.addedNodes) {
        if (n.nodeType !== 1) continue;
        for (const a of [n, ...n.querySelectorAll('[role=alert]')])
          if (a.matches('[role=alert]') && a.textContent.trim())
            window.said.push([where(a), a.textContent.trim()]);
      }
    }
  }).observe(document.body, {childList: true, subtree: true, characterData: true});
}"""


def test_subjects_list_speaks_only_of_a_state_change(page: Any, lab: Lab,
                                                     artifacts_dir: Path) -> None:
    """The Subjects page draws its list again every second while a recording is busy. A
    drawing that changes nothing says nothing (the list was one live region, read out again
    at each drawing), a refusal beside *Delete recording* is said once and stays with the
    code typed and the focus, and a recording whose state changes says its name and new
    state, no more."""
    code = "LIVE05"
    project_id = lab.api(f"/api/subjects/{lab.subject_id}")["project_id"]
    subject = lab.api("/api/subjects", {"project_id": project_id, "code": code})
    session = lab.api("/api/sessions", {"subject_id": subject["id"], "label": "busy"})
    rec_id = ""
    try:
        rec_id = str(lab.api(f"/api/sessions/{session['id']}/recordings",
                             {"label": "busy walk", "streams": [], "image_every": 3})["id"])
        row = f"#sessions [data-recording='{rec_id}']"
        page.goto(f"{lab.url}/subjects.html#subject={subject['id']}")
        _shown(page, f"{row}[data-state=recording]")
        drawn: list[str] = []  # the list's drawings: one per answer about the subject
        page.on("response", lambda r: drawn.append(r.url)
                if r.url.endswith(f"/api/subjects/{subject['id']}") else None)
        page.evaluate(LISTEN_JS, LIVE_SELECTOR)
        page.fill(f"{row} .actions input", "wrong")
        page.click(f"{row} button:text('Delete recording')")
        refusal = f"Not deleted: type {code} in the box first, then press Delete recording."
        _text(page, f"{row} [role=alert]", "Not deleted")
        deadline = time.time() + 60
        while len(drawn) < 4:  # drawn again (at least three times after the refusal)
            assert time.time() < deadline, f"the busy list was not drawn again: {drawn}"
            page.wait_for_timeout(200)
        page.evaluate("(s) => document.querySelector(s).scrollIntoView()", row)
        screenshot(page, artifacts_dir, "a11y_subjects_busy")
        said = page.evaluate("window.said")
        assert said == [[f"{rec_id} msg bad", refusal]], said
        # the delete box keeps what was typed and the focus, the refusal stays beside it
        assert page.evaluate("[document.activeElement.value, "
                             "document.activeElement.closest('[data-recording]')"
                             "?.dataset.recording]") == ["wrong", rec_id]
        assert page.inner_text(f"{row} [role=alert]") == refusal

        lab.api(f"/api/recordings/{rec_id}/stop", {}, method="POST")
        _shown(page, f"{row}[data-state=complete]")
        page.evaluate("(s) => document.querySelector(s).scrollIntoView()", row)
        screenshot(page, artifacts_dir, "a11y_subjects_complete")
        said = page.evaluate("window.said")[1:]
        states = {"busy walk on the nodes", "busy walk transferring", "busy walk complete"}
        assert said and said[-1] == [f"{rec_id} rec-title", "busy walk complete"], said
        assert all(w == f"{rec_id} rec-title" and s in states for w, s in said), said
        assert all(a != b for a, b in itertools.pairwise(said)), said  # each news once
        assert not page.js_errors, page.js_errors
    finally:
        if rec_id:
            with contextlib.suppress(urllib.error.HTTPError):  # (stopped already)
                lab.api(f"/api/recordings/{rec_id}/stop", {}, method="POST")
        with contextlib.suppress(urllib.error.HTTPError):  # (a failure above says why)
            lab.api(f"/api/subjects/{subject['id']}/delete", {"confirm": code})


def test_a_refused_password_is_read_once(page: Any, lab: Lab, artifacts_dir: Path) -> None:
    """A refusal in the change-password dialog is the field's description and the field
    takes the focus: read once, with the field (it was a live region too, and read twice).
    Where the field has the focus already (Enter pressed in it), the dialog's hidden live
    region says it, once, and again at a second press."""
    page.add_init_script(WATCH_FOCUS_JS)
    focus = Focus(page)
    page.goto(lab.url + "/rig.html")
    page.click(".user-menu summary")
    page.click("#password-open")
    _shown(page, "#password-dialog")
    page.evaluate(LISTEN_JS, LIVE_SELECTOR)
    page.click("#pw-submit")  # all empty: the focus goes from the button to the field
    _text(page, "#pw-current-msg", ".")
    focus.expect("Current password")
    description = focus.cdp.send("Accessibility.getPartialAXTree", {
        "objectId": focus.cdp.send("Runtime.evaluate", {
            "expression": "document.activeElement"})["result"]["objectId"],
        "fetchRelatives": False})["nodes"][0].get("description", {}).get("value")
    assert description == "Type your current password."
    assert page.evaluate("window.said") == []  # said with the field, as its description
    assert not _live_focus(page), _live_focus(page)
    screenshot(page, artifacts_dir, "a11y_password_refused_focus")
    for n in (1, 2):  # Enter in the field: the focus stays, the live region says it
        page.keyboard.press("Enter")
        page.wait_for_function("(n) => window.said.length >= n", arg=n)
    assert page.evaluate("window.said") == [["pw-said", "Type your current password."]] * 2
    assert page.evaluate("document.activeElement.id") == "pw-current"
    assert page.inner_text("#pw-current-msg") == "Type your current password."
    assert not _live_focus(page), _live_focus(page)
    assert not page.js_errors, page.js_errors
