"""Hostile IMU uploads (security review 19): XML bombs and inflated MVNX exports, zip
tricks in phone exports. Each must end in an :class:`InputError` that says what is wrong,
quickly and with bounded memory, never a crash, a hang or a memory blow-up."""

from __future__ import annotations

import tracemalloc
import zipfile
from pathlib import Path
from typing import Any

import pytest

from engine.errors import InputError
from engine.imu import _mvnx
from engine.imu.io import load_imu, load_mvnx_all

_LOL = (b'<!DOCTYPE lolz [<!ENTITY lol "lol">'
        + b"".join(b'<!ENTITY lol%d "%s">' % (i, (b"&lol%d;" % (i - 1) if i > 1 else b"&lol;")
                                              * 10) for i in range(1, 10)) + b"]>")
_FRAME = (b'<frame type="normal" index="%d"><sensorOrientation>1 0 0 0</sensorOrientation>'
          b"<sensorFreeAcceleration>0 0 0</sensorFreeAcceleration></frame>")


def _mvnx_of(frames: bytes, head: bytes = b"", sensors: bytes = b'<sensor label="P"/>') -> bytes:
    return (b'<?xml version="1.0" encoding="UTF-8"?>' + head
            + b'<mvnx><subject frameRate="60"><sensors>' + sensors + b"</sensors><frames>"
            + frames + b"</frames></subject></mvnx>")


def _small_frames(n: int) -> bytes:
    return b"".join(_FRAME % i for i in range(n))


def _refused(tmp_path: Path, data: bytes, match: str) -> None:
    p = tmp_path / "take.mvnx"
    p.write_bytes(data)
    with pytest.raises(InputError, match=match):
        load_mvnx_all(p)


def test_dtd_after_a_long_comment_is_refused(tmp_path: Path) -> None:
    # the old check read only the first 64 kB; a comment (holding "<mvnx") pushed the DTD past it
    pad = b"<!-- <mvnx " + b"x" * 70_000 + b" -->"
    _refused(tmp_path, _mvnx_of(b"&lol9;", pad + _LOL), "DTD or entities")
    xxe = b'<!DOCTYPE m [<!ENTITY x SYSTEM "file:///etc/passwd">]>'
    _refused(tmp_path, _mvnx_of(_small_frames(3), pad + xxe,
                                b'<sensor label="&x;"/>'), "DTD or entities")


def test_billion_laughs_and_utf16_dtd_are_refused(tmp_path: Path) -> None:
    _refused(tmp_path, _mvnx_of(b"&lol9;", _LOL), "DTD or entities")
    u16 = ('<?xml version="1.0" encoding="UTF-16"?><!DOCTYPE m [<!ENTITY a "b">]>'
           '<mvnx><frames></frames></mvnx>').encode("utf-16")
    _refused(tmp_path, u16, "UTF-16")
    latin = _mvnx_of(_small_frames(3)).replace(b"UTF-8", b"shift_jis")
    _refused(tmp_path, latin, "encoding")


def test_deep_nesting_is_refused(tmp_path: Path) -> None:
    n = 100_000
    _refused(tmp_path, b"<mvnx>" + b"<a>" * n + b"</a>" * n + b"</mvnx>", "nested")


def test_a_frame_with_many_children_is_refused(tmp_path: Path) -> None:
    _refused(tmp_path, _mvnx_of(b'<frame type="normal">' + b"<a/>" * 100_000 + b"</frame>"),
             "more than 256 elements")


def test_one_huge_text_node_is_refused_before_splitting(tmp_path: Path) -> None:
    big = b"<sensorOrientation>" + b"1 " * 200_000 + b"</sensorOrientation>"
    _refused(tmp_path, _mvnx_of(b'<frame type="normal" index="0">' + big + b"</frame>"),
             "characters")


def test_many_trackers_and_long_labels_are_refused(tmp_path: Path) -> None:
    # 20 000 trackers took 75 s (one recording each) before the cap
    many = (b'<frame type="normal" index="%d"><sensorOrientation>' + b"1 0 0 0 " * 2000
            + b"</sensorOrientation><sensorFreeAcceleration>" + b"0 0 0 " * 2000
            + b"</sensorFreeAcceleration></frame>")
    _refused(tmp_path, _mvnx_of(b"".join(many % i for i in range(3))), "trackers")
    _refused(tmp_path, _mvnx_of(_small_frames(3), sensors=b'<sensor label="' + b"A" * 10_000
                                + b'"/>'), "label longer")
    _refused(tmp_path, _mvnx_of(_small_frames(3), sensors=b'<sensor label="s"/>' * 1000),
             "more than 256 sensors")


