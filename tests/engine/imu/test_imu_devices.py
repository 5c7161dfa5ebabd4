"""IMU CSVs from more devices: Shimmer (Consensys) and Xsens / Movella DOT exports, files
with several sensors' columns, and a time column that must not be a temperature.

The fixtures are written here from a synthetic recording, laid out as the vendors
document their CSVs:

* Shimmer Consensys: an Excel ``sep=`` line, column names prefixed with the device
  (``Shimmer_8C4F_Accel_LN_X_CAL``; ``_CAL`` calibrated, ``_RAW`` counts; ``Accel_LN`` the
  low-noise and ``Accel_WR`` the wide-range accelerometer), a row of units under the
  names (``ms``, ``m/(s^2)``, ``deg/s``, ``local_flux``) — older exports put a
  ``CAL``/``RAW`` row between the two; two Shimmers docked together export into one file.
* Movella DOT: metadata lines before the header, ``PacketCounter``, ``SampleTimeFine``
  (a uint32 µs clock that wraps), ``Quat_*``, ``Acc_*`` (m/s²), ``Gyr_*`` (deg/s),
  ``Mag_*`` (a.u., 1 = the field at calibration), ``Status``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from engine.errors import InputError
from engine.imu.io import G, ImuRecording, MultipleSensorsError, load_imu
from tests.engine.imu.test_imu_sweep import _synthetic


@pytest.fixture(scope="module")
def recs() -> tuple[ImuRecording, ImuRecording]:
    """Two sensors' recordings, fast enough that deg/s is told from the rates."""
    a = _synthetic(peak_rad_s=3.0, seconds=4.0)
    b = _synthetic(peak_rad_s=3.5, seconds=4.0)
    b.acc = b.acc[:, [1, 0, 2]] * np.array([1.0, -1.0, 1.0])  # another orientation
    assert a.mag is not None and b.mag is not None
    b.mag = b.mag[:, [1, 0, 2]]
    return a, b


def _fmt(v: float) -> str:
    return f"{v:.15g}"


def _shimmer(p: Path, sensors: dict[str, ImuRecording], *, sep: str = "\t",
             sep_line: bool = True, cal_row: bool = False, wide_range: bool = False,
             formatted: bool = False, ln_clip: float | None = None,
             unix_ms: float = 1.7e12) -> Path:
    """A Consensys export of one or more Shimmers (time as Unix ms)."""
    names: list[str] = []
    kinds: list[str] = []
    units: list[str] = []
    cols: list[np.ndarray] = []

    def add(name: str, unit: str, values: np.ndarray | list[str], kind: str = "CAL") -> None:
        names.append(name + ("" if cal_row else f"_{kind}"))
        kinds.append(kind)
        units.append(unit)
        cols.append(values)

    for dev, r in sensors.items():
        s = f"Shimmer_{dev}"
        assert r.mag is not None
        if formatted:  # the date as text, e.g. 2023/11/14 22:13:20.010
            add(f"{s}_TimestampSync_FormattedUnix", "no units",
                [f"2023/11/14 22:13:{20 + t:06.3f}" for t in r.time])
        add(f"{s}_Timestamp_Unix", "ms", unix_ms + 1000.0 * r.time)
        for k, ax in enumerate("XYZ"):
            add(f"{s}_Accel_LN_{ax}", "no units", np.round(2048 + 100 * r.acc[:, k]), "RAW")
        ln = r.acc if ln_clip is None else np.clip(r.acc, -ln_clip, ln_clip)
        for k, ax in enumerate("XYZ"):
            add(f"{s}_Accel_LN_{ax}", "m/(s^2)", ln[:, k])
        if wide_range:  # a second accelerometer: the low-noise one is read unless clipped
            for k, ax in enumerate("XYZ"):
                add(f"{s}_Accel_WR_{ax}", "m/(s^2)",
                    (1.05 if ln_clip is None else 1.0) * r.acc[:, k])
        add(f"{s}_Battery", "mVolts", np.full(len(r), 3900.0))
        for k, ax in enumerate("XYZ"):
            add(f"{s}_Gyro_{ax}", "deg/s", np.rad2deg(r.gyr[:, k]))
        for k, ax in enumerate("XYZ"):
            add(f"{s}_Mag_{ax}", "local_flux", r.mag[:, k] / 100.0)  # ≈ gauss
        add(f"{s}_Temperature_BMP280", "Degrees Celsius",
            24.0 + 0.5 * np.sin(r.time))  # rises first: must not be taken for time
    lines = [f'"sep={sep}"'] if sep_line else []
    lines.append(sep.join(names) + sep)  # Consensys ends each line with a separator
    if cal_row:
        lines.append(sep.join(kinds) + sep)
    lines.append(sep.join(units) + sep)
    cells = [c if isinstance(c, list) else [_fmt(v) for v in c] for c in cols]
    lines += [sep.join(row) + sep for row in zip(*cells, strict=True)]
    p.write_text("\n".join(lines) + "\n")
    return p


