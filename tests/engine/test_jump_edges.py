"""Pixels behind a depth edge (``engine.pointcloud.jump_edge_pixels``): time-of-flight
flying pixels between a body and the floor are flagged, the floor out to the far end of
the range and the body's own pixels are not; on a real depth frame only pixels at depth
edges are flagged."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from engine.errors import InputError
from engine.pointcloud import CameraIntrinsics, jump_edge_pixels, pixel_ray_table

#: a Kinect v2 depth camera at half size (the live view's kind of image)
INTR = CameraIntrinsics(256, 212, 182.0, 182.0, 127.5, 105.5)
HEIGHT_M, TILT_DEG = 1.0, 8.0  # on a tripod, looking slightly down


def _floor_depth(intr: CameraIntrinsics) -> np.ndarray:
    """Depth along the optical axis of the floor seen by a camera ``HEIGHT_M`` up, pitched
    down by ``TILT_DEG``; 0 where a ray does not reach the floor within 8 m."""
    rays = pixel_ray_table(intr)
    t = np.radians(TILT_DEG)
    # camera (x right, y down, z forward) → world height: down component of each ray
    down = rays[..., 1] * np.cos(t) + np.sin(t)
    with np.errstate(divide="ignore"):
        z = np.where(down > 0, HEIGHT_M / down, 0.0)
    return np.where(z < 8.0, z, 0.0)


def test_flying_pixels_between_a_body_and_the_floor_are_flagged() -> None:
    floor = _floor_depth(INTR)
    depth = floor.copy()
    body = np.zeros(depth.shape, bool)
    body[20:150, 100:140] = True  # a person 1.5 m away, in front of the floor
    depth[body] = 1.5
    # flying pixels: the column right of the body mixes body and floor, as a ToF pixel
    # straddling the edge does (Sarbolandi et al. 2015), from 15 % to 95 % of the way
    rows = np.arange(110, 150)  # (above row 110 nothing is behind: no floor)
    mix = np.linspace(0.15, 0.95, len(rows))
    depth[rows, 140] = 1.5 + mix * (floor[rows, 140] - 1.5)
    assert (floor[rows, 140] - 1.5 > 1.0).all()  # the floor behind is > 1 m farther
    drop = jump_edge_pixels(depth, pixel_ray_table(INTR))

    assert drop[rows, 140].all()  # every flying pixel
    assert not drop[body].any()  # the body keeps its rim
    away = np.ones(depth.shape, bool)
    away[15:155, 95:146] = False
    assert floor[away].max() > 7.5  # the floor is seen out to the end of the range
    assert not drop[away & (depth > 0)].any()  # and none of it is flagged


def test_real_depth_frame_flags_only_pixels_at_depth_edges(shared_data: Path) -> None:
    """The PrimeSense frames of Open3D's RGB-D tutorial: a few per cent of the pixels are
    flagged, each one beside a neighbour more than 2 cm nearer."""
    K = np.array([[525.0, 0.0, 319.5], [0.0, 525.0, 239.5], [0.0, 0.0, 1.0]])
    intr = CameraIntrinsics.from_matrix(K, 640, 480, None)
    for k in (0, 1):
        d = cv2.imread(str(shared_data / f"rgbd/open3d/RGBD_depth_0000{k}.png"),
                       cv2.IMREAD_UNCHANGED) * 0.001
        drop = jump_edge_pixels(d, pixel_ray_table(intr))
        frac = drop.sum() / (d > 0).sum()
        assert 0.002 < frac < 0.04, frac
        pad = np.pad(np.where(d > 0, d, np.inf), 1, constant_values=np.inf)
        nearest = np.min([pad[:-2, 1:-1], pad[2:, 1:-1], pad[1:-1, :-2], pad[1:-1, 2:]],
                         axis=0)
        assert (nearest[drop] < d[drop] - 0.02).all()


def test_bad_arguments_are_named() -> None:
    rays = pixel_ray_table(INTR)
    with pytest.raises(InputError, match="rays must be"):
        jump_edge_pixels(np.ones((10, 10)), rays)
    with pytest.raises(InputError, match="between 0 and 90"):
        jump_edge_pixels(_floor_depth(INTR), rays, 0.0)
    # no measurement (0 or NaN) and rays outside a lens's field (NaN) are never flagged
    d = _floor_depth(INTR)
    d[50:60, 50:60] = np.nan
    r = rays.copy()
    r[:, :20] = np.nan
    drop = jump_edge_pixels(d, r)
    assert not drop[:, :20].any() and not drop[50:60, 50:60].any()
