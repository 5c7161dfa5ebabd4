"""The printable marker sheet: time to draw it, vectors against bitmaps, and the server's
cache.

The wizard's "Download the marker sheet" took 12–20 s on a loaded lab machine: every
marker went into the PDF as a 300 dpi bitmap (2 362² pixels for a 20 cm marker) that
matplotlib resampled, colour-mapped and compressed. The sheet now draws each marker's
black cells as one vector path (``engine.calibration.markers.marker_path_m``), and
``GET /api/calibration/markers.pdf`` keeps the last sheets it drew (a few kB each).

Measured in the same run, on the wizard's default sheet (ids 1-8, 20 cm, A4: eight pages):

* ``bitmap_s``: the peer, the previous drawing (same layout, markers as 300 dpi bitmaps
  through ``imshow``);
* ``vector_s``: ``write_marker_sheet`` as it is now; ``speedup`` = bitmap_s / vector_s;
* ``route_first_s`` / ``route_cached_s``: the API's sheet function, first and second
  request for the same parameters.

Each figure is the median of ``REPS`` runs after one warm-up (matplotlib imported). Prints
one JSON line.
"""

from __future__ import annotations

import json
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

REPS = 3
IDS, SIZE_M, PAPER, DPI = "1-8", 0.20, "a4", 300


def _bitmap_sheet(path: Path) -> None:
    """The peer: the same pages with every marker embedded as a 300 dpi bitmap."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.backends.backend_pdf import PdfPages
    from matplotlib.figure import Figure

    from engine.calibration.markers import PAPER_SIZES_M, marker_image, parse_ids

    pw, ph = PAPER_SIZES_M[PAPER]
    px = round(SIZE_M / 0.0254 * DPI)
    with PdfPages(path) as pdf:
        for mid in parse_ids(IDS):  # one 20 cm marker per A4 page
            fig = Figure(figsize=(pw / 0.0254, ph / 0.0254), dpi=DPI)
            ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
            ax.set_xlim(0, pw)
            ax.set_ylim(0, ph)
            ax.set_axis_off()
            x0, y1 = (pw - SIZE_M) / 2, ph - 0.01
            ax.imshow(marker_image(mid, px), cmap="gray", vmin=0, vmax=255,
                      interpolation="nearest", extent=(x0, x0 + SIZE_M, y1 - SIZE_M, y1))
            ax.text(pw / 2, y1 - SIZE_M - 0.002, f"id {mid}", ha="center", va="top",
                    fontsize=7)
            pdf.savefig(fig)


def _vector_sheet(path: Path) -> None:
    from engine.calibration.markers import write_marker_sheet

    write_marker_sheet(IDS, SIZE_M, path, paper=PAPER)


def _median_s(fn: Callable[[], object]) -> float:
    times = []
    for _ in range(REPS):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def main() -> None:
    """Measure and print one JSON line."""
    from app.api.routes.calibration import _marker_sheet_pdf
    from engine.calibration.markers import parse_ids

    with tempfile.TemporaryDirectory() as d:
        bitmap_pdf, vector_pdf = Path(d) / "bitmap.pdf", Path(d) / "vector.pdf"
        _vector_sheet(vector_pdf)  # warm-up: imports, fonts
        _bitmap_sheet(bitmap_pdf)
        bitmap_s = _median_s(lambda: _bitmap_sheet(bitmap_pdf))
        vector_s = _median_s(lambda: _vector_sheet(vector_pdf))
        sizes = (bitmap_pdf.stat().st_size, vector_pdf.stat().st_size)
    ids = tuple(parse_ids(IDS))
    _marker_sheet_pdf.cache_clear()
    t = time.perf_counter()
    _marker_sheet_pdf(ids, SIZE_M, "DICT_4X4_50", PAPER)
    route_first_s = time.perf_counter() - t
    route_cached_s = _median_s(lambda: _marker_sheet_pdf(ids, SIZE_M, "DICT_4X4_50", PAPER))
    print(json.dumps({
        "bench": "marker_sheet", "sheet": f"ids {IDS}, {SIZE_M * 100:.0f} cm, {PAPER}",
        "bitmap_s": round(bitmap_s, 3), "vector_s": round(vector_s, 3),
        "speedup": round(bitmap_s / vector_s, 1),
        "bitmap_pdf_bytes": sizes[0], "vector_pdf_bytes": sizes[1],
        "route_first_s": round(route_first_s, 3), "route_cached_s": round(route_cached_s, 6),
    }))


if __name__ == "__main__":
    main()
