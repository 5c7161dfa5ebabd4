"""IMU import: formats, unit conversion, and the errors/warnings bad files must give."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from engine.errors import InputError
from engine.imu.io import G, load_broad, load_csv, load_imu, load_xio_csv

FS = 100.0
N = 300


def _motion(seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Plausible SI data: time s, gyr rad/s, acc m/s², mag µT."""
    rng = np.random.default_rng(seed)
    t = np.arange(N) / FS
    gyr = np.stack([np.sin(3 * t), np.cos(2 * t), 0.5 * np.sin(t)], 1) * 2.0
    acc = rng.normal(0, 0.5, (N, 3)) + np.array([0.0, 0.0, G])
    mag = rng.normal(0, 0.3, (N, 3)) + np.array([20.0, 0.0, -44.0])
    return t, gyr, acc, mag


def _write(path: Path, header: list[str], cols: list[np.ndarray], sep: str = ",") -> Path:
    data = np.column_stack(cols)
    lines = [sep.join(header)] + [sep.join("" if np.isnan(v) else f"{v:.9g}" for v in row)
                                  for row in data]
    path.write_text("\n".join(lines) + "\n")
    return path


def _xio_header(mag: bool = True) -> list[str]:
    h = ["Packet number"]
    h += [f"Gyroscope {a} (deg/s)" for a in "XYZ"]
    h += [f"Accelerometer {a} (g)" for a in "XYZ"]
    if mag:
        h += [f"Magnetometer {a} (G)" for a in "XYZ"]
    return h


def test_xio_csv_converts_units(tmp_path: Path) -> None:
    _, gyr, acc, mag = _motion()
    p = _write(tmp_path / "imu.csv", _xio_header(),
               [np.arange(N), np.rad2deg(gyr), acc / G, mag / 100.0])
    rec = load_xio_csv(p, frequency=FS)
    assert np.allclose(rec.gyr, gyr, atol=1e-6)
    assert np.allclose(rec.acc, acc, atol=1e-6)
    assert rec.mag is not None and np.allclose(rec.mag, mag, atol=1e-5)
    assert rec.frequency == pytest.approx(FS)
    assert rec.warnings == []
    # the same through the dispatcher
    assert np.allclose(load_imu(p, frequency=FS).gyr, rec.gyr)
    with pytest.raises(InputError, match="frequency"):
        load_xio_csv(p)


def test_xio_csv_missing_group_and_extra_columns(tmp_path: Path) -> None:
    t, gyr, acc, _ = _motion()
    h = ["Time (s)"] + [f"Gyroscope {a} (deg/s)" for a in "XYZ"] + ["Temperature (C)"]
    p = _write(tmp_path / "g.csv", h, [t, np.rad2deg(gyr), np.full(N, 25.0)])
    with pytest.raises(InputError, match="Accelerometer"):
        load_xio_csv(p)
    h = ["Time (s)", *_xio_header(mag=False)[1:], "Temperature (C)"]
    p = _write(tmp_path / "x.csv", h, [t, np.rad2deg(gyr), acc / G, np.full(N, 25.0)])
    rec = load_xio_csv(p)
    assert rec.mag is None
    assert any("Temperature" in w for w in rec.warnings)


def _generic(tmp_path: Path, gyr_scale: float = 1.0, acc_scale: float = 1.0,
             t_override: np.ndarray | None = None, nan_row: int | None = None,
             extra: bool = False) -> Path:
    t, gyr, acc, mag = _motion()
    g = gyr * gyr_scale
    if nan_row is not None:
        g = g.copy()
        g[nan_row] = np.nan
    header = ["time", "gyr_x", "gyr_y", "gyr_z", "acc_x", "acc_y", "acc_z", "mag_x", "mag_y",
              "mag_z"]
    cols = [t if t_override is None else t_override, g, acc * acc_scale, mag]
    if extra:
        header.append("battery")
        cols.append(np.ones(N))
    return _write(tmp_path / "generic.csv", header, cols, sep=";")


def test_generic_csv_ok_and_warnings(tmp_path: Path) -> None:
    rec = load_csv(_generic(tmp_path, nan_row=10, extra=True), gyr_unit="rad/s",
                   acc_unit="m/s2", mag_unit="uT")
    assert rec.frequency == pytest.approx(FS)
    assert any("NaN" in w for w in rec.warnings)
    assert any("battery" in w for w in rec.warnings)
    assert np.isnan(rec.gyr[10]).all()


def test_generic_csv_unit_mistakes(tmp_path: Path) -> None:
    # deg/s data declared as rad/s: found from the magnitude
    p = _generic(tmp_path, gyr_scale=180 / np.pi)  # peaks of 115 "rad/s"
    with pytest.raises(InputError, match="deg/s"):
        load_csv(p, gyr_unit="rad/s", acc_unit="m/s2", mag_unit="uT")
    # g data declared as m/s²
    p = _generic(tmp_path, acc_scale=1 / G)
    with pytest.raises(InputError, match="in g"):
        load_csv(p, gyr_unit="rad/s", acc_unit="m/s2", mag_unit="uT")
    # m/s² data declared as g
    p = _generic(tmp_path)
    with pytest.raises(InputError, match="m/s"):
        load_csv(p, gyr_unit="rad/s", acc_unit="g", mag_unit="uT")
    with pytest.raises(InputError, match="unknown gyroscope unit"):
        load_csv(p, gyr_unit="rpm", acc_unit="m/s2", mag_unit="uT")
    # µT declared as nT -> implausible field, a warning (not an error)
    rec = load_csv(p, gyr_unit="rad/s", acc_unit="m/s2", mag_unit="nT")
    assert any("magnetic" in w for w in rec.warnings)


