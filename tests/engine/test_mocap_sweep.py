"""``gaitrig gait`` against files as other labs write them: an adversarial sweep.

Two base recordings — the real Vicon trial ``mocap/kineticstoolkit/walk.c3d`` (shared
data, skipped without it) and a synthetic walker (:mod:`engine.sim.walker`) — are
rewritten in other formats, units, axes, places, headings and marker names, and with
the data problems real files have. Each variant goes through the CLI in-process; a
variant that still holds the same walk must give the same steps (same count and sides,
lengths and widths within 1 mm, times shifted only by the known offset); a broken file
must give exit code 2 and one line saying what to fix, never a traceback.
"""

from __future__ import annotations

import copy
import io
import json
from collections.abc import Callable
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.cli import main
from engine.io.c3d import read_c3d, write_c3d
from engine.io.csv import write_skeleton_csv
from engine.io.markers import MarkerTrajectories, up_rotation
from engine.io.trc import write_trc
from engine.sim.walker import Walker, WalkerParams
from engine.skeleton import KINECT_V2, SkeletonSeries, TrackingState

Doc = dict[str, Any]

#: Synthetic walker's Kinect joints → Plug-in Gait-like labels.
_PIG = {"AnkleLeft": "LANK", "AnkleRight": "RANK", "FootLeft": "LTOE", "FootRight": "RTOE",
        "KneeLeft": "LKNE", "KneeRight": "RKNE", "SpineBase": "SACR", "Head": "HEAD"}


def _walker_joints(back_and_forth: bool = False, t1: float = 7.0) -> tuple[np.ndarray, np.ndarray]:
    w = Walker(WalkerParams(), [0.0, 0.0, 0.0], [5.0, 0.0, 0.0], start_time=0.5,
               back_and_forth=back_and_forth, seed=3)
    t = np.round(np.arange(0.0, t1, 0.01), 6)
    return t, w.joints(t)


def _synthetic(back_and_forth: bool = False) -> MarkerTrajectories:
    t, J = _walker_joints(back_and_forth, 14.0 if back_and_forth else 7.0)
    idx = [KINECT_V2.index(j) for j in _PIG]
    return MarkerTrajectories(t, J[:, idx], list(_PIG.values()), 100.0, "m")


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, Doc | None, str]:
    rc = main(["gait", *argv])
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    if rc == 0:
        assert err == ""
        return rc, json.loads(out), err
    assert out == "" and err.count("\n") == 1 and err.startswith("gaitrig gait: error: "), err
    return rc, None, err


def _same_steps(ref: Doc, got: Doc, dt: float = 0.0, tol_m: float = 1e-3) -> None:
    """Same walk: same steps (sides, count), lengths/widths within ``tol_m``, times + dt."""
    a, b = ref["steps"], got["steps"]
    assert [s["side"] for s in b] == [s["side"] for s in a], (a, b)
    for sa, sb in zip(a, b, strict=True):
        assert sb["length_m"] == pytest.approx(sa["length_m"], abs=tol_m)
        assert sb["width_m"] == pytest.approx(sa["width_m"], abs=tol_m)
        assert sb["time_s"] == pytest.approx(sa["time_s"] + dt, abs=2e-3)


# ---------------------------------------------------------------- transforms

def _moved(m: MarkerTrajectories, R: np.ndarray | None = None,
           offset: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> MarkerTrajectories:
    """Rotate (about the origin) then translate the markers (Z-up world)."""
    P = m.positions if R is None else m.positions @ R.T
    return replace(m, positions=P + np.asarray(offset))


def _rz(deg: float) -> np.ndarray:
    a = np.deg2rad(deg)
    return np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0, 0, 1.0]])


def _file_axes(m: MarkerTrajectories, up: str) -> MarkerTrajectories:
    """The Z-up markers as a file whose vertical axis is ``up`` would hold them."""
    return replace(m, positions=m.positions @ up_rotation(up))


def _relabel(m: MarkerTrajectories, names: dict[str, str]) -> MarkerTrajectories:
    return replace(m, labels=[names.get(lab, lab) for lab in m.labels])


def _subset(m: MarkerTrajectories, keep: Callable[[str], bool]) -> MarkerTrajectories:
    idx = [i for i, lab in enumerate(m.labels) if keep(lab)]
    return replace(m, positions=m.positions[:, idx], labels=[m.labels[i] for i in idx])


def _trc_text(m: MarkerTrajectories, tmp: Path, units: str = "mm") -> str:
    p = tmp / "_base.trc"
    write_trc(p, m, units=units)
    return p.read_text()


def _write(kind: str, m: MarkerTrajectories, tmp: Path, units: str = "mm") -> Path:
    p = tmp / f"variant.{kind}"
    if kind == "c3d":
        write_c3d(p, m, units=units)
    else:
        write_trc(p, m, units=units)
    return p


# ---------------------------------------------------------------- references

@pytest.fixture(scope="module")
def real(shared_data: Path) -> MarkerTrajectories:
    """The Vicon trial's markers without its PROCESSING ankle widths: the variants are
    C3D and TRC files (TRC has no place for them), compared with one reference."""
    m = read_c3d(shared_data / "mocap" / "kineticstoolkit" / "walk.c3d")
    m.meta.pop("ankle_width_m")
    return m


@pytest.fixture(scope="module")
def synth() -> MarkerTrajectories:
    return _synthetic()


@pytest.fixture(scope="module", params=["real", "synth"])
def _base_ref(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
              ) -> tuple[MarkerTrajectories, Doc]:
    """:func:`base`, computed once per module for each base recording (it was once per
    test, ~150 of them)."""
    m = request.getfixturevalue(request.param)
    p = tmp_path_factory.mktemp(f"base-{request.param}") / "ref.c3d"
    write_c3d(p, m, units="mm")
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        rc = main(["gait", str(p), "--json"])
    assert rc == 0 and err.getvalue() == "", err.getvalue()
    doc = json.loads(out.getvalue())
    assert len(doc["steps"]) >= 3
    return m, doc


