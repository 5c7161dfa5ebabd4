"""The Reports page's upload route takes ``gaitrig gait``'s ankle options as query
parameters (``ankle_markers``, ``ankle_width_mm``), as it takes ``left``/``right``/``up``,
and refuses bad values with a 422 that says what to fix."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from engine.io.trc import write_trc
from tests.app.mocap_files import upload_for_report
from tests.engine.test_mocap_ankle_options import _markers, _walk


@pytest.fixture(scope="module")
def trc(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    p = tmp_path_factory.mktemp("ankle") / "bare.trc"
    write_trc(p, _markers(_walk(), "#_Ankle", lateral=True), units="mm")
    return p.read_bytes()


def _upload(client: TestClient, data: bytes, query: str) -> tuple[int, str]:
    return upload_for_report(client, data, "bare.trc", "UP1", query)


def test_upload_with_ankle_options(admin_client: TestClient, trc: bytes) -> None:
    code, text = _upload(admin_client, trc, "ankle_markers=lateral&ankle_width_mm=60,84")
    assert code == 200, text
    assert "as asked (ankle markers: lateral)" in text


@pytest.mark.parametrize(("query", "words"), [
    ("ankle_width_mm=7", "an ankle width of 7 mm (both feet) is outside 40-150 mm"),
    ("ankle_width_mm=abc", "ankle_width_mm 'abc' is not a width in mm"),
    ("ankle_markers=joint&ankle_width_mm=70", "leave one of the two out"),
    ("ankle_width_mm=70", "give --ankle-markers lateral if they are on the lateral malleoli"),
    ("ankle_markers=medial", "ankle_markers"),
])
def test_bad_ankle_options_are_refused(admin_client: TestClient, trc: bytes, query: str,
                                       words: str) -> None:
    code, text = _upload(admin_client, trc, query)
    assert code == 422, text
    assert words in text, text
