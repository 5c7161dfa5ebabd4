"""``--ankle-markers auto|lateral|joint`` and ``--ankle-width-mm`` against ground truth.

A synthetic walk whose true ankle joint centres are known; its lateral-malleolus markers
sit where Plug-in Gait puts them (centre + ankle width / 2 + marker radius along the
foot's lateral axis on the floor), its joint markers at the centres. Each option must
give the steps between the true centres (markers ``XL``/``XR``, measured with
``--left/--right``), or refuse with a message that says what to fix.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.cli import main
from engine.errors import InputError
from engine.io.c3d import write_c3d
from engine.io.csv import write_skeleton_csv
from engine.io.markers import MarkerTrajectories
from engine.io.trc import write_trc
from engine.mocap import DEFAULT_MARKER_DIAMETER_M, feet_from_markers, load_feet
from engine.sim.straight_walk import SynthWalk, synth_walk, walk_skeleton
from engine.skeleton import KINECT_V2, SkeletonSeries, TrackingState
from tests.engine.test_foreign_files import _run  # gaitrig gait: (exit code, JSON, stderr)

Doc = dict[str, Any]
#: The subject's true ankle widths (m): unlike each other and the 70 mm population one.
WIDTHS = {"L": 0.060, "R": 0.084}


def _walk() -> SynthWalk:
    return synth_walk(n_steps=12, rate=100.0, heading_deg=35.0, origin=(15.0, -8.0, 0.0))


def _lateral(w: SynthWalk, side: str, width: float) -> np.ndarray:
    """The lateral malleolus marker: the centre moved width/2 + marker radius outwards,
    on the floor, perpendicular to the foot's heel→toe axis."""
    f = w.joints[f"toe{side}"] - w.joints[f"heel{side}"]
    left = np.stack([-f[:, 1], f[:, 0], np.zeros(len(f))], axis=1)
    left /= np.linalg.norm(left, axis=1, keepdims=True)
    out = left if side == "L" else -left
    return w.joints[f"ankle{side}"] + (0.5 * width + 0.5 * DEFAULT_MARKER_DIAMETER_M) * out


def _markers(w: SynthWalk, ankle: str, lateral: bool, feet: bool = True,
             meta: dict[str, object] | None = None) -> MarkerTrajectories:
    """Ankle markers named ``L<ankle>``-style (``LANK``, ``L_Ankle``), on the lateral
    malleoli or at the joint centres; heels, toes, pelvis and the truth ``XL``/``XR``."""
    names: list[str] = []
    pts: list[np.ndarray] = []
    for side in ("L", "R"):
        names.append(ankle.replace("#", side))
        pts.append(_lateral(w, side, WIDTHS[side]) if lateral else w.joints[f"ankle{side}"])
        if feet:
            names += [f"{side}HEE", f"{side}TOE"]
            pts += [w.joints[f"heel{side}"], w.joints[f"toe{side}"]]
    pel = w.joints["pelvis"]
    for lab, off in (("LASI", (0.05, 0.12, 0.0)), ("RASI", (0.05, -0.12, 0.0)),
                     ("LPSI", (-0.12, 0.05, 0.02)), ("RPSI", (-0.12, -0.05, 0.02))):
        names.append(lab)
        pts.append(pel + np.array(off))
    names += ["XL", "XR"]
    pts += [w.joints["ankleL"], w.joints["ankleR"]]
    rate = round(1.0 / float(np.median(np.diff(w.times))), 6)
    return MarkerTrajectories(w.times, np.stack(pts, axis=1), names, rate, "m",
                              meta=dict(meta or {}))


def _write(m: MarkerTrajectories, path: Path) -> Path:
    if path.suffix == ".c3d":
        write_c3d(path, m, units="mm")
    else:
        write_trc(path, m, units="mm")
    return path


def _widths_off(ref: Doc, got: Doc) -> list[float]:
    """Per step, the measured width minus the true one (m); same steps required."""
    a, b = ref["steps"], got["steps"]
    assert [s["side"] for s in b] == [s["side"] for s in a] and len(a) >= 6, (a, b)
    for sa, sb in zip(a, b, strict=True):
        assert sb["length_m"] == pytest.approx(sa["length_m"], abs=2e-3)
    return [sb["width_m"] - sa["width_m"] for sa, sb in zip(a, b, strict=True)]


@pytest.fixture(scope="module")
def walk() -> SynthWalk:
    return _walk()


