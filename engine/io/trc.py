"""OpenSim TRC (tab-separated marker trajectories) read/write.

Layout: a ``PathFileType`` line, a header-name line and its values line (``DataRate``,
``Units`` ...), the ``Frame#  Time  <marker>\\t\\t\\t ...`` line, the ``X1 Y1 Z1 ...``
line, then one row per frame. Empty fields, NaN or an exact 0,0,0 are missing markers.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from engine.errors import InputError
from engine.io.markers import (
    MarkerTrajectories,
    check_time_unit,
    file_units,
    rounded_grid,
    unit_scale,
)


def read_trc(path: str | Path) -> MarkerTrajectories:
    """Read a TRC file.

    Args:
        path: An OpenSim / Vicon TRC file (``Units`` in its header: mm, cm or m).

    Returns:
        Marker trajectories in metres (file axes; OpenSim files are usually Y-up).

    Raises:
        InputError: the file is not a TRC file or is inconsistent.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"TRC file not found: {p}")
    # utf-8-sig: some Windows exporters start the file with a BOM
    lines = p.read_text(encoding="utf-8-sig", errors="replace").splitlines()
    if len(lines) < 5 or not lines[0].startswith("PathFileType"):
        raise InputError(f"{p.name} is not a TRC file (first line must start with PathFileType)")
    keys = lines[1].split("\t")
    vals = lines[2].split("\t")
    hdr = {k.strip(): v.strip() for k, v in zip(keys, vals, strict=False)}
    try:
        rate = float(hdr.get("DataRate") or hdr.get("CameraRate") or "nan")
    except ValueError:
        raise InputError(f"{p.name}: DataRate {hdr.get('DataRate')!r} is not a number") from None
    name_cells = lines[3].split("\t")
    # Some exporters write no Frame# column: the names line then starts with "Time".
    has_frame = int(name_cells[0].strip().lower() != "time")
    labels = [c.strip() for c in name_cells[has_frame + 1:] if c.strip()]
    M = len(labels)
    if M == 0:
        hint = "" if "\t" in lines[3] else " (TRC columns are separated by tabs)"
        raise InputError(f"{p.name}: no marker names on line 4{hint}")
    rows: list[np.ndarray] = []
    row_lines: list[int] = []
    # Line 5 is the X1/Y1/Z1 row, but some exporters leave it out and start the data there.
    first_row = 5 if lines[4].strip()[:1].isalpha() or not lines[4].strip() else 4
    for ln, line in enumerate(lines[first_row:], start=first_row + 1):
        if not line.strip():
            continue
        cells = [""] * (1 - has_frame) + line.split("\t")
        if len(cells) < 2:
            raise InputError(f"{p.name} line {ln}: expected Frame# and Time")
        vals_f = np.full(2 + 3 * M, np.nan)
        for i, cell in enumerate(cells[: 2 + 3 * M]):
            s = cell.strip()
            if s:
                try:
                    vals_f[i] = float(s)
                except ValueError:
                    hint = " (use a decimal point)" if "," in s else ""
                    raise InputError(f"{p.name} line {ln}: {s!r} is not a number{hint}"
                                     ) from None
        rows.append(vals_f)
        row_lines.append(ln)
    if not rows:
        raise InputError(f"{p.name} has no data rows")
    A = np.vstack(rows)
    times = A[:, 1]
    bad = np.flatnonzero(~np.isfinite(times) | np.r_[False, ~(np.diff(times) > 0)])
    if len(bad):
        i = int(bad[0])
        raise InputError(f"{p.name} line {row_lines[i]}: time {times[i]:g} is missing or not "
                         "after the previous row's; times must increase (remove repeated or "
                         "out-of-order rows)")
    check_time_unit(times, p.name)
    if len(times) > 1:
        # The Time column is the data's time axis: a DataRate that disagrees with it (an
        # export resampled under its original header) gives way. Its mean step, not the
        # median: times written with 3 decimals step 6 or 7 ms at 150 Hz.
        rate_t = float((len(times) - 1) / (times[-1] - times[0]))
        if not np.isfinite(rate) or rate <= 0 or abs(rate / rate_t - 1.0) > 0.01:
            rate = rate_t
        times = rounded_grid(times, rate)
    elif not np.isfinite(rate) or rate <= 0:
        rate = 1.0
    raw = A[:, 2:].reshape(len(A), M, 3)
    # A header without Units (or with one that is no length unit): guess from the body.
    units = file_units(hdr.get("Units", ""), raw, labels)
    pos = raw * unit_scale(units)
    # Exporters (Vicon, Cortex) write a missing sample as 0,0,0, as C3D files do.
    pos[np.all(pos == 0.0, axis=-1)] = np.nan
    return MarkerTrajectories(times, pos, labels, rate, units, [], {"source": str(p)})


def write_trc(path: str | Path, markers: MarkerTrajectories, units: str | None = None) -> None:
    """Write marker trajectories as an OpenSim TRC file (events are not part of TRC).

    Args:
        path: Destination ``.trc`` (overwritten).
        markers: Trajectories in metres.
        units: Length unit to write (default: ``markers.units``, else mm).

    Raises:
        InputError: a marker label contains a tab character.
    """
    u = units or markers.units or "mm"
    scale = unit_scale(u)
    p = Path(path)
    T, M = len(markers), len(markers.labels)
    if any("\t" in lab for lab in markers.labels):
        raise InputError("TRC marker labels cannot contain tab characters")
    out = [
        f"PathFileType\t4\t(X/Y/Z)\t{p.name}",
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\t"
        "OrigDataStartFrame\tOrigNumFrames",
        f"{markers.rate:.10g}\t{markers.rate:.10g}\t{T}\t{M}\t{u}\t{markers.rate:.10g}\t1\t{T}",
        "Frame#\tTime\t" + "\t".join(f"{lab}\t\t" for lab in markers.labels),
        "\t\t" + "\t".join(f"X{i + 1}\tY{i + 1}\tZ{i + 1}" for i in range(M)),
        "",
    ]
    P = markers.positions / scale
    for t in range(T):
        cells = [str(t + 1), repr(float(markers.times[t]))]
        cells += ["" if not np.isfinite(v) else repr(float(v)) for v in P[t].ravel()]
        out.append("\t".join(cells))
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text("\n".join(out) + "\n", encoding="utf-8")
