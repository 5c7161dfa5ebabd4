"""Madgwick filter: reproduces ``ahrs.filters.Madgwick`` and follows the conventions."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from engine.errors import InputError
from engine.geometry import quat_angle, quat_conj, quat_from_axis_angle, quat_mul, quat_rotate
from engine.imu.io import load_madgwick_mat
from engine.imu.madgwick import Madgwick, from_enu, initial_orientation, madgwick, to_enu


@pytest.fixture(scope="module")
def example(shared_data: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    import scipy.io

    d = scipy.io.loadmat(shared_data / "imu" / "madgwick" / "ExampleData.mat")
    return np.deg2rad(d["Gyroscope"]), d["Accelerometer"], d["Magnetometer"]


def _paper_step(q: np.ndarray, gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray | None,
                beta: float, dt: float) -> np.ndarray:
    """One update as Madgwick's report writes it, with matrices (eqs. 12-13, 25-26,
    29-34, 45-46): the reference the compiled loop is checked against."""
    a = acc / np.linalg.norm(acc)
    qw, qx, qy, qz = q
    f = [2 * (qx * qz - qw * qy) - a[0], 2 * (qw * qx + qy * qz) - a[1],
         2 * (0.5 - qx**2 - qy**2) - a[2]]
    J = [[-2 * qy, 2 * qz, -2 * qw, 2 * qx], [2 * qx, 2 * qw, 2 * qz, 2 * qy],
         [0, -4 * qx, -4 * qy, 0]]
    if mag is not None:
        m = mag / np.linalg.norm(mag)
        h = quat_mul(quat_mul(q, np.r_[0.0, m]), quat_conj(q))[1:]
        bx, bz = np.hypot(h[0], h[1]), h[2]
        f += [2 * bx * (0.5 - qy**2 - qz**2) + 2 * bz * (qx * qz - qw * qy) - m[0],
              2 * bx * (qx * qy - qw * qz) + 2 * bz * (qw * qx + qy * qz) - m[1],
              2 * bx * (qw * qy + qx * qz) + 2 * bz * (0.5 - qx**2 - qy**2) - m[2]]
        J += [[-2 * bz * qy, 2 * bz * qz, -4 * bx * qy - 2 * bz * qw, -4 * bx * qz + 2 * bz * qx],
              [-2 * bx * qz + 2 * bz * qx, 2 * bx * qy + 2 * bz * qw, 2 * bx * qx + 2 * bz * qz,
               -2 * bx * qw + 2 * bz * qy],
              [2 * bx * qy, 2 * bx * qz - 4 * bz * qx, 2 * bx * qw - 4 * bz * qy, 2 * bx * qx]]
    grad = np.asarray(J).T @ np.asarray(f)
    q_dot = 0.5 * quat_mul(q, np.r_[0.0, gyr])
    if np.linalg.norm(grad) > 1e-12:  # at an exact fit the gradient is zero: no step
        q_dot = q_dot - beta * grad / np.linalg.norm(grad)
    q_new = q + q_dot * dt
    return np.asarray(q_new / np.linalg.norm(q_new))


@pytest.mark.parametrize("marg", [False, True])
def test_follows_the_report_on_example_data(example: tuple, marg: bool) -> None:
    """The compiled loop against the report's equations written out with matrices, on the
    x-IMU example recording (every sample, 6D and 9D)."""
    gyr, acc, mag = example
    m = mag if marg else None
    ours = Madgwick(beta=0.041, frequency=256.0).fit(gyr, acc, m).quat_
    assert ours is not None and ours.shape == (len(gyr), 4)
    ref = np.empty_like(ours)
    ref[0] = ours[0]  # the start is initial_orientation's (tested below)
    for t in range(1, len(gyr)):
        ref[t] = _paper_step(ref[t - 1], gyr[t], acc[t], None if m is None else m[t],
                             0.041, 1 / 256.0)
    assert np.max(np.abs(ours - ref)) < 1e-9


@pytest.mark.parametrize("marg", [False, True])
def test_matches_ahrs_on_example_data(example: tuple, marg: bool) -> None:
    """Another implementation (``ahrs``) gives the same orientations. Compared from its
    second sample on: ``ahrs`` starts from the first sample's own orientation, where the
    recording's first two samples are identical, so its first step normalises a zero
    gradient's rounding noise (a β·dt step in a direction that changes with the numpy
    build); the engine takes no step there."""
    ahrs_filters = pytest.importorskip("ahrs.filters")
    gyr, acc, mag = example
    m = mag if marg else None
    ref = ahrs_filters.Madgwick(gyr=gyr, acc=acc, mag=m, frequency=256.0, gain=0.041).Q
    second = _paper_step(ref[1], gyr[2], acc[2], None if m is None else m[2], 0.041, 1 / 256.0)
    if np.max(np.abs(second - ref[2])) > 1e-9:
        import ahrs

        pytest.skip(f"the installed ahrs {ahrs.__version__} (numpy {np.__version__}) departs "
                    "from Madgwick's equations: not a reference")
    ours = Madgwick(beta=0.041, frequency=256.0).fit(
        gyr[1:], acc[1:], None if m is None else m[1:], q0=ref[1]).quat_
    assert ours is not None and ours.shape == ref[1:].shape
    assert np.max(np.abs(ours - ref[1:])) < 1e-6


def test_example_data_through_loader(shared_data: Path) -> None:
    rec = load_madgwick_mat(shared_data / "imu" / "madgwick" / "ExampleData.mat")
    assert rec.frequency == pytest.approx(256.0)
    assert np.median(np.linalg.norm(rec.acc, axis=1)) == pytest.approx(9.81, abs=0.3)
    q = madgwick(rec.gyr, rec.acc, rec.mag, beta=0.041, frequency=rec.frequency)
    # the sensor starts lying still: the estimated up axis agrees with the accelerometer
    up_sensor = quat_rotate(quat_conj(q[100]), [0.0, 0.0, 1.0])
    a = rec.acc[100] / np.linalg.norm(rec.acc[100])
    assert np.degrees(np.arccos(np.clip(up_sensor @ a, -1, 1))) < 2.0


def test_many_sensors_equal_single_runs() -> None:
    rng = np.random.default_rng(1)
    T, S = 400, 3
    gyr = rng.normal(0, 0.5, (T, S, 3))
    acc = rng.normal(0, 1.0, (T, S, 3)) + np.array([0.0, 0.0, 9.81])
    mag = rng.normal(0, 1.0, (T, S, 3)) + np.array([20.0, 0.0, -40.0])
    q_all = madgwick(gyr, acc, mag, beta=0.1, frequency=100.0)
    for s in range(S):
        q_one = madgwick(gyr[:, s], acc[:, s], mag[:, s], beta=0.1, frequency=100.0)
        assert np.allclose(q_all[:, s], q_one, atol=1e-12)


def test_static_converges_to_truth_in_enu() -> None:
    # a sensor rotated by a known orientation, at rest, sees gravity and the field
    q_true = quat_from_axis_angle([0.3, -0.5, 0.8], 1.2)
    T = 3000
    field_enu = np.array([0.0, 20.0, -44.0])
    acc = np.tile(quat_rotate(quat_conj(q_true), [0.0, 0.0, 9.81]), (T, 1))
    mag = np.tile(quat_rotate(quat_conj(q_true), field_enu), (T, 1))
    gyr = np.zeros((T, 3))
    start = quat_from_axis_angle([1.0, 0.0, 0.0], 0.5)  # deliberately wrong start
    q = madgwick(gyr, acc, mag, beta=0.5, frequency=100.0, q0=start, frame="ENU")
    assert quat_angle(quat_mul(q[-1], quat_conj(q_true))) < np.deg2rad(0.5)
    # the TRIAD initial orientation is exact for noise-free data
    q0 = initial_orientation(acc[0], mag[0], "ENU")
    assert quat_angle(quat_mul(q0, quat_conj(q_true))) < 1e-9
    assert np.allclose(from_enu(to_enu(q0)), q0)


def test_input_errors() -> None:
    g = np.zeros((10, 3))
    a = np.tile([0.0, 0.0, 9.81], (10, 1))
    with pytest.raises(InputError, match="shape"):
        madgwick(g, a[:5])
    with pytest.raises(InputError, match="frequency"):
        madgwick(g, a, frequency=0.0)
    with pytest.raises(InputError, match="beta"):
        madgwick(g, a, beta=-1.0)
    with pytest.raises(InputError, match="accelerometer"):
        initial_orientation([0.0, 0.0, 0.0])
    with pytest.raises(InputError, match="parallel"):
        initial_orientation([0.0, 0.0, 1.0], [0.0, 0.0, -5.0])


def test_nan_gyro_holds_orientation() -> None:
    g = np.zeros((20, 3))
    g[:, 2] = 1.0
    g[10] = np.nan
    a = np.tile([0.0, 0.0, 9.81], (20, 1))
    q = madgwick(g, a, beta=0.0, frequency=100.0, q0=[1, 0, 0, 0])
    assert np.allclose(q[10], q[9])
    assert np.all(np.isfinite(q))


def test_bias_drift_compensation_zeta() -> None:
    from engine.geometry import make_transform, quat_to_matrix
    from engine.imu.metrics import orientation_errors
    from engine.sim.imu import ImuNoise, simulate_imu

    fs = 100.0
    t = np.arange(0.0, 120.0, 1 / fs)
    rv = np.stack([0.8 * np.sin(0.5 * t), 0.6 * np.sin(0.3 * t + 1.0), 1.2 * np.sin(0.2 * t)], 1)
    q = np.stack([quat_from_axis_angle(r / max(np.linalg.norm(r), 1e-12), np.linalg.norm(r))
                  for r in rv])
    poses = np.stack([make_transform(quat_to_matrix(qq), [0.0, 0.0, 0.0]) for qq in q])
    noise = ImuNoise(gyr_noise=0.002, gyr_bias=np.deg2rad(1.5), gyr_bias_walk=0.0)
    rec = simulate_imu(t, poses, noise=noise, rng=2)
    late = t > 60
    errs = {}
    for zeta in (0.0, 0.015):
        qe = madgwick(rec.gyr, rec.acc, rec.mag, beta=0.01, frequency=fs, frame="ENU",
                      q0=rec.quat_ref[0], zeta=zeta)
        errs[zeta] = orientation_errors(qe, rec.quat_ref, late)["total_deg"]
    assert errs[0.015] < 0.7 * errs[0.0]
    with pytest.raises(InputError, match="zeta"):
        madgwick(rec.gyr, rec.acc, zeta=-1.0)
