"""Xsens MVN exports (``.mvnx``) and phone apps' one-file-per-sensor exports (Sensor
Logger, phyphox; zip or folder), written here from a simulated motion with a known
orientation (:func:`engine.sim.imu.simulate_imu`) as the vendors lay them out:

* MVNX: namespaced XML, ``identity``/``tpose`` frames before the motion, per frame
  ``sensorOrientation`` (w-first, sensor-to-NWU), ``sensorFreeAcceleration`` (global,
  gravity removed), ``sensorMagneticField`` (a.u.), the segments' ``angularVelocity``
  (global); older exports' ``sensorAcceleration``/``sensorAngularVelocity``.
* Sensor Logger: ``time`` (ns since the epoch), ``seconds_elapsed``, ``z, y, x``;
  ``Accelerometer.csv`` without gravity plus ``Gravity.csv`` (iOS), ``Orientation.csv``
  (``qx…qw``), ``Metadata.csv`` (platform, standardisation); iOS' negated acceleration.
* phyphox: ``Time (s)``, ``X (m/s^2)`` …, ``meta/device.csv``; accelerometer and
  gyroscope at different rates.

Each must give the simulated readings in SI and, through the filters (ours and
Madgwick's), the orientation error against the truth that the plain CSV import of the
same samples gives.
"""

from __future__ import annotations

import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from engine.errors import InputError
from engine.geometry import quat_conj, quat_from_rotvec, quat_mul, quat_rotate, quat_to_matrix
from engine.imu import _phone
from engine.imu.filter import orientation_filter
from engine.imu.io import G, ImuRecording, MultipleSensorsError, load_imu, load_mvnx_all
from engine.imu.madgwick import madgwick
from engine.imu.metrics import orientation_errors
from engine.sim.imu import NO_NOISE, simulate_imu
from tests.engine.imu.test_foreign_imu import DEG, write_csv, xyz_lower

NS = "http://www.xsens.com/mvn/mvnx"
#: NWU <- ENU (the inverse of the reader's +90° about Z)
_Q_NWU_ENU = np.array([np.sqrt(0.5), 0.0, 0.0, -np.sqrt(0.5)])


def _motion(fs: float = 100.0, seconds: float = 8.0, peak: float = 3.0, rng: int = 1,
            noise: bool = True) -> ImuRecording:
    """A walk-like sway (as :func:`tests.engine.imu.test_imu_sweep._synthetic`), 2 s at
    rest first so the filters settle."""
    t = np.arange(0.0, seconds, 1.0 / fs)
    s = np.clip(t - 2.0, 0.0, None)
    rv = np.stack([0.3 * np.sin(2 * np.pi * 0.9 * s), 0.2 * np.sin(2 * np.pi * 0.45 * s),
                   0.1 * np.sin(2 * np.pi * 0.3 * s + 1.0) - 0.1 * np.sin(1.0)], 1)
    rv = rv * peak / 1.8 + np.array([0.2, -0.1, 0.4])
    T = np.tile(np.eye(4), (len(t), 1, 1))
    T[:, :3, :3] = quat_to_matrix(quat_from_rotvec(rv))
    T[:, 0, 3] = 1.2 * s
    T[:, 2, 3] = 1.0 + 0.02 * np.sin(2 * np.pi * 1.8 * s)
    kw = {} if noise else {"noise": NO_NOISE}
    return simulate_imu(t, T, rng=rng, name="sim", **kw)


@pytest.fixture(scope="module")
def sims() -> dict[str, ImuRecording]:
    a = _motion(rng=1)
    b = _motion(rng=2, peak=2.0)
    return {"Pelvis": a, "RightLowerLeg": b}


