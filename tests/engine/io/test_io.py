"""Round trips of the C3D / TRC / CSV readers-writers and unit/axis detection."""

from __future__ import annotations

from pathlib import Path

import ezc3d
import numpy as np
import pytest

from engine.errors import InputError
from engine.gait import GaitAnalysis
from engine.io.c3d import read_c3d, write_c3d, write_skeleton_c3d
from engine.io.csv import read_skeleton_csv, write_skeleton_csv
from engine.io.markers import (
    MarkerEvent,
    MarkerTrajectories,
    detect_units,
    detect_vertical_axis,
    find_marker,
    floor_axis,
    normalise_units,
    to_z_up,
    up_rotation,
)
from engine.io.trc import read_trc, write_trc
from engine.mocap import load_feet
from engine.sim.straight_walk import synth_walk, walk_markers, walk_skeleton
from engine.skeleton import KINECT_V2, SkeletonSeries, TrackingState


def _skeleton(rng: np.random.Generator) -> SkeletonSeries:
    w = synth_walk(rate=30.0, origin=(3.0, -2.0, 0.0))
    P = walk_skeleton(w) + rng.normal(0, 0.001, (len(w.times), 25, 3))
    S = np.full(P.shape[:2], TrackingState.TRACKED, dtype=np.uint8)
    S[5:9, 3] = TrackingState.INFERRED
    S[10:12, 14] = TrackingState.NOT_TRACKED
    P[10:12, 14] = np.nan
    return SkeletonSeries(w.times + 10.0, P, S, KINECT_V2)


def test_c3d_marker_round_trip_with_events(tmp_path: Path) -> None:
    m = walk_markers(synth_walk(origin=(2500.0, 1300.0, 0.0)))
    m.positions[3:6, 2] = np.nan
    m.times = m.times + 1.23  # starts on frame 123
    m.events = [MarkerEvent(1.5, "L", "foot_strike", "Foot Strike"),
                MarkerEvent(2.0, "R", "foot_off", "Foot Off"),
                MarkerEvent(75.25, "", "general", "General")]
    p = tmp_path / "a.c3d"
    write_c3d(p, m, units="mm")
    r = read_c3d(p)
    assert r.labels == m.labels and r.rate == m.rate and r.units == "mm"
    np.testing.assert_allclose(r.times, m.times, atol=1e-9)
    np.testing.assert_array_equal(np.isnan(r.positions), np.isnan(m.positions))
    # float32 storage: relative precision 6e-8 of 2.5 km-in-mm coordinates
    np.testing.assert_allclose(r.positions, m.positions, rtol=1e-6, atol=1e-6)
    assert [(e.side, e.kind) for e in r.events] == [("L", "foot_strike"), ("R", "foot_off"),
                                                    ("", "general")]
    np.testing.assert_allclose([e.time_s for e in r.events], [1.5, 2.0, 75.25], atol=1e-5)
    # readable by plain ezc3d as other tools would do
    c = ezc3d.c3d(str(p))
    assert c["parameters"]["POINT"]["LABELS"]["value"] == m.labels


@pytest.mark.parametrize(("data", "why"), [
    (b"not a c3d file at all", "the file is damaged or not a C3D file"),  # "iostream error"
    (b"\x02\x50" + b"\x00" * 600, "the file is damaged or not a C3D file"),  # "processor type"
    (b"", "the file is empty"),
])
def test_unreadable_c3d_says_what_it_is_not_and_what_to_do(tmp_path: Path, data: bytes,
                                                           why: str) -> None:
    """ezc3d's own words ("File must be a valid c3d file: iostream error") are not what a
    clinician can act on: the message says what the file is not and to export it again."""
    p = tmp_path / "trial 3.c3d"
    p.write_bytes(data)
    with pytest.raises(InputError) as err:
        read_c3d(p)
    assert str(err.value) == (f"cannot read trial 3.c3d as C3D: {why} (export it again from "
                              "the motion-capture software, as C3D)")


