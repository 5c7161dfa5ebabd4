"""Shared pytest fixtures: paths to ../shared/data and the artefact folder."""

from __future__ import annotations

import asyncio
import contextlib
import os
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

# Console passwords are hashed at scrypt N = 2**10, the setting's floor, in the suite
# (N = 2**17, the shipped default, costs up to a second per login on a loaded 2-core
# machine; 2**14 still 25 ms of CPU, 2**10 1.5 ms, and the suite hashes at every app start
# and login, hundreds of times); servers and nodes started by tests inherit it. The
# default and the re-hash at a higher cost are tested in tests/app/test_security_review.py.
os.environ.setdefault("GAITRIG_PASSWORD_HASH_COST", "10")

ROOT = Path(__file__).resolve().parents[1]

# The suite starts a few hundred server and node processes. Where the environment forbids
# writing bytecode (PYTHONDONTWRITEBYTECODE, as on this project's CI machine), each of them
# compiled the project's ~120 modules again (≈ 0.15 s of CPU per process); the compiled
# files go to the git-ignored .pytest_cache instead of beside the sources.
if os.environ.pop("PYTHONDONTWRITEBYTECODE", None):
    os.environ.setdefault("PYTHONPYCACHEPREFIX", str(ROOT / ".pytest_cache" / "pycache"))
    sys.dont_write_bytecode = False
    sys.pycache_prefix = os.environ["PYTHONPYCACHEPREFIX"]
SHARED_DATA = ROOT.parent / "shared" / "data"
ARTIFACTS = ROOT / "test-artifacts"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Path to ../shared/data; skips the test with a clear reason when absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data not available: {SHARED_DATA} is absent (see shared/data/README.md)")
    return SHARED_DATA


@pytest.fixture(scope="session")
def artifacts_dir() -> Path:
    """Folder for screenshots, plots and reports kept after a run."""
    ARTIFACTS.mkdir(exist_ok=True)
    return ARTIFACTS


CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                 "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync"]


def _throttle_pages(browser: Any, rate: float) -> None:
    """Make every page of ``browser`` run its JavaScript ``rate`` times slower (CDP).

    A stress knob for hunting races (``GAITRIG_TEST_CPU_THROTTLE=6``): a page's answers
    then arrive and are handled late, as on a loaded 2-core CI machine, without burning
    the CPU that the servers and the other tests need.
    """
    new_context = browser.new_context

    def throttled_context(*args: Any, **kwargs: Any) -> Any:
        ctx = new_context(*args, **kwargs)
        new_page = ctx.new_page

        def throttled_page(*a: Any, **k: Any) -> Any:
            page = new_page(*a, **k)
            ctx.new_cdp_session(page).send("Emulation.setCPUThrottlingRate", {"rate": rate})
            return page

        ctx.new_page = throttled_page
        return ctx

    browser.new_context = throttled_context


def _bypass_csp_by_default(browser: Any) -> None:
    """Make the contexts of ``browser`` bypass the page's Content-Security-Policy unless a
    test asks otherwise (``new_context(bypass_csp=False)``), and drop their route
    handlers when they are closed (the browser outlives the test).

    Playwright's ``wait_for_function`` evaluates its predicate with ``eval`` inside the
    page, which the console's policy (no ``'unsafe-eval'``) refuses. The policy itself is
    checked by ``tests/browser/test_csp.py``, whose context does not bypass it.
    """
    new_context = browser.new_context

    def context(*args: Any, **kwargs: Any) -> Any:
        kwargs.setdefault("bypass_csp", True)
        ctx = new_context(*args, **kwargs)
        close = ctx.close

        def close_quietly(*a: Any, **k: Any) -> Any:
            # A route handler still running when its context closes fails in the shared
            # Playwright connection and surfaces in the next test's first call; let the
            # handlers go first, ignoring what they were doing.
            with contextlib.suppress(Exception):
                for pg in ctx.pages:
                    pg.unroute_all(behavior="ignoreErrors")
                ctx.unroute_all(behavior="ignoreErrors")
            return close(*a, **k)

        ctx.close = close_quietly
        return ctx

    browser.new_context = context