def _same_motion(ref: ImuRecording, got: ImuRecording, *, mag_scale: float | None = None,
                 t_atol: float = 1e-4) -> None:
    assert len(got) == len(ref)
    assert np.allclose(got.time - got.time[0], ref.time - ref.time[0], atol=t_atol)
    assert np.allclose(got.gyr, ref.gyr, rtol=1e-9, atol=1e-9)
    assert np.allclose(got.acc, ref.acc, rtol=1e-9, atol=1e-9)
    if mag_scale is not None:
        assert got.mag is not None and ref.mag is not None
        assert np.allclose(got.mag, ref.mag * mag_scale, rtol=1e-9, atol=1e-12)
        assert got.meta["mag_unit"] == "norm"  # arbitrary units: direction only


# ----------------------------------------------------------------------- Shimmer


@pytest.mark.parametrize("sep", ["\t", ",", ";"])
def test_shimmer_prefixed_columns_and_units_row(recs: tuple[ImuRecording, ImuRecording],
                                                tmp_path: Path, sep: str) -> None:
    a, _ = recs
    rec = load_imu(_shimmer(tmp_path / "shimmer.csv", {"8C4F": a}, sep=sep))
    _same_motion(a, rec, mag_scale=0.01)
    assert rec.meta["sensor"] == "Shimmer_8C4F"
    assert rec.meta["units_from"] == {"gyr": "header", "acc": "header", "mag": "header"}
    assert rec.meta["time_unit"] == "ms"
    assert not any("assumed" in w for w in rec.warnings), rec.warnings
    ignored = next(w for w in rec.warnings if w.startswith("ignored"))
    assert "Accel_LN_X_RAW" in ignored and "Temperature_BMP280_CAL" in ignored


def test_shimmer_without_sep_line_and_with_a_cal_raw_row(
        recs: tuple[ImuRecording, ImuRecording], tmp_path: Path) -> None:
    a, _ = recs
    rec = load_imu(_shimmer(tmp_path / "old.csv", {"8C4F": a}, sep_line=False,
                            cal_row=True))
    _same_motion(a, rec, mag_scale=0.01)


def test_shimmer_formatted_date_column_is_ignored(recs: tuple[ImuRecording, ImuRecording],
                                                 tmp_path: Path) -> None:
    """Consensys can add the date as text; the numeric Unix time is read instead."""
    a, _ = recs
    rec = load_imu(_shimmer(tmp_path / "fmt.csv", {"8C4F": a}, formatted=True))
    _same_motion(a, rec, mag_scale=0.01)
    assert any("TimestampSync_FormattedUnix_CAL" in w for w in rec.warnings
               if w.startswith("ignored"))


def test_shimmer_low_noise_accelerometer_is_preferred(recs: tuple[ImuRecording, ImuRecording],
                                                      tmp_path: Path) -> None:
    a, _ = recs
    rec = load_imu(_shimmer(tmp_path / "wr.csv", {"8C4F": a}, wide_range=True))
    _same_motion(a, rec)  # not the 5 % larger wide-range values
    assert any("Accel_WR_X_CAL" in w for w in rec.warnings if w.startswith("ignored"))


