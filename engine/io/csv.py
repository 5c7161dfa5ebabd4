"""Skeleton CSV: ``time,<Joint>_x,<Joint>_y,<Joint>_z[,<Joint>_state]`` in metres.

Joint names are SDK names (Kinect v2 by default; Kinect v1 and Azure Kinect names are
recognised too). ``_state`` columns hold :class:`TrackingState` values (0, 1, 2); when
absent a joint is TRACKED wherever its coordinates are present. Empty cells or ``nan``
are missing values. Joints of the set that the file omits are NOT_TRACKED.
"""

from __future__ import annotations

import csv as _csv
from pathlib import Path

import numpy as np

from engine.errors import InputError
from engine.io.markers import check_time_unit, rounded_grid
from engine.skeleton import JOINT_SETS, JointSet, SkeletonSeries, TrackingState
from engine.wording import named


def _joint_set_for_columns(names: list[str]) -> tuple[JointSet, dict[str, str]]:
    """The smallest joint set naming every joint (case-insensitive), and the map from the
    file's spelling to the set's."""
    best: JointSet | None = None
    for js in JOINT_SETS.values():
        known = {j.lower() for j in js.joints}
        if ({n.lower() for n in names} <= known
                and (best is None or len(js.joints) < len(best.joints))):
            best = js
    if best is None:
        all_known = {j.lower() for js in JOINT_SETS.values() for j in js.joints}
        unknown = sorted(n for n in names if n.lower() not in all_known)
        raise InputError(
            "unknown joint names in CSV header: " + ", ".join(unknown[:8])
            + "; use Kinect v2 SDK names such as SpineBase, AnkleLeft, AnkleRight"
        )
    canon = {j.lower(): j for j in best.joints}
    return best, {n: canon[n.lower()] for n in names}


#: Names of the time column (seconds), case-insensitive.
_TIME_COLUMNS = ("time", "time_s")
#: First cells of mocap systems' own CSV exports (lower case) → what they are.
_OTHER_CSV = {"trajectories": "a Vicon Nexus CSV", "devices": "a Vicon Nexus CSV",
              "model outputs": "a Vicon Nexus CSV", "joints": "a Vicon Nexus CSV",
              "format version": "an OptiTrack Motive CSV"}