class _Chromium:
    """One headless Chromium (and its Playwright driver) for the whole session."""

    def __init__(self) -> None:
        from playwright.sync_api import sync_playwright

        self._pw_cm = sync_playwright()
        pw = self._pw_cm.__enter__()
        try:
            self.browser = pw.chromium.launch(executable_path=str(CHROMIUM),
                                              args=CHROMIUM_ARGS, headless=True)
        except BaseException:
            self._pw_cm.__exit__(None, None, None)
            raise
        # Playwright's sync API marks its asyncio loop as running in this thread after
        # every call (so that its dispatcher can resume it); between browser tests the
        # mark is taken off (see ``browser``), else ``asyncio.run`` in a later test fails.
        self.loop = self._pw_cm._loop
        throttle = float(os.environ.get("GAITRIG_TEST_CPU_THROTTLE") or 1)
        if throttle > 1:
            _throttle_pages(self.browser, throttle)
        _bypass_csp_by_default(self.browser)

    def enter(self) -> None:
        """Mark Playwright's loop as running again before a test drives the browser."""
        asyncio._set_running_loop(self.loop)

    def leave(self) -> None:
        """Close what the test left open (contexts hold cookies and pages) and unmark the
        loop, so the next test starts as with a fresh browser."""
        try:
            for ctx in list(self.browser.contexts):
                ctx.close()
        finally:
            asyncio._set_running_loop(None)

    def close(self) -> None:
        self.enter()
        try:
            self.browser.close()
        finally:
            self._pw_cm.__exit__(None, None, None)
            asyncio._set_running_loop(None)


@pytest.fixture(scope="session")
def _chromium() -> Iterator[_Chromium]:
    """The session's Chromium, started by the first test that needs a browser."""
    if not CHROMIUM.exists():
        pytest.skip(f"{CHROMIUM} is missing: install Debian's chromium package to run "
                    "browser tests")
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        pytest.skip("the playwright Python package is not installed")
    chromium = _Chromium()
    asyncio._set_running_loop(None)
    try:
        yield chromium
    finally:
        chromium.close()


@pytest.fixture
def browser(_chromium: _Chromium) -> Iterator[Any]:
    """Headless Debian Chromium for one test.

    One Chromium is started per session (starting the Playwright driver and Chromium
    costs seconds per test on a loaded machine); each test gets it with no context open,
    and every context it opened is closed after it, so tests share no cookies, storage
    or pages. Contexts bypass the Content-Security-Policy unless created with
    ``bypass_csp=False``. Skips with a reason when Chromium or Playwright is missing;
    never downloads a browser.
    """
    _chromium.enter()
    try:
        yield _chromium.browser
    finally:
        _chromium.leave()


#: Files of one worker's longest stretches (tens of seconds each, measured with
#: ``--durations=0``), started early by :func:`pytest_collection_modifyitems`.
_LONG_FILES = (
    "tests/engine/report/test_report_many_sessions.py",
    "tests/app/analysis/test_reports.py",
    "tests/app/data/test_record_flow.py",
    "tests/test_docs.py",
    "tests/engine/test_mocap_sweep.py",
    "tests/app/calibration/test_capture_lens_nodes.py",
    "tests/integration/test_node_features.py",
    "tests/app/data/test_transfer_faults.py",
    "tests/integration/test_node_warnings.py",
    "tests/integration/test_backup_live.py",
    "tests/engine/calibration/test_capture_check.py",
    "tests/integration/test_node_lens.py",
    "tests/app/data/test_subject_lifecycle.py",
    "tests/engine/report/test_report_scripts.py",
    "tests/app/calibration/test_wizard_browser.py",
    "tests/app/test_security_review.py",
    "tests/engine/report/test_report_clinical.py",
)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The order files are handed to ``make test``'s workers (``--dist loadfile
    --no-loadscope-reorder``): the browser tests first, one after another, then the
    long files, then the rest as collected.

    The browser tests share one live demo server per worker (package scope), which is
    stopped whenever a worker turns to a file of another folder and started again (≈ 10 s)
    at its next browser file: xdist's default order (by number of tests) interleaved them
    and started it 17 times. Long files go early so that the run does not end with one
    worker alone on one of them. Only the order changes; a file's tests stay together and
    in their order (a stable sort).
    """
    long_rank = {name: i for i, name in enumerate(_LONG_FILES)}

    def rank(item: pytest.Item) -> tuple[int, int]:
        path = item.nodeid.split("::", 1)[0]
        if path.startswith("tests/browser/"):
            return (0, 0)
        if path in long_rank:
            return (1, long_rank[path])
        return (2, 0)

    items.sort(key=rank)