def test_elements_outside_the_frames_do_not_pile_up(tmp_path: Path) -> None:
    # 500 000 empty elements beside the frames: the tree kept every one (~80 B each,
    # ~39 MB); now only the pre-scan's block (< 12 MB at worst) is held at once
    p = tmp_path / "take.mvnx"
    p.write_bytes(_mvnx_of(b"<x/>" * 500_000 + _small_frames(3)))
    tracemalloc.start()
    try:
        recs = load_mvnx_all(p)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert list(recs) == ["P"]
    assert peak < 16 * 2**20, peak


def test_a_tag_with_a_million_attributes_is_refused_before_parsing(tmp_path: Path) -> None:
    # expat hands them over at once: 10 MB of attributes peaked at 600 MB (256 MB: ~15 GB)
    attrs = b" ".join(b'a%d=">"' % i for i in range(200_000))  # '>' is legal in a value
    _refused(tmp_path, _mvnx_of(b"<x " + attrs + b"/>" + _small_frames(3)), "without an XML tag")


def test_a_long_run_across_read_blocks_is_seen(tmp_path: Path) -> None:
    # 3.5 MB of frames, then a 1.5 MB text node that straddles the scan's blocks
    frames = _small_frames(26_000)
    assert 3 * 2**20 < len(frames) < 4 * 2**20
    _refused(tmp_path, _mvnx_of(frames + b"<c>" + b"7" * (3 * 2**19) + b"</c>"),
             "without an XML tag")


