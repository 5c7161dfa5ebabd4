"""Reports for every clinic: subject names in CJK, Greek, Cyrillic, Arabic and Latin with
diacritics are set in a font that has their glyphs — in the PDF (WeasyPrint) and in the
plots (matplotlib) — instead of as empty boxes ("tofu").

Only DejaVu fonts were installed, and DejaVu has no CJK glyphs: ``王小明`` printed as
three boxes while ``pdftotext`` still extracted the name (the boxes keep their Unicode
mapping), so the checks here look at the rendered page.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest

from engine.report.render import ReportData, render_pdf
from tests.engine.report.test_report_clinical import _trials

CJK_FAMILIES = ("WenQuanYi Micro Hei", "Noto Sans CJK")
NAMES = {
    "chinese": "王小明",
    "japanese": "山田太郎",
    "japanese_kana": "やまだ たろう",
    "korean": "김민준",
    "polish": "Łukasz Żółć",
    "greek": "Γιώργος Παπαδόπουλος",
    "cyrillic": "Иван Петров",
    "arabic": "محمد علي",
}
CJK = {"chinese", "japanese", "japanese_kana", "korean"}
DPI = 150


def _cjk_font_installed() -> bool:
    if shutil.which("fc-list") is None:
        return False
    families = subprocess.run(["fc-list", ":", "family"], capture_output=True, text=True,
                              timeout=30).stdout
    return any(f in families for f in CJK_FAMILIES)


@pytest.fixture(scope="module")
def cjk_font() -> None:
    """Skip without a CJK font on a developer machine; in CI (``CI=true``) the bootstrap
    installs ``fonts-wqy-microhei``, so a missing font there is a broken bootstrap."""
    if shutil.which("pdftoppm") is None or shutil.which("pdffonts") is None:
        pytest.skip("poppler-utils not installed")
    if not _cjk_font_installed():
        if os.environ.get("CI") == "true":
            pytest.fail("no CJK font (WenQuanYi Micro Hei / Noto Sans CJK) in fc-list although "
                        "CI=true: scripts/bootstrap.sh should have installed "
                        "fonts-wqy-microhei")
        pytest.skip("no CJK font installed (apt-get install fonts-wqy-microhei); "
                    "scripts/bootstrap.sh installs it as root")


def _name_box(pdf: Path, name: str) -> tuple[float, float, float, float]:
    """Bounding box (pt) of the subject name in page 1's header, from ``pdftotext -bbox``."""
    xml = subprocess.run(["pdftotext", "-bbox", "-f", "1", "-l", "1", str(pdf), "-"],
                         capture_output=True, text=True, check=True, timeout=60).stdout
    words = name.split()
    words += [w[::-1] for w in words]  # right-to-left words come out in visual order
    boxes = [tuple(float(v) for v in m[:4]) for m in re.findall(
        r'<word xMin="([\d.]+)" yMin="([\d.]+)" xMax="([\d.]+)" yMax="([\d.]+)">([^<]*)</word>',
        xml) if m[4] in words and float(m[1]) < 150.0]  # the header, not the footer
    assert len(boxes) == len(name.split()), (name, xml[:2000])
    return (min(b[0] for b in boxes), min(b[1] for b in boxes), max(b[2] for b in boxes),
            max(b[3] for b in boxes))


def _glyph_groups(page: np.ndarray, box: tuple[float, float, float, float]) -> list[np.ndarray]:
    """Ink of the box cut at blank columns: one piece per glyph (or joined glyphs)."""
    s = DPI / 72.0
    x0, y0, x1, y1 = (round(v * s) for v in box)
    ink = page[max(y0 - 2, 0):y1 + 2, max(x0 - 2, 0):x1 + 2].mean(axis=2) < 140
    cols = ink.any(axis=0)
    edges = np.flatnonzero(np.diff(np.r_[0, cols.astype(np.int8), 0]))
    return [ink[:, a:b] for a, b in zip(edges[::2], edges[1::2], strict=True)]


def _is_tofu(groups: list[np.ndarray]) -> bool:
    """True when the glyphs are all one shape: the missing-glyph box repeated (or run
    together into one block)."""
    if len(groups) < 2:
        return True
    ref = groups[0]
    for g in groups[1:]:
        if abs(g.shape[1] - ref.shape[1]) > 2:
            return False
        a = cv2.resize(g.astype(np.uint8), (ref.shape[1], ref.shape[0]),
                       interpolation=cv2.INTER_NEAREST)
        if np.mean(a != ref) > 0.1:
            return False
    return True