def test_centres_placed_exactly_from_given_widths(walk: SynthWalk) -> None:
    """Engine API: bare ``L_Ankle`` names on the lateral malleoli, forced lateral with
    the subject's widths, give the true joint centres in every frame."""
    m = _markers(walk, "#_Ankle", lateral=True)
    feet = feet_from_markers(m, ankle_markers="lateral",
                             ankle_width_m=(WIDTHS["L"], WIDTHS["R"]))
    for side in ("L", "R"):
        assert feet.primary[side] == "ankle_centre"
        assert np.allclose(feet.points[side]["ankle_centre"], walk.joints[f"ankle{side}"],
                           atol=1e-9)
        assert f"ankle width {1000 * WIDTHS[side]:.0f} mm: given;" in \
            feet.sources[f"{side}_ankle_centre"]
    # by default a bare name is a joint: nothing is moved (backwards compatible)
    auto = feet_from_markers(m)
    assert auto.primary == {"L": "ankle", "R": "ankle"} and auto.notes == []


def test_lateral_forces_the_joint_centre(walk: SynthWalk, tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    """``L_Ankle``/``R_Ankle`` on the lateral malleoli: auto takes them for joints (steps
    ≈ 8.6 cm too wide); ``lateral`` with the subject's widths gives the true steps within
    1 mm; ``lateral`` alone the population width, with its note."""
    p = _write(_markers(walk, "#_Ankle", lateral=True), tmp_path / "bare.trc")
    rc, ref, err = _run([str(p), "--json", "--left", "XL", "--right", "XR"], capsys)
    assert rc == 0 and ref is not None, err
    rc, auto, err = _run([str(p), "--json"], capsys)
    assert rc == 0 and auto is not None, err
    assert all(d > 0.08 for d in _widths_off(ref, auto))
    assert auto["summary"]["foot_points"] == {"L": "ankle: L_Ankle", "R": "ankle: R_Ankle"}

    rc, doc, err = _run([str(p), "--json", "--ankle-markers", "lateral",
                         "--ankle-width-mm", "60,84"], capsys)
    assert rc == 0 and doc is not None, err
    assert max(abs(d) for d in _widths_off(ref, doc)) < 1e-3
    s = doc["summary"]
    assert s["foot_points"]["L"] == ("ankle joint centre: L_Ankle moved 3.7 cm medially "
                                     "(ankle width 60 mm: given; marker diameter 14 mm: "
                                     "default)")
    assert "(ankle width 84 mm: given;" in s["foot_points"]["R"]
    assert s["notes"] == ["The ankle markers L_Ankle and R_Ankle were taken for "
                          "lateral-malleolus markers, as asked (ankle markers: lateral)."]

    rc, pop, err = _run([str(p), "--json", "--ankle-markers", "LATERAL"], capsys)
    assert rc == 0 and pop is not None, err
    # 70 mm for both: the left centre 5 mm too far in, the right 7 mm not far enough
    assert np.median(_widths_off(ref, pop)) == pytest.approx(0.002, abs=1e-3)
    assert "population default" in pop["summary"]["foot_points"]["L"]
    assert any("population ankle width of 70 mm" in n for n in pop["summary"]["notes"])


def test_one_width_for_both_feet(walk: SynthWalk, tmp_path: Path,
                                 capsys: pytest.CaptureFixture[str]) -> None:
    """``--ankle-width-mm 72``: 72 mm on each side (the mean of 60 and 84: the widths'
    errors cancel, ±12 mm per foot moved 6 mm each)."""
    p = _write(_markers(walk, "#ANK", lateral=True), tmp_path / "w.trc")
    rc, ref, err = _run([str(p), "--json", "--left", "XL", "--right", "XR"], capsys)
    assert rc == 0 and ref is not None, err
    rc, doc, err = _run([str(p), "--json", "--ankle-width-mm", "72"], capsys)
    assert rc == 0 and doc is not None, err
    assert max(abs(d) for d in _widths_off(ref, doc)) < 1e-3
    for side in ("L", "R"):
        assert "(ankle width 72 mm: given;" in doc["summary"]["foot_points"][side]
    assert doc["summary"]["notes"] == []


def test_joint_forbids_the_correction(walk: SynthWalk, tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    """Virtual joint-centre markers exported as ``LANK``/``RANK``: auto moves them
    medially (steps ≈ 8 cm too narrow); ``joint`` measures them: the true steps."""
    p = _write(_markers(walk, "#ANK", lateral=False), tmp_path / "virtual.c3d")
    rc, ref, err = _run([str(p), "--json", "--left", "XL", "--right", "XR"], capsys)
    assert rc == 0 and ref is not None, err
    rc, auto, err = _run([str(p), "--json"], capsys)
    assert rc == 0 and auto is not None, err
    assert np.median(_widths_off(ref, auto)) < -0.07
    rc, doc, err = _run([str(p), "--json", "--ankle-markers", "joint"], capsys)
    assert rc == 0 and doc is not None, err
    assert max(abs(d) for d in _widths_off(ref, doc)) < 1e-3
    s = doc["summary"]
    assert s["foot_points"] == {"L": "ankle: LANK", "R": "ankle: RANK"}
    assert s["notes"] == ["The ankle markers LANK and RANK were taken for the ankle joint "
                          "centres, as asked (ankle markers: joint), and measured as they "
                          "are."]
    # with a medial marker beside, joint still measures the named marker
    m = _markers(walk, "#ANK", lateral=False)
    m = MarkerTrajectories(m.times, np.concatenate([m.positions, m.positions[:, :1] + 0.08],
                                                   axis=1), [*m.labels, "LMED"], m.rate, "m")
    feet = feet_from_markers(m, ankle_markers="joint")
    assert feet.primary == {"L": "ankle", "R": "ankle"}
    assert "ankle_centre" not in feet.points["L"]


def test_trc_with_widths_same_as_c3d_with_processing(walk: SynthWalk, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]
                                                     ) -> None:
    """The same LANK/RANK walk as a C3D carrying PROCESSING:L/RAnkleWidth and as a TRC
    (no widths): the TRC with ``--ankle-width-mm`` gives the C3D's steps; without it the
    population width. Given widths override the C3D's, and say so."""
    m = _markers(walk, "#ANK", lateral=True, meta={"ankle_width_m": dict(WIDTHS)})
    c3d = _write(m, tmp_path / "walk.c3d")
    trc = _write(m, tmp_path / "walk.trc")
    rc, ref, err = _run([str(c3d), "--json", "--left", "XL", "--right", "XR"], capsys)
    assert rc == 0 and ref is not None, err
    rc, from_c3d, err = _run([str(c3d), "--json"], capsys)
    assert rc == 0 and from_c3d is not None, err
    assert "PROCESSING:LAnkleWidth" in from_c3d["summary"]["foot_points"]["L"]
    assert max(abs(d) for d in _widths_off(ref, from_c3d)) < 1e-3
    rc, plain, err = _run([str(trc), "--json"], capsys)
    assert rc == 0 and plain is not None, err
    assert "population default" in plain["summary"]["foot_points"]["R"]
    rc, from_trc, err = _run([str(trc), "--json", "--ankle-width-mm", "60,84"], capsys)
    assert rc == 0 and from_trc is not None, err
    for a, b in zip(from_c3d["steps"], from_trc["steps"], strict=True):
        assert (a["side"], a["time_s"]) == (b["side"], b["time_s"])
        assert b["width_m"] == pytest.approx(a["width_m"], abs=1e-5)
        assert b["length_m"] == pytest.approx(a["length_m"], abs=1e-5)
    assert from_c3d["summary"]["step_width_m"]["mean"] == pytest.approx(
        from_trc["summary"]["step_width_m"]["mean"], abs=1e-5)
    # given widths win over the file's, and the foot point says which were set aside
    rc, over, err = _run([str(c3d), "--json", "--ankle-width-mm", "64,84"], capsys)
    assert rc == 0 and over is not None, err
    assert ("(ankle width 64 mm: given, instead of PROCESSING:LAnkleWidth 60 mm; "
            in over["summary"]["foot_points"]["L"])
    assert "(ankle width 84 mm: given; " in over["summary"]["foot_points"]["R"]
    assert np.median(_widths_off(ref, over)) == pytest.approx(-0.002, abs=1e-3)


def test_report_takes_the_options(walk: SynthWalk, tmp_path: Path,
                                  capsys: pytest.CaptureFixture[str]) -> None:
    """``gaitrig report`` has the same options (and refuses the same bad values)."""
    p = _write(_markers(walk, "#_Ankle", lateral=True), tmp_path / "bare.trc")
    out = tmp_path / "r.html"
    assert main(["report", str(p), "--subject", "P1", "-o", str(out), "--ankle-markers",
                 "lateral", "--ankle-width-mm", "60,84"]) == 0
    html = out.read_text(encoding="utf-8")
    assert "as asked (ankle markers: lateral)" in html
    capsys.readouterr()
    assert main(["report", str(p), "--subject", "P1", "-o", str(out),
                 "--ankle-width-mm", "700"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("gaitrig report: error: bare.trc: an ankle width of 700 mm "), err


_BAD: dict[str, tuple[list[str], str, str]] = {
    # case: (options, file kind, words the message must hold)
    "cm": (["--ankle-width-mm", "7"], "lateral",
           "an ankle width of 7 mm (both feet) is outside 40-150 mm (adult ankles measure "
           "about 55-90 mm); give the distance across the malleoli in millimetres, one "
           "value for both feet or left,right: --ankle-width-mm 70 or --ankle-width-mm "
           "68,72"),
    "metres_right": (["--ankle-width-mm", "70,0.07"], "lateral",
                     "an ankle width of 0.07 mm (right) is outside 40-150 mm"),
    "nan": (["--ankle-width-mm", "nan"], "lateral", "is outside 40-150 mm"),
    "joint_and_width": (["--ankle-markers", "joint", "--ankle-width-mm", "70"], "lateral",
                        "with --ankle-markers joint the markers are the joint centres: "
                        "leave one of the two out"),
    "lateral_and_names": (["--ankle-markers", "lateral", "--left", "XL", "--right", "XR"],
                          "lateral", "with --left/--right given, the named markers are "
                          "measured as they are"),
    "width_and_names": (["--ankle-width-mm", "70", "--left", "XL", "--right", "XR"],
                        "lateral", "leave --ankle-width-mm out, or leave --left/--right out"),
    "width_unused": (["--ankle-width-mm", "70"], "bare",
                     "--ankle-width-mm is not used: L_Ankle and R_Ankle are taken for ankle "
                     "joint centres by name (or no ankle marker was found); give "
                     "--ankle-markers lateral if they are on the lateral malleoli"),
    "lateral_no_feet": (["--ankle-markers", "lateral"], "no_feet",
                        "--ankle-markers lateral: the left ankle joint centre cannot be "
                        "placed from L_Ankle"),
    "lateral_skeleton": (["--ankle-markers", "lateral"], "csv",
                         "--ankle-markers lateral applies to marker files (.c3d, .trc); a "
                         "skeleton CSV's ankles are joints: leave it out"),
    "width_skeleton": (["--ankle-width-mm", "70"], "csv", "--ankle-width-mm applies to "
                       "marker files"),
}


@pytest.mark.parametrize("case", sorted(_BAD))
def test_bad_ankle_options_are_refused(case: str, walk: SynthWalk, tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    """Each refusal is one line on stderr, exit code 2, saying what to fix."""
    opts, kind, words = _BAD[case]
    if kind == "csv":
        J = walk_skeleton(walk)
        s = SkeletonSeries(walk.times, J, np.full(J.shape[:2], TrackingState.TRACKED,
                                                  dtype=np.uint8), KINECT_V2)
        p = tmp_path / "skel.csv"
        write_skeleton_csv(p, s)
    else:
        m = (_markers(walk, "#ANK", lateral=True) if kind == "lateral"
             else _markers(walk, "#_Ankle", lateral=True, feet=kind != "no_feet"))
        p = _write(m, tmp_path / f"{case}.trc")
    rc, doc, err = _run([str(p), "--json", *opts], capsys)
    assert rc == 2 and doc is None
    assert words in err, err


@pytest.mark.parametrize(("value", "words"), [
    ("abc", "'abc' is not a width in mm: give one number for both feet or left,right, "
            "e.g. 70 or 68,72"),
    ("60,70,80", "'60,70,80' gives 3 widths: give one for both feet or two, left,right"),
])
def test_unparsable_widths_are_refused(value: str, words: str, tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["gait", str(tmp_path / "any.trc"), "--ankle-width-mm", value])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"argument --ankle-width-mm: {words}" in err, err


def test_python_api_refuses_bad_values(tmp_path: Path) -> None:
    """``load_feet`` checks the options before reading the file."""
    p = tmp_path / "missing.trc"
    with pytest.raises(InputError, match="outside 40-150 mm"):
        load_feet(p, ankle_width_m=0.2)
    with pytest.raises(InputError, match="3 ankle widths given"):
        load_feet(p, ankle_width_m=(0.06, 0.07, 0.08))
    with pytest.raises(InputError, match="is not one of auto, lateral, joint"):
        load_feet(p, ankle_markers="medial")
