"""IMU upload of an Xsens MVN export (one stream per tracker, or the chosen one) and of a
phone app's zip (Sensor Logger, iOS sign): the session's reference errors are the
filter's against the simulated truth; a zip without a gyroscope or accelerometer file,
with an unsafe member name or unpacking too large is refused with a 400 saying what to
fix."""

from __future__ import annotations

import io
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.api.limits import size_words
from engine.imu import _phone
from engine.imu.filter import orientation_filter
from engine.imu.io import ImuRecording
from engine.imu.metrics import orientation_errors
from tests.app.analysis.test_imu_api import client  # noqa: F401 - the logged-in fixture
from tests.engine.imu.test_foreign_imu_mvnx_phone import (
    _meta,
    _motion,
    sensor_logger,
    write_mvnx,
    zip_files,
)


@pytest.fixture(scope="module")
def sims() -> dict[str, ImuRecording]:
    return {"Pelvis": _motion(rng=1), "RightLowerLeg": _motion(rng=2, peak=2.0)}


def _say(n: int) -> str:
    """A size in the routes' words (``limits.size_words``: KB below 1 MB, never "0 MB")."""
    return size_words(n)


def _over(n: int) -> str:
    """A size said to be over a limit: rounded up (``round_up=True``)."""
    return size_words(n, round_up=True)


def _post(c: TestClient, name: str, content: bytes, **data: object) -> tuple[int, dict]:
    r = c.post("/api/imu/sessions", files=[("files", (name, content, "application/zip"))],
               data={"synchronise": "false", **data})
    return r.status_code, r.json()


def _own_error(rec: ImuRecording) -> float:
    """Our filter's error against the truth (the page runs it on the whole recording)."""
    q, _, _ = orientation_filter(rec.gyr, rec.acc, rec.mag, frequency=rec.frequency,
                                 offline=True)
    assert rec.quat_ref is not None
    return orientation_errors(q, rec.quat_ref)["total_deg"]


def test_mvnx_upload_one_stream_per_tracker(client: TestClient,  # noqa: F811
                                            sims: dict[str, ImuRecording],
                                            tmp_path: Path) -> None:
    content = write_mvnx(tmp_path / "take.mvnx", sims).read_bytes()
    code, body = _post(client, "take.mvnx", content)
    assert code == 200, body
    assert [s["name"] for s in body["sensors"]] == ["Pelvis", "RightLowerLeg"]
    for name, sim in sims.items():
        assert body["reference_errors"][name]["total_deg"] == pytest.approx(
            _own_error(sim), abs=0.01)
    # a name given to the file prefixes its trackers; a choice takes one tracker
    code, body = _post(client, "take.mvnx", content, sensors="suit")
    assert code == 200, body
    assert [s["name"] for s in body["sensors"]] == ["suit_Pelvis", "suit_RightLowerLeg"]
    code, body = _post(client, "take.mvnx", content, file_sensors="RightLowerLeg")
    assert code == 200, body
    assert [s["name"] for s in body["sensors"]] == ["take_RightLowerLeg"]
    code, body = _post(client, "take.mvnx", content, file_sensors="Head")
    assert code == 400 and "Pelvis, RightLowerLeg" in body["detail"]
    assert "take.mvnx" in body["detail"] and "imu0" not in body["detail"]


