"""``gaitrig gait`` on files as other labs' systems write them (the general case).

Variants of the real Vicon trial ``mocap/kineticstoolkit/walk.c3d`` (shared data) and of
the simulated walker, built once per module, each written as another lab would write it:
other headings and vertical axes, mirrored (left-handed) exports, units and their
spellings, C3D integer storage, analog channels, markers that are never seen, far from
the origin, other frame rates, drop-outs, other marker naming conventions, TRC and CSV
dialects. Through the CLI (in-process), each must give the same steps as the original —
same sides, lengths and widths within 1 mm, event times within one frame — or, where a
file cannot say something, one line naming the option to pass.

Complements ``test_mocap_sweep.py`` (which covers the basic unit/axis/name variants).
"""

from __future__ import annotations

import json
import struct
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from app.cli import main
from engine.io.c3d import read_c3d, write_c3d
from engine.io.csv import write_skeleton_csv
from engine.io.markers import MarkerTrajectories, up_rotation
from engine.io.trc import write_trc
from engine.sim.walker import Walker, WalkerParams
from engine.skeleton import KINECT_V2, SkeletonSeries, TrackingState

Doc = dict[str, Any]

#: Walker joints → Plug-in Gait labels (the walker has no heel: its ankles are primary).
_PIG = {"AnkleLeft": "LANK", "AnkleRight": "RANK", "FootLeft": "LTOE", "FootRight": "RTOE",
        "KneeLeft": "LKNE", "KneeRight": "RKNE", "SpineBase": "SACR", "Head": "HEAD"}


def _walker(rate: float = 100.0) -> MarkerTrajectories:
    w = Walker(WalkerParams(), [0.0, 0.0, 0.0], [5.0, 0.0, 0.0], start_time=0.5, seed=3)
    t = np.arange(round(7.0 * rate)) / rate
    idx = [KINECT_V2.index(j) for j in _PIG]
    return MarkerTrajectories(t, w.joints(t)[:, idx], list(_PIG.values()), rate, "m")


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, Doc | None, str]:
    rc = main(["gait", *argv])
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    if rc == 0:
        return rc, json.loads(out), err
    assert out == "" and err.count("\n") == 1 and err.startswith("gaitrig gait: error: "), err
    return rc, None, err


def _same_steps(ref: Doc, got: Doc, frame_s: float, tol_m: float = 1e-3,
                first_event_s: float | None = None) -> None:
    """Same sides and count, lengths/widths within ``tol_m``, times within one frame
    (the first event within ``first_event_s`` when given)."""
    a, b = ref["steps"], got["steps"]
    assert [s["side"] for s in b] == [s["side"] for s in a], (a, b)
    for sa, sb in zip(a, b, strict=True):
        assert sb["length_m"] == pytest.approx(sa["length_m"], abs=tol_m)
        assert sb["width_m"] == pytest.approx(sa["width_m"], abs=tol_m)
        assert sb["time_s"] == pytest.approx(sa["time_s"], abs=frame_s + 1e-6)
    ea = [(e["side"], e["kind"]) for e in ref["events"]]
    assert [(e["side"], e["kind"]) for e in got["events"]] == ea
    tol = [frame_s + 1e-6] * len(ea)
    if first_event_s is not None and tol:
        tol[0] = first_event_s
    for eg, er, tl in zip(got["events"], ref["events"], tol, strict=True):
        assert eg["time_s"] == pytest.approx(er["time_s"], abs=tl), (eg, er)


# ------------------------------------------------------------------ transforms


def _rz(deg: float) -> np.ndarray:
    a = np.deg2rad(deg)
    return np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0, 0, 1.0]])


