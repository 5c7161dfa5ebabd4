"""Coverage-map update time for live tripod dragging (issue 4: ≤ 200 ms after a drag).

Six Kinect v2 sensors in the seed-000 avenue, a 5 cm grid over a 10 × 4 m floor. Times:
the incremental update after one sensor moves (what the planning UI calls per drag
event), a full recomputation, and a peer in the same run: the straightforward method that
projects sampled feet-to-head cylinder points (9 heights × 16 around) of every cell into
every sensor. Also cross-checks the map against the simulated lab
(``engine.sim.rig.default_avenue_rig``): for a standing walker's 25 joints placed at every
cell, the sim's own pixel-based view test (``SimSensor.in_depth_view``) must agree with
the map's whole-body test. Prints one JSON line.
"""

from __future__ import annotations

import json
import time

import numpy as np

from engine.coverage import CoverageModel, Grid, avenue_rig, coverage_map, sensor_pose
from engine.geometry import invert_transform


def _sampled_peer(sensors: list, grid: Grid, H: float, r: float) -> np.ndarray:
    """Counts by projecting cylinder sample points into each frustum (the plain method)."""
    x, y = grid.centres()
    X, Y = np.meshgrid(x, y)
    ang = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    z = np.linspace(0.0, H, 9)
    offs = np.stack(np.broadcast_arrays(r * np.cos(ang)[:, None], r * np.sin(ang)[:, None],
                                        z[None, :]), -1).reshape(-1, 3)
    P = np.stack([X, Y, np.zeros_like(X)], -1)[..., None, :] + offs  # (Ny, Nx, K, 3)
    counts = np.zeros(X.shape, dtype=np.int64)
    for s in sensors:
        Ti = invert_transform(s.T_world_sensor)
        Pc = P @ Ti[:3, :3].T + Ti[:3, 3]
        th = np.tan(np.radians(s.hfov_deg / 2))
        tv = np.tan(np.radians(s.vfov_deg / 2))
        zc = Pc[..., 2]
        ok = ((np.abs(Pc[..., 0]) <= zc * th) & (np.abs(Pc[..., 1]) <= zc * tv)
              & (zc >= s.min_range_m) & (zc <= s.max_range_m))
        counts += ok.all(axis=-1)
    return counts


def _sim_agreement() -> dict[str, float]:
    """Map vs the simulator's per-joint view test, over all sensors and cells."""
    from engine.coverage import sensors_from_rig
    from engine.sim.rig import default_avenue_rig
    from engine.sim.walker import Walker, WalkerParams

    rig = default_avenue_rig(seed=None)
    grid = Grid(-3.0, 7.0, -2.0, 2.0, 0.1)
    walker = Walker(WalkerParams(), [0.0, 0.0, 0.0], [10.0, 0.0, 0.0], start_time=0.0,
                    back_and_forth=False, horizon_s=1.0)
    J = walker.joints(np.array([0.0]))[0]  # standing at the start, facing +X
    J[:, :2] -= J[0, :2]
    # the cylinder that holds this body: its joints' reach around the spine base
    r = float(np.hypot(J[:, 0], J[:, 1]).max())
    cm = coverage_map(sensors_from_rig(rig), grid, body_height_m=1.8, body_radius_m=r)
    x, y = grid.centres()
    X, Y = np.meshgrid(x, y)
    P = J[None, None] + np.stack([X, Y, np.zeros_like(X)], -1)[:, :, None, :]
    map_only = sim_only = same = 0
    for i, s in enumerate(rig.sensors):
        sim = s.in_depth_view(P.reshape(-1, 3)).reshape(P.shape[:3]).all(-1)
        pred = cm.visible[i]
        map_only += int((pred & ~sim).sum())
        sim_only += int((sim & ~pred).sum())
        same += int((pred == sim).sum())
    n = len(rig.sensors) * X.size
    return {"sim_agreement": round(same / n, 4), "sim_map_only_cells": map_only,
            "sim_joints_only_cells": sim_only, "sim_body_radius_m": round(r, 3)}


def _best(f, n: int) -> float:  # type: ignore[no-untyped-def]
    ts = []
    for _ in range(n):
        t0 = time.perf_counter()
        f()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def main() -> None:
    rig = avenue_rig()
    grid = Grid(-3.0, 7.0, -2.0, 2.0, 0.05)  # 10 × 4 m around the avenue
    H, r = 1.8, 0.2
    model = CoverageModel(rig, grid, body_height_m=H, body_radius_m=r)
    k = [0]

    def drag() -> None:
        k[0] += 1
        model.move_sensor("S1", sensor_pose((2.4 + 0.01 * (k[0] % 50), 1.0, 1.0), 215.0, -8.0))

    t_inc = _best(drag, 30)
    t_full = _best(lambda: coverage_map(rig, grid, body_height_m=H, body_radius_m=r), 10)
    t_peer = _best(lambda: _sampled_peer(rig, grid, H, r), 3)
    exact = coverage_map(rig, grid, body_height_m=H, body_radius_m=r)
    peer = _sampled_peer(rig, grid, H, r)
    print(json.dumps({
        "bench": "coverage",
        "sensors": len(rig),
        "grid_cells": int(np.prod(grid.shape)),
        "incremental_update_ms": round(1e3 * t_inc, 2),
        "full_update_ms": round(1e3 * t_full, 2),
        "peer_sampled_points_ms": round(1e3 * t_peer, 2),
        "speedup_full_vs_peer": round(t_peer / t_full, 1),
        "speedup_incremental_vs_peer": round(t_peer / t_inc, 1),
        "meets_200ms": bool(t_inc <= 0.2 and t_full <= 0.2),
        "cells_disagreeing_with_peer": int((exact.counts != peer).sum()),
        "two_sided_fraction": round(exact.fraction(exact.two_sided), 3),
        "blind_fraction": round(exact.fraction(exact.blind), 3),
        **_sim_agreement(),
    }))


if __name__ == "__main__":
    main()
