"""A clinic's lists in a real browser: among hundreds of subjects a person finds one by
typing part of its code (Subjects, Record and Reports pages), pages through the Subjects
list and reorders it, with the keyboard. A server of its own (no nodes) on a data folder
filled through the database layer (``bench/_clinic.py``)."""

from __future__ import annotations

import os
import secrets
import shutil
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from bench._clinic import populate, subject_code
from tests.browser.conftest import login, new_page, serve_without_nodes

pytestmark = pytest.mark.browser

N_SUBJECTS = 600  # 150 per project (populate's round robin over four)


@dataclass
class Clinic:
    """The server of a populated clinic (what :func:`login` needs)."""

    base_url: str
    password: str


@pytest.fixture(scope="module")
def clinic() -> Iterator[Clinic]:
    tmp = Path(tempfile.mkdtemp(prefix="gaitrig-scale-"))
    populate(tmp / "data", N_SUBJECTS, recordings_per_subject=2, n_with_files=40)
    password = secrets.token_urlsafe(9)
    try:
        with serve_without_nodes(tmp / "data", {**os.environ, "GAITRIG_ADMIN_PASSWORD": password}
                                 ) as (url, _log):
            yield Clinic(url, password)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


@pytest.fixture
def page(browser: Any, clinic: Clinic) -> Iterator[Any]:
    p = new_page(browser, 15000)
    try:
        login(p, clinic)  # type: ignore[arg-type]
        yield p
    finally:
        p.context.close()


def _codes(page: Any) -> list[str]:
    return [str(c) for c in page.eval_on_selector_all(
        "#subjects tr[data-subject]", "rows => rows.map(r => r.dataset.subject)")]


def test_find_page_and_sort_subjects(page: Any, clinic: Clinic) -> None:
    page.goto(clinic.base_url + "/subjects.html")
    # the first page of project 1 (codes 1, 5, 9, … by populate's round robin), in code order
    page.wait_for_selector("#subjects tr[data-subject]")
    first = [subject_code(k) for k in range(1, N_SUBJECTS + 1, 4)]
    assert _codes(page) == first[:50]
    count = page.locator("#subjects-count")
    assert count.inner_text() == "Subjects 1–50 of 150."
    assert page.locator("#subjects-prev").is_disabled()
    # page through with the keyboard
    page.focus("#subjects-next")
    page.keyboard.press("Enter")
    page.wait_for_function("document.querySelector('#subjects-count').textContent"
                           ".startsWith('Subjects 51–100 of 150')")
    assert _codes(page) == first[50:100]
    # reorder: newest first
    page.select_option("#subject-sort", "-created")
    page.wait_for_function("document.querySelector('#subjects-count').textContent"
                           ".startsWith('Subjects 1–50')")
    assert _codes(page)[0] == first[-1]
    # find one subject by typing part of its code (label-named field), open it
    want = subject_code(413)  # in project 1
    page.get_by_label("Find by code").fill(want[-3:])
    page.wait_for_function(f"document.querySelector('#subjects-count').textContent"
                           f".includes('“{want[-3:]}”')")
    assert want in _codes(page) and len(_codes(page)) <= 5
    page.locator(f'#subjects tr[data-subject="{want}"] a').press("Enter")
    page.wait_for_function(f"document.querySelector('#detail-h').textContent === "
                           f"'Subject {want}'")
    # nothing matches: said so
    page.get_by_label("Find by code").fill("ZZZ")
    page.wait_for_function("document.querySelector('#subjects-count').textContent"
                           ".includes('No subject code contains')")
    assert _codes(page) == []
    # a code of another project: said where it is, and one activation opens it there
    other = subject_code(414)  # project 2
    page.get_by_label("Find by code").fill(other)
    page.get_by_role("link", name=f"open {other}").press("Enter")
    page.wait_for_function(f"document.querySelector('#detail-h').textContent === "
                           f"'Subject {other}'")
    assert page.input_value("#project") == "2"
    assert page.js_errors == []


def test_find_a_subject_to_record_and_report(page: Any, clinic: Clinic) -> None:
    want = subject_code(201)  # project 1; not among the newest listed at first
    page.goto(clinic.base_url + "/record.html")
    page.wait_for_function("document.querySelectorAll('#subject option').length > 1")
    assert "type part of the code" in page.inner_text("#subject-count")
    page.get_by_label("Find subject code").fill(want)
    page.keyboard.press("Enter")
    page.wait_for_function(f"document.querySelector('#subject').selectedOptions[0]?.text "
                           f"=== '{want}'")
    page.wait_for_function("document.querySelectorAll('#session option').length >= 1 && "
                           "document.querySelector('#session').value !== ''")

    page.goto(clinic.base_url + "/reports.html")
    page.wait_for_function("document.querySelectorAll('#subject option').length > 1")
    has_it = ("[...document.querySelectorAll('#subject option')]"
              f".some(o => o.text.startsWith('{want} '))")
    assert not page.evaluate(has_it)
    assert "type part of the code" in page.inner_text("#subject-count")
    page.get_by_label("Find subject code").fill(want[2:])
    # "Choose a subject…" and the one subject whose code holds the text
    page.wait_for_function("document.querySelectorAll('#subject option').length === 2")
    assert page.evaluate(has_it)
    assert "1 subject found" in page.inner_text("#subject-count")
    page.select_option("#subject", label=page.locator("#subject option").nth(1).inner_text())
    page.wait_for_function("document.querySelectorAll('#session option').length > 1")
    assert page.js_errors == []