def test_the_element_count_is_bounded(tmp_path: Path,
                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """256 MB of empty elements is 64 M elements, ~5 min of walking (2 M took 10.7 s
    here); the count is bounded (12 M in use; 1 000 here to keep the test small)."""
    monkeypatch.setattr(_mvnx, "MAX_ELEMENTS", 1000)
    _refused(tmp_path, _mvnx_of(b"<x/>" * 2000 + _small_frames(3)), "more than 1,000 XML")
    p = tmp_path / "ok.mvnx"
    p.write_bytes(_mvnx_of(_small_frames(100)))  # ~310 elements: read
    assert len(load_mvnx_all(p)["P"]) == 100


def test_small_frames_stream_in_memory_below_the_file_size(tmp_path: Path) -> None:
    """A long take of small frames: the parser streams and keeps the numbers 8 bytes
    each, so parsing peaks under the file's size (it peaked at 2.4× with one small array
    per frame and element). 20 000 frames, 2.7 MB: parsing 2.3 MB, the whole load with
    the recordings 7.5 MB; 256 MB (the upload limit) extrapolates to ~0.7 GB."""
    p = tmp_path / "take.mvnx"
    p.write_bytes(_mvnx_of(_small_frames(20_000)))
    tracemalloc.start()
    try:
        d = _mvnx._read(p)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert len(d["index"]) == 20_000
    assert peak < p.stat().st_size, (peak, p.stat().st_size)


def test_the_mvnx_limits_are_above_a_real_export() -> None:
    # a full suit: 23 segments, 17 trackers, ~10 elements a frame, ~9 kB of numbers a frame
    assert _mvnx.MAX_TRACKERS >= 17 and _mvnx.MAX_LABELS >= 23
    assert _mvnx.MAX_FRAME_CHILDREN >= 20 and _mvnx.MAX_VALUE_CHARS >= 16 * 2**10


def test_zip_tricks_are_refused_or_ignored(tmp_path: Path) -> None:
    """Held before this review (regression guards): thousands of empty members, a nested
    zip (never opened), a symlink entry (read as a file's bytes, never followed)."""
    many = tmp_path / "many.zip"
    with zipfile.ZipFile(many, "w") as z:
        for i in range(3000):
            z.writestr(f"e{i}.csv", b"")
    with pytest.raises(InputError, match="files in the zip"):
        load_imu(many)
    nested = tmp_path / "nested.zip"
    with zipfile.ZipFile(nested, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("inner.zip", many.read_bytes())
    with pytest.raises(InputError, match="no accelerometer or gyroscope"):
        load_imu(nested)
    link = tmp_path / "link.zip"
    with zipfile.ZipFile(link, "w") as z:
        info = zipfile.ZipInfo("Gyroscope.csv")
        info.external_attr = (0o120777 << 16)  # a symlink to /etc/passwd
        z.writestr(info, "/etc/passwd")
        z.writestr("Accelerometer.csv", "time,x,y,z\n1,0,0,9.8\n2,0,0,9.8\n")
    with pytest.raises(InputError) as e:
        load_imu(link)
    assert "root:" not in str(e.value)


_ACC = b"time,x,y,z\n" + b"".join(b"%d,0,0,9.8\n" % (i * 10**7) for i in range(200))


def _phone_zip(tmp_path: Path, members: dict[str, bytes]) -> Path:
    p = tmp_path / "phone.zip"
    with zipfile.ZipFile(p, "w", zipfile.ZIP_DEFLATED) as z:
        for name, data in members.items():
            z.writestr(name, data)
    return p


def test_a_csv_with_a_million_columns_is_refused_in_a_short_message(tmp_path: Path) -> None:
    # the whole header came back in the message (~10 MB of error text) after 56 s
    n = 200_000
    wide = (b",".join(b"c%d" % i for i in range(n)) + b"\n"
            + b",".join(b"1" for _ in range(n)) + b"\n")
    with pytest.raises(InputError, match="columns, more than the 64") as e:
        load_imu(_phone_zip(tmp_path, {"Gyroscope.csv": wide, "Accelerometer.csv": _ACC}))
    assert len(str(e.value)) < 500


def test_a_field_past_the_csv_limit_is_an_input_error(tmp_path: Path) -> None:
    # csv.Error ("field larger than field limit") escaped the reader, not an InputError
    long_line = b"time,x,y,z\n" + b"1" * 500_000 + b"\n"
    with pytest.raises(InputError, match="not a sensor CSV"):
        load_imu(_phone_zip(tmp_path, {"Gyroscope.csv": long_line, "Accelerometer.csv": _ACC}))
    gyr = b"time,x,y,z\n" + b"".join(b"%d,0.1,0,0\n" % (i * 10**7) for i in range(200))
    meta = b"platform,version\n" + b"x" * 500_000 + b",1\n"
    rec = load_imu(_phone_zip(tmp_path, {"Gyroscope.csv": gyr, "Accelerometer.csv": _ACC,
                                         "Metadata.csv": meta}))
    assert len(rec) > 100 and rec.meta["acc_sign_from"] == "assumed"


def test_a_zip_whose_file_list_is_huge_is_refused_before_it_is_parsed(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``zipfile`` turns a zip's whole file list into objects as it opens it, before any
    member count can be checked: a list longer than a phone recording's is refused from the
    end record's declared size, without opening the zip (and so without that memory)."""
    from engine.imu import _phone

    big = tmp_path / "many.zip"
    with zipfile.ZipFile(big, "w") as zf:
        for k in range(12_000):  # ~1.4 MB of file list, no data
            zf.writestr(f"Recording/{'x' * 60}_{k:05d}.csv", b"")
    opened: list[object] = []
    real_zipfile = zipfile.ZipFile
    monkeypatch.setattr(_phone.zipfile, "ZipFile",
                        lambda *a, **k: opened.append(a) or real_zipfile(*a, **k))
    with pytest.raises(InputError, match=r"many\.zip: the zip's list of files is 1\.\d MB"):
        load_imu(big)
    assert _phone.zip_unpacked_bytes(big) is None
    assert opened == []
    # a phone recording's zip: its declared list size is the real one, and it opens
    small = tmp_path / "walk.zip"
    with zipfile.ZipFile(small, "w") as zf:
        zf.writestr("Walk/Accelerometer.csv", "time,x,y,z\n0,0,0,9.8\n")
        zf.writestr("Walk/Gyroscope.csv", "time,x,y,z\n0,0,0,0\n")
    with real_zipfile(small) as zf:
        listed = sum(46 + len(i.filename) + len(i.extra) + len(i.comment)
                     for i in zf.infolist())
        unpacked = sum(i.file_size for i in zf.infolist())
    assert _phone._zip_directory_bytes(small) == listed
    assert _phone.zip_unpacked_bytes(small) == unpacked
    # not a zip at all: no end record, left to zipfile's own message
    (tmp_path / "no.zip").write_bytes(b"not a zip" * 100)
    assert _phone._zip_directory_bytes(tmp_path / "no.zip") is None


def test_compressed_datasets_are_counted_at_their_size_in_memory(tmp_path: Path) -> None:
    """A compressed HDF5 dataset or .mat variable can unpack to far more than the file:
    estimate_memory_bytes tells the numbers' size (8 bytes each, float64) from the
    headers, reading none, and is at least the file's size; a .mat's variables the
    reader does not take are skipped unread, and a wanted one that is no numeric array
    (a cell: its header does not tell its size) is refused before it is read."""
    import h5py
    import numpy as np
    import scipy.io

    from engine.imu.io import estimate_memory_bytes

    bomb = tmp_path / "trial.hdf5"
    with h5py.File(bomb, "w") as f:  # 2.4 GB of zeros in a few kB
        f.create_dataset("imu_gyr", shape=(10**8, 3), dtype="f4", chunks=(10**5, 3),
                         compression="gzip")
        f.create_dataset("opt_pos", shape=(10**9, 3), dtype="f8", chunks=(10**5, 3),
                         compression="gzip")
    assert bomb.stat().st_size < 10**5
    assert estimate_memory_bytes(bomb) == 8 * 3 * 10**8  # opt_pos is not read
    # APDM: the largest sensor's datasets (one is read), float32 counted as float64
    apdm = tmp_path / "opal.h5"
    with h5py.File(apdm, "w") as f:
        for sid, n in (("XI-1", 1000), ("XI-2", 10**7)):
            for k in ("Accelerometer", "Gyroscope"):
                f.create_dataset(f"Sensors/{sid}/{k}", shape=(n, 3), dtype="f4",
                                 chunks=True, compression="gzip")
            f.create_dataset(f"Sensors/{sid}/Time", shape=(n,), dtype="u8", chunks=True,
                             compression="gzip")
        f.create_dataset("Processed/XI-2/Orientation", shape=(10**7, 4), dtype="f4",
                         chunks=True, compression="gzip")
    assert estimate_memory_bytes(apdm) == 8 * 10**7 * (3 + 3 + 1 + 4)
    # .mat (v5, compressed): the variables the reader takes, not the others
    mat = tmp_path / "walk.mat"
    n = 10**6
    scipy.io.savemat(mat, {"time": np.arange(n, dtype=float)[:, None] / 100,
                           "Gyroscope": np.zeros((n, 3), np.float32),
                           "Accelerometer": np.zeros((n, 3)), "junk": np.zeros(10**7)},
                     do_compression=True)
    assert mat.stat().st_size < 8 * n
    assert estimate_memory_bytes(mat) == 8 * n * 7
    # small or unreadable files, CSVs and the rest: their size
    for name, data in (("tiny.mat", None), ("bad.h5", b"not HDF5"), ("bad.mat", b"x" * 99),
                       ("a.csv", b"time,gyr_x\n0,1\n")):
        p = tmp_path / name
        if data is None:
            scipy.io.savemat(p, {"time": np.zeros((1, 1))})
        else:
            p.write_bytes(data)
        assert estimate_memory_bytes(p) == p.stat().st_size, name
    # a wanted variable that is a cell: refused unread, with what to do
    cell = tmp_path / "cell.mat"
    scipy.io.savemat(cell, {"time": np.zeros((10, 1)), "Accelerometer": np.zeros((10, 3)),
                            "Gyroscope": np.array([np.zeros(3), np.zeros(2)], dtype=object)})
    with pytest.raises(InputError, match=r"cell\.mat: variable 'Gyroscope' is not numeric "
                                         r"\(a MATLAB cell, not a numeric array\); save it "
                                         "as a plain matrix"):
        load_imu(cell)


def _broad_h5(p: Path, n: int = 200, **extra: Any) -> None:
    """A small self-contained BROAD-layout HDF5 trial (``extra``: more datasets/links)."""
    import h5py
    import numpy as np

    with h5py.File(p, "w") as f:
        f.attrs["sampling_rate"] = 100.0
        f["imu_gyr"] = np.zeros((n, 3))
        f["imu_acc"] = np.tile([0.0, 0.0, 9.81], (n, 1))
        f["imu_mag"] = np.tile([20.0, 0.0, -40.0], (n, 1))
        f["opt_quat"] = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
        f["movement"] = np.zeros(n, dtype=bool)
        for k, v in extra.items():
            f[k] = v


def test_an_hdf5_file_that_takes_data_from_other_files_is_refused(tmp_path: Path) -> None:
    """HDF5 lets a dataset's numbers live in any file it names (external storage), link to
    another file's objects, or map other files (virtual datasets): an uploaded trial must
    not make the server read its own files, so only self-contained files are read."""
    import h5py
    import numpy as np

    from engine.imu.io import estimate_memory_bytes

    secret = tmp_path / "server-file.bin"  # e.g. another subject's data, the database
    secret.write_bytes(np.arange(600, dtype=float).tobytes())
    ok = tmp_path / "ok.hdf5"
    _broad_h5(ok)
    assert load_imu(ok).gyr.shape == (200, 3)  # the same layout, self-contained, is read

    external = tmp_path / "external.hdf5"
    _broad_h5(external)
    with h5py.File(external, "a") as f:
        del f["imu_gyr"]
        f.create_dataset("imu_gyr", shape=(200, 3), dtype=float,
                         external=[(str(secret), 0, 200 * 3 * 8)])
    with h5py.File(external, "r") as f:  # (h5py itself would read the other file)
        assert f["imu_gyr"][()].ravel()[:3].tolist() == [0.0, 1.0, 2.0]
    with pytest.raises(InputError, match=r"external\.hdf5: the file takes data from other "
                                         r"files \(imu_gyr \(data kept in other files\)\), "
                                         "which is not accepted; save it as one "
                                         "self-contained HDF5 file"):
        load_imu(external)

    linked = tmp_path / "linked.hdf5"
    _broad_h5(linked, other=h5py.ExternalLink(str(ok), "/imu_acc"))
    with pytest.raises(InputError, match=r"other \(a link to another file\)"):
        load_imu(linked)

    virtual = tmp_path / "virtual.hdf5"
    _broad_h5(virtual)
    layout = h5py.VirtualLayout(shape=(200, 3), dtype=float)
    layout[:] = h5py.VirtualSource(str(ok), "imu_acc", shape=(200, 3))
    with h5py.File(virtual, "a") as f:
        del f["imu_acc"]
        f.create_virtual_dataset("imu_acc", layout)
    with pytest.raises(InputError, match=r"imu_acc \(a virtual dataset\)"):
        load_imu(virtual)

    # APDM's layout goes through the same check, and the request budget's estimate only
    # counts such a file at its size (the reader then refuses it)
    apdm = tmp_path / "opal.h5"
    with h5py.File(apdm, "w") as f:
        f.create_dataset("Sensors/XI-1/Accelerometer", shape=(200, 3), dtype=float,
                         external=[(str(secret), 0, 200 * 3 * 8)])
        f["Sensors/XI-1/Gyroscope"] = np.zeros((200, 3))
        f["Sensors/XI-1/Time"] = np.arange(200, dtype="u8") * 10_000
    with pytest.raises(InputError, match="takes data from other files"):
        load_imu(apdm)
    assert estimate_memory_bytes(apdm) == apdm.stat().st_size


def test_a_variable_length_dataset_is_refused_unread(tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """A variable-length dataset is counted by the upload budget at a pointer per item,
    but each item can hold any number of values (a few kB of file, gigabytes once read):
    a dataset the readers take that is not plain numbers is refused before it is read,
    with what to do (BROAD layout and APDM alike)."""
    import h5py
    import numpy as np

    reads: list[str] = []
    real_getitem = h5py.Dataset.__getitem__

    def spy(self: Any, key: Any) -> Any:
        reads.append(self.name)
        return real_getitem(self, key)

    vlen = h5py.vlen_dtype(np.float64)
    broad = tmp_path / "trial.hdf5"
    _broad_h5(broad)
    with h5py.File(broad, "a") as f:
        del f["imu_gyr"]
        ds = f.create_dataset("imu_gyr", shape=(3,), dtype=vlen)
        for k in range(3):
            ds[k] = np.zeros(1000)
    apdm = tmp_path / "opal.h5"
    with h5py.File(apdm, "w") as f:
        f["Sensors/XI-1/Accelerometer"] = np.tile([0.0, 0.0, 9.81], (100, 1))
        g = f.create_dataset("Sensors/XI-1/Gyroscope", shape=(2,), dtype=vlen)
        g[0] = np.zeros(500)
        g[1] = np.zeros(500)
        f["Sensors/XI-1/Time"] = np.arange(100, dtype=np.uint64) * 7812
    monkeypatch.setattr(h5py.Dataset, "__getitem__", spy)
    for p, name in ((broad, "imu_gyr"), (apdm, "Gyroscope")):
        with pytest.raises(InputError, match=rf"{p.name}: dataset '{name}' holds "
                                             r"variable-length data, not numbers; save it"):
            load_imu(p)
        assert not any(r.endswith(name) for r in reads), reads
