"""IMU files as other labs write them: an adversarial import sweep.

Two base recordings — Madgwick's real ``imu/madgwick/ExampleData.mat`` (shared data,
skipped without it) and a synthetic slow walk-like motion (:func:`engine.sim.imu.simulate_imu`)
— are rewritten as CSV in other units, time bases, layouts and column names, and with the
data problems real files have. Each variant goes through :func:`engine.imu.io.load_imu`
(what the IMU upload calls); a variant that still holds the same recording must give the
same SI values (times shifted only by the known offset), and say what it assumed; a broken
one must give one typed :class:`InputError` line saying what to fix, never another
exception, never silently wrong values.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from engine.errors import InputError
from engine.geometry import quat_conj, quat_from_rotvec, quat_rotate, quat_to_matrix
from engine.imu import io as imu_io
from engine.imu.io import G, ImuRecording, load_imu
from engine.sim.imu import simulate_imu

# ----------------------------------------------------------------- base recordings


def _synthetic(peak_rad_s: float = 1.5, seconds: float = 8.0, fs: float = 100.0
               ) -> ImuRecording:
    """A slow, walk-like sway (rates up to ``peak_rad_s``) of a sensor on a moving bone."""
    t = np.arange(0.0, seconds, 1.0 / fs)
    rv = np.stack([0.3 * np.sin(2 * np.pi * 0.9 * t), 0.2 * np.sin(2 * np.pi * 0.45 * t),
                   0.1 * np.sin(2 * np.pi * 0.3 * t + 1.0)], 1)
    rv *= peak_rad_s / 1.8  # ≈ peak rate of the unscaled sway
    T = np.tile(np.eye(4), (len(t), 1, 1))
    T[:, :3, :3] = quat_to_matrix(quat_from_rotvec(rv))
    T[:, 0, 3] = 1.2 * t  # walking forwards
    T[:, 2, 3] = 1.0 + 0.02 * np.sin(2 * np.pi * 1.8 * t)
    return simulate_imu(t, T, rng=1, name="sim")


@pytest.fixture(scope="module", params=["real", "synthetic"])
def base(request: pytest.FixtureRequest) -> ImuRecording:
    if request.param == "synthetic":
        return _synthetic()
    shared: Path = request.getfixturevalue("shared_data")
    rec = load_imu(shared / "imu" / "madgwick" / "ExampleData.mat")
    n = 3000  # 12 s at 256 Hz: every variant keeps the sweep fast
    assert rec.mag is not None
    return replace(rec, time=rec.time[:n], gyr=rec.gyr[:n], acc=rec.acc[:n], mag=rec.mag[:n])


# ----------------------------------------------------------------- writing variants

#: SI -> file unit factors (file value = SI value / factor)
_GYR = {"rad/s": 1.0, "deg/s": np.pi / 180}
_ACC = {"m/s2": 1.0, "g": G, "mg": G / 1000}
_MAG = {"uT": 1.0, "G": 100.0, "mT": 1000.0, "nT": 1e-3}
_TIME = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}


@dataclass
class Layout:
    """How one lab writes its CSV."""

    names: dict[str, str] = field(default_factory=lambda: {
        "time": "time", "gyr": "gyr_{a}", "acc": "acc_{a}", "mag": "mag_{a}"})
    gyr: str = "deg/s"  # sure to be detected on both bases (rates above 40)
    acc: str = "m/s2"
    mag: str | None = "uT"
    time: str | None = "s"  # None: no time column
    t0: float = 0.0  # added to the time (s)
    counter: str | None = None  # a sample-counter column name
    sep: str = ","
    decimal_comma: bool = False
    extra: dict[str, float] = field(default_factory=dict)
    units_row: bool = False
    header_units: bool = False
    float32_time: bool = False
    prefix: str = ""  # e.g. a BOM or comment lines
    newline: str = "\n"
    trailer: str = ""
    encoding: str = "utf-8"


def _write(p: Path, rec: ImuRecording, lay: Layout,
           edit: Callable[[np.ndarray, list[str]], np.ndarray] | None = None) -> Path:
    n = lay.names
    cols: list[np.ndarray] = []
    header: list[str] = []
    units: list[str] = []
    if lay.counter:
        header.append(lay.counter)
        units.append("")
        cols.append(np.arange(len(rec), dtype=float))
    if lay.time:
        t = (rec.time + lay.t0) / _TIME[lay.time]
        if lay.float32_time:
            t = t.astype(np.float32).astype(float)
        header.append(n["time"] + (f" ({lay.time})" if lay.header_units else ""))
        units.append(lay.time)
        cols.append(t)
    groups: list[tuple[str, np.ndarray, str, float]] = [
        ("gyr", rec.gyr, lay.gyr, _GYR[lay.gyr]), ("acc", rec.acc, lay.acc, _ACC[lay.acc])]
    if lay.mag and rec.mag is not None:
        groups.append(("mag", rec.mag, lay.mag, _MAG[lay.mag]))
    for g, arr, unit, f in groups:
        for k, a in enumerate("xyz"):
            name = n[g].format(a=a, A=a.upper())
            header.append(name + (f" ({unit})" if lay.header_units else ""))
            units.append(unit)
            cols.append(arr[:, k] / f)
    for name, v in lay.extra.items():
        header.append(name)
        units.append("")
        cols.append(np.full(len(rec), v))
    data = np.column_stack(cols)
    if edit is not None:
        data = edit(data, header)

    def cell(v: float) -> str:
        s = "" if np.isnan(v) else f"{v:.15g}"
        return s.replace(".", ",") if lay.decimal_comma else s

    lines = [lay.sep.join(header)]
    if lay.units_row:
        lines.append(lay.sep.join(units))
    lines += [lay.sep.join(cell(v) for v in row) for row in data]
    text = lay.prefix + lay.newline.join(lines) + lay.newline + lay.trailer
    p.write_bytes(text.encode(lay.encoding))
    return p


def _same(ref: ImuRecording, got: ImuRecording, t0: float = 0.0, rtol: float = 1e-7,
          t_atol: float = 1e-7, mag: bool = True) -> None:
    assert len(got) == len(ref)
    assert np.allclose(got.time, ref.time + t0, rtol=1e-12, atol=t_atol)
    assert got.frequency == pytest.approx(ref.frequency, rel=1e-4)
    for a, b in ((got.gyr, ref.gyr), (got.acc, ref.acc)):
        assert np.allclose(a, b, rtol=rtol, atol=1e-9)
    if mag:
        assert got.mag is not None and ref.mag is not None
        assert np.allclose(got.mag, ref.mag, rtol=rtol, atol=1e-9)
    else:
        assert got.mag is None


def _error(p: Path, match: str, **kw: Any) -> str:
    with pytest.raises(InputError, match=match) as e:
        load_imu(p, **kw)
    msg = str(e.value)
    assert "\n" not in msg and p.stem in msg, msg  # one line naming the file
    return msg


# ----------------------------------------------------------------- units

XIO = {"time": "Time", "gyr": "Gyroscope {A}", "acc": "Accelerometer {A}",
       "mag": "Magnetometer {A}"}


@pytest.mark.parametrize(("gyr", "acc", "mag"), [
    ("rad/s", "m/s2", "uT"), ("deg/s", "g", "G"), ("deg/s", "mg", "mT"),
    ("rad/s", "g", "nT"), ("deg/s", "m/s2", None)])
def test_units_from_the_header(base: ImuRecording, tmp_path: Path, gyr: str, acc: str,
                               mag: str | None) -> None:
    lay = Layout(names=XIO, gyr=gyr, acc=acc, mag=mag, header_units=True)
    rec = load_imu(_write(tmp_path / "x.csv", base, lay))
    _same(base, rec, mag=mag is not None)
    assert rec.meta["units_from"]["gyr"] == "header"
    assert not any("assumed" in w for w in rec.warnings)


def test_units_detected_say_what_was_assumed(base: ImuRecording, tmp_path: Path) -> None:
    """deg/s (fast enough to be sure), g and gauss without any unit: detected, and said."""
    rec = load_imu(_write(tmp_path / "d.csv", base, Layout(gyr="deg/s", acc="g", mag="G",
                                                           time=None, counter="sample")),
                   frequency=base.frequency)
    _same(base, rec, t0=-base.time[0])
    said = " ".join(rec.warnings)
    assert "assumed gyroscope in deg/s" in said and "accelerometer in g" in said
    assert "magnetometer in G" in said
    assert rec.meta["units_from"] == {"gyr": "detected", "acc": "detected", "mag": "detected"}


def test_ambiguous_gyroscope_unit_is_refused_until_declared(tmp_path: Path) -> None:
    """A slow walk in deg/s (peaks 30 deg/s) reads like a brisk one in rad/s: never guess."""
    slow = _synthetic(peak_rad_s=np.deg2rad(30.0))
    p = _write(tmp_path / "slow.csv", slow, Layout(gyr="deg/s"))
    msg = _error(p, "declare gyr_unit")
    assert "rad/s or deg/s" in msg
    _same(slow, load_imu(p, gyr_unit="deg/s"))
    # the same numbers truly in rad/s: the override also exists the other way
    p = _write(tmp_path / "fast.csv", slow, Layout(gyr="rad/s"))
    _error(p, "declare gyr_unit")
    _same(slow, load_imu(p, gyr_unit="rad/s"))


def test_declared_unit_overrides_header_and_contradictions_are_named(
        base: ImuRecording, tmp_path: Path) -> None:
    p = _write(tmp_path / "o.csv", base, Layout(names=XIO, gyr="deg/s", acc="g", mag="G",
                                                header_units=True))
    _error(p, "probably in deg/s", gyr_unit="rad/s")
    rec = load_imu(p, mag_unit="uT")  # a wrong override wins, but is said and checked
    assert any("overrides the header" in w for w in rec.warnings)
    assert any("magnetic field" in w for w in rec.warnings)
    rec = load_imu(p, mag_unit="none")
    assert rec.mag is None


def test_unknown_header_unit(base: ImuRecording, tmp_path: Path) -> None:
    p = _write(tmp_path / "lsb.csv", base, Layout(names=XIO, header_units=True))
    p.write_text(p.read_text().replace("(deg/s)", "(LSB)"))
    _error(p, r"unknown gyroscope unit 'LSB'.*declare gyr_unit")


@pytest.mark.parametrize("unit", ["s", "ms", "us", "ns"])
@pytest.mark.parametrize("t0", [0.0, 123.456, 1.7e9])
def test_time_units_and_offsets(base: ImuRecording, tmp_path: Path, unit: str,
                                t0: float) -> None:
    lay = Layout(time=unit, t0=t0)
    p = _write(tmp_path / "t.csv", base, lay)
    rec = load_imu(p)
    # written with 15 significant digits: 1.7e9 s keeps 1 µs
    _same(base, rec, t0=t0, t_atol=1e-7 if t0 < 1e6 else 1e-5)
    assert rec.meta["time_unit"] == unit
    assert any(f"assumed time in {unit}" in w for w in rec.warnings)
    # declared explicitly: no assumption; a wrong declaration is named
    rec = load_imu(p, time_unit=unit)
    assert not any("assumed time" in w for w in rec.warnings)
    if unit != "s":
        _error(p, f"probably in {unit}", time_unit="s")


def test_time_unit_in_header_and_units_row(base: ImuRecording, tmp_path: Path) -> None:
    for lay in (Layout(names={**XIO, "time": "Timestamp"}, time="ms", header_units=True),
                Layout(time="ms", units_row=True),
                Layout(names={"time": "time_ms", "gyr": "gyr_{a}", "acc": "acc_{a}",
                              "mag": "mag_{a}"}, time="ms")):
        rec = load_imu(_write(tmp_path / "h.csv", base, lay))
        _same(base, rec)
        assert rec.meta["time_from"] == "header", lay


def test_epoch_milliseconds_and_float32(base: ImuRecording, tmp_path: Path) -> None:
    rec = load_imu(_write(tmp_path / "e.csv", base, Layout(time="ms", t0=1.7e9)))
    assert np.allclose(rec.time, base.time + 1.7e9, atol=1e-5)
    # float32 epoch seconds: 128 s resolution — refused with the reason, not "unsorted"
    p = _write(tmp_path / "f32.csv", base, Layout(t0=1.7e9, float32_time=True))
    _error(p, "32-bit floats")
    # float32 of a short relative time: harmless rounding
    rec = load_imu(_write(tmp_path / "f32s.csv", base, Layout(float32_time=True)))
    assert np.allclose(rec.time, base.time, atol=1e-5)


def test_counter_with_dropped_samples_keeps_time(base: ImuRecording, tmp_path: Path) -> None:
    keep = np.ones(len(base), bool)
    keep[100:110] = False

    def drop(d: np.ndarray, _h: list[str]) -> np.ndarray:
        return d[keep]

    p = _write(tmp_path / "c.csv", base, Layout(names=XIO, time=None, counter="Packet number",
                                                header_units=True), edit=drop)
    rec = load_imu(p, frequency=base.frequency)
    assert np.allclose(rec.time, base.time[keep] - base.time[0], atol=1e-9)
    assert any("gap" in w for w in rec.warnings)
    _error(p, "frequency")


# ----------------------------------------------------------------- layouts


HEADERS = {
    "xsens": {"time": "SampleTimeFine", "gyr": "Gyr_{A}", "acc": "Acc_{A}", "mag": "Mag_{A}"},
    "spaced": {"time": "Time", "gyr": "gyro {a}", "acc": "accel {a}", "mag": "mag {a}"},
    "camel": {"time": "Timestamp", "gyr": "Gyroscope{A}", "acc": "Accelerometer{A}",
              "mag": "Magnetometer{A}"},
    "short": {"time": "t", "gyr": "w{a}", "acc": "a{a}", "mag": "m{a}"},
    "dotted": {"time": "time", "gyr": "gyr.{a}", "acc": "acc.{a}", "mag": "mag.{a}"},
    "unit_in_name": {"time": "time_s", "gyr": "gyro_{a}_dps", "acc": "acc_{a}_g",
                     "mag": "mag_{a}_uT"},
}


@pytest.mark.parametrize("style", sorted(HEADERS))
def test_header_names(base: ImuRecording, tmp_path: Path, style: str) -> None:
    lay = Layout(names=HEADERS[style], gyr="deg/s", acc="g",
                 header_units=style not in ("xsens", "unit_in_name"),
                 time=None if style == "xsens" else "s",
                 counter="PacketCounter" if style == "xsens" else None)
    rec = load_imu(_write(tmp_path / "n.csv", base, lay), frequency=base.frequency)
    _same(base, rec, t0=-base.time[0] if style == "xsens" else 0.0)
    if style != "xsens":
        assert not any("assumed" in w for w in rec.warnings), rec.warnings


LAYOUTS: dict[str, Layout] = {
    "semicolon_decimal_comma": Layout(sep=";", decimal_comma=True),
    "tab_decimal_comma": Layout(sep="\t", decimal_comma=True),
    "tab": Layout(sep="\t"),
    "bom_crlf": Layout(prefix="\ufeff", newline="\r\n"),
    "comments": Layout(prefix="# exported by LabX v2\n// sensor 4711\n\n%range 2000dps\n"),
    "trailing_blank_lines": Layout(trailer="\n\n  \n"),
    "units_row": Layout(units_row=True, gyr="deg/s", acc="g", mag="G"),
    "extra_columns": Layout(extra={"quat_w": 1.0, "quat_x": 0.0, "Temperature (C)": 25.0,
                                   "battery": 3.9}),
    "latin1_degree_header": Layout(names={"time": "Zeit", "gyr": "Gyr {A} [°/s]",
                                          "acc": "Acc {A} [g]", "mag": "Mag {A} [µT]"},
                                   gyr="deg/s", acc="g", encoding="latin-1", time=None,
                                   counter="Sample"),
}


@pytest.mark.parametrize("name", sorted(LAYOUTS))
def test_layouts(base: ImuRecording, tmp_path: Path, name: str) -> None:
    lay = LAYOUTS[name]
    rec = load_imu(_write(tmp_path / f"{name}.csv", base, lay), frequency=base.frequency)
    _same(base, rec, t0=-base.time[0] if lay.time is None else 0.0)
    if lay.extra:
        assert any("Temperature" in w and "battery" in w for w in rec.warnings)


def test_comment_and_blank_lines_between_rows(base: ImuRecording, tmp_path: Path) -> None:
    p = _write(tmp_path / "mid.csv", base, Layout())
    lines = p.read_text().splitlines()
    lines.insert(50, "# pause marker")
    lines.insert(20, "")
    p.write_text("\n".join(lines) + "\n")
    _same(base, load_imu(p))


# ----------------------------------------------------------------- data problems


def _edit_rows(fn: Callable[[np.ndarray], None]) -> Callable[[np.ndarray, list[str]],
                                                             np.ndarray]:
    def edit(d: np.ndarray, _h: list[str]) -> np.ndarray:
        d = d.copy()
        fn(d)
        return d
    return edit


def test_nan_and_empty_cells_are_kept_and_said(base: ImuRecording, tmp_path: Path) -> None:
    def holes(d: np.ndarray) -> None:
        d[30, 1:4] = np.nan  # empty cells
        d[40, 4] = np.nan

    p = _write(tmp_path / "nan.csv", base, Layout(), edit=_edit_rows(holes))
    p.write_text(p.read_text().replace(",,,", ",NaN,,", 1))
    rec = load_imu(p)
    assert np.isnan(rec.gyr[30]).all() and np.isnan(rec.acc[40, 0])
    assert any(w.startswith("1 gyroscope sample is NaN/inf") and w.endswith("it is skipped")
               for w in rec.warnings)
    ok = np.ones(len(base), bool)
    ok[[30, 40]] = False
    assert np.allclose(rec.gyr[ok], base.gyr[ok])


def test_repeated_rows_dropped_conflicting_duplicates_refused(base: ImuRecording,
                                                              tmp_path: Path) -> None:
    def dup(d: np.ndarray, _h: list[str]) -> np.ndarray:
        return np.insert(d, [50, 50, 200], d[[50, 50, 200]], axis=0)

    rec = load_imu(_write(tmp_path / "dup.csv", base, Layout(), edit=dup))
    _same(base, rec)
    assert any("dropped 3 repeated rows (same time" in w for w in rec.warnings)

    def conflict(d: np.ndarray) -> None:
        d[51, 0] = d[50, 0]

    _error(_write(tmp_path / "dup2.csv", base, Layout(), edit=_edit_rows(conflict)),
           "not strictly increasing at sample 51")

    def swap(d: np.ndarray) -> None:
        d[[60, 61]] = d[[61, 60]]

    _error(_write(tmp_path / "swap.csv", base, Layout(), edit=_edit_rows(swap)),
           "sort the file")


def test_gaps_saturation_dead_channel(base: ImuRecording, tmp_path: Path) -> None:
    def gap(d: np.ndarray, _h: list[str]) -> np.ndarray:
        return np.delete(d, np.s_[100:150], axis=0)

    rec = load_imu(_write(tmp_path / "gap.csv", base, Layout(), edit=gap))
    assert any(w.startswith("1 gap in the time stamps") for w in rec.warnings)
    assert not any("1 gap(s)" in w for w in rec.warnings)
    assert rec.frequency == pytest.approx(base.frequency, rel=1e-4)

    lim = 0.5 * float(np.max(np.abs(base.gyr[:, 2])))

    def clip(d: np.ndarray) -> None:
        d[:, 3] = np.clip(d[:, 3], -lim, lim)  # gyr_z clipped at a (too small) range
        d[:, 5] = 0.25  # acc_y stuck

    rec = load_imu(_write(tmp_path / "clip.csv", base, Layout(), edit=_edit_rows(clip)),
                   acc_unit="m/s2")  # a stuck axis can hide gravity from the detection
    said = " ".join(rec.warnings)
    assert "gyroscope Z saturates" in said and "accelerometer Y is constant" in said
    rec = load_imu(_write(tmp_path / "ok.csv", base, Layout()))
    assert not any("saturates" in w or "constant" in w for w in rec.warnings)


@pytest.mark.parametrize("holes", [[(100, 101)], [(100, 120), (400, 410)]])
def test_filled_gaps_replace_the_gap_warning(tmp_path: Path,
                                             holes: list[tuple[int, int]]) -> None:
    """:func:`fill_gaps` drops the "gaps in the time stamps" warning it repairs, in the
    singular and the plural, and keeps the others (the assumed units)."""
    rec0 = _synthetic()
    keep = np.ones(len(rec0), bool)
    for a, b in holes:
        keep[a:b] = False

    def gap(d: np.ndarray, _h: list[str]) -> np.ndarray:
        return d[keep]

    rec = load_imu(_write(tmp_path / "gap.csv", rec0, Layout(), edit=gap))
    n = len(holes)
    said = [w for w in rec.warnings if w.startswith(f"{n} gap{'' if n == 1 else 's'} in the "
                                                    "time stamps (largest ")]
    assert len(said) == 1, rec.warnings
    others = [w for w in rec.warnings if w not in said]
    filled = imu_io.fill_gaps(rec)
    assert len(filled) == len(rec0)
    assert filled.warnings == [*others, filled.warnings[-1]]
    n_drop = int((~keep).sum())
    assert filled.warnings[-1].startswith(
        f"{n_drop} dropped sample{'' if n_drop == 1 else 's'} filled by interpolation (")


@pytest.mark.parametrize("extra", [{}, {"temperature": 25.0}, {"temperature": 25.0,
                                                                "battery": 3.7}])
def test_quaternion_columns_are_not_said_ignored(tmp_path: Path,
                                                 extra: dict[str, float]) -> None:
    """Reference quaternion columns are read, so the "ignored column" warning written
    before they were found is replaced by one naming only what is left (or none)."""
    rec0 = _synthetic()
    assert rec0.quat_ref is not None
    q = rec0.quat_ref

    def quat(d: np.ndarray, h: list[str]) -> np.ndarray:
        h.extend(["quat_w", "quat_x", "quat_y", "quat_z"])
        return np.column_stack([d, q])

    rec = load_imu(_write(tmp_path / "q.csv", rec0, Layout(extra=extra), edit=quat))
    assert rec.quat_ref is not None
    said = [w for w in rec.warnings if w.startswith("ignored")]
    if not extra:
        assert said == []
    else:
        noun = "column" if len(extra) == 1 else "columns"
        assert said == [f"ignored {noun}: {', '.join(extra)}"]


def test_broken_files(base: ImuRecording, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
                      ) -> None:
    def first(d: np.ndarray, _h: list[str]) -> np.ndarray:
        return d[:1]

    _error(_write(tmp_path / "one.csv", base, Layout(), edit=first), "at least two samples")
    p = tmp_path / "empty.csv"
    p.write_bytes(b"")
    _error(p, "empty")
    p.write_bytes(b"\n\n\r\n")
    _error(p, "empty")
    p.write_text("time,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z\n")
    _error(p, "data rows")
    p = tmp_path / "garbage.csv"
    p.write_bytes(np.random.default_rng(0).bytes(5000))
    _error(p, "binary")
    p.write_bytes(b"PK\x03\x04" + bytes(range(256)) * 4)  # an .xlsx renamed .csv
    _error(p, "binary")
    p = _write(tmp_path / "huge.csv", base, Layout())
    monkeypatch.setattr(imu_io, "MAX_CSV_BYTES", p.stat().st_size - 1)
    _error(p, "split the recording")
    monkeypatch.undo()
    p.write_text(p.read_text().replace("\n", "\nhello,1,2\n", 1))
    _error(p, "data row 2 has 3 fields")
    lines = p.read_text().splitlines()
    lines[1] = "1;2;3;4;5;6;7;8;9;10"
    p.write_text("\n".join(lines) + "\n")
    _error(p, "data row 2 has 1 fields")
    lines[1] = ",".join(["0.1", "abc", *["1"] * 8])
    p.write_text("\n".join(lines) + "\n")
    _error(p, "non-numeric value 'abc'")
    p.write_text("time,foo,bar\n0,1,2\n0.01,1,2\n")
    _error(p, "missing column.*gyroscope or accelerometer")


def test_gravity_free_acceleration_is_not_taken_for_g(tmp_path: Path) -> None:
    """A 'linear acceleration' export (gravity removed, ~1 m/s²) must not pass for g."""
    base = _synthetic()
    assert base.quat_ref is not None
    g_sensor = quat_rotate(quat_conj(base.quat_ref), np.array([0.0, 0.0, G]))
    lin = replace(base, acc=base.acc - g_sensor)
    p = _write(tmp_path / "lin.csv", lin, Layout())
    _error(p, "declare acc_unit.*gravity must not be removed")
    _error(p, "linear acceleration", acc_unit="m/s2")


def test_decimal_comma_with_comma_separator_is_named(base: ImuRecording,
                                                     tmp_path: Path) -> None:
    _error(_write(tmp_path / "dc.csv", base, Layout(decimal_comma=True)),
           "decimal commas need ';'")


def test_empty_time_cell_is_refused(base: ImuRecording, tmp_path: Path) -> None:
    def hole(d: np.ndarray) -> None:
        d[20, 0] = np.nan

    _error(_write(tmp_path / "tnan.csv", base, Layout(), edit=_edit_rows(hole)),
           "time column contains NaN")


def test_wrapping_packet_counter(base: ImuRecording, tmp_path: Path) -> None:
    """A uint8 packet counter (0..255, 0, 1 ...) with dropped packets keeps the time."""
    keep = np.ones(len(base), bool)
    keep[300:305] = False

    def wrap(d: np.ndarray, _h: list[str]) -> np.ndarray:
        d = d.copy()
        d[:, 0] = (d[:, 0] + 200) % 256
        return d[keep]

    p = _write(tmp_path / "wrap.csv", base, Layout(time=None, counter="Packet number"),
               edit=wrap)
    rec = load_imu(p, frequency=base.frequency)
    assert np.allclose(rec.time, base.time[keep] - base.time[0], atol=1e-9)