def test_mvnx_upload_size_bound(client: TestClient, sims: dict[str, ImuRecording],  # noqa: F811
                                tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """An MVNX export may be larger than other files (segment kinematics in every frame)
    but is bounded too."""
    from app.api.routes import imu as route

    content = write_mvnx(tmp_path / "take.mvnx", sims).read_bytes()
    monkeypatch.setattr(route, "MAX_MVNX_BYTES", len(content) - 1)
    code, body = _post(client, "take.mvnx", content)
    assert code == 413 and "take.mvnx: larger than" in body["detail"]
    monkeypatch.setattr(route, "MAX_MVNX_BYTES", len(content))
    assert _post(client, "take.mvnx", content)[0] == 200


def test_phone_zip_upload(client: TestClient, sims: dict[str, ImuRecording],  # noqa: F811
                          tmp_path: Path) -> None:
    sim = sims["Pelvis"]
    files = sensor_logger(sim, ios=True, metadata=_meta("ios", False))
    content = zip_files(tmp_path / "walk.zip", files).read_bytes()
    code, body = _post(client, "walk.zip", content)
    assert code == 200, body
    (row,) = body["sensors"]
    assert row["name"] == "walk" and row["samples"] == len(sim)
    assert body["reference_errors"]["walk"]["total_deg"] == pytest.approx(_own_error(sim),
                                                                          abs=0.01)
    # declared Android against the iOS data: the sign is then wrong, and the filter's
    # orientation is upside down against the phone's own
    code, body = _post(client, "walk.zip", content, platform="android")
    assert code == 200, body
    assert body["reference_errors"]["walk"]["total_deg"] > 90.0
    assert _post(client, "walk.zip", content, platform="windows")[0] == 422


def _zip_bytes(files: dict[str, str | bytes]) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        for k, v in files.items():
            z.writestr(k, v)
    return buf.getvalue()


def test_bad_zips_are_refused(client: TestClient, sims: dict[str, ImuRecording],  # noqa: F811
                              monkeypatch: pytest.MonkeyPatch) -> None:
    files = sensor_logger(sims["Pelvis"], ios=False)
    no_gyro = {k: v for k, v in files.items() if k != "Gyroscope.csv"}
    code, body = _post(client, "phone.zip", _zip_bytes(no_gyro))
    assert code == 400 and "phone.zip: no gyroscope file (Gyroscope.csv)" in body["detail"]
    no_acc = {k: v for k, v in files.items() if k not in ("Accelerometer.csv", "Gravity.csv")}
    code, body = _post(client, "phone.zip", _zip_bytes(no_acc))
    assert code == 400 and "no accelerometer file with gravity" in body["detail"]
    code, body = _post(client, "phone.zip", _zip_bytes({"Location.csv": "time,lat\n1,2\n"}))
    assert code == 400 and "no accelerometer or gyroscope file" in body["detail"]
    code, body = _post(client, "phone.zip", _zip_bytes({**files, "../up.csv": "1"}))
    assert code == 400 and "unsafe file name" in body["detail"]
    monkeypatch.setattr(_phone, "MAX_ZIP_UNCOMPRESSED", 2**20)
    code, body = _post(client, "phone.zip", _zip_bytes({**files, "Big.csv": b"0" * 2**21}))
    assert code == 400 and "split the recording" in body["detail"]
    code, body = _post(client, "phone.zip", b"not a zip")
    assert code == 400 and "not a readable zip" in body["detail"]


def test_phone_zips_of_one_session_bounded_together(
        client: TestClient, sims: dict[str, ImuRecording],  # noqa: F811
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Phone zips unpack to ≈3.8× their size in memory: one request's zips together may
    unpack to at most MAX_REQUEST_DATA_BYTES, refused (413, saying the total, the limit
    and what to do) from their directories before any is unpacked. A zip whose directory
    understates a member cannot slip past: it is refused when unpacked."""
    from app.api.routes import imu as route

    files = sensor_logger(sims["Pelvis"], ios=False)
    content = zip_files(tmp_path / "walk.zip", files).read_bytes()
    size = _phone.zip_unpacked_bytes(tmp_path / "walk.zip")
    assert size is not None and size > len(content)  # deflated CSV
    loaded: list[Path] = []
    real_load = route._load

    def load(path: Path, kwargs: dict) -> ImuRecording:
        loaded.append(path)
        return real_load(path, kwargs)

    monkeypatch.setattr(route, "_load", load)
    monkeypatch.setattr(route, "MAX_REQUEST_DATA_BYTES", size)
    code, body = _post(client, "walk.zip", content)
    assert code == 200, body
    loaded.clear()
    r = client.post("/api/imu/sessions", data={"synchronise": "false"},
                    files=[("files", (n, content, "application/zip"))
                           for n in ("walk1.zip", "walk2.zip", "notes.csv")])
    assert r.status_code == 413 and not loaded
    detail = r.json()["detail"]
    mb = _over(2 * size)
    assert detail.startswith(f"the 2 phone zips of this session unpack to {mb} together "
                             "(the largest, walk1.zip, "), detail
    assert f"more than the {_say(size)} one session may unpack; upload them in " \
           "several sessions" in detail
    monkeypatch.setattr(route, "MAX_REQUEST_DATA_BYTES", size - 1)
    code, body = _post(client, "walk.zip", content)
    assert code == 413 and not loaded
    assert body["detail"].startswith("walk.zip: the zip unpacks to "), body
    assert "split the recording" in body["detail"]
    # a member longer than its directory says: counted at its declared size, and zipfile
    # reads no more than that (its CRC then fails), so the bound holds
    monkeypatch.setattr(route, "MAX_REQUEST_DATA_BYTES", size)
    data = bytearray(_zip_bytes({"Gyroscope.csv": b"0" * 100_000}))
    for sig, at in ((b"PK\x03\x04", 22), (b"PK\x01\x02", 24)):  # local header, directory
        k = data.find(sig)
        data[k + at:k + at + 4] = (1000).to_bytes(4, "little")
    tmp_zip = tmp_path / "lying.zip"
    tmp_zip.write_bytes(bytes(data))
    assert _phone.zip_unpacked_bytes(tmp_zip) == 1000
    code, body = _post(client, "lying.zip", bytes(data))
    assert code == 400 and "lying.zip: cannot unpack 'Gyroscope.csv'" in body["detail"], body
    assert _phone.zip_unpacked_bytes(tmp_path / "none.zip") is None
    assert _post(client, "bad.zip", b"not a zip")[0] == 400  # the engine says why


def _csv_bytes(seconds: float = 2.0) -> bytes:
    """A generic one-sensor CSV (gyroscope rad/s, acceleration g: declare the units)."""
    t = np.arange(round(seconds * 100)) / 100
    return "\n".join(["time,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z",
                      *(f"{ti:.2f},0.01,0,0,0,0,1.0" for ti in t)]).encode()


def test_one_budget_for_the_csvs_and_zips_of_a_request(
        client: TestClient, sims: dict[str, ImuRecording],  # noqa: F811
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Plain CSVs (and the skeleton CSV) count against MAX_REQUEST_DATA_BYTES too, at
    their size, with the zips at their unpacked size: one budget per request. Past it the
    request is refused (413, the total, the limit and what to do) before any file is read,
    and nothing is stored; at it, accepted. Each zip's directory is read once, for the
    bound and the unpacking."""
    from app.api.routes import imu as route
    from app.server.imu_analysis import ImuStore

    content = zip_files(tmp_path / "walk.zip", sensor_logger(sims["Pelvis"], ios=False)
                        ).read_bytes()
    unpacked = _phone.zip_unpacked_bytes(tmp_path / "walk.zip")
    assert unpacked is not None
    csv = _csv_bytes()
    added: list[object] = []
    real_add = ImuStore.add
    monkeypatch.setattr(ImuStore, "add",
                        lambda self, job: added.append(job) or real_add(self, job))
    loaded: list[Path] = []
    real_load = route._load

    def load(path: Path, kwargs: dict) -> ImuRecording:
        loaded.append(path)
        return real_load(path, kwargs)

    monkeypatch.setattr(route, "_load", load)
    opened: list[Path] = []

    class Counting(zipfile.ZipFile):  # defined before the patch: the real class
        def __init__(self, file: Path, *a: Any, **k: Any) -> None:
            opened.append(file)
            super().__init__(file, *a, **k)

    monkeypatch.setattr(_phone.zipfile, "ZipFile", Counting)

    def post(*named: tuple[str, bytes], skeleton: bytes | None = None) -> Any:
        up = [("files", (n, c, "application/octet-stream")) for n, c in named]
        if skeleton is not None:
            up.append(("skeleton", ("walk_depth.csv", skeleton, "text/csv")))
        return client.post("/api/imu/sessions", files=up, data={
            "synchronise": "false", "gyr_unit": "rad/s", "acc_unit": "g"})

    # at the budget: accepted, the zip opened once (before: once for the bound, once to
    # unpack it)
    total = unpacked + len(csv)
    monkeypatch.setattr(route, "MAX_REQUEST_DATA_BYTES", total)
    r = post(("walk.zip", content), ("mine.csv", csv))
    assert r.status_code == 200, r.text
    assert [s["name"] for s in r.json()["sensors"]] == ["walk", "mine"]
    assert len(opened) == 1 and len(loaded) == 2 and len(added) == 1
    # one byte over: refused before any file is read, nothing stored
    opened.clear()
    loaded.clear()
    monkeypatch.setattr(route, "MAX_REQUEST_DATA_BYTES", total - 1)
    r = post(("walk.zip", content), ("mine.csv", csv))
    assert r.status_code == 413 and not loaded and len(added) == 1, r.text
    largest = "walk.zip" if unpacked >= len(csv) else "mine.csv"
    assert " 0 MB" not in r.json()["detail"]  # sizes under 1 MB said in KB
    assert r.json()["detail"] == (
        f"upload fewer or shorter files: the 2 files of this session hold {_over(total)} to "
        f"read (files as they are, phone zips unpacked, .mat and HDF5 files as their "
        f"numbers take in memory; the largest, {largest}, {_say(max(unpacked, len(csv)))}), "
        f"at most {_say(total - 1)} in one session; upload them in several sessions or split "
        "the longest recording")
    assert len(opened) == 1
    # CSVs only (twelve 64 MB ones fitted before), the skeleton CSV counted too
    monkeypatch.setattr(route, "MAX_REQUEST_DATA_BYTES", 2 * len(csv))
    r = post(("mine1.csv", csv), ("mine2.csv", csv), ("mine3.csv", csv))
    assert r.status_code == 413 and not loaded and len(added) == 1, r.text
    assert r.json()["detail"].startswith("upload fewer or shorter files: the 3 files of "
                                         "this session hold ")
    r = post(("mine1.csv", csv), ("mine2.csv", csv), skeleton=b"time,SpineBase_x\n0,0\n")
    assert r.status_code == 413 and not loaded and len(added) == 1, r.text
    assert "the 3 files of this session" in r.json()["detail"]
    r = post(("mine1.csv", csv), ("mine2.csv", csv))
    assert r.status_code == 200, r.text
    assert len(loaded) == 2 and len(added) == 2


def _madgwick_mat(path: Path, rec: ImuRecording) -> bytes:
    """``rec`` as Madgwick's ExampleData.mat (deg/s, g, gauss), compressed as MATLAB
    writes it."""
    import scipy.io

    scipy.io.savemat(path, {"time": rec.time[:, None], "Gyroscope": np.rad2deg(rec.gyr),
                            "Accelerometer": rec.acc / 9.80665,
                            "Magnetometer": (rec.mag if rec.mag is not None
                                             else np.zeros_like(rec.acc)) / 100},
                     do_compression=True)
    return path.read_bytes()


def _broad_hdf5(path: Path, n: int) -> bytes:
    """A BROAD trial of ``n`` samples at rest, its datasets gzip-compressed (the file far
    smaller than its numbers in memory)."""
    import h5py

    with h5py.File(path, "w") as f:
        for k, row in (("imu_gyr", [0.0, 0, 0]), ("imu_acc", [0.0, 0, 9.81]),
                       ("imu_mag", [20.0, 0, -40]), ("opt_quat", [1.0, 0, 0, 0])):
            f.create_dataset(k, data=np.tile(row, (n, 1)), compression="gzip")
        f.create_dataset("movement", data=np.ones(n, bool), compression="gzip")
        f.attrs["sampling_rate"] = 100.0
    return path.read_bytes()


def test_binary_files_count_against_the_request_budget(
        client: TestClient, sims: dict[str, ImuRecording],  # noqa: F811
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """.mat, HDF5 and .mvnx uploads share the request's one budget with its CSVs and
    zips (twelve 64 MB .mat files fitted before): a .mvnx at its size, .mat and HDF5
    files at their numbers' size in memory (8 bytes a number, from the datasets' shapes:
    a compressed dataset unpacks to more than the file). Past the budget the request is
    refused (413, the total, the largest, the limit and what to do) before any file is
    read, and nothing is stored; a .mat and a CSV just within it are accepted."""
    from app.api.routes import imu as route
    from app.server.imu_analysis import ImuStore
    from engine.imu.io import estimate_memory_bytes

    assert route.MAX_REQUEST_DATA_BYTES == 256 * 2**20
    rec = sims["Pelvis"]
    mat = _madgwick_mat(tmp_path / "walk.mat", rec)
    h5 = _broad_hdf5(tmp_path / "trial.hdf5", len(rec))
    mvnx = write_mvnx(tmp_path / "take.mvnx", sims).read_bytes()
    csv = _csv_bytes()
    n = len(rec)
    mat_bytes = 8 * n * (1 + 3 + 3 + 3)
    h5_bytes = 8 * n * (3 + 3 + 3 + 4 + 1)
    assert estimate_memory_bytes(tmp_path / "walk.mat") == mat_bytes > len(mat)
    assert estimate_memory_bytes(tmp_path / "trial.hdf5") == h5_bytes > len(h5)
    assert estimate_memory_bytes(tmp_path / "take.mvnx") == len(mvnx)
    added: list[object] = []
    real_add = ImuStore.add
    monkeypatch.setattr(ImuStore, "add",
                        lambda self, job: added.append(job) or real_add(self, job))
    loaded: list[Path] = []
    real_load = route._load
    real_mvnx = route.load_mvnx_all

    def load(path: Path, kwargs: dict) -> ImuRecording:
        loaded.append(path)
        return real_load(path, kwargs)

    def load_mvnx(path: Path) -> dict[str, ImuRecording]:
        loaded.append(path)
        return real_mvnx(path)

    monkeypatch.setattr(route, "_load", load)
    monkeypatch.setattr(route, "load_mvnx_all", load_mvnx)

    def post(*named: tuple[str, bytes]) -> Any:
        return client.post("/api/imu/sessions", data={
            "synchronise": "false", "gyr_unit": "rad/s", "acc_unit": "g"},
            files=[("files", (n, c, "application/octet-stream")) for n, c in named])

    # several binary files over the budget: refused before any is read, nothing stored;
    # each one alone fits
    total = mat_bytes + h5_bytes + 2 * len(mvnx)
    monkeypatch.setattr(route, "MAX_REQUEST_DATA_BYTES", total - 1)
    r = post(("walk.mat", mat), ("trial.hdf5", h5), ("take1.mvnx", mvnx),
             ("take2.mvnx", mvnx))
    assert r.status_code == 413 and not loaded and not added, r.text
    largest = max((("walk.mat", mat_bytes), ("trial.hdf5", h5_bytes),
                   ("take1.mvnx", len(mvnx))), key=lambda s: s[1])
    assert r.json()["detail"] == (
        f"upload fewer or shorter files: the 4 files of this session hold {_over(total)} to "
        "read (files as they are, phone zips unpacked, .mat and HDF5 files as their "
        f"numbers take in memory; the largest, {largest[0]}, {_say(largest[1])}), at most "
        f"{_say(total - 1)} in one session; upload them in several sessions or split the "
        "longest recording")
    # a compressed HDF5 file counts at its numbers' size, not the file's
    monkeypatch.setattr(route, "MAX_REQUEST_DATA_BYTES", h5_bytes - 1)
    r = post(("trial.hdf5", h5))
    assert r.status_code == 413 and not loaded and not added, r.text
    assert r.json()["detail"] == (
        f"upload fewer or shorter files: trial.hdf5 holds {_over(h5_bytes)} to read (files as "
        "they are, phone zips unpacked, .mat and HDF5 files as their numbers take in "
        f"memory), at most {_say(h5_bytes - 1)} in one session; upload them in several "
        "sessions or split the longest recording")
    # a .mat and a CSV just within the budget: accepted; a byte less: refused
    monkeypatch.setattr(route, "MAX_REQUEST_DATA_BYTES", mat_bytes + len(csv))
    r = post(("walk.mat", mat), ("mine.csv", csv))
    assert r.status_code == 200, r.text
    assert [s["name"] for s in r.json()["sensors"]] == ["walk", "mine"]
    assert len(loaded) == 2 and len(added) == 1
    loaded.clear()
    monkeypatch.setattr(route, "MAX_REQUEST_DATA_BYTES", mat_bytes + len(csv) - 1)
    r = post(("walk.mat", mat), ("mine.csv", csv))
    assert r.status_code == 413 and not loaded and len(added) == 1, r.text
    assert "the 2 files of this session" in r.json()["detail"]
