"""Live view throughput: the merged point cloud, the depth panels and the coverage redraw.

Six full-resolution (512×424) depth frames of the simulated lab (``engine.sim``, the
walker in view) go through the live merged-cloud pipeline of the 3D view
(:func:`app.viewer.cloud.merge_depth_views`: unproject with each sensor's intrinsics,
transform by ``T_world_sensor``, 3 cm voxel average; then serialise), and — in the same
run, on the same frames — through a plain Open3D pipeline doing the same work
(``PointCloud.create_from_depth_image`` + ``transform`` per sensor, concatenate,
``voxel_down_sample``, numpy serialisation). Figures are medians over repeats; goals:
≥ 2× faster than Open3D and ≥ 10 updates/s. The same frames unprojected through a depth
lens (an Azure Kinect's: rays from the cached table) give ``cloud_lens_vs_pinhole``
(goal: within a few per cent of 1).

Also measured: a simulated node's cost per live panel — rendering depth + body index at
the panel's half size directly (``SimBackend.render(..., scale=0.5)``, what the node does
for the live subscription) against rendering full size and downscaling (what it did
before, and still does for recordings) — then the server's per-panel cost for the Live
page (PNG decode of depth and body index, colourise + highlight, JPEG) as panels/s
capacity (goal: six nodes × 10 fps = 60/s), and the planning redraw after a tripod moves
(coverage layer update + map image + PNG; goal ≤ 200 ms). Prints one JSON line.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable
from typing import Any

import cv2
import numpy as np
import open3d as o3d

from app.nodes.backends.sim import SimBackend
from app.server.registry import LatestImage
from app.server.streaming import decode_pair, encode_panel
from app.viewer.cloud import DepthView, merge_depth_views, serialise_cloud
from app.viewer.planning import Planner
from app.viewer.scene import sensor_color
from engine.coverage import sensors_from_rig

VOXEL_M = 0.03
#: depth lens of the lens figure (strong barrel; every pixel keeps its ray)
LENS = (-0.12, 0.03, 0.0008, -0.0005, 0.0)
Z_RANGE = (0.3, 8.0)


def _median_ms(fn: Callable[[], Any], repeats: int) -> float:
    fn()  # warm-up (numba compilation, caches)
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return 1000.0 * float(np.median(ts))


def _frames(t_world: float) -> tuple[list[DepthView], list[dict[str, Any]], Any]:
    views, raw = [], []
    rig = None
    for k in range(1, 7):
        b = SimBackend(f"S{k}", seed=0)
        rig = b.rig
        b.open()
        imgs = b.render(t_world, ["depth", "body_index"])
        s = b.sensor
        K = s.model.depth_intrinsics()
        depth = np.asarray(imgs["depth"], np.uint16)
        views.append(DepthView(depth, K, s.T_world_sensor, sensor_color(s.id),
                               imgs["body_index"] != 255))
        raw.append(imgs)
    return views, raw, rig


def _ours(views: list[DepthView]) -> tuple[bytes, int]:
    pts, cols = merge_depth_views(views, VOXEL_M, Z_RANGE)
    return serialise_cloud(pts, cols), len(pts)


def _open3d(views: list[DepthView]) -> tuple[bytes, int]:
    merged = o3d.geometry.PointCloud()
    for v in views:
        h, w = v.depth_mm.shape
        K = np.asarray(v.K)
        intr = o3d.camera.PinholeCameraIntrinsic(w, h, K[0, 0], K[1, 1], K[0, 2], K[1, 2])
        pcd = o3d.geometry.PointCloud.create_from_depth_image(
            o3d.geometry.Image(v.depth_mm),  # type: ignore[call-overload]
            intr, depth_scale=1000.0, depth_trunc=Z_RANGE[1])
        pcd.transform(np.asarray(v.T_world_sensor))
        pcd.paint_uniform_color(np.asarray(v.color, float) / 255.0)
        merged += pcd
    down = merged.voxel_down_sample(VOXEL_M)
    pts = np.asarray(down.points, dtype=np.float32)
    cols = (np.asarray(down.colors) * 255.0 + 0.5).astype(np.uint8)
    return serialise_cloud(pts, cols), len(pts)


def main() -> None:
    views, raw, rig = _frames(t_world=4.0)
    n_ours = _ours(views)[1]
    n_o3d = _open3d(views)[1]
    ours_ms = _median_ms(lambda: _ours(views), 15)
    o3d_ms = _median_ms(lambda: _open3d(views), 15)
    lens_views = [dataclasses.replace(v, dist=LENS) for v in views]
    lens_ms = _median_ms(lambda: _ours(lens_views), 15)  # the warm-up builds the tables
    pin_ms = _median_ms(lambda: _ours(views), 15)  # again, beside it, for the ratio

    # Live panel: what the server does per new depth + body-index pair of a node
    def png(img: np.ndarray) -> bytes:
        return cv2.imencode(".png", cv2.resize(img, (256, 212),
                                               interpolation=cv2.INTER_NEAREST))[1].tobytes()

    pairs = [(LatestImage(1.0, 1.0, "png", png(r["depth"]), {"scale": 0.5}),
              LatestImage(1.0, 1.0, "png", png(r["body_index"]), {"scale": 0.5})) for r in raw]
    jpeg_bytes = [len(encode_panel(decode_pair("S", 1, d, b), 10.0)) for d, b in pairs]

    def panels() -> None:
        for d, b in pairs:
            encode_panel(decode_pair("S", 1, d, b), 10.0)

    panel_ms = _median_ms(panels, 15) / len(pairs)

    planner = Planner(sensors_from_rig(rig), rig)
    s1 = planner.sensors[0]
    yaws = iter(np.linspace(-180.0, 180.0, 1000))

    def drag() -> None:
        planner.move(s1.id, position=tuple(s1.T_world_sensor[:3, 3]), yaw_deg=float(next(yaws)))
        planner.png()

    drag_ms = _median_ms(drag, 15)

    # Node side: one live panel of S1 with the walker in view (world time 4 s)
    sim = SimBackend("S1", seed=0)
    sim.open()
    ts = iter(np.linspace(3.5, 4.5, 10_000))
    full_ms = _median_ms(lambda: {k: cv2.resize(v, (256, 212), interpolation=cv2.INTER_NEAREST)
                                  for k, v in sim.render(float(next(ts)),
                                                         ["depth", "body_index"]).items()}, 30)
    preview_ms = _median_ms(lambda: sim.render(float(next(ts)), ["depth", "body_index"], 0.5),
                            30)
    print(json.dumps({
        "bench": "live",
        "cloud_frames": len(views), "frame_size": list(views[0].depth_mm.shape[::-1]),
        "voxel_m": VOXEL_M,
        "cloud_ours_ms": round(ours_ms, 2), "cloud_open3d_ms": round(o3d_ms, 2),
        "cloud_speedup_vs_open3d": round(o3d_ms / ours_ms, 2),
        "cloud_updates_per_s": round(1000.0 / ours_ms, 1),
        "cloud_points_ours": n_ours, "cloud_points_open3d": n_o3d,
        "cloud_lens_ms": round(lens_ms, 2),
        "cloud_lens_vs_pinhole": round(lens_ms / pin_ms, 3),
        "goal_speedup_2x": o3d_ms / ours_ms >= 2.0, "goal_10_updates_per_s": ours_ms <= 100.0,
        "panel_ms": round(panel_ms, 2), "panels_per_s": round(1000.0 / panel_ms, 1),
        "panel_jpeg_bytes_median": int(np.median(jpeg_bytes)),
        "goal_60_panels_per_s": 1000.0 / panel_ms >= 60.0,
        "coverage_drag_ms": round(drag_ms, 2), "goal_drag_200ms": drag_ms <= 200.0,
        "sim_panel_full_then_resize_ms": round(full_ms, 2),
        "sim_panel_preview_ms": round(preview_ms, 2),
        "sim_panel_speedup": round(full_ms / preview_ms, 2),
    }))


if __name__ == "__main__":
    main()