@pytest.fixture
def base(_base_ref: tuple[MarkerTrajectories, Doc]) -> tuple[MarkerTrajectories, Doc]:
    """(markers in metres, Z up; the CLI's answer on them written as a C3D file in mm);
    the answer is each test's own copy."""
    m, doc = _base_ref
    return m, copy.deepcopy(doc)


def test_real_file_reference_equals_rewritten_copy(shared_data: Path,
                                                   capsys: pytest.CaptureFixture[str],
                                                   tmp_path: Path) -> None:
    """A copy of the trial written by write_c3d keeps its PROCESSING ankle widths, which
    place the crossing method's ankle joint centres: the original's steps."""
    f = shared_data / "mocap" / "kineticstoolkit" / "walk.c3d"
    p = tmp_path / "copy.c3d"
    write_c3d(p, read_c3d(f), units="mm")
    rc, orig, _ = _run([str(f), "--json"], capsys)
    rc2, copy, _ = _run([str(p), "--json"], capsys)
    assert rc == rc2 == 0 and orig is not None and copy is not None
    _same_steps(orig, copy)
    assert "PROCESSING:LAnkleWidth" in orig["summary"]["foot_points"]["L"]
    assert copy["summary"]["foot_points"] == orig["summary"]["foot_points"]
    assert copy["summary"]["notes"] == orig["summary"]["notes"] == []


# ---------------------------------------------------------------- same walk, other files

SAME_WALK: dict[str, tuple[str, str, Callable[[MarkerTrajectories], MarkerTrajectories],
                           list[str]]] = {
    # name: (format, units, transform, extra CLI args)
    "c3d_m": ("c3d", "m", lambda m: m, []),
    "c3d_cm": ("c3d", "cm", lambda m: m, []),
    "trc_mm": ("trc", "mm", lambda m: m, []),
    "trc_m": ("trc", "m", lambda m: m, []),
    "trc_cm": ("trc", "cm", lambda m: m, []),
    "up_y": ("trc", "mm", lambda m: _file_axes(m, "y"), []),
    "up_y_given": ("trc", "mm", lambda m: _file_axes(m, "y"), ["--up", "y"]),
    "up_minus_y": ("trc", "m", lambda m: _file_axes(m, "-y"), []),
    "up_minus_y_given": ("trc", "m", lambda m: _file_axes(m, "-y"), ["--up", "-y"]),
    "up_minus_y_given_eq": ("trc", "m", lambda m: _file_axes(m, "-y"), ["--up=-y"]),
    "up_x": ("c3d", "mm", lambda m: _file_axes(m, "x"), []),
    "up_minus_z": ("c3d", "mm", lambda m: _file_axes(m, "-z"), []),
    "far_1km_c3d": ("c3d", "mm", lambda m: _moved(m, offset=(1000.0, -1000.0, 0.0)), []),
    "far_1km_trc": ("trc", "mm", lambda m: _moved(m, offset=(1000.0, -1000.0, 0.0)), []),
    "far_10km_trc": ("trc", "mm", lambda m: _moved(m, offset=(-1e4, 1e4, 0.0)), []),
    "far_10km_up_y_trc_m": ("trc", "m",
                            lambda m: _file_axes(_moved(m, offset=(1e4, 1e4, 0.0)), "y"), []),
    "floor_at_100m": ("trc", "mm", lambda m: _moved(m, offset=(0.0, 0.0, 100.0)), []),
    "walk_minus_x": ("trc", "mm", lambda m: _moved(m, _rz(180.0)), []),
    "walk_y": ("c3d", "mm", lambda m: _moved(m, _rz(90.0)), []),
    "walk_diagonal": ("trc", "mm", lambda m: _moved(m, _rz(-135.0), (3.0, 2.0, 0.0)), []),
    "prefix_subject": ("c3d", "mm", lambda m: _relabel(m, {lab: f"Subject01:{lab}"
                                                           for lab in m.labels}), []),
    "lower_case": ("trc", "mm", lambda m: _relabel(m, {lab: lab.lower() for lab in m.labels}),
                   []),
    "confusing_extras": ("trc", "mm", lambda m: _with_decoys(m), []),
    "override_names": ("trc", "mm", lambda m: _relabel(m, {"LANK": "Foot_A", "RANK": "Foot_B"}),
                       ["--left", "foot_a", "--right", "FOOT_B"]),
}


def _with_decoys(m: MarkerTrajectories) -> MarkerTrajectories:
    """Extra markers whose names contain foot words but are not foot markers."""
    names = ["LANKLE_WIDTH", "RANKLE_WIDTH", "CentreOfMass", "LHEEL_OFFSET", "L_Ankle_Angle",
             "Ankle", "LeftAnkleMoment"]
    extra = np.repeat(m.positions[:, :1] + np.array([0.0, 0.0, 2.0]), len(names), axis=1)
    return replace(m, positions=np.concatenate([extra, m.positions], axis=1),
                   labels=names + m.labels)


def _as_is_ref(m: MarkerTrajectories, tmp: Path, capsys: pytest.CaptureFixture[str]) -> Doc:
    """The base file's steps with its ankle markers measured as they are (named with
    --left/--right): no joint centre estimated from a lateral-malleolus LANK."""
    p = tmp / "ref_as_is.c3d"
    write_c3d(p, m, units="mm")
    rc, doc, err = _run([str(p), "--json", "--left", "LANK", "--right", "RANK"], capsys)
    assert rc == 0 and doc is not None, err
    return doc