def test_shimmer_wide_range_accelerometer_when_the_low_noise_one_saturates(
        recs: tuple[ImuRecording, ImuRecording], tmp_path: Path) -> None:
    a, _ = recs
    rec = load_imu(_shimmer(tmp_path / "clip.csv", {"8C4F": a}, wide_range=True,
                            ln_clip=0.95 * G))
    _same_motion(a, rec)
    assert any("low-noise accelerometer (Shimmer_8C4F_Accel_LN_X_CAL …) saturates" in w
               and "Accel_WR_X_CAL" in w for w in rec.warnings), rec.warnings
    # without a wide-range one the clipped values are read, and the saturation said
    rec = load_imu(_shimmer(tmp_path / "clip1.csv", {"8C4F": a}, ln_clip=0.95 * G))
    assert any("saturates" in w for w in rec.warnings)
    assert np.max(np.abs(rec.acc)) == pytest.approx(0.95 * G)


def test_two_shimmers_in_one_file_need_a_choice(recs: tuple[ImuRecording, ImuRecording],
                                                tmp_path: Path) -> None:
    a, b = recs
    p = _shimmer(tmp_path / "two.csv", {"8C4F": a, "9A1B": b})
    with pytest.raises(MultipleSensorsError, match="two.csv: the file holds 2 sensors "
                       r"\(Shimmer_8C4F, Shimmer_9A1B\)") as e:
        load_imu(p)
    assert e.value.sensors == ["Shimmer_8C4F", "Shimmer_9A1B"]
    assert isinstance(e.value, InputError)  # what the upload turns into a 400
    _same_motion(a, load_imu(p, sensor="Shimmer_8C4F"), mag_scale=0.01)
    second = load_imu(p, sensor="9a1b")  # the device id alone, any case
    _same_motion(b, second, mag_scale=0.01)
    assert second.meta["sensor"] == "Shimmer_9A1B"
    with pytest.raises(MultipleSensorsError, match=r"no sensor 'FFFF' in the file; it holds "
                       "Shimmer_8C4F, Shimmer_9A1B"):
        load_imu(p, sensor="FFFF")


# ------------------------------------------------------------------ Movella DOT


def _dot(p: Path, sensors: dict[str, ImuRecording], *, clock0: float = 2.0**32 - 1.5e6,
         tick_s: float = 1e-6) -> Path:
    """A Movella DOT export; several sensors' columns are prefixed with their tags."""
    first = next(iter(sensors.values()))
    header = ["PacketCounter", "SampleTimeFine"]
    cols = [np.arange(len(first), dtype=float) % 65536,
            np.mod(clock0 + np.round(first.time / tick_s), 2.0**32)]  # wraps after 1.5 s
    for tag, r in sensors.items():
        pre = f"{tag}_" if len(sensors) > 1 else ""
        assert r.mag is not None
        header += [f"{pre}Quat_{c}" for c in "WXYZ"]
        cols += [np.ones(len(r)), np.zeros(len(r)), np.zeros(len(r)), np.zeros(len(r))]
        for name, arr in (("Acc", r.acc), ("Gyr", np.rad2deg(r.gyr)), ("Mag", r.mag / 50.0)):
            header += [f"{pre}{name}_{c}" for c in "XYZ"]
            cols += [arr[:, k] for k in range(3)]
    header.append("Status")
    cols.append(np.zeros(len(first)))
    lines = ["DeviceTag: " + ", ".join(sensors), "Firmware Version: 2.6.0",
             "Output rate: 100Hz", ",".join(header)]
    lines += [",".join(_fmt(v) for v in row) for row in np.column_stack(cols)]
    p.write_text("\n".join(lines) + "\n")
    return p


