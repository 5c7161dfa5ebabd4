"""Reference (motion-capture) files for upload tests, generated from the synthetic walk
(:mod:`engine.sim.straight_walk`): a walk the gait analysis finds steps in, and the same
subject standing (readable, no walk). The Subjects page's "Attach reference" refuses a
reference without steps, so a test that needs an accepted reference uploads a walk."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import numpy as np


def walk_trc(path: Path, n_steps: int = 6) -> Path:
    """A TRC (mm, Plug-in Gait marker names) of a straight walk of ``n_steps`` strikes."""
    from engine.io.trc import write_trc
    from engine.sim.straight_walk import synth_walk, walk_markers

    write_trc(path, walk_markers(synth_walk(n_steps=n_steps, rate=50.0)), units="mm")
    return path


def standing_trc(path: Path) -> Path:
    """A TRC (mm, Plug-in Gait marker names) of the walk's subject standing still for its
    duration: every reader takes it, and the gait analysis finds no walk (0 steps)."""
    from engine.io.markers import MarkerTrajectories
    from engine.io.trc import write_trc
    from engine.sim.straight_walk import synth_walk, walk_markers

    m = walk_markers(synth_walk(rate=50.0))
    still = np.repeat(m.positions[:1], len(m.times), axis=0)
    write_trc(path, MarkerTrajectories(m.times, still, m.labels, m.rate, m.units), units="mm")
    return path


def _walk_series(n_steps: int) -> Any:
    """A 30 Hz Kinect v2 skeleton (every joint TRACKED) of a straight walk."""
    from engine.sim.straight_walk import synth_walk, walk_skeleton
    from engine.skeleton import KINECT_V2, SkeletonSeries

    w = synth_walk(n_steps=n_steps, rate=30.0)
    pos = walk_skeleton(w)
    return SkeletonSeries(w.times, pos, np.full(pos.shape[:2], 2, np.uint8), KINECT_V2)


def walk_skeleton_csv(n_steps: int = 6) -> bytes:
    """A skeleton CSV (Kinect v2 joints, 30 Hz) of a straight walk: an accepted reference."""
    from engine.io.csv import write_skeleton_csv

    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "walk.csv"
        write_skeleton_csv(p, _walk_series(n_steps))
        return p.read_bytes()


def walk_skeleton_c3d(n_steps: int = 6) -> tuple[bytes, int]:
    """A skeleton C3D (Kinect v2 joint labels, mm, 30 Hz) of a straight walk, as the
    console's skeleton export writes it: an accepted reference; with its frame count."""
    from engine.io.c3d import write_skeleton_c3d

    series = _walk_series(n_steps)
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "walk.c3d"
        write_skeleton_c3d(p, series)
        return p.read_bytes(), len(series.times)


def upload_for_report(client: Any, data: bytes, name: str, subject: str,
                      query: str = "") -> tuple[int, str]:
    """POST ``data`` as file ``name`` to the Reports page's "Analyse a file" (HTML report,
    extra query ``query``, e.g. ``"advice=form&up=z"``); its status and text."""
    r = client.post(f"/api/reports/upload?format=html&{query}", data={"subject": subject},
                    files={"file": (name, data, "application/octet-stream")})
    return r.status_code, r.text