def test_generic_csv_time_and_columns(tmp_path: Path) -> None:
    t = np.arange(N) / FS
    t2 = t.copy()
    t2[50] = t2[48]
    with pytest.raises(InputError, match="strictly increasing"):
        load_csv(_generic(tmp_path, t_override=t2), gyr_unit="rad/s", acc_unit="m/s2",
                 mag_unit="uT")
    p = _write(tmp_path / "short.csv", ["time", "gyr_x", "gyr_y", "acc_x"],
               [t, t, t, t])
    with pytest.raises(InputError, match="missing column"):
        load_csv(p, gyr_unit="rad/s", acc_unit="m/s2")
    with pytest.raises(InputError, match="missing column"):
        load_imu(p)
    with pytest.raises(InputError, match="unsupported"):
        load_imu(tmp_path / "x.bin")


def test_broad_hdf5_and_mat_agree(shared_data: Path, tmp_path: Path) -> None:
    import scipy.io

    src = shared_data / "imu" / "broad" / "24_disturbed_tapping_A.hdf5"
    rec = load_broad(src)
    assert rec.frequency == pytest.approx(285.714, abs=1e-2)
    assert rec.quat_ref is not None and rec.quat_ref.shape == (len(rec), 4)
    assert rec.movement is not None and rec.movement.any()
    ok = np.isfinite(rec.quat_ref).all(1)
    assert np.allclose(np.linalg.norm(rec.quat_ref[ok], axis=1), 1.0, atol=1e-6)
    n = 2000
    mat = tmp_path / "trial.mat"
    scipy.io.savemat(mat, {"imu_gyr": rec.gyr[:n], "imu_acc": rec.acc[:n],
                           "imu_mag": rec.mag[:n] if rec.mag is not None else None,
                           "opt_quat": rec.quat_ref[:n], "movement": rec.movement[:n],
                           "sampling_rate": rec.frequency})
    rec2 = load_imu(mat)
    assert rec2.meta["format"] == "broad"
    assert np.allclose(rec2.gyr, rec.gyr[:n])
    assert np.array_equal(rec2.movement, rec.movement[:n])
    bad = tmp_path / "bad.hdf5"
    bad.write_bytes(b"not hdf5")
    with pytest.raises(InputError, match=r"bad\.hdf5: not a readable HDF5 file"):
        load_broad(bad)


def _mat_bytes(tmp_path: Path) -> bytes:
    """A small valid Madgwick-layout .mat file (compressed, as MATLAB writes them)."""
    import scipy.io

    t = np.arange(200) / 100.0
    p = tmp_path / "ok.mat"
    scipy.io.savemat(p, {"time": t[:, None], "Gyroscope": np.zeros((200, 3)),
                         "Accelerometer": np.tile([0.0, 0.0, 1.0], (200, 1)),
                         "Magnetometer": np.tile([0.2, 0.0, -0.4], (200, 1))},
                     do_compression=True)
    assert load_imu(p).gyr.shape == (200, 3)
    return p.read_bytes()


def test_damaged_mat_and_hdf5_give_input_error(tmp_path: Path) -> None:
    """Truncated, corrupted or mislabelled files: a typed InputError naming the file and
    saying to export it again, never a scipy/zlib/h5py exception."""
    good = _mat_bytes(tmp_path)
    rng = np.random.default_rng(0)
    cases = [good[:n] for n in (0, 10, 128, 300, len(good) // 2, len(good) - 5)]
    for _ in range(15):
        b = bytearray(good)
        for i in rng.integers(128, len(b), 10):
            b[i] = int(rng.integers(0, 256))
        cases.append(bytes(b))
    cases += [b"MATLAB 5.0 MAT-file" + bytes(200), rng.bytes(3000)]
    bad = tmp_path / "trial.mat"
    n_damaged = 0
    for c in cases:
        bad.write_bytes(c)
        for reader in (load_imu, load_broad):
            try:
                reader(bad)
            except InputError as e:
                assert "trial" in str(e)
                n_damaged += "export it again" in str(e)
    assert n_damaged >= len(cases)  # most fail in the reader itself
    h5 = tmp_path / "trial.hdf5"
    h5.write_bytes(b"\x89HDF\r\n\x1a\n" + rng.bytes(500))
    with pytest.raises(InputError, match=r"trial\.hdf5: not a readable HDF5 file"):
        load_imu(h5)
    # a readable .mat whose variables are not numeric
    import scipy.io

    scipy.io.savemat(bad, {"time": np.array(["a", "b"]), "Gyroscope": np.zeros((2, 3)),
                           "Accelerometer": np.zeros((2, 3))})
    with pytest.raises(InputError, match="'time' is not numeric"):
        load_imu(bad)


def test_load_imu_names_an_option_the_csv_reader_does_not_take(tmp_path: Path) -> None:
    """An option meant for another reader (``platform`` is for a phone app's zip) is an
    InputError that names it and the CSV reader's options, not a TypeError; the list of
    options passed on is exactly load_csv's keywords."""
    import inspect

    from engine.imu.io import _CSV_OPTIONS

    keywords = {n for n, p in inspect.signature(load_csv).parameters.items()
                if p.kind is inspect.Parameter.KEYWORD_ONLY}
    assert keywords == _CSV_OPTIONS
    path = _generic(tmp_path)
    with pytest.raises(InputError, match=r"no option platform .*gyr_unit.*zip or folder"):
        load_imu(path, platform="ios")
    assert load_imu(path, gyr_unit="rad/s", acc_unit="m/s2", mag_unit="uT").frequency \
        == pytest.approx(FS)
