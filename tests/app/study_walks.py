"""Simulated walks of a validation study for the project agreement tests: a recording's
analysis (what the server's fusion would give, put in its place) and a reference file
(skeleton CSV) of the same walk on the same time axis, with its own noise.

The walks come from :class:`engine.sim.walker.Walker`; each subject walks at its own pace,
so that subject averages differ between subjects (the study's AV rows)."""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

import numpy as np

#: subject code → (speed m/s, step length m, step width m); other codes walk as
#: WalkerParams's defaults
SUBJECTS = {"V01": (1.05, 0.62, 0.10), "V02": (1.20, 0.70, 0.13),
            "V03": (1.35, 0.76, 0.09), "V04": (1.15, 0.66, 0.15)}
DURATION_S = 8.0


@functools.lru_cache(maxsize=32)
def _joints(code: str, seed: int, noise_seed: int) -> tuple[Any, Any]:
    from engine.sim.walker import Walker, WalkerParams

    speed, length, width = SUBJECTS.get(code, (1.25, 0.72, 0.115))
    w = Walker(WalkerParams(speed_m_s=speed, step_length_m=length, step_width_m=width),
               [0.0, 0.0, 0.0], [14.0, 0.0, 0.0], start_time=0.5, back_and_forth=False,
               seed=seed, horizon_s=14.0)
    t = np.arange(0.0, DURATION_S, 1 / 30)
    J = w.joints(t) + np.random.default_rng(noise_seed).normal(0.0, 0.005, (len(t), 25, 3))
    return t, J


def _series(code: str, seed: int, noise_seed: int) -> Any:
    from engine.skeleton import KINECT_V2, SkeletonSeries, TrackingState

    t, J = _joints(code, seed, noise_seed)
    return SkeletonSeries(t, J, np.full(J.shape[:2], TrackingState.TRACKED, np.uint8),
                          KINECT_V2)


@functools.lru_cache(maxsize=32)
def _gait(code: str, seed: int) -> dict[str, Any]:
    from app.server import analysis as an

    return an.analyse_series(_series(code, seed, seed))


def walk_analysis(rec_id: str, code: str, seed: int,
                  sensors: tuple[str, ...] = ("S1", "S2")) -> dict[str, Any]:
    """What :func:`app.server.analysis.analyse_recording` gives of a walk of subject
    ``code`` (``seed``: which walk)."""
    return {"rec_id": rec_id, "ok": True, "error": None, "sensors_used": list(sensors),
            "sensors_available": list(sensors), "sensors": {}, "fusion": None,
            **_gait(code, seed)}


def walk_reference_csv(path: Path, code: str, seed: int, delay_s: float = 0.0) -> Path:
    """The reference system's skeleton CSV of the same walk (its own noise); with
    ``delay_s``, the reference started that much before the recording (its times later)."""
    from engine.io.csv import write_skeleton_csv
    from engine.skeleton import SkeletonSeries

    s = _series(code, seed, 1000 + seed)
    if delay_s:
        s = SkeletonSeries(s.times + delay_s, s.positions, s.states, s.joint_set)
    write_skeleton_csv(path, s)
    return path


def attach_reference(rec_dir: Path, file: Path, offset_s: float = 0.0) -> None:
    """Put ``file`` where the Reports page's "Reference recording for the agreement
    section" keeps a recording's reference (``<rec>/reference/``, as its upload does)."""
    folder = rec_dir / "reference"
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"reference{file.suffix}").write_bytes(file.read_bytes())
    import json

    (folder / "meta.json").write_text(json.dumps({
        "filename": file.name, "ext": file.suffix, "offset_s": offset_s, "n_steps": 0}))
