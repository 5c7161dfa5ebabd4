"""The printable marker sheet drawn as vectors: every cell where the dictionary puts it,
exact at any resolution, and the PDF free of bitmaps (they made it slow to draw)."""

from __future__ import annotations

import re
import shutil
import subprocess
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from engine.calibration.detect import detect_markers
from engine.calibration.markers import (
    marker_cells,
    marker_image,
    marker_path_m,
    write_marker_sheet,
)
from engine.errors import InputError


@pytest.mark.parametrize(("marker_id", "dictionary"), [(1, "DICT_4X4_50"), (7, "DICT_4X4_50"),
                                                      (3, "DICT_6X6_250"),
                                                      (5, "DICT_APRILTAG_36h11")])
def test_cells_and_outline_match_the_dictionary(marker_id: int, dictionary: str) -> None:
    """The outline covers exactly the black cells of OpenCV's own marker image."""
    black = marker_cells(marker_id, dictionary)
    n = black.shape[0]
    img = marker_image(marker_id, n * 10, dictionary)
    assert np.array_equal(black, img[5::10, 5::10] < 128)
    assert black[0].all() and black[-1].all() and black[:, 0].all()  # the black border
    verts, codes = marker_path_m(marker_id, 0.2, 0.01, 0.25, dictionary)
    rects = verts.reshape(-1, 5, 2)
    assert len(codes) == 5 * len(rects)
    # paint the rectangles back onto the cell grid: every black cell once, no white one
    painted = np.zeros((n, n), int)
    cell = 0.2 / n
    for r in rects:
        (x0, y0), (x1, y1) = r[0], r[2]
        c0, c1 = round((x0 - 0.01) / cell), round((x1 - 0.01) / cell)
        row = round((0.25 - y1) / cell)
        assert round((y1 - y0) / cell) == 1 and c1 > c0
        painted[row, c0:c1] += 1
    assert np.array_equal(painted, black.astype(int))
    with pytest.raises(InputError, match="outside"):
        marker_cells(60, "DICT_4X4_50")


def test_png_page_of_eight_markers_is_detected_at_true_size(tmp_path: Path) -> None:
    """Eight 5 cm markers on one A4 page: all found, each 5 cm wide at 300 dpi."""
    files = write_marker_sheet("1-8", 0.05, tmp_path / "m.png", dpi=300)
    assert len(files) == 1
    # (the detector's corners: ±0.8 mm at 5 cm)
    _assert_eight_markers_of_5_cm(files[0], dpi=300, tol_m=0.001)


def _assert_eight_markers_of_5_cm(png: Path, dpi: int, tol_m: float) -> None:
    """The page image ``png`` (at ``dpi``) shows markers 1-8, each edge 5 cm ± ``tol_m``."""
    img = cv2.imread(str(png), cv2.IMREAD_GRAYSCALE)
    ds = detect_markers(img)
    assert ds.ids == list(range(1, 9))
    for m in ds.markers:
        c = m.corners_px
        edge_m = np.linalg.norm(c - np.roll(c, -1, axis=0), axis=1).mean() / dpi * 0.0254
        assert abs(edge_m - 0.05) < tol_m, (m.id, edge_m)


def _streams(pdf: bytes) -> list[bytes]:
    """The PDF's content streams, inflated."""
    out = []
    for m in re.finditer(rb"stream\r?\n(.*?)endstream", pdf, flags=re.DOTALL):
        try:
            out.append(zlib.decompress(m.group(1)))
        except zlib.error:
            out.append(m.group(1))
    return out


def test_pdf_has_vector_markers_and_no_bitmaps(tmp_path: Path) -> None:
    out = tmp_path / "markers.pdf"
    write_marker_sheet("1-4", 0.10, out)
    data = out.read_bytes()
    assert b"/Subtype /Image" not in data
    assert len(data) < 200_000  # eight 2 400² bitmaps made it a slow, large file
    # the page draws filled paths (`re`/`m ... l ... h` then `f`)
    assert any(b" f\n" in s or b"\nf\n" in s for s in _streams(data))


@pytest.mark.skipif(shutil.which("pdftoppm") is None,
                    reason="pdftoppm (poppler-utils) not installed: the PDF is not rasterised")
def test_pdf_rasterised_by_another_renderer_is_detected(tmp_path: Path) -> None:
    """What a printer gets: the PDF drawn by poppler shows every marker, at true size."""
    out = tmp_path / "markers.pdf"
    write_marker_sheet("1-8", 0.05, out)
    subprocess.run(["pdftoppm", "-r", "200", "-gray", "-png", str(out), str(tmp_path / "p")],
                   check=True, timeout=60)
    pages = sorted(tmp_path.glob("p*.png"))
    assert len(pages) == 1
    _assert_eight_markers_of_5_cm(pages[0], dpi=200, tol_m=0.0012)