def test_movella_dot_export(recs: tuple[ImuRecording, ImuRecording], tmp_path: Path) -> None:
    a, _ = recs
    rec = load_imu(_dot(tmp_path / "dot.csv", {"LeftShank": a}))
    _same_motion(a, rec, mag_scale=1 / 50.0, t_atol=1e-6)  # across the clock's wrap
    assert rec.meta["time_unit"] == "us"
    assert rec.frequency == pytest.approx(a.frequency)
    assert any("assumed magnetometer in norm" in w for w in rec.warnings)


def test_xsens_mti_sample_time_in_100_us_ticks(recs: tuple[ImuRecording, ImuRecording],
                                               tmp_path: Path) -> None:
    a, _ = recs
    rec = load_imu(_dot(tmp_path / "mti.csv", {"Pelvis": a}, clock0=1e6, tick_s=1e-4))
    _same_motion(a, rec, mag_scale=1 / 50.0, t_atol=1e-6)
    assert rec.frequency == pytest.approx(100.0)


def test_xsens_export_of_several_sensors(recs: tuple[ImuRecording, ImuRecording],
                                         tmp_path: Path) -> None:
    a, b = recs
    p = _dot(tmp_path / "dots.csv", {"LeftShank": a, "RightShank": b})
    with pytest.raises(MultipleSensorsError, match=r"2 sensors \(LeftShank, RightShank\)"):
        load_imu(p)
    rec = load_imu(p, sensor="RightShank")  # the shared SampleTimeFine is its time
    _same_motion(b, rec, mag_scale=1 / 50.0, t_atol=1e-6)
    assert rec.meta["sensor"] == "RightShank"
    assert any("LeftShank_Gyr_X" in w for w in rec.warnings if w.startswith("ignored"))


def test_sensor_choice_for_a_one_sensor_file(recs: tuple[ImuRecording, ImuRecording],
                                             tmp_path: Path) -> None:
    """Naming the only sensor is fine; naming another is an error listing it."""
    a, _ = recs
    p = _shimmer(tmp_path / "one.csv", {"8C4F": a})
    _same_motion(a, load_imu(p, sensor="8C4F"), mag_scale=0.01)
    with pytest.raises(MultipleSensorsError, match="it holds Shimmer_8C4F"):
        load_imu(p, sensor="9A1B")


# ------------------------------------------------------------- time vs temperature


def _plain(p: Path, r: ImuRecording, extra: dict[str, np.ndarray], time_name: str | None,
           first: bool = True) -> Path:
    """time (optional), gyr (deg/s), acc (g) and extra columns; extras first or last."""
    cols = {f"gyr_{c}": np.rad2deg(r.gyr[:, k]) for k, c in enumerate("xyz")}
    cols |= {f"acc_{c}": r.acc[:, k] / G for k, c in enumerate("xyz")}
    if time_name:
        cols = {time_name: r.time} | cols
    cols = (extra | cols) if first else (cols | extra)
    lines = [",".join(cols)] + [",".join(_fmt(v) for v in row)
                                for row in np.column_stack(list(cols.values()))]
    p.write_text("\n".join(lines) + "\n")
    return p


def _temperature(r: ImuRecording, rising: bool = False) -> np.ndarray:
    if rising:  # a sensor warming up: increasing, but not a time
        return 24.0 + 0.01 * np.arange(len(r))
    rng = np.random.default_rng(3)
    return np.round(25.0 + 0.3 * rng.standard_normal(len(r)), 1)


def test_a_temperature_named_t_is_not_the_time(recs: tuple[ImuRecording, ImuRecording],
                                               tmp_path: Path) -> None:
    a, _ = recs
    rec = load_imu(_plain(tmp_path / "tfirst.csv", a, {"T": _temperature(a)}, "time"))
    assert np.allclose(rec.time, a.time)
    with pytest.raises(InputError) as msg:
        load_imu(_plain(tmp_path / "tonly.csv", a, {"T": _temperature(a)}, None))
    assert "no time column" in str(msg.value) and "'T' does not increase" in str(msg.value)
    rec = load_imu(tmp_path / "tonly.csv", frequency=a.frequency)
    assert rec.meta["time_from"] == "frequency"
    assert any("'T' does not increase" in w for w in rec.warnings)


