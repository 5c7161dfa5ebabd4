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

import json
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.cli import main
from engine.io.c3d import read_c3d, write_c3d
from engine.io.markers import MarkerTrajectories, up_rotation
from engine.io.trc import write_trc
from engine.sim.walker import Walker, WalkerParams
from engine.skeleton import KINECT_V2

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
    return read_c3d(shared_data / "mocap" / "kineticstoolkit" / "walk.c3d")


@pytest.fixture(scope="module")
def synth() -> MarkerTrajectories:
    return _synthetic()


@pytest.fixture(params=["real", "synth"])
def base(request: pytest.FixtureRequest, tmp_path: Path,
         capsys: pytest.CaptureFixture[str]) -> tuple[MarkerTrajectories, Doc]:
    """(markers in metres, Z up; the CLI's answer on them written as a C3D file in mm)."""
    m = request.getfixturevalue(request.param)
    p = tmp_path / "ref.c3d"
    write_c3d(p, m, units="mm")
    rc, doc, err = _run([str(p), "--json"], capsys)
    assert rc == 0, err
    assert doc is not None and len(doc["steps"]) >= 3
    return m, doc


def test_real_file_reference_equals_rewritten_copy(real: MarkerTrajectories, shared_data: Path,
                                                   capsys: pytest.CaptureFixture[str],
                                                   tmp_path: Path) -> None:
    f = shared_data / "mocap" / "kineticstoolkit" / "walk.c3d"
    rc, orig, _ = _run([str(f), "--json"], capsys)
    p = tmp_path / "copy.c3d"
    write_c3d(p, real, units="mm")
    rc2, copy, _ = _run([str(p), "--json"], capsys)
    assert rc == rc2 == 0 and orig is not None and copy is not None
    _same_steps(orig, copy)


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


@pytest.mark.parametrize("case", sorted(SAME_WALK))
def test_same_walk_same_steps(case: str, base: tuple[MarkerTrajectories, Doc], tmp_path: Path,
                              capsys: pytest.CaptureFixture[str]) -> None:
    m, ref = base
    kind, units, f, extra = SAME_WALK[case]
    p = _write(kind, f(m), tmp_path, units)
    rc, doc, err = _run([str(p), "--json", *extra], capsys)
    assert rc == 0, err
    assert doc is not None
    _same_steps(ref, doc)