def _render(pdf: bytes, tmp: Path) -> tuple[Path, np.ndarray]:
    f = tmp / "r.pdf"
    f.write_bytes(pdf)
    subprocess.run(["pdftoppm", "-r", str(DPI), "-f", "1", "-l", "1", "-png", str(f),
                    str(tmp / "p")], check=True, timeout=60)
    page = cv2.imread(str(next(tmp.glob("p*.png"))))
    return f, page


@pytest.mark.parametrize("script", sorted(NAMES))
def test_subject_name_in_any_script_is_printed_not_boxes(cjk_font: None, script: str,
                                                         tmp_path: Path) -> None:
    name = NAMES[script]
    f, page = _render(render_pdf(ReportData(name, _trials(1))), tmp_path)
    text = subprocess.run(["pdftotext", "-layout", str(f), "-"], capture_output=True,
                          text=True, check=True, timeout=60).stdout
    assert text.count(name) >= 2  # header and page footer
    fonts = subprocess.run(["pdffonts", str(f)], capture_output=True, text=True, check=True,
                           timeout=60).stdout
    if script in CJK:
        assert any(c.replace(" ", "-") in fonts for c in CJK_FAMILIES), fonts
    groups = _glyph_groups(page, _name_box(f, name))
    assert not _is_tofu(groups), f"{name!r} printed as {len(groups)} identical boxes"


def test_the_tofu_check_sees_boxes_from_a_font_without_the_glyphs(cjk_font: None,
                                                                   tmp_path: Path) -> None:
    """The same name rendered with DejaVu only (a fontconfig that knows no other font)
    comes out as boxes, and the check above says so: it can fail."""
    dejavu = subprocess.run(["fc-match", "-f", "%{file}", "DejaVu Sans"], capture_output=True,
                            text=True, timeout=30).stdout
    if not dejavu.endswith(".ttf"):
        pytest.skip("DejaVu Sans not found by fc-match")
    (tmp_path / "cache").mkdir()
    conf = tmp_path / "fonts.conf"
    conf.write_text('<?xml version="1.0"?><!DOCTYPE fontconfig SYSTEM "fonts.dtd">'
                    f"<fontconfig><dir>{Path(dejavu).parent}</dir>"
                    f"<cachedir>{tmp_path / 'cache'}</cachedir></fontconfig>")
    out = tmp_path / "tofu.pdf"
    code = ("import sys\nfrom engine.report.render import ReportData, render_pdf\n"
            "from tests.engine.report.test_report_clinical import _trials\n"
            f"open({str(out)!r}, 'wb').write(render_pdf(ReportData({NAMES['chinese']!r}, "
            "_trials(1))))\n")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=300,
                   cwd=Path(__file__).parents[3],
                   env={**os.environ, "FONTCONFIG_FILE": str(conf)})
    f, page = _render(out.read_bytes(), tmp_path)
    fonts = subprocess.run(["pdffonts", str(f)], capture_output=True, text=True, check=True,
                           timeout=60).stdout
    assert not any(c.replace(" ", "-") in fonts for c in CJK_FAMILIES), fonts
    assert _is_tofu(_glyph_groups(page, _name_box(f, NAMES["chinese"])))


def _missing_glyph_warnings(name: str, families: list[str] | None) -> list[str]:
    import matplotlib.pyplot as plt

    from engine.report import plots

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if families is None:
            plots.plot_foot_placements([(name, [{"side": "L", "position": [0.5, 0.05, 0]},
                                                {"side": "R", "position": [1.1, -0.05, 0]}])])
        else:  # the same title drawn with only the given fonts
            with plt.rc_context({"font.family": families}):
                fig, ax = plt.subplots()
                ax.set_title(name)
                plots.figure_png(fig)
    return [str(w.message) for w in caught if "missing from font" in str(w.message)]


def test_plots_fall_back_to_a_cjk_font_for_trial_names(cjk_font: None) -> None:
    """Trial names are the titles of the foot-placement panels; DejaVu alone draws CJK
    names as boxes (matplotlib warns 'Glyph … missing from font(s) DejaVu Sans')."""
    from engine.report import plots

    assert any(f in " ".join(plots.font_families()) for f in CJK_FAMILIES)
    assert _missing_glyph_warnings("DejaVu Sans only: 王小明", ["DejaVu Sans"])
    for name in NAMES.values():
        assert not _missing_glyph_warnings(f"{name} — walk 1", None), name
