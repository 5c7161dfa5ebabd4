"""Fiducial markers: dictionaries, marker images, the marker frame, printable sheets.

Dictionary choice: the default is ArUco ``DICT_4X4_50``. A 4×4 code has the largest cells
for a given printed size (6×6 cells with the border), so markers lying on the floor stay
decodable at 4–5 m from a Kinect colour camera, and 50 ids are plenty for a gait lab;
its minimum Hamming distance keeps false ids rare. ``DICT_APRILTAG_36h11`` (more robust
to false positives, smaller cells) and any other OpenCV predefined dictionary are accepted
by name (``"DICT_6X6_250"``, ``"6x6_250"``, ``"apriltag_36h11"`` …).

Marker frame (shared by detection, 3D corners and the calibration): origin at the marker
centre, +X to the right of the printed image, +Y towards the top of the image, +Z out of
the paper. A marker lying on the floor therefore has Z up, and marker 1 defines the world
frame (MISSION.md: right-handed, Z up, origin at marker 1). Corner order is OpenCV's:
top-left, top-right, bottom-right, bottom-left.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from engine.errors import InputError

FloatArray = NDArray[np.float64]

DEFAULT_DICTIONARY = "DICT_4X4_50"

#: Paper sizes in metres (width, height), portrait.
PAPER_SIZES_M: dict[str, tuple[float, float]] = {
    "a4": (0.210, 0.297),
    "letter": (0.2159, 0.2794),
    "a3": (0.297, 0.420),
}

_INCH = 0.0254
_TEXT_H_M = 0.017  # id/size caption under each marker
_BOTTOM_BAND_M = 0.02  # scale bar and page footer


def dictionary_name(name: str) -> str:
    """Canonical OpenCV name (``DICT_...``) for a user-given dictionary name.

    Args:
        name: ``"DICT_4X4_50"``, ``"4x4_50"``, ``"aruco_original"`` ... in any case.

    Returns:
        The ``cv2.aruco`` attribute name.

    Raises:
        InputError: unknown dictionary (the message lists the valid names).
    """
    key = name.strip().upper().replace("-", "_")
    if not key.startswith("DICT_"):
        key = "DICT_" + key
    if not hasattr(cv2.aruco, key) or not isinstance(getattr(cv2.aruco, key), int):
        valid = sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_") and n.upper() == n)
        raise InputError(f"unknown marker dictionary {name!r}; use one of {', '.join(valid)}")
    return key


def get_dictionary(name: str = DEFAULT_DICTIONARY) -> cv2.aruco.Dictionary:
    """The OpenCV predefined dictionary named ``name`` (see :func:`dictionary_name`).

    Args:
        name: A dictionary name (``"DICT_4X4_50"``, ``"4x4_50"`` ...).

    Returns:
        The ``cv2.aruco.Dictionary``.

    Raises:
        InputError: unknown dictionary (the message lists the valid names).
    """
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary_name(name)))


def dictionary_size(name: str = DEFAULT_DICTIONARY) -> int:
    """Number of distinct ids in a dictionary.

    Args:
        name: Marker dictionary name.

    Returns:
        The number of ids (ids run from 0).

    Raises:
        InputError: unknown dictionary.
    """
    return int(get_dictionary(name).bytesList.shape[0])


def marker_model_corners(size_m: float) -> FloatArray:
    """The four corners (4, 3) of a marker of edge ``size_m`` in the marker frame.

    Order TL, TR, BR, BL as detected by OpenCV; z = 0.

    Args:
        size_m: Edge length of the black square, m.

    Returns:
        ``(4, 3)`` corners, m.

    Raises:
        InputError: non-positive size.
    """
    if not size_m > 0:
        raise InputError(f"marker size must be positive (metres), got {size_m}")
    h = size_m / 2.0
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])


def marker_image(
    marker_id: int, px: int = 600, dictionary: str = DEFAULT_DICTIONARY, border_bits: int = 1
) -> NDArray[np.uint8]:
    """Square grey image (px × px, uint8) of one marker, black border included.

    Args:
        marker_id: Id in the dictionary.
        px: Image edge, pixels.
        dictionary: Marker dictionary name.
        border_bits: Width of the black border, in cells.

    Returns:
        ``(px, px)`` uint8 image, 0 = black, 255 = white.

    Raises:
        InputError: id outside the dictionary or too few pixels for the code.
    """
    d = get_dictionary(dictionary)
    n = int(d.bytesList.shape[0])
    if not 0 <= marker_id < n:
        raise InputError(
            f"marker id {marker_id} is outside {dictionary_name(dictionary)} (0..{n - 1})"
        )
    cells = int(d.markerSize) + 2 * border_bits
    if px < cells:
        raise InputError(f"need at least {cells} pixels for this dictionary, got {px}")
    img = cv2.aruco.generateImageMarker(d, int(marker_id), int(px), borderBits=border_bits)
    return np.asarray(img, dtype=np.uint8)


def marker_cells(marker_id: int, dictionary: str = DEFAULT_DICTIONARY,
                 border_bits: int = 1) -> NDArray[np.bool_]:
    """The marker's cells, black border included: ``(n, n)`` bools, True = black, row 0 at
    the top of the printed image.

    Args:
        marker_id: Id in the dictionary.
        dictionary: Marker dictionary name.
        border_bits: Width of the black border, in cells.

    Returns:
        ``(n, n)`` bools.

    Raises:
        InputError: id outside the dictionary.
    """
    d = get_dictionary(dictionary)
    cells = int(d.markerSize) + 2 * border_bits
    return marker_image(marker_id, cells, dictionary, border_bits) < 128


def marker_path_m(marker_id: int, size_m: float, x_m: float, y_top_m: float,
                  dictionary: str = DEFAULT_DICTIONARY) -> tuple[FloatArray, NDArray[np.uint8]]:
    """The black cells of a marker as one vector outline, for a printed sheet.

    Each row's runs of black cells become one rectangle (counter-clockwise, none
    overlapping), all in one compound path: a single fill, so a viewer or printer draws
    no hairline seam between neighbouring cells, and the edges are exact at any zoom or
    printer resolution (a bitmap was 2 400² pixels per 20 cm marker, slow to embed).

    Args:
        marker_id: Id in ``dictionary``.
        size_m: Edge length of the black square (m).
        x_m: Left edge of the square on the page (m, x to the right).
        y_top_m: Top edge of the square on the page (m, y up the page).
        dictionary: Dictionary name.

    Returns:
        ``(vertices, codes)`` as :class:`matplotlib.path.Path` takes them: vertices
        ``(k, 2)`` in metres on the page, codes ``(k,)`` (MOVETO, LINETO ×3, CLOSEPOLY
        per rectangle).
    """
    black = marker_cells(marker_id, dictionary)
    n = black.shape[0]
    cell = size_m / n
    # runs of black cells per row: where a row switches white→black and black→white
    padded = np.pad(black, ((0, 0), (1, 1))).astype(np.int8)
    change = np.diff(padded, axis=1)
    rows, starts = np.nonzero(change == 1)
    _, stops = np.nonzero(change == -1)  # same row order (row-major scan), one per start
    x0 = x_m + starts * cell
    x1 = x_m + stops * cell
    y1 = y_top_m - rows * cell
    y0 = y1 - cell
    verts = np.stack([np.stack([x0, y0], 1), np.stack([x1, y0], 1), np.stack([x1, y1], 1),
                      np.stack([x0, y1], 1), np.stack([x0, y0], 1)], axis=1).reshape(-1, 2)
    one = np.array([1, 2, 2, 2, 79], dtype=np.uint8)  # Path.MOVETO, LINETO, CLOSEPOLY
    return verts.astype(np.float64), np.tile(one, len(rows))


def parse_ids(spec: str | Iterable[int]) -> list[int]:
    """Parse ``"1-8"``, ``"1,3,5-7"`` (or an iterable of ints) into a sorted unique list.

    Args:
        spec: The ids as text or integers.

    Returns:
        Sorted unique ids.

    Raises:
        InputError: malformed text, negative ids or reversed ranges.
    """
    if not isinstance(spec, str):
        ids = [int(i) for i in spec]
    else:
        ids = []
        for part in (p.strip() for p in spec.split(",")):
            if not part:
                continue
            m = re.fullmatch(r"(\d+)\s*(?:-\s*(\d+))?", part)
            if not m:
                raise InputError(f"cannot read marker ids {part!r}; write e.g. 1-8 or 1,2,5")
            a = int(m.group(1))
            b = int(m.group(2)) if m.group(2) else a
            if b < a:
                raise InputError(f"range {part!r} is reversed; write {b}-{a}")
            ids.extend(range(a, b + 1))
    if not ids:
        raise InputError("no marker ids given")
    if min(ids) < 0:
        raise InputError("marker ids must be ≥ 0")
    return sorted(set(ids))


def _sheet_layout(
    size_m: float, paper: str, margin_m: float
) -> tuple[float, float, int, int, float]:
    """Paper width/height (portrait or landscape, whichever holds more markers), the grid
    (cols, rows) of markers and the white gap between neighbouring markers.

    The unprinted paper margin is white, so it doubles as the quiet zone on the outside.
    """
    try:
        pw0, ph0 = PAPER_SIZES_M[paper.lower()]
    except KeyError as exc:
        raise InputError(f"unknown paper {paper!r}; use one of {', '.join(PAPER_SIZES_M)}") from exc
    gap = max(size_m / 6.0, 0.01)  # ≥ one code cell of white between markers
    best: tuple[float, float, int, int, float] | None = None
    for pw, ph in ((pw0, ph0), (ph0, pw0)):
        usable_w = pw - 2 * margin_m + 1e-9
        usable_h = ph - 2 * margin_m - _BOTTOM_BAND_M + 1e-9
        cols = int((usable_w + gap) // (size_m + gap))
        rows = int((usable_h + gap) // (size_m + _TEXT_H_M + gap))
        if cols >= 1 and rows >= 1 and (best is None or cols * rows > best[2] * best[3]):
            best = (pw, ph, cols, rows, gap)
    if best is None:
        raise InputError(
            f"a {size_m * 100:.1f} cm marker does not fit on {paper.upper()} paper with "
            f"{margin_m * 1000:.0f} mm margins; choose a smaller --size or --paper a3"
        )
    return best


def write_marker_sheet(
    ids: Sequence[int] | str,
    size_m: float,
    path: str | Path,
    dictionary: str = DEFAULT_DICTIONARY,
    paper: str = "a4",
    margin_m: float = 0.005,
    dpi: int = 300,
) -> list[Path]:
    """Write a printable sheet of markers at TRUE SIZE.

    Every page carries as many markers as fit, each with its id and edge length printed
    under it, a 10 cm scale bar to check the printer did not rescale, and marker 1 (when
    present) gets its X (red) and Y (green) axes drawn under it.

    Args:
        ids: Marker ids (or a spec such as ``"1-8"``).
        size_m: Printed edge length of the black square (m).
        path: ``.pdf`` (one multi-page file) or ``.png`` (one file per page,
            ``name_p2.png`` for page 2 …).
        dictionary: Dictionary name.
        paper: ``"a4"``, ``"letter"`` or ``"a3"``.
        margin_m: Page margin (m); printers rarely print closer than 5 mm to the edge.
        dpi: Resolution of PNG output (a PDF draws the markers as vectors).

    Returns:
        The files written.

    Raises:
        InputError: bad ids, size, paper or file suffix.
    """
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.backends.backend_pdf import PdfPages
    from matplotlib.figure import Figure
    from matplotlib.patches import PathPatch
    from matplotlib.path import Path as MplPath

    id_list = parse_ids(ids)
    out = Path(path)
    suffix = out.suffix.lower()
    if suffix not in (".pdf", ".png"):
        raise InputError(f"marker sheet must be .pdf or .png, got {out.name!r}")
    dname = dictionary_name(dictionary)
    n_dict = dictionary_size(dname)
    bad = [i for i in id_list if i >= n_dict]
    if bad:
        raise InputError(f"ids {bad} are outside {dname} (0..{n_dict - 1})")
    pw, ph, cols, rows, gap = _sheet_layout(size_m, paper, margin_m)
    per_page = cols * rows
    pages = [id_list[i : i + per_page] for i in range(0, len(id_list), per_page)]
    cell_w = size_m + gap
    cell_h = size_m + _TEXT_H_M + gap

    def draw_page(page_ids: list[int], page_no: int) -> Figure:
        fig = Figure(figsize=(pw / _INCH, ph / _INCH), dpi=dpi)
        ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
        ax.set_xlim(0, pw)
        ax.set_ylim(0, ph)  # axes in metres, origin bottom-left: everything at true size
        ax.set_axis_off()
        x0 = (pw - (cols * cell_w - gap)) / 2.0  # centre the grid horizontally
        used_h = rows * cell_h - gap
        y_top = ph - margin_m - max(0.0, (ph - 2 * margin_m - _BOTTOM_BAND_M - used_h) / 2.0)
        for k, mid in enumerate(page_ids):
            r, c = divmod(k, cols)
            cx = x0 + c * cell_w
            cy_top = y_top - r * cell_h
            verts, codes = marker_path_m(mid, size_m, cx, cy_top, dname)
            ax.add_patch(PathPatch(MplPath(verts, codes), facecolor="black",
                                   edgecolor="none", linewidth=0))
            ax.text(cx + size_m / 2, cy_top - size_m - 0.002,
                    f"{dname}  id {mid}   edge {size_m * 100:.1f} cm",
                    ha="center", va="top", fontsize=7)
            if mid == 1:
                # world axes glyph below the marker (never touching it: coloured ink next to
                # the black border would break detection): X right, Y up the page, Z out
                ox, oy = cx + 0.002, cy_top - size_m - _TEXT_H_M + 0.0015
                ax.annotate("", xy=(ox + 0.010, oy), xytext=(ox, oy),
                            arrowprops={"color": "red", "width": 0.6, "headwidth": 3,
                                        "headlength": 3, "shrink": 0.0})
                ax.annotate("", xy=(ox, oy + 0.006), xytext=(ox, oy),
                            arrowprops={"color": "green", "width": 0.6, "headwidth": 3,
                                        "headlength": 3, "shrink": 0.0})
                ax.text(ox + 0.011, oy, "X    marker 1 = world origin, Z up out of the paper",
                        color="red", va="center", fontsize=5)
                ax.text(ox + 0.001, oy + 0.006, "Y", color="green", va="center", fontsize=5)
        # 10 cm scale bar: measure it after printing to verify "actual size" printing
        bx, by = margin_m + 0.005, margin_m + 0.006
        ax.plot([bx, bx + 0.10], [by, by], color="black", linewidth=2)
        for t in np.linspace(0, 0.10, 11):
            ax.plot([bx + t, bx + t], [by, by + (0.004 if t in (0, 0.05, 0.10) else 0.002)],
                    color="black", linewidth=0.8)
        ax.text(bx + 0.105, by, "10 cm — must measure 10.0 cm; print at 100 % / actual size",
                va="center", fontsize=6)
        ax.text(pw - margin_m, ph - margin_m / 2, f"gaitrig markers · page {page_no}/{len(pages)}",
                ha="right", va="center", fontsize=5)
        return fig

    out.parent.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    if suffix == ".pdf":
        with PdfPages(out) as pdf:
            for i, pg in enumerate(pages, start=1):
                pdf.savefig(draw_page(pg, i))
        written.append(out)
    else:
        for i, pg in enumerate(pages, start=1):
            p = out if i == 1 else out.with_name(f"{out.stem}_p{i}{out.suffix}")
            draw_page(pg, i).savefig(p, dpi=dpi)
            written.append(p)
    return written
