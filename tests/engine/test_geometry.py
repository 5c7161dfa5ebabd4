import numpy as np
import pytest

from engine import geometry as g
from engine.errors import InputError


def _random_T(rng):
    return g.make_transform(g.quat_to_matrix(g.quat_normalize(rng.normal(size=4))),
                            rng.normal(size=3))


def test_quaternion_matrix_round_trip():
    rng = np.random.default_rng(0)
    q = g.quat_normalize(rng.normal(size=(50, 4)))
    q2 = g.quat_from_matrix(g.quat_to_matrix(q))
    assert np.allclose(np.abs(np.sum(q * q2, axis=1)), 1.0)


def test_quat_rotate_matches_matrix_and_mul():
    rng = np.random.default_rng(1)
    q = g.quat_normalize(rng.normal(size=(10, 4)))
    v = rng.normal(size=(10, 3))
    R = g.quat_to_matrix(q)
    assert np.allclose(g.quat_rotate(q, v), np.einsum("nij,nj->ni", R, v))
    p = g.quat_normalize(rng.normal(size=(10, 4)))
    assert np.allclose(g.quat_rotate(g.quat_mul(p, q), v), g.quat_rotate(p, g.quat_rotate(q, v)))


def test_rotvec_round_trip_and_axis_angle():
    q = g.quat_from_axis_angle([0, 0, 1], np.pi / 2)
    assert np.allclose(g.quat_rotate(q, [1, 0, 0]), [0, 1, 0])
    rv = np.array([0.3, -0.2, 0.9])
    assert np.allclose(g.quat_to_rotvec(g.quat_from_rotvec(rv)), rv)
    assert np.allclose(g.so3_exp(rv), g.quat_to_matrix(g.quat_from_rotvec(rv)))


def test_procrustes_recovers_transform_far_from_origin():
    rng = np.random.default_rng(2)
    T = _random_T(rng)
    T[:3, 3] += [1000.0, -2000.0, 50.0]
    src = rng.normal(size=(8, 3))
    dst = g.transform_points(T, src)
    assert np.allclose(g.procrustes(src, dst), T, atol=1e-9)


def test_procrustes_rejects_degenerate_input():
    with pytest.raises(InputError):
        g.procrustes(np.zeros((2, 3)), np.zeros((2, 3)))
    line = np.outer(np.arange(5.0), [1, 0, 0])
    with pytest.raises(InputError, match="collinear"):
        g.procrustes(line, line)


def test_invert_and_pose_error():
    rng = np.random.default_rng(3)
    T = _random_T(rng)
    assert np.allclose(g.invert_transform(T) @ T, np.eye(4))
    dt, dr = g.pose_error(T, T)
    assert dt == pytest.approx(0) and dr == pytest.approx(0, abs=1e-7)


def test_look_at_convention():
    T = g.look_at([0, -3, 1], [0, 0, 1])
    # optical axis (+Z camera) points along +Y world; image down (+Y camera) is world −Z
    assert np.allclose(T[:3, 2], [0, 1, 0])
    assert np.allclose(T[:3, 1], [0, 0, -1])
    assert np.isclose(np.linalg.det(T[:3, :3]), 1.0)