def errors(rec: ImuRecording, truth: np.ndarray) -> dict[str, float]:
    """Total error (deg) of our filter and Madgwick's against the true orientation."""
    q, _, _ = orientation_filter(rec.gyr, rec.acc, rec.mag, frequency=rec.frequency,
                                 offline=True)
    qm = madgwick(rec.gyr, rec.acc, rec.mag, frequency=rec.frequency, frame="ENU")
    return {"ours": orientation_errors(q, truth)["total_deg"],
            "madgwick": orientation_errors(qm, truth)["total_deg"]}


def csv_import(tmp_path: Path, r: ImuRecording, name: str = "plain.csv") -> ImuRecording:
    assert r.mag is not None
    cols = [("time", r.time), *xyz_lower("acc_{}", r.acc), *xyz_lower("gyr_{}", r.gyr, DEG),
            *xyz_lower("mag_{}", r.mag)]
    return load_imu(write_csv(tmp_path / name, cols))


# ------------------------------------------------------------------------ MVNX


def _vals(a: np.ndarray) -> str:
    return " ".join(f"{v:.9g}" for v in a.ravel())


def write_mvnx(path: Path, sims: dict[str, ImuRecording], *, segment_w: bool = True,
               raw: str = "", free: bool = True, sensors_tag: bool = True,
               doctype: bool = False, fs: float = 100.0) -> Path:
    """An MVN export of ``sims`` (label -> recording with ``quat_ref`` truth in ENU).

    ``raw``: "" (MVN 2018+: no raw readings), "sensor" (``sensorAcceleration`` and
    ``sensorAngularVelocity`` in the sensor frame) or "global" (the angular velocity in
    the global frame)."""
    labels = list(sims)
    segments = ["Pelvis", "L5", "RightUpperLeg", "RightLowerLeg"]
    n = len(next(iter(sims.values())))
    q_nwu = {k: quat_mul(_Q_NWU_ENU, r.quat_ref) for k, r in sims.items()}
    field = {k: float(np.median(np.linalg.norm(r.mag, axis=1))) for k, r in sims.items()}
    out = ['<?xml version="1.0" encoding="UTF-8" standalone="no"?>']
    if doctype:
        out.append('<!DOCTYPE mvnx [<!ENTITY a "aaaaaaaa">]>')
    out += [f'<mvnx version="4" xmlns="{NS}">', '<mvn version="2022.0.0" build="1"/>',
            '<comment>synthetic</comment>',
            f'<subject label="s" frameRate="{fs:g}" segmentCount="{len(segments)}" '
            'recDate="Tue Nov 24 10:00:00.000 2026" originalFilename="take.mvn">',
            "<segments>"]
    for i, s in enumerate(segments):
        out.append(f'<segment label="{s}" id="{i + 1}"><points><point label="p">'
                   '<pos_b>0 0 0</pos_b></point></points></segment>')
    out.append("</segments>")
    if sensors_tag:
        out.append("<sensors>" + "".join(f'<sensor label="{k}"/>' for k in labels)
                   + "</sensors>")
    out.append(f'<frames segmentCount="{len(segments)}" sensorCount="{len(labels)}">')
    for kind in ("identity", "tpose", "tpose-isb"):
        out.append(f'<frame time="0" tc="" ms="" type="{kind}"><orientation>'
                   + _vals(np.tile([1.0, 0, 0, 0], len(segments))) + "</orientation></frame>")
    up = np.array([0.0, 0.0, G])
    for i in range(n):
        so, fa, mf, sa, sw = [], [], [], [], []
        seg = np.zeros((len(segments), 3))
        for k, r in sims.items():
            q = q_nwu[k][i]
            so.append(q)
            fa.append(quat_rotate(q, r.acc[i]) - up)
            mf.append(r.mag[i] / field[k])
            sa.append(r.acc[i])
            sw.append(r.gyr[i] if raw == "sensor" else quat_rotate(q, r.gyr[i]))
            seg[segments.index(k)] = quat_rotate(q, r.gyr[i])
        parts = [f'<frame time="{round(i * 1000 / fs)}" index="{i}" tc="00:00:00:00" '
                 f'ms="{1764000000000 + round(i * 1000 / fs)}" type="normal">',
                 f"<orientation>{_vals(np.tile([1.0, 0, 0, 0], len(segments)))}</orientation>"]
        if segment_w:
            parts.append(f"<angularVelocity>{_vals(seg)}</angularVelocity>")
        if raw:
            parts.append(f"<sensorAcceleration>{_vals(np.array(sa))}</sensorAcceleration>")
            parts.append(f"<sensorAngularVelocity>{_vals(np.array(sw))}"
                         "</sensorAngularVelocity>")
        if free:
            parts.append(f"<sensorFreeAcceleration>{_vals(np.array(fa))}"
                         "</sensorFreeAcceleration>")
        parts.append(f"<sensorMagneticField>{_vals(np.array(mf))}</sensorMagneticField>")
        parts.append(f"<sensorOrientation>{_vals(np.array(so))}</sensorOrientation>")
        parts.append("</frame>")
        out.append("".join(parts))
    out += ["</frames>", "</subject>", "</mvnx>"]
    path.write_text("\n".join(out) + "\n", encoding="utf-8")
    return path


