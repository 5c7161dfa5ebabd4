"""``gaitrig report`` (files → HTML/PDF), and back-facing un-mirroring against the
simulator's ground truth of which frames the Kinect model reported mirrored."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from app.cli import main
from app.server.analysis import _transform, unmirror_back_facing
from engine.io.csv import write_skeleton_csv
from engine.sim.straight_walk import synth_walk, walk_skeleton
from engine.skeleton import KINECT_V2, SkeletonSeries


def _walk_csv(path: Path, n_steps: int = 12) -> Path:
    w = synth_walk(n_steps=n_steps, rate=30.0)
    P = walk_skeleton(w)
    write_skeleton_csv(path, SkeletonSeries(w.times, P, np.full(P.shape[:2], 2, np.uint8),
                                            KINECT_V2))
    return path


def test_cli_report_html(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    f = _walk_csv(tmp_path / "walk.csv")
    out = tmp_path / "r.html"
    assert main(["report", str(f), str(f), "--subject", "P09", "-o", str(out)]) == 0
    html = out.read_text()
    assert "P09" in html and "<html" in html.lower() and "Step length" in html
    # synth_walk: 0.70 m steps, 0.12 m wide; two identical trials are pooled.
    assert "70.0" in html and "12.0" in html
    assert "(2 trials, " in capsys.readouterr().out


def test_cli_report_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    f = _walk_csv(tmp_path / "walk.csv")
    noank = tmp_path / "noankle.csv"
    noank.write_text("time,Head_x,Head_y,Head_z\n0,0,0,1.7\n0.1,0.1,0,1.7\n0.2,0.2,0,1.7\n")
    short = _walk_csv(tmp_path / "short.csv", n_steps=2)
    cases = [
        ([str(f), "--subject", "P1", "-o", str(tmp_path / "r.txt")], ".pdf or .html"),
        ([str(tmp_path / "nope.c3d"), "--subject", "P1", "-o", str(tmp_path / "r.pdf")],
         "no such file"),
        ([str(noank), "--subject", "P1", "-o", str(tmp_path / "r.pdf")], "AnkleLeft"),
        ([str(short), "--subject", "P1", "-o", str(tmp_path / "r.pdf")], "step"),
        ([str(f), "--subject", "P1", "-o", str(tmp_path / "no" / "r.pdf")], "does not exist"),
    ]
    for argv, words in cases:
        assert main(["report", *argv]) == 2, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("gaitrig report: error:"), err
        assert words in err, (words, err)
        assert "Traceback" not in err
    assert not (tmp_path / "r.pdf").exists()


def test_unmirroring_matches_the_simulated_mirroring() -> None:
    from engine.sim.clock import frame_times
    from engine.sim.rig import default_avenue_rig
    from engine.sim.skeleton_model import observe_skeletons
    from engine.sim.walker import Walker, WalkerParams

    rig = default_avenue_rig(0)
    walker = Walker(WalkerParams.random(np.random.default_rng(0)), rig.walkway.start,
                    rig.walkway.end, start_time=0.0, seed=0, horizon_s=40)
    rng = np.random.default_rng(1)
    tw = frame_times(0.0, 30.0, rng, fps=30)
    total_mirrored = 0
    for k in range(1, 7):
        sensor = rig.sensor(f"S{k}")
        s = observe_skeletons(sensor, rig, walker, tw, rng)
        T = np.asarray(sensor.T_world_sensor, dtype=float)
        world = _transform(s, T)
        fixed, frac = unmirror_back_facing(world, T[:3, 3])
        ankle = KINECT_V2.joints.index("AnkleLeft")
        swapped = np.asarray(~np.isclose(np.nan_to_num(fixed.positions[:, ankle]),
                                         np.nan_to_num(world.positions[:, ankle])).all(axis=1),
                             dtype=bool)
        truth = np.asarray(s.meta["mirrored"], dtype=bool)
        tracked = np.asarray(s.meta["body_tracked"], dtype=bool)
        total_mirrored += int(truth.sum())
        agree = float((swapped == truth)[tracked].mean())
        assert agree > 0.9, (k, agree)
        assert abs(frac - swapped[tracked].mean()) < 0.05
    assert total_mirrored > 300  # the walk is seen from behind for a good part


def test_cli_report_takes_up_and_units_as_gait_does(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--up -y`` (a Y-down lab) and ``--units``, spelled as for ``gaitrig gait``."""
    from engine.io.trc import write_trc
    from engine.sim.straight_walk import walk_markers

    m = walk_markers(synth_walk(n_steps=12))
    m.positions = np.stack([m.positions[..., 0], -m.positions[..., 2], m.positions[..., 1]],
                           axis=-1)  # Y down, Z along the walk's left (right-handed)
    f = tmp_path / "ydown.trc"
    write_trc(f, m, units="mm")
    out = tmp_path / "r.html"
    argv = [str(f), "--subject", "P1", "-o", str(out)]
    assert main(["report", *argv, "--up", "-y", "--units", "MM"]) == 0, capsys.readouterr()
    assert "70.0" in out.read_text()  # 0.70 m steps once Y-down is turned Z-up
    capsys.readouterr()
    # the unit given is used, not the file's: metres make the body 1000 times too tall
    assert main(["report", *argv, "--units", "m"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("gaitrig report: error:") and "--units" in err
    assert main(["report", *argv, "--up"]) == 2
    assert "--up needs an axis" in capsys.readouterr().err


def test_a_report_of_files_claims_no_interpolated_gaps(tmp_path: Path) -> None:
    """A mocap file is not fused: its report said '0 gaps in single joints' trajectories
    (each sensor and the fused skeleton)' of sensors it never had."""
    from app.server.analysis import analyse_file, build_report
    from engine.report.render import render_html

    data = build_report("P1", [analyse_file(_walk_csv(tmp_path / "walk.csv"))])
    assert data.quality.gaps_filled is None
    assert "Short gaps interpolated" not in render_html(data)


def test_a_report_of_files_says_how_the_ankles_were_measured(tmp_path: Path) -> None:
    """A lateral-malleolus ankle marker (LANK) whose joint centre cannot be placed (no
    heel marker for the foot's axis) is measured as it is: the report's data-quality
    notes say so, naming the trial, as the gait JSON's summary does."""
    from app.server.analysis import analyse_file, build_report
    from engine.io.c3d import write_c3d
    from engine.io.markers import MarkerTrajectories
    from engine.report.render import render_html

    w = synth_walk(n_steps=12, rate=100.0)
    P = walk_skeleton(w)
    names = {"AnkleLeft": "LANK", "AnkleRight": "RANK", "FootLeft": "LTOE",
             "FootRight": "RTOE", "SpineBase": "SACR", "Head": "HEAD"}
    idx = [KINECT_V2.index(j) for j in names]
    f = tmp_path / "walk.c3d"
    write_c3d(f, MarkerTrajectories(w.times, P[:, idx], list(names.values()), 100.0, "m"))
    a = analyse_file(f)
    notes = a["gait"]["summary"]["notes"]
    assert [n.split(" is on")[0] for n in notes] == ["The left ankle marker LANK",
                                                      "The right ankle marker RANK"]
    assert a["gait"]["summary"]["foot_points"] == {"L": "ankle: LANK", "R": "ankle: RANK"}
    data = build_report("P1", [a])
    assert [n for n in data.quality.notes if "lateral malleolus" in n] == [
        f"Recording walk.c3d: {n}" for n in notes]
    assert "RANK itself is measured" in render_html(data)