@pytest.mark.parametrize("case", sorted(SAME_WALK))
def test_same_walk_same_steps(case: str, base: tuple[MarkerTrajectories, Doc], tmp_path: Path,
                              capsys: pytest.CaptureFixture[str]) -> None:
    m, ref = base
    kind, units, f, extra = SAME_WALK[case]
    if "--left" in extra:
        # named markers are measured as they are, the automatic LANK at its joint centre
        ref = _as_is_ref(m, tmp_path, capsys)
    p = _write(kind, f(m), tmp_path, units)
    rc, doc, err = _run([str(p), "--json", *extra], capsys)
    assert rc == 0, err
    assert doc is not None
    _same_steps(ref, doc)


def test_far_10km_c3d_float32(base: tuple[MarkerTrajectories, Doc], tmp_path: Path,
                              capsys: pytest.CaptureFixture[str]) -> None:
    """C3D stores float32 (24-bit mantissa): at 10 km a coordinate keeps ±0.5 mm in either
    unit. Measured against the exact walk: steps within 0.8 mm at 10 km (0.05 mm at
    1 km, up to 5.5 mm at 100 km); the bound here leaves room for that, not for more."""
    m, ref = base
    for units in ("mm", "m"):
        p = _write("c3d", _moved(m, offset=(1e4, -1e4, 0.0)), tmp_path, units)
        rc, doc, err = _run([str(p), "--json"], capsys)
        assert rc == 0 and doc is not None, err
        _same_steps(ref, doc, tol_m=3e-3)


# ---------------------------------------------------------------- marker names

#: name set → labels for (left, right) ankle markers.
NAMES: dict[str, tuple[str, str]] = {
    "pig": ("LANK", "RANK"), "prefixed": ("Subject01:LANK", "Subject01:RANK"),
    "dot": ("L.Ankle", "R.Ankle"), "fcc_heel": ("L_FCC", "R_FCC"),
    "left_ankle": ("LeftAnkle", "RightAnkle"), "right_heel": ("LeftHeel", "RightHeel"),
    "kinect": ("AnkleLeft", "AnkleRight"), "snake": ("l_ankle", "r_ankle"),
    "upper": ("L.ANKLE", "R.ANKLE"), "lower_pig": ("lank", "rank"),
    "heel_only": ("LHEE", "RHEE"), "mal": ("L_LMAL", "R_LMAL"),
}

_FOOT_WORDS = ("ANK", "HEE", "TOE", "AJC", "FO", "TO", "TI", "KNE", "KJC", "FE", "THI")


def _feet_renamed(m: MarkerTrajectories, left: str, right: str) -> MarkerTrajectories:
    """Only the ankles (renamed) and the non-leg markers."""
    keep = _subset(m, lambda lab: lab in ("LANK", "RANK")
                   or not lab[1:].startswith(_FOOT_WORDS))
    return _relabel(keep, {"LANK": left, "RANK": right})


#: Name sets of a lateral-malleolus marker: with the heels and toes gone there is no foot
#: axis to place its joint centre, so the marker is measured as it is, and said so.
_LATERAL = ("pig", "prefixed", "lower_pig", "mal")


@pytest.mark.parametrize("names", sorted(NAMES))
def test_marker_names(names: str, base: tuple[MarkerTrajectories, Doc], tmp_path: Path,
                      capsys: pytest.CaptureFixture[str]) -> None:
    """Each name set finds the ankles. Only the ankle markers are kept, so every set
    measures them as they are (joint names, a heel name, or lateral-malleolus names
    without a foot axis): the base file's steps with LANK/RANK named."""
    m, _ = base
    ref = _as_is_ref(m, tmp_path, capsys)
    p = _write("trc", _feet_renamed(m, *NAMES[names]), tmp_path)
    rc, doc, err = _run([str(p), "--json"], capsys)
    assert rc == 0 and doc is not None, err
    _same_steps(ref, doc)
    notes = doc["summary"]["notes"]
    if names in _LATERAL:
        left = NAMES[names][0]
        assert len(notes) == 2 and f"marker {left} is on the lateral malleolus" in notes[0]
    else:
        assert notes == []