def _cut_message(name: str, held: int, announced: int) -> str:
    return (f"cannot read {name} as C3D: the file is cut short (it holds {held} of the "
            f"{announced} frames its header announces); copy or export it again")


def test_a_c3d_file_cut_short_is_refused_in_words(tmp_path: Path) -> None:
    """A copy or download that stopped leaves a C3D file that starts right: its first
    1 kB (of 86 kB) read as 525 frames of gaps, half of it as half the walk, without a
    word. The header's frame count, data start and point count say how long it must be;
    a file one byte short of its last frame is refused, one padded to a whole 512-byte
    block (as ezc3d writes them) or longer is read."""
    m = walk_markers(synth_walk())
    whole = tmp_path / "whole.c3d"
    write_c3d(whole, m, units="mm")
    data = whole.read_bytes()
    start = (data[16] + 256 * data[17] - 1) * 512  # header word 9: data block
    frame = 4 * len(m.labels) * 4  # float32 x, y, z, residual of each marker
    assert len(m) == 525 and len(data) > start + 525 * frame  # (padded to a block)
    cut = tmp_path / "walk.c3d"
    for size, held in [(1024, 0), (start + 2 * frame + 7, 2), (len(data) // 2, 259),
                       (start + 525 * frame - 1, 524)]:
        cut.write_bytes(data[:size])
        with pytest.raises(InputError) as err:
            read_c3d(cut)
        assert str(err.value) == _cut_message("walk.c3d", held, 525), size
    for size in (start + 525 * frame, len(data), len(data) + 1000):
        cut.write_bytes(data[:size] + b"\x00" * max(0, size - len(data)))
        r = read_c3d(cut)
        assert len(r) == 525 and not np.isnan(r.positions).all(), size


@pytest.mark.parametrize("kind", ["integer", "big-endian"])
def test_a_cut_c3d_file_is_told_from_its_header_of_any_kind(tmp_path: Path, kind: str) -> None:
    """The data's size per frame follows from the header: 2-byte integers where the scale
    factor is positive, words read big-endian where the processor is MIPS (86)."""
    m = walk_markers(synth_walk())
    whole = tmp_path / "whole.c3d"
    write_c3d(whole, m, units="mm")
    head = bytearray(whole.read_bytes())
    start = (head[16] + 256 * head[17] - 1) * 512
    value_bytes = 4
    if kind == "integer":  # scale factor +0.1 (little-endian float32)
        head[12:16] = np.float32(0.1).tobytes()
        value_bytes = 2
    else:
        words = np.frombuffer(bytes(head[2:22]), "<u2").astype(">u2").tobytes()
        scale = np.frombuffer(bytes(head[12:16]), "<f4").astype(">f4").tobytes()
        head[2:22] = words
        head[12:16] = scale
        head[(head[0] - 1) * 512 + 3] = 86
    frame = 4 * len(m.labels) * value_bytes
    p = tmp_path / "walk.c3d"
    p.write_bytes(bytes(head[:start + 100 * frame + 3]))
    with pytest.raises(InputError) as err:
        read_c3d(p)
    assert str(err.value) == _cut_message("walk.c3d", 100, 525)


def test_the_real_trial_cut_short_is_refused_and_whole_read(shared_data: Path,
                                                            tmp_path: Path) -> None:
    """kineticstoolkit's walk.c3d (Vicon Nexus: 96 points, 248 analog channels at 20
    samples a frame, 221 frames, data from block 111)."""
    f = shared_data / "mocap" / "kineticstoolkit" / "walk.c3d"
    if not f.is_file():
        pytest.skip(f"{f} absent")
    data = f.read_bytes()
    frame = (4 * 96 + 248 * 20) * 4
    start = 110 * 512
    assert len(data) >= start + 221 * frame
    cut = tmp_path / "walk.c3d"
    for size, held in [(1024, 0), (start, 0), (start + 2 * frame + 100, 2),
                       (len(data) - 1, 220)]:
        cut.write_bytes(data[:size])
        with pytest.raises(InputError) as err:
            read_c3d(cut)
        assert str(err.value) == _cut_message("walk.c3d", held, 221), size
    assert len(read_c3d(f)) == 221


def test_c3d_skeleton_export(tmp_path: Path) -> None:
    s = _skeleton(np.random.default_rng(0))
    ev = [MarkerEvent(11.0, "R", "placement", "placement")]
    write_skeleton_c3d(tmp_path / "s.c3d", s, ev)
    r = read_c3d(tmp_path / "s.c3d")
    assert r.labels == list(KINECT_V2.joints) and r.rate == pytest.approx(30.0)
    np.testing.assert_allclose(r.times, s.times, atol=1e-6)
    exp = s.positions.copy()
    np.testing.assert_allclose(r.positions, exp, atol=1e-6, equal_nan=True)
    assert r.events[0].kind == "placement"


def test_vicon_file_round_trip(shared_data: Path, tmp_path: Path) -> None:
    src = shared_data / "mocap" / "kineticstoolkit" / "walk.c3d"
    m = read_c3d(src)
    write_c3d(tmp_path / "w.c3d", m)
    r = read_c3d(tmp_path / "w.c3d")
    assert r.labels == m.labels and r.rate == m.rate and r.units == m.units
    np.testing.assert_allclose(r.times, m.times, atol=1e-9)
    np.testing.assert_allclose(r.positions, m.positions, rtol=1e-6, equal_nan=True)
    assert [(e.side, e.kind) for e in r.events] == [(e.side, e.kind) for e in m.events]
    np.testing.assert_allclose([e.time_s for e in r.events], [e.time_s for e in m.events],
                               atol=1e-6)
    write_trc(tmp_path / "w.trc", m)
    t = read_trc(tmp_path / "w.trc")
    assert t.labels == m.labels and t.rate == m.rate
    np.testing.assert_allclose(t.positions, m.positions, rtol=1e-12, equal_nan=True)


def _crossing_widths(path: Path) -> list[tuple[str, float]]:
    g = GaitAnalysis("crossing").fit(load_feet(path))
    return [(s.side, s.width_m) for s in g.steps_]


@pytest.mark.parametrize("units", ["mm", "m", "cm"])
def test_vicon_ankle_widths_survive_a_rewrite(shared_data: Path, tmp_path: Path,
                                              units: str) -> None:
    """The Plug-in Gait ankle widths read from PROCESSING are written back there (the
    points' unit, mm for a cm file), so a rewritten trial places the crossing method's
    ankle joint centres as the original does: the same step widths within 1 mm (the
    copy fell back to the 70 mm population width before, 3-4 mm narrower steps)."""
    src = shared_data / "mocap" / "kineticstoolkit" / "walk.c3d"
    m = read_c3d(src)
    assert m.meta["ankle_width_m"] == {"L": pytest.approx(0.064), "R": pytest.approx(0.063)}
    p = tmp_path / f"w_{units}.c3d"
    write_c3d(p, m, units=units)
    r = read_c3d(p)
    assert r.meta["ankle_width_m"] == {"L": pytest.approx(0.064), "R": pytest.approx(0.063)}
    assert "marker_diameter_m" not in r.meta  # the trial gives none: none invented
    # as Vicon tools and plain ezc3d read them: PROCESSING floats, mm or m
    proc = ezc3d.c3d(str(p))["parameters"]["PROCESSING"]
    want = (0.064, 0.063) if units == "m" else (64.0, 63.0)
    got = [float(np.ravel(proc[f"{s}AnkleWidth"]["value"])[0]) for s in ("L", "R")]
    np.testing.assert_allclose(got, want, rtol=1e-6)
    orig, copy = _crossing_widths(src), _crossing_widths(p)
    assert [s for s, _ in copy] == [s for s, _ in orig] and len(orig) >= 3
    np.testing.assert_allclose([w for _, w in copy], [w for _, w in orig], atol=1e-3)
    assert load_feet(p).notes == []  # no population width said to be used


def test_c3d_marker_diameter_and_one_side_written_back(tmp_path: Path) -> None:
    """A diameter and a single side's width go back as they came; a file without them
    has no PROCESSING group; a width that is not a length in metres is refused."""
    m = walk_markers(synth_walk())
    p = tmp_path / "none.c3d"
    write_c3d(p, m, units="mm")
    assert "PROCESSING" not in ezc3d.c3d(str(p))["parameters"]
    assert "ankle_width_m" not in read_c3d(p).meta
    m.meta = {"ankle_width_m": {"R": 0.071}, "marker_diameter_m": 0.025}
    for units in ("mm", "m"):
        write_c3d(tmp_path / f"one_{units}.c3d", m, units=units)
        r = read_c3d(tmp_path / f"one_{units}.c3d")
        assert r.meta["ankle_width_m"] == {"R": pytest.approx(0.071)}
        assert r.meta["marker_diameter_m"] == pytest.approx(0.025)
    for bad in ({"ankle_width_m": {"L": 64.0}}, {"ankle_width_m": 0.07},
                {"marker_diameter_m": float("nan")}):
        m.meta = bad
        with pytest.raises(InputError, match="metres"):
            write_c3d(tmp_path / "bad.c3d", m)


def test_trc_round_trip_exact(tmp_path: Path) -> None:
    m = walk_markers(synth_walk(), up="y")
    m.positions[7, 1] = np.nan
    for units in ("mm", "m"):
        write_trc(tmp_path / f"a_{units}.trc", m, units=units)
        r = read_trc(tmp_path / f"a_{units}.trc")
        assert r.labels == m.labels and r.rate == pytest.approx(m.rate) and r.units == units
        np.testing.assert_allclose(r.times, m.times, rtol=1e-15)
        np.testing.assert_allclose(r.positions, m.positions, rtol=1e-14, atol=1e-15,
                                   equal_nan=True)


def test_csv_round_trip_exact(tmp_path: Path) -> None:
    s = _skeleton(np.random.default_rng(1))
    write_skeleton_csv(tmp_path / "s.csv", s)
    r = read_skeleton_csv(tmp_path / "s.csv")
    assert r.joint_set is KINECT_V2
    np.testing.assert_array_equal(r.times, s.times)
    np.testing.assert_array_equal(r.states, s.states)
    np.testing.assert_array_equal(r.positions, s.positions)  # repr() is exact


def test_csv_without_states_and_partial_joints(tmp_path: Path) -> None:
    p = tmp_path / "p.csv"
    p.write_text("time,AnkleLeft_x,AnkleLeft_y,AnkleLeft_z\n0.0,1,2,3\n0.1,,,\n")
    r = read_skeleton_csv(p)
    i = KINECT_V2.index("AnkleLeft")
    assert r.states[0, i] == TrackingState.TRACKED and r.states[1, i] == 0
    assert r.states[0, KINECT_V2.index("Head")] == TrackingState.NOT_TRACKED


@pytest.mark.parametrize("text, match", [
    ("t,AnkleLeft_x\n", "first column"),
    ("time,Ankle_x,Ankle_y,Ankle_z\n0,1,2,3\n", "unknown joint"),
    ("time,AnkleLeft_x,AnkleLeft_y\n0,1,2\n", "lacks"),
    ("time,AnkleLeft_x,AnkleLeft_y,AnkleLeft_z\n0,a,2,3\n", "not a number"),
    ("time,AnkleLeft_x,AnkleLeft_y,AnkleLeft_z\n1,1,2,3\n0,1,2,3\n", "increasing"),
])
def test_csv_bad_input(tmp_path: Path, text: str, match: str) -> None:
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(InputError, match=match):
        read_skeleton_csv(p)


def test_bad_files_raise_input_error(tmp_path: Path) -> None:
    (tmp_path / "x.c3d").write_bytes(b"not a c3d file at all")
    (tmp_path / "x.trc").write_text("hello\n")
    for name in ("x.c3d", "x.trc"):
        with pytest.raises(InputError):
            load_feet(tmp_path / name)
    with pytest.raises(InputError, match="unsupported"):
        load_feet(tmp_path / "x.json")
    with pytest.raises(InputError, match="not found"):
        read_c3d(tmp_path / "missing.c3d")


def test_unit_and_vertical_axis_detection() -> None:
    m = walk_markers(synth_walk(origin=(40.0, 7.0, 0.0)))
    for scale, unit in ((1000.0, "mm"), (100.0, "cm"), (1.0, "m")):
        assert detect_units(m.positions * scale, m.labels) == unit
    assert detect_vertical_axis(m.positions, m.labels) == "z"
    Y = walk_markers(synth_walk(), up="y")
    assert detect_vertical_axis(Y.positions, Y.labels) == "y"
    assert detect_vertical_axis(-Y.positions, Y.labels) == "-y"
    # unlabelled markers: the axis with the largest body spread and least travel
    anon = [f"M{i}" for i in range(len(m.labels))]
    assert detect_vertical_axis(m.positions, anon) == "z"
    for up in ("x", "y", "z", "-x", "-y", "-z"):
        R = up_rotation(up)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(to_z_up([0.0, 1.0, 0.0], "y"), [0, 0, 1.0])
    with pytest.raises(InputError):
        up_rotation("w")


@pytest.mark.parametrize(("written", "unit"), [
    ("mm", "mm"), ("MM", "mm"), (" mm ", "mm"), ("[mm]", "mm"), ("Millimeter", "mm"),
    ("millimetres", "mm"), ("M", "m"), ("meters", "m"), ("Metre", "m"), ("CM", "cm"),
    ("centimeters", "cm"), ("", None), ("mm/s", None), ("ms", None), ("inch", None),
])
def test_unit_spellings(written: str, unit: str | None) -> None:
    assert normalise_units(written) == unit


@pytest.mark.parametrize(("labels", "side", "part", "found"), [
    (["LANK", "LHEE"], "L", "ankle", "LANK"),
    (["L.Ankle.Med", "L.Ankle.Lat"], "L", "ankle", "L.Ankle.Lat"),   # medial not taken
    (["LKneeOut", "LAnkleOut"], "L", "ankle", "LAnkleOut"),
    (["R_FCC", "R_FAL"], "R", "heel", "R_FCC"),
    (["Pat:r_ca", "Pat:r_lm"], "R", "ankle", "Pat:r_lm"),
    (["CA", "LM"], "L", "ankle", None),                             # two letters: side first
    (["LANKLE_WIDTH", "Ankle", "L_Ankle_Angle"], "L", "ankle", None),  # not markers
    (["ANKLE_RIGHT", "ANKLE_LEFT"], "L", "ankle", "ANKLE_LEFT"),
    (["RT_HEEL", "LT_HEEL"], "L", "heel", "LT_HEEL"),
    (["left_foot_index", "left_heel"], "L", "toe", "left_foot_index"),
    (["WaistLFront", "L_IAS"], "L", "asis", "L_IAS"),
    (["RMMA", "RLMA", "RPCA"], "R", "ankle", "RLMA"),               # Oxford Foot Model
    (["RMMA", "RLMA", "RPCA"], "R", "heel", "RPCA"),
    (["L.Med.Malleolus", "L.Lat.Malleolus"], "L", "ankle", "L.Lat.Malleolus"),
])
def test_marker_name_conventions(labels: list[str], side: str, part: str,
                                 found: str | None) -> None:
    assert find_marker(labels, side, part) == found


@pytest.mark.parametrize("heading", [0.0, 90.0, 45.0])
def test_floor_axis_of_feet_only(heading: float) -> None:
    """The vertical of feet-only markers, walking along an axis or not, with drop-outs
    (NaN samples beside finite central differences)."""
    m = walk_markers(synth_walk(heading_deg=heading))
    feet = [i for i, lab in enumerate(m.labels) if lab[1:] in ("ANK", "HEE", "TOE")]
    labels = [m.labels[i] for i in feet]
    P = m.positions[:, feet].copy()
    P[40:43, 0] = np.nan
    P[90, 3] = np.nan
    for up in ("x", "y", "z"):
        assert floor_axis(P @ up_rotation(up), labels) == "xyz".index(up)
        assert detect_vertical_axis(-(P @ up_rotation(up)), labels) == f"-{up}"
    assert floor_axis(P, ["A", "B", "C", "D", "E", "F"]) is None  # no sides: no pairs


def test_y_up_trc_in_mm_without_units_gives_same_gait(tmp_path: Path) -> None:
    w = synth_walk(origin=(5.0, 2.0, 0.0), heading_deg=20.0)
    ref = GaitAnalysis("crossing").fit(load_feet_from(walk_markers(w), tmp_path / "z.trc"))
    ym = walk_markers(w, up="y")
    write_trc(tmp_path / "y.trc", ym, units="mm")
    # strip the Units header value: the reader must guess mm from the body size
    lines = (tmp_path / "y.trc").read_text().splitlines()
    lines[2] = lines[2].replace("\tmm\t", "\t\t")
    (tmp_path / "y.trc").write_text("\n".join(lines) + "\n")
    f = load_feet(tmp_path / "y.trc")
    assert f.sources["up"] == "y"
    g = GaitAnalysis("crossing").fit(f)
    assert [round(s.length_m, 4) for s in g.steps_] == [round(s.length_m, 4) for s in ref.steps_]
    assert [round(s.width_m, 4) for s in g.steps_] == [round(s.width_m, 4) for s in ref.steps_]
    # explicit --up/--units give the same result
    g2 = GaitAnalysis("crossing").fit(load_feet(tmp_path / "y.trc", up="y", units="mm"))
    assert len(g2.steps_) == len(g.steps_)


def load_feet_from(m: MarkerTrajectories, path: Path):  # type: ignore[no-untyped-def]
    write_trc(path, m)
    return load_feet(path)


def test_skeleton_c3d_with_detected_gait_events(tmp_path: Path) -> None:
    s = _skeleton(np.random.default_rng(2))
    g = GaitAnalysis("crossing").fit(s.slice_time(s.times[0], s.times[-1]))
    write_skeleton_c3d(tmp_path / "g.c3d", s, g.marker_events())
    r = read_c3d(tmp_path / "g.c3d")
    assert [(e.side, e.kind) for e in r.events] == [(e.side, e.kind) for e in g.events_]
    np.testing.assert_allclose([e.time_s for e in r.events], [e.time_s for e in g.events_],
                               atol=1e-5)


def test_a_whole_c3d_file_whose_header_overstates_its_frames_is_read(tmp_path: Path) -> None:
    """Some writers' headers disagree with their parameters (here the header's analog
    samples per frame, word 3, with no analog channel in ANALOG:USED): the data is read by
    the parameters, so a file whole by them is read, never refused as cut short."""
    m = walk_markers(synth_walk())
    whole = tmp_path / "whole.c3d"
    write_c3d(whole, m, units="mm")
    head = bytearray(whole.read_bytes())
    head[4:6] = (40).to_bytes(2, "little")  # 40 analog samples a frame, by the header
    p = tmp_path / "walk.c3d"
    p.write_bytes(bytes(head))
    r = read_c3d(p)
    assert len(r) == 525 and np.allclose(r.positions, read_c3d(whole).positions,
                                         equal_nan=True)
    # cut short by both, it is refused (with the header's figures)
    p.write_bytes(bytes(head[:len(head) // 2]))
    with pytest.raises(InputError, match="the file is cut short"):
        read_c3d(p)