def test_a_bare_t_that_increases_is_the_time(recs: tuple[ImuRecording, ImuRecording],
                                             tmp_path: Path) -> None:
    a, _ = recs
    rec = load_imu(_plain(tmp_path / "t.csv", a, {}, "t"))
    assert np.allclose(rec.time, a.time)
    # with a time unit it is the time even when it goes back: that is then the error
    lines = _plain(tmp_path / "t.csv", a, {}, "T (s)").read_text().splitlines()
    lines[5], lines[6] = lines[6], lines[5]
    (tmp_path / "back.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match="not strictly increasing"):
        load_imu(tmp_path / "back.csv")


@pytest.mark.parametrize("name", ["Temperature", "Temp", "T_degC", "T (°C)", "temp_c",
                                  "T [K]"])
def test_temperature_columns_are_never_the_time(recs: tuple[ImuRecording, ImuRecording],
                                                tmp_path: Path, name: str) -> None:
    """Even a warming sensor's rising temperature, in front of the real time column."""
    a, _ = recs
    p = _plain(tmp_path / "temp.csv", a, {name: _temperature(a, rising=True)}, "Time")
    rec = load_imu(p)
    assert np.allclose(rec.time, a.time)
    assert any(name in w for w in rec.warnings if w.startswith("ignored"))
    # and without a time column it is not taken either
    p = _plain(tmp_path / "temp_only.csv", a, {name: _temperature(a, rising=True)}, None)
    with pytest.raises(InputError, match="no time column"):
        load_imu(p)


def test_a_text_time_column_is_passed_over(recs: tuple[ImuRecording, ImuRecording],
                                           tmp_path: Path) -> None:
    a, _ = recs
    dates = np.array([f"2023-11-14 22:13:{20 + t:06.3f}" for t in a.time])
    base = _plain(tmp_path / "x.csv", a, {}, "time_s").read_text().splitlines()
    text = ["Timestamp," + base[0]] + [f"{d},{ln}" for d, ln in zip(dates, base[1:],
                                                                    strict=True)]
    p = tmp_path / "dates.csv"
    p.write_text("\n".join(text) + "\n")
    rec = load_imu(p)
    assert np.allclose(rec.time, a.time)
    # the numeric clock is preferred to ISO date-times (finer)
    assert any(w == "ignored column: Timestamp" for w in rec.warnings)
    only = [ln.split(",", 1)[0] + "," + ln.split(",", 2)[2] for ln in text]  # no time_s
    p.write_text("\n".join(only) + "\n")
    # without the numeric clock the ISO date-times are the time (POSIX seconds)
    rec = load_imu(p)
    assert np.allclose(rec.time - rec.time[0], a.time, atol=1e-6)
    garbled = [only[0]] + [f"14.11.2023 22:13{ln[16:]}" for ln in only[1:]]
    p.write_text("\n".join(garbled) + "\n")
    with pytest.raises(InputError, match=r"no time column \(column 'Timestamp' holds text"):
        load_imu(p)


def test_units_row_with_an_empty_cell(recs: tuple[ImuRecording, ImuRecording],
                                      tmp_path: Path) -> None:
    """A units row whose first cell is empty (a counter has no unit) left a stray value in
    the data and the reader crashed (ValueError: cannot reshape) instead of reading it."""
    a, _ = recs
    lines = _plain(tmp_path / "x.csv", a, {"sample": np.arange(len(a), dtype=float)},
                   "time").read_text().splitlines()
    lines.insert(1, ",s,deg/s,deg/s,deg/s,g,g,g")
    p = tmp_path / "units.csv"
    p.write_text("\n".join(lines) + "\n")
    rec = load_imu(p)
    assert np.allclose(rec.time, a.time) and np.allclose(rec.gyr, a.gyr)
    assert rec.meta["units_from"] == {"gyr": "header", "acc": "header"}