@pytest.mark.parametrize(("case", "expect"), [
    ("toes_only", "no usable left ankle or heel and no right ankle or heel"),
    ("no_right", "no usable right ankle or heel"),
    ("no_left_prefixed", "no usable left ankle or heel"),
])
def test_missing_feet_named(case: str, expect: str, base: tuple[MarkerTrajectories, Doc],
                            tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    m, _ = base
    if case == "toes_only":
        v = _subset(m, lambda lab: lab in ("LTOE", "RTOE", "SACR", "LASI", "RASI"))
    elif case == "no_right":
        v = _subset(m, lambda lab: not lab.startswith("R") or lab[1:].startswith("ASI"))
    else:
        v = _subset(m, lambda lab: not lab.startswith("L") or lab[1:].startswith("ASI"))
        v = _relabel(v, {lab: f"Pat:{lab}" for lab in v.labels})
    p = _write("c3d", v, tmp_path)
    rc, _, err = _run([str(p), "--json"], capsys)
    assert rc == 2 and expect in err and "--left/--right" in err


def test_override_names_not_found(base: tuple[MarkerTrajectories, Doc], tmp_path: Path,
                                  capsys: pytest.CaptureFixture[str]) -> None:
    m, _ = base
    p = _write("trc", m, tmp_path)
    rc, _, err = _run([str(p), "--left", "LANK", "--right", "RANKLE", "--json"], capsys)
    assert rc == 2 and "'RANKLE' not found" in err
    rc, _, err = _run([str(p), "--left", "LANK", "--json"], capsys)
    assert rc == 2 and "both --left and --right" in err


def test_many_columns(base: tuple[MarkerTrajectories, Doc], tmp_path: Path,
                      capsys: pytest.CaptureFixture[str]) -> None:
    """600 extra markers (C3D: LABELS2/LABELS3 groups) change nothing."""
    m, ref = base
    n = 600
    extra = m.positions[:, :1] + np.linspace(0.0, 1.0, n)[None, :, None]
    big = replace(m, positions=np.concatenate([extra, m.positions], axis=1),
                  labels=[f"EXTRA{i}" for i in range(n)] + m.labels)
    for kind in ("c3d", "trc"):
        p = _write(kind, big, tmp_path)
        rc, doc, err = _run([str(p), "--json"], capsys)
        assert rc == 0 and doc is not None, (kind, err)
        _same_steps(ref, doc)


# ---------------------------------------------------------------- TRC text variants

def _no_frame_column(text: str) -> str:
    lines = text.split("\n")
    return "\n".join(lines[:3] + [ln.split("\t", 1)[1] if "\t" in ln else ln
                                  for ln in lines[3:]])


TRC_TEXT: dict[str, Callable[[str], str]] = {
    "crlf": lambda s: s.replace("\n", "\r\n"),
    "trailing_tabs": lambda s: "\n".join(ln + "\t\t" if ln else ln for ln in s.split("\n")),
    "no_frame_column": _no_frame_column,
    "no_units": lambda s: s.replace("\tmm\t", "\t\t"),
    "units_word": lambda s: s.replace("\tmm\t", "\tmillimeters\t"),
    "blank_line_after_header_missing": lambda s: s.replace("\n\n", "\n", 1),
    "spaces_around_cells": lambda s: s.replace("\t", " \t "),
    "frame_numbers_from_152": lambda s: "\n".join(
        _renumber(ln, i) for i, ln in enumerate(s.split("\n"))),
}


def _renumber(line: str, i: int) -> str:
    cells = line.split("\t")
    if i >= 6 and cells[0].isdigit():
        cells[0] = str(int(cells[0]) + 151)
    return "\t".join(cells)


@pytest.mark.parametrize("case", sorted(TRC_TEXT))
def test_trc_text_variants(case: str, base: tuple[MarkerTrajectories, Doc], tmp_path: Path,
                           capsys: pytest.CaptureFixture[str]) -> None:
    m, ref = base
    p = tmp_path / "variant.trc"
    p.write_bytes(TRC_TEXT[case](_trc_text(m, tmp_path)).encode())
    rc, doc, err = _run([str(p), "--json"], capsys)
    assert rc == 0 and doc is not None, err
    _same_steps(ref, doc)


# ---------------------------------------------------------------- data problems

def _gap(m: MarkerTrajectories, label: str, t0: float, dur: float,
         value: float = np.nan) -> MarkerTrajectories:
    P = m.positions.copy()
    k = m.labels.index(label)
    sel = (m.times >= t0) & (m.times < t0 + dur)
    P[sel, k] = value
    return replace(m, positions=P)


def _mid_time(doc: Doc) -> float:
    """A time between two placements, where no foot is being placed."""
    s = doc["steps"]
    return 0.5 * (s[0]["time_s"] + s[1]["time_s"]) - 0.05


@pytest.mark.parametrize("kind", ["trc", "c3d"])
@pytest.mark.parametrize("fill", ["nan", "zero"])
def test_short_gap_bridged(kind: str, fill: str, base: tuple[MarkerTrajectories, Doc],
                           tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A 0.1 s drop-out (empty cells, NaN, or Vicon's 0,0,0) away from a placement."""
    m, ref = base
    v = _gap(m, "LANK", _mid_time(ref), 0.1, np.nan if fill == "nan" else 0.0)
    p = _write(kind, v, tmp_path)
    rc, doc, err = _run([str(p), "--json"], capsys)
    assert rc == 0 and doc is not None, err
    assert len(doc["steps"]) == len(ref["steps"])
    _same_steps(ref, doc, tol_m=5e-3)


def test_c3d_negative_residual_is_missing(base: tuple[MarkerTrajectories, Doc], tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    """Vicon marks a missing sample with residual −1 (and arbitrary coordinates)."""
    import ezc3d

    m, ref = base
    p = _write("c3d", m, tmp_path)
    c = ezc3d.c3d(str(p))
    k = m.labels.index("LANK")
    sel = np.flatnonzero((m.times >= _mid_time(ref)) & (m.times < _mid_time(ref) + 0.1))
    pts = c["data"]["points"]
    pts[:3, k, sel] = 1e6  # garbage that must not be used
    c["data"]["points"] = pts
    res = np.zeros((1, pts.shape[1], pts.shape[2]))
    res[0, k, sel] = -1.0
    c["data"]["meta_points"]["residuals"] = res
    c.write(str(p))
    rc, doc, err = _run([str(p), "--json"], capsys)
    assert rc == 0 and doc is not None, err
    _same_steps(ref, doc, tol_m=5e-3)


def test_long_zero_gap_is_not_a_foot_at_origin(base: tuple[MarkerTrajectories, Doc],
                                               tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    """A marker at exactly 0,0,0 for 0.5 s (TRC) must read as missing, not as a jump to
    the origin: no step may be longer than 1.5 m or start at the origin."""
    m, ref = base
    v = _moved(m, offset=(20.0, 5.0, 0.0))
    v = _gap(v, "RANK", _mid_time(ref), 0.5, 0.0)
    p = _write("trc", v, tmp_path)
    rc, doc, err = _run([str(p), "--json"], capsys)
    if rc == 0:
        assert doc is not None
        assert all(s["length_m"] < 1.5 and s["width_m"] < 0.5 for s in doc["steps"]), doc
    else:
        assert "step" in err


# ---------------------------------------------------------------- time axis

def test_time_offset_c3d_first_frame(base: tuple[MarkerTrajectories, Doc], tmp_path: Path,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    """A file starting 1000 s into the session: same steps, times shifted by 1000 s."""
    m, ref = base
    for kind in ("c3d", "trc"):
        p = _write(kind, replace(m, times=m.times + 1000.0), tmp_path)
        rc, doc, err = _run([str(p), "--json"], capsys)
        assert rc == 0 and doc is not None, err
        _same_steps(ref, doc, dt=1000.0)


@pytest.mark.parametrize("case", ["duplicate", "backwards"])
def test_bad_time_axis_trc(case: str, base: tuple[MarkerTrajectories, Doc], tmp_path: Path,
                           capsys: pytest.CaptureFixture[str]) -> None:
    m, _ = base
    lines = _trc_text(m, tmp_path).split("\n")
    k = 6 + len(m) // 2  # a data line in the middle
    cells = lines[k].split("\t")
    prev = lines[k - 1].split("\t")
    cells[1] = prev[1] if case == "duplicate" else str(float(prev[1]) - 0.5)
    lines[k] = "\t".join(cells)
    p = tmp_path / "t.trc"
    p.write_text("\n".join(lines))
    rc, _, err = _run([str(p), "--json"], capsys)
    assert rc == 2 and "t.trc" in err and f"line {k + 1}" in err and "time" in err


# ---------------------------------------------------------------- too little walking

def _window(m: MarkerTrajectories, t0: float, t1: float) -> MarkerTrajectories:
    sel = (m.times >= t0) & (m.times < t1)
    return replace(m, times=m.times[sel], positions=m.positions[sel])


@pytest.mark.parametrize("case", ["ten_frames", "one_step", "standing", "one_frame"])
def test_too_little_walking(case: str, base: tuple[MarkerTrajectories, Doc], tmp_path: Path,
                            capsys: pytest.CaptureFixture[str]) -> None:
    m, ref = base
    s = ref["steps"]
    if case == "ten_frames":
        v = _window(m, m.times[0], m.times[10])
    elif case == "one_frame":
        v = _window(m, m.times[0], m.times[1])
    elif case == "one_step":
        v = _window(m, s[0]["time_s"] - 0.1, s[1]["time_s"] + 0.1)
    else:
        frame = m.positions[len(m) // 2]
        v = replace(m, positions=np.repeat(frame[None], len(m), axis=0))
    for kind in ("c3d", "trc"):
        p = _write(kind, v, tmp_path)
        rc, doc, err = _run([str(p), "--json"], capsys)
        assert rc == 2, (kind, doc)
        # what to fix: record more walking (not: rename markers that are there)
        assert "steps" in err or "no straight walking" in err or "frame" in err, err
        assert "--left/--right" not in err, err


# ---------------------------------------------------------------- not a mocap file

@pytest.mark.parametrize("ext", [".c3d", ".trc", ".csv", ".C3D", ".txt"])
@pytest.mark.parametrize("content", ["empty", "garbage", "text"])
def test_not_a_mocap_file(ext: str, content: str, tmp_path: Path,
                          capsys: pytest.CaptureFixture[str]) -> None:
    p = tmp_path / f"file{ext}"
    data = {"empty": b"", "garbage": bytes(range(256)) * 40,
            "text": b"hello\tworld\n1\t2\n" * 10}[content]
    p.write_bytes(data)
    rc, _, err = _run([str(p), "--json"], capsys)
    assert rc == 2 and (p.name in err or "unsupported file type" in err), err


def test_directory_and_missing_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for p in (tmp_path, tmp_path / "nope.trc", tmp_path / "nope.csv"):
        rc, _, err = _run([str(p), "--json"], capsys)
        assert rc == 2 and str(p.name) in err, err


# ---------------------------------------------------------------- skeleton CSV

@pytest.fixture(scope="module")
def skeleton() -> SkeletonSeries:
    t, J = _walker_joints()
    return SkeletonSeries(t, J, np.full(J.shape[:2], TrackingState.TRACKED, dtype=np.uint8),
                          KINECT_V2)


def _csv_variant(s: SkeletonSeries, R: np.ndarray | None = None,
                 offset: tuple[float, float, float] = (0.0, 0.0, 0.0),
                 up: str = "z", dt: float = 0.0) -> SkeletonSeries:
    P = s.positions if R is None else s.positions @ R.T
    P = (P + np.asarray(offset)) @ up_rotation(up)
    return SkeletonSeries(s.times + dt, P, s.states.copy(), s.joint_set)


CSV_SAME: dict[str, tuple[dict[str, Any], list[str], Callable[[str], str]]] = {
    "camera_y_up": ({"up": "y"}, [], lambda x: x),
    "camera_y_down": ({"up": "-y"}, [], lambda x: x),
    "camera_y_down_given": ({"up": "-y"}, ["--up", "-y"], lambda x: x),
    "far_10km": ({"offset": (1e4, -1e4, 0.0)}, [], lambda x: x),
    "walk_minus_x_far_y_up": ({"R": _rz(180.0), "offset": (1e3, 5.0, 0.0), "up": "y"}, [],
                              lambda x: x),
    "time_offset": ({"dt": 5000.0}, [], lambda x: x),
    "crlf": ({}, [], lambda x: x.replace("\n", "\r\n")),
    "no_state_columns": ({}, [], lambda x: _drop_state_columns(x)),
}


def _drop_state_columns(text: str) -> str:
    rows = [ln.split(",") for ln in text.strip().split("\n")]
    keep = [i for i, h in enumerate(rows[0]) if not h.endswith("_state")]
    return "\n".join(",".join(r[i] for i in keep) for r in rows) + "\n"


def _csv_text(s: SkeletonSeries, tmp: Path) -> str:
    p = tmp / "_base.csv"
    write_skeleton_csv(p, s)
    return p.read_text()


def _csv_ref(skeleton: SkeletonSeries, tmp: Path, capsys: pytest.CaptureFixture[str]) -> Doc:
    p = tmp / "ref.csv"
    write_skeleton_csv(p, skeleton)
    rc, doc, err = _run([str(p), "--json"], capsys)
    assert rc == 0 and doc is not None and len(doc["steps"]) >= 3, err
    return doc


@pytest.mark.parametrize("case", sorted(CSV_SAME))
def test_csv_same_walk(case: str, skeleton: SkeletonSeries, tmp_path: Path,
                       capsys: pytest.CaptureFixture[str]) -> None:
    ref = _csv_ref(skeleton, tmp_path, capsys)
    kw, extra, edit = CSV_SAME[case]
    p = tmp_path / "variant.csv"
    p.write_bytes(edit(_csv_text(_csv_variant(skeleton, **kw), tmp_path)).encode())
    rc, doc, err = _run([str(p), "--json", *extra], capsys)
    assert rc == 0 and doc is not None, err
    _same_steps(ref, doc, dt=kw.get("dt", 0.0))


@pytest.mark.parametrize(("case", "expect"), [
    ("semicolon", "comma-separated"),
    ("backwards_time", "bad.csv row"),
    ("duplicate_time", "bad.csv row"),
    ("no_ankle_right", "AnkleRight"),
    ("head_only", "AnkleLeft"),
    ("text_cell", "not a number"),
    ("header_only", "no data rows"),
    ("no_time_column", "'time'"),
])
def test_csv_bad_input(case: str, expect: str, skeleton: SkeletonSeries, tmp_path: Path,
                       capsys: pytest.CaptureFixture[str]) -> None:
    lines = _csv_text(skeleton, tmp_path).split("\n")
    mid = len(lines) // 2
    if case == "semicolon":
        lines = [ln.replace(",", ";") for ln in lines]
    elif case in ("backwards_time", "duplicate_time"):
        prev = float(lines[mid - 1].split(",")[0])
        t = prev - 0.3 if case == "backwards_time" else prev
        lines[mid] = ",".join([repr(t), *lines[mid].split(",")[1:]])
    elif case == "no_ankle_right":
        rows = [ln.split(",") for ln in lines if ln]
        keep = [i for i, h in enumerate(rows[0]) if not h.startswith("AnkleRight")]
        lines = [",".join(r[i] for i in keep) for r in rows]
    elif case == "head_only":
        # one joint: too few to guess a unit from; the missing feet are what to name
        rows = [ln.split(",") for ln in lines if ln]
        keep = [i for i, h in enumerate(rows[0]) if h == "time" or h.startswith("Head")]
        lines = [",".join(r[i] for i in keep) for r in rows]
    elif case == "text_cell":
        lines[mid] = lines[mid].replace(",", ",abc,", 1).replace(",", "", 1)
    elif case == "header_only":
        lines = lines[:1]
    else:
        lines[0] = lines[0].replace("time", "t", 1)
    p = tmp_path / "bad.csv"
    p.write_text("\n".join(lines))
    rc, _, err = _run([str(p), "--json"], capsys)
    assert rc == 2 and expect in err, err
    if case.endswith("_time"):
        assert f"row {mid + 1}:" in err  # the file's line


# ---------------------------------------------------------------- turns

def test_back_and_forth_in_one_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Walking 5 m, turning, walking back: several passes; the same steps wherever the
    corridor is and whichever axis is up."""
    m = _synthetic(back_and_forth=True)
    p = _write("trc", m, tmp_path)
    rc, ref, err = _run([str(p), "--json"], capsys)
    assert rc == 0 and ref is not None, err
    assert ref["summary"]["n_passes"] >= 2
    v = _file_axes(_moved(m, _rz(60.0), (-3e3, 2e3, 0.0)), "-y")
    p2 = _write("trc", v, tmp_path, "m")
    rc, doc, err = _run([str(p2), "--json"], capsys)
    assert rc == 0 and doc is not None, err
    assert doc["summary"]["n_passes"] == ref["summary"]["n_passes"]
    _same_steps(ref, doc)


# ---------------------------------------------------------------- feet-only files, units

FEET_ONLY: dict[str, tuple[str, list[str]]] = {
    "z": ("z", []), "y": ("y", []), "x": ("x", []),
    "y_given": ("y", ["--up", "y"]), "minus_y_given": ("-y", ["--up", "-y"]),
    "minus_y": ("-y", []), "minus_z": ("-z", []),
}


@pytest.mark.parametrize("case", sorted(FEET_ONLY))
def test_feet_only_axes(case: str, base: tuple[MarkerTrajectories, Doc], tmp_path: Path,
                        capsys: pytest.CaptureFixture[str]) -> None:
    """Only ankle/heel/toe markers (no pelvis or head to tell up from down)."""
    m, ref = base
    up, extra = FEET_ONLY[case]
    feet = _subset(m, lambda lab: lab in ("LANK", "RANK", "LHEE", "RHEE", "LTOE", "RTOE"))
    p = _write("trc", _file_axes(_moved(feet, _rz(30.0), (500.0, 0.0, 0.0)), up), tmp_path)
    rc, doc, err = _run([str(p), "--json", *extra], capsys)
    assert rc == 0 and doc is not None, err
    _same_steps(ref, doc)


@pytest.mark.parametrize(("written", "header", "extra"), [
    ("mm", "m", []), ("m", "mm", []), ("cm", "m", []), ("mm", "m", ["--units", "mm"]),
    ("m", "", []), ("mm", "", []),
])
def test_units_header_wrong_or_absent(written: str, header: str, extra: list[str],
                                      base: tuple[MarkerTrajectories, Doc], tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    m, ref = base
    text = _trc_text(m, tmp_path, units=written).replace(f"\t{written}\t", f"\t{header}\t", 1)
    p = tmp_path / "u.trc"
    p.write_text(text)
    rc, doc, err = _run([str(p), "--json", *extra], capsys)
    assert rc == 0 and doc is not None, err
    _same_steps(ref, doc)


@pytest.mark.parametrize("up", ["-y", "-z", "x", "-x"])
def test_feet_only_upside_down_heelstrike(up: str, base: tuple[MarkerTrajectories, Doc],
                                          tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    """Foot strikes need the sign of up: without pelvis/head markers it is found from
    the feet themselves (long stances at the floor, short swings above it)."""
    m, _ = base
    feet = _subset(m, lambda lab: lab in ("LANK", "RANK", "LHEE", "RHEE", "LTOE", "RTOE"))
    docs = []
    for u in ("z", up):
        p = _write("trc", _file_axes(feet, u), tmp_path)
        rc, doc, err = _run([str(p), "--json", "--method", "heelstrike"], capsys)
        assert rc == 0 and doc is not None, err
        docs.append(doc)
    _same_steps(docs[0], docs[1])


@pytest.mark.parametrize("case", ["c3d_m", "trc_cm", "up_minus_y", "up_x", "far_1km_trc",
                                  "far_10km_trc", "walk_diagonal", "walk_y", "prefix_subject",
                                  "confusing_extras", "floor_at_100m"])
def test_same_walk_same_heel_strikes(case: str, base: tuple[MarkerTrajectories, Doc],
                                     tmp_path: Path,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    m, _ = base
    ref_p = _write("c3d", m, tmp_path)
    rc, ref, err = _run([str(ref_p), "--json", "--method", "heelstrike"], capsys)
    assert rc == 0 and ref is not None, err
    kind, units, f, extra = SAME_WALK[case]
    p = _write(kind, f(m), tmp_path, units)
    rc, doc, err = _run([str(p), "--json", "--method", "heelstrike", *extra], capsys)
    assert rc == 0 and doc is not None, err
    _same_steps(ref, doc)
    assert [e["time_s"] for e in doc["events"]] == pytest.approx(
        [e["time_s"] for e in ref["events"]], abs=2e-3)


@pytest.mark.parametrize("kind", ["trc", "c3d"])
@pytest.mark.parametrize("keep", [0.3, 0.75, 0.999])
def test_truncated_file(kind: str, keep: float, base: tuple[MarkerTrajectories, Doc],
                        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A file cut short (copy interrupted): an analysis of what is there, or one line."""
    m, _ = base
    p = _write(kind, m, tmp_path)
    data = p.read_bytes()
    p.write_bytes(data[: int(len(data) * keep)])
    rc, doc, err = _run([str(p), "--json"], capsys)
    assert rc in (0, 2)
    if rc == 2:
        assert p.name in err or "step" in err or "walking" in err, err
    else:
        assert doc is not None and len(doc["steps"]) >= 2


@pytest.mark.parametrize(("scale", "extra"),
                         [(1000.0, []), (100.0, []), (1000.0, ["--units", "mm"])])
def test_csv_not_in_metres(scale: float, extra: list[str], skeleton: SkeletonSeries,
                           tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The CSV format is metres; a file in mm or cm is recognised by the body's size."""
    ref = _csv_ref(skeleton, tmp_path, capsys)
    s = SkeletonSeries(skeleton.times, skeleton.positions * scale, skeleton.states,
                       skeleton.joint_set)
    p = tmp_path / "mm.csv"
    write_skeleton_csv(p, s)
    rc, doc, err = _run([str(p), "--json", *extra], capsys)
    assert rc == 0 and doc is not None, err
    _same_steps(ref, doc)


def test_two_subjects_in_one_file(base: tuple[MarkerTrajectories, Doc], tmp_path: Path,
                                  capsys: pytest.CaptureFixture[str]) -> None:
    """Two prefixed Plug-in Gait sets: no silent choice; --left/--right pick one."""
    m, _ = base
    a = _relabel(m, {lab: f"Anna:{lab}" for lab in m.labels})
    b = _relabel(_moved(m, offset=(0.0, 2.0, 0.0)), {lab: f"Ben:{lab}" for lab in m.labels})
    two = replace(a, positions=np.concatenate([b.positions, a.positions], axis=1),
                  labels=b.labels + a.labels)
    p = _write("c3d", two, tmp_path)
    rc, _, err = _run([str(p), "--json"], capsys)
    assert rc == 2 and "Ben:LANK, Anna:LANK" in err and "--left/--right" in err
    for method in ("crossing", "heelstrike"):
        p1 = _write("trc", m, tmp_path)
        rc, one, err = _run([str(p1), "--json", "--left", "LANK", "--right", "RANK",
                             "--method", method], capsys)
        assert rc == 0 and one is not None, err
        p = _write("c3d", two, tmp_path)
        rc, doc, err = _run([str(p), "--json", "--left", "Anna:LANK", "--right", "Anna:RANK",
                             "--method", method], capsys)
        assert rc == 0 and doc is not None, err
        _same_steps(one, doc)
        assert [e["time_s"] for e in doc["events"]] == pytest.approx(
            [e["time_s"] for e in one["events"]], abs=2e-3)


@pytest.mark.parametrize(("kind", "extra", "expect"), [
    ("trc", ["--up", "x"], "--up x contradicts"), ("trc", ["--up", "y"], "--up y contradicts"),
    ("c3d", ["--up", "-z"], "--up -z contradicts"), ("csv", ["--up", "y"], "--up y contradicts"),
    ("trc", ["--units", "m"], "--units m"), ("c3d", ["--units", "cm"], "--units cm"),
    ("csv", ["--units", "mm"], "--units mm"),
])
def test_wrong_overrides_are_refused(kind: str, extra: list[str], expect: str,
                                     skeleton: SkeletonSeries, tmp_path: Path,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    """A --up or --units that contradicts the body is an error, not a plausible answer
    (a wrong --up y gave near-normal step lengths with heights as widths)."""
    if kind == "csv":
        p = tmp_path / "w.csv"
        write_skeleton_csv(p, skeleton)
    else:
        p = _write(kind, _synthetic(), tmp_path, "mm")
    rc, _, err = _run([str(p), "--json", *extra], capsys)
    assert rc == 2 and expect in err, err


@pytest.mark.parametrize(("case", "expect"), [
    ("both_empty", "LANK, LHEE, RANK, RHEE hold no data"),
    ("right_empty", "no usable right ankle or heel marker: RANK, RHEE hold no data"),
    ("spaces", "no marker names on line 4 (TRC columns are separated by tabs)"),
    ("decimal_comma", "is not a number (use a decimal point)"),
])
def test_empty_markers_and_foreign_text(case: str, expect: str, tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    m = _synthetic()
    heels = m.positions[:, [0, 1]] - [0.05, 0.0, 0.05]  # behind and below the ankles
    m = replace(m, positions=np.concatenate([m.positions, heels], axis=1),
                labels=[*m.labels, "LHEE", "RHEE"])
    for side in ("R",) if case == "right_empty" else ("L", "R"):
        for part in ("ANK", "HEE"):
            m = _gap(m, side + part, -1.0, 1e3)
    p = _write("trc", m, tmp_path)
    if case == "spaces":
        p.write_text(p.read_text().replace("\t", " "))
    elif case == "decimal_comma":
        p.write_text(p.read_text().replace(".", ","))
    rc, _, err = _run([str(p), "--json"], capsys)
    assert rc == 2 and expect in err, err


@pytest.mark.parametrize("method", ["crossing", "heelstrike"])
def test_table_output_on_shrinking_windows(method: str, base: tuple[MarkerTrajectories, Doc],
                                           tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    """The human-readable table on ever shorter pieces of the walk: a table or one line,
    never an exception (values that cannot be computed are null in JSON, '—' here)."""
    m, _ = base
    n = len(m)
    for frac in (1.0, 0.8, 0.6, 0.5, 0.4, 0.3):
        for start in (0, n - int(n * frac)):
            v = _window(m, m.times[start], m.times[min(n - 1, start + int(n * frac) - 1)])
            p = _write("trc", v, tmp_path)
            rc = main(["gait", str(p), "--method", method])
            out, err = capsys.readouterr()
            assert rc in (0, 2) and "Traceback" not in err
            assert ("step length cm" in out) if rc == 0 else (err.count("\n") == 1), err


@pytest.mark.parametrize("value", ["inf", "-inf", "nan", "NaN", "-nan"])
def test_non_finite_cells_are_missing(value: str, base: tuple[MarkerTrajectories, Doc],
                                      tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    """An exporter's inf/nan cells are drop-outs: same steps, and no numpy warning."""
    import warnings

    m, ref = base
    lines = _trc_text(m, tmp_path).split("\n")
    k = 6 + int(np.searchsorted(m.times, _mid_time(ref)))
    cells = lines[k].split("\t")
    li = 2 + 3 * m.labels.index("LANK")
    cells[li:li + 3] = [value] * 3
    lines[k] = "\t".join(cells)
    p = tmp_path / "nf.trc"
    p.write_text("\n".join(lines))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rc, doc, err = _run([str(p), "--json"], capsys)
    assert rc == 0 and doc is not None, err
    _same_steps(ref, doc)


def test_byte_order_mark(skeleton: SkeletonSeries, tmp_path: Path,
                         capsys: pytest.CaptureFixture[str]) -> None:
    """Windows tools (Excel's 'CSV UTF-8', some TRC exporters) start text with a BOM."""
    ref = _csv_ref(skeleton, tmp_path, capsys)
    p = tmp_path / "bom.csv"
    p.write_bytes(b"\xef\xbb\xbf" + _csv_text(skeleton, tmp_path).replace("\n", "\r\n").encode())
    rc, doc, err = _run([str(p), "--json"], capsys)
    assert rc == 0 and doc is not None, err
    _same_steps(ref, doc)
    m = _synthetic()
    p0 = _write("trc", m, tmp_path)
    rc, ref_trc, err = _run([str(p0), "--json"], capsys)
    assert rc == 0 and ref_trc is not None, err
    p = tmp_path / "bom.trc"
    p.write_bytes(b"\xef\xbb\xbf" + p0.read_bytes())
    rc, doc, err = _run([str(p), "--json"], capsys)
    assert rc == 0 and doc is not None, err
    _same_steps(ref_trc, doc)


@pytest.mark.parametrize(("kind", "scale"), [("csv", 1e3), ("csv", 1e7), ("trc", 1e3)])
def test_time_not_in_seconds(kind: str, scale: float, skeleton: SkeletonSeries,
                             tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Times in ms or 100 ns ticks (Kinect SDK) are named as such (was: 'no straight
    walking found')."""
    if kind == "csv":
        s = SkeletonSeries(skeleton.times * scale + 5.0, skeleton.positions, skeleton.states,
                           skeleton.joint_set)
        p = tmp_path / "ms.csv"
        write_skeleton_csv(p, s)
    else:
        m = _synthetic()
        p = _write("trc", replace(m, times=m.times * scale, rate=100.0 / scale), tmp_path)
    rc, _, err = _run([str(p), "--json"], capsys)
    assert rc == 2 and "must be in seconds" in err and p.name in err, err