@pytest.mark.parametrize("raw", ["", "sensor", "global"])
def test_mvnx_round_trip(sims: dict[str, ImuRecording], tmp_path: Path, raw: str) -> None:
    """Every tracker becomes a stream with the simulated readings (the text keeps 9
    digits), its MVN orientation the reference in ENU, and the filters' error against
    the truth that of the plain CSV import of the same samples."""
    p = write_mvnx(tmp_path / "take.mvnx", sims, raw=raw)
    recs = load_mvnx_all(p)
    assert list(recs) == list(sims)
    for label, sim in sims.items():
        rec = recs[label]
        assert sim.mag is not None and sim.quat_ref is not None and rec.mag is not None
        assert rec.meta["format"] == "xsens-mvnx" and rec.meta["mag_unit"] == "norm"
        assert len(rec) == len(sim) and rec.frequency == pytest.approx(100.0)
        assert np.allclose(rec.time, sim.time - sim.time[0], atol=1e-9)
        assert np.allclose(rec.acc, sim.acc, atol=2e-6), np.abs(rec.acc - sim.acc).max()
        assert np.allclose(rec.gyr, sim.gyr, atol=2e-7), np.abs(rec.gyr - sim.gyr).max()
        field = np.median(np.linalg.norm(sim.mag, axis=1))
        assert np.allclose(rec.mag * field, sim.mag, atol=1e-5)
        assert rec.quat_ref is not None
        assert np.all(np.abs(np.sum(rec.quat_ref * sim.quat_ref, axis=1)) > 1 - 1e-12)
        want = {"": "segment", "sensor": "(sensor frame)", "global": "(global frame"}[raw]
        assert want in rec.meta["gyr_from"]
        got, plain = errors(rec, sim.quat_ref), errors(csv_import(tmp_path, sim), sim.quat_ref)
        for f in ("ours", "madgwick"):
            assert got[f] == pytest.approx(plain[f], abs=0.005), (f, got, plain)
        # the file's own reference gives the truth's error
        own = errors(rec, rec.quat_ref)
        assert own["ours"] == pytest.approx(got["ours"], abs=1e-6)
    assert plain["ours"] < 3.0  # the comparison is of a working filter


def test_mvnx_gyroscope_from_the_orientation(sims: dict[str, ImuRecording],
                                             tmp_path: Path) -> None:
    """Without any angular velocity in the export, the rates are the rotation between
    consecutive sensor orientations: MVN's orientation is noise-free here, so the
    error stays within 0.5° of the plain import (whose gyroscope has noise and bias)."""
    p = write_mvnx(tmp_path / "take.mvnx", sims, segment_w=False)
    rec = load_imu(p, sensor="pelvis")
    sim = sims["Pelvis"]
    assert sim.quat_ref is not None
    assert "consecutive" in rec.meta["gyr_from"]
    assert any("frame-to-frame rotation" in w for w in rec.warnings)
    truth_w = np.abs(rec.gyr[1:] - sim.gyr[1:]).max()
    assert truth_w < 0.1  # the sim's noise and bias, not a wrong frame
    got, plain = errors(rec, sim.quat_ref), errors(csv_import(tmp_path, sim), sim.quat_ref)
    assert abs(got["ours"] - plain["ours"]) < 0.5, (got, plain)


