""""Analyse a file" (``POST /api/reports/upload``) takes ``gaitrig gait``'s options for
files from other labs (``up``, ``units``, ``left``/``right``, ankle options) and they reach
the analysis: a file whose vertical axis cannot be detected is refused without ``up`` and
analysed with it. A refusal asked for by the Reports page (``advice=form``) names the
page's fields under "Options for files from other labs", not the command line's flags
("give it with --up"), which the CLI and the API's default keep."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.api.routes.reports import FILE_OPTIONS
from engine.io.markers import MarkerTrajectories
from engine.io.trc import write_trc
from engine.sim.straight_walk import synth_walk
from tests.app.mocap_files import upload_for_report


def ambiguous_up_trc(path: Path) -> Path:
    """Ankle, heel and toe markers of a walk along Y whose heights are copied into the
    lateral axis X: the still feet stand at one level along X and Z, so the vertical
    axis cannot be told from them (it is Z)."""
    w = synth_walk(n_steps=12, rate=100.0, heading_deg=90.0, origin=(1.0, 0.5, 0.0))
    names: list[str] = []
    pts: list[np.ndarray] = []
    for side in ("L", "R"):
        for part, lab in (("ankle", "ANK"), ("heel", "HEE"), ("toe", "TOE")):
            names.append(side + lab)
            pts.append(w.joints[f"{part}{side}"])
    P = np.stack(pts, axis=1)
    P[..., 0] = P[..., 2] + 1.0
    write_trc(path, MarkerTrajectories(w.times, P, names, 100.0, "m", meta={}), units="mm")
    return path


@pytest.fixture(scope="module")
def trc(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    return ambiguous_up_trc(tmp_path_factory.mktemp("up") / "other lab.trc").read_bytes()


def _upload(client: TestClient, data: bytes, query: str) -> tuple[int, str]:
    return upload_for_report(client, data, "other lab.trc", "OL1", query)


def test_vertical_axis_reaches_the_analysis(admin_client: TestClient, trc: bytes) -> None:
    code, text = _upload(admin_client, trc, "")
    assert code == 422, text
    assert "cannot tell the vertical axis" in text and "give it with --up, e.g. --up" in text
    code, text = _upload(admin_client, trc, "advice=form")
    assert code == 422, text
    assert "--up" not in text, text
    assert f"choose the vertical axis under '{FILE_OPTIONS}', e.g. " in text, text
    code, text = _upload(admin_client, trc, "up=z&advice=form")
    assert code == 200, text
    assert "Walking speed" in text


def test_units_reach_the_analysis(admin_client: TestClient, trc: bytes) -> None:
    """The file is in mm: read as metres the body is a thousand times too big."""
    code, text = _upload(admin_client, trc, "up=z&units=m")
    assert code == 422 and "with --units m the body measures" in text, text
    assert "fix --units or leave it out" in text, text
    code, text = _upload(admin_client, trc, "up=z&units=m&advice=form")
    assert code == 422 and "with the units m the body measures" in text, text
    assert f"choose other units under '{FILE_OPTIONS}', or Automatic" in text, text
    assert "--units" not in text, text
    code, text = _upload(admin_client, trc, "up=z&units=mm")
    assert code == 200, text


def test_foot_markers_reach_the_analysis(admin_client: TestClient, trc: bytes) -> None:
    code, text = _upload(admin_client, trc, "up=z&left=LHEE&advice=form")
    assert code == 422, text
    assert f"give both the left and the right foot marker under '{FILE_OPTIONS}'" in text
    code, text = _upload(admin_client, trc, "up=z&left=LHEE&right=RHEE")
    assert code == 200, text