def read_skeleton_csv(path: str | Path) -> SkeletonSeries:
    """Read a skeleton CSV file into a :class:`SkeletonSeries` (metres, file axes).

    Args:
        path: A CSV with ``time`` (s) then ``<Joint>_x, _y, _z`` (m) and optionally
            ``<Joint>_state`` columns (the layout :func:`write_skeleton_csv` writes).

    Returns:
        The series, time first axis; the joint set is told from the joint names.

    Raises:
        InputError: missing ``time`` column, incomplete x/y/z triplets, unknown joints,
            non-numeric cells or non-increasing times.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"CSV file not found: {p}")
    try:
        # utf-8-sig: Excel and other Windows tools start the file with a BOM
        with p.open(newline="", encoding="utf-8-sig") as f:
            reader = _csv.reader(f)
            try:
                header = [h.strip() for h in next(reader)]
            except StopIteration:
                raise InputError(f"{p.name} is empty") from None
            rows = [r for r in reader if any(c.strip() for c in r)]
    except (UnicodeDecodeError, _csv.Error) as exc:
        raise InputError(f"{p.name} is not a UTF-8 text CSV file ({exc})") from None
    if len(header) == 1 and header[0].count(";") >= 3:
        raise InputError(f"{p.name} is separated by semicolons; the skeleton CSV format is "
                         "comma-separated (time,<Joint>_x,<Joint>_y,<Joint>_z, decimal points)")
    time_cols = [i for i, h in enumerate(header) if h.lower() in _TIME_COLUMNS]
    first = header[0].lower() if header else ""
    if not time_cols and first in _OTHER_CSV:
        raise InputError(f"{p.name} is {_OTHER_CSV[first]} export, not a skeleton CSV: "
                         "give the trial exported as C3D (or TRC) instead")
    if not time_cols:
        raise InputError(f"{p.name}: no 'time' column; the first column must be 'time' "
                         "(seconds), then <Joint>_x,<Joint>_y,<Joint>_z[,<Joint>_state]")
    # Columns other than time and <Joint>_x/_y/_z/_state (a frame counter, a body id, a
    # spreadsheet's unnamed index column) are left out.
    col: dict[str, int] = {"time": time_cols[0]}
    joints: list[str] = []
    for i, h in enumerate(header):
        base, _, suffix = h.rpartition("_")
        if i == time_cols[0] or suffix.lower() not in ("x", "y", "z", "state") or not base:
            continue
        col[f"{base}_{suffix.lower()}"] = i
        if base not in joints:
            joints.append(base)
    for j in joints:
        missing = [f"{j}_{a}" for a in "xyz" if f"{j}_{a}" not in col]
        if missing:
            raise InputError(f"{p.name}: joint {j} lacks {named('column', missing)}")
    js, canon = _joint_set_for_columns(joints)
    if not rows:
        raise InputError(f"{p.name} has no data rows")
    A = np.full((len(rows), len(header)), np.nan)
    used = sorted(col.values())
    for i, r in enumerate(rows):
        for k in used:
            s = r[k].strip() if k < len(r) else ""
            if s:
                try:
                    A[i, k] = float(s)
                except ValueError:
                    raise InputError(
                        f"{p.name} row {i + 2}, column {header[k]}: {s!r} is not a number"
                    ) from None
    T, J = len(rows), len(js.joints)
    pos = np.full((T, J, 3), np.nan)
    states = np.zeros((T, J), dtype=np.uint8)
    for j in joints:
        ji = js.index(canon[j])
        pos[:, ji] = A[:, [col[f"{j}_{a}"] for a in "xyz"]]
        ok = np.all(np.isfinite(pos[:, ji]), axis=1)
        if f"{j}_state" in col:
            st = A[:, col[f"{j}_state"]]
            st = np.where(np.isfinite(st), st, TrackingState.NOT_TRACKED)
            if np.any((st < 0) | (st > 2)):
                raise InputError(f"{p.name}: {j}_state must be 0, 1 or 2")
            states[:, ji] = np.where(ok, st, TrackingState.NOT_TRACKED).astype(np.uint8)
        else:
            states[:, ji] = np.where(ok, TrackingState.TRACKED, TrackingState.NOT_TRACKED)
    times = A[:, col["time"]]
    if np.any(~np.isfinite(times)):
        raise InputError(f"{p.name}: every row needs a time")
    back = np.flatnonzero(np.diff(times) <= 0)
    if len(back):
        i = int(back[0]) + 1
        raise InputError(f"{p.name} row {i + 2}: time {times[i]:g} is not after the "
                         "previous row's; times must be strictly increasing (remove "
                         "repeated or out-of-order rows)")
    check_time_unit(times, p.name)
    times = rounded_grid(times)
    return SkeletonSeries(times, pos, states, js, {"source": str(p)})


def write_skeleton_csv(path: str | Path, series: SkeletonSeries, with_states: bool = True) -> None:
    """Write a skeleton series as CSV (full float precision, ``nan`` → empty cell).

    Args:
        path: Destination file (overwritten).
        series: The skeleton; positions are written in its own frame and units (m).
        with_states: Add a ``<Joint>_state`` column (``TrackingState`` value) per joint.
    """
    p = Path(path)
    header = ["time"]
    for j in series.joint_set.joints:
        header += [f"{j}_x", f"{j}_y", f"{j}_z"] + ([f"{j}_state"] if with_states else [])
    p.parent.mkdir(parents=True, exist_ok=True)
    with p.open("w", newline="", encoding="utf-8") as f:
        w = _csv.writer(f)
        w.writerow(header)
        for t in range(len(series)):
            row = [repr(float(series.times[t]))]
            for ji in range(len(series.joint_set.joints)):
                row += ["" if not np.isfinite(v) else repr(float(v))
                        for v in series.positions[t, ji]]
                if with_states:
                    row.append(str(int(series.states[t, ji])))
            w.writerow(row)
