"""Shared pytest fixtures: paths to ../shared/data and the artefact folder."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

# Console passwords are hashed at scrypt N = 2**14 in the suite (N = 2**17, the shipped
# default, costs up to a second per login on a loaded 2-core machine, and the suite logs in
# hundreds of times); servers and nodes started by tests inherit it. The default is tested
# in tests/app/test_security_review.py.
os.environ.setdefault("GAITRIG_PASSWORD_HASH_COST", "14")

ROOT = Path(__file__).resolve().parents[1]
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


@pytest.fixture
def browser() -> Iterator[Any]:
    """Headless Debian Chromium for one test.

    Every browser test uses this fixture: Playwright's sync API cannot start a second
    instance while one runs, and while one runs it keeps an asyncio loop running in the
    main thread (so ``asyncio.run`` in later tests would fail) — hence one per test,
    closed after it. Skips with a reason when Chromium or Playwright is missing; never
    downloads a browser.
    """
    if not CHROMIUM.exists():
        pytest.skip(f"{CHROMIUM} is missing: install Debian's chromium package to run "
                    "browser tests")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.skip("the playwright Python package is not installed")
    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS,
                               headless=True)
        throttle = float(os.environ.get("GAITRIG_TEST_CPU_THROTTLE") or 1)
        if throttle > 1:
            _throttle_pages(b, throttle)
        try:
            yield b
        finally:
            b.close()