def _map(m: MarkerTrajectories, A: np.ndarray | None = None,
         offset: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> MarkerTrajectories:
    """``p -> A p + offset`` on every marker (A may be a reflection)."""
    P = m.positions if A is None else m.positions @ np.asarray(A, dtype=float).T
    return replace(m, positions=P + np.asarray(offset))


def _file_axes(m: MarkerTrajectories, up: str) -> MarkerTrajectories:
    """Z-up markers as held by a file whose vertical axis is ``up`` (right-handed)."""
    return replace(m, positions=m.positions @ up_rotation(up))


def _centre_offset(m: MarkerTrajectories) -> np.ndarray:
    c = np.nanmean(m.positions, axis=(0, 1))
    return np.array([c[0], c[1], 0.0])


def _resample(m: MarkerTrajectories, rate: float) -> MarkerTrajectories:
    """The same walk sampled at ``rate`` (cubic spline through each coordinate)."""
    t = np.arange(np.ceil(m.times[0] * rate), np.floor(m.times[-1] * rate) + 1) / rate
    P = np.empty((len(t), len(m.labels), 3))
    for k in range(len(m.labels)):
        x = m.positions[:, k]
        ok = np.isfinite(x).all(axis=1)
        if ok.sum() < 4:
            P[:, k] = np.nan
            continue
        P[:, k] = CubicSpline(m.times[ok], x[ok])(t)
        P[(t < m.times[ok][0]) | (t > m.times[ok][-1]), k] = np.nan
    return replace(m, times=t, positions=P, rate=rate, events=[])


# ------------------------------------------------------------------ writers


def _write(kind: str, m: MarkerTrajectories, path: Path, units: str = "mm") -> Path:
    if kind == "c3d":
        write_c3d(path, m, units=units)
    else:
        write_trc(path, m, units=units)
    return path


def _write_c3d_int(path: Path, m: MarkerTrajectories, units: str = "mm",
                   write_units: bool = True, dec: bool = False,
                   header_rate: float | None = None) -> None:
    """A C3D in integer storage (positive ``POINT:SCALE``), as older Vicon/Motion
    Analysis systems write it; missing samples are 0,0,0 with residual -1.

    Written by hand (ezc3d writes float storage only): header, one parameter section
    (POINT: USED, FRAMES, SCALE, RATE, DATA_START, [UNITS,] LABELS) and int16 frames.
    ``dec``: a DEC (VAX) processor file, whose floats are DEC F-floats.
    ``header_rate``: the header's frame rate, if not ``POINT:RATE``'s.
    """

    def f32(v: float) -> bytes:
        ieee = struct.pack("<f", v * (4.0 if dec else 1.0))
        return ieee[2:] + ieee[:2] if dec else ieee

    scale_u = {"mm": 1e-3, "m": 1.0, "cm": 1e-2}[units]
    P = m.positions / scale_u
    T, M = P.shape[:2]
    scale = float(np.nanmax(np.abs(P))) / 30000.0
    labels = [lab.ljust(8)[:32] for lab in m.labels]
    width = max(len(lab) for lab in labels)

    def param(name: str, gid: int, type_: int, dims: list[int], data: bytes) -> bytes:
        body = struct.pack("<bB", type_, len(dims)) + bytes(dims) + data + b"\x00"
        nm = name.encode()
        return struct.pack("<bb", len(nm), gid) + nm + struct.pack("<h", len(body) + 2) + body

    first = round(float(m.times[0]) * m.rate) + 1
    grp = b"POINT"
    recs = [struct.pack("<bb", len(grp), -1) + grp + struct.pack("<h", 3) + b"\x00"]
    recs += [param("USED", 1, 2, [], struct.pack("<h", M)),
             param("FRAMES", 1, 2, [], struct.pack("<H", T)),
             param("SCALE", 1, 4, [], f32(scale)),
             param("RATE", 1, 4, [], f32(m.rate)),
             param("DATA_START", 1, 2, [], b"\x00\x00"),  # set below
             param("LABELS", 1, -1, [width, M],
                   b"".join(lab.ljust(width).encode() for lab in labels))]
    if write_units:
        recs.insert(-1, param("UNITS", 1, -1, [len(units)], units.encode()))
    n_blocks = -(-(4 + sum(len(r) for r in recs)) // 512)
    data_start = 2 + n_blocks
    recs[5] = param("DATA_START", 1, 2, [], struct.pack("<h", data_start))
    last = bytearray(recs[-1])  # offset 0: the last parameter of the section
    last[2 + len(b"LABELS"):4 + len(b"LABELS")] = b"\x00\x00"
    recs[-1] = bytes(last)
    sec = (struct.pack("<BBBB", 1, 0x50, n_blocks, 85 if dec else 84)
           + b"".join(recs)).ljust(512 * n_blocks, b"\x00")
    header = (struct.pack("<BBhhhhh", 2, 0x50, M, 0, first, first + T - 1, 10) + f32(scale)
              + struct.pack("<hh", data_start, 0)
              + f32(m.rate if header_rate is None else header_rate)).ljust(512, b"\x00")
    frames = bytearray()
    for t in range(T):
        for k in range(M):
            x = P[t, k]
            if np.all(np.isfinite(x)):
                frames += struct.pack("<hhhh", *np.round(x / scale).astype(int), 0)
            else:
                frames += struct.pack("<hhhh", 0, 0, 0, -1)
    path.write_bytes(header + sec + bytes(frames))


def _c3d_patched(path: Path, m: MarkerTrajectories, units: str = "mm",
                 edit: Callable[[Any], None] | None = None) -> Path:
    """Write with ezc3d, then change the file's parameters/data with ``edit(c3d)``."""
    import ezc3d

    write_c3d(path, m, units=units)
    if edit is not None:
        c = ezc3d.c3d(str(path))
        edit(c)
        c.write(str(path))
    return path


def _set_units(value: str) -> Callable[[Any], None]:
    def edit(c: Any) -> None:
        c["parameters"]["POINT"]["UNITS"]["value"] = [value]
    return edit


def _set_scale(value: float) -> Callable[[Any], None]:
    def edit(c: Any) -> None:
        c["parameters"]["POINT"]["SCALE"]["value"] = [value]
    return edit


def _with_analogs(c: Any) -> None:
    """16 analog channels at 10 samples per frame (force plates, EMG)."""
    n_frames = c["data"]["points"].shape[2]
    c["parameters"]["ANALOG"]["RATE"]["value"] = [10.0 * c["parameters"]["POINT"]["RATE"]
                                                 ["value"][0]]
    c["parameters"]["ANALOG"]["LABELS"]["value"] = tuple(f"EMG{i}" for i in range(16))
    c["parameters"]["ANALOG"]["USED"]["value"] = [16]
    rng = np.random.default_rng(0)
    c["data"]["analogs"] = rng.normal(size=(1, 16, 10 * n_frames))
    del c["data"]["meta_points"]


def _dead(labels: tuple[str, ...], zeros: bool) -> Callable[[MarkerTrajectories],
                                                             MarkerTrajectories]:
    """Markers listed in the file but never seen (NaN, or 0,0,0 as Vicon writes)."""
    def f(m: MarkerTrajectories) -> MarkerTrajectories:
        P = m.positions.copy()
        for lab in labels:
            if lab in m.labels:
                P[:, m.labels.index(lab)] = 0.0 if zeros else np.nan
        return replace(m, positions=P)
    return f


def _mirror(axis: int) -> np.ndarray:
    A = np.eye(3)
    A[axis, axis] = -1.0
    return A


#: name → (builder(markers, tmp) -> (file, extra CLI args)). Markers are metres, Z up.
Builder = Callable[[MarkerTrajectories, Path], tuple[Path, list[str]]]


def _plain(kind: str, f: Callable[[MarkerTrajectories], MarkerTrajectories],
           units: str = "mm", extra: list[str] | None = None) -> Builder:
    def b(m: MarkerTrajectories, tmp: Path) -> tuple[Path, list[str]]:
        return _write(kind, f(m), tmp / f"v.{kind}", units), list(extra or [])
    return b


def _patched(edit: Callable[[Any], None] | None, units: str = "mm",
             f: Callable[[MarkerTrajectories], MarkerTrajectories] = lambda m: m) -> Builder:
    def b(m: MarkerTrajectories, tmp: Path) -> tuple[Path, list[str]]:
        return _c3d_patched(tmp / "v.c3d", f(m), units, edit), []
    return b


def _int_c3d(units: str, write_units: bool = True, dec: bool = False,
             header_rate: float | None = None) -> Builder:
    def b(m: MarkerTrajectories, tmp: Path) -> tuple[Path, list[str]]:
        p = tmp / "v.c3d"
        _write_c3d_int(p, m, units, write_units, dec, header_rate)
        return p, []
    return b


def _centred(m: MarkerTrajectories) -> MarkerTrajectories:
    return _map(m, offset=tuple(-_centre_offset(m)))  # type: ignore[arg-type]


def _negative(m: MarkerTrajectories) -> MarkerTrajectories:
    c = _centre_offset(m)
    return _map(m, offset=(-c[0] - 12.0, -c[1] - 7.0, 0.0))


SAME: dict[str, Builder] = {
    # headings and vertical axes
    "walk_minus_x": _plain("trc", lambda m: _map(m, _rz(90.0))),
    "walk_plus_x": _plain("c3d", lambda m: _map(m, _rz(-90.0))),
    "walk_minus_y": _plain("c3d", lambda m: _map(m, _rz(180.0))),
    "walk_diagonal_45": _plain("trc", lambda m: _map(m, _rz(45.0))),
    "walk_diagonal_135": _plain("c3d", lambda m: _map(m, _rz(135.0))),
    "y_up": _plain("trc", lambda m: _file_axes(m, "y")),
    "y_up_given": _plain("trc", lambda m: _file_axes(m, "y"), extra=["--up", "y"]),
    "x_up": _plain("c3d", lambda m: _file_axes(m, "x")),
    "x_up_given": _plain("c3d", lambda m: _file_axes(m, "x"), extra=["--up", "x"]),
    # left-handed exports: one axis mirrored
    "mirror_x": _plain("c3d", lambda m: _map(m, _mirror(0))),
    "mirror_y": _plain("trc", lambda m: _map(m, _mirror(1))),
    "mirror_z": _plain("c3d", lambda m: _map(m, _mirror(2))),
    "mirror_y_up": _plain("trc", lambda m: _map(_file_axes(m, "y"), _mirror(2))),
    "mirror_x_up_given": _plain("trc", lambda m: _map(_file_axes(m, "x"), _mirror(1)),
                                extra=["--up", "x"]),
    # units and their spellings; C3D storage
    "c3d_units_MM": _patched(_set_units("MM")),
    "c3d_units_space_mm": _patched(_set_units(" mm")),
    "c3d_units_mm_padded": _patched(_set_units("mm  ")),
    "c3d_units_millimeter": _patched(_set_units("millimeter")),
    "c3d_units_M": _patched(_set_units("M"), units="m"),
    "c3d_units_meter": _patched(_set_units("Meter"), units="m"),
    "c3d_units_CM": _patched(_set_units("CM"), units="cm"),
    "c3d_units_empty_mm": _patched(_set_units(""), units="mm"),
    "c3d_units_empty_m": _patched(_set_units(""), units="m"),
    "c3d_scale_minus_0.1": _patched(_set_scale(-0.1)),
    "c3d_int_mm": _int_c3d("mm"),
    "c3d_int_cm": _int_c3d("cm"),
    "c3d_int_no_units_parameter": _int_c3d("mm", write_units=False),
    "c3d_int_dec_processor": _int_c3d("mm", dec=True),
    "c3d_header_rate_zero": _int_c3d("mm", header_rate=0.0),
    "c3d_analogs": _patched(_with_analogs),
    "c3d_no_event_group": _plain("c3d", lambda m: replace(m, events=[])),
    "c3d_dead_markers_nan": _plain("c3d", _dead(("LKNE", "RTOE", "LPSI", "SACR"), False)),
    "c3d_dead_markers_zero": _plain("c3d", _dead(("LKNE", "RTOE", "LPSI", "SACR"), True)),
    "c3d_dead_heels": _plain("c3d", _dead(("LHEE", "RHEE"), True)),
    "c3d_dead_knees_zero": _plain("c3d", _dead(("LKNE", "RKNE", "HEAD", "LTHI"), True)),
    # far from the origin, origin mid-walkway, negative half, floor not at 0
    "far_5km_c3d_mm": _plain("c3d", lambda m: _map(m, offset=(5e3, 5e3, 0.0))),
    "far_5km_c3d_m": _plain("c3d", lambda m: _map(m, offset=(5e3, -5e3, 0.0)), units="m"),
    "far_5km_trc": _plain("trc", lambda m: _map(m, offset=(-5e3, 5e3, 0.0))),
    "far_5km_y_up_c3d": _plain("c3d", lambda m: _file_axes(_map(m, offset=(5e3, 5e3, 0.0)),
                                                           "y")),
    "origin_mid_walkway": _plain("c3d", _centred),
    "negative_half": _plain("trc", _negative),
    "negative_half_y_up": _plain("c3d", lambda m: _file_axes(_negative(m), "y")),
    "floor_below_origin": _plain("c3d", lambda m: _map(m, offset=(0.0, 0.0, -0.9))),
    "origin_on_ceiling": _plain("trc", lambda m: _map(m, offset=(0.0, 0.0, -3.0))),
    "origin_on_ceiling_z_down": _plain("c3d", lambda m: _file_axes(
        _map(m, offset=(1.0, -2.0, -3.0)), "-z")),
    "floor_far_below_y_up": _plain("trc", lambda m: _file_axes(_map(m, offset=(0, 0, -30.0)),
                                                               "y")),
}


@pytest.fixture(scope="module")
def real(shared_data: Path, tmp_path_factory: pytest.TempPathFactory
         ) -> tuple[MarkerTrajectories, Doc]:
    """The real Vicon trial and the CLI's answer on it as the variants are written.

    The variants keep its markers but not its Plug-in Gait ``PROCESSING`` ankle widths
    (dropped here: ``write_c3d`` writes them back, TRC has no place for them), so the
    crossing method places their ankle joint centres with the population ankle width
    (``engine.mocap.DEFAULT_ANKLE_WIDTH_M``) instead of the subject's 63-64 mm: 3-4 mm
    narrower steps than on the original file. The reference is the trial written the
    same way (the original's own widths: ``test_lateral_ankle_markers_real_trial``).
    """
    f = shared_data / "mocap" / "kineticstoolkit" / "walk.c3d"
    m = read_c3d(f)
    m.meta.pop("ankle_width_m")
    p = tmp_path_factory.mktemp("real") / "walk.c3d"
    write_c3d(p, m)
    return m, _doc([str(p)])


@pytest.fixture(scope="module")
def synth(tmp_path_factory: pytest.TempPathFactory) -> tuple[MarkerTrajectories, Doc]:
    m = _walker()
    p = tmp_path_factory.mktemp("synth") / "ref.c3d"
    write_c3d(p, m)
    return m, _doc([str(p)])


def _doc(argv: list[str]) -> Doc:
    """The CLI's JSON for ``argv`` (for module fixtures, which cannot use capsys)."""
    import contextlib
    import io

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        rc = main(["gait", *argv, "--json"])
    assert rc == 0
    doc: Doc = json.loads(out.getvalue())
    assert len(doc["steps"]) >= 3
    return doc


@pytest.fixture(params=["real", "synth"])
def base(request: pytest.FixtureRequest) -> tuple[MarkerTrajectories, Doc]:
    return request.getfixturevalue(request.param)  # type: ignore[no-any-return]


#: Cases that kill a heel or toe marker of the real trial: that foot has no heel→toe
#: axis, so its lateral ankle marker is measured as it is (both feet) or moved across the
#: walking direction (one foot), as when the file has no such marker at all — their
#: reference is the trial's Plug-in Gait markers
#: without those (not the whole trial without them: its model outputs have an RFOO, which
#: is taken for a toe where no RTOE is listed).
_DEAD_FOOT = {"c3d_dead_heels": ("LHEE", "RHEE"),
              "c3d_dead_markers_nan": ("LKNE", "RTOE", "LPSI", "SACR"),
              "c3d_dead_markers_zero": ("LKNE", "RTOE", "LPSI", "SACR")}


def _without(m: MarkerTrajectories, labels: tuple[str, ...]) -> MarkerTrajectories:
    keep = [k for k, lab in enumerate(m.labels) if lab not in labels]
    return replace(m, positions=m.positions[:, keep], labels=[m.labels[k] for k in keep])


@pytest.mark.parametrize("case", sorted(SAME))
def test_same_walk_same_steps(case: str, base: tuple[MarkerTrajectories, Doc], tmp_path: Path,
                              capsys: pytest.CaptureFixture[str]) -> None:
    m, ref = base
    p, extra = SAME[case](m, tmp_path)
    rc, doc, err = _run([str(p), "--json", *extra], capsys)
    assert rc == 0 and doc is not None, err
    if case in _DEAD_FOOT and "LHEE" in m.labels:
        v = _without(_renamed(m, NAMINGS["plug_in_gait"]), _DEAD_FOOT[case])
        rc, ref, err = _run([str(_write("c3d", v, tmp_path / "ref.c3d")), "--json"], capsys)
        assert rc == 0 and ref is not None, err
        dead = {lab[0] for lab in _DEAD_FOOT[case] if lab[1:] in ("HEE", "TOE")}
        notes = doc["summary"]["notes"]
        if len(dead) == 2:  # neither foot has an axis: both markers kept
            assert all(any(f"marker {s}ANK is on the lateral" in n for n in notes)
                       for s in dead), notes
        else:  # the other foot's centre placed: this one's across the walking direction
            word = {"L": "left", "R": "right"}[dead.pop()]
            assert any(n.startswith(f"The {word} foot has no heel and toe") for n in notes)
    _same_steps(ref, doc, 1.0 / m.rate)


def test_units_that_are_no_length_are_guessed(real: tuple[MarkerTrajectories, Doc],
                                              tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    """A POINT:UNITS that is no length unit ('mm/s', a typo) was a hard error that even
    --units could not get past: the unit is guessed from the body, --units overrides."""
    m, ref = real
    p = _c3d_patched(tmp_path / "u.c3d", m, "mm", _set_units("mn"))
    for extra in ([], ["--units", "mm"]):
        rc, doc, err = _run([str(p), "--json", *extra], capsys)
        assert rc == 0 and doc is not None, err
        _same_steps(ref, doc, 0.01)


def test_c3d_without_a_frame_rate_is_named(synth: tuple[MarkerTrajectories, Doc],
                                           tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    m, _ = synth
    p = tmp_path / "r.c3d"
    _write_c3d_int(p, replace(m, rate=1.0, times=np.arange(len(m), dtype=float)),
                   header_rate=0.0)
    data = bytearray(p.read_bytes())
    i = data.index(b"RATE", 512) + 4 + 2 + 2  # name, offset, type and dimensions
    data[i:i + 4] = struct.pack("<f", 0.0)
    p.write_bytes(bytes(data))
    rc, _, err = _run([str(p), "--json"], capsys)
    assert rc == 2 and "r.c3d gives no frame rate" in err, err


# ------------------------------------------------------------------ frame rates

RATES = (50.0, 60.0, 119.88, 120.0, 150.0, 200.0, 250.0)


@pytest.mark.parametrize("rate", RATES)
def test_frame_rates_real(rate: float, real: tuple[MarkerTrajectories, Doc], tmp_path: Path,
                          capsys: pytest.CaptureFixture[str]) -> None:
    """The Vicon trial resampled (cubic spline) to other camera rates."""
    m, ref = real
    v = _resample(m, rate)
    for kind in ("c3d", "trc"):
        p = _write(kind, v, tmp_path / f"r.{kind}")
        rc, doc, err = _run([str(p), "--json"], capsys)
        assert rc == 0 and doc is not None, err
        _same_steps(ref, doc, max(1.0 / rate, 0.01))


@pytest.mark.parametrize("rate", RATES)
def test_frame_rates_walker(rate: float, synth: tuple[MarkerTrajectories, Doc],
                            tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The simulated walk sampled at other rates (exact positions at every rate).

    Its first event is the standing foot's placement of a start from standing, timed
    at the sample where the standing ends: measured 30 ms off at 50 Hz (1.5 frames),
    so it is held to two frames; every other event to one.
    """
    _, ref = synth
    p = _write("c3d", _walker(rate), tmp_path / "r.c3d")
    rc, doc, err = _run([str(p), "--json"], capsys)
    assert rc == 0 and doc is not None, err
    frame = max(1.0 / rate, 0.01)
    _same_steps(ref, doc, frame, first_event_s=2 * frame + 1e-6)


# ------------------------------------------------------------------ drop-outs

def _gaps(m: MarkerTrajectories, labels: list[str], t0: float, n: int, how: str,
          tmp: Path) -> Path:
    """``n`` frames of each of ``labels`` missing from ``t0`` on, as a file: NaN or
    0,0,0 (C3D), 0,0,0 with residual −1 as Vicon writes them (C3D), or empty cells (TRC)."""
    import ezc3d

    P = m.positions.copy()
    ks = [m.labels.index(lab) for lab in labels]
    i0 = int(np.searchsorted(m.times, t0))
    sel = np.arange(i0, i0 + n)
    for k in ks:
        P[sel, k] = 0.0 if how in ("zero", "residual") else np.nan
    v = replace(m, positions=P)
    if how == "empty":
        return _write("trc", v, tmp / "g.trc")
    p = _write("c3d", v, tmp / "g.c3d")
    if how == "residual":
        c = ezc3d.c3d(str(p))
        res = np.zeros((1, len(m.labels), len(m)))
        for k in ks:
            res[0, k, sel] = -1.0
        c["data"]["meta_points"]["residuals"] = res
        c.write(str(p))
    return p


_GAP_CASES = [(how, where, 100.0) for how in ("nan", "zero", "residual", "empty")
              for where in ("placement", "swing")]
_GAP_CASES += [(how, "placement", rate) for how in ("residual", "empty")
               for rate in (60.0, 250.0)]


@pytest.mark.parametrize(("how", "where", "rate"), _GAP_CASES)
def test_short_gaps_in_ankle_and_heel(how: str, where: str, rate: float,
                                      real: tuple[MarkerTrajectories, Doc], tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    """A few frames (~40 ms) missing in the ankle marker used for the steps and in the
    other foot's heel, at a foot placement or mid-swing: bridged, same steps."""
    m, ref = real
    v = m if rate == 100.0 else _resample(m, rate)
    s = ref["steps"][1]
    t0 = s["time_s"] - 0.02 if where == "placement" else s["time_s"] - 0.5 * s["duration_s"]
    other = "R" if s["side"] == "L" else "L"
    p = _gaps(v, [f"{s['side']}ANK", f"{other}HEE"], t0, max(3, round(0.04 * rate)), how,
              tmp_path)
    rc, doc, err = _run([str(p), "--json"], capsys)
    assert rc == 0 and doc is not None, err
    _same_steps(ref, doc, max(1.0 / rate, 0.01))


# ------------------------------------------------------------------ marker names

#: convention → names of (pelvis: L/R ASIS, L/R PSIS or one sacrum; left ankle, heel, toe,
#: knee); the right side's are made by swapping the side token.
NAMINGS: dict[str, dict[str, str]] = {
    "plug_in_gait": {"LASI": "LASI", "LPSI": "LPSI", "LANK": "LANK", "LHEE": "LHEE",
                     "LTOE": "LTOE", "LKNE": "LKNE"},
    "helen_hayes_sacrum": {"LASI": "LASI", "SACR": "SACR", "LANK": "LANK", "LHEE": "LHEE",
                           "LTOE": "LTOE", "LKNE": "LKNE"},
    "subject_prefix_lower": {"LASI": "Subject01:lasi", "LPSI": "Subject01:lpsi",
                             "LANK": "Subject01:lank", "LHEE": "Subject01:lhee",
                             "LTOE": "Subject01:ltoe", "LKNE": "Subject01:lkne"},
    "opensim_dots": {"LASI": "L.ASIS", "LPSI": "L.PSIS", "LANK": "L.Ankle", "LHEE": "L.Heel",
                     "LTOE": "L.Toe", "LKNE": "L.Knee"},
    "opensim_gait2392": {"LASI": "L.ASIS", "SACR": "V.Sacral", "LANK": "L.Ankle.Lat",
                         "LHEE": "L.Heel", "LTOE": "L.Toe.Tip", "LKNE": "L.Knee.Lat"},
    "cortex_underscore": {"LASI": "L_ASIS", "LPSI": "L_PSIS", "LANK": "L_Ankle",
                          "LHEE": "L_Heel", "LTOE": "L_Toe", "LKNE": "L_Knee"},
    "qualisys_cast": {"LASI": "L_IAS", "LPSI": "L_IPS", "LANK": "L_FAL", "LHEE": "L_FCC",
                      "LTOE": "L_FM2", "LKNE": "L_FLE"},
    "qualisys_malleolus_heels": {"LASI": "LASIS", "LPSI": "LPSIS", "LANK": "LLMA",
                                 "LHEE": "LDHE", "LTOE": "L2ND", "LKNE": "LLFC"},
    "qualisys_animation": {"LASI": "WaistLFront", "LPSI": "WaistLBack", "LANK": "LAnkleOut",
                           "LHEE": "LHeelBack", "LTOE": "LToeTip", "LKNE": "LKneeOut"},
    "ior_rizzoli": {"LASI": "L_ASIS", "LPSI": "L_PSIS", "LANK": "L_LM", "LHEE": "L_CA",
                    "LTOE": "L_FM2", "LKNE": "L_LE"},
    "word_prefix": {"LASI": "LeftASIS", "LPSI": "LeftPSIS", "LANK": "LeftAnkle",
                    "LHEE": "LeftHeel", "LTOE": "LeftToe", "LKNE": "LeftKnee"},
    "word_suffix": {"LASI": "ASIS_Left", "LPSI": "PSIS_Left", "LANK": "Ankle_Left",
                    "LHEE": "Heel_Left", "LTOE": "Toe_Left", "LKNE": "Knee_Left"},
    "lt_rt_prefix": {"LASI": "LT_ASIS", "LPSI": "LT_PSIS", "LANK": "LT_ANKLE",
                     "LHEE": "LT_HEEL", "LTOE": "LT_TOE", "LKNE": "LT_KNEE"},
    "letter_suffix": {"LASI": "ASIS_L", "LPSI": "PSIS_L", "LANK": "Ankle_L", "LHEE": "Heel_L",
                      "LTOE": "Toe_L", "LKNE": "Knee_L"},
    "openpose_markerless": {"LASI": "LHip", "SACR": "MidHip", "LANK": "LAnkle",
                            "LHEE": "LHeel", "LTOE": "LBigToe", "LKNE": "LKnee"},
    "mediapipe_markerless": {"LASI": "left_hip", "LANK": "left_ankle", "LHEE": "left_heel",
                             "LTOE": "left_foot_index", "LKNE": "left_knee"},
    "theia_markerless": {"LASI": "l_hip", "SACR": "pelvis", "LANK": "l_ankle",
                         "LHEE": "l_heel", "LTOE": "l_toe", "LKNE": "l_knee"},
    "kinect": {"SACR": "SpineBase", "LANK": "AnkleLeft", "LTOE": "FootLeft",
               "LKNE": "KneeLeft"},
    "azure_kinect": {"SACR": "PELVIS", "LANK": "ANKLE_LEFT", "LTOE": "FOOT_LEFT",
                     "LKNE": "KNEE_LEFT"},
}


def _right(name: str) -> str:
    """The right side's name of a left-side name in any of the conventions above."""
    for a, b in (("Left", "Right"), ("left", "right"), ("LEFT", "RIGHT"), ("WaistL", "WaistR")):
        if a in name:
            return name.replace(a, b)
    head, sep, bare = name.rpartition(":")
    if bare.endswith(("_L", ".L")):
        return name[:-1] + "R"
    if bare[:1] in "Ll":
        return head + sep + ("R" if bare[0] == "L" else "r") + bare[1:]
    return name


def _renamed(m: MarkerTrajectories, names: dict[str, str]) -> MarkerTrajectories:
    """Only the markers the convention has, under its names (a sacrum from the PSIS)."""
    pos, labels = [], []
    for pig, name in names.items():
        for side_pig, side_name in ((pig, name), ("R" + pig[1:], _right(name))):
            if pig == "SACR":
                x = m.positions[:, [m.index("LPSI"), m.index("RPSI")]].mean(axis=1)
            else:  # (for a hip joint centre, the ASIS stands in)
                x = m.marker(side_pig)
            if side_name not in labels:
                pos.append(x)
                labels.append(side_name)
    return replace(m, positions=np.stack(pos, axis=1), labels=labels)


#: Conventions whose ankle name (a bare ``Ankle``) names the joint itself, as skeletons
#: and markerless trackers do: the point is measured as it is. Renamed from the real
#: trial's lateral-malleolus LANK, their steps are those of the Plug-in Gait file with
#: LANK/RANK named explicitly (the marker itself), not of its estimated joint centres.
JOINT_ANKLE_NAMINGS = ("opensim_dots", "cortex_underscore", "word_prefix", "word_suffix",
                       "lt_rt_prefix", "letter_suffix", "openpose_markerless",
                       "mediapipe_markerless", "theia_markerless", "kinect", "azure_kinect")


@pytest.fixture(scope="module")
def real_feet_ref(real: tuple[MarkerTrajectories, Doc],
                  tmp_path_factory: pytest.TempPathFactory) -> dict[str, Doc]:
    """The CLI's answer on the real trial's own labels, per pelvis convention (the
    body centre used to find the walking passes is the pelvis markers' mean), and with
    the lateral ankle markers measured as they are (``… as_is``)."""
    m, _ = real
    out = {}
    for key in ("plug_in_gait", "helen_hayes_sacrum", "no_pelvis"):
        names = NAMINGS["plug_in_gait" if key == "no_pelvis" else key]
        if key == "no_pelvis":
            names = {k: v for k, v in names.items() if k not in ("LASI", "LPSI")}
        p = tmp_path_factory.mktemp("names") / f"{key}.c3d"
        write_c3d(p, _renamed(m, names))
        out[key] = _doc([str(p)])
        out[f"{key} as_is"] = _doc([str(p), "--left", "LANK", "--right", "RANK"])
    return out


def _names_ref(naming: str, refs: dict[str, Doc]) -> Doc:
    names = NAMINGS[naming]
    pelvis = ("no_pelvis" if "LASI" not in names and "SACR" not in names
              else "plug_in_gait")
    return refs[pelvis + (" as_is" if naming in JOINT_ANKLE_NAMINGS else "")]


@pytest.mark.parametrize("naming", sorted(NAMINGS))
def test_marker_naming_conventions(naming: str, real: tuple[MarkerTrajectories, Doc],
                                   real_feet_ref: dict[str, Doc], tmp_path: Path,
                                   capsys: pytest.CaptureFixture[str]) -> None:
    """Ankle, heel, toe and pelvis found under each convention: the same steps as the
    Plug-in Gait names (the ankle is the point measured when both ankle and heel exist:
    the joint centre of a lateral-malleolus name, a joint's name as it is)."""
    m, _ = real
    names = NAMINGS[naming]
    p = _write("trc", _renamed(m, names), tmp_path / "n.trc")
    rc, doc, err = _run([str(p), "--json"], capsys)
    assert rc == 0 and doc is not None, err
    _same_steps(_names_ref(naming, real_feet_ref), doc, 0.01)


def test_ankle_preferred_over_heel(real: tuple[MarkerTrajectories, Doc], tmp_path: Path,
                                   capsys: pytest.CaptureFixture[str]) -> None:
    """With both, the crossing method measures the ankle and the heel-strike method the
    heel (docs/gait-json.md, "Inputs"); without an ankle the heel is measured, and
    --left/--right choose either."""
    from engine.mocap import load_feet

    m, _ref = real
    both = _write("c3d", _renamed(m, NAMINGS["cortex_underscore"]), tmp_path / "b.c3d")
    feet = load_feet(both)
    assert feet.primary == {"L": "ankle", "R": "ankle"}
    assert (feet.sources["L_ankle"], feet.sources["L_heel"]) == ("L_Ankle", "L_Heel")
    no_ankle = {k: v for k, v in NAMINGS["cortex_underscore"].items() if k != "LANK"}
    heel = _write("c3d", _renamed(m, no_ankle), tmp_path / "h.c3d")
    assert load_feet(heel).primary == {"L": "heel", "R": "heel"}
    rc, by_heel, err = _run([str(heel), "--json"], capsys)
    assert rc == 0 and by_heel is not None, err
    rc, chosen, err = _run([str(both), "--json", "--left", "l_heel", "--right", "R_HEEL"],
                           capsys)
    assert rc == 0 and chosen is not None, err
    _same_steps(by_heel, chosen, 0.01)
    # the heel-strike method measures the heel when both are there
    runs = [_run([str(both), "--json", "--method", "heelstrike", *extra], capsys)
            for extra in ([], ["--left", "L_Heel", "--right", "R_Heel"])]
    assert all(rc == 0 for rc, _, _ in runs), runs
    _same_steps(runs[1][1], runs[0][1], 0.01)  # type: ignore[arg-type]


@pytest.mark.parametrize("naming", ["opensim_gait2392", "qualisys_cast", "ior_rizzoli",
                                    "qualisys_animation", "mediapipe_markerless", "kinect"])
@pytest.mark.parametrize("up", ["y", "-y", "x"])
def test_naming_conventions_other_axes(naming: str, up: str,
                                       real: tuple[MarkerTrajectories, Doc],
                                       real_feet_ref: dict[str, Doc], tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    """The names also tell up from down (pelvis/hips above the feet) in other axes."""
    m, _ = real
    names = NAMINGS[naming]
    p = _write("c3d", _file_axes(_renamed(m, names), up), tmp_path / "n.c3d")
    rc, doc, err = _run([str(p), "--json"], capsys)
    assert rc == 0 and doc is not None, err
    # (kinect, mediapipe: joint names, the markers as they are — JOINT_ANKLE_NAMINGS)
    ref = real_feet_ref["plug_in_gait" + (" as_is" if naming in JOINT_ANKLE_NAMINGS else "")]
    _same_steps(ref, doc, 0.01)


# ------------------------------------------------------------------ TRC dialects

def _trc_lines(m: MarkerTrajectories, tmp: Path, units: str = "mm") -> list[str]:
    p = tmp / "_base.trc"
    write_trc(p, m, units=units)
    return p.read_text().split("\n")


def _cortex(lines: list[str]) -> list[str]:
    """Cortex: a Windows path in line 1, names and data rows ending in tabs, CRLF."""
    out = list(lines)
    out[0] = "PathFileType\t4\t(X/Y/Z)\tC:\\Cortex\\Data\\walk.trc"
    return [ln + "\t" if i >= 3 and ln else ln for i, ln in enumerate(out)]


def _no_xyz_row(lines: list[str]) -> list[str]:
    """No X1/Y1/Z1 row and no blank line: the data start on line 5."""
    return lines[:4] + [ln for ln in lines[5:] if ln]


def _wrong_rate(lines: list[str]) -> list[str]:
    """A DataRate that disagrees with the Time column (a resampled export)."""
    out = list(lines)
    vals = out[2].split("\t")
    vals[0] = vals[1] = str(float(vals[0]) * 2.5)
    out[2] = "\t".join(vals)
    return out


def _opensim_metres(lines: list[str]) -> list[str]:
    """OpenSim's own writer: metres, 'm' in the header, trailing tab on header lines."""
    return [ln + "\t" if i in (1, 2) else ln for i, ln in enumerate(lines)]


TRC_DIALECTS: dict[str, tuple[str, Callable[[list[str]], list[str]], str, bytes]] = {
    # name: (units written, edit of the lines, line ending, prefix bytes)
    "cortex_crlf": ("mm", _cortex, "\r\n", b""),
    "bom_crlf_trailing_tabs": ("mm", lambda ls: [ln + "\t\t" for ln in ls], "\r\n",
                               b"\xef\xbb\xbf"),
    "opensim_metres": ("m", _opensim_metres, "\n", b""),
    "units_upper_M": ("m", lambda ls: [ln.replace("\tm\t", "\tM\t") for ln in ls], "\n", b""),
    "units_word_meters": ("m", lambda ls: [ln.replace("\tm\t", "\tmeters\t") for ln in ls],
                          "\n", b""),
    "no_xyz_row": ("mm", _no_xyz_row, "\n", b""),
    "wrong_data_rate": ("mm", _wrong_rate, "\n", b""),
    "old_mac_cr": ("mm", lambda ls: ls, "\r", b""),
}


@pytest.mark.parametrize("case", sorted(TRC_DIALECTS))
def test_trc_dialects(case: str, base: tuple[MarkerTrajectories, Doc], tmp_path: Path,
                      capsys: pytest.CaptureFixture[str]) -> None:
    m, ref = base
    units, edit, eol, prefix = TRC_DIALECTS[case]
    p = tmp_path / "d.trc"
    p.write_bytes(prefix + eol.join(edit(_trc_lines(m, tmp_path, units))).encode())
    rc, doc, err = _run([str(p), "--json"], capsys)
    assert rc == 0 and doc is not None, err
    _same_steps(ref, doc, 1.0 / m.rate)


def test_trc_first_frame_kept_without_xyz_row(synth: tuple[MarkerTrajectories, Doc],
                                              tmp_path: Path) -> None:
    from engine.io.trc import read_trc

    m, _ = synth
    p = tmp_path / "d.trc"
    p.write_text("\n".join(_no_xyz_row(_trc_lines(m, tmp_path))))
    got = read_trc(p)
    assert len(got) == len(m) and got.times[0] == m.times[0]
    assert got.rate == m.rate


# ------------------------------------------------------------------ skeleton CSV dialects

@pytest.fixture(scope="module")
def skeleton_csv(tmp_path_factory: pytest.TempPathFactory) -> tuple[str, Doc]:
    """The walker as a skeleton CSV (our schema, with _state columns) and its answer."""
    w = Walker(WalkerParams(), [0.0, 0.0, 0.0], [5.0, 0.0, 0.0], start_time=0.5, seed=3)
    t = np.arange(700) / 100.0
    J = w.joints(t)
    s = SkeletonSeries(t, J, np.full(J.shape[:2], TrackingState.TRACKED, dtype=np.uint8),
                       KINECT_V2)
    p = tmp_path_factory.mktemp("csv") / "ref.csv"
    write_skeleton_csv(p, s)
    return p.read_text(), _doc([str(p)])


def _columns(text: str, edit: Callable[[list[list[str]]], list[list[str]]]) -> str:
    rows = [ln.split(",") for ln in text.strip().split("\n")]
    return "\n".join(",".join(r) for r in edit(rows)) + "\n"


def _insert(rows: list[list[str]], at: int, name: str,
            value: Callable[[int], str]) -> list[list[str]]:
    return [[*r[:at], name if i == 0 else value(i), *r[at:]] for i, r in enumerate(rows)]


def _move_time(rows: list[list[str]]) -> list[list[str]]:
    return [[*r[1:7], r[0], *r[7:]] for r in rows]


CSV_DIALECTS: dict[str, Callable[[str], str]] = {
    "pandas_index_column": lambda s: _columns(s, lambda rs: _insert(rs, 0, "",
                                                                    lambda i: str(i - 1))),
    "extra_columns": lambda s: _columns(s, lambda rs: _insert(
        _insert(rs, 1, "frame", str), 5, "body_id", lambda i: "72057594037928806")),
    "text_column": lambda s: _columns(s, lambda rs: _insert(rs, 3, "subject",
                                                            lambda i: "P01")),
    "time_not_first": lambda s: _columns(s, _move_time),
    "Time_capital_upper_axes": lambda s: _columns(s, lambda rs: [
        [c.replace("_x", "_X").replace("_y", "_Y").replace("_z", "_Z") if i == 0 else c
         for c in r] if i == 0 else r for i, r in enumerate(
            [["Time", *rs[0][1:]], *rs[1:]])]),
    "time_s_column": lambda s: s.replace("time,", "time_s,", 1),
    "lower_case_joints": lambda s: s.replace(s.split("\n", 1)[0], s.split("\n", 1)[0].lower()),
    "bom_crlf": lambda s: "\ufeff" + s.replace("\n", "\r\n"),
    "no_states_trailing_comma": lambda s: _columns(s, lambda rs: [
        [c for j, c in enumerate(r) if not rs[0][j].endswith("_state")] + [""] for r in rs]),
}


@pytest.mark.parametrize("case", sorted(CSV_DIALECTS))
def test_csv_dialects(case: str, skeleton_csv: tuple[str, Doc], tmp_path: Path,
                      capsys: pytest.CaptureFixture[str]) -> None:
    text, ref = skeleton_csv
    p = tmp_path / "d.csv"
    p.write_bytes(CSV_DIALECTS[case](text).encode())
    rc, doc, err = _run([str(p), "--json"], capsys)
    assert rc == 0 and doc is not None, err
    _same_steps(ref, doc, 0.01)


#: The start of a Vicon Nexus and of an OptiTrack Motive CSV export.
_NEXUS_CSV = ("Trajectories\n100\n,,Sub01:LASI,,,Sub01:RASI,,\n"
              "Frame,Sub Frame,X,Y,Z,X,Y,Z\n,,mm,mm,mm,mm,mm,mm\n1,0,1,2,3,4,5,6\n")
_MOTIVE_CSV = ("Format Version,1.23,Take Name,walk,Capture Frame Rate,120.000000,"
               "Length Units,Millimeters\n\n,,Marker,Marker\n,,Sub01:LANK,Sub01:LANK\n"
               "Frame,Time (Seconds),X,Y\n0,0.000000,1.0,2.0\n")


@pytest.mark.parametrize(("case", "expect"), [
    ("unknown_joint", "unknown joint names in CSV header: Ankle_Lft"),
    ("no_time", "no 'time' column"),
    ("vicon_nexus", "d.csv is a Vicon Nexus CSV export, not a skeleton CSV: give the trial "
                    "exported as C3D"),
    ("motive", "d.csv is an OptiTrack Motive CSV export"),
])
def test_csv_dialects_refused(case: str, expect: str, skeleton_csv: tuple[str, Doc],
                              tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """What is no skeleton CSV is named, with what to give instead."""
    text, _ = skeleton_csv
    head, rest = text.split("\n", 1)
    if case == "unknown_joint":
        head = head.replace("AnkleLeft_", "Ankle_Lft_")
    elif case == "no_time":
        head = head.replace("time,", "frame,", 1)
    else:
        head, rest = "", _NEXUS_CSV if case == "vicon_nexus" else _MOTIVE_CSV
    p = tmp_path / "d.csv"
    p.write_text((head + "\n" if head else "") + rest)
    rc, _, err = _run([str(p), "--json"], capsys)
    assert rc == 2 and expect in err, err


# ------------------------------------------------------------------ heel-strike method

HEELSTRIKE_CASES = ("walk_minus_x", "walk_diagonal_135", "y_up", "x_up", "mirror_y",
                    "mirror_y_up", "c3d_units_MM", "c3d_int_mm", "far_5km_c3d_mm",
                    "negative_half_y_up", "floor_below_origin", "c3d_dead_knees_zero")
#: Storage that rounds coordinates (int16 at 0.17 mm, float32 at 5 km: 0.5 mm) is
#: checked on the real trial only. On the walker (measured): footprints move by up to
#: 1.4 mm — it has no heel marker, so its ankle is taken at the strike instant, while it
#: still rolls forward, and the rounding moves that instant by a few ms — and the last
#: foot off (a closing step whose toe rises at two near-equal speeds 0.15 s apart) by
#: 98 ms. Both are the walker's, not the file's.
_ROUNDED = ("c3d_int_mm", "far_5km_c3d_mm")


@pytest.mark.parametrize("case", HEELSTRIKE_CASES)
def test_same_walk_same_heel_strikes(case: str, base: tuple[MarkerTrajectories, Doc],
                                     tmp_path: Path,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    """Foot strikes and offs need the sign of up and the heel/toe points: the same events
    (within a frame) and steps in every variant."""
    m, _ = base
    if case in _ROUNDED and "HEAD" in m.labels:
        pytest.skip("rounded storage is checked on the real trial (see _ROUNDED)")
    ref_p = _write("c3d", m, tmp_path / "ref.c3d")
    rc, ref, err = _run([str(ref_p), "--json", "--method", "heelstrike"], capsys)
    assert rc == 0 and ref is not None, err
    p, extra = SAME[case](m, tmp_path)
    rc, doc, err = _run([str(p), "--json", "--method", "heelstrike", *extra], capsys)
    assert rc == 0 and doc is not None, err
    _same_steps(ref, doc, 1.0 / m.rate)


@pytest.mark.parametrize("rate", [60.0, 150.0, 250.0])
def test_heel_strikes_at_other_rates(rate: float, real: tuple[MarkerTrajectories, Doc],
                                     tmp_path: Path,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    """Vicon-annotated foot strikes/offs of the real trial found at other rates too:
    within 20 ms (as at 100 Hz, tests/engine/test_gait_c3d.py) plus one frame."""
    from engine.agreement import match_events
    from engine.gait import GaitAnalysis
    from engine.mocap import load_feet

    m, _ = real
    p = _write("c3d", _resample(m, rate), tmp_path / "r.c3d")
    ga = GaitAnalysis("heelstrike").fit(load_feet(p))
    truth = [e for e in m.events if e.kind in ("foot_strike", "foot_off")]
    pairs = match_events(ga.events_, truth)
    assert len(pairs) == len(truth)
    for det, ann in pairs:
        assert abs(det.time_s - ann.time_s) <= 0.02 + 1.0 / rate, (det, ann)


# ------------------------------------------------------------------ whole labs

def _lab(m: MarkerTrajectories, naming: str, up: str, heading_deg: float,
         offset: tuple[float, float, float], rate: float) -> MarkerTrajectories:
    v = _renamed(m, NAMINGS[naming])
    v = _map(v, _rz(heading_deg), offset)
    if rate != m.rate:
        v = _resample(v, rate)
    return _file_axes(v, up)


LABS: dict[str, tuple[str, str, float, tuple[float, float, float], float, str, str]] = {
    # name: (naming, up, heading, offset (m, Z up), rate, format, units)
    "pose2sim_markerless_trc": ("openpose_markerless", "y", 90.0, (-1.5, 3.0, 0.0), 60.0,
                                "trc", "m"),
    "opensim_gait2392_trc": ("opensim_gait2392", "y", -90.0, (0.3, -0.4, 0.0), 60.0, "trc",
                             "mm"),
    "qualisys_cast_c3d": ("qualisys_cast", "z", 180.0, (250.0, -40.0, 0.0), 150.0, "c3d",
                          "mm"),
    "mediapipe_feet_x_up_c3d": ("mediapipe_markerless", "x", 30.0, (0.0, 0.0, -1.2), 50.0,
                                "c3d", "m"),
    "ior_mirrored_trc": ("ior_rizzoli", "-y", 45.0, (12.0, 8.0, 0.0), 200.0, "trc", "cm"),
}


@pytest.mark.parametrize("lab", sorted(LABS))
def test_whole_lab_conventions(lab: str, real: tuple[MarkerTrajectories, Doc],
                               real_feet_ref: dict[str, Doc], tmp_path: Path,
                               capsys: pytest.CaptureFixture[str]) -> None:
    """Several differences at once, as another lab's file has them: names, vertical axis,
    heading, origin, rate, format and unit (the IOR one also mirrored)."""
    m, _ = real
    naming, up, heading, offset, rate, kind, units = LABS[lab]
    v = _lab(m, naming, up, heading, offset, rate)
    if lab.startswith("ior_mirrored"):
        v = _map(v, _mirror(0))
    p = _write(kind, v, tmp_path / f"lab.{kind}", units)
    rc, doc, err = _run([str(p), "--json"], capsys)
    assert rc == 0 and doc is not None, err
    # (pose2sim, mediapipe: joint names, the markers as they are — JOINT_ANKLE_NAMINGS)
    ref = real_feet_ref["plug_in_gait" + (" as_is" if naming in JOINT_ANKLE_NAMINGS else "")]
    _same_steps(ref, doc, max(1.0 / rate, 0.01))


def test_kinect_csv_camera_frame(skeleton_csv: tuple[str, Doc], tmp_path: Path,
                                 capsys: pytest.CaptureFixture[str]) -> None:
    """A skeleton CSV at Kinect's 30 Hz in a camera-like frame (Y up, walking along the
    depth axis, offset): the same steps as the 100 Hz world-frame file. The first event
    (the standing foot's placement, timed at the sample where the standing ends) is held
    to two frames, as in test_frame_rates_walker (measured: 43 ms = 1.3 frames)."""
    _, ref = skeleton_csv
    rate = 30.0
    w = Walker(WalkerParams(), [0.0, 0.0, 0.0], [5.0, 0.0, 0.0], start_time=0.5, seed=3)
    t = np.arange(round(7.0 * rate)) / rate
    J = w.joints(t)
    J = _map(MarkerTrajectories(t, J, list(KINECT_V2.joints), rate), _rz(90.0),
             (0.0, 8.0, 0.0)).positions @ up_rotation("y")
    s = SkeletonSeries(t, J, np.full(J.shape[:2], TrackingState.TRACKED, dtype=np.uint8),
                       KINECT_V2)
    p = tmp_path / "k.csv"
    write_skeleton_csv(p, s)
    rc, doc, err = _run([str(p), "--json"], capsys)
    assert rc == 0 and doc is not None, err
    _same_steps(ref, doc, 1.0 / rate, first_event_s=2.0 / rate)


# ------------------------------------------------------------------ feet-only files

_FEET = ("LANK", "RANK", "LHEE", "RHEE", "LTOE", "RTOE")


def _feet_only(m: MarkerTrajectories) -> MarkerTrajectories:
    idx = [m.labels.index(lab) for lab in _FEET]
    return replace(m, positions=m.positions[:, idx], labels=list(_FEET))


@pytest.fixture(scope="module")
def feet_only_ref(real: tuple[MarkerTrajectories, Doc],
                  tmp_path_factory: pytest.TempPathFactory) -> dict[str, Doc]:
    """The real trial's foot markers alone, Z up given, per method."""
    p = tmp_path_factory.mktemp("feet") / "ref.trc"
    write_trc(p, _feet_only(real[0]))
    return {meth: _doc([str(p), "--up", "z", "--method", meth])
            for meth in ("crossing", "heelstrike")}


@pytest.mark.parametrize(("heading", "up"), [
    (0.0, "z"), (90.0, "z"), (180.0, "y"), (270.0, "-y"), (0.0, "x"), (90.0, "-z"),
    (30.0, "y"), (0.0, "-y"),
])
def test_feet_only_any_heading(heading: float, up: str, real: tuple[MarkerTrajectories, Doc],
                               feet_only_ref: dict[str, Doc], tmp_path: Path,
                               capsys: pytest.CaptureFixture[str]) -> None:
    """Ankle, heel and toe markers only, walking along an axis of the file: the lateral
    axis was taken for the vertical one (the feet's spread and travel decided; widths
    came out 0.5 cm): now the axis along which the still feet are at one level."""
    m, _ = real
    p = _write("trc", _file_axes(_map(_feet_only(m), _rz(heading), (3.0, -1.0, 0.0)), up),
               tmp_path / "f.trc")
    for meth in ("crossing", "heelstrike"):
        rc, doc, err = _run([str(p), "--json", "--method", meth], capsys)
        assert rc == 0 and doc is not None, err
        _same_steps(feet_only_ref[meth], doc, 0.01)


def test_feet_that_cannot_tell_up_ask_for_it(real: tuple[MarkerTrajectories, Doc],
                                             tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    """Feet whose still positions spread alike along two axes (here: the heights copied
    into the lateral axis) do not tell the vertical one: --up is asked for, and works."""
    m, _ = real
    v = _feet_only(m)
    P = v.positions.copy()
    P[..., 0] = P[..., 2]  # the walk is along Y
    p = _write("trc", replace(v, positions=P), tmp_path / "f.trc")
    rc, _, err = _run([str(p), "--json"], capsys)
    assert rc == 2 and "cannot tell the vertical axis" in err and "--up" in err, err
    rc, doc, err = _run([str(p), "--json", "--up", "z"], capsys)
    assert rc == 0 and doc is not None, err


@pytest.mark.parametrize("rate", [60.0, 150.0])
def test_trc_times_with_three_decimals(rate: float, real: tuple[MarkerTrajectories, Doc],
                                       tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    """Exporters that print the Time column with 3 decimals (steps of 6 and 7 ms at
    150 Hz): the rate stays the header's (was 142.9 Hz from the median step), the steps
    and the heel strikes the same."""
    from engine.io.trc import read_trc

    m, ref = real
    v = _resample(m, rate)
    lines = _trc_lines(v, tmp_path)
    for i in range(6, len(lines)):
        c = lines[i].split("\t")
        if len(c) > 2:
            c[1] = f"{float(c[1]):.3f}"
            lines[i] = "\t".join(c)
    p = tmp_path / "t3.trc"
    p.write_text("\n".join(lines))
    assert read_trc(p).rate == pytest.approx(rate)
    rc, doc, err = _run([str(p), "--json"], capsys)
    assert rc == 0 and doc is not None, err
    _same_steps(ref, doc, 1.0 / rate)
    exact = _write("trc", v, tmp_path / "exact.trc")
    runs = [_run([str(f), "--json", "--method", "heelstrike"], capsys) for f in (exact, p)]
    assert all(rc == 0 for rc, _, _ in runs), runs
    _same_steps(runs[0][1], runs[1][1], 1.0 / rate)  # type: ignore[arg-type]


def test_csv_times_with_three_decimals(tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    """A 150 Hz skeleton CSV whose time column has 3 decimals: read as the uniform grid,
    so heel strikes and foot offs come out as from the exact times."""
    from engine.io.csv import read_skeleton_csv

    w = Walker(WalkerParams(), [0.0, 0.0, 0.0], [5.0, 0.0, 0.0], start_time=0.5, seed=3)
    t = np.arange(1050) / 150.0
    J = w.joints(t)
    s = SkeletonSeries(t, J, np.full(J.shape[:2], TrackingState.TRACKED, dtype=np.uint8),
                       KINECT_V2)
    exact = tmp_path / "exact.csv"
    write_skeleton_csv(exact, s)
    rows = exact.read_text().split("\n")
    rounded = tmp_path / "rounded.csv"
    rounded.write_text("\n".join([rows[0]] + [
        f"{float(r.split(',', 1)[0]):.3f},{r.split(',', 1)[1]}" for r in rows[1:] if r]))
    np.testing.assert_allclose(read_skeleton_csv(rounded).times, t, atol=1e-5)
    runs = [_run([str(f), "--json", "--method", "heelstrike"], capsys)
            for f in (exact, rounded)]
    assert all(rc == 0 for rc, _, _ in runs), runs
    _same_steps(runs[0][1], runs[1][1], 1.0 / 150.0)  # type: ignore[arg-type]


# ------------------------------------------------------------------ lateral ankle markers

def _width_means(doc: Doc) -> tuple[float, float]:
    w = doc["summary"]["step_width_m"]
    return w["left_mean"], w["right_mean"]


def test_lateral_ankle_markers_real_trial(shared_data: Path, real: tuple[MarkerTrajectories,
                                                                          Doc]) -> None:
    """Plug-in Gait's LANK/RANK sit on the lateral malleoli, 3.5-5 cm outside the heels:
    the crossing method measured between them, 20.3 cm steps against heel strikes' 12.4.
    It now measures the ankle joint centres, placed with the file's PROCESSING ankle
    widths (64/63 mm): per side within 1.5 cm of the heel-strike widths, and within 2 cm
    on the floor of Plug-in Gait's own joint centres (its LTIO/RTIO outputs)."""
    from engine.mocap import feet_from_markers

    f = shared_data / "mocap" / "kineticstoolkit" / "walk.c3d"
    cross = _doc([str(f)])
    heel = _doc([str(f), "--method", "heelstrike"])
    lateral = _doc([str(f), "--left", "LANK", "--right", "RANK"])
    for c, h, lat in zip(_width_means(cross), _width_means(heel), _width_means(lateral),
                         strict=True):
        assert abs(c - h) < 0.015, (c, h)
        assert lat - h > 0.06, (lat, h)  # the markers themselves: ≈ 8 cm wider
    pts = cross["summary"]["foot_points"]
    assert "PROCESSING:LAnkleWidth" in pts["L"] and "64 mm" in pts["L"], pts
    assert "PROCESSING:RAnkleWidth" in pts["R"] and "63 mm" in pts["R"], pts
    assert cross["summary"]["notes"] == []
    assert heel["summary"]["foot_points"] == {"L": "heel: LHEE", "R": "heel: RHEE"}
    # the heel-strike method is unchanged: the same steps as with the heels named
    _same_steps(_doc([str(f), "--method", "heelstrike", "--left", "LHEE", "--right", "RHEE"]),
                heel, 0.01)
    m = read_c3d(f)
    assert m.meta["ankle_width_m"] == {"L": pytest.approx(0.064), "R": pytest.approx(0.063)}
    feet = feet_from_markers(m)
    for s in ("L", "R"):
        ajc = m.marker(f"{s}TIO")  # Plug-in Gait's ankle joint centre (Z up already)
        d = np.linalg.norm((feet.foot(s) - ajc)[:, :2], axis=1)
        d_lat = np.linalg.norm((feet.points[s]["ankle"] - ajc)[:, :2], axis=1)
        assert np.nanmedian(d) < 0.02 and np.nanmedian(d_lat) > 0.03, (s, np.nanmedian(d))
    # without the PROCESSING group (the variants above): the population width, said so
    no_proc = real[1]
    assert all("population default" in p for p in no_proc["summary"]["foot_points"].values())
    assert [n.split(" with ")[0] for n in no_proc["summary"]["notes"]] == [
        "The ankle joint centres were placed 4.2 cm medial of LANK and RANK"]
    assert "population ankle width of 70 mm" in no_proc["summary"]["notes"][0]
    for c, h, c_proc in zip(_width_means(no_proc), _width_means(heel), _width_means(cross),
                            strict=True):
        assert abs(c - h) < 0.015, (c, h)
        # 70 mm instead of 64/63: each foot ≈ 3 mm further in
        assert 0.004 < c_proc - c < 0.009, (c_proc, c)


def _with_medial(m: MarkerTrajectories) -> MarkerTrajectories:
    """The real trial's Plug-in Gait markers, medial malleolus markers LMED/RMED placed
    opposite LANK/RANK across Plug-in Gait's ankle joint centres (so their midpoints are
    those centres), and the centres themselves as XL/XR (names no rule takes)."""
    v = _renamed(m, NAMINGS["plug_in_gait"])
    extra = {}
    for s in ("L", "R"):
        ajc = m.marker(f"{s}TIO")
        extra[f"{s}MED"] = 2.0 * ajc - m.marker(f"{s}ANK")
        extra[f"X{s}"] = ajc
    P = np.concatenate([v.positions, np.stack(list(extra.values()), axis=1)], axis=1)
    return replace(v, positions=P, labels=v.labels + list(extra))


MEDIAL_VARIANTS: dict[str, tuple[str, Callable[[MarkerTrajectories], MarkerTrajectories],
                                 str]] = {
    "as_is_c3d": ("c3d", lambda m: m, "mm"),
    "rotated_135_far_trc": ("trc", lambda m: _map(m, _rz(135.0), (40.0, -25.0, 0.0)), "mm"),
    "y_up_metres_c3d": ("c3d", lambda m: _file_axes(_map(m, _rz(-60.0)), "y"), "m"),
    "mirrored_x_up_trc": ("trc", lambda m: _map(_file_axes(m, "x"), _mirror(1)), "mm"),
}


@pytest.mark.parametrize("case", sorted(MEDIAL_VARIANTS))
def test_medial_malleolus_markers(case: str, real: tuple[MarkerTrajectories, Doc],
                                  tmp_path: Path,
                                  capsys: pytest.CaptureFixture[str]) -> None:
    """With medial malleolus markers the joint centre is the midpoint of the two
    malleoli: the same steps as measuring the true centres (named XL/XR), in any
    heading, place, vertical axis, unit and handedness."""
    m, _ = real
    kind, f, units = MEDIAL_VARIANTS[case]
    p = _write(kind, f(_with_medial(m)), tmp_path / f"v.{kind}", units)
    rc, doc, err = _run([str(p), "--json"], capsys)
    assert rc == 0 and doc is not None, err
    assert doc["summary"]["foot_points"] == {
        "L": "ankle joint centre: midpoint of LANK and LMED",
        "R": "ankle joint centre: midpoint of RANK and RMED"}
    assert doc["summary"]["notes"] == []
    rc, ref, err = _run([str(p), "--json", "--left", "XL", "--right", "XR"], capsys)
    assert rc == 0 and ref is not None, err
    _same_steps(ref, doc, 0.01)


def test_medial_marker_makes_a_bare_ankle_a_malleolus(real: tuple[MarkerTrajectories, Doc],
                                                      tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]
                                                      ) -> None:
    """OpenSim's L.Ankle beside L.Ankle.Med: a bare ankle name is a joint's, unless a
    medial marker shows it is the lateral malleolus (then the midpoint is measured)."""
    m, _ = real
    names = {"LANK": "L.Ankle", "RANK": "R.Ankle", "LMED": "L.Ankle.Med",
             "RMED": "R.Ankle.Med"}
    v = _with_medial(m)
    p = _write("trc", replace(v, labels=[names.get(x, x) for x in v.labels]),
               tmp_path / "o.trc")
    rc, doc, err = _run([str(p), "--json"], capsys)
    assert rc == 0 and doc is not None, err
    assert doc["summary"]["foot_points"]["L"] == ("ankle joint centre: midpoint of L.Ankle "
                                                  "and L.Ankle.Med")
    rc, ref, err = _run([str(p), "--json", "--left", "XL", "--right", "XR"], capsys)
    assert rc == 0 and ref is not None, err
    _same_steps(ref, doc, 0.01)


@pytest.mark.parametrize("mirrored", [False, True])
@pytest.mark.parametrize("heading", [0.0, 100.0, 225.0])
def test_medial_direction_any_heading(heading: float, mirrored: bool) -> None:
    """The medial direction is perpendicular to the heel→toe axis on the floor and points
    to the other foot, whatever the heading and handedness; a frame without a foot axis
    takes it from its neighbours; the width rule moves the marker by width/2 + radius."""
    from engine.mocap import ankle_joint_centre, medial_directions

    T = 20
    R = _rz(heading) @ (_mirror(1) if mirrored else np.eye(3))
    fwd, left = R @ np.array([1.0, 0.0, 0.0]), R @ np.array([0.0, 1.0, 0.0])
    base = np.array([3e3, -2e3, 0.08]) + np.linspace(0, 1, T)[:, None] * fwd  # far out
    ank = base + 0.0 * left                      # a right foot's lateral marker …
    heel = base - 0.05 * fwd + 0.03 * left       # … its heel 3 cm medial of it
    toe = base + 0.15 * fwd + 0.03 * left
    other = base + 0.25 * left                   # the left foot
    heel[5:8] = np.nan                           # no foot axis in three frames
    n = medial_directions(ank, heel, toe, other)
    assert n is not None
    assert np.allclose(n, left, atol=1e-9)
    res = ankle_joint_centre(ank, None, heel, toe, other, 0.064, 0.014)
    assert res is not None and res[1] == "width"
    assert np.allclose(res[0], ank + 0.039 * left, atol=1e-9)
    # no toe: no foot axis, no centre (the caller keeps the marker and says so)
    assert ankle_joint_centre(ank, None, heel, None, other, 0.064) is None
    # a medial marker: its midpoint
    res = ankle_joint_centre(ank, ank + 0.08 * left, None, None, other, None)
    assert res is not None and res[1] == "medial"
    assert np.allclose(res[0], ank + 0.04 * left)


def test_processing_widths_read_in_mm_or_metres(real: tuple[MarkerTrajectories, Doc],
                                                tmp_path: Path) -> None:
    """PROCESSING subject measurements are read in mm (Vicon) or metres, whatever the
    points' unit; a 0 (not measured) is no width."""
    import ezc3d

    m, _ = real
    v = _renamed(m, NAMINGS["plug_in_gait"])
    for units, vals, want in (("m", (64.0, 0.0, 10.0), ({"L": 0.064}, 0.010)),
                              ("mm", (0.07, 0.068, None), ({"L": 0.07, "R": 0.068}, None))):
        p = _write("c3d", v, tmp_path / f"{units}.c3d", units)
        c = ezc3d.c3d(str(p))
        for name, x in zip(("LAnkleWidth", "RAnkleWidth", "MarkerDiameter"), vals,
                           strict=True):
            if x is not None:
                c.add_parameter("PROCESSING", name, [x])
        c.write(str(p))
        got = read_c3d(p).meta
        assert got.get("ankle_width_m") == {k: pytest.approx(x) for k, x in want[0].items()}
        assert got.get("marker_diameter_m") == (None if want[1] is None
                                                else pytest.approx(want[1]))


def test_table_says_which_point_was_measured(shared_data: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    """The text output names the point of each foot (the JSON's foot_points)."""
    f = shared_data / "mocap" / "kineticstoolkit" / "walk.c3d"
    assert main(["gait", str(f)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[2] == ("left foot measured at: ankle joint centre: LANK moved 3.9 cm medially "
                      "(ankle width 64 mm: PROCESSING:LAnkleWidth; marker diameter 14 mm: "
                      "default)")
    assert out[3].startswith("right foot measured at: ankle joint centre: RANK moved 3.9 cm")


#: (file kind, heading °, mirrored file, foot without heel and toe, the file's ankle
#: widths L/R in m or None: the population width, which walk_markers places LANK with)
_ONE_FOOT_AXIS = {
    "c3d_widths_known": ("c3d", 100.0, False, "L", (0.060, 0.080)),
    "trc_default_width_mirrored": ("trc", 225.0, True, "R", None),
}


@pytest.mark.parametrize("case", sorted(_ONE_FOOT_AXIS))
def test_one_foot_without_heel_and_toe(case: str, tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    """One foot has lateral ankle, heel and toe markers, the other only its lateral
    ankle marker: that foot's joint centre is placed across the walking direction with
    its own ankle width (the file's, else the population one), so the steps are those
    between the true joint centres (named XL/XR) within 1 mm. Keeping that foot's
    marker, as before, made every step about 4 cm (half an ankle width and a marker)
    too wide."""
    from engine.mocap import DEFAULT_ANKLE_WIDTH_M
    from engine.sim.straight_walk import synth_walk, walk_markers

    kind, heading, mirrored, bare, widths = _ONE_FOOT_AXIS[case]
    w = synth_walk(n_steps=12, rate=100.0, heading_deg=heading)
    m = walk_markers(w)  # LANK/RANK on the lateral malleoli of a 70 mm ankle
    P = m.positions.copy()
    if widths is not None:
        # move each marker outwards to the malleolus of the file's ankle width
        for side, width in zip("LR", widths, strict=True):
            k = m.labels.index(f"{side}ANK")
            out = P[:, k] - w.joints[f"ankle{side}"]
            out /= np.linalg.norm(out, axis=1, keepdims=True)
            P[:, k] += 0.5 * (width - DEFAULT_ANKLE_WIDTH_M) * out
        m.meta = {"ankle_width_m": dict(zip("LR", widths, strict=True))}
    keep = [k for k, lab in enumerate(m.labels) if lab not in (f"{bare}HEE", f"{bare}TOE")]
    truth = np.stack([w.joints["ankleL"], w.joints["ankleR"]], axis=1)
    m = replace(m, positions=np.concatenate([P[:, keep], truth], axis=1),
                labels=[m.labels[k] for k in keep] + ["XL", "XR"])
    m = _map(m, _mirror(0) if mirrored else None, (2500.0, -700.0, 0.0))
    p = _write(kind, m, tmp_path / f"one_foot.{kind}", "mm")
    rc, doc, err = _run([str(p), "--json"], capsys)
    assert rc == 0 and doc is not None, err
    rc, ref, err = _run([str(p), "--json", "--left", "XL", "--right", "XR"], capsys)
    assert rc == 0 and ref is not None, err
    _same_steps(ref, doc, 0.01)
    rc, as_is, err = _run([str(p), "--json", "--left", "LANK", "--right", "RANK"], capsys)
    assert rc == 0 and as_is is not None, err
    for a, r in zip(as_is["steps"], ref["steps"], strict=True):
        assert a["width_m"] - r["width_m"] > 0.07  # both markers: ≈ 8 cm wider
    pts, notes = doc["summary"]["foot_points"], doc["summary"]["notes"]
    mm_ = round(1000 * (widths[0 if bare == "L" else 1] if widths else DEFAULT_ANKLE_WIDTH_M))
    src = f"PROCESSING:{bare}AnkleWidth" if widths else "population default"
    assert f"ankle width {mm_} mm: {src}" in pts[bare], pts
    assert pts[bare].endswith("across the walking direction)"), pts
    other = "R" if bare == "L" else "L"
    assert "across" not in pts[other] and "moved" in pts[other], pts
    word = {"L": "left", "R": "right"}[bare]
    assert notes[0].startswith(f"The {word} foot has no heel and toe markers"), notes
    assert len(notes) == (1 if widths else 2), notes


@pytest.mark.parametrize("bare", ["L", "R"])
def test_real_trial_one_foot_without_heel_and_toe(shared_data: Path, bare: str) -> None:
    """The Vicon trial with one foot's heel and toe markers (and Plug-in Gait's foot
    outputs) removed: that foot's joint centre, placed across the walking direction,
    gives the whole file's crossing step widths within 1 mm (the marker kept: 3.8 cm
    wider); lengths move by under 1 cm (the foot's turn-out is not known)."""
    from engine.gait import GaitAnalysis
    from engine.mocap import feet_from_markers

    m = read_c3d(shared_data / "mocap" / "kineticstoolkit" / "walk.c3d")
    full = GaitAnalysis("crossing").fit(feet_from_markers(m)).steps_
    gone = {f"{bare}HEE", f"{bare}TOE", f"{bare}FOO"}
    feet = feet_from_markers(_without(m, tuple(gone)))
    one = GaitAnalysis("crossing").fit(feet).steps_
    assert [s.side for s in one] == [s.side for s in full] and len(full) >= 3
    for a, b in zip(full, one, strict=True):
        assert abs(a.width_m - b.width_m) < 1e-3, (a.width_m, b.width_m)
        assert abs(a.length_m - b.length_m) < 0.01, (a.length_m, b.length_m)
    assert feet.sources[f"{bare}_ankle_centre"].endswith("across the walking direction)")