def test_mvnx_choice_and_refusals(sims: dict[str, ImuRecording], tmp_path: Path) -> None:
    p = write_mvnx(tmp_path / "take.mvnx", sims)
    with pytest.raises(MultipleSensorsError, match="Pelvis, RightLowerLeg") as e:
        load_imu(p)
    assert e.value.sensors == ["Pelvis", "RightLowerLeg"]
    assert load_imu(p, sensor="rightlowerleg").name == "RightLowerLeg"
    with pytest.raises(InputError, match="no sensor 'Head'"):
        load_imu(p, sensor="Head")
    # no <sensors> list: numbered
    q = write_mvnx(tmp_path / "nolabels.mvnx", sims, sensors_tag=False)
    assert list(load_mvnx_all(q)) == ["sensor1", "sensor2"]
    # a segment-only export
    text = p.read_text()
    seg_only = tmp_path / "segments.mvnx"
    seg_only.write_text(text.replace("sensorOrientation", "segmentThing"))
    with pytest.raises(InputError, match="no sensor data"):
        load_imu(seg_only, sensor="Pelvis")
    no_acc = write_mvnx(tmp_path / "noacc.mvnx", sims, free=False)
    with pytest.raises(InputError, match="sensorFreeAcceleration"):
        load_mvnx_all(no_acc)
    bomb = write_mvnx(tmp_path / "dtd.mvnx", {"Pelvis": sims["Pelvis"]}, doctype=True)
    with pytest.raises(InputError, match="DTD"):
        load_imu(bomb)
    cut = tmp_path / "cut.mvnx"
    cut.write_bytes(p.read_bytes()[: len(p.read_bytes()) // 2])
    with pytest.raises(InputError, match="damaged or truncated"):
        load_imu(cut, sensor="Pelvis")
    # a frame without an element the others have; frames out of order
    first = text.index("<sensorFreeAcceleration>", text.index('index="5"'))
    gap = tmp_path / "gap.mvnx"
    gap.write_text(text[:first] + text[text.index("</sensorFreeAcceleration>", first) + 25:])
    with pytest.raises(InputError, match="frame 5 lacks <sensorFreeAcceleration>"):
        load_imu(gap, sensor="Pelvis")
    swapped = tmp_path / "swapped.mvnx"
    swapped.write_text(text.replace('index="7"', 'index="3"'))
    with pytest.raises(InputError, match="index does not increase at motion frame 7"):
        load_imu(swapped, sensor="Pelvis")
    other = tmp_path / "other.mvnx"
    other.write_text("<?xml version='1.0'?><data>1 2 3</data>")
    with pytest.raises(InputError, match="not an Xsens MVNX"):
        load_imu(other)


# ------------------------------------------------------------------ phone apps


def _sl_file(cols: dict[str, np.ndarray], t: np.ndarray, t0_ns: int) -> str:
    """A Sensor Logger CSV: time (epoch ns), seconds_elapsed, then the columns."""
    names = ["time", "seconds_elapsed", *cols]
    rows = [",".join(names)]
    for i, v in enumerate(t):
        rows.append(",".join([str(t0_ns + round(v * 1e9)), f"{v:.9f}",
                              *(f"{c[i]:.9g}" for c in cols.values())]))
    return "\n".join(rows) + "\n"


def sensor_logger(sim: ImuRecording, *, ios: bool, orientation: bool = True,
                  metadata: str | None = None, gyro: bool = True,
                  accel: bool = True) -> dict[str, str]:
    """Sensor Logger's files for ``sim``: acceleration split into user acceleration and
    gravity (as iOS logs it; Android's TotalAcceleration is their sum), iOS sign if asked."""
    assert sim.mag is not None and sim.quat_ref is not None
    t, t0 = sim.time, 1_764_000_000_000_000_000
    grav = quat_rotate(quat_conj(sim.quat_ref), np.array([0.0, 0.0, G]))
    user = sim.acc - grav
    s = -1.0 if ios else 1.0

    def zyx(a: np.ndarray) -> dict[str, np.ndarray]:
        return {"z": a[:, 2], "y": a[:, 1], "x": a[:, 0]}

    files = {"Magnetometer.csv": _sl_file(zyx(sim.mag), t, t0)}
    if gyro:
        files["Gyroscope.csv"] = _sl_file(zyx(sim.gyr), t, t0)
    if accel:
        files["Accelerometer.csv"] = _sl_file(zyx(s * user), t, t0)
        files["Gravity.csv"] = _sl_file(zyx(s * grav), t, t0)
    if orientation:
        q = sim.quat_ref
        files["Orientation.csv"] = _sl_file(
            {"qz": q[:, 3], "qy": q[:, 2], "qx": q[:, 1], "qw": q[:, 0],
             "roll": np.zeros(len(t)), "pitch": np.zeros(len(t)), "yaw": np.zeros(len(t))},
            t, t0)
    if metadata is not None:
        files["Metadata.csv"] = metadata
    files["Annotation.csv"] = "time,seconds_elapsed,text,millisecond_press_duration\n"
    return files


def _meta(platform: str, standardisation: bool) -> str:
    return ("version,device name,recording epoch time,recording time,recording timezone,"
            "platform,appVersion,device id,sensors,sampleRateMs,standardisation,"
            "platform version\n"
            f"3,Phone,1764000000000,2026-11-24_10-00-00,Europe/Berlin,{platform},1.64,abc,"
            f"Accelerometer|Gyroscope,10|10,{str(standardisation).lower()},17\n")


def zip_files(path: Path, files: dict[str, str | bytes], folder: str = "") -> Path:
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for name, content in files.items():
            z.writestr(folder + name, content)
    return path


@pytest.mark.parametrize("ios", [True, False])
def test_sensor_logger_zip_round_trip(sims: dict[str, ImuRecording], tmp_path: Path,
                                      ios: bool) -> None:
    """iOS (negated acceleration, user acceleration + gravity files) and Android: the
    sign told from the phone's orientation, the readings the simulated ones, the filters'
    error that of the plain CSV import; the orientation file becomes the reference."""
    sim = sims["Pelvis"]
    assert sim.quat_ref is not None
    p = zip_files(tmp_path / "rec.zip", sensor_logger(sim, ios=ios,
                                                      metadata=_meta("android", False)))
    rec = load_imu(p)
    assert rec.meta["format"] == "phone-files"
    assert rec.meta["acc_sign"] == ("ios" if ios else "android")
    assert rec.meta["acc_sign_from"] == "orientation"
    assert len(rec) == len(sim)
    assert np.allclose(rec.time, sim.time, atol=1e-6)
    assert np.allclose(rec.acc, sim.acc, atol=1e-6)
    assert np.allclose(rec.gyr, sim.gyr, atol=1e-8)
    assert rec.mag is not None and np.allclose(rec.mag, sim.mag, atol=1e-6)
    if ios:  # the metadata said android: the data wins, and says so
        assert any("the data is followed" in w for w in rec.warnings)
    got, plain = errors(rec, sim.quat_ref), errors(csv_import(tmp_path, sim), sim.quat_ref)
    for f in ("ours", "madgwick"):
        assert got[f] == pytest.approx(plain[f], abs=0.005), (f, got, plain)
    assert rec.quat_ref is not None
    assert np.all(np.abs(np.sum(rec.quat_ref * sim.quat_ref, axis=1)) > 1 - 1e-9)


@pytest.mark.parametrize(("meta", "declared", "want", "source"), [
    (("ios", False), None, "ios", "metadata"),
    (("ios", True), None, "android", "metadata"),  # "Standardise Units & Frames" on
    (("android", False), None, "android", "metadata"),
    (None, None, "android", "assumed"),
    (None, "ios", "ios", "declared"),
    (("android", False), "ios", "ios", "declared"),
])
def test_phone_sign_without_orientation(sims: dict[str, ImuRecording], tmp_path: Path,
                                        meta: tuple[str, bool] | None, declared: str | None,
                                        want: str, source: str) -> None:
    """No orientation file: the sign comes from the declared platform, else Sensor
    Logger's metadata, else Android's is assumed with a warning saying what to declare."""
    sim = sims["Pelvis"]
    files = sensor_logger(sim, ios=want == "ios", orientation=False,
                          metadata=_meta(*meta) if meta else None)
    p = zip_files(tmp_path / "rec.zip", files)
    rec = load_imu(p, platform=declared) if declared else load_imu(p)
    assert rec.meta["acc_sign"] == want and rec.meta["acc_sign_from"] == source
    assert np.allclose(rec.acc, sim.acc, atol=1e-6)
    assert any("declare platform 'ios'" in w for w in rec.warnings) == (source == "assumed")


def test_phyphox_folder_with_different_rates(tmp_path: Path) -> None:
    """phyphox-style files in a folder (with ``meta/device.csv``): the accelerometer at
    200 Hz, the gyroscope at 100 Hz with jittered time stamps. Merged on the gyroscope's
    stamps, the acceleration interpolated: the filters' error is within 0.1° of a plain
    CSV of the 100 Hz recording of the same motion (noise-free sensors: what differs is
    the interpolation at jittered instants; measured: ours 1.17° against 1.25°, Madgwick
    0.664° against 0.671°)."""
    fast = _motion(fs=200.0, noise=False)
    slow = _motion(fs=100.0, noise=False)
    assert slow.quat_ref is not None and slow.mag is not None
    rng = np.random.default_rng(3)
    tg = slow.time + rng.uniform(-0.2, 0.2, len(slow)) * 0.01
    tg[0] = 0.0
    d = tmp_path / "phyphox"
    (d / "meta").mkdir(parents=True)

    def file(name: str, t: np.ndarray, a: np.ndarray, unit: str) -> None:
        cols = [("Time (s)", t), *[(f"{ax} ({unit})", a[:, k]) for k, ax in enumerate("XYZ")]]
        write_csv(d / name, cols)

    file("Accelerometer.csv", fast.time, fast.acc, "m/s^2")
    file("Gyroscope.csv", tg, slow.gyr, "rad/s")
    file("Magnetometer.csv", slow.time, slow.mag, "µT")
    (d / "meta" / "device.csv").write_text('"property","value"\n"deviceModel","Pixel 7"\n'
                                           '"deviceBrand","google"\n')
    rec = load_imu(d)
    assert np.allclose(rec.time, tg, atol=1e-9)  # the gyroscope's own stamps
    assert np.allclose(rec.gyr, slow.gyr, rtol=1e-9, atol=1e-12)  # as recorded
    assert any("different rates merged" in w for w in rec.warnings)
    assert rec.meta["device"] == "Pixel 7"
    got = errors(rec, slow.quat_ref)
    plain = errors(csv_import(tmp_path, slow), slow.quat_ref)
    for f in ("ours", "madgwick"):
        assert got[f] == pytest.approx(plain[f], abs=0.1), (f, got, plain)


def test_phone_zip_refusals(sims: dict[str, ImuRecording], tmp_path: Path,
                            monkeypatch: pytest.MonkeyPatch) -> None:
    sim = sims["Pelvis"]
    no_gyro = zip_files(tmp_path / "a.zip", sensor_logger(sim, ios=False, gyro=False))
    with pytest.raises(InputError, match=r"no gyroscope file \(Gyroscope\.csv\)"):
        load_imu(no_gyro)
    no_acc = zip_files(tmp_path / "b.zip", sensor_logger(sim, ios=False, accel=False))
    with pytest.raises(InputError, match="no accelerometer file with gravity"):
        load_imu(no_acc)
    files = sensor_logger(sim, ios=False)
    only_user = {k: v for k, v in files.items() if k != "Gravity.csv"}
    with pytest.raises(InputError, match=r"holds no gravity.*no Gravity\.csv"):
        load_imu(zip_files(tmp_path / "c.zip", only_user))
    nothing = zip_files(tmp_path / "d.zip", {"Location.csv": "time,latitude\n1,2\n"})
    with pytest.raises(InputError, match="no accelerometer or gyroscope file"):
        load_imu(nothing)
    traversal = zip_files(tmp_path / "e.zip", {**files, "../../evil.csv": "x"})
    with pytest.raises(InputError, match="unsafe file name"):
        load_imu(traversal)
    absolute = zip_files(tmp_path / "f.zip", {**files, "/etc/evil.csv": "x"})
    with pytest.raises(InputError, match="unsafe file name"):
        load_imu(absolute)
    two = tmp_path / "g.zip"
    with zipfile.ZipFile(two, "w") as z:
        for folder in ("rec1/", "rec2/"):
            for k, v in files.items():
                z.writestr(folder + k, v)
    with pytest.raises(InputError, match="several recordings"):
        load_imu(two)
    ragged = zip_files(tmp_path / "k.zip", {**files, "Gyroscope.csv": "time,x,y,z\n1,2\n"})
    with pytest.raises(InputError, match=r"^Gyroscope\.csv: data row 2 has 2 fields"):
        load_imu(ragged)
    (tmp_path / "h.zip").write_bytes(b"PK\x03\x04 not really")
    with pytest.raises(InputError, match="not a readable zip"):
        load_imu(tmp_path / "h.zip")
    many = zip_files(tmp_path / "i.zip", {**files, **{f"x{i}.txt": "" for i in range(300)}})
    with pytest.raises(InputError, match=r"30[0-9] files in the zip"):
        load_imu(many)
    # a bomb: 64 MB of zeros compress to a few kB; the unpacked total is bounded
    bomb = tmp_path / "j.zip"
    with zipfile.ZipFile(bomb, "w", zipfile.ZIP_DEFLATED) as z:
        for k, v in files.items():
            z.writestr(k, v)
        z.writestr("Pressure.csv", b"0" * (64 * 2**20))
    assert bomb.stat().st_size < 2**20
    monkeypatch.setattr(_phone, "MAX_ZIP_UNCOMPRESSED", 32 * 2**20)
    with pytest.raises(InputError, match=r"unpack to 6[0-9] MB"):
        load_imu(bomb)


def test_zip_directory_read_once_for_the_bound_and_the_unpacking(
        sims: dict[str, ImuRecording], tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """``read_zip_directory`` opens the zip once: its members, the ones ``load_phone``
    unpacks and their declared total; ``load_phone`` given it opens no zip again (and
    leaves it open for its owner), given a path it opens the zip once."""
    sim = sims["Pelvis"]
    files = sensor_logger(sim, ios=False)
    p = zip_files(tmp_path / "walk.zip", {**files, "__MACOSX/._Gyroscope.csv": "x",
                                          ".hidden.csv": "x", "photo.jpg": b"\xff" * 500})
    opened: list[object] = []

    class Counting(zipfile.ZipFile):  # defined before the patch: the real class
        def __init__(self, file: Path, *a: Any, **k: Any) -> None:
            opened.append(file)
            super().__init__(file, *a, **k)

    monkeypatch.setattr(_phone.zipfile, "ZipFile", Counting)
    with _phone.read_zip_directory(p) as d:
        assert opened == [p]
        assert d.path == p and len(d.members) == len(files) + 3
        assert sorted(i.filename for i in d.sensor_members) == sorted(files)
        sizes = {k: len(v.encode() if isinstance(v, str) else v) for k, v in files.items()}
        assert d.unpacked_bytes == sum(sizes.values())
        rec = _phone.load_phone(d)
        assert opened == [p]  # unpacked from the directory already read
        assert np.allclose(rec.gyr, sim.gyr, atol=1e-8)
        assert d._zf.fp is not None  # still open: the caller owns it
    assert d._zf.fp is None
    assert _phone.zip_unpacked_bytes(p) == d.unpacked_bytes
    opened.clear()
    assert len(load_imu(p)) == len(rec) and opened == [p]
    (tmp_path / "no.zip").write_bytes(b"PK\x03\x04 not really")
    with pytest.raises(InputError, match=r"^no\.zip: not a readable zip archive"):
        _phone.read_zip_directory(tmp_path / "no.zip")


def test_phone_zip_in_a_folder_and_uncalibrated_g(sims: dict[str, ImuRecording],
                                                  tmp_path: Path) -> None:
    """The recording's files in a folder inside the zip (as a zipped export folder),
    iOS' uncalibrated acceleration in g with gravity (negated) and no separate gravity:
    unit told from the magnitudes, sign from the metadata."""
    sim = sims["Pelvis"]
    assert sim.mag is not None
    t, t0 = sim.time, 1_764_000_000_000_000_000
    zyx = {"z": -sim.acc[:, 2] / G, "y": -sim.acc[:, 1] / G, "x": -sim.acc[:, 0] / G}
    files = {"AccelerometerUncalibrated.csv": _sl_file(zyx, t, t0),
             "Gyroscope.csv": _sl_file({"z": sim.gyr[:, 2], "y": sim.gyr[:, 1],
                                        "x": sim.gyr[:, 0]}, t, t0),
             "Metadata.csv": _meta("ios", False)}
    p = zip_files(tmp_path / "export.zip", files, folder="2026-11-24_10-00-00/")
    rec = load_imu(p)
    assert rec.meta["acc_unit"] == "g" and rec.meta["acc_sign"] == "ios"
    assert np.allclose(rec.acc, sim.acc, atol=1e-6)
    assert rec.mag is None


def test_matlab_mobile(sims: dict[str, ImuRecording], tmp_path: Path) -> None:
    """MATLAB Mobile's sensor log (.mat of timetables, MATLAB objects) is refused with
    the conversion to do in MATLAB; the CSVs that conversion writes (``t, X, Y, Z``),
    zipped, are read."""
    import scipy.io

    mat = tmp_path / "sensorlog_20261124_100000.mat"
    scipy.io.savemat(mat, {"Acceleration": np.zeros((3, 3)),
                           "AngularVelocity": np.zeros((3, 3))})
    with pytest.raises(InputError, match=r"MATLAB Mobile.*writetable.*upload the zip"):
        load_imu(mat)
    sim = sims["Pelvis"]

    def table(a: np.ndarray) -> str:
        rows = ["t,X,Y,Z"] + [f"{t:.6f},{x:.10g},{y:.10g},{z:.10g}"
                              for t, (x, y, z) in zip(sim.time, a, strict=True)]
        return "\n".join(rows) + "\n"

    p = zip_files(tmp_path / "mm.zip", {"Accelerometer.csv": table(sim.acc),
                                        "Gyroscope.csv": table(sim.gyr)})
    rec = load_imu(p, platform="android")
    assert np.allclose(rec.acc, sim.acc, atol=1e-8) and np.allclose(rec.gyr, sim.gyr)
    assert rec.meta["acc_sign_from"] == "declared"
